"""The demos' stop signals (supervisor.StopSignals), offline.

A fresh-clone run saw ``make demo-knee`` exit 1 ("demo-knee: error: Unable
to convert call argument '0' to Python object") on SIGINT: the
KeyboardInterrupt raised by the signal handler came out of rclpy's pybind11
extension as a RuntimeError. These tests reproduce that mechanism without
ROS: a stop signal is remembered, and a demo that meets any error after one
reports the interrupt (exit 130), not an error.
"""
import signal

import pytest

from hill_muscle_ros import demo_knee
from hill_muscle_ros.supervisor import StopSignals

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
