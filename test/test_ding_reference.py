"""The pulse-driven muscle (``activation_model: ding2003``) against the
independent fine-step reference (test/ding_reference.py), and the reference
against exact results.

The production model runs at its default 1 kHz sample rate; the reference
integrates with RK4 at 0.1 ms sub-steps cut exactly at every pulse. Every
production comparison must agree within :data:`ACCURACY_N` in force.
Ding et al. 2003 (J Biomech 36: 1345-1356; Muscle Nerve 2003) give the
activation; the Lapicque (Weiss) strength-duration law the recruitment of a
pulse of a given current.
"""
import math

import numpy as np
import pytest

from ding_reference import (DING_A_N_PER_S, channel_territories, ding_force, ding_reference,
                            equivalent_pulse_width, train_pulses)
from fes_reference import unit_layout
from hill_muscle_ros.model import Muscle, MuscleParams, simulate
from hill_muscle_ros.model.protocol import PulseProtocol
from hill_muscle_ros.model.stimulator import ChannelCommand

#: [N] the accuracy target at the default 1 ms step.
ACCURACY_N = 0.1
#: [-] mean fitness: the force tolerance's share of the muscle (0.1 N of 45 N
#: is 2.2e-3), halved.
FITNESS_ACCURACY = 1e-3
#: [s] sample step of the production model's default rate (1 kHz).
DT = 1e-3
#: [s] the reference's RK4 sub-step (its own error at 1e-4 s is below 1e-6 N:
#: test_reference_halving_the_sub_step_changes_the_force_by_under_1_uN).
DT_REF = 1e-4
#: Ding et al. 2003's time constants and Km, R0 - Km (the parameters' defaults).
TAU_C, TAU1, TAU2, KM, R0_OFFSET = 0.020, 0.050957, 0.060, 0.103, 1.04
#: [N] A (tau1 + tau2): Ding's force at infinite frequency, 3009 N/s x 0.110957 s.
F_DING_MAX = DING_A_N_PER_S * (TAU1 + TAU2)
#: The pulse model on the paper's muscle.
DING = {'activation_model': 'ding2003'}


def _knots(steps, duration_s: float) -> list[list[float]]:
    """Protocol knots of a piecewise-constant track [(t_from, value), ...]."""
    if isinstance(steps, (int, float)):
        return [[0.0, float(steps)]]
    knots = []
    for j, (t_from, value) in enumerate(steps):
        knots.append([float(t_from), float(value)])
        end = steps[j + 1][0] if j + 1 < len(steps) else duration_s
        knots.append([float(end), float(value)])
    return knots


def _channel_mapping(channel: dict, duration_s: float) -> dict:
    """A protocol's channel entry from a channel given as step tracks."""
    out = {key: _knots(channel[key], duration_s) for key in ('frequency_hz', 'pulse_width_s')}
    if channel.get('current_a') is not None:
        out['current_a'] = _knots(channel['current_a'], duration_s)
    for key in ('mode', 'burst_interval_s'):
        if key in channel:
            out[key] = channel[key]
    return out


def _reference_pulses(channel: dict, duration_s: float) -> list[tuple]:
    return train_pulses(duration_s, channel['frequency_hz'], channel['pulse_width_s'],
                        channel.get('current_a'), channel.get('mode', 'single'),
                        channel.get('burst_interval_s', 0.005))


def _protocol(channels: list[dict], duration_s: float, dl_mt=None) -> PulseProtocol:
    return PulseProtocol.from_mapping({
        'name': 'ding reference', 'duration_s': duration_s,
        'channels': [_channel_mapping(ch, duration_s) for ch in channels],
        'dl_mt_m': dl_mt if dl_mt is not None else [[0.0, 0.0]]})


def _run_both(params: dict, channels: list[dict], duration_s: float, dl_mt=None):
    """The production model (simulate at 1 kHz) and the reference on one protocol.

    :return: the production's SimulationResult and the reference's outputs
    """
    protocol = _protocol(channels, duration_s, dl_mt)
    result = simulate(protocol, MuscleParams(**params))
    dl = np.asarray(protocol.dl_mt(result.t_s), dtype=float)
    ref = ding_reference(params, [_reference_pulses(ch, duration_s) for ch in channels], dl,
                         dt_s=DT, dt_ref_s=DT_REF)
    return result, ref


def _max_diff(a, b) -> float:
    return float(np.max(np.abs(np.asarray(a) - np.asarray(b))))


#: A stretch and release while a train runs (and after it stops).
STRETCH = [[0.0, 0.0], [0.3, 0.0], [0.5, 0.004], [0.8, 0.004], [1.0, 0.0]]


# -- the production model against the reference ----------------------------------------


@pytest.mark.parametrize('frequency_hz', [10.0, 33.0, 80.0])
def test_single_pulse_trains_give_the_reference_force(frequency_hz):
    """60 % of the units (PW 0.3 ms of 0.5 ms) at 10, 33 and 80 Hz for 0.7 s,
    then relaxation, under a stretch and release. Measured 7.0e-5, 2.7e-5 and
    2.7e-5 N."""
    channel = {'frequency_hz': frequency_hz, 'pulse_width_s': [(0.0, 0.0003), (0.7, 0.0)]}
    result, ref = _run_both(DING, [channel], 1.0, STRETCH)
    assert _max_diff(result.force_n, ref['force_n']) <= ACCURACY_N


@pytest.mark.parametrize('mode, frequency_hz, burst_interval_s',
                         [('doublet', 20.0, 0.005), ('triplet', 15.0, 0.005),
                          ('doublet', 25.0, 0.012)])
def test_doublets_and_triplets_give_the_reference_force(mode, frequency_hz, burst_interval_s):
    """Bursts of 2 or 3 pulses 5 ms (or 12 ms) apart: the later pulses of a
    burst enhance CN by R_i = 1 + (R0 - 1) exp(-interval / tau_c). Measured
    3.7e-5, 3.8e-5 and 3.5e-5 N."""
    channel = {'frequency_hz': frequency_hz, 'pulse_width_s': [(0.0, 0.0004), (0.6, 0.0)],
               'mode': mode, 'burst_interval_s': burst_interval_s}
    result, ref = _run_both(DING, [channel], 0.9)
    assert _max_diff(result.force_n, ref['force_n']) <= ACCURACY_N


#: 20 Hz, then 50 Hz from 0.51 s: the burst at 0.55 s reads 50 Hz, the next is
#: at 0.57 s (the step is off the burst grid, so no rounding decides it).
FREQUENCY_STEP = {'frequency_hz': [(0.0, 20.0), (0.51, 50.0)], 'pulse_width_s': 0.00035}


def test_a_frequency_step_gives_the_reference_force():
    """Measured 3.1e-5 N."""
    result, ref = _run_both(DING, [FREQUENCY_STEP], 1.0)
    assert _max_diff(result.force_n, ref['force_n']) <= ACCURACY_N


def test_a_frequency_step_by_stimulate_and_step_trains_gives_the_reference_force():
    """The same step given live: ``stimulate`` at 0 s and at 0.51 s (the
    schedule carries over), ``step_trains`` every millisecond. Measured 3.1e-5 N."""
    muscle = Muscle(MuscleParams(**DING))
    n_steps = 1000
    force = [muscle.outputs().force_n]
    muscle.stimulate([ChannelCommand(1, 'single', 0.00035, None, 20.0)])
    for k in range(n_steps):
        if k == 510:
            muscle.stimulate([ChannelCommand(1, 'single', 0.00035, None, 50.0)])
        force.append(muscle.step_trains(0.0, DT).force_n)
    ref = ding_reference(DING, [_reference_pulses(FREQUENCY_STEP, 1.0)], np.zeros(n_steps + 1),
                         dt_s=DT, dt_ref_s=DT_REF)
    assert _max_diff(force, ref['force_n']) <= ACCURACY_N


def test_stiff_tendon_at_optimal_length_gives_dings_force_in_newtons():
    """k_SE 1e10 N/m, the CE at l_opt and f_iso_max = A (tau1 + tau2) = 333.87 N,
    every unit recruited: the muscle's force is Ding's F of the original model,
    F' = A x - F / (tau1 + tau2 x). (The Hill muscle lags F by about
    (F0 + a) / b F' / k_SE: 2e-3 N at k_SE 1e10 N/m.) Measured 6.9e-4 N of 276 N."""
    params = dict(DING, f_iso_max_n=F_DING_MAX, k_se_n_per_m=1e10, l_rest_m=0.1, l_opt_m=0.1)
    channel = {'frequency_hz': [(0.0, 12.0), (0.4, 40.0)], 'pulse_width_s': [(0.0, 0.0005),
                                                                             (0.8, 0.0)]}
    protocol = _protocol([channel], 1.0)
    result = simulate(protocol, MuscleParams(**params))
    times = [t for t, _, _ in _reference_pulses(channel, 1.0)]
    _, force = ding_force(times, result.t_s, DING_A_N_PER_S, TAU_C, TAU1, TAU2, KM, R0_OFFSET)
    assert _max_diff(result.force_n, force) <= ACCURACY_N


#: Two channels of 40 % and 60 % of the units, over two fibre types of
#: different force (so which units of a territory come first matters).
TWO_CHANNELS = dict(DING, channel_fractions=[0.4, 0.6], channel_seed=3,
                    fibre_fractions=[0.5, 0.5], fibre_force_weights=[1.0, 3.0],
                    f_iso_max_n=120.0)


def test_two_channels_with_their_own_trains_recruit_their_own_territories():
    """Channel 1: 25 Hz singles, its width stepping up and down; channel 2: a
    40 Hz doublet train starting at 0.2 s. Each recruits only its territory.
    Measured 1.5e-3 N."""
    channels = [
        {'frequency_hz': 25.0,
         'pulse_width_s': [(0.0, 0.0002), (0.3, 0.00045), (0.6, 0.0001)]},
        {'frequency_hz': 40.0, 'pulse_width_s': [(0.0, 0.0), (0.2, 0.0003), (0.75, 0.0)],
         'mode': 'doublet'},
    ]
    result, ref = _run_both(TWO_CHANNELS, channels, 1.0, STRETCH)
    assert _max_diff(result.force_n, ref['force_n']) <= ACCURACY_N


def test_pulse_current_recruits_by_the_strength_duration_law():
    """Two channels with currents: 20 mA then 30 mA at 0.4 ms on channel 1
    (PW_eq = c k / (I_ref - k), k = I PW / (PW + c)); 60 mA on channel 2,
    beyond I_ref at 0.3 ms, which recruits the whole territory. Measured 6.7e-5 N."""
    params = dict(TWO_CHANNELS, chronaxie_s=459e-6, current_ref_a=0.040)
    channels = [
        {'frequency_hz': 30.0, 'pulse_width_s': 0.0004,
         'current_a': [(0.0, 0.020), (0.35, 0.030)]},
        {'frequency_hz': 20.0, 'pulse_width_s': 0.0003, 'current_a': 0.060},
    ]
    result, ref = _run_both(params, channels, 0.8)
    assert _max_diff(result.force_n, ref['force_n']) <= ACCURACY_N


#: Fatigue fast enough to show within 4 s (Riener's law per unit).
FAST_FATIGUE = dict(DING, fatigue='riener', fatigue_min=[0.2], tau_fatigue_s=[3.0],
                    tau_recovery_s=[5.0])


def test_higher_frequency_tires_the_units_faster_as_the_reference():
    """4 s at 20 Hz and at 50 Hz, 60 % of the units recruited: each unit's
    fitness follows Riener's law with a = a_c(t), so 50 Hz (a near 0.87) tires
    more than 20 Hz (a near 0.70); force and mean fitness as the reference.
    Measured 2.7e-5 N and 7.8e-8 in mean fitness (0.740 and 0.690 at 4 s)."""
    final = {}
    for frequency_hz in (20.0, 50.0):
        channel = {'frequency_hz': frequency_hz, 'pulse_width_s': 0.0003}
        result, ref = _run_both(FAST_FATIGUE, [channel], 4.0)
        assert _max_diff(result.force_n, ref['force_n']) <= ACCURACY_N, frequency_hz
        assert _max_diff(result.mean_fitness, ref['mean_fitness']) <= FITNESS_ACCURACY, \
            frequency_hz
        final[frequency_hz] = result.mean_fitness[-1]
    assert final[50.0] < final[20.0] - 0.05


def test_units_are_released_one_second_after_the_last_pulse():
    """A 30 Hz train stops after 0.3 s; a stretch at 0.5-0.7 s is carried by
    the tendon (a -> 0: the CE can hardly lengthen) until 1 s after the last
    pulse (1.2667 s), when the units are released and the CE is free."""
    channel = {'frequency_hz': 30.0, 'pulse_width_s': [(0.0, 0.0004), (0.3, 0.0)]}
    dl = [[0.0, 0.0], [0.5, 0.0], [0.7, 0.004]]
    result, ref = _run_both(DING, [channel], 1.5, dl)
    assert _max_diff(result.force_n, ref['force_n']) <= ACCURACY_N
    np.testing.assert_array_equal(result.recruitment, ref['recruitment'])


def test_protocol_pulses_are_the_trains_of_the_specification():
    """The protocol's trains (start at the onset, next burst 1 / f after the
    previous, f read there, PW and I of a burst's first pulse) are the
    reference's, to float rounding."""
    channels = [FREQUENCY_STEP,
                {'frequency_hz': 25.0, 'pulse_width_s': [(0.0, 0.0), (0.2, 0.0003), (0.5, 0.0),
                                                         (0.6123, 0.0002)],
                 'mode': 'triplet', 'current_a': [(0.0, 0.02), (0.7, 0.03)]}]
    protocol = _protocol(channels, 1.0)
    for channel, pulses in zip(channels, protocol.pulses()):
        expected = _reference_pulses(channel, 1.0)
        assert len(pulses) == len(expected)
        np.testing.assert_allclose([p.time_s for p in pulses], [e[0] for e in expected],
                                   rtol=0, atol=1e-12)
        assert [p.pulse_width_s for p in pulses] == [e[1] for e in expected]
        assert [p.current_a for p in pulses] == [e[2] for e in expected]


# -- the reference against exact results ------------------------------------------------


def _cn_exact(pulse_times, t):
    """CN of Ding's Eq. in closed form: sum_i R_i (t - t_i) / tau_c exp(-(t - t_i) / tau_c)."""
    t = np.asarray(t, dtype=float)
    cn = np.zeros_like(t)
    r0 = KM + R0_OFFSET
    for i, t_i in enumerate(pulse_times):
        r_i = 1.0 if i == 0 else 1.0 + (r0 - 1.0) * math.exp(-(t_i - pulse_times[i - 1]) / TAU_C)
        s = np.clip(t - t_i, 0.0, None)
        cn += r_i * s / TAU_C * np.exp(-s / TAU_C)
    return cn


def test_reference_cn_after_one_pulse_is_t_over_tau_c_times_exp():
    """CN(t) = (t / tau_c) exp(-t / tau_c) after one pulse at 0."""
    t = np.arange(301) * DT
    out = ding_reference(DING, [[(0.0, 0.0003, None)]], np.zeros_like(t), dt_ref_s=DT_REF)
    np.testing.assert_allclose(out['cn'][:, 0], t / TAU_C * np.exp(-t / TAU_C), rtol=0,
                               atol=1e-10)


def test_reference_cn_of_a_doublet_train_sums_the_enhanced_pulse_responses():
    """Each pulse adds R_i (t - t_i) / tau_c exp(-(t - t_i) / tau_c) with
    R_i = 1 + (R0 - 1) exp(-(t_i - t_(i-1)) / tau_c); pulses off the sample grid."""
    pulses = train_pulses(0.4, 17.0, 0.0003, mode='doublet', burst_interval_s=0.0063)
    t = np.arange(401) * DT
    out = ding_reference(DING, [pulses], np.zeros_like(t), dt_ref_s=DT_REF)
    np.testing.assert_allclose(out['cn'][:, 0], _cn_exact([p[0] for p in pulses], t), rtol=0,
                               atol=1e-9)


def test_reference_activation_is_dings_force_over_a_times_tau1_plus_tau2():
    """a of the muscle reference (normalised, with the Hill muscle) times
    A (tau1 + tau2) is Ding's F of the separate unnormalised integration; with
    l_rest = l_opt and every unit recruited, F0 is that force too."""
    params = dict(DING, f_iso_max_n=F_DING_MAX, l_rest_m=0.1)
    pulses = train_pulses(0.6, [(0.0, 10.0), (0.3, 60.0)], 0.0005)
    t = np.arange(601) * DT
    out = ding_reference(params, [pulses], np.zeros_like(t), dt_ref_s=DT_REF)
    cn, force = ding_force([p[0] for p in pulses], t, dt_ref_s=DT_REF)
    np.testing.assert_allclose(out['cn'][:, 0], cn, rtol=0, atol=1e-12)
    np.testing.assert_allclose(out['activation'][:, 0] * F_DING_MAX, force, rtol=0, atol=1e-9)
    np.testing.assert_allclose(out['eff_f_iso_n'], force, rtol=0, atol=1e-9)


def test_reference_activation_stays_below_its_infinite_frequency_limit():
    """100 Hz doublets (a pulse every 5 ms, CN near saturation): 0 <= a < 1,
    and a stays below the steady state of the largest x reached,
    x (tau1 + tau2 x) / (tau1 + tau2) < 1. Measured a at most 0.965."""
    pulses = train_pulses(1.0, 100.0, 0.0005, mode='doublet', burst_interval_s=0.005)
    t = np.arange(1001) * DT
    out = ding_reference(DING, [pulses], np.zeros_like(t), dt_ref_s=DT_REF)
    a = out['activation'][:, 0]
    x_max = np.max(out['cn'][:, 0] / (KM + out['cn'][:, 0]))
    assert np.all(a >= 0.0) and a.max() < 1.0
    assert a.max() <= x_max * (TAU1 + TAU2 * x_max) / (TAU1 + TAU2)
    assert a.max() > 0.9   # it is near the limit


def test_reference_stiff_tendon_lags_dings_force_by_the_quasi_static_lag():
    """With the CE at l_opt, every unit recruited and f_iso_max = A (tau1 + tau2),
    F0 is Ding's F; a stiff tendon (k_SE 1e6 N/m) makes the CE move at
    v = -F' / k_SE, so Eq. 3 gives F_SE = F + slope v with slope (F + a) / b
    concentric and (F + a') / (2 b') eccentric. The lag (4.8 N at most) is
    that to first order: the rest (second order in 1 / k_SE) is 0.35 N."""
    k_se = 1e6
    params = dict(DING, f_iso_max_n=F_DING_MAX, l_rest_m=0.1, k_se_n_per_m=k_se)
    pulses = train_pulses(0.3, 40.0, 0.0005)
    t = np.arange(301) * DT
    out = ding_reference(params, [pulses], np.zeros_like(t), dt_ref_s=1e-5)
    cn, force = ding_force([p[0] for p in pulses], t, dt_ref_s=1e-5)
    x = cn / (KM + cn)
    rate = DING_A_N_PER_S * x - force / (TAU1 + TAU2 * x)      # F' [N/s]
    slope = np.where(rate > 0.0, (force + 10.0) / 0.040, (force + 10.0) / (2 * 0.030))
    lag = -slope * rate / k_se
    error = out['force_n'] - force
    assert 4.0 <= np.max(np.abs(error)) <= 6.0
    assert np.max(np.abs(error - lag)) <= 0.4


def test_reference_territories_partition_the_units_in_block_sizes():
    """Channel blocks of default_rng(seed).permutation(N) with ends
    floor(N cumsum / sum + 0.5): disjoint, covering every unit; one channel is
    the whole recruitment order."""
    p = {'n_units': 1000, 'channel_fractions': [0.25, 0.35, 0.4], 'channel_seed': 5,
         'fibre_fractions': [1.0], 'fibre_force_weights': [1.0], 'f_iso_max_n': 45.0,
         'recruitment_order': 'random', 'recruitment_seed': 2, 'unit_length_spread': 0.0,
         'fatigue_min': [0.2], 'tau_fatigue_s': [30.0], 'tau_recovery_s': [50.0]}
    order = unit_layout(p)['unit']
    territories = channel_territories(p, order)
    assert [len(x) for x in territories] == [250, 350, 400]
    np.testing.assert_array_equal(np.sort(np.concatenate(territories)), np.arange(1000))
    perm = np.random.default_rng(5).permutation(1000)
    assert set(order[territories[1]]) == set(perm[250:600])
    one = channel_territories(dict(p, channel_fractions=[1.0]), order)
    np.testing.assert_array_equal(one[0], np.arange(1000))


@pytest.mark.parametrize('pulse_width_s, current_a, expected_s', [
    (0.0003, 0.040, 0.0003),                                       # I = I_ref: PW itself
    (0.0003, None, 0.0003),                                        # no current: PW
    (0.0002, 0.030, 459e-6 * (6e-6 / 659e-6) / (0.040 - 6e-6 / 659e-6)),
    (0.0004, 0.090, math.inf),                                     # k >= I_ref: every unit
])
def test_reference_equivalent_pulse_width_follows_the_strength_duration_law(
        pulse_width_s, current_a, expected_s):
    assert equivalent_pulse_width(pulse_width_s, current_a, 0.040, 459e-6) == \
        pytest.approx(expected_s, rel=1e-12)


def test_reference_trains_start_at_onset_and_read_f_at_the_previous_burst():
    """A doublet train: bursts at 0.1 s (the onset), then 1/f after each burst
    with f read there (25 Hz, then 50 Hz from the burst at 0.3 s on); the
    stimulation stopping at 0.33 s cuts the train and a restart at 0.4 s
    starts a new one."""
    pulses = train_pulses(0.5, [(0.0, 25.0), (0.29, 50.0)],
                          [(0.0, 0.0), (0.1, 0.0002), (0.33, 0.0), (0.4, 0.0003)],
                          mode='doublet', burst_interval_s=0.005)
    bursts = [0.1, 0.14, 0.18, 0.22, 0.26, 0.30, 0.32, 0.4, 0.42, 0.44, 0.46, 0.48]
    expected = sorted(b + d for b in bursts for d in (0.0, 0.005))
    np.testing.assert_allclose([p[0] for p in pulses], expected, rtol=0, atol=1e-12)
    assert [p[1] for p in pulses] == [0.0002] * 14 + [0.0003] * 10


def test_reference_fitness_follows_riener_with_the_channels_activation():
    """60 % recruited by every pulse: the mean fitness is 0.6 mu + 0.4 (the
    others stay fresh), and mu solves mu' = (mu_min - mu) a / T_fat +
    (1 - mu)(1 - a) / T_rec with the channel's a; central differences of the
    samples against the law at the midpoints (second order in 1 ms)."""
    params = dict(DING, fatigue='riener', fatigue_min=[0.2], tau_fatigue_s=[0.5],
                  tau_recovery_s=[0.8])
    pulses = train_pulses(0.6, 40.0, [(0.0, 0.0003), (0.4, 0.0)])
    t = np.arange(601) * DT
    out = ding_reference(params, [pulses], np.zeros_like(t), dt_ref_s=DT_REF)
    mu = (out['mean_fitness'] - 0.4) / 0.6
    a = out['activation'][:, 0]
    rate = (mu[2:] - mu[:-2]) / (2 * DT)
    law = (0.2 - mu[1:-1]) * a[1:-1] / 0.5 + (1.0 - mu[1:-1]) * (1.0 - a[1:-1]) / 0.8
    assert mu[-1] < 0.8
    assert np.max(np.abs(rate - law)) <= 2e-3   # measured 5.0e-4 /s


def test_reference_releases_the_units_one_second_after_the_last_pulse():
    """The recruitment drops to 0 at the first sample after t_last + 1 s and the
    CE is free there: l_CE = l_rest + dl_MT and the force is k_PE dl_MT."""
    pulses = train_pulses(0.3, 30.0, 0.0004)
    t = np.arange(1501) * DT
    dl = np.interp(t, [0.0, 0.5, 0.7], [0.0, 0.0, 0.004])
    out = ding_reference(DING, [pulses], dl, dt_ref_s=DT_REF)
    release = pulses[-1][0] + 1.0
    after = t >= release
    assert np.all(out['recruitment'][~after & (t > 0)] == 0.8)
    assert np.all(out['recruitment'][after] == 0.0)
    np.testing.assert_allclose(out['l_ce_m'][after], 0.125 + dl[after], rtol=0, atol=1e-15)
    np.testing.assert_allclose(out['force_n'][after], 1000.0 * dl[after], rtol=0, atol=1e-12)
    assert out['force_n'][~after][-1] > 10.0    # the tendon held the stretch until then


def test_reference_halving_the_sub_step_changes_the_force_by_under_1_uN():
    """50 Hz doublets under a stretch: RK4 at 0.1 ms against 0.05 ms. Measured
    8.8e-8 N (0.2 ms against 0.1 ms: 1.0e-6 N)."""
    pulses = train_pulses(0.4, 50.0, 0.0004, mode='doublet')
    t = np.arange(401) * DT
    dl = np.interp(t, [0.0, 0.1, 0.3, 0.4], [0.0, 0.0, 0.004, 0.001])
    coarse, fine = (ding_reference(DING, [pulses], dl, dt_ref_s=h)['force_n']
                    for h in (1e-4, 5e-5))
    assert _max_diff(coarse, fine) <= 1e-6
