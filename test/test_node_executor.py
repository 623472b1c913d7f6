"""How `run_node` spins a node: the executor switch and the stop signals.

The default is rclpy's C++ EventsExecutor; ``HILL_MUSCLE_EXECUTOR=single``
falls back to the SingleThreadedExecutor. Under either, a stop signal ends the
node cleanly: its ``on_exit`` runs (the simulator logs its statistics there)
and nothing is reported as an error; the recorder, which spins the same
executor for its timers, closes its bag with what it received.
"""
from __future__ import annotations

import itertools
import os
import signal

import pytest
import rclpy
from rclpy.executors import SingleThreadedExecutor
from std_msgs.msg import Float64

from hill_muscle_ros.nodes._process import (EXECUTOR_ENV, EXECUTORS, StartupError, StopSignals,
                                            make_executor)
from hill_muscle_ros.recording.reader import read_bag
from ros_helpers import Probe, ProcessGroup, node_command, ros_env

_RUNS = itertools.count()


@pytest.fixture
def context():
    ctx = rclpy.Context()
    ctx.init()
    yield ctx
    ctx.try_shutdown()


def test_default_executor_is_the_events_executor(context, monkeypatch):
    monkeypatch.delenv(EXECUTOR_ENV, raising=False)
    executor = make_executor(context)
    try:
        assert type(executor).__name__ == 'EventsExecutor'
    finally:
        executor.shutdown()


def test_single_selects_the_single_threaded_executor(context, monkeypatch):
    monkeypatch.setenv(EXECUTOR_ENV, 'single')
    executor = make_executor(context)
    try:
        assert isinstance(executor, SingleThreadedExecutor)
    finally:
        executor.shutdown()


def test_unknown_executor_name_is_a_startup_error_naming_the_variable(context, monkeypatch):
    monkeypatch.setenv(EXECUTOR_ENV, 'multi')
    with pytest.raises(StartupError, match=f"{EXECUTOR_ENV}='multi'.*events, single"):
        make_executor(context)


def test_a_probe_spins_with_the_events_executor_unless_asked_for_the_single_one():
    with Probe('executor_probe') as events, Probe('executor_probe', executor='single') as single:
        assert type(events.executor).__name__ == 'EventsExecutor'
        assert isinstance(single.executor, SingleThreadedExecutor)


def test_a_probe_refuses_an_unknown_executor_by_name():
    with pytest.raises(ValueError, match="`executor` must be one of events, single, got 'multi'"):
        Probe('executor_probe', executor='multi')


def test_stop_signal_is_recorded_not_raised_and_repeats_are_ignored():
    before = signal.getsignal(signal.SIGINT)
    with StopSignals() as stop:
        os.kill(os.getpid(), signal.SIGTERM)
        os.kill(os.getpid(), signal.SIGINT)   # a repeat while stopping: ignored
        signal.getsignal(signal.SIGINT)       # Python runs pending handlers by here
        assert stop.received == signal.SIGTERM
    assert signal.getsignal(signal.SIGINT) is before


@pytest.mark.ros
@pytest.mark.parametrize('sig', [signal.SIGINT, signal.SIGTERM], ids=['SIGINT', 'SIGTERM'])
@pytest.mark.parametrize('executor', sorted(EXECUTORS))
def test_simulator_stops_cleanly_on_a_stop_signal(tmp_path, executor, sig):
    ns = f'/exec_{os.getpid()}_{next(_RUNS)}'
    with ProcessGroup(tmp_path) as procs, Probe('exec_probe') as probe:
        sim = procs.start('simulator', node_command('simulator', ns=ns),
                          env=ros_env(**{EXECUTOR_ENV: executor}))
        force = probe.record(f'{ns}/force', Float64)
        probe.wait_for_messages(force, 100, procs=[sim])
        sim.popen.send_signal(sig)
        assert sim.wait() == 0
        log = sim.output()
    assert 'steps/s' in log   # on_exit's statistics
    assert 'FATAL' not in log and 'Traceback' not in log and 'Error' not in log


@pytest.mark.ros
def test_unknown_executor_name_stops_the_node_with_one_line(tmp_path):
    with ProcessGroup(tmp_path) as procs:
        sim = procs.start('simulator', node_command('simulator'),
                          env=ros_env(**{EXECUTOR_ENV: 'bogus'}))
        assert sim.wait() == 1
        log = sim.output()
    assert f"{EXECUTOR_ENV}='bogus'" in log and 'Traceback' not in log


@pytest.mark.ros
@pytest.mark.parametrize('executor', sorted(EXECUTORS))
def test_recorder_records_and_stops_cleanly_under_either_executor(tmp_path, executor):
    ns = f'/exec_rec_{os.getpid()}_{next(_RUNS)}'
    bag = tmp_path / 'bag'
    with ProcessGroup(tmp_path) as procs, Probe('exec_rec_probe') as probe:
        rec = procs.start('recorder', node_command(
            'recorder', ns=ns, params={'output': str(bag), 'topics': ['force']}),
            env=ros_env(**{EXECUTOR_ENV: executor}))
        probe.publish_when_matched(f'{ns}/force', Float64(data=3.0), procs=[rec])
        probe.retire(f'{ns}/force')   # acknowledged, and gone: nothing more to wait for
        rec.popen.send_signal(signal.SIGINT)
        assert rec.wait() == 0
        log = rec.output()
    assert list(read_bag(bag).topic(f'{ns}/force').values()) == [3.0], log
    assert 'FATAL' not in log and 'Traceback' not in log
