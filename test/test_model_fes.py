"""The FES muscle (delay, activation, recruitment curves, fatigue, fibre types,
unit lengths): laws checked against their closed forms and against the paper's
model where they must reduce to it."""
import math

import numpy as np
import pytest
from hypothesis import given, strategies as st

from hill_muscle_ros.model import Muscle, MuscleParams, Protocol, simulate
from hill_muscle_ros.model.equations import fes_velocity, quasi_static_force
from hill_muscle_ros.model.protocol import commands_from_pulse_widths
from hill_muscle_ros.model.stimulus import command_from_pulse_width
from hill_muscle_ros.resources import protocol_path

#: [N] agreement of two paths that compute the same model (rounding only).
SAME_MODEL_TOL_N = 1e-9
#: [-] the same for dimensionless outputs (activation, fitness).
SAME_MODEL_TOL = 1e-12
VARIANTS = [(u, l) for u in ('multi', 'single') for l in ('initial', 'instantaneous')]


def _protocol(name):
    return Protocol.from_yaml(protocol_path(name))


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


def test_an_array_of_pulse_widths_gets_each_widths_own_command():
    p = MuscleParams(recruitment_curve='exponential', pw_threshold_s=131.4e-6,
                     pw_scale_s=194.1e-6)
    widths = np.array([[0.0, 370e-6, 370e-6], [120e-6, 700e-6, 370e-6]])
    u = commands_from_pulse_widths(widths, p)
    assert u.shape == widths.shape
    assert u.tolist() == [[command_from_pulse_width(w, p) for w in row] for row in widths]


def test_a_bad_width_in_an_array_is_named_with_its_value():
    with pytest.raises(ValueError, match='`quadriceps` must be finite and non-negative, '
                                         'got -1e-06'):
        commands_from_pulse_widths([300e-6, -1e-6, 300e-6], MuscleParams(), 'quadriceps')


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


def test_single_muscle_released_below_one_unit_jumps_back_with_instantaneous_activation():
    """Deactivating towards a command below half a unit (N a < 0.5) releases a
    single muscle at that crossing; with tau_act = 0 it is back at the command
    at once, with its force, where it would rise from 0 with tau_act > 0."""
    p = MuscleParams(units='single', n_units=1, tau_act_s=0.0, tau_deact_s=0.006)
    m = Muscle(p)
    for _ in range(20):
        m.step(0.9, 0.0, 1e-3)
    low = 0.3   # below the release level 0.5 / N
    for _ in range(20):
        out = m.step(low, 0.0, 1e-3)
    # 0.9 decays to 0.5 in 6 ms ln(0.6 / 0.2) = 6.6 ms: released, then at the command.
    assert out.recruitment == low and out.n_recruited == 1
    assert math.isfinite(out.force_n) and out.eff_f_iso_n > 0.0


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


# -- the batch shares the scalar engine ---------------------------------------------------

#: One muscle per FES feature, plus all of them at once and a paper muscle.
FEATURES = {
    'curve+delay+activation': dict(recruitment_curve='exponential', emd_s=0.025,
                                   tau_act_s=0.06, tau_deact_s=0.11),
    'relative fv': dict(fv_scaling='relative', tau_act_s=0.02, tau_deact_s=0.05),
    'fatigue': dict(fatigue='riener', tau_fatigue_s=[0.5], tau_recovery_s=[0.8]),
    'fibre types random': dict(fibre_fractions=[0.4, 0.6], fibre_force_weights=[1.0, 2.5],
                               recruitment_order='random', recruitment_seed=3,
                               fatigue='riener', tau_fatigue_s=[2.0, 0.4]),
    'length spread': dict(unit_length_spread=0.3, length='instantaneous'),
    'single fatigue': dict(units='single', fatigue='riener', tau_fatigue_s=[0.5],
                           tau_act_s=0.03, tau_deact_s=0.05),
    'paper': dict(),
}


def test_batch_equals_separate_muscles_on_every_feature_to_1e_9_newton():
    from hill_muscle_ros.model.muscle.batch import MuscleBatch
    params = [MuscleParams(**kw) for kw in FEATURES.values()]
    batch = MuscleBatch(params)
    singles = [Muscle(p) for p in params]
    rng = np.random.default_rng(7)
    command = 0.0
    for k in range(1500):
        if k % 100 == 0:
            command = float(rng.choice([0.0, rng.uniform(0.05, 1.0)]))
        dl = 0.004 * math.sin(2 * math.pi * k / 700)
        out = batch.step(command, dl, 1e-3)
        for i, muscle in enumerate(singles):
            ref = muscle.step(command, dl, 1e-3)
            assert abs(out.force_n[i] - ref.force_n) <= SAME_MODEL_TOL_N, \
                (list(FEATURES)[i], k)
            # The batch's compiled engine runs the compiled FES muscle, which
            # agrees with the single Muscle to rounding, not bit for bit.
            assert abs(out.recruitment[i] - ref.recruitment) <= SAME_MODEL_TOL
            assert abs(out.mean_fitness[i] - ref.mean_fitness) <= SAME_MODEL_TOL


# -- fatigue --------------------------------------------------------------------------------

def _held(params, level, duration_s, rate_hz=100.0):
    protocol = Protocol.from_mapping({'name': 'held', 'duration_s': duration_s,
                                      'recruitment': [[0.0, level]],
                                      'dl_mt_m': [[0.0, 0.0]]})
    return simulate(protocol, params, rate_hz)


@pytest.mark.parametrize('units', ['multi', 'single'])
def test_fatigue_under_full_recruitment_decays_to_fatigue_min_with_tau_fatigue(units):
    mu_min, tau = 0.3, 4.0
    result = _held(MuscleParams(units=units, fatigue='riener', fatigue_min=[mu_min],
                                tau_fatigue_s=[tau]), 1.0, 20.0)
    expected = mu_min + (1.0 - mu_min) * np.exp(-result.t_s / tau)
    np.testing.assert_allclose(result.mean_fitness, expected, rtol=0, atol=1e-12)


def test_recovery_of_a_released_unit_follows_tau_recovery():
    mu_min, tau_f, tau_r = 0.2, 2.0, 5.0
    params = MuscleParams(fatigue='riener', fatigue_min=[mu_min], tau_fatigue_s=[tau_f],
                          tau_recovery_s=[tau_r])
    protocol = Protocol.from_mapping({'name': 'on-off', 'duration_s': 20.0,
                                      'recruitment': [[0.0, 1.0], [3.0, 1.0], [3.0, 0.0]],
                                      'dl_mt_m': [[0.0, 0.0]]})
    result = simulate(protocol, params, 100.0)
    mu_release = mu_min + (1.0 - mu_min) * math.exp(-3.0 / tau_f)
    after = result.t_s >= 3.0
    expected = 1.0 - (1.0 - mu_release) * np.exp(-(result.t_s[after] - 3.0) / tau_r)
    np.testing.assert_allclose(result.mean_fitness[after], expected, rtol=0, atol=1e-12)


def _fatigued_profile(order='size', fractions=(1.0,), level=0.5, duration_s=30.0):
    muscle = Muscle(MuscleParams(fatigue='riener', fibre_fractions=fractions,
                                 recruitment_order=order))
    muscle.set_recruitment(level)
    for _ in range(int(duration_s * 100)):
        muscle.step(level, 0.0, 0.01)
    return muscle.fitness_profile()


def test_units_recruited_only_at_high_r_stay_fresh():
    mu = _fatigued_profile(level=0.5)
    assert np.all(mu[500:] == 1.0)
    assert np.all(mu[:500] < 0.6)


def test_the_first_units_of_the_order_tire_first():
    # Ramp up: unit j is recruited at an instant that grows with j, so it has
    # been working for less time; its fitness must not be lower than unit j-1's.
    muscle = Muscle(MuscleParams(fatigue='riener'))
    for k in range(2000):
        muscle.step(k / 2000, 0.0, 0.01)
    mu = muscle.fitness_profile()
    assert np.all(np.diff(mu) >= 0.0)
    assert mu[0] < mu[-2]


# -- the protocol player's mapping ---------------------------------------------------------

def test_pulse_width_for_command_inverts_each_curve():
    from hill_muscle_ros.model.stimulus import pulse_width_for_command
    for curve in ('linear', 'threshold_linear', 'exponential'):
        p = MuscleParams(recruitment_curve=curve, pw_threshold_s=100e-6)
        for u in (0.1, 0.5, 0.9):
            pw = pulse_width_for_command(u, p)
            assert command_from_pulse_width(pw, p) == pytest.approx(u, abs=1e-12)


def test_full_recruitment_has_no_pulse_width_on_the_exponential_curve():
    from hill_muscle_ros.model.stimulus import pulse_width_for_command
    with pytest.raises(ValueError, match='infinite pulse width'):
        pulse_width_for_command(1.0, MuscleParams(recruitment_curve='exponential'))


def test_player_sends_the_command_of_the_curve_on_the_recruitment_output():
    protocol = Protocol.from_mapping({'name': 'pw', 'duration_s': 1.0,
                                      'pulse_width_s': [[0.0, 300e-6]],
                                      'dl_mt_m': [[0.0, 0.0]]})
    p = MuscleParams(recruitment_curve='exponential', pw_threshold_s=131.4e-6)
    expected = 1.0 - math.exp(-(300e-6 - 131.4e-6) / 194.1e-6)
    assert protocol.stimulation_command(0.5, 'recruitment', p) == pytest.approx(expected,
                                                                                abs=1e-15)
    assert protocol.stimulation_command(0.5, 'pulse_width', p) == 300e-6


# -- stiffness ------------------------------------------------------------------------------

def test_relative_fv_scaling_is_stable_at_1khz_while_f0_decays():
    """With relative F-V constants the CE relaxes at a rate growing as 1 / F0;
    the step is cut where a fixed 1 ms RK4 step would oscillate (found by
    comparing with a 20 kHz run: 0.85 N off, f_SE up to 24 F0, before)."""
    protocol = Protocol.from_mapping({
        'name': 'x', 'duration_s': 2.0, 'dl_mt_m': [[0.0, 0.0]],
        'recruitment': [[0.1, 0.0], [0.1, 1.0], [1.0, 1.0], [1.0, 0.0]]})
    params = MuscleParams(tau_act_s=0.06, tau_deact_s=0.11, fv_scaling='relative')
    coarse, fine = simulate(protocol, params, 1000.0), simulate(protocol, params, 20000.0)
    np.testing.assert_allclose(coarse.f_se_n, fine.f_se_n[::20], rtol=0, atol=0.05)


def test_single_relative_muscle_rising_from_zero_has_no_force_spike():
    """A single unit's activation rises from exactly 0, so F0 is 0 at the start
    of the step and the CE's relaxation rate must be taken inside the step too:
    taken at the start only, a stiff tendon spiked to 21.6 N at 1 kHz where a
    20 kHz run gives 0.003 N. Within 0.1 N of the 20 kHz run now (0.06 N at
    the first millisecond of force, where F0 is a few mN)."""
    params = MuscleParams(units='single', fv_scaling='relative', tau_act_s=0.025,
                          tau_deact_s=0.025, k_se_n_per_m=962000.0)
    protocol = Protocol.from_mapping({'name': 'rise', 'duration_s': 0.5,
                                      'dl_mt_m': [[0.0, 0.01]],
                                      'recruitment': [[0.0, 0.0], [0.1, 0.0], [0.3, 0.3]]})
    coarse, fine = simulate(protocol, params, 1000.0), simulate(protocol, params, 20000.0)
    np.testing.assert_allclose(coarse.f_se_n, fine.f_se_n[::20], rtol=0, atol=0.1)


@given(f0=st.floats(1e-3, 3000.0), share=st.floats(-0.95, 0.95), relative=st.booleans())
def test_the_quasi_static_force_is_the_one_whose_velocity_is_the_mtus(f0, share, relative):
    """quasi_static_force is Eq. 3 itself: the force at which the inverted
    Eq. 3 (fes_velocity, the CE's ODE) gives back the velocity, over the whole
    range from the fastest shortening to the fastest lengthening, with absolute
    and F0-relative constants."""
    a, b, a_ecc, b_ecc, f_iso_max, k_se = 375.0, 0.235, 375.0, 0.176, 1500.0, 962000.0
    scale = f0 / f_iso_max if relative else 1.0
    v_max = b * f0 / (a * scale) if share < 0.0 else b_ecc * f0 / (a_ecc * scale)
    v = share * v_max
    f = quasi_static_force(v, f0, a, b, a_ecc, b_ecc, f_iso_max, relative)
    # An SE stretched by f / k_SE with the CE at rest length carries f.
    back = fes_velocity(0.0, f / k_se, f0, k_se, 0.0, a, b, a_ecc, b_ecc, f_iso_max, relative)
    assert back == pytest.approx(v, rel=1e-9, abs=1e-12)


def test_without_recruitment_the_quasi_static_force_is_zero():
    assert quasi_static_force(0.1, 0.0, 375.0, 0.235, 375.0, 0.176, 1500.0, True) == 0.0
