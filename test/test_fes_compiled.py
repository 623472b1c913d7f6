"""The compiled FES muscle (model/muscle/kernels.py) against the same functions run as
plain Python (``HILL_MUSCLE_ENGINE=python``'s build).

Random parameters and random protocols (commands held for a few steps or
changing every step, given at a step's start and sometimes at its end, the
MTU length wandering): every output of every step agrees to 1e-9 (N, m, m/s).
Each test switches on one more FES feature, in the order they were covered.
"""
import math

import numpy as np
import pytest
from hypothesis import HealthCheck, assume, example, given, settings, strategies as st

from hill_muscle_ros.model.muscle import kernels as muscle_kernels, state as muscle_state
from hill_muscle_ros.model.params import MuscleParams

#: [N], [m], [m/s] agreement asked of every output (the forces' is the goal's 1e-9 N).
TOL = 1e-9
#: Hypothesis examples per test: enough to hit events, releases and segment splits,
#: while the plain Python build stays quick (units below 200); each test also
#: runs its pinned corner (:func:`pinned_protocol`).
EXAMPLES = 20



@pytest.fixture(scope='module')
def kernels():
    return muscle_kernels.compiled()


def _reference(params, r_start, r_end, dl, dt):
    """The outputs of each step on the plain Python build of the kernels."""
    return muscle_kernels.run_muscle(muscle_state.FesBundle([params]), 0, r_start, dl, dt, r_end)


def _compare(kernels, params, protocol):
    r_start, r_end, dl, dt = protocol
    ref = _reference(params, r_start, r_end, dl, dt)
    got = muscle_kernels.run_muscle(muscle_state.FesBundle([params]), 0, r_start, dl, dt,
                                 r_end, kernels)
    assert np.abs(got - ref).max() <= TOL, np.abs(got - ref).max(axis=0)


@st.composite
def protocols(draw):
    """Commands held for 1-20 steps (1: changing every step), some given at a
    step's end too; dl_MT a random walk within a few mm; dt 0.2-2 ms."""
    steps = draw(st.integers(20, 250))
    dt = draw(st.sampled_from([2e-4, 5e-4, 1e-3, 2e-3]))
    hold = draw(st.integers(1, 20))
    rng = np.random.default_rng(draw(st.integers(0, 2 ** 32 - 1)))
    levels = rng.choice([0.0, 1.0, *rng.uniform(0.0, 1.0, 6)], size=steps // hold + 1)
    r_start = np.repeat(levels, hold)[:steps]
    r_end = None
    if draw(st.booleans()):
        r_end = np.where(rng.uniform(size=steps) < 0.2, rng.uniform(size=steps), r_start)
    dl = np.clip(np.cumsum(rng.normal(0.0, draw(st.sampled_from([1e-5, 1e-4, 5e-4])),
                                      steps)), -0.03, 0.03)
    return r_start, r_end, dl, dt


def pinned_protocol(dt=2e-4):
    """A fixed :func:`protocols` case: 250 steps of ``dt``, the command through 0
    and 1, held 1 to 20 steps, given at some steps' ends too; dl_MT wandering."""
    rng = np.random.default_rng(11)
    holds = np.resize([1, 20, 3, 1, 1, 7, 12, 1], 60)
    levels = np.resize([0.0, 1.0, 0.35, 0.0, 0.8, 1.0, 0.1, 0.6], 60)
    r_start = np.repeat(levels, holds)[:250]
    r_end = np.where(rng.uniform(size=250) < 0.2, rng.uniform(size=250), r_start)
    dl = np.clip(np.cumsum(rng.normal(0.0, 5e-4, 250)), -0.03, 0.03)
    return r_start, r_end, dl, dt


def activation(draw):
    """Delay and activation/deactivation time constants (0: instantaneous)."""
    return dict(emd_s=draw(st.sampled_from([0.0, 0.0005, 0.0123, 0.031])),
                tau_act_s=draw(st.sampled_from([0.0, 0.004, 0.025])),
                tau_deact_s=draw(st.sampled_from([0.0, 0.006, 0.028])))


def _params(**fields):
    try:
        return MuscleParams(**fields)
    except ValueError:
        assume(False)


@st.composite
def delay_activation_params(draw):
    return _params(units=draw(st.sampled_from(['multi', 'single'])),
                   length=draw(st.sampled_from(['initial', 'instantaneous'])),
                   n_units=draw(st.integers(1, 150)), **activation(draw))


@st.composite
def fatigue_params(draw):
    return _params(units=draw(st.sampled_from(['multi', 'single'])),
                   length=draw(st.sampled_from(['initial', 'instantaneous'])),
                   n_units=draw(st.integers(1, 150)), fatigue='riener',
                   fatigue_min=(draw(st.floats(0.0, 0.9)),),
                   tau_fatigue_s=(draw(st.sampled_from([0.05, 0.5, 30.0])),),
                   tau_recovery_s=(draw(st.sampled_from([0.08, 1.0, 50.0])),),
                   **activation(draw))


@st.composite
def fibre_type_params(draw):
    k = draw(st.integers(1, 3))
    fractions = tuple(draw(st.floats(0.1, 1.0)) for _ in range(k))
    return _params(units='multi', length=draw(st.sampled_from(['initial', 'instantaneous'])),
                   n_units=draw(st.integers(3, 150)), fatigue=draw(
                       st.sampled_from(['none', 'riener'])),
                   fibre_fractions=fractions,
                   fibre_force_weights=tuple(draw(st.floats(0.2, 3.0)) for _ in range(k)),
                   tau_fatigue_s=tuple(draw(st.sampled_from([0.1, 2.0, 30.0]))
                                       for _ in range(k)),
                   recruitment_order=draw(st.sampled_from(['size', 'reverse', 'random'])),
                   recruitment_seed=draw(st.integers(0, 5)), **activation(draw))


@st.composite
def spread_params(draw):
    # Up to 60 units drawn (each has a length of its own, the plain build's
    # costliest step); the pinned spread case has 150.
    k = draw(st.integers(1, 2))
    return _params(units='multi', length=draw(st.sampled_from(['initial', 'instantaneous'])),
                   n_units=draw(st.integers(1, 60)),
                   fatigue=draw(st.sampled_from(['none', 'riener'])),
                   fibre_fractions=(0.5,) * k,
                   unit_length_spread=draw(st.sampled_from([0.05, 0.3, 0.6])),
                   recruitment_order=draw(st.sampled_from(['size', 'random'])),
                   **activation(draw))


@st.composite
def relative_params(draw):
    units = draw(st.sampled_from(['multi', 'single']))
    return _params(units=units, length=draw(st.sampled_from(['initial', 'instantaneous'])),
                   n_units=draw(st.integers(1, 150)), fv_scaling='relative',
                   fatigue=draw(st.sampled_from(['none', 'riener'])),
                   unit_length_spread=draw(st.sampled_from([0.0, 0.2])) if units == 'multi'
                   else 0.0, **activation(draw))


#: Each test's pinned corner, run on :func:`pinned_protocol`: one unit, the
#: longest delay, instant activation; the fastest fatigue and recovery; three
#: fibre types in reverse order of few units; the widest spread; relative f-v.
PINNED = {
    'delay': MuscleParams(units='single', length='instantaneous', n_units=1, emd_s=0.031,
                          tau_act_s=0.0, tau_deact_s=0.028),
    'fatigue': MuscleParams(n_units=150, fatigue='riener', fatigue_min=(0.0,),
                            tau_fatigue_s=(0.05,), tau_recovery_s=(0.08,), emd_s=0.0005,
                            tau_act_s=0.004, tau_deact_s=0.0),
    'types': MuscleParams(n_units=3, length='instantaneous', fatigue='riener',
                          fibre_fractions=(0.1, 1.0, 0.5), fibre_force_weights=(3.0, 0.2, 1.0),
                          tau_fatigue_s=(0.1, 2.0, 30.0), recruitment_order='reverse',
                          emd_s=0.0123),
    'spread': MuscleParams(n_units=150, length='instantaneous', fatigue='riener',
                           fibre_fractions=(0.5, 0.5), unit_length_spread=0.3,
                           recruitment_order='random', tau_act_s=0.025, tau_deact_s=0.006),
    'relative': MuscleParams(n_units=1, fv_scaling='relative', fatigue='riener',
                             unit_length_spread=0.2, emd_s=0.031, tau_act_s=0.004,
                             tau_deact_s=0.028),
}


def pinned(key):
    """The pinned case ``key`` of :data:`PINNED` as a Hypothesis example."""
    return example(params=PINNED[key], protocol=pinned_protocol())


SETTINGS = settings(max_examples=EXAMPLES, deadline=None,
                    suppress_health_check=[HealthCheck.too_slow,
                                           HealthCheck.function_scoped_fixture])


@SETTINGS
@given(params=delay_activation_params(), protocol=protocols())
@pinned('delay')
def test_delay_and_activation_match_the_plain_build(kernels, params, protocol):
    _compare(kernels, params, protocol)


@SETTINGS
@given(params=fatigue_params(), protocol=protocols())
@pinned('fatigue')
def test_fatigue_matches_the_plain_build(kernels, params, protocol):
    _compare(kernels, params, protocol)


@SETTINGS
@given(params=fibre_type_params(), protocol=protocols())
@pinned('types')
def test_fibre_types_match_the_plain_build(kernels, params, protocol):
    _compare(kernels, params, protocol)


@SETTINGS
@given(params=spread_params(), protocol=protocols())
@pinned('spread')
def test_unit_length_spread_matches_the_plain_build(kernels, params, protocol):
    _compare(kernels, params, protocol)


@SETTINGS
@given(params=relative_params(), protocol=protocols())
@pinned('relative')
def test_relative_fv_scaling_matches_the_plain_build(kernels, params, protocol):
    _compare(kernels, params, protocol)


def test_knee_quadriceps_preset_matches_the_plain_build(kernels):
    """Every feature at once, 1000 units: the knee preset's quadriceps for 1 s of
    a pulse train switched on, off, on and off again."""
    from hill_muscle_ros.model.limb import LimbPlant
    import yaml
    from pathlib import Path
    data = yaml.safe_load((Path(__file__).parents[1] / 'config' / 'knee.yaml').read_text())
    plant = LimbPlant.from_mapping(data['/**']['ros__parameters'], ignore=('rate_hz',))
    params = plant.muscles[0].params
    t = np.arange(1000) * 1e-3
    r = np.where((t % 0.5) < 0.3, 0.6, 0.0)
    dl = 0.004 * np.sin(2.0 * math.pi * t)
    _compare(kernels, params, (r, None, dl, 1e-3))


def test_delay_line_grows_for_a_shorter_step(kernels):
    """A bundle sized for 1 ms steps runs 0.1 ms steps with a 31 ms delay: the
    ring buffer grows, keeping the commands pending."""
    params = MuscleParams(emd_s=0.031, tau_act_s=0.01, tau_deact_s=0.01, n_units=20)
    bundle = muscle_state.FesBundle([params], dt_s=1e-3)
    r = np.linspace(0.0, 1.0, 40)
    first = muscle_kernels.run_muscle(bundle, 0, r, np.zeros(40), 1e-3, None, kernels)
    cap = bundle.cap
    second = muscle_kernels.run_muscle(bundle, 0, r[::-1], np.zeros(40), 1e-4, None, kernels)
    assert bundle.cap > cap
    ref = _reference(params, r, None, np.zeros(40), 1e-3)
    plain = muscle_state.FesBundle([params], dt_s=1e-4)
    muscle_kernels.run_muscle(plain, 0, r, np.zeros(40), 1e-3)
    ref_second = muscle_kernels.run_muscle(plain, 0, r[::-1], np.zeros(40), 1e-4)
    assert np.abs(first - ref[:40]).max() <= TOL
    assert np.abs(second - ref_second).max() <= TOL


def test_a_new_bundle_starts_fresh_though_its_layout_is_kept(kernels):
    """FesBundle keeps the laid-out arrays of recent parameter sets: a bundle made
    after another of the same muscle has run equals one laid out from scratch,
    and owns its arrays (writable, shared with no other bundle)."""
    params = MuscleParams(n_units=200, fibre_fractions=[0.4, 0.6], recruitment_order='random',
                          recruitment_seed=5, fatigue='riener', tau_fatigue_s=[3.0, 1.0],
                          emd_s=0.02, tau_act_s=0.03)
    used = muscle_state.FesBundle([params])
    n = 300
    muscle_kernels.run_muscle(used, 0, np.full(n, 0.6), np.zeros(n), 1e-3, None, kernels)
    new = muscle_state.FesBundle([params])
    scratch = muscle_state.FesBundle._filled((params,), new.cap)
    np.testing.assert_array_equal(new.F, scratch.F)
    np.testing.assert_array_equal(new.I, scratch.I)
    assert not np.array_equal(used.F, new.F)
    assert new.F.flags.writeable and new.I.flags.writeable
    assert not np.shares_memory(new.F, used.F) and not np.shares_memory(new.I, used.I)
