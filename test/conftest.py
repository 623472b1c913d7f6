"""Test-wide setup.

DDS isolation: every test run gets its own ROS_DOMAIN_ID and keeps discovery
on this host, so parallel runs (or a developer's live session) never cross-talk.
The domain is claimed with an exclusive lock file held for the whole run, so
two concurrent runs on one machine never draw the same one. Subprocesses
inherit these variables. Under pytest-xdist each worker claims a domain of
its own.

Workers (``make test`` runs ``pytest -n auto --dist loadgroup``, four workers
where :func:`auto_workers` allows; ``make test-serial`` runs serially): two pools,
:func:`pytest_xdist_make_scheduler`. Half the workers run the modules that
start ROS processes or DDS participants, at normal priority, two side by
side; a module with an ``alone`` test or one that takes the stall watcher (a
timing claim that needs the machine: the simulator's 20 ms tick gap under
tool churn, the 15 N stretch, failed all three runs beside another ROS module)
runs while no other ROS module does; for a claim on milliseconds, or one that
needs both CPUs, the offline workers are frozen meanwhile (:func:`_ros_turns`).
The other half run the offline modules (the model, the offline CLI and
bags, the figures, the clean install: :func:`is_offline_module`)
at the kernel's idle priority (``SCHED_IDLE``, and
the idle I/O class): they get a CPU only when no ordinary process wants it, a
ROS process that wakes takes the CPU back at once, so they use the CPU time
the ROS tests leave idle without delaying them. That holds across sessions
only if what they start cannot escape it: the offline workers join a CPU
cgroup marked idle, which their subprocesses cannot leave by starting a
session (:func:`_join_idle_cgroup`); where the cgroup tree is not writable,
they run in sessions of their own at the weakest autogroup nice
(:func:`_leave_the_ros_tests_autogroup`). Once the offline modules are all
handed out, the first offline worker to run out of work joins the ROS ones
(:data:`JOINING_WORKERS`, :func:`_rejoin_the_ros_tests`).
"""
import ast
import ctypes
import fcntl
import gc
import os
import random
import subprocess
import sys
import time
import warnings
from pathlib import Path

import pytest
from hypothesis import settings

from hill_muscle_ros.dds_transport import use_udp_transport
from hill_muscle_ros.domain_lock import lock_free_domain
from stall_watch import RepeatedOnStall, StallWatcher

#: Domain IDs 1..100 stay clear of 0 (the default most people use), of the
#: demo's 101..199, and within the range Fast DDS maps to valid UDP ports.
_DOMAIN_LOW, _DOMAIN_HIGH = 1, 100
_LOCK_PATTERN = 'hill_muscle_ros_test_domain_{}.lock'

REPO = Path(__file__).resolve().parents[1]
PROTOCOLS = REPO / 'config' / 'protocols'

#: The open lock file of the claimed domain; the lock lasts while it is open.
_domain_lock = None


def _claim_domain() -> int:
    """Lock and return a domain ID no other test run on this machine holds."""
    global _domain_lock
    candidates = list(range(_DOMAIN_LOW, _DOMAIN_HIGH + 1))
    random.Random(os.getpid()).shuffle(candidates)
    claimed = lock_free_domain(candidates, _LOCK_PATTERN)
    if claimed is not None:
        domain, _domain_lock = claimed
        return domain
    raise RuntimeError(f'every ROS_DOMAIN_ID in {_DOMAIN_LOW}..{_DOMAIN_HIGH} is held by '
                       f'another test run')


# No per-example deadline: how fast the code runs is make bench's business, and
# beside the ROS tests an example at idle CPU priority waited 374 ms for a CPU.
settings.register_profile('hill_muscle_ros', deadline=None)
settings.load_profile('hill_muscle_ros')

#: Set in the environment when this run (not its caller) claimed the domain, so
#: that xdist workers, which inherit the environment, claim their own.
_CLAIMED_ENV = 'HILL_MUSCLE_TEST_DOMAIN_CLAIMED'


#: The lock files through which the ROS workers take turns (:func:`_ros_turns`),
#: made by the controller, inherited by the workers.
_TURNS_ENV = 'HILL_MUSCLE_TEST_ROS_TURNS'


def pytest_configure(config):
    if 'PYTEST_XDIST_WORKER' not in os.environ and _runs_workers(config):
        import tempfile
        os.environ[_TURNS_ENV] = tempfile.mkdtemp(prefix='hill_muscle_ros_turns_')
    inherited_claim = os.environ.get(_CLAIMED_ENV) == '1'
    if 'HILL_MUSCLE_TEST_DOMAIN' not in os.environ or (
            inherited_claim and 'PYTEST_XDIST_WORKER' in os.environ):
        os.environ['HILL_MUSCLE_TEST_DOMAIN'] = str(_claim_domain())
        os.environ[_CLAIMED_ENV] = '1'
    os.environ['ROS_DOMAIN_ID'] = os.environ['HILL_MUSCLE_TEST_DOMAIN']
    os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    os.environ.pop('ROS_STATIC_PEERS', None)
    # The test process's own participants (the probes) set up DDS as the
    # package's nodes do, before any rclpy.init: otherwise a probe's writer
    # heartbeats every 3 s, and a burst sent before the node's reader had
    # matched the writer (the writer matched first) waited for the next one,
    # 2.1 s late in a fresh-clone run; and a node that started after a probe
    # and missed its answer waited up to 3 s for its next announcement. The
    # nodes inherit these variables and set up their own (dds_transport).
    use_udp_transport()


@pytest.fixture(scope='session')
def stall_watcher():
    """One :class:`~stall_watch.StallWatcher` for the whole run: the only
    evidence on which a test may repeat a timing measurement."""
    with StallWatcher() as watcher:
        yield watcher


@pytest.fixture
def quasi_static_calls(monkeypatch):
    """The Python engine only, and a list that records each call of
    ``FesMuscle.quasi_static_force`` (the muscle's ``fv_scaling``): did a run
    take a CE quasi-static?"""
    from hill_muscle_ros.model.fes_muscle import FesMuscle
    calls = []
    original = FesMuscle.quasi_static_force

    def spy(self, *args):
        calls.append(self.params.fv_scaling)
        return original(self, *args)

    monkeypatch.setattr(FesMuscle, 'quasi_static_force', spy)
    monkeypatch.setenv('HILL_MUSCLE_ENGINE', 'python')   # the spy sees the Python engine
    return calls


@pytest.fixture(scope='session')
def protocol_paths():
    """Paths of the shipped protocols by their short name."""
    return {'I': PROTOCOLS / 'protocol_I.yaml', 'II': PROTOCOLS / 'protocol_II.yaml'}


def _runs_workers(config) -> bool:
    """Whether this pytest process hands the tests to xdist workers."""
    return bool(getattr(config.option, 'numprocesses', None)) and \
        getattr(config.option, 'dist', 'no') != 'no'


def _compile_code(sets) -> str:
    """Python code that builds the kernel ``sets`` (names of
    :data:`~hill_muscle_ros.model.precompile.KERNEL_SETS`) in one process, as
    ``hill-muscle compile`` does, then prints its compiling seconds."""
    return ('from hill_muscle_ros.model import engine, precompile\n'
            f'precompile.compile_kernel_group({tuple(sets)!r})\n'
            'print(engine.compile_seconds())')


#: Compiles the paper's muscle's kernel sets (which share no code with the FES
#: ones), then prints its compiling seconds (:func:`pytest_sessionstart`).
_COMPILE_THE_PAPERS = _compile_code(('muscle_batch', 'muscle_run'))
#: [s] what that process compiled (empty if it did not run).
_sidecar_compile_s: list[float] = []


#: Compiles the nodes' kernel sets (the FES muscle's and the limb's), then
#: prints its compiling seconds (:func:`pytest_sessionstart`, serial runs).
_COMPILE_THE_NODES = _compile_code(('fes_muscle', 'limb'))
#: ROS test modules whose nodes load no compiled kernel: they start only the
#: recorder, the controllers and the protocol player (of the nodes, only the
#: simulator and the limb load one, in ``nodes._common.load_engine``), and
#: none claims a time that needs the machine (none is in :data:`ALONE_MODULES`).
#: :func:`_check_kernel_free` holds each to the first part.
#: Not the recorder's own module, though it starts only recorders: beside the
#: compiling (two processes under xdist) its 1 kHz publisher and recorder lost
#: messages, and its stop test found a hole of 35 (a fresh clone's workers run).
KERNEL_FREE_ROS_MODULES = ('test_controller_node', 'test_node_joint_controller',
                           'test_faults_bad_protocol', 'test_node_teardown_guard',
                           'test_recorder_sim_time')
#: Test modules that a run takes first, while other processes compile the
#: kernels (:func:`pytest_sessionstart`): they load no compiled kernel. The
#: offline ones claim no timing either (the clean install, 20-25 s of pip and
#: imports, takes most of the compiling's 30 s); then the
#: :data:`KERNEL_FREE_ROS_MODULES`, 35-45 s of ROS tests that waited for the
#: compiling before (under xdist both ROS workers waited about 40 s).
FIRST_WHILE_COMPILING = ('test_install_clean', 'test_colcon_build',
                         'test_repository_standalone', 'test_model_curves',
                         'test_model_memory', 'test_control_pi') + KERNEL_FREE_ROS_MODULES
#: What a module of :data:`KERNEL_FREE_ROS_MODULES` must not name: the
#: executables of the nodes that load compiled kernels (setup.py) and their
#: module names, or a ``demo`` word (``make demo``), as string constants; and,
#: in its imports, those nodes, the demos (which start them) and the kernel
#: modules. A static check: a helper that starts such a node unnamed escapes
#: it, and then that node compiles the kernels itself, 30 s and more, and
#: fails its start-up wait with its log.
KERNEL_NODE_NAMES = frozenset({'simulator', 'limb_simulator', 'limb'})
KERNEL_IMPORT_PARTS = ('nodes.simulator', 'nodes.limb', 'demo', 'kernels', 'engine',
                       'compiled_muscle')
#: The compiling processes and when they started, until their seconds are
#: collected (:func:`_await_the_kernels`, :func:`_stop_compiling`).
_compiling: list = []


def _compiles_for_the_nodes(config) -> bool:
    """Whether this run loads the nodes' compiled kernels before their tests:
    the limb and simulator nodes would run them (numba importable,
    ``HILL_MUSCLE_ENGINE`` not ``python``), and this is not an xdist worker."""
    if 'PYTEST_XDIST_WORKER' in os.environ:
        return False
    from hill_muscle_ros.model import engine
    try:
        return engine.choice() == engine.COMPILED
    except (ValueError, ImportError):
        return False   # the node falls back to Python then; test_node_limb says whether it should


#: Under xdist, the workers' kernel sets: the nodes' and the batch of FES
#: muscles (on the FES muscle: in the same process, so compiled once).
_COMPILE_FOR_THE_WORKERS = _compile_code(('fes_muscle', 'limb', 'fes_batch'))
#: Under xdist: the lock file that the compiling processes hold (``flock``)
#: until they end; a worker waits for it (:func:`_await_the_kernels`). Set by
#: the controller before it starts its workers, which inherit it.
_COMPILING_LOCK_ENV = 'HILL_MUSCLE_TEST_COMPILING_LOCK'
#: [s] bound on a worker's wait for the compiling processes (a cold compile
#: of every set takes about 40 s); past it, the tests compile what is missing.
_COMPILING_DEADLINE_S = 600.0
#: [s] how often a waiting worker tries the lock again.
_COMPILING_POLL_S = 0.05


def pytest_sessionstart(session):
    """Load the compiled limb and the compiled FES muscle before any test that
    may start a node: a node started by a test then loads them from numba's
    disk cache (about 1 s) instead of compiling them (about 30 s, the tests'
    whole start-up deadline). The offline tests compile these kernels anyway,
    so the run compiles nothing more.

    A second process compiles them into the cache while the
    :data:`FIRST_WHILE_COMPILING` modules run (:func:`pytest_collection_modifyitems`
    puts them first serially; under xdist each pool hands them out first):
    before, the run used one core, and waited 30 s for the compiler before
    its first test. :func:`_await_the_kernels` waits for it before any other
    module. Under xdist it compiles the workers' kernel sets too, and the
    paper's muscle's compile in a third process at the same time; the
    workers start (and collect) meanwhile. After ``make kernels`` (which
    ``make test`` runs first: ``hill-muscle compile``) these processes only
    load the sets from numba's cache, in about a second."""
    if not _compiles_for_the_nodes(session.config):
        return
    if not _runs_workers(session.config):
        _compiling.append((subprocess.Popen([sys.executable, '-c', _COMPILE_THE_NODES],
                                            stdout=subprocess.PIPE, text=True),
                           time.monotonic()))
        return
    lock_path = os.path.join(os.environ[_TURNS_ENV], 'compiling')
    lock = os.open(lock_path, os.O_RDWR | os.O_CREAT)
    try:
        # Taken here, held by the children (they share the open file): the
        # lock is free once both have ended, however they end.
        fcntl.flock(lock, fcntl.LOCK_EX)
        for code in (_COMPILE_FOR_THE_WORKERS, _COMPILE_THE_PAPERS):
            _compiling.append((subprocess.Popen([sys.executable, '-c', code],
                                                stdout=subprocess.PIPE, text=True,
                                                pass_fds=(lock,)),
                               time.monotonic()))
    finally:
        os.close(lock)
    os.environ[_COMPILING_LOCK_ENV] = lock_path


def _compiled_seconds(process: subprocess.Popen) -> float:
    """[s] what a compiling process (:data:`_COMPILE_THE_PAPERS`,
    :data:`_COMPILE_THE_NODES`) says it compiled, once it ends; 0 if it failed
    (its stderr says why, and the tests compile what it did not)."""
    out, _ = process.communicate()
    return float(out.split()[-1]) if process.returncode == 0 and out.split() else 0.0


def pytest_collection_modifyitems(session, config, items):
    """A serial run takes the :data:`FIRST_WHILE_COMPILING` modules first
    (:func:`pytest_sessionstart`), the offline ones before the
    :data:`KERNEL_FREE_ROS_MODULES`, so that less of the ROS tests' time falls
    beside the compiling; the rest keep their order."""
    if _compiles_for_the_nodes(config) and not _runs_workers(config):
        items.sort(key=lambda item: (_module_name(item) not in FIRST_WHILE_COMPILING,
                                     _module_name(item) in KERNEL_FREE_ROS_MODULES))


def _module_name(item) -> str:
    return item.module.__name__.rsplit('.', 1)[-1]


def _await_the_kernels(item) -> None:
    """Before the first test outside :data:`FIRST_WHILE_COMPILING`: wait for
    the compiling process(es) (:func:`pytest_sessionstart`). Serially, then
    load the nodes' kernels here from the cache; an xdist worker waits for
    the controller's processes through their lock file and loads nothing:
    its tests load what they use."""
    if _module_name(item) in FIRST_WHILE_COMPILING:
        return
    if 'PYTEST_XDIST_WORKER' in os.environ:
        _await_the_compiling_lock()
        return
    if not _compiling:
        return
    process, started = _compiling.pop()
    _sidecar_compile_s.append(_compiled_seconds(process))
    from hill_muscle_ros.model import engine, fes_kernels, limb_kernels
    waited = time.monotonic()
    fes_kernels.compiled()   # the simulator node's FES muscle (compiled_muscle)
    limb_kernels.compiled()
    _say(item, f'\nthe nodes\' compiled kernels: {_sidecar_compile_s[-1]:.1f} s compiling in '
               f'a second process, beside the first modules; {time.monotonic() - started:.1f} s '
               f'from the start to loaded here, {time.monotonic() - waited:.1f} s loading '
               f'({engine.compile_seconds():.1f} s of it compiling)')


#: Whether this xdist worker has waited for the compiling processes.
_compiling_awaited: list[bool] = []


def _await_the_compiling_lock() -> None:
    """An xdist worker's wait for :data:`_COMPILING_LOCK_ENV` (once). It
    writes nothing to the terminal: a worker's terminal output is not shown."""
    path = os.environ.get(_COMPILING_LOCK_ENV)
    if path is None or _compiling_awaited:
        return
    _compiling_awaited.append(True)
    started = time.monotonic()
    lock = os.open(path, os.O_RDONLY)
    try:
        while True:
            try:
                fcntl.flock(lock, fcntl.LOCK_SH | fcntl.LOCK_NB)
                break
            except BlockingIOError:
                if time.monotonic() - started > _COMPILING_DEADLINE_S:
                    # A warning: a worker's terminal output is not shown, the
                    # warnings summary is.
                    warnings.warn(f'the compiling processes still run after '
                                  f'{_COMPILING_DEADLINE_S:g} s: the tests compile what '
                                  f'they need', stacklevel=1)
                    return
                time.sleep(_COMPILING_POLL_S)
    finally:
        os.close(lock)    # closing releases the lock


def _say(item, line: str) -> None:
    """Write ``line`` to the terminal, outside the test's captured output."""
    reporter = item.config.pluginmanager.get_plugin('terminalreporter')
    capture = item.config.pluginmanager.get_plugin('capturemanager')
    if reporter is not None and capture is not None:
        with capture.global_and_fixture_disabled():   # a test's setup is captured
            reporter.write_line(line)


def _stop_compiling() -> None:
    """Collect what each compiling process compiled (:data:`_sidecar_compile_s`),
    once no test needs them: a run that ended before it needed the kernels
    (``-k`` on the first modules) kills them instead; numba writes each cache
    file whole (a temporary file renamed), so nothing half-written stays."""
    while _compiling:
        process, _ = _compiling.pop()
        if process.poll() is None:
            process.kill()
        _sidecar_compile_s.append(_compiled_seconds(process))


#: Key of a worker's compiling seconds in xdist's ``workeroutput``.
_WORKER_COMPILE_KEY = 'hill_muscle_ros_numba_compile_s'
#: [s] compiling seconds reported by the xdist workers that have finished.
_workers_compile_s: list[float] = []


def _compile_seconds() -> float:
    """[s] this process's time in numba's compiler (0 if it never loaded it)."""
    engine = sys.modules.get('hill_muscle_ros.model.engine')
    return engine.compile_seconds() if engine is not None else 0.0


def pytest_unconfigure(config):
    """The controller removes the ROS workers' lock files (:func:`_ros_turns`)
    and the offline workers' CPU cgroup (:func:`_join_idle_cgroup`); a serial
    run stops a compiling process it did not wait for (:func:`_stop_compiling`)."""
    _stop_compiling()
    folder = os.environ.get(_TURNS_ENV)
    if folder is not None and 'PYTEST_XDIST_WORKER' not in os.environ:
        import shutil
        shutil.rmtree(folder, ignore_errors=True)
        _remove_idle_cgroup()


def pytest_sessionfinish(session):
    """An xdist worker hands its compiling time to the controller."""
    workeroutput = getattr(session.config, 'workeroutput', None)
    if workeroutput is not None:
        workeroutput[_WORKER_COMPILE_KEY] = _compile_seconds()


def pytest_testnodedown(node, error):
    """The controller collects each finished worker's compiling time."""
    seconds = getattr(node, 'workeroutput', {}).get(_WORKER_COMPILE_KEY)
    if seconds is not None:
        _workers_compile_s.append(seconds)


class GcPauses:
    """The garbage collector's pauses in this process, with the test that ran
    meanwhile: the probe of a DDS test lives here, and while a collection
    runs it neither publishes nor receives, a stall the nodes under test see
    as silence. (A serial run before :func:`_collect_between_modules`: 20,738
    collections, 36.7 s in all, 85 of at least 100 ms, the longest 581 ms,
    longer than the joint controller's 0.5 s feedback timeout.) The
    collections :func:`_collect_between_modules` asks for are counted apart.
    """

    #: [s] pauses at least this long are listed by test
    LONG_S = 0.1

    def __init__(self) -> None:
        self.count, self.total_s = 0, 0.0
        self.asked_count, self.asked_s = 0, 0.0
        self.long: list[tuple[float, int, str]] = []   # (seconds, generation, test)
        self.asking = False
        self._started = None
        gc.callbacks.append(self._on_gc)

    def _on_gc(self, phase: str, info: dict) -> None:
        if phase == 'start':
            self._started = time.perf_counter()
            return
        if self._started is None:
            return
        pause_s = time.perf_counter() - self._started
        self._started = None
        if self.asking:
            self.asked_count += 1
            self.asked_s += pause_s
            return
        self.count += 1
        self.total_s += pause_s
        if pause_s >= self.LONG_S:
            test = os.environ.get('PYTEST_CURRENT_TEST', '(between tests)')
            self.long.append((pause_s, info.get('generation', -1), test))

    def summary(self) -> str:
        worst = sorted(self.long, reverse=True)[:5]
        return (f'garbage collector in this process: {self.count} collections in tests, '
                f'{self.total_s:.1f} s in all, {len(self.long)} of at least '
                f'{self.LONG_S * 1e3:.0f} ms; {self.asked_count} between modules, '
                f'{self.asked_s:.1f} s' + ''.join(
                    f'\n  {s * 1e3:.0f} ms (generation {g}) in {t}' for s, g, t in worst))


_gc_pauses = GcPauses()
#: The module whose tests run now (:func:`_collect_between_modules`).
_gc_module = None


def _collect_between_modules(module) -> None:
    """At the first test of each module: collect, then freeze what survives
    (``gc.freeze``: later collections skip it), and keep the collector off
    for a module that joins the ROS graph.

    Between modules no probe is alive, so a pause costs nothing but time;
    inside a DDS test a full collection of the whole suite's heap (numba's
    compiled kernels, hypothesis, every module imported) stopped the probe
    for up to 0.58 s, and a probe that plays a limb every 5 ms went silent
    past the controller's feedback timeout. Frozen, that heap is no longer
    walked; within a ROS module the young garbage reference counting leaves
    (cycles only) waits for the next module.
    """
    global _gc_module
    if module is _gc_module:
        return
    _gc_module = module
    gc.enable()
    _gc_pauses.asking = True
    try:
        gc.collect()
    finally:
        _gc_pauses.asking = False
    gc.freeze()
    if _ros_names_in(module):
        gc.disable()


#: The tests that repeated a run on a measured external stall (one entry a repeat).
_repeats: list[str] = []


def pytest_warning_recorded(warning_message, when, nodeid, location):
    """Count the :class:`~stall_watch.RepeatedOnStall` warnings (under xdist
    the controller hears the workers' too)."""
    if issubclass(warning_message.category, RepeatedOnStall):
        _repeats.append(nodeid)


def pytest_terminal_summary(terminalreporter):
    """Say how long the pytest processes spent in numba's compiler: a clean
    clone compiles every kernel once (the budget is 60 s), a second run loads
    them. Under xdist: this process and each worker, and their sum. And the
    garbage collector's long pauses here (:class:`GcPauses`), and the runs repeated
    on a measured stall (:func:`pytest_warning_recorded`)."""
    for why in _auto_decision:
        terminalreporter.write_line(f'-n auto: {why}')
    terminalreporter.write_line(_gc_pauses.summary())
    terminalreporter.write_line(
        f'runs repeated on a measured external stall: {len(_repeats)}'
        + ''.join(f'\n  {nodeid}' for nodeid in _repeats)
        + ('\n  (their causes: the warnings summary above)' if _repeats else ''))
    _stop_compiling()   # every test has run: none needs them any more
    own = _compile_seconds()
    sidecar = ', '.join(f'{s:.1f}' for s in _sidecar_compile_s) or '0.0'
    total = own + sum(_sidecar_compile_s) + sum(_workers_compile_s)
    workers = ', '.join(f'{s:.1f}' for s in _workers_compile_s)
    terminalreporter.write_line(
        f'numba compiling in the pytest processes: {total:.1f} s (this one {own:.1f} s, '
        f'its compiling processes {sidecar} s'
        + (f', workers {workers} s' if workers else '')
        + '; the tests\' subprocesses not counted)')


# --------------------------------------------------------------------------- two workers

#: The work unit of the tests that run ROS processes or DDS participants.
SERIAL_GROUP = 'ros_serial'
#: The work unit of the offline tests (idle priority).
OFFLINE_GROUP = 'offline_idle'
#: Test modules that start no ROS process and no DDS participant: by prefix,
#: and by name.
OFFLINE_PREFIXES = ('test_model_', 'test_fes_', 'test_limb_')
OFFLINE_MODULES = frozenset({
    'test_cli', 'test_control_pi', 'test_controller_inputs', 'test_figures',
    'test_install_clean', 'test_recorder_units', 'test_recording_bag',
    'test_recording_offline', 'test_repository_standalone', 'test_joint_controller',
    'test_gym', 'test_fit', 'test_fit_limb', 'test_recording_joint_state',
    'test_batch_compiled', 'test_sweep', 'test_muscle_compiled', 'test_batch_fes_compiled',
    'test_simulate_fes_compiled', 'test_compiled_muscle', 'test_cli_bounded_number',
    'test_recording_receipt_clock', 'test_auto_workers', 'test_precompile'})
#: Names whose presence in a module's namespace means it may start nodes or
#: join the graph: such a module cannot be an offline one.
ROS_NAMES = frozenset({'rclpy', 'ros_helpers', 'Probe', 'ProcessGroup', 'node_command',
                       'supervisor', 'GraphProbe', 'StallWatcher'})


def _kernel_references_in(path: str | Path) -> list[str]:
    """What the test module at ``path`` names of :data:`KERNEL_NODE_NAMES`
    (string constants) and :data:`KERNEL_IMPORT_PARTS` (imports), sorted
    (empty: its nodes load no compiled kernel)."""
    found = set()
    for node in ast.walk(ast.parse(Path(path).read_text(encoding='utf-8'))):
        if isinstance(node, ast.Constant) and isinstance(node.value, str) and (
                node.value in KERNEL_NODE_NAMES or 'demo' in node.value.split()):
            found.add(repr(node.value))
        elif isinstance(node, (ast.Import, ast.ImportFrom)):
            names = [a.name for a in node.names]
            if isinstance(node, ast.ImportFrom):
                names = [f'{node.module or ""}.{n}' for n in names]
            found.update(f'import of {n}' for n in names
                         if any(part in n for part in KERNEL_IMPORT_PARTS))
    return sorted(found)


#: The :data:`KERNEL_FREE_ROS_MODULES` checked so far in this process.
_checked_kernel_free: set[str] = set()


def _check_kernel_free(module) -> None:
    """Fail a module listed in :data:`KERNEL_FREE_ROS_MODULES` that names a
    node or a module that loads compiled kernels: run while they compile, its
    node would compile them itself (about 30 s, past its start-up deadline)."""
    name = module.__name__.rsplit('.', 1)[-1]
    if name not in KERNEL_FREE_ROS_MODULES or name in _checked_kernel_free:
        return
    _checked_kernel_free.add(name)
    found = _kernel_references_in(module.__file__)
    if found:
        pytest.fail(f'{name} is listed in KERNEL_FREE_ROS_MODULES in conftest.py (it runs '
                    f'while the kernels compile) but names {", ".join(found)}: take it off '
                    f'that list', pytrace=False)


def _ros_names_in(module) -> list[str]:
    """The :data:`ROS_NAMES` in ``module``'s namespace, sorted (empty: it
    starts no node and joins no graph)."""
    return sorted(ROS_NAMES & set(vars(module)))


#: ioprio_set(2): who = a process, the idle and the default class, the class
#: field's shift, the syscall number on x86-64.
_IOPRIO_WHO_PROCESS, _IOPRIO_CLASS_IDLE, _IOPRIO_CLASS_NONE = 1, 3, 0
_IOPRIO_CLASS_SHIFT = 13
_SYS_IOPRIO_SET = 251
#: The weakest nice value: an autogroup at 19 weighs 15 against a default 1024.
_WEAKEST_NICE = 19
#: Where a CPU cgroup hierarchy may be mounted: cgroup v1's cpu controller,
#: then a cgroup v2 tree. A mount point counts only if it has ``cgroup.procs``.
_CPU_CGROUP_ROOTS = (Path('/sys/fs/cgroup/cpu'), Path('/sys/fs/cgroup'))
#: The CPU cgroup of the offline workers and all they start (``cpu.idle``).
_IDLE_CGROUP = 'hill_muscle_ros_offline_tests'
#: cgroup v1's freezer hierarchy, where the offline workers also join a group
#: of that name, so that an ``alone`` module can freeze them (:func:`_freeze_offline`).
_FREEZER_ROOT = Path('/sys/fs/cgroup/freezer')
#: [s] bound on the wait for the offline workers' group to be frozen.
_FREEZE_DEADLINE_S = 10.0


#: [s] the modules that took longest in a fresh clone's run under ``-n 4
#: --dist loadgroup`` (rounded; an idle-priority offline module waits for the
#: CPUs too, so its time depends on what runs beside it): each pool hands them
#: out first, the rest follow in collection order. The sweep (dask worker
#: processes) took 17 s serially but 77 s when it came last, beside three ROS
#: workers, and ended that run 5 s after everything else.
LONG_MODULES = {
    'test_sweep': 77, 'test_install_clean': 59, 'test_fit_limb': 33,
    'test_muscle_compiled': 29, 'test_fit': 26, 'test_model_fes_accuracy': 26,
    'test_limb_step_compiled': 24, 'test_limb_compiled': 22, 'test_control_pi': 17,
    'test_model_limb': 15, 'test_batch_compiled': 13, 'test_model_limb_batch': 13,
    'test_batch_fes_compiled': 12, 'test_model_curves': 12, 'test_recording_offline': 10,
    'test_node_diagnostics': 45, 'test_controller_closed_loop': 45, 'test_faults_garbage': 36,
    'test_joint_closed_loop': 35, 'test_demo_knee': 33, 'test_recorder_node': 32,
    'test_faults_flood': 32, 'test_node_player': 30, 'test_faults_recorder_stop': 28,
    'test_fit_live': 24, 'test_demo': 22, 'test_recorder_simulation': 21,
    'test_sim_tool_churn': 18, 'test_faults_controller_kill': 17, 'test_faults_limb': 17,
    'test_controller_node': 17, 'test_controller_demo': 15, 'test_node_simulator': 14,
    'test_node_length_stamped': 13, 'test_node_joint_controller': 13, 'test_node_limb': 10}


#: The ROS modules with a timing claim that needs the machine: an ``alone``
#: test, or a test that takes :func:`stall_watcher`. Under xdist each runs while
#: no other ROS module does (:func:`_ros_turns`), and they are handed out
#: first, one after the other, so that the other ROS worker waits for them
#: once rather than at every turn. :func:`_ros_turns` fails a module that
#: should be listed here and is not.
ALONE_MODULES = frozenset({
    'test_sim_tool_churn', 'test_faults_garbage', 'test_fit_live',
    'test_controller_closed_loop', 'test_joint_closed_loop', 'test_faults_limb',
    'test_faults_controller_kill', 'test_recorder_simulation', 'test_faults_flood',
    'test_demo_sim_time'})
#: The :data:`ALONE_MODULES` during which the offline workers are frozen too
#: (:func:`_freeze_offline`): a claim on milliseconds that idle priority does
#: not protect (the churn test's 20 ms tick gap: its tick thread waited 9-21 ms
#: for a CPU beside two idle-priority busy loops), or a test that needs both
#: CPUs (the flood: its flooder and the simulator). In a fresh clone's run
#: with no freezing, these were the only alone modules that failed; the others
#: claim times of 0.1 s and more, and run beside the idle offline workers.
FROZEN_MODULES = frozenset({'test_sim_tool_churn', 'test_faults_flood'})


def is_offline_module(name: str) -> bool:
    """Whether the test module ``name`` (``test_model_curves``) is an offline one."""
    return name.startswith(OFFLINE_PREFIXES) or name in OFFLINE_MODULES


#: How many offline workers may join the ROS pool once the offline modules
#: are all handed out: the offline pool ends in about half the run, and then
#: the two ROS workers alone ran the ROS modules left for about 140 s, the
#: second half of the run (a fresh clone's four-worker ``make test``). One more,
#: not two: each ROS module keeps most of a core busy (a serial run: 361
#: CPU-s in its 383 s of ROS modules), so three share the two CPUs already.
JOINING_WORKERS = 1


def joining_workers(n_workers: int) -> int:
    """How many offline workers of ``n_workers`` may join the ROS pool:
    :data:`JOINING_WORKERS`, but none where one worker runs the ROS tests
    (``-n 2``): there they run one module at a time, as in a serial run, and a
    joining worker would run a second beside it."""
    return JOINING_WORKERS if ros_workers(n_workers) > 1 else 0


#: ``pytest -n auto --dist loadgroup`` (the test command, ``make test``): this
#: many workers where the offline ones can be kept out of the ROS tests' way
#: (:func:`auto_workers`): two run the ROS modules, two at a time (one at a
#: time for the :data:`ALONE_MODULES`), two the offline modules at idle CPU
#: priority, frozen during :data:`FROZEN_MODULES`. A module of ROS tests run
#: alone keeps less than one core busy (the player's: 11.5 CPU-s in its
#: 19.8 s, the closed knee's 21.9 in 29.7), so two fit on two CPUs; with one
#: ROS worker (``-n 2``) the ROS modules alone took 357-373 s one after the
#: other.
AUTO_WORKERS = 4
#: Environment variable that sets the ``-n auto`` worker count (0: serial).
WORKERS_ENV = 'HILL_MUSCLE_TEST_WORKERS'


def _offline_workers_can_be_isolated() -> str | None:
    """``None`` if this machine lets the offline workers run in an idle CPU
    cgroup that can be frozen (:func:`_join_idle_cgroup`, :func:`_freeze_offline`),
    else why not. Tried by making both groups, then removing them."""
    made = []
    try:
        cpu_roots = _cpu_cgroup_roots()
        if not cpu_roots:
            return 'no CPU cgroup tree'
        cpu_group = cpu_roots[0] / _IDLE_CGROUP
        cpu_group.mkdir(exist_ok=True)
        made.append(cpu_group)
        if not (cpu_group / 'cpu.idle').is_file():
            return f'no cpu.idle in {cpu_roots[0]} (Linux 5.15 on)'
        if (_FREEZER_ROOT / 'cgroup.procs').is_file():
            freezer_group = _FREEZER_ROOT / _IDLE_CGROUP
            freezer_group.mkdir(exist_ok=True)
            made.append(freezer_group)
        elif not (cpu_group / 'cgroup.freeze').is_file():
            return 'no cgroup freezer'
        return None
    except OSError as err:
        return f'cgroup tree not writable ({err})'
    finally:
        for group in reversed(made):
            try:
                group.rmdir()
            except OSError:
                pass   # another run's offline workers are in it


def auto_workers() -> tuple[int, str]:
    """How many xdist workers ``-n auto`` starts, and why (0: serial).

    :data:`AUTO_WORKERS` on a machine of two CPUs or more whose cgroup tree
    lets the offline workers be isolated; else serial, since the churn
    test's 20 ms claim failed beside busy neighbours that were not frozen.
    :data:`WORKERS_ENV` overrides it.
    """
    override = os.environ.get(WORKERS_ENV)
    if override is not None:
        try:
            n = int(override)
        except ValueError:
            raise pytest.UsageError(f'`{WORKERS_ENV}` must be a whole number of workers '
                                    f'(0: serial), got {override!r}') from None
        if n < 0:
            raise pytest.UsageError(f'`{WORKERS_ENV}` must be 0 or more, got {n}')
        return n, f'{WORKERS_ENV}={n}'
    cpus = len(os.sched_getaffinity(0))
    if cpus < 2:
        return 0, f'serial: {cpus} CPU'
    why_not = _offline_workers_can_be_isolated()
    if why_not is not None:
        return 0, f'serial: the offline tests cannot be kept out of the ROS tests\' way: {why_not}'
    return AUTO_WORKERS, (f'{AUTO_WORKERS} workers: {ros_workers(AUTO_WORKERS)} run the ROS '
                          f'tests, the others the offline tests at idle priority')


#: What :func:`pytest_xdist_auto_num_workers` decided, for the terminal summary.
_auto_decision: list[str] = []


def pytest_xdist_auto_num_workers(config):
    """``-n auto``: :func:`auto_workers`."""
    n, why = auto_workers()
    _auto_decision.append(why)
    return n


def ros_workers(n_workers: int) -> int:
    """How many of ``n_workers`` xdist workers run the ROS tests: half (at
    least one); the rest run the offline ones."""
    return max(1, n_workers // 2)


def pytest_xdist_make_scheduler(config, log):
    """``--dist loadgroup``: two pools of workers, one for the tests that start
    ROS processes or DDS participants (:data:`SERIAL_GROUP`), one for the
    offline tests (:data:`OFFLINE_GROUP`): a worker runs modules of its own
    pool, a whole module at a time, the :data:`FIRST_WHILE_COMPILING`, then
    the :data:`ALONE_MODULES`, then the :data:`LONG_MODULES` first, then in
    collection order (:func:`ros_workers` says how many are ROS workers).
    Once the offline modules are all handed out, :data:`JOINING_WORKERS` of
    the offline workers join the ROS pool.

    pytest-xdist's own loadgroup (the ``xdist_group`` mark) renames the test
    ids, which pytest 9.2 no longer lets it do, and pins a group to one
    worker; the pools are made here by module name (the controller has the
    test ids only).
    """
    if config.getvalue('dist') != 'loadgroup':
        return None
    from xdist.scheduler import LoadScopeScheduling

    def pool_of_scope(scope: str) -> str:
        return OFFLINE_GROUP if is_offline_module(Path(scope).stem) else SERIAL_GROUP

    class PoolScheduling(LoadScopeScheduling):
        def __init__(self, *args, **kwargs) -> None:
            super().__init__(*args, **kwargs)
            self._joined = []   # the offline workers that joined the ROS pool (_next_scope)

        def _split_scope(self, nodeid: str) -> str:
            return nodeid.split('::', 1)[0]

        def _pool_of_node(self, node) -> str:
            # Workers are gw0, gw1, ...: the first ros_workers() run the ROS tests.
            index = int(node.gateway.id.removeprefix('gw'))
            if index < ros_workers(self.numnodes) or node in self._joined:
                return SERIAL_GROUP
            return OFFLINE_GROUP

        def _next_scope(self, node) -> str | None:
            pool = self._pool_of_node(node)
            scopes = [s for s in self.workqueue if pool_of_scope(s) == pool]
            if (not scopes and pool == OFFLINE_GROUP
                    and len(self._joined) < joining_workers(self.numnodes)):
                # Its pool ran dry while the ROS pool has work left: it joins
                # that (as an ordinary ROS worker: pytest_runtest_setup).
                scopes = [s for s in self.workqueue if pool_of_scope(s) == SERIAL_GROUP]
                if scopes:
                    self._joined.append(node)
            # The modules that need no compiled kernel first, while they
            # compile (_await_the_kernels); then those that run alone; then the
            # longest, so that a pool's workers end together. With one ROS
            # worker (-n 2) those that run alone come last instead: the
            # offline worker ends well before it (a fresh clone's run: ROS
            # modules 357 s, offline 249 s at idle priority), so they mostly run
            # on a machine as quiet as a serial run's, not beside the compiling
            # processes and a frozen neighbour (the churn test repeated a run
            # on a 17.8 ms stall there once; in the one run with this order it
            # still repeated one, on a 14.0 ms stall).
            alone_last = ros_workers(self.numnodes) == 1
            return min(scopes, key=lambda s: (
                Path(s).stem not in FIRST_WHILE_COMPILING,
                (Path(s).stem in ALONE_MODULES) == alone_last,
                -LONG_MODULES.get(Path(s).stem, 0)), default=None)

        def _assign_work_unit(self, node) -> None:
            scope = self._next_scope(node)
            if scope is None:
                return
            work_unit = self.workqueue.pop(scope)
            self.assigned_work.setdefault(node, {})[scope] = work_unit
            collection = self.registered_collections[node]
            node.send_runtest_some([collection.index(nodeid)
                                    for nodeid, done in work_unit.items() if not done])

        def _reschedule(self, node) -> None:
            if node.shutting_down:
                return
            # Nothing is decided for a worker with work ahead of it: an offline
            # worker that joined the ROS pool while it still had a long module
            # to run (the sweep, 87 s at idle priority beside the ROS tests)
            # kept the other, idle one from joining, which then stopped.
            if self._pending_of(self.assigned_work[node]) > 2:
                return
            if self._next_scope(node) is None:
                node.shutdown()   # after the tests it has; its pool has no more
                return
            self._assign_work_unit(node)

        def schedule(self) -> None:
            # The base class shuts down the workers that exceed the number of
            # modules, whichever pool they serve (a run of two offline
            # modules lost both offline workers that way); here each worker
            # stops only when its own pool has nothing left (_reschedule).
            if self.collection is None:
                if not self._check_nodes_have_same_collection():
                    self.log('**Different tests collected, aborting run**')
                    return
                self.collection = list(next(iter(self.registered_collections.values())))
                for nodeid in self.collection:
                    self.workqueue.setdefault(self._split_scope(nodeid), {})[nodeid] = False
            for node in self.nodes:
                self._reschedule(node)

    return PoolScheduling(config, log)


def _set_io_class(tid: int, io_class: int) -> None:
    """ioprio_set(2) for thread ``tid`` (Linux x86-64; elsewhere nothing)."""
    if sys.platform != 'linux' or os.uname().machine != 'x86_64':
        return
    libc = ctypes.CDLL(None, use_errno=True)
    libc.syscall(_SYS_IOPRIO_SET, _IOPRIO_WHO_PROCESS, tid, io_class << _IOPRIO_CLASS_SHIFT)


def _cpu_cgroup_roots():
    """The mount points of :data:`_CPU_CGROUP_ROOTS` that are cgroup trees
    (a plain directory there, tmpfs for one, is not)."""
    return [root for root in _CPU_CGROUP_ROOTS if (root / 'cgroup.procs').is_file()]


def _join_idle_cgroup() -> bool:
    """Move this process into a CPU cgroup whose ``cpu.idle`` is 1 (Linux 5.15
    on), made if absent; return whether it did (it takes write access to the
    cgroup tree: root, or a delegated tree).

    The whole cgroup then weighs as an idle task against the rest of the
    machine, and what this process starts stays in it, sessions of its own
    included. Without it, an offline test's subprocess that starts its own
    session (a sweep's Dask scheduler and workers, the supervisor's
    processes) had an autogroup of its own at the default weight, and took
    the CPUs from the ROS tests as an equal (a fresh clone's run: the garbage
    test's simulator overloaded and dropped bad values, the churn test saw a
    machine stall in all three runs).
    """
    for root in _cpu_cgroup_roots():
        group = root / _IDLE_CGROUP
        previous = _group_of_this_process(root)
        try:
            group.mkdir(exist_ok=True)
            (group / 'cpu.idle').write_text('1')
            (group / 'cgroup.procs').write_text(str(os.getpid()))
        except OSError:
            continue
        _left_groups.append(previous)
        _join_freezer_group()
        return True
    return False


#: The groups this process left for :data:`_IDLE_CGROUP` (:func:`_rejoin_the_ros_tests`).
_left_groups: list[Path] = []


def _group_of_this_process(root: Path) -> Path:
    """This process's group in the hierarchy mounted at ``root``
    (``/proc/self/cgroup``: ``id:controllers:path``; cgroup v2 has no controllers)."""
    wanted = 'freezer' if root == _FREEZER_ROOT else 'cpu'
    for line in Path('/proc/self/cgroup').read_text().splitlines():
        _, controllers, path = line.split(':', 2)
        if wanted in controllers.split(',') or (not controllers and root.name != wanted):
            return root / path.lstrip('/')
    return root


def _rejoin_the_ros_tests() -> None:
    """An offline worker that joined the ROS pool (``JOINING_WORKERS``) goes
    back to the groups it left, so that it is neither idle nor frozen with the
    offline workers; without cgroups, its session's autogroup back to nice 0."""
    if not _left_groups:
        try:
            with open('/proc/self/autogroup', 'w') as autogroup:
                autogroup.write('0')
        except OSError:
            pass     # no autogroups: the policy alone then
        return
    while _left_groups:
        group = _left_groups.pop()
        try:
            (group / 'cgroup.procs').write_text(str(os.getpid()))
        except OSError as err:
            raise RuntimeError(f'cannot leave the offline workers\' cgroup for {group}: '
                               f'{err}') from err


def _join_freezer_group() -> None:
    """Move this process into :data:`_IDLE_CGROUP` of cgroup v1's freezer
    hierarchy too, where there is one and it is writable (a cgroup v2 tree
    freezes the CPU group itself: :func:`_freeze_offline`)."""
    if not (_FREEZER_ROOT / 'cgroup.procs').is_file():
        return
    group = _FREEZER_ROOT / _IDLE_CGROUP
    previous = _group_of_this_process(_FREEZER_ROOT)
    try:
        group.mkdir(exist_ok=True)
        (group / 'cgroup.procs').write_text(str(os.getpid()))
    except OSError:
        return
    _left_groups.append(previous)


def _freeze_offline(frozen: bool) -> str:
    """Freeze (or thaw) the offline workers and all they started, for a
    module of :data:`FROZEN_MODULES` (:func:`_ros_turns`); return what was
    done, for its log.

    Their idle CPU priority was not enough for a 20 ms timing claim: by hand,
    the churn test's tick thread waited 9-21 ms for a CPU beside two busy
    loops at ``SCHED_IDLE`` in a CPU group with ``cpu.idle`` 1 (cgroup v1),
    against 1-6 ms on an idle machine; and a fresh clone's workers run failed
    that test on such waits. A frozen process gets no CPU at all; its wall
    clock runs on, so an offline test's deadline loses the frozen time
    (every such deadline here is far longer than an ``alone`` module). Another
    pytest run's offline workers in the same group freeze too.
    """
    groups = [(_FREEZER_ROOT / _IDLE_CGROUP / 'freezer.state', 'FROZEN', 'THAWED')]
    groups += [(root / _IDLE_CGROUP / 'cgroup.freeze', '1', '0')
               for root in _cpu_cgroup_roots()]
    for state, on, off in groups:
        if not state.is_file():
            continue
        try:
            state.write_text(on if frozen else off)
        except OSError as err:
            return f'not {"frozen" if frozen else "thawed"} ({state}: {err})'
        if not frozen:
            return 'thawed'
        # v1 reads FREEZING until every task has stopped; v2 says it in cgroup.events.
        events = state.with_name('cgroup.events')
        deadline = time.monotonic() + _FREEZE_DEADLINE_S
        while time.monotonic() < deadline:
            if (state.read_text().strip() == on if state.name == 'freezer.state'
                    else 'frozen 1' in events.read_text()):
                return 'frozen'
            time.sleep(0.001)
        return f'still freezing after {_FREEZE_DEADLINE_S:g} s ({state})'
    return 'no freezer group'


def _remove_idle_cgroup() -> None:
    """Remove :data:`_IDLE_CGROUP` once empty (another run's workers may still
    be in it: then it stays, and is used again)."""
    _freeze_offline(False)   # an alone module that died frozen them
    for root in [*_cpu_cgroup_roots(), _FREEZER_ROOT]:
        try:
            (root / _IDLE_CGROUP).rmdir()
        except OSError:
            pass


def _leave_the_ros_tests_autogroup() -> None:
    """Move this process into a session of its own and give its autogroup the
    weakest nice value (Linux ``sched_autogroup``).

    With autogroups (``/proc/sys/kernel/sched_autogroup_enabled``, on here),
    the scheduler first shares the CPUs fairly between sessions, and only
    then between the threads of a session by their policy. Every node a test
    starts has a session of its own; the xdist workers share ``make``'s. So
    a worker at SCHED_IDLE still took its session's fair share against each
    node whenever the ROS worker in the same session slept: two idle-policy
    busy loops in the test's session made the 15 N stretch test fail all
    three runs, its processes waiting 114-325 ms for a CPU (stall watcher);
    in sessions of their own at nice 19, the four closed-loop tests passed
    first time. Without autogroups this changes nothing.
    """
    try:
        os.setsid()
    except PermissionError:
        return   # already a process group leader: stays where it is
    try:
        with open('/proc/self/autogroup', 'w') as autogroup:
            autogroup.write(str(_WEAKEST_NICE))
    except OSError:
        pass     # no autogroups (kernel without them): the policy alone then


def _set_priority(policy: int, io_class: int) -> None:
    """The CPU policy and I/O class of every thread of this process.

    Linux keeps both per thread, and a thread inherits them from the thread
    that creates it. Setting them for the calling thread alone left the
    threads made before it at normal priority: the BLAS pool that importing
    NumPy starts, for one (read back from /proc: policy 0 beside the main
    thread's 5). The stalls the closed-loop tests measured beside this worker
    were the session's share (:func:`_leave_the_ros_tests_autogroup`): they
    stayed with every thread idle, and went with the session of its own.
    """
    for entry in os.listdir('/proc/self/task'):
        tid = int(entry)
        try:
            os.sched_setscheduler(tid, policy, os.sched_param(0))
            _set_io_class(tid, io_class)
        except ProcessLookupError:
            pass   # the thread ended meanwhile


@pytest.hookimpl(tryfirst=True)
def pytest_runtest_setup(item):
    """Under xdist: offline tests (and what they start) at idle CPU and I/O
    priority, the ROS tests at normal priority (see the module docstring).

    A hook that runs before any fixture of the test is set up: as an autouse
    fixture it came after the module's own fixtures, so the clean install's
    venv and pip (a module fixture, 20-30 s) ran at normal priority in the
    ROS tests' cgroup.

    First, in every run, the garbage collector's turn
    (:func:`_collect_between_modules`), and the wait for the compiled kernels
    (:func:`_await_the_kernels`)."""
    _collect_between_modules(item.module)
    _check_kernel_free(item.module)
    _await_the_kernels(item)
    if 'PYTEST_XDIST_WORKER' not in os.environ or not hasattr(os, 'SCHED_IDLE'):
        return
    module = item.module
    idle = is_offline_module(module.__name__.rsplit('.', 1)[-1])
    uses_ros = _ros_names_in(module)
    if idle and uses_ros:
        pytest.fail(f'{module.__name__} is listed as offline in conftest.py (it runs beside '
                    f'the ROS tests at idle priority) but uses {", ".join(uses_ros)}: take it '
                    f'off OFFLINE_PREFIXES / OFFLINE_MODULES')
    policy = os.SCHED_IDLE if idle else os.SCHED_OTHER
    if os.sched_getscheduler(0) != policy:
        # Once per worker: a worker runs one pool only (PoolScheduling), but
        # for the offline workers that join the ROS pool once theirs is done.
        if idle and not _join_idle_cgroup():
            # Autogroups do not apply inside a cgroup, so only without one.
            _leave_the_ros_tests_autogroup()
        if not idle:
            _rejoin_the_ros_tests()
        _set_priority(policy, _IOPRIO_CLASS_IDLE if idle else _IOPRIO_CLASS_NONE)


@pytest.fixture(scope='module', autouse=True)
def _ros_turns(request):
    """Under xdist, the ROS workers take turns by module: a module of
    :data:`ALONE_MODULES` runs while no other ROS module does; the others run
    side by side. A readers-writer lock between the worker processes (``flock``):
    everyone queues at a turnstile first, so a waiting ``alone`` module is
    not overtaken by the modules that start after it asked. While a module of
    :data:`FROZEN_MODULES` runs, the offline workers are frozen too
    (:func:`_freeze_offline`)."""
    folder = os.environ.get(_TURNS_ENV)
    name = request.module.__name__.rsplit('.', 1)[-1]
    if 'PYTEST_XDIST_WORKER' not in os.environ or folder is None or is_offline_module(name):
        yield
        return
    # A test that takes the stall watcher repeats a run only on a measured
    # stall: a timing claim too (the 15 N stretch test failed all three runs
    # beside another ROS module, its controller waiting up to 511 ms for a CPU).
    claims = any(item.get_closest_marker('alone') or 'stall_watcher' in item.fixturenames
                 for item in request.session.items if item.module is request.module)
    alone = name in ALONE_MODULES
    if claims and not alone:
        pytest.fail(f'{name} has an `alone` test or takes the stall watcher: add it to '
                    f'ALONE_MODULES in conftest.py')
    frozen = name in FROZEN_MODULES
    turnstile = os.open(os.path.join(folder, 'turnstile'), os.O_RDWR | os.O_CREAT)
    turn = os.open(os.path.join(folder, 'turn'), os.O_RDWR | os.O_CREAT)
    try:
        fcntl.flock(turnstile, fcntl.LOCK_EX)
        fcntl.flock(turn, fcntl.LOCK_EX if alone else fcntl.LOCK_SH)
        fcntl.flock(turnstile, fcntl.LOCK_UN)
        if frozen:
            print(f'\n{name}: offline workers {_freeze_offline(True)}')
        yield
    finally:
        if frozen:
            _freeze_offline(False)
        os.close(turn)        # closing releases the lock
        os.close(turnstile)
