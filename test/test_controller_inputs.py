"""Inputs of the force controller core: what it rejects, and when it may act."""
import math

import pytest

from hill_muscle_ros.control import ControllerInputs, ControllerParams, ForceController

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


# -- ControllerInputs: the controller acts only on inputs it has received ----------

FEEDBACK_TIMEOUT_S = 0.5
TARGET_TIMEOUT_S = 2.0


def test_nothing_received_means_no_target():
    assert ControllerInputs(FEEDBACK_TIMEOUT_S).state(0.0) == ControllerInputs.NO_TARGET


def test_force_without_a_target_is_not_ready():
    inputs = ControllerInputs(FEEDBACK_TIMEOUT_S)
    inputs.set_force(10.0, 0.0)
    assert inputs.state(0.01) == ControllerInputs.NO_TARGET


def test_target_without_force_is_not_ready():
    inputs = ControllerInputs(FEEDBACK_TIMEOUT_S)
    inputs.set_target(10.0, 0.0)
    assert inputs.state(0.01) == ControllerInputs.NO_FEEDBACK


def test_target_and_fresh_force_are_ready():
    inputs = ControllerInputs(FEEDBACK_TIMEOUT_S)
    inputs.set_target(10.0, 0.0)
    inputs.set_force(9.0, 0.1)
    assert inputs.state(0.1 + FEEDBACK_TIMEOUT_S) == ControllerInputs.READY


def test_force_older_than_the_feedback_timeout_is_stale():
    inputs = ControllerInputs(FEEDBACK_TIMEOUT_S)
    inputs.set_target(10.0, 0.0)
    inputs.set_force(9.0, 0.1)
    assert inputs.state(0.1 + 1.01 * FEEDBACK_TIMEOUT_S) == ControllerInputs.STALE_FEEDBACK


def test_a_target_holds_forever_when_target_timeout_is_zero():
    inputs = ControllerInputs(FEEDBACK_TIMEOUT_S, 0.0)
    inputs.set_target(10.0, 0.0)
    inputs.set_force(9.0, 1e6)
    assert inputs.state(1e6) == ControllerInputs.READY


def test_a_target_older_than_target_timeout_is_stale():
    inputs = ControllerInputs(FEEDBACK_TIMEOUT_S, TARGET_TIMEOUT_S)
    inputs.set_target(10.0, 0.0)
    inputs.set_force(9.0, 1.01 * TARGET_TIMEOUT_S)
    assert inputs.state(1.01 * TARGET_TIMEOUT_S) == ControllerInputs.STALE_TARGET


def test_a_new_target_refreshes_a_stale_one():
    inputs = ControllerInputs(FEEDBACK_TIMEOUT_S, TARGET_TIMEOUT_S)
    inputs.set_target(10.0, 0.0)
    inputs.set_target(12.0, 3.0)
    inputs.set_force(9.0, 3.0)
    assert inputs.state(3.0) == ControllerInputs.READY
    assert inputs.target_n == 12.0


def test_each_force_sample_is_new_once():
    inputs = ControllerInputs(FEEDBACK_TIMEOUT_S)
    inputs.set_force(9.0, 0.0)
    assert [inputs.take_new_force(), inputs.take_new_force()] == [True, False]
