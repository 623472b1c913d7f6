"""The curves of Eq. (1) and Eq. (3), and the springs (doc/model.md sections 1-3)."""
import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hill_muscle_ros.model import MuscleParams
from hill_muscle_ros.model.equations import (force_length, force_velocity,
                                             force_velocity_inverse, isometric_force_for,
                                             parallel_force, series_force)

P = MuscleParams()
HILL = (P.fv_a_n, P.fv_b_m_per_s, P.fv_a_ecc_n, P.fv_b_ecc_m_per_s)
forces0 = st.floats(min_value=0.5, max_value=200.0)


def test_force_length_peaks_at_one_at_optimal_length():
    assert force_length(1.0) == pytest.approx(1.0, abs=1e-12)
    assert force_length(0.99) < 1.0 and force_length(1.01) < 1.0


def test_force_length_at_rest_length_matches_model_md_value():
    # doc/model.md section 6: f_iso_max * FL(1.25) = 37.19 N.
    assert 45.0 * force_length(1.25) == pytest.approx(37.19, abs=0.005)
    assert force_length(1.25) == pytest.approx(-2.777 * 1.5625 + 5.554 * 1.25 - 1.777)


@pytest.mark.parametrize('x', [0.0, 0.3, 0.3999, 1.6001, 1.7, 3.0, -1.0])
def test_force_length_is_zero_outside_its_range(x):
    assert force_length(x) == 0.0


@given(st.floats(min_value=-10, max_value=10))
def test_force_length_is_never_negative(x):
    assert force_length(x) >= 0.0


@given(forces0)
def test_force_velocity_is_isometric_force_at_zero_velocity(f0):
    assert force_velocity(0.0, f0, *HILL) == pytest.approx(f0, rel=1e-12)
    assert force_velocity_inverse(f0, f0, *HILL) == 0.0


@given(forces0)
def test_force_velocity_reaches_plateau_continuously(f0):
    v_max_ecc = f0 * P.fv_b_ecc_m_per_s / P.fv_a_ecc_n
    assert force_velocity(v_max_ecc, f0, *HILL) == pytest.approx(1.5 * f0, rel=1e-12)
    assert force_velocity(v_max_ecc * (1 + 1e-9), f0, *HILL) == 1.5 * f0


@given(forces0)
def test_force_velocity_is_zero_at_maximal_shortening_velocity(f0):
    v_max = -f0 * P.fv_b_m_per_s / P.fv_a_n
    assert force_velocity(v_max, f0, *HILL) == pytest.approx(0.0, abs=1e-9 * f0)
    assert force_velocity_inverse(0.0, f0, *HILL) == pytest.approx(v_max)


@given(forces0, st.floats(min_value=1e-6, max_value=1.5 - 1e-6))
def test_force_velocity_inverse_inverts_force_velocity(f0, frac):
    f = frac * f0
    v = force_velocity_inverse(f, f0, *HILL)
    assert force_velocity(v, f0, *HILL) == pytest.approx(f, rel=1e-9, abs=1e-9)


@settings(max_examples=300)
@given(forces0, st.floats(min_value=-50.0, max_value=400.0),
       st.floats(min_value=0.0, max_value=50.0))
def test_force_velocity_inverse_is_non_decreasing(f0, f, df):
    assert force_velocity_inverse(f + df, f0, *HILL) >= force_velocity_inverse(f, f0, *HILL)


@settings(max_examples=300)
@given(forces0, st.sampled_from([0.0, 1.0, 1.5]), st.sampled_from([-1.0, 1.0]))
def test_force_velocity_inverse_is_continuous_at_every_branch_boundary(f0, frac, side):
    f = frac * f0
    eps = 1e-9 * max(f0, 1.0)
    here = force_velocity_inverse(f, f0, *HILL)
    near = force_velocity_inverse(f + side * eps, f0, *HILL)
    # Lipschitz bound: the steepest slope is b (F0 + a) / a^2 at F = 0.
    slope = max(P.fv_b_m_per_s * (f0 + P.fv_a_n) / P.fv_a_n ** 2,
                2 * P.fv_b_ecc_m_per_s * (1.5 * f0 + P.fv_a_ecc_n) / P.fv_a_ecc_n ** 2)
    assert abs(near - here) <= slope * eps * 1.01


@given(forces0, st.floats(min_value=1e-6, max_value=1.5 - 1e-6))
def test_isometric_force_for_returns_the_f0_at_which_the_ce_moves_at_that_speed(f0, frac):
    """Eq. (3) solved for F0 inverts Eq. (3) solved for v: any state the CE can
    be in is recovered."""
    f = frac * f0
    v = force_velocity_inverse(f, f0, *HILL)
    assert isometric_force_for(f, v, *HILL) == pytest.approx(f0, rel=1e-9)


@given(st.floats(min_value=0.5, max_value=200.0), st.floats(min_value=1e-4, max_value=1.0))
def test_isometric_force_for_a_lengthening_too_fast_gives_the_fastest_f0(f, v):
    """At force f the CE lengthens at most at f b' / (1.5 a'), with
    F0 = f / 1.5; asked for more, the answer is that F0, and no F0 does better."""
    a, b, a_ecc, b_ecc = HILL
    v_fastest = f * b_ecc / (1.5 * a_ecc)
    f0 = isometric_force_for(f, v, *HILL)
    if v > v_fastest:
        assert f0 == pytest.approx(f / 1.5)
    assert force_velocity_inverse(f, f0, *HILL) <= v_fastest * (1 + 1e-12)
    for other in (0.5 * f0, 0.9 * f0, 1.1 * f0, 2.0 * f0):
        assert force_velocity_inverse(f, other, *HILL) <= v_fastest * (1 + 1e-12)


def test_isometric_force_for_zero_force_is_zero():
    assert isometric_force_for(0.0, 0.01, *HILL) == 0.0


def test_series_spring_pulls_but_never_pushes():
    assert series_force(1e4, 0.0, P.l_rest_m, P.l_rest_m) == 0.0
    assert series_force(1e4, 0.002, P.l_rest_m, P.l_rest_m) == pytest.approx(20.0)
    assert series_force(1e4, -0.002, P.l_rest_m, P.l_rest_m) == 0.0


def test_parallel_spring_pulls_but_never_pushes():
    assert parallel_force(1e3, 0.01) == pytest.approx(10.0)
    assert parallel_force(1e3, -0.01) == 0.0
    assert not math.copysign(1.0, parallel_force(1e3, -0.01)) < 0
