"""The limb's kernels run as plain Python against their numba build (model/limb/kernels.py).

simulate_limb with HILL_MUSCLE_ENGINE=python and =compiled, on the knee and
ankle presets with random commands (held, stepping, ramping: changing every
step) and random external torques: the same functions, so every column of
every sample agrees to rounding (1e-9 rad, rad/s, m, N). The physics of
either is checked against the independent reference in test_model_limb.
"""
import dataclasses
from pathlib import Path

import numpy as np
import pytest
import yaml
from hypothesis import HealthCheck, example, given, settings, strategies as st

from hill_muscle_ros.model import engine
from hill_muscle_ros.model.equations import SINE_SERIES_MAX_RAD
from hill_muscle_ros.model.limb import (LimbOutOfRange, LimbPlant, LimbProtocol, LimbResult,
                                        arrays as limb_arrays, kernels, simulate_limb,
                                        simulate_limb_batch)
from hill_muscle_ros.model.limb.simulate import run_limb
from limb_engines import TOL, on_engine, run_on, spy_quasi_static


#: The module takes about 10 CPU-s: scheduled among the first (conftest).
pytestmark = pytest.mark.slow

CONFIG = Path(__file__).parents[1] / 'config'
PYTHON, COMPILED = engine.PYTHON, engine.COMPILED


def _plant(name):
    data = yaml.safe_load((CONFIG / f'{name}.yaml').read_text())['/**']['ros__parameters']
    return LimbPlant.from_mapping(data, ignore=('rate_hz',))


PLANTS = {name: _plant(name) for name in ('knee', 'ankle')}
#: [s] where the knee extension is cut here: 0.5 s after its release (3.5 s).
#: The quadriceps' quasi-static steps of the release all fall before 3.8 s; the
#: rest of the 6 s protocol, the shank swinging with the muscles at rest, was
#: a quarter of the plain Python run.
KNEE_EXTENSION_END_S = 4.0
KNEE_EXTENSION = dataclasses.replace(
    LimbProtocol.from_yaml(CONFIG / 'protocols' / 'knee_extension.yaml'),
    duration_s=KNEE_EXTENSION_END_S)


@pytest.fixture(scope='module', autouse=True)
def compiled_kernels():
    pytest.importorskip('numba')
    return kernels.compiled()


def _both(plant, protocol, rate_hz=1000.0):
    """simulate_limb on the plain functions, then on their compiled build."""
    return (run_on(PYTHON, simulate_limb, plant, protocol, rate_hz),
            run_on(COMPILED, simulate_limb, plant, protocol, rate_hz))


def _assert_same(ref, got):
    assert ref.columns.keys() == got.columns.keys()
    worst = {k: float(np.abs(ref[k] - got[k]).max()) for k in ref.columns}
    assert max(worst.values()) <= TOL, worst


@st.composite
def limb_protocols(draw, names, durations=(0.2, 0.4, 0.6)):
    """Per muscle random recruitment knots (steps where a time repeats, ramps
    between), a random external torque, one of ``durations`` [s] (short: a
    plain run of the knee takes up to 3 ms a step while the commands ramp)."""
    duration = draw(st.sampled_from(durations))
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


#: [s] durations of the random knee protocols: short, as a plain run of the
#: knee is the costliest (a 0.3 s one was drawn too). A knot or a step of the
#: commands is met alike in 0.1 s and 0.3 s; the builds' long comparison on the
#: knee is the knee extension's (KNEE_EXTENSION_END_S), and PINNED_KNEE lasts 0.3 s.
KNEE_DURATIONS_S = (0.1, 0.2)
SETTINGS = settings(max_examples=5, deadline=None,
                    suppress_health_check=[HealthCheck.too_slow,
                                           HealthCheck.function_scoped_fixture])


#: Pinned knee and ankle protocols: commands stepping up, ramping, and down to 0,
#: a torque pushing both ways.
PINNED_KNEE = LimbProtocol.from_mapping({
    'name': 'pinned knee', 'duration_s': 0.3,
    'muscles': {'quadriceps': {'recruitment': [[0.02, 0.0], [0.02, 1.0], [0.15, 0.2],
                                               [0.2, 0.2], [0.2, 0.0]]},
                'hamstrings': {'recruitment': [[0.05, 0.0], [0.25, 0.8], [0.25, 0.1]]}},
    'external_torque_n_m': [[0.0, -3.0], [0.1, 3.0], [0.1, 0.5]]})
PINNED_ANKLE = LimbProtocol.from_mapping({
    'name': 'pinned ankle', 'duration_s': 0.4,
    'muscles': {'tibialis_anterior': {'recruitment': [[0.0, 0.0], [0.05, 0.0], [0.05, 1.0],
                                                      [0.2, 0.4], [0.3, 0.4], [0.3, 0.0]]}},
    'external_torque_n_m': [[0.0, 2.0], [0.25, -3.0]]})


@settings(SETTINGS, max_examples=4)
@given(protocol=limb_protocols(['quadriceps', 'hamstrings'], KNEE_DURATIONS_S))
@example(protocol=PINNED_KNEE)
def test_knee_runs_alike_on_both_builds(protocol):
    _assert_same(*_both(PLANTS['knee'], protocol))


@SETTINGS
@given(protocol=limb_protocols(['tibialis_anterior']))
@example(protocol=PINNED_ANKLE)
def test_ankle_runs_alike_on_both_builds(protocol):
    _assert_same(*_both(PLANTS['ankle'], protocol))


@pytest.fixture(scope='module')
def knee_extension_python():
    """The knee extension protocol (to KNEE_EXTENSION_END_S) on the plain
    functions, once per module, with the fv_scaling of each muscle the kernels
    took quasi-static."""
    with pytest.MonkeyPatch.context() as mp:
        calls = spy_quasi_static(mp, PLANTS['knee'])
        result = simulate_limb(PLANTS['knee'], KNEE_EXTENSION)
    return result, calls


def test_simulate_limb_runs_the_build_the_engine_names(knee_extension_python, monkeypatch):
    """The knee extension (its stimulation and release) through simulate_limb:
    HILL_MUSCLE_ENGINE=compiled runs the compiled build, python the plain
    functions, and the two agree."""
    builds = []
    original = limb_arrays.LimbArrays.entry

    def spy(self, build, *args):
        builds.append(build)
        return original(self, build, *args)

    monkeypatch.setattr(limb_arrays.LimbArrays, 'entry', spy)
    got = run_on(COMPILED, simulate_limb, PLANTS['knee'], KNEE_EXTENSION)
    run_on(PYTHON, simulate_limb, PLANTS['knee'], LimbProtocol.from_mapping({
        'name': 'short', 'duration_s': 0.01,
        'muscles': {'quadriceps': {'recruitment': [[0, 0]]}}}))
    assert builds == [kernels.compiled(), kernels]
    _assert_same(knee_extension_python[0], got)


def test_the_engine_is_chosen_by_the_environment_variable_alone(monkeypatch):
    """python never loads the compiled build; auto loads it for the first run,
    however short, where numba imports."""
    plant = PLANTS['ankle']
    protocol = LimbProtocol.from_mapping({'name': 'p', 'duration_s': 0.05, 'muscles': {
        plant.muscles[0].name: {'recruitment': [[0.0, 0.3]]}}})
    monkeypatch.setattr(kernels, '_compiled', None)   # not loaded in this process
    with on_engine(PYTHON):
        simulate_limb(plant, protocol)
    assert not kernels.loaded()
    with on_engine('auto'):
        simulate_limb(plant, protocol)
    assert kernels.loaded()


def test_a_muscle_stretched_out_of_range_raises_alike_on_both_builds():
    """A moment arm that stretches the MTU beyond its limit: the same ValueError."""
    plant = PLANTS['ankle']
    muscle = dataclasses.replace(plant.muscles[0], moment_arm_m=1.0)
    plant = dataclasses.replace(plant, muscles=(muscle,),
                                joint=dataclasses.replace(plant.joint,
                                                          initial_angle_rad=0.0))
    protocol = LimbProtocol.from_mapping({
        'name': 'push', 'duration_s': 2.0, 'muscles': {muscle.name: {'recruitment': [[0, 0]]}},
        'external_torque_n_m': [[0.0, 500.0]]})
    messages = []
    for value in (PYTHON, COMPILED):
        with pytest.raises(ValueError, match=r'^muscle `tibialis_anterior` is stretched') as err:
            run_on(value, simulate_limb, plant, protocol)
        messages.append(str(err.value))
    assert messages[0] == messages[1]


def _knee_variants():
    """Three knee plants: the preset, a stronger quadriceps, a stiffer, damped joint."""
    plant = PLANTS['knee']
    quad = plant.muscles[0]
    strong = dataclasses.replace(quad, params=dataclasses.replace(quad.params,
                                                                  f_iso_max_n=2500.0))
    return [plant, dataclasses.replace(plant, muscles=(strong,) + plant.muscles[1:]),
            dataclasses.replace(plant, joint=dataclasses.replace(
                plant.joint, stiffness_n_m_per_rad=40.0, damping_n_m_s_per_rad=2.0))]


@settings(max_examples=2, deadline=None,
          suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])
@given(protocol=limb_protocols(['quadriceps', 'hamstrings'], KNEE_DURATIONS_S), data=st.data())
def test_limb_batch_runs_alike_on_both_builds(protocol, data):
    """simulate_limb_batch (the sweep's limb path) on both builds: every sampled
    angle and force of every plant to 1e-9."""
    steps = int(round(protocol.duration_s * 1000.0))
    indices = sorted(set(data.draw(st.lists(st.integers(0, steps), min_size=1, max_size=8))))
    plants = _knee_variants()
    ref = run_on(PYTHON, simulate_limb_batch, plants, protocol, 1000.0, indices)
    got = run_on(COMPILED, simulate_limb_batch, plants, protocol, 1000.0, indices)
    for r, g in zip(ref, got):
        assert r.shape == g.shape
        assert np.abs(r - g).max() <= TOL


def test_limb_batch_out_of_range_raises_alike_on_both_builds():
    """Of two limbs, the second driven out of range: the same LimbOutOfRange
    (the limb's index and its muscle's message) on both builds."""
    plant = PLANTS['ankle']
    muscle = dataclasses.replace(plant.muscles[0], moment_arm_m=1.0)
    weak = dataclasses.replace(plant, muscles=(muscle,))
    protocol = LimbProtocol.from_mapping({
        'name': 'push', 'duration_s': 2.0,
        'muscles': {muscle.name: {'recruitment': [[0, 0]]}},
        'external_torque_n_m': [[0.0, 500.0]]})
    errors = {}
    for value in (PYTHON, COMPILED):
        with pytest.raises(LimbOutOfRange) as err:
            run_on(value, simulate_limb_batch, [plant, weak], protocol, 1000.0, [0, 1500])
        errors[value] = (err.value.limb, err.value.message)
    assert errors[COMPILED] == errors[PYTHON]
    assert errors[PYTHON][0] == 1


def test_both_builds_agree_while_the_released_quadriceps_is_quasi_static(
        knee_extension_python):
    """The knee extension's release: the quadriceps' last units leave, its CE
    relaxes faster than QUASI_STATIC_RATE_PER_S and is taken quasi-static (the
    plain run asks for its force there), and both builds agree to 1e-9."""
    ref, calls = knee_extension_python
    assert set(calls) == {'relative'}, 'the release never made the quadriceps quasi-static'
    _assert_same(ref, run_on(COMPILED, simulate_limb, PLANTS['knee'], KNEE_EXTENSION))


def test_steady_and_resting_muscles_are_stepped_without_planning_as_if_planned(monkeypatch):
    """The quadriceps stimulated twice with a rest between, the hamstrings never:
    a muscle in whose step no unit joins or leaves (kernels.plan_steady: at
    rest, its activation 0 or falling from below half a unit; or holding a
    command) gets plan's piece and end without planning, and the run agrees
    to 1e-9 with the plain functions' run in which every muscle plans every
    step (plan_steady never taken); at the end both muscles rest."""
    plant = PLANTS['knee']
    burst = [[0.1, 0.0], [0.1, 0.6], [0.3, 0.6], [0.3, 0.0],
             [0.9, 0.0], [0.9, 0.5], [1.1, 0.5], [1.1, 0.0]]
    protocol = LimbProtocol.from_mapping({'name': 'two bursts', 'duration_s': 1.6,
                                          'muscles': {'quadriceps': {'recruitment': burst}}})
    with monkeypatch.context() as mp:
        mp.setattr(kernels, 'plan_steady', lambda F, I, W, i, t0, t1: False)
        ref = run_on(PYTHON, simulate_limb, plant, protocol)
    arrays = limb_arrays.LimbArrays(plant, 1e-3)
    u = np.asarray(protocol.commands(ref.t_s, plant), dtype=float)
    rows = run_on(COMPILED, run_limb, arrays, u, np.zeros(len(ref.t_s)), 1e-3)
    rows[:, 0] = ref.t_s
    got = LimbResult(ref.t_s, dict(zip(ref.columns, rows.T)))
    _assert_same(ref, got)
    # The quadriceps fell below half a unit between the bursts and after them.
    recruitment = ref['quadriceps_recruitment']

    def at(t_s):
        return recruitment[int(np.argmin(np.abs(ref.t_s - t_s)))]
    assert at(0.2) > 0.0 and 0.0 < at(0.85) < 0.5 / 1000 and at(1.0) > 0.0
    assert list(arrays.W[kernels.W_STEADY, :2]) == [1.0, 1.0]
    assert all(kernels.resting(arrays.bundle.F, arrays.bundle.I, arrays.W, i)
               for i in range(2))


def _other_knee():
    """The knee with other quadriceps and hamstrings numbers but their layout:
    a run of it can take the arrays of a run of the knee."""
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


def test_a_run_in_the_arrays_of_the_run_before_starts_from_rest_like_a_new_one():
    """simulate_limb takes the arrays the previous run of its thread handed back
    (the same layout): knee, other knee, knee again give each the plain
    functions' result, and the third run exactly the first's. The runs end
    0.6 s in, both muscles stimulated: the arrays are handed back far from rest."""
    protocol = _rest_stimulate_rest(0.6)
    knee, other = PLANTS['knee'], _other_knee()
    with on_engine(COMPILED):
        first = simulate_limb(knee, protocol)
        handed_back = {id(a) for a in limb_arrays.SCRATCH._free.values()}
        assert handed_back, 'the run handed no arrays back'
        second = simulate_limb(other, protocol)
        assert {id(a) for a in limb_arrays.SCRATCH._free.values()} == handed_back, \
            'the second run did not take the first run\'s arrays'
        third = simulate_limb(knee, protocol)
    _assert_same(run_on(PYTHON, simulate_limb, knee, protocol), first)
    _assert_same(run_on(PYTHON, simulate_limb, other, protocol), second)
    assert not np.array_equal(first['quadriceps_force_n'], second['quadriceps_force_n'])
    for name in first.columns:
        np.testing.assert_array_equal(third[name], first[name], err_msg=name)


def test_runs_in_threads_at_once_each_use_arrays_of_their_own():
    """Threads running limbs at once (a sweep's) give what each run gives alone."""
    from concurrent.futures import ThreadPoolExecutor
    protocol = _rest_stimulate_rest(0.6)
    plants = [PLANTS['knee'], _other_knee()] * 3
    with on_engine(COMPILED):
        alone = [simulate_limb(p, protocol) for p in plants]
        with ThreadPoolExecutor(max_workers=3) as threads:
            together = list(threads.map(lambda p: simulate_limb(p, protocol), plants))
    for a, b in zip(alone, together):
        for name in a.columns:
            np.testing.assert_array_equal(b[name], a[name], err_msg=name)


def test_a_joint_too_fast_for_the_stage_sine_series_runs_as_with_libm_sines(monkeypatch):
    # A 40 N m push for 0.2 s, then the quadriceps at 0.4 from 0.3 s to 0.6 s, stepped at 100 Hz:
    # RK4's half-step stages move the knee (up to 0.07 rad) beyond the range
    # for which sine_near's series is bounded to rounding, so the step takes
    # libm's sin there and the series where the knee is slow; the whole run
    # agrees with the plain functions' run that takes libm's sin at every stage.
    rate_hz = 100.0
    protocol = LimbProtocol.from_mapping({
        'name': 'push', 'duration_s': 0.6,
        'muscles': {'quadriceps': {'recruitment': [[0.0, 0.0], [0.3, 0.0], [0.3, 0.4]]}},
        'external_torque_n_m': [[0.0, 40.0], [0.2, 40.0], [0.2, 0.0]]})
    with monkeypatch.context() as mp:
        mp.setattr(kernels, 'SINE_SERIES_MAX_RAD', -1.0)   # no stage within the series' range
        ref = run_on(PYTHON, simulate_limb, PLANTS['knee'], protocol, rate_hz)
    got = run_on(COMPILED, simulate_limb, PLANTS['knee'], protocol, rate_hz)
    half_step_rad = 0.5 / rate_hz * np.abs(ref['omega_rad_per_s'])
    assert half_step_rad.max() > SINE_SERIES_MAX_RAD > half_step_rad.min()
    _assert_same(ref, got)
