"""The demos' stop signals (supervisor.StopSignals), offline.

A stop signal that arrives while a supervised process is being polled,
waited for or stopped is raised once that call is over, not inside
``subprocess.Popen``: raised between Popen taking its reaping lock and the
``try`` that releases it, it left the lock held, and ``make demo`` hung in
``Popen.wait`` after Ctrl-C in about one run of 15.

A fresh-clone run saw ``make demo-knee`` exit 1 ("demo-knee: error: Unable
to convert call argument '0' to Python object") on SIGINT: the
KeyboardInterrupt raised by the signal handler came out of rclpy's pybind11
extension as a RuntimeError. These tests reproduce that mechanism without
ROS: a stop signal is remembered, and a demo that meets any error after one
reports the interrupt (exit 130), not an error.
"""
import signal
import sys

import pytest

from hill_muscle_ros import demo_knee
from hill_muscle_ros.supervisor import Process, StopSignals, wait_until

#: [s] grace of the sleeping child's stop (SIGINT ends it at once).
GRACE_S = 10.0

#: pybind11's message when a Python exception interrupts an argument conversion.
PYBIND11_MESSAGE = "Unable to convert call argument '0' to Python object"


@pytest.fixture
def restore_handlers():
    saved = {sig: signal.getsignal(sig) for sig in StopSignals.SIGNALS}
    yield
    for sig, handler in saved.items():
        signal.signal(sig, handler)


@pytest.mark.parametrize('sig', StopSignals.SIGNALS, ids=lambda s: signal.Signals(s).name)
def test_a_stop_signal_raises_keyboard_interrupt_and_is_remembered(restore_handlers, sig):
    stops = StopSignals()
    with pytest.raises(KeyboardInterrupt):
        signal.raise_signal(sig)
    assert stops.received == sig


def test_sigint_is_taken_even_if_it_was_inherited_ignored(restore_handlers):
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    StopSignals()
    with pytest.raises(KeyboardInterrupt):
        signal.raise_signal(signal.SIGINT)


def test_an_error_after_a_stop_signal_ends_the_knee_demo_as_interrupted(
        restore_handlers, monkeypatch, tmp_path, capsys):
    def run_interrupted_inside_an_extension(*args, **kwargs):
        try:
            signal.raise_signal(signal.SIGINT)
        except KeyboardInterrupt:
            raise RuntimeError(PYBIND11_MESSAGE) from None
    monkeypatch.setattr(demo_knee, 'run', run_interrupted_inside_an_extension)
    assert demo_knee.main(['--out', str(tmp_path / 'out')]) == demo_knee.EXIT_INTERRUPTED
    assert 'interrupted' in capsys.readouterr().err


def test_an_error_without_a_stop_signal_is_reported_as_an_error(
        restore_handlers, monkeypatch, tmp_path, capsys):
    def run_failing(*args, **kwargs):
        raise RuntimeError('the limb node exited')
    monkeypatch.setattr(demo_knee, 'run', run_failing)
    assert demo_knee.main(['--out', str(tmp_path / 'out')]) == demo_knee.EXIT_ERROR
    assert 'the limb node exited' in capsys.readouterr().err


class SignalAfterAcquire:
    """Stands in for Popen's reaping lock: sends a stop signal to this process
    right after the lock is taken, in the window before Popen's ``try``."""

    def __init__(self, lock, sig: int) -> None:
        self._lock, self._sig, self.fired = lock, sig, False

    def acquire(self, *args) -> bool:
        taken = self._lock.acquire(*args)
        if taken and not self.fired:
            self.fired = True
            signal.raise_signal(self._sig)   # the handler runs before this returns
        return taken

    def release(self) -> None:
        self._lock.release()

    def locked(self) -> bool:
        return self._lock.locked()

    def __enter__(self):
        self.acquire()
        return self

    def __exit__(self, *exc) -> None:
        self.release()


#: What the sleeper prints once Python is up: a SIGINT before that may end it
#: with exit 1 (Python still starting), not by the signal.
SLEEPING = 'sleeping'


@pytest.fixture
def sleeper(tmp_path):
    proc = Process('sleeper', [sys.executable, '-c',
                               f'import time; print({SLEEPING!r}, flush=True); time.sleep(60)'],
                   tmp_path / 'sleeper.log', env={})
    # A test run beside others on a loaded machine: signalled still starting,
    # the sleeper exited 1 instead of by SIGINT.
    wait_until(lambda: SLEEPING in proc.output(), 'the sleeper to start', GRACE_S, watch=[proc])
    yield proc
    proc.kill()


def test_a_stop_signal_inside_a_poll_is_raised_after_it_and_the_child_can_still_be_stopped(
        restore_handlers, sleeper):
    StopSignals()
    lock = sleeper.popen._waitpid_lock = SignalAfterAcquire(sleeper.popen._waitpid_lock,
                                                           signal.SIGINT)
    with pytest.raises(KeyboardInterrupt):
        sleeper.returncode
    assert lock.fired
    assert not lock.locked(), 'the stop signal left Popen\'s reaping lock held'
    assert sleeper.stop(GRACE_S) == -signal.SIGINT


def test_a_stop_signal_during_the_stop_of_a_group_stops_every_process_first(
        restore_handlers, tmp_path):
    from hill_muscle_ros.supervisor import ProcessGroup
    StopSignals()
    group = ProcessGroup(tmp_path, env={}, grace_s=GRACE_S)
    first = group.start('first', [sys.executable, '-c', 'import time; time.sleep(60)'])
    second = group.start('second', [sys.executable, '-c', 'import time; time.sleep(60)'])
    second.popen._waitpid_lock = SignalAfterAcquire(second.popen._waitpid_lock, signal.SIGTERM)
    try:
        with pytest.raises(KeyboardInterrupt):
            group.stop_all()
        # Both ended (the first may take SIGINT still starting up: exit 1).
        assert first.returncode is not None and second.returncode is not None
    finally:
        first.kill()
        second.kill()


def test_a_stop_signal_while_a_group_starts_a_process_comes_after_it_joined_the_group(
        restore_handlers, tmp_path, monkeypatch):
    from hill_muscle_ros import supervisor
    real_popen = supervisor.subprocess.Popen

    def popen_then_signal(*args, **kwargs):
        child = real_popen(*args, **kwargs)
        signal.raise_signal(signal.SIGINT)   # the child runs: the signal comes now
        return child

    StopSignals()
    group = supervisor.ProcessGroup(tmp_path, env={}, grace_s=GRACE_S)
    monkeypatch.setattr(supervisor.subprocess, 'Popen', popen_then_signal)
    try:
        with pytest.raises(KeyboardInterrupt):
            group.start('sleeper', [sys.executable, '-c', 'import time; time.sleep(60)'])
        monkeypatch.undo()
        assert [p.name for p in group.processes] == ['sleeper'], 'a started child left unstopped'
    finally:
        monkeypatch.undo()
        group.stop_all()
