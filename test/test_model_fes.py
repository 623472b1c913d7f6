"""The FES muscle (delay, activation, recruitment curves, fatigue, fibre types,
unit lengths): laws checked against their closed forms and against the paper's
model where they must reduce to it."""
import math

import numpy as np
import pytest

from hill_muscle_ros.model import Muscle, MuscleParams, Protocol, simulate
from hill_muscle_ros.model.fes_muscle import FesMuscle
from hill_muscle_ros.model.stimulus import command_from_pulse_width
from hill_muscle_ros.resources import protocol_path

#: [N] agreement of two paths that compute the same model (rounding only).
SAME_MODEL_TOL_N = 1e-9
VARIANTS = [(u, l) for u in ('multi', 'single') for l in ('initial', 'instantaneous')]


def _protocol(name):
    return Protocol.from_yaml(protocol_path(name))


def _fes_simulate(protocol, params, rate_hz=1000.0):
    """simulate() with the FES engine forced, even where every feature is off."""
    original = Muscle.__new__

    def forced(cls, p=None):
        return object.__new__(FesMuscle)
    Muscle.__new__ = forced
    try:
        return simulate(protocol, params, rate_hz)
    finally:
        Muscle.__new__ = original


def test_defaults_make_the_papers_muscle_and_features_make_the_fes_one():
    assert type(Muscle(MuscleParams())) is Muscle
    assert type(Muscle(MuscleParams(tau_act_s=0.05))) is FesMuscle


@pytest.mark.parametrize('units,length', VARIANTS)
@pytest.mark.parametrize('name', ['I', 'II'])
def test_fes_engine_with_every_feature_off_equals_the_papers_loop(name, units, length):
    params = MuscleParams(units=units, length=length)
    paper = simulate(_protocol(name), params)
    fes = _fes_simulate(_protocol(name), params)
    np.testing.assert_allclose(fes.force_n, paper.force_n, rtol=0, atol=SAME_MODEL_TOL_N)
    np.testing.assert_array_equal(fes.recruitment, paper.recruitment)


# -- recruitment curves ---------------------------------------------------------------


def test_linear_curve_is_the_papers_ratio_and_saturates():
    p = MuscleParams()
    assert command_from_pulse_width(0.00025, p) == 0.5
    assert command_from_pulse_width(0.001, p) == 1.0


def test_threshold_linear_curve_is_zero_below_threshold_and_one_at_pw_max():
    p = MuscleParams(recruitment_curve='threshold_linear', pw_threshold_s=0.0001)
    assert command_from_pulse_width(0.00005, p) == 0.0
    assert command_from_pulse_width(0.0003, p) == pytest.approx(0.5, abs=1e-15)
    assert command_from_pulse_width(0.0005, p) == 1.0


def test_exponential_curve_follows_ding_2007():
    p = MuscleParams(recruitment_curve='exponential', pw_threshold_s=131.4e-6,
                     pw_scale_s=194.1e-6)
    assert command_from_pulse_width(100e-6, p) == 0.0
    pw = 131.4e-6 + 194.1e-6
    assert command_from_pulse_width(pw, p) == pytest.approx(1.0 - math.exp(-1.0), abs=1e-15)


@pytest.mark.parametrize('bad', [-1e-6, math.nan, math.inf])
def test_bad_pulse_width_is_rejected_by_name(bad):
    with pytest.raises(ValueError, match='`pulse_width_s` must be finite and non-negative'):
        command_from_pulse_width(bad, MuscleParams())


# -- delay and activation -------------------------------------------------------------


def _step_response(params, duration_s=0.5, command=1.0, rate_hz=1000.0):
    protocol = Protocol.from_mapping({'name': 'step', 'duration_s': duration_s,
                                      'recruitment': [[0.0, command]],
                                      'dl_mt_m': [[0.0, 0.0]]})
    return simulate(protocol, params, rate_hz)


@pytest.mark.parametrize('emd_s', [0.0, 0.025, 0.0312])
def test_activation_step_response_is_its_closed_form_after_the_delay(emd_s):
    tau = 0.06
    result = _step_response(MuscleParams(tau_act_s=tau, tau_deact_s=0.11, emd_s=emd_s))
    t = result.t_s
    expected = np.where(t > emd_s, 1.0 - np.exp(-(t - emd_s) / tau), 0.0)
    np.testing.assert_allclose(result.recruitment, expected, rtol=0, atol=1e-12)


def test_deactivation_follows_its_own_time_constant():
    protocol = Protocol.from_mapping({'name': 'off', 'duration_s': 1.0,
                                      'recruitment': [[0.0, 1.0], [0.5, 1.0], [0.5, 0.0]],
                                      'dl_mt_m': [[0.0, 0.0]]})
    result = simulate(protocol, MuscleParams(tau_act_s=0.01, tau_deact_s=0.1))
    t, a = result.t_s, result.recruitment
    after = t > 0.5
    a_off = 1.0 - math.exp(-0.5 / 0.01)
    expected = a_off * np.exp(-(t[after] - 0.5) / 0.1)
    # Multi: recruitment reads the activation; it is the muscle's R.
    np.testing.assert_allclose(a[after], expected, rtol=0, atol=1e-12)


def test_delay_holds_the_muscle_at_rest_until_it_has_passed():
    result = _step_response(MuscleParams(emd_s=0.03), duration_s=0.1)
    before = result.t_s < 0.03 - 1e-12
    assert np.all(result.recruitment[before] == 0.0)
    assert np.all(result.eff_f_iso_n[before] == 0.0)
    assert result.recruitment[result.at(0.03)] == 1.0
