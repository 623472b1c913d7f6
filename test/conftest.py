"""Test-wide setup: DDS isolation, the two kinds of test, and the real-time table.

**DDS isolation.** Every pytest process (the controller and each xdist
worker) claims a ROS_DOMAIN_ID of its own with an exclusive lock file held
for the whole run, so parallel workers, parallel runs and a developer's live
session never cross-talk; discovery stays on this host
(``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST``). Subprocesses inherit both.

**Two kinds of test.** ``make test`` runs the behaviour: every test not
marked ``realtime``, on pytest-xdist workers with ``--dist loadscope``: the
tests of a module go to one worker together, so that the nodes a module
starts in a module-scoped fixture start once. (``--dist loadgroup`` with an
``xdist_group`` marker a module did not keep a module on one worker under
pytest 9.2 and xdist 3.8.) ``make check-realtime`` runs the tests
marked ``realtime`` (claims on milliseconds of wall time) alone and
serially, each under the :class:`~stall_watch.StallWatcher`, and prints one
table of claims (:func:`pytest_terminal_summary`).
"""
import gc
import os
import random
import sys
import time
from pathlib import Path

import pytest
from hypothesis import settings

from hill_muscle_ros.dds_transport import use_udp_transport
from hill_muscle_ros.domain_lock import lock_free_domain
from stall_watch import RepeatedOnStall, StallWatcher

#: Fixtures shared by test modules, each defined once: the sim-time demo run.
pytest_plugins = ('demo_run',)

#: Domain IDs 1..100 stay clear of 0 (the default most people use), of the
#: demo's 101..199, and within the range Fast DDS maps to valid UDP ports.
_DOMAIN_LOW, _DOMAIN_HIGH = 1, 100
_LOCK_PATTERN = 'hill_muscle_ros_test_domain_{}.lock'

REPO = Path(__file__).resolve().parents[1]
PROTOCOLS = REPO / 'config' / 'protocols'

#: The open lock file of the claimed domain; the lock lasts while it is open.
_domain_lock = None

#: Set in the environment by the pytest process that claimed the domain, so
#: that its xdist workers, which inherit the environment, claim their own.
_CLAIMED_ENV = 'HILL_MUSCLE_TEST_DOMAIN_CLAIMED'


def _claim_domain() -> int:
    """Lock and return a domain ID no other pytest process on this machine holds."""
    global _domain_lock
    candidates = list(range(_DOMAIN_LOW, _DOMAIN_HIGH + 1))
    random.Random(os.getpid()).shuffle(candidates)
    claimed = lock_free_domain(candidates, _LOCK_PATTERN)
    if claimed is None:
        raise RuntimeError(f'every ROS_DOMAIN_ID in {_DOMAIN_LOW}..{_DOMAIN_HIGH} is held by '
                           f'another test run')
    domain, _domain_lock = claimed
    return domain


# No per-example deadline: how fast the code runs is make bench's business.
settings.register_profile('hill_muscle_ros', deadline=None)
settings.load_profile('hill_muscle_ros')


def pytest_configure(config):
    inherited_claim = os.environ.get(_CLAIMED_ENV) == '1'
    if 'HILL_MUSCLE_TEST_DOMAIN' not in os.environ or (
            inherited_claim and 'PYTEST_XDIST_WORKER' in os.environ):
        os.environ['HILL_MUSCLE_TEST_DOMAIN'] = str(_claim_domain())
        os.environ[_CLAIMED_ENV] = '1'
    os.environ['ROS_DOMAIN_ID'] = os.environ['HILL_MUSCLE_TEST_DOMAIN']
    os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    os.environ.pop('ROS_STATIC_PEERS', None)
    # The test process's own participants (the probes) set up DDS as the
    # package's nodes do, before any rclpy.init: the nodes' heartbeat and
    # buffer settings then hold for the probes' writers too.
    use_udp_transport()


#: Markers of tests run by a command of their own, never by ``make test``:
#: ``realtime`` (``make check-realtime``) and ``install`` (``make check-install``).
OWN_COMMAND = ('realtime', 'install')


def pytest_collection_modifyitems(config, items):
    """Modules with a ``slow`` test first, each kept whole and in order: xdist
    hands the modules out in this order, and a long one left for the end
    keeps its worker busy while the other idles. Then the tests of a
    command of their own (:data:`OWN_COMMAND`) out of a run that does not ask
    for them by ``-m``."""
    slow = {item.module for item in items if item.get_closest_marker('slow')}
    items.sort(key=lambda item: item.module not in slow)
    markexpr = config.option.markexpr or ''
    left_out = [name for name in OWN_COMMAND if name not in markexpr]
    kept = [item for item in items
            if not any(item.get_closest_marker(name) for name in left_out)]
    if len(kept) != len(items):
        config.hook.pytest_deselected(items=[i for i in items if i not in kept])
        items[:] = kept


#: The module whose tests run now (:func:`pytest_runtest_setup`).
_gc_module = None


@pytest.hookimpl(tryfirst=True)
def pytest_runtest_setup(item):
    """At a module's first test: collect, then freeze what survives, and keep
    the collector off while a ``ros`` module runs. Inside a DDS test a full
    collection of the suite's heap (numba's kernels, hypothesis) stopped the
    probe for up to 0.58 s; frozen, that heap is no longer walked, and the
    young cycles wait for the next module."""
    global _gc_module
    if item.module is _gc_module:
        return
    _gc_module = item.module
    gc.enable()
    gc.collect()
    gc.freeze()
    if item.get_closest_marker('ros'):
        gc.disable()


@pytest.fixture(scope='session')
def stall_watcher():
    """One :class:`~stall_watch.StallWatcher` for the whole run: the only
    evidence on which a test may repeat a timing measurement."""
    with StallWatcher() as watcher:
        yield watcher


@pytest.fixture(autouse=True)
def _stalls_of_a_realtime_test(request):
    """Under a ``realtime`` test, the stall watcher runs and the test's span is
    kept, so that a failure can be told from a stall of the machine
    (:func:`pytest_runtest_makereport`)."""
    marker = request.node.get_closest_marker('realtime')
    # A test that takes the watcher (repeat_only_on_external_stall) or says it
    # judges stalls itself (realtime(judges_stalls=True)) is its own judge.
    if (marker is None or 'stall_watcher' in request.fixturenames
            or marker.kwargs.get('judges_stalls')):
        yield
        return
    watcher = request.getfixturevalue('stall_watcher')
    request.node.stall_span = (watcher, time.monotonic())
    yield


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item, call):
    """A ``realtime`` claim that failed while the stall watcher measured an
    external stall is reported as skipped (STALLED in the table), naming the
    stall: the machine, not the product, was measured. Without one it fails."""
    outcome = yield
    report = outcome.get_result()
    span = getattr(item, 'stall_span', None)
    if call.when != 'call' or not report.failed or span is None:
        return
    watcher, start_s = span
    stalls = watcher.stalls(start_s, time.monotonic())
    if stalls:
        worst = max(stalls, key=lambda stall: stall[2])
        why = (f'STALLED: the claim failed while the machine kept {len(stalls)} process(es) '
               f'of the test from a CPU, worst {worst[0]} waiting {worst[2] * 1e3:.0f} ms '
               f'within {worst[3] * 1e3:.0f} ms')
        _repeats.append((item.nodeid, why))
        report.outcome = 'skipped'
        report.longrepr = (str(item.path), item.location[1] or 0, why)


#: The rows of the real-time table: (test, claim) -> (measured, limit); a
#: repeated run's row replaces the earlier one's.
_claims: dict[tuple[str, str], tuple[str, str]] = {}
#: The test ids that repeated a run on a measured external stall, with why.
_repeats: list[tuple[str, str]] = []


@pytest.fixture
def realtime_claim(request):
    """``realtime_claim(claim, measured, limit)`` adds a row to
    ``make check-realtime``'s table; the row's verdict is the test's outcome."""
    def record(claim: str, measured: str, limit: str) -> None:
        _claims[(request.node.nodeid, claim)] = (measured, limit)
    return record


def pytest_warning_recorded(warning_message, when, nodeid, location):
    """Count the :class:`~stall_watch.RepeatedOnStall` warnings, with their cause."""
    if issubclass(warning_message.category, RepeatedOnStall):
        _repeats.append((nodeid, str(warning_message.message)))


def pytest_terminal_summary(terminalreporter, exitstatus, config):
    """The real-time table (``-m realtime``): one row a claim, its measured
    value, its limit, PASS or FAIL (the test's outcome), and the stalls that
    made a test repeat a run. Then the runs repeated on a measured stall."""
    outcomes = {}
    for outcome in ('passed', 'failed', 'error', 'skipped'):
        for report in terminalreporter.stats.get(outcome, []):
            if report.when == 'call' or outcome != 'passed':
                outcomes.setdefault(report.nodeid, outcome)
    if _claims:
        rows = [('claim', 'measured', 'limit', 'verdict', 'stalls measured')]
        for (nodeid, claim), (measured, limit) in _claims.items():
            verdict = {'passed': 'PASS', 'skipped': 'STALLED'}.get(outcomes.get(nodeid), 'FAIL')
            stalls = '; '.join(why for test, why in _repeats if test == nodeid) or 'none'
            rows.append((claim, measured, limit, verdict, stalls))
        widths = [max(len(row[i]) for row in rows) for i in range(4)]
        terminalreporter.section('real-time claims')
        for row in rows:
            terminalreporter.write_line('  '.join(cell.ljust(width) for cell, width
                                                  in zip(row, widths)) + '  ' + row[4])
    terminalreporter.write_line(
        f'runs repeated, or claims judged STALLED, on a measured external stall: '
        f'{len(_repeats)}'
        + ''.join(f'\n  {nodeid}: {why}' for nodeid, why in _repeats))


@pytest.fixture
def quasi_static_calls(monkeypatch):
    """The Python engine only, and a list that records the ``fv_scaling`` of each
    call of the kernels' ``quasi_force``: did a run take a CE quasi-static?"""
    from hill_muscle_ros.model.muscle import kernels as muscle_kernels, state as muscle_state
    calls = []
    original = muscle_kernels.quasi_force

    def spy(F, I, i, *args):
        relative = I[muscle_state.hdr(I, i, muscle_state.H_IP) + muscle_state.I_RELATIVE]
        calls.append('relative' if relative else 'absolute')
        return original(F, I, i, *args)

    # The kernels call it by the name each module bound at import.
    for module in list(sys.modules.values()):
        if (getattr(module, '__name__', '').startswith('hill_muscle_ros.model')
                and getattr(module, 'quasi_force', None) is original):
            monkeypatch.setattr(module, 'quasi_force', spy)
    monkeypatch.setenv('HILL_MUSCLE_ENGINE', 'python')   # the spy sees the Python engine
    return calls


@pytest.fixture(scope='session')
def protocol_paths():
    """Paths of the shipped protocols by their short name."""
    return {'I': PROTOCOLS / 'protocol_I.yaml', 'II': PROTOCOLS / 'protocol_II.yaml'}
