"""The limb stepped one call at a time (Limb, and LimbBatch on it) on the plain
functions of its kernels against their numba build.

Random commands (changing at random steps) and external torques on the knee
and ankle presets, with resets and a change of step length: every output of
every step agrees to rounding (1e-9 rad, rad/s, N m, m, N). Bad inputs raise
the same errors on both builds and change nothing; a limb driven out of range
raises the same error on both and is left in the same state. The engine is
HILL_MUSCLE_ENGINE's alone; a deep copy of a limb steps on as the limb would.
"""
import copy

import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, settings, strategies as st

from hill_muscle_ros.model import engine
from hill_muscle_ros.model.limb import Limb, LimbBatch, LimbOutOfRange, kernels
from hill_muscle_ros.params_file import load_plant
from hill_muscle_ros.resources import config_dir
from limb_engines import TOL, on_engine, run_on

PYTHON, COMPILED = engine.PYTHON, engine.COMPILED
#: [s] the presets' step (1 kHz)
DT_S = 1e-3
PLANTS = {name: load_plant(config_dir() / f'{name}.yaml')[0] for name in ('knee', 'ankle')}
#: Limbs of the batches compared with their limbs stepped one by one or on the
#: other build: two are a batch (the second's index and state are its own); a
#: third repeated the plain Python run of a limb, most of these tests' time.
BATCH_LIMBS = 2
SETTINGS = settings(max_examples=3, deadline=None,
                    suppress_health_check=[HealthCheck.too_slow,
                                           HealthCheck.function_scoped_fixture])


@pytest.fixture(scope='module', autouse=True)
def compiled_kernels():
    pytest.importorskip('numba')
    return kernels.compiled()


def _pair(make, *args):
    """``make(*args)`` on the plain functions, then on the compiled build."""
    return run_on(PYTHON, make, *args), run_on(COMPILED, make, *args)


def _assert_close(ref, got):
    """Two LimbOutputs (or LimbBatchOutputs) field by field."""
    assert ref._fields == got._fields
    worst = {f: float(np.max(np.abs(np.subtract(a, b)))) for f, a, b in zip(ref._fields, ref, got)}
    assert max(worst.values()) <= TOL, worst


def _inputs(seed, n_muscles, n_steps):
    """Per step: commands (each held 1-80 steps), torque [N m] (held alike), dt [s]."""
    rng = np.random.default_rng(seed)
    u, tau, out = rng.uniform(0, 1, n_muscles), 0.0, []
    for k in range(n_steps):
        if rng.uniform() < 0.05:
            u = rng.uniform(0, 1, n_muscles) * (rng.uniform(size=n_muscles) < 0.8)
        if rng.uniform() < 0.05:
            tau = float(rng.uniform(-3.0, 3.0))
        # A stretch at half the step: the delay lines grow, keeping the state.
        dt = DT_S / 2 if n_steps // 2 <= k < n_steps // 2 + 20 else DT_S
        out.append((u.tolist(), tau, dt))
    return out


@SETTINGS
@given(name=st.sampled_from(sorted(PLANTS)), seed=st.integers(0, 2 ** 32 - 1),
       reset_at=st.integers(30, 120))
@example(name='knee', seed=1, reset_at=110)
@example(name='ankle', seed=2, reset_at=40)
def test_a_limb_steps_alike_on_both_builds(name, seed, reset_at):
    plant = PLANTS[name]
    ref, got = _pair(Limb, plant)
    assert (ref.build, got.build) == (PYTHON, COMPILED)
    _assert_close(ref.outputs(), got.outputs())
    for k, (u, tau, dt) in enumerate(_inputs(seed, len(plant.muscles), 150)):
        if k == reset_at:
            ref.reset()
            got.reset()
            _assert_close(ref.outputs(), got.outputs())
        _assert_close(ref.step(u, tau, dt), got.step(u, tau, dt))
    assert (got.t_s, got.theta_rad, got.omega_rad_per_s) == pytest.approx(
        (ref.t_s, ref.theta_rad, ref.omega_rad_per_s), abs=TOL)


@pytest.mark.parametrize('commands, tau, dt, message', [
    ([0.5, 1.5], 0.0, DT_S, r'`hamstrings.command` must be in \[0, 1\], got 1.5'),
    ([0.5, float('nan')], 0.0, DT_S, r'`hamstrings.command` must be in \[0, 1\], got nan'),
    ([0.5], 0.0, DT_S, r'`commands` must have one value per muscle \(2\), got 1'),
    ([0.5, 0.5], 2e4, DT_S, r'`external_torque_n_m` must be finite and within ±10000 N m'),
    ([0.5, 0.5], 0.0, -1e-3, r'`dt_s` must be positive and finite, got -0.001'),
])
def test_a_bad_input_raises_alike_on_both_builds_and_changes_nothing(commands, tau, dt,
                                                                     message):
    limbs = _pair(Limb, PLANTS['knee'])
    for limb in limbs:
        for _ in range(60):
            limb.step([0.7, 0.1], 0.5, DT_S)
        before = limb.outputs()
        with pytest.raises(ValueError, match=message):
            limb.step(commands, tau, dt)
        assert limb.outputs() == before
    _assert_close(*(limb.step([0.2, 0.4], 0.0, DT_S) for limb in limbs))


def test_out_of_range_raises_alike_on_both_builds_and_leaves_the_limb_alike():
    # 1e4 N m on the 0.0197 kg m^2 foot: its muscle's MTU passes 1 m within tens of steps.
    limbs = _pair(Limb, PLANTS['ankle'])
    messages = []
    for limb in limbs:
        with pytest.raises(ValueError, match=r'^muscle `tibialis_anterior` is stretched') as err:
            for _ in range(1000):
                limb.step([0.0], 1e4, DT_S)
        messages.append(str(err.value))
    assert messages[0] == messages[1]
    _assert_close(limbs[0].outputs(), limbs[1].outputs())


@pytest.mark.parametrize('value', [PYTHON, COMPILED])
def test_a_deep_copy_steps_on_as_the_limb_and_apart_from_it(value):
    """copy.deepcopy(limb) (the fault tests' releases from one instant): the copy
    has the limb's state, steps exactly as the limb does, and neither moves the other."""
    with on_engine(value):
        limb = Limb(PLANTS['knee'])
    for _ in range(50):
        limb.step([0.6, 0.2], 0.3, DT_S)
    twin = copy.deepcopy(limb)
    assert twin.outputs() == limb.outputs() and twin.build == limb.build == value
    for _ in range(30):
        assert twin.step([0.1, 0.5], 0.0, DT_S) == limb.step([0.1, 0.5], 0.0, DT_S)
    before = limb.outputs()
    twin.step([1.0, 0.0], 0.0, DT_S)
    assert limb.outputs() == before and twin.outputs() != before


@pytest.mark.parametrize('value, build', [(PYTHON, 'plain'), (COMPILED, 'compiled'),
                                          ('auto', 'compiled')])
def test_a_limb_runs_the_build_the_environment_variable_names(value, build):
    with on_engine(value):
        limb = Limb(PLANTS['ankle'])
    want = kernels if build == 'plain' else kernels.compiled()
    assert limb._kernels is want
    assert limb.build == (PYTHON if build == 'plain' else COMPILED)


@pytest.mark.parametrize('value', [PYTHON, COMPILED])
def test_a_limb_asked_for_a_build_runs_it_whatever_the_variable_says(value, monkeypatch):
    # The limb node's fallback to the plain functions when the compiled build
    # fails to load; the batch passes the build on to its limbs.
    monkeypatch.setenv(engine.ENV_VAR, COMPILED if value == PYTHON else PYTHON)
    assert Limb(PLANTS['ankle'], build=value).build == value
    assert LimbBatch([PLANTS['ankle']] * 2, build=value).build == value


def test_an_unknown_build_is_refused_naming_it():
    with pytest.raises(ValueError, match=r"`build` must be 'compiled', 'python' or None, "
                                         r"got 'numba'"):
        Limb(PLANTS['ankle'], build='numba')


def test_an_unknown_engine_is_refused_naming_the_value(monkeypatch):
    monkeypatch.setenv(engine.ENV_VAR, 'numba')
    with pytest.raises(ValueError, match=r"`HILL_MUSCLE_ENGINE` must be one of auto, "
                                         r"compiled, python, got 'numba'"):
        Limb(PLANTS['ankle'])


@settings(SETTINGS, max_examples=2)
@given(name=st.sampled_from(sorted(PLANTS)), seed=st.integers(0, 2 ** 32 - 1))
@example(name='knee', seed=3)
@example(name='ankle', seed=4)
def test_a_limb_batch_steps_alike_on_both_builds(name, seed):
    # A batch's limbs are each a Limb stepped in turn (writing its row), whatever their count.
    k_limbs, plant = BATCH_LIMBS, PLANTS[name]
    ref, got = _pair(LimbBatch, [plant] * k_limbs)
    assert (ref.build, got.build) == (PYTHON, COMPILED)
    rng = np.random.default_rng(seed)
    m = len(plant.muscles)
    for k in range(100):
        if k % 25 == 0:   # commands given between steps, as a sample of simulate_limb does
            u = rng.uniform(0, 1, (k_limbs, m))
            ref.give_commands(u)
            got.give_commands(u)
            _assert_close(ref.outputs(), got.outputs())
        if k == 60:
            ref.reset()
            got.reset()
        tau = rng.uniform(-3.0, 3.0, k_limbs)
        _assert_close(ref.step_commands(u, tau, DT_S), got.step_commands(u, tau, DT_S))


def test_a_limb_batch_out_of_range_names_the_limb_alike_on_both_builds():
    errors = []
    for batch in _pair(LimbBatch, [PLANTS['ankle']] * 2):
        with pytest.raises(LimbOutOfRange) as err:
            for _ in range(1000):
                batch.step_commands(0.0, [0.0, 1e4], DT_S)
        errors.append((err.value.limb, err.value.message))
    assert errors[0] == errors[1]
    assert errors[0][0] == 1


@pytest.mark.parametrize('value', [PYTHON, COMPILED])
def test_a_limb_batch_bad_command_changes_nothing(value):
    with on_engine(value):
        batch = LimbBatch([PLANTS['knee']] * 2)
    batch.step_commands(0.5, 0.0, DT_S)
    before = batch.outputs()
    with pytest.raises(ValueError, match=r'`commands\[1, 0\]` \(quadriceps\) must be in '
                                         r'\[0, 1\], got 1.5'):
        batch.step_commands([[0.2, 0.2], [1.5, 0.2]], 0.0, DT_S)
    after = batch.outputs()
    for a, b in zip(before, after):
        np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize('name', sorted(PLANTS))
def test_hold_commands_is_n_steps_and_their_squared_angle_errors(name):
    # The batch's one call of the kernels per limb against limbs stepped one by
    # one, the squared errors summed here; each on the other build.
    plant, n = PLANTS[name], 20
    rng = np.random.default_rng(7)
    m = len(plant.muscles)
    got = run_on(COMPILED, LimbBatch, [plant] * BATCH_LIMBS)
    refs = [run_on(PYTHON, Limb, plant) for _ in range(BATCH_LIMBS)]
    for period in range(4):
        u, target = rng.uniform(0, 1, (BATCH_LIMBS, m)), rng.uniform(0.2, 0.8, BATCH_LIMBS)
        out, squared = got.hold_commands(u, 0.5, DT_S, n, target)
        for k, ref in enumerate(refs):
            thetas = [ref.step(u[k].tolist(), 0.5, DT_S).theta_rad for _ in range(n)]
            assert squared[k] == pytest.approx(sum((t - target[k]) ** 2 for t in thetas),
                                               abs=TOL)
            assert out.theta_rad[k] == pytest.approx(thetas[-1], abs=TOL)
    assert out.t_s == pytest.approx(4 * n * DT_S, abs=1e-12)


def test_hold_commands_agrees_between_builds_and_names_a_limb_out_of_range():
    results = []
    for batch in _pair(LimbBatch, [PLANTS['ankle']] * 2):
        out, squared = batch.hold_commands([[0.3], [0.6]], 0.0, DT_S, 30, 0.1)
        with pytest.raises(LimbOutOfRange, match=r'^limb 1: muscle `tibialis_anterior` is '
                                                 r'stretched'):
            batch.hold_commands(0.0, [0.0, 1e4], DT_S, 1000, 0.0)
        results.append((out, squared))
    _assert_close(results[0][0], results[1][0])
    np.testing.assert_allclose(results[0][1], results[1][1], rtol=0, atol=TOL)


@pytest.mark.parametrize('value', [PYTHON, COMPILED])
def test_hold_commands_refuses_fewer_than_one_step(value):
    with on_engine(value):
        batch = LimbBatch([PLANTS['ankle']])
    with pytest.raises(ValueError, match=r'`n_steps` must be at least 1, got 0'):
        batch.hold_commands(0.5, 0.0, DT_S, 0, 0.0)


@pytest.mark.parametrize('dt_s', [2e-3, float('nan')])
def test_hold_commands_refuses_a_step_longer_than_1_ms_and_moves_no_limb(dt_s):
    # Each squared error is taken at a step's end: a step is one substep.
    batch = LimbBatch([PLANTS['ankle']] * 2)
    before = batch.outputs()
    with pytest.raises(ValueError, match=r'`dt_s` must be (in \(0, 0.001\] s|positive)'):
        batch.hold_commands(0.5, 0.0, dt_s, 3, 0.0)
    for a, b in zip(batch.outputs(), before):
        np.testing.assert_array_equal(a, b)
