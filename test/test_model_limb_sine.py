"""The gravity torque's sine in the compiled limb's RK4 stages (``sine_near``):
sin of an angle near one whose sine and cosine are known, from the
angle-addition formula and the series of sin d and cos d, must be libm's
sin to rounding wherever the step takes it, and nowhere else."""
import math

from hypothesis import given, settings
from hypothesis import strategies as st

from hill_muscle_ros.model.equations import SINE_SERIES_MAX_RAD, sine_near

#: A double's rounding near 1, twice: the sum of two rounded products.
ROUNDING = 2 * 2.0 ** -52


@settings(max_examples=2000, deadline=None)
@given(theta_a=st.floats(-2 * math.pi, 2 * math.pi),
       d=st.floats(-SINE_SERIES_MAX_RAD, SINE_SERIES_MAX_RAD))
def test_sine_near_is_libm_sin_to_rounding_within_its_range(theta_a, d):
    theta = theta_a + d
    exact_d = theta - theta_a   # the step the stages pass: of the rounded angles
    assert abs(sine_near(math.sin(theta_a), math.cos(theta_a), exact_d)
               - math.sin(theta)) <= ROUNDING


def test_sine_near_at_zero_step_is_the_known_sine_exactly():
    for theta in (0.3, -1.2, 2.9):
        assert sine_near(math.sin(theta), math.cos(theta), 0.0) == math.sin(theta)


def test_the_series_falls_short_beyond_its_range():
    # A check that the range bound means something: at twenty times the bound
    # the truncated series is off by far more than rounding.
    theta_a, d = 0.7, 10 * SINE_SERIES_MAX_RAD * 2
    assert abs(sine_near(math.sin(theta_a), math.cos(theta_a), d)
               - math.sin(theta_a + d)) > 1e3 * ROUNDING
