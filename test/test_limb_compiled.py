"""The compiled limb (model/limb_kernels.py) against Limb, the reference.

simulate_limb on the Python engine and on the compiled one, on the knee and
ankle presets with random commands (held, stepping, ramping: changing every
step) and random external torques: every column of every sample agrees to
1e-9 (rad, rad/s, m, N).
"""
from pathlib import Path

import numpy as np
import pytest
import yaml
from hypothesis import HealthCheck, given, settings, strategies as st

from hill_muscle_ros.model import engine, limb_kernels
from hill_muscle_ros.model.limb import (LimbPlant, LimbProtocol, LimbResult, simulate_limb)
from hill_muscle_ros.model.equations import SINE_SERIES_MAX_RAD

#: [rad], [rad/s], [m], [N]: agreement asked of every column.
TOL = 1e-9
CONFIG = Path(__file__).parents[1] / 'config'


def _plant(name):
    data = yaml.safe_load((CONFIG / f'{name}.yaml').read_text())['/**']['ros__parameters']
    return LimbPlant.from_mapping(data, ignore=('rate_hz',))


PLANTS = {name: _plant(name) for name in ('knee', 'ankle')}


@pytest.fixture(scope='module')
def kernels():
    return limb_kernels.compiled()


def _python(plant, protocol, monkeypatch):
    monkeypatch.setenv(engine.ENV_VAR, 'python')
    try:
        return simulate_limb(plant, protocol)
    finally:
        monkeypatch.delenv(engine.ENV_VAR)


def _assert_same(ref, got):
    assert ref.columns.keys() == got.columns.keys()
    worst = {k: float(np.abs(ref[k] - got[k]).max()) for k in ref.columns}
    assert max(worst.values()) <= TOL, worst


@st.composite
def limb_protocols(draw, names):
    """Per muscle random recruitment knots (steps where a time repeats, ramps
    between), a random external torque, 0.2-1.2 s."""
    duration = draw(st.sampled_from([0.2, 0.6, 1.2]))
    rng = np.random.default_rng(draw(st.integers(0, 2 ** 32 - 1)))

    def knots(low, high, count):
        times = np.sort(rng.uniform(0.0, duration, count)).round(4)
        if count > 1 and rng.uniform() < 0.5:
            times[1] = times[0]   # a step
        return [[float(t), float(v)] for t, v in zip(times, rng.uniform(low, high, count))]

    muscles = {name: {'recruitment': knots(0.0, 1.0, draw(st.integers(1, 6)))}
               for name in names}
    torque = knots(-3.0, 3.0, draw(st.integers(1, 4)))
    return LimbProtocol.from_mapping({'name': 'random', 'duration_s': duration,
                                      'muscles': muscles, 'external_torque_n_m': torque})


SETTINGS = settings(max_examples=12, deadline=None,
                    suppress_health_check=[HealthCheck.too_slow,
                                           HealthCheck.function_scoped_fixture])


@SETTINGS
@given(protocol=limb_protocols(['quadriceps', 'hamstrings']))
def test_knee_matches_the_reference(kernels, monkeypatch, protocol):
    plant = PLANTS['knee']
    _assert_same(_python(plant, protocol, monkeypatch),
                 limb_kernels.simulate_limb_compiled(plant, protocol, 1000.0, kernels))


@SETTINGS
@given(protocol=limb_protocols(['tibialis_anterior']))
def test_ankle_matches_the_reference(kernels, monkeypatch, protocol):
    plant = PLANTS['ankle']
    _assert_same(_python(plant, protocol, monkeypatch),
                 limb_kernels.simulate_limb_compiled(plant, protocol, 1000.0, kernels))


def test_simulate_limb_runs_compiled_when_the_engine_is_compiled(kernels, monkeypatch):
    """The knee extension protocol through simulate_limb: the compiled engine is
    taken (its result object comes from simulate_limb_compiled) and agrees."""
    plant = PLANTS['knee']
    protocol = LimbProtocol.from_yaml(CONFIG / 'protocols' / 'knee_extension.yaml')
    calls = []
    original = limb_kernels.simulate_limb_compiled

    def spy(*args, **kwargs):
        calls.append(args)
        return original(*args, **kwargs)

    monkeypatch.setattr(limb_kernels, 'simulate_limb_compiled', spy)
    monkeypatch.setenv(engine.ENV_VAR, 'compiled')
    got = simulate_limb(plant, protocol)
    monkeypatch.delenv(engine.ENV_VAR)
    assert len(calls) == 1
    _assert_same(_python(plant, protocol, monkeypatch), got)


def test_a_muscle_stretched_out_of_range_raises_as_the_reference(kernels, monkeypatch):
    """A moment arm that stretches the MTU beyond its limit: the same ValueError."""
    import dataclasses
    plant = PLANTS['ankle']
    muscle = dataclasses.replace(plant.muscles[0], moment_arm_m=1.0)
    plant = dataclasses.replace(plant, muscles=(muscle,),
                                joint=dataclasses.replace(plant.joint,
                                                          initial_angle_rad=0.0))
    protocol = LimbProtocol.from_mapping({
        'name': 'push', 'duration_s': 2.0, 'muscles': {muscle.name: {'recruitment': [[0, 0]]}},
        'external_torque_n_m': [[0.0, 500.0]]})
    with pytest.raises(ValueError) as ref:
        _python(plant, protocol, monkeypatch)
    with pytest.raises(ValueError) as got:
        limb_kernels.simulate_limb_compiled(plant, protocol, 1000.0, kernels)
    assert str(got.value) == str(ref.value)


def _knee_variants():
    """Three knee plants: the preset, a stronger quadriceps, a stiffer, damped joint."""
    import dataclasses
    plant = PLANTS['knee']
    quad = plant.muscles[0]
    strong = dataclasses.replace(quad, params=dataclasses.replace(quad.params,
                                                                  f_iso_max_n=2500.0))
    return [plant, dataclasses.replace(plant, muscles=(strong,) + plant.muscles[1:]),
            dataclasses.replace(plant, joint=dataclasses.replace(
                plant.joint, stiffness_n_m_per_rad=40.0, damping_n_m_s_per_rad=2.0))]


@settings(max_examples=4, deadline=None,
          suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])
@given(protocol=limb_protocols(['quadriceps', 'hamstrings']), data=st.data())
def test_limb_batch_matches_the_reference(kernels, monkeypatch, protocol, data):
    """simulate_limb_batch (the sweep's limb path) on both engines: every sampled
    angle and force of every plant to 1e-9."""
    from hill_muscle_ros.model.limb_batch import simulate_limb_batch
    steps = int(round(protocol.duration_s * 1000.0))
    indices = sorted(set(data.draw(st.lists(st.integers(0, steps), min_size=1, max_size=8))))
    plants = _knee_variants()
    monkeypatch.setenv(engine.ENV_VAR, 'python')
    ref = simulate_limb_batch(plants, protocol, 1000.0, indices)
    monkeypatch.setenv(engine.ENV_VAR, 'compiled')
    got = simulate_limb_batch(plants, protocol, 1000.0, indices)
    for r, g in zip(ref, got):
        assert r.shape == g.shape
        assert np.abs(r - g).max() <= TOL


def test_limb_batch_out_of_range_raises_as_the_reference(kernels, monkeypatch):
    """Of two limbs, the second driven out of range: the same LimbOutOfRange
    (the limb's index and its muscle's message) on both engines."""
    import dataclasses
    from hill_muscle_ros.model.limb_batch import LimbOutOfRange, simulate_limb_batch
    plant = PLANTS['ankle']
    muscle = dataclasses.replace(plant.muscles[0], moment_arm_m=1.0)
    weak = dataclasses.replace(plant, muscles=(muscle,))
    protocol = LimbProtocol.from_mapping({
        'name': 'push', 'duration_s': 2.0,
        'muscles': {muscle.name: {'recruitment': [[0, 0]]}},
        'external_torque_n_m': [[0.0, 500.0]]})
    errors = {}
    for value in ('python', 'compiled'):
        monkeypatch.setenv(engine.ENV_VAR, value)
        with pytest.raises(LimbOutOfRange) as err:
            simulate_limb_batch([plant, weak], protocol, 1000.0, [0, 1500])
        errors[value] = (err.value.limb, err.value.message)
    assert errors['compiled'] == errors['python']
    assert errors['python'][0] == 1


def test_auto_takes_the_compiled_limb_where_it_pays(kernels, monkeypatch):
    """HILL_MUSCLE_ENGINE=auto: a short run stays on the Python loop while the
    compiled limb is not loaded; a run of RUN_MIN_MUSCLE_STEPS muscle-steps
    loads it; once loaded, a short run takes it too."""
    plant = PLANTS['ankle']   # one muscle: muscle-steps = steps
    name = plant.muscles[0].name

    def protocol(duration_s):
        return LimbProtocol.from_mapping({'name': 'p', 'duration_s': duration_s,
                                          'muscles': {name: {'recruitment': [[0.0, 0.3]]}}})

    calls = []
    original = limb_kernels.simulate_limb_compiled

    def spy(*args, **kwargs):
        calls.append(args)
        return original(*args, **kwargs)

    monkeypatch.setattr(limb_kernels, 'simulate_limb_compiled', spy)
    monkeypatch.delenv(engine.ENV_VAR, raising=False)
    monkeypatch.setattr(limb_kernels, '_compiled', None)   # not loaded in this process
    simulate_limb(plant, protocol(0.2))
    assert len(calls) == 0
    simulate_limb(plant, protocol(limb_kernels.RUN_MIN_MUSCLE_STEPS / 1000.0))
    assert len(calls) == 1 and limb_kernels.loaded()
    simulate_limb(plant, protocol(0.2))
    assert len(calls) == 2


def test_engines_agree_while_the_released_quadriceps_is_quasi_static(kernels, monkeypatch,
                                                                     quasi_static_calls):
    """The knee extension's release: the quadriceps' last units leave, its CE
    relaxes faster than QUASI_STATIC_RATE_PER_S and is taken quasi-static (the
    Python limb asks for its force there), and both engines agree to 1e-9."""
    plant = PLANTS['knee']
    protocol = LimbProtocol.from_yaml(CONFIG / 'protocols' / 'knee_extension.yaml')
    ref = _python(plant, protocol, monkeypatch)
    assert quasi_static_calls, 'the release never made a CE quasi-static'
    _assert_same(ref, limb_kernels.simulate_limb_compiled(plant, protocol, 1000.0, kernels))


def test_steady_and_resting_muscles_are_stepped_without_planning_and_as_the_reference(
        kernels, monkeypatch):
    """The quadriceps stimulated twice with a rest between, the hamstrings never:
    a muscle in whose step no unit joins or leaves (limb_kernels.plan_steady:
    at rest, its activation 0 or falling from below half a unit; or holding a
    command) gets plan's piece and end without planning, and the run agrees
    with the Python limb to 1e-9; at the end both muscles rest."""
    plant = PLANTS['knee']
    burst = [[0.1, 0.0], [0.1, 0.6], [0.3, 0.6], [0.3, 0.0],
             [0.9, 0.0], [0.9, 0.5], [1.1, 0.5], [1.1, 0.0]]
    protocol = LimbProtocol.from_mapping({'name': 'two bursts', 'duration_s': 1.6,
                                          'muscles': {'quadriceps': {'recruitment': burst}}})
    ref = _python(plant, protocol, monkeypatch)
    arrays = limb_kernels.LimbArrays(plant, 1e-3)
    u = np.asarray(protocol.commands(ref.t_s, plant), dtype=float)
    rows = limb_kernels.run_limb(arrays, u, np.zeros(len(ref.t_s)), 1e-3, kernels)
    rows[:, 0] = ref.t_s
    got = LimbResult(ref.t_s, dict(zip(ref.columns, rows.T)))
    _assert_same(ref, got)
    # The quadriceps fell below half a unit between the bursts and after them.
    recruitment = ref['quadriceps_recruitment']

    def at(t_s):
        return recruitment[int(np.argmin(np.abs(ref.t_s - t_s)))]
    assert at(0.2) > 0.0 and 0.0 < at(0.85) < 0.5 / 1000 and at(1.0) > 0.0
    assert list(arrays.W[limb_kernels.W_STEADY, :2]) == [1.0, 1.0]
    assert all(limb_kernels.resting(arrays.bundle.F, arrays.bundle.I, arrays.W, i)
               for i in range(2))


def _other_knee():
    """The knee with other quadriceps and hamstrings numbers but their layout:
    a run of it can take the arrays of a run of the knee."""
    import dataclasses
    knee = PLANTS['knee']
    quad, ham = knee.muscles
    return dataclasses.replace(knee, muscles=(
        dataclasses.replace(quad, params=dataclasses.replace(quad.params, f_iso_max_n=900.0,
                                                             tau_act_s=0.04)),
        dataclasses.replace(ham, params=dataclasses.replace(ham.params, k_se_n_per_m=2e5))))


def _rest_stimulate_rest(duration_s=1.2):
    return LimbProtocol.from_mapping({
        'name': 'pool', 'duration_s': duration_s,
        'muscles': {'quadriceps': {'recruitment': [[0.1, 0.0], [0.1, 0.7], [0.7, 0.7],
                                                   [0.7, 0.0]]},
                    'hamstrings': {'recruitment': [[0.4, 0.0], [0.4, 0.3], [0.9, 0.3],
                                                   [0.9, 0.0]]}},
        'external_torque_n_m': [[0.0, 0.0]]})


def test_a_run_in_the_arrays_of_the_run_before_starts_from_rest_like_a_new_one(kernels,
                                                                             monkeypatch):
    """simulate_limb_compiled takes the arrays the previous run of its thread
    handed back (the same layout): knee, other knee, knee again give each the
    reference's result, and the third run exactly the first's."""
    protocol = _rest_stimulate_rest()
    knee, other = PLANTS['knee'], _other_knee()
    first = limb_kernels.simulate_limb_compiled(knee, protocol, 1000.0, kernels)
    handed_back = {id(a) for a in limb_kernels._POOL._free.values()}
    assert handed_back, 'the run handed no arrays back'
    second = limb_kernels.simulate_limb_compiled(other, protocol, 1000.0, kernels)
    assert {id(a) for a in limb_kernels._POOL._free.values()} == handed_back, \
        'the second run did not take the first run\'s arrays'
    third = limb_kernels.simulate_limb_compiled(knee, protocol, 1000.0, kernels)
    _assert_same(_python(knee, protocol, monkeypatch), first)
    _assert_same(_python(other, protocol, monkeypatch), second)
    assert not np.array_equal(first['quadriceps_force_n'], second['quadriceps_force_n'])
    for name in first.columns:
        np.testing.assert_array_equal(third[name], first[name], err_msg=name)


def test_runs_in_threads_at_once_each_use_arrays_of_their_own(kernels):
    """Threads running limbs at once (a sweep's) give what each run gives alone."""
    from concurrent.futures import ThreadPoolExecutor
    protocol = _rest_stimulate_rest(0.6)
    plants = [PLANTS['knee'], _other_knee()] * 3
    alone = [limb_kernels.simulate_limb_compiled(p, protocol, 1000.0, kernels) for p in plants]
    with ThreadPoolExecutor(max_workers=3) as threads:
        together = list(threads.map(
            lambda p: limb_kernels.simulate_limb_compiled(p, protocol, 1000.0, kernels), plants))
    for a, b in zip(alone, together):
        for name in a.columns:
            np.testing.assert_array_equal(b[name], a[name], err_msg=name)


def test_a_joint_too_fast_for_the_stage_sine_series_agrees_with_the_reference(kernels,
                                                                              monkeypatch):
    # A 40 N m push for 0.2 s, then the quadriceps at 0.4, stepped at 100 Hz:
    # RK4's half-step stages move the knee (up to 0.07 rad) beyond the range
    # for which sine_near's series is bounded to rounding, so the compiled step
    # takes libm's sin there and the series where the knee is slow; the whole
    # run agrees with the reference.
    rate_hz = 100.0
    protocol = LimbProtocol.from_mapping({
        'name': 'push', 'duration_s': 1.0,
        'muscles': {'quadriceps': {'recruitment': [[0.0, 0.0], [0.3, 0.0], [0.3, 0.4]]}},
        'external_torque_n_m': [[0.0, 40.0], [0.2, 40.0], [0.2, 0.0]]})
    monkeypatch.setenv(engine.ENV_VAR, 'python')
    ref = simulate_limb(PLANTS['knee'], protocol, rate_hz)
    monkeypatch.setenv(engine.ENV_VAR, 'compiled')
    got = simulate_limb(PLANTS['knee'], protocol, rate_hz)
    half_step_rad = 0.5 / rate_hz * np.abs(ref['omega_rad_per_s'])
    assert half_step_rad.max() > SINE_SERIES_MAX_RAD > half_step_rad.min()
    _assert_same(ref, got)
