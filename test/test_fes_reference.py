"""The FES reference (fes_reference.py) against analytic facts and the paper's reference.

These tests check the reference itself, never the production model: with
every FES feature at its default it is the paper's model (reference.py's
DOP853 solution), and its activation, fatigue, recovery and unit layout follow
their closed forms.
"""
import itertools
import math

import numpy as np
import pytest

from hill_muscle_ros.model import MuscleParams, Protocol
from hill_muscle_ros.model.equations import FL_A

from fes_reference import fes_reference
from reference import reference_force

#: [s] sample step of the tests, the production model's default.
DT = 1e-3
F_ISO = 45.0
N = 1000


def grid(duration_s: float) -> np.ndarray:
    """[s] samples k * DT from 0 to ``duration_s`` inclusive."""
    return np.arange(int(round(duration_s / DT)) + 1) * DT


def held(t: np.ndarray, steps: list[tuple[float, float]]) -> np.ndarray:
    """Piecewise-constant input: each (t_from, value) holds from t_from on."""
    out = np.zeros_like(t)
    for t_from, value in steps:
        out[t >= t_from - 1e-12] = value
    return out


VARIANTS = list(itertools.product(('multi', 'single'), ('initial', 'instantaneous')))


@pytest.mark.parametrize('units, length', VARIANTS)
def test_defaults_are_the_papers_model_on_protocol_II(protocol_paths, units, length):
    """FES features off: the paper's model. Measured 6e-8 N (initial) and
    3.1e-4 N (instantaneous, F0 held over the 0.1 ms sub-step)."""
    protocol = Protocol.from_yaml(protocol_paths['II'])
    t = grid(protocol.duration_s)
    out = fes_reference({'units': units, 'length': length}, t, protocol.stimulation(t),
                        protocol.stimulation_key, protocol.dl_mt(t), dt_ref_s=1e-4)
    expected = reference_force(protocol, MuscleParams(units=units, length=length), t)
    assert np.max(np.abs(out['force_n'] - expected)) <= 2e-3


@pytest.mark.parametrize('emd_s', [0.025, 0.025373], ids=['on-grid', 'inside-sub-step'])
def test_recruitment_is_the_closed_form_step_response_after_the_delay(emd_s):
    """a = 0 until the delayed step, then first-order rises and decays with
    tau_act / tau_deact. 25.373 ms puts the switch inside a 10 us sub-step."""
    tau_act, tau_deact = 0.06, 0.11
    t = grid(1.0)
    r = held(t, [(0.1, 0.8), (0.4, 0.3), (0.7, 0.0)])
    out = fes_reference({'emd_s': emd_s, 'tau_act_s': tau_act, 'tau_deact_s': tau_deact},
                        t, r, 'recruitment', np.zeros_like(t))
    t1, t2, t3 = 0.1 + emd_s, 0.4 + emd_s, 0.7 + emd_s
    a2 = 0.8 * (1 - math.exp(-(t2 - t1) / tau_act))
    a3 = 0.3 + (a2 - 0.3) * math.exp(-(t3 - t2) / tau_deact)
    expected = np.select(
        [t < t1, t < t2, t < t3, t >= t3],
        [0.0, 0.8 * (1 - np.exp(-(t - t1) / tau_act)),
         0.3 + (a2 - 0.3) * np.exp(-(t - t2) / tau_deact), a3 * np.exp(-(t - t3) / tau_deact)])
    np.testing.assert_allclose(out['recruitment'], expected, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(out['command'], r)


FATIGUE = {'fatigue': 'riener', 'fibre_fractions': (0.3, 0.7), 'fatigue_min': (0.2, 0.5),
           'tau_fatigue_s': (0.2, 0.5), 'tau_recovery_s': (0.3, 0.4)}
SINGLE_FATIGUE = {'units': 'single', 'fatigue': 'riener', 'fatigue_min': (0.2,),
                  'tau_fatigue_s': (0.2,), 'tau_recovery_s': (0.3,)}


@pytest.mark.parametrize('params', [FATIGUE, SINGLE_FATIGUE], ids=['multi', 'single'])
def test_mean_fitness_under_full_recruitment_decays_to_mu_min(params):
    """R = 1 throughout: every unit of type k follows mu_min + (1 - mu_min) exp(-t / T_fat)."""
    t = grid(0.6)
    out = fes_reference(params, t, np.ones_like(t), 'recruitment', np.zeros_like(t),
                        dt_ref_s=1e-4)
    shares = np.asarray(params.get('fibre_fractions', (1.0,)))
    expected = sum(share * (mu_min + (1 - mu_min) * np.exp(-t / tau))
                   for share, mu_min, tau in zip(shares, params['fatigue_min'],
                                                 params['tau_fatigue_s']))
    np.testing.assert_allclose(out['mean_fitness'], expected, rtol=0, atol=1e-12)


@pytest.mark.parametrize('params', [FATIGUE, SINGLE_FATIGUE], ids=['multi', 'single'])
def test_fitness_recovers_towards_one_once_stimulation_stops(params):
    """R = 1 until T, then 0: from mu(T) each unit follows
    1 - (1 - mu(T)) exp(-(t - T) / T_rec)."""
    stop = 0.3
    t = grid(0.8)
    out = fes_reference(params, t, held(t, [(0.0, 1.0), (stop, 0.0)]), 'recruitment',
                        np.zeros_like(t), dt_ref_s=1e-4)
    shares = np.asarray(params.get('fibre_fractions', (1.0,)))
    expected = 0.0
    for share, mu_min, t_fat, t_rec in zip(shares, params['fatigue_min'],
                                           params['tau_fatigue_s'], params['tau_recovery_s']):
        mu_stop = mu_min + (1 - mu_min) * math.exp(-stop / t_fat)
        expected = expected + share * np.where(
            t < stop, mu_min + (1 - mu_min) * np.exp(-t / t_fat),
            1 - (1 - mu_stop) * np.exp(-(t - stop) / t_rec))
    np.testing.assert_allclose(out['mean_fitness'], expected, rtol=0, atol=1e-12)


#: l_rest = l_opt puts the resting CE at FL = 1, so F0 at t = 0 is sum of f_max.
AT_OPTIMUM = {'l_rest_m': 0.1, 'l_opt_m': 0.1}


@pytest.mark.parametrize('order', ['size', 'reverse', 'random'])
def test_fibre_force_weights_sum_to_f_iso_max_at_optimal_length(order):
    t = grid(0.002)
    params = dict(AT_OPTIMUM, fibre_fractions=(0.2, 0.5, 0.3), fibre_force_weights=(1.0, 2.5, 4.0),
                  recruitment_order=order, recruitment_seed=7)
    out = fes_reference(params, t, np.ones_like(t), 'recruitment', np.zeros_like(t))
    assert out['eff_f_iso_n'][0] == pytest.approx(F_ISO, rel=1e-12)


@pytest.mark.parametrize('order, first_half_n',
                         [('size', F_ISO * 1 / 4), ('reverse', F_ISO * 3 / 4)])
def test_recruitment_order_picks_which_fibre_type_comes_first(order, first_half_n):
    """Two equal blocks with weights 1 and 3: the first 500 units give 1/4 or 3/4 of f_iso_max."""
    t = grid(0.002)
    params = dict(AT_OPTIMUM, fibre_fractions=(0.5, 0.5), fibre_force_weights=(1.0, 3.0),
                  recruitment_order=order)
    out = fes_reference(params, t, np.full_like(t, 0.5), 'recruitment', np.zeros_like(t))
    assert out['eff_f_iso_n'][0] == pytest.approx(first_half_n, rel=1e-12)


@pytest.mark.parametrize('recruitment', [0.1, 1.0])
def test_length_spread_covers_its_range_evenly_in_any_prefix(recruitment):
    """With c_p spread evenly over [1 - s, 1 + s] and FL(x) = 1 + FL_A (x - 1)^2,
    the recruited units give M/N f_iso_max (1 + FL_A s^2 / 3). The golden-ratio
    points are within 0.003 of that mean square for M >= 100 (measured 2.9e-3
    at M = 100); the test allows 0.01."""
    s = 0.3
    t = grid(0.002)
    out = fes_reference(dict(AT_OPTIMUM, unit_length_spread=s), t, np.full_like(t, recruitment),
                        'recruitment', np.zeros_like(t))
    expected = recruitment * F_ISO * (1 + FL_A * s ** 2 / 3)
    assert out['eff_f_iso_n'][0] == pytest.approx(expected,
                                                  abs=recruitment * F_ISO * -FL_A * s ** 2 * 0.01)


def test_single_muscle_is_released_when_n_a_falls_below_one_half():
    """Slow deactivation from a = 1 at 0.2 s: a = exp(-(t - 0.2) / tau) until
    N a < 1/2, at 0.2 + tau ln(2N); from then a = 0 and the CE is free."""
    tau = 0.05
    t = grid(0.8)
    out = fes_reference({'units': 'single', 'tau_deact_s': tau}, t,
                        held(t, [(0.0, 1.0), (0.2, 0.0)]), 'recruitment', np.full_like(t, 0.002))
    release = 0.2 + tau * math.log(2 * N)
    decay = np.exp(-(t - 0.2) / tau)
    expected = np.where(t < 0.2, 1.0, np.where(t < release, decay, 0.0))
    np.testing.assert_allclose(out['recruitment'], expected, rtol=0, atol=1e-12)
    after = t >= release
    assert np.all(out['eff_f_iso_n'][after] == 0.0) and np.all(out['eff_f_iso_n'][~after] > 0.0)
    np.testing.assert_allclose(out['l_ce_m'][after], 0.125 + 0.002, rtol=0, atol=1e-15)


@pytest.mark.parametrize('curve, params, expected', [
    ('linear', {}, [0.0, 0.2, 0.2628, 0.651, 1.0]),
    ('threshold_linear', {'pw_threshold_s': 100e-6}, [0.0, 0.0, 31.4 / 400, 225.5 / 400, 1.0]),
    ('exponential', {'pw_threshold_s': 131.4e-6},
     [0.0, 0.0, 0.0, 1 - math.exp(-1.0), 1 - math.exp(-(1000 - 131.4) / 194.1)]),
])
def test_command_is_the_recruitment_curve_of_the_pulse_width(curve, params, expected):
    """u = PW / PW_max, (PW - PW_th) / (PW_max - PW_th) or
    1 - exp(-(PW - PW_th) / PW_scale), clipped to [0, 1]."""
    pulse_widths = np.array([0.0, 100e-6, 131.4e-6, 325.5e-6, 1000e-6])
    t = np.arange(pulse_widths.size) * DT
    out = fes_reference(dict(params, recruitment_curve=curve), t, pulse_widths, 'pulse_width_s',
                        np.zeros_like(t), dt_ref_s=1e-4)
    np.testing.assert_allclose(out['command'], expected, rtol=1e-12, atol=1e-15)


def test_sub_step_that_does_not_divide_the_sample_step_is_a_value_error():
    t = grid(0.01)
    with pytest.raises(ValueError, match='`dt_ref_s` must divide the sample step'):
        fes_reference({}, t, np.zeros_like(t), 'recruitment', np.zeros_like(t), dt_ref_s=3e-4)


def test_unknown_parameter_is_a_value_error():
    t = grid(0.01)
    with pytest.raises(ValueError, match='unknown parameter `tau_act`'):
        fes_reference({'tau_act': 0.01}, t, np.zeros_like(t), 'recruitment', np.zeros_like(t))


def test_halving_the_sub_step_changes_the_force_by_under_0_3_mN():
    """The reference's own error, first order in dt_ref (recruitment events
    placed on the nearest sub-step boundary, F0 held over a sub-step): 10 us
    vs 20 us on the exponential curve with a 25 ms delay and 60/110 ms
    activation; measured 1.0e-4 N."""
    t = grid(0.6)
    pw = held(t, [(0.05, 300e-6), (0.3, 120e-6), (0.45, 0.0)])
    dl = np.interp(t, [0.0, 0.1, 0.3, 0.5], [0.0, 0.0, 0.004, -0.001])
    params = {'recruitment_curve': 'exponential', 'pw_threshold_s': 100e-6, 'emd_s': 0.025,
              'tau_act_s': 0.06, 'tau_deact_s': 0.11}
    fine, coarse = (fes_reference(params, t, pw, 'pulse_width_s', dl, dt_ref_s=h)['force_n']
                    for h in (1e-5, 2e-5))
    assert np.max(np.abs(fine - coarse)) <= 3e-4
