"""The compiled limb stepped one call at a time (limb_kernels.CompiledLimb, and
LimbBatch on it) against Limb, the reference.

Random commands (changing at random steps) and external torques on the knee
and ankle presets, with resets and a change of step length: every output of
every step agrees to 1e-9 (rad, rad/s, N m, m, N). Bad inputs raise the
reference's errors and change nothing; a limb driven out of range raises the
reference's error and is left where the reference is left.
"""
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings, strategies as st

from hill_muscle_ros.model import engine, limb_kernels
from hill_muscle_ros.model.limb import Limb
from hill_muscle_ros.model.limb_batch import LimbBatch, LimbOutOfRange
from hill_muscle_ros.params_file import load_plant
from hill_muscle_ros.resources import config_dir

#: [rad], [rad/s], [N m], [m], [N]: agreement asked of every output.
TOL = 1e-9
#: [s] the presets' step (1 kHz)
DT_S = 1e-3
PLANTS = {name: load_plant(config_dir() / f'{name}.yaml')[0] for name in ('knee', 'ankle')}
SETTINGS = settings(max_examples=10, deadline=None,
                    suppress_health_check=[HealthCheck.too_slow,
                                           HealthCheck.function_scoped_fixture])


@pytest.fixture(scope='module')
def kernels():
    return limb_kernels.compiled()


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
        # A stretch at half the step: the compiled delay lines grow, keeping the state.
        dt = DT_S / 2 if n_steps // 2 <= k < n_steps // 2 + 20 else DT_S
        out.append((u.tolist(), tau, dt))
    return out


@SETTINGS
@given(name=st.sampled_from(sorted(PLANTS)), seed=st.integers(0, 2 ** 32 - 1),
       reset_at=st.integers(50, 350))
def test_compiled_limb_steps_as_limb(kernels, name, seed, reset_at):
    plant = PLANTS[name]
    ref, got = Limb(plant), limb_kernels.CompiledLimb(plant, kernels)
    _assert_close(ref.outputs(), got.outputs())
    for k, (u, tau, dt) in enumerate(_inputs(seed, len(plant.muscles), 400)):
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
def test_compiled_limb_bad_input_raises_as_limb_and_changes_nothing(kernels, commands, tau,
                                                                     dt, message):
    plant = PLANTS['knee']
    limbs = [Limb(plant), limb_kernels.CompiledLimb(plant, kernels)]
    for limb in limbs:
        for _ in range(60):
            limb.step([0.7, 0.1], 0.5, DT_S)
    before = limbs[1].outputs()
    for limb in limbs:
        with pytest.raises(ValueError, match=message):
            limb.step(commands, tau, dt)
    assert limbs[1].outputs() == before
    _assert_close(*(limb.step([0.2, 0.4], 0.0, DT_S) for limb in limbs))


def test_compiled_limb_out_of_range_raises_as_limb_and_is_left_where_limb_is(kernels):
    # 1e4 N m on the 0.0197 kg m^2 foot: its muscle's MTU passes 1 m within tens of steps.
    plant = PLANTS['ankle']
    limbs = [Limb(plant), limb_kernels.CompiledLimb(plant, kernels)]
    messages = []
    for limb in limbs:
        with pytest.raises(ValueError, match=r'^muscle `tibialis_anterior` is stretched') as err:
            for _ in range(1000):
                limb.step([0.0], 1e4, DT_S)
        messages.append(str(err.value))
    assert messages[0] == messages[1]
    _assert_close(limbs[0].outputs(), limbs[1].outputs())


@SETTINGS
@given(name=st.sampled_from(sorted(PLANTS)), seed=st.integers(0, 2 ** 32 - 1))
def test_compiled_limb_batch_steps_as_the_python_batch(kernels, name, seed):
    k_limbs, plant = 3, PLANTS[name]
    ref, got = (LimbBatch([plant] * k_limbs, engine=e) for e in ('python', 'compiled'))
    assert (ref.engine, got.engine) == ('python', 'compiled')
    rng = np.random.default_rng(seed)
    m = len(plant.muscles)
    for k in range(300):
        if k % 40 == 0:   # commands given between steps, as a sample of simulate_limb does
            u = rng.uniform(0, 1, (k_limbs, m))
            ref.give_commands(u)
            got.give_commands(u)
            _assert_close(ref.outputs(), got.outputs())
        if k == 150:
            ref.reset()
            got.reset()
        tau = rng.uniform(-3.0, 3.0, k_limbs)
        _assert_close(ref.step_commands(u, tau, DT_S), got.step_commands(u, tau, DT_S))


def test_compiled_limb_batch_out_of_range_names_the_limb_as_the_python_batch(kernels):
    errors = []
    for e in ('python', 'compiled'):
        batch = LimbBatch([PLANTS['ankle']] * 2, engine=e)
        with pytest.raises(LimbOutOfRange) as err:
            for _ in range(1000):
                batch.step_commands(0.0, [0.0, 1e4], DT_S)
        errors.append((err.value.limb, err.value.message))
    assert errors[0] == errors[1]
    assert errors[0][0] == 1


def test_compiled_limb_batch_bad_command_changes_nothing(kernels):
    batch = LimbBatch([PLANTS['knee']] * 2, engine='compiled')
    batch.step_commands(0.5, 0.0, DT_S)
    before = batch.outputs()
    with pytest.raises(ValueError, match=r'`commands\[1, 0\]` \(quadriceps\) must be in '
                                         r'\[0, 1\], got 1.5'):
        batch.step_commands([[0.2, 0.2], [1.5, 0.2]], 0.0, DT_S)
    after = batch.outputs()
    for a, b in zip(before, after):
        np.testing.assert_array_equal(a, b)


def test_step_engine_auto_waits_for_the_compiled_limb_to_be_loaded(kernels, monkeypatch):
    # A step-by-step limb has no work to repay the loading: auto takes Python
    # until the compiled limb is loaded; the variable's compiled and python win.
    monkeypatch.setenv(engine.ENV_VAR, 'auto')
    assert limb_kernels.step_engine() == engine.COMPILED   # loaded by the fixture
    monkeypatch.setattr(limb_kernels, '_compiled', None)
    assert limb_kernels.step_engine() == engine.PYTHON
    assert type(limb_kernels.make_limb(PLANTS['ankle'])) is Limb
    monkeypatch.setenv(engine.ENV_VAR, 'python')
    assert limb_kernels.step_engine() == engine.PYTHON
    assert limb_kernels.step_engine('compiled') == engine.COMPILED


def test_step_engine_rejects_an_unknown_engine():
    with pytest.raises(ValueError, match=r"`engine` must be 'compiled', 'python' or None, "
                                         r"got 'numba'"):
        limb_kernels.step_engine('numba')


@pytest.mark.parametrize('name', sorted(PLANTS))
def test_hold_commands_is_n_steps_and_their_squared_angle_errors(kernels, name):
    # The compiled batch's one call per limb against the Python limbs stepped
    # one by one, the squared errors summed here.
    plant, n = PLANTS[name], 20
    rng = np.random.default_rng(7)
    m = len(plant.muscles)
    got = LimbBatch([plant] * 3, engine='compiled')
    refs = [Limb(plant) for _ in range(3)]
    for period in range(6):
        u, target = rng.uniform(0, 1, (3, m)), rng.uniform(0.2, 0.8, 3)
        out, squared = got.hold_commands(u, 0.5, DT_S, n, target)
        for k, ref in enumerate(refs):
            thetas = [ref.step(u[k].tolist(), 0.5, DT_S).theta_rad for _ in range(n)]
            assert squared[k] == pytest.approx(sum((t - target[k]) ** 2 for t in thetas),
                                               abs=TOL)
            assert out.theta_rad[k] == pytest.approx(thetas[-1], abs=TOL)
    assert out.t_s == pytest.approx(6 * n * DT_S, abs=1e-12)


def test_hold_commands_agrees_between_engines_and_names_a_limb_out_of_range(kernels):
    results = []
    for e in ('python', 'compiled'):
        batch = LimbBatch([PLANTS['ankle']] * 2, engine=e)
        out, squared = batch.hold_commands([[0.3], [0.6]], 0.0, DT_S, 30, 0.1)
        with pytest.raises(LimbOutOfRange, match=r'^limb 1: muscle `tibialis_anterior` is '
                                                 r'stretched'):
            batch.hold_commands(0.0, [0.0, 1e4], DT_S, 1000, 0.0)
        results.append((out, squared))
    _assert_close(results[0][0], results[1][0])
    np.testing.assert_allclose(results[0][1], results[1][1], rtol=0, atol=TOL)


@pytest.mark.parametrize('engine_name', ['python', 'compiled'])
def test_hold_commands_refuses_fewer_than_one_step(kernels, engine_name):
    batch = LimbBatch([PLANTS['ankle']], engine=engine_name)
    with pytest.raises(ValueError, match=r'`n_steps` must be at least 1, got 0'):
        batch.hold_commands(0.5, 0.0, DT_S, 0, 0.0)
