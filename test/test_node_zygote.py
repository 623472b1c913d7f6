"""A node forked from the test zygote behaves as the node started from its script.

The ROS tests start the package's nodes as forks of a Python that imported
them already (``node_zygote.py``). These tests hold that to the script: the
same exit status and message for a bad parameter, a clean stop on SIGINT in
a session of its own, the test's environment and not the zygote's, and an
``exec`` wherever a fork could differ.
"""
import os
import signal
import sys
from pathlib import Path

import pytest
from std_msgs.msg import Float64

from node_zygote import ZYGOTE, ForkedPopen
from ros_helpers import Probe, ProcessGroup, node_command

pytestmark = pytest.mark.ros

@pytest.fixture(autouse=True)
def _forking_on(monkeypatch):
    """These tests are about forked nodes, even in a run that switched forking off."""
    monkeypatch.setenv('HILL_MUSCLE_TEST_FORK', '1')


#: A start-up parameter the simulator refuses, and the words its refusal must name.
BAD_RATE = ('-p', 'rate_hz:=-5.0')
NEEDLE = 'rate_hz'


def _bad_start(tmp_path: Path, fork: str) -> tuple[int, str, object]:
    os.environ['HILL_MUSCLE_TEST_FORK'] = fork   # _forking_on puts it back
    with ProcessGroup(tmp_path) as procs:
        proc = procs.start(f'bad_{fork}', node_command('simulator', extra_ros_args=BAD_RATE))
        status = proc.wait()
    return status, proc.output(), proc.popen


def _error_lines(log: str) -> list[str]:
    """The log's error lines without their timestamps."""
    return [line.split('] ', 2)[-1] for line in log.splitlines() if 'ERROR' in line]


def test_a_forked_node_refuses_a_bad_parameter_exactly_as_its_script(tmp_path):
    forked_status, forked_log, forked = _bad_start(tmp_path, '1')
    script_status, script_log, script = _bad_start(tmp_path, '0')
    assert isinstance(forked, ForkedPopen) and not isinstance(script, ForkedPopen)
    assert forked_status == script_status != 0
    assert NEEDLE in forked_log
    assert _error_lines(forked_log) == _error_lines(script_log) != []
    assert 'Traceback' not in forked_log


def test_a_forked_node_runs_in_a_session_of_its_own_and_stops_cleanly_on_sigint(tmp_path):
    with ProcessGroup(tmp_path) as procs, Probe('zygote_probe') as probe:
        sim = procs.start('sim', node_command('simulator', ns='/zygote',
                                              params={'rate_hz': 200.0}))
        force = probe.record('/zygote/force', Float64)
        probe.wait_for_messages(force, procs=[sim])
        assert isinstance(sim.popen, ForkedPopen)
        assert os.getsid(sim.pid) == sim.pid
        assert os.getppid() != os.getpgid(sim.pid)
        sim.send_signal(signal.SIGINT)
        assert sim.wait() == 0
    assert '[zygote.simulator.stats]: ran ' in sim.output()


def test_a_forked_node_sees_the_tests_environment(tmp_path):
    # The zygote runs the compiled engine; this start asks for the Python one,
    # and the node must say so from the environment it was given.
    env = dict(os.environ, HILL_MUSCLE_ENGINE='python')
    with ProcessGroup(tmp_path) as procs:
        proc = procs.start('env', node_command('simulator', ns='/zygote_env'), env=env)
        procs.wait_until(lambda: 'muscle engine' in proc.output(), 'the engine line')
    assert isinstance(proc.popen, ForkedPopen)
    assert 'muscle engine: python (HILL_MUSCLE_ENGINE=python)' in proc.output()


@pytest.mark.parametrize('case', ['cli', 'preexec_fn', 'numba_env', 'switched_off'])
def test_what_a_fork_could_change_is_started_from_the_script(case, monkeypatch):
    node = node_command('simulator')
    assert ZYGOTE.forkable(node, dict(os.environ), None)
    cmd, env, preexec_fn = node, dict(os.environ), None
    if case == 'cli':
        cmd = [str(Path(sys.executable).parent / 'hill-muscle'), 'simulate']
    elif case == 'preexec_fn':
        preexec_fn = os.getpid
    elif case == 'numba_env':
        env['NUMBA_CACHE_DIR'] = '/nowhere'
    else:
        monkeypatch.setenv('HILL_MUSCLE_TEST_FORK', '0')
    assert not ZYGOTE.forkable(cmd, env, preexec_fn)
