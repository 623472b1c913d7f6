"""Input validation of the force controller core (what the node rejects)."""
import math

import pytest

from hill_muscle_ros.control import ControllerParams, ForceController

LIMIT_N = ControllerParams().force_limit_n


@pytest.mark.parametrize('bad', [math.nan, math.inf, -math.inf, -1.0, 2 * LIMIT_N])
def test_bad_force_target_is_rejected_by_name(bad):
    with pytest.raises(ValueError, match='`force_target`'):
        ForceController().check_target(bad)


@pytest.mark.parametrize('good', [0.0, 20.0, LIMIT_N])
def test_force_target_in_range_is_returned(good):
    assert ForceController().check_target(good) == good


@pytest.mark.parametrize('bad', [math.nan, math.inf, -math.inf, 2 * LIMIT_N, -2 * LIMIT_N])
def test_bad_force_feedback_is_rejected_by_name(bad):
    with pytest.raises(ValueError, match='`force`'):
        ForceController().check_force(bad)


def test_slightly_negative_force_feedback_is_accepted():
    """A load cell at rest reads a little below zero."""
    assert ForceController().check_force(-0.01) == -0.01


def test_reference_model_follows_a_step_with_its_time_constant():
    """F_ref = F* - (F* - F0) exp(-t / tau): after one tau, 63 % of the step."""
    ctrl = ForceController()
    tau = ctrl.params.reference_tau_s
    dt = tau / 100
    ctrl.update(0.0, 0.0, dt)  # starts at the measured force, 0 N
    for _ in range(100):
        ctrl.update(20.0, 0.0, dt)
    assert ctrl.reference_n == pytest.approx(20.0 * (1.0 - math.exp(-1.0)), rel=1e-9)


def test_zero_reference_time_constant_tracks_the_target_itself():
    ctrl = ForceController(ControllerParams(reference_tau_s=0.0))
    ctrl.update(20.0, 5.0, 0.01)
    assert ctrl.reference_n == 20.0
