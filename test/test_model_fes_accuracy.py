"""Exact at 1 kHz: the FES muscle at its default 1 ms step against the
independent per-unit reference at 40 us (test/fes_reference.py), on protocols
with continuously varying pulse widths and lengths, recruitment falling to
zero and back, and long fatigue runs, for every variant and feature.

Holding R over each 1 ms step errs by 0.1-0.3 N on these protocols (and
more with faster activation); the production step splits at the recruitment
instants, so it must stay within :data:`ACCURACY_N` of the reference.
"""
import dataclasses

import numpy as np
import pytest

from fes_reference import fes_reference
from hill_muscle_ros.model import MuscleParams, Protocol, simulate

#: [N] the accuracy target at the default 1 ms step.
ACCURACY_N = 0.05
#: The base FES plant: Ding's exponential curve, a 25 ms delay, activation
#: 60 ms and deactivation 110 ms.
BASE = dict(recruitment_curve='exponential', pw_threshold_s=131.4e-6, pw_scale_s=194.1e-6,
            emd_s=0.025, tau_act_s=0.06, tau_deact_s=0.11)
#: Fatigue fast enough to matter within a few seconds.
FAST_FATIGUE = dict(fatigue='riener', fatigue_min=[0.2], tau_fatigue_s=[1.5],
                    tau_recovery_s=[2.5])

VARIANTS = {
    'multi-initial': dict(),
    'multi-instantaneous': dict(length='instantaneous'),
    'single-initial': dict(units='single'),
    'single-instantaneous': dict(units='single', length='instantaneous'),
    'relative-fv': dict(fv_scaling='relative'),
    'off-grid-delay': dict(emd_s=0.0253),
    'fatigue': FAST_FATIGUE,
    'single-fatigue': dict(FAST_FATIGUE, units='single'),
    'types-random-spread-fatigue': dict(
        FAST_FATIGUE, fibre_fractions=[0.5, 0.5], fibre_force_weights=[1.0, 2.0],
        tau_fatigue_s=[4.0, 0.8], recruitment_order='random', recruitment_seed=11,
        unit_length_spread=0.3),
    'types-reverse-spread-instantaneous': dict(
        fibre_fractions=[0.3, 0.7], recruitment_order='reverse', unit_length_spread=0.2,
        length='instantaneous'),
    'threshold-linear-instant-activation': dict(
        recruitment_curve='threshold_linear', pw_threshold_s=0.0001, emd_s=0.0, tau_act_s=0.0,
        tau_deact_s=0.0, fatigue='riener', tau_fatigue_s=[1.0]),
}


def _knots(t, values):
    return [[float(a), float(b)] for a, b in zip(t, values)]


def _varying_protocol():
    """Pulse widths and length varying all the time (the width crosses the
    threshold, so recruitment falls to zero and comes back), then steps to
    zero and back under a stretch-and-release ramp."""
    t = np.linspace(0.0, 1.2, 49)
    pw = np.clip(250e-6 + 220e-6 * np.sin(2 * np.pi * t / 0.9), 0.0, None)
    steps = [[1.2, 0.00045], [1.5, 0.00045], [1.5, 0.0], [1.7, 0.0], [1.7, 0.0003],
             [2.0, 0.0003], [2.0, 0.00015], [2.4, 0.00015]]
    t_dl = np.linspace(0.0, 1.2, 25)
    dl = 0.004 * np.sin(2 * np.pi * t_dl / 0.7) + 0.002 * t_dl
    dl_knots = _knots(t_dl, dl) + [[1.6, 0.006], [2.0, -0.003], [2.4, 0.0]]
    return Protocol.from_mapping({'name': 'varying', 'duration_s': 2.4,
                                  'pulse_width_s': _knots(t, pw) + steps,
                                  'dl_mt_m': dl_knots})


def _intermittent_protocol():
    """A long fatigue run: 1 s on, 1 s off, then a step to a higher width."""
    knots = []
    for k in range(5):
        knots += [[2.0 * k, 0.0003], [2.0 * k + 1.0, 0.0003], [2.0 * k + 1.0, 0.0],
                  [2.0 * k + 2.0, 0.0]]
    knots += [[10.0, 0.0006], [12.0, 0.0006]]
    return Protocol.from_mapping({'name': 'intermittent', 'duration_s': 12.0,
                                  'pulse_width_s': knots, 'dl_mt_m': [[0.0, 0.0]]})


#: The protocols of the accuracy test, with the reference's sub-step [s]. On
#: the varying protocol, 40 us: over every variant it is within 3.6e-3 N of a
#: 10 us reference (a fourteenth of ACCURACY_N), as close as a 20 us one is
#: (3.56e-3 N: what is left is where each grid places the events), and the
#: production step is within 5.1e-3 N of it (1.5e-3 N of the 10 us one). The
#: held-R error the test must catch is 0.33 N. 20 us took twice the CPU.
PROTOCOLS = {'varying': (_varying_protocol, 4e-5)}
#: Every protocol by name, the long fatigue run included.
MAKERS = {'varying': _varying_protocol, 'intermittent': _intermittent_protocol}

#: (protocol, variant, dt_ref_s) -> reference run. The reference depends only
#: on these (never on the production code), and a run takes 1-4 s: a test
#: that needs the same one again reuses it.
_REFERENCES = {}


def _reference(protocol_name, variant, dt_ref_s, protocol, params, t_s):
    key = (protocol_name, variant, dt_ref_s)
    if key not in _REFERENCES:
        _REFERENCES[key] = fes_reference(dataclasses.asdict(params), t_s,
                                         protocol.stimulation(t_s), protocol.stimulation_key,
                                         protocol.dl_mt(t_s), dt_ref_s=dt_ref_s)
    return _REFERENCES[key]


def _max_error(protocol_name, variant, dt_ref_s):
    protocol = MAKERS[protocol_name]()
    params = MuscleParams(**dict(BASE, **VARIANTS[variant]))
    result = simulate(protocol, params)
    ref = _reference(protocol_name, variant, dt_ref_s, protocol, params, result.t_s)
    np.testing.assert_allclose(result.recruitment, ref['recruitment'], rtol=0, atol=1e-9)
    # The reference places events on its grid (up to dt_ref / 2 off): 1e-5 covers that.
    np.testing.assert_allclose(result.mean_fitness, ref["mean_fitness"], rtol=0, atol=1e-5)
    return float(np.max(np.abs(result.force_n - ref['force_n'])))


@pytest.mark.parametrize('variant', VARIANTS)
@pytest.mark.parametrize('protocol', PROTOCOLS)
def test_force_at_1ms_is_within_0_05_newton_of_the_fine_step_reference(protocol, variant):
    _, dt_ref_s = PROTOCOLS[protocol]
    assert _max_error(protocol, variant, dt_ref_s) <= ACCURACY_N


@pytest.mark.parametrize('variant', ['fatigue', 'single-fatigue', 'types-random-spread-fatigue'])
def test_long_intermittent_fatigue_run_stays_within_0_05_newton(variant):
    # 12 s: the reference at 0.1 ms (its own error there is about 2e-5 N on such runs).
    assert _max_error('intermittent', variant, 1e-4) <= ACCURACY_N


def test_holding_r_over_each_step_would_miss_the_target(monkeypatch):
    """The target is not loose: the same muscle with the recruitment held
    over each whole step (every step's events moved to its end) is off by far
    more, so the splitting is what the test measures."""
    from hill_muscle_ros.model import engine
    from hill_muscle_ros.model.equations import activation_at
    from hill_muscle_ros.model.muscle import kernels as muscle_kernels
    from hill_muscle_ros.model.muscle import state as muscle_state
    from hill_muscle_ros.model.memory import recruited_units
    # The patch changes the plain functions, which the Python engine calls by
    # name; the compiled build, loaded earlier, is left alone.
    monkeypatch.setenv(engine.ENV_VAR, engine.PYTHON)

    def at_step_end(F, I, i, s0, s1, a0, u_d, tau, m0):
        n = I[muscle_state.hdr(I, i, muscle_state.H_IP) + muscle_state.I_N]
        m1 = recruited_units(activation_at(a0, u_d, tau, s1 - s0), n)
        if m1 != m0:
            muscle_kernels.add_event(F, I, i, s1, muscle_state.A_RECRUIT, m1, 0.0, 0.0, 0.0)
        return m1
    monkeypatch.setattr(muscle_kernels, 'plan_events', at_step_end)
    error = _max_error('varying', 'multi-initial', PROTOCOLS['varying'][1])
    # Measured 0.33 N on this protocol.
    assert error > 4 * ACCURACY_N
