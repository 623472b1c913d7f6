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
