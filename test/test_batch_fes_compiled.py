"""A MuscleBatch holding muscles with FES features on: the compiled engine against NumPy's.

On the NumPy engine each FES muscle is its own Muscle (the reference); on
the compiled engine they are stepped together on the compiled FES muscle
(model/muscle/batch_kernels.py). Every output of every step, of ``outputs()``
and after ``set_recruitment`` must agree to 1e-9 (N, m, m/s), counts and
commands exactly, with paper's-model muscles mixed in, steps of changing
length (delay lines growing) and resets.
"""
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings, strategies as st

from hill_muscle_ros.model import MuscleParams
from hill_muscle_ros.model.muscle.batch import MuscleBatch

from test_fes_compiled import (delay_activation_params, fatigue_params, fibre_type_params,
                               relative_params, spread_params)
from test_model_engines import muscle_params

#: [N], [m], [m/s] agreement asked of every output (the forces' is the goal's 1e-9 N).
TOL = 1e-9
#: Outputs that must be identical: counts and the commands echoed.
EXACT = ('n_recruited', 'command')

any_params = (delay_activation_params() | fatigue_params() | fibre_type_params()
              | spread_params() | relative_params() | muscle_params())


def _agree(got, ref) -> bool:
    """Whether every output agrees as :func:`assert_same` asks, in one array
    comparison (the per-field numpy.testing calls took half this module's time).
    False also where both are NaN or infinite: the per-field check judges those."""
    names = got._fields[1:]
    close = [n for n in names if n not in EXACT]
    a = np.concatenate([np.ravel(getattr(got, n)) for n in close])
    b = np.concatenate([np.ravel(getattr(ref, n)) for n in close])
    return (a.shape == b.shape and bool(np.all(np.abs(a - b) <= TOL))
            and all(np.array_equal(getattr(got, n), getattr(ref, n)) for n in EXACT))


def assert_same(got, ref, label):
    assert got.t_s == ref.t_s, label
    if _agree(got, ref):
        return
    for name in got._fields[1:]:
        a, b = np.asarray(getattr(got, name)), np.asarray(getattr(ref, name))
        if name in EXACT:
            np.testing.assert_array_equal(a, b, err_msg=f'{name} {label}')
        else:
            np.testing.assert_allclose(a, b, rtol=0, atol=TOL, err_msg=f'{name} {label}')


@st.composite
def cases(draw):
    """1-5 muscles (FES features mixed with the paper's model) and 10-120 actions:
    steps (R held for a few steps or changing, dt 0.2-2 ms), set_recruitment
    alone, outputs(), reset()."""
    k = draw(st.integers(1, 5))
    params = draw(st.lists(any_params, min_size=k, max_size=k))
    rng = np.random.default_rng(draw(st.integers(0, 2 ** 32 - 1)))
    n = draw(st.integers(10, 120))
    hold = draw(st.integers(1, 15))
    levels = rng.choice([0.0, 1.0, *rng.uniform(0.0, 1.0, 4)], size=(n // hold + 1, k))
    r = np.repeat(levels, hold, axis=0)[:n]
    dl = np.clip(np.cumsum(rng.normal(0.0, 3e-4, (n, k)), axis=0), -0.03, 0.03)
    dts = rng.choice([2e-4, 5e-4, 1e-3, 2e-3], size=n) if draw(st.booleans()) \
        else np.full(n, draw(st.sampled_from([5e-4, 1e-3])))
    actions = rng.choice(['step', 'set', 'outputs', 'reset'], size=n,
                         p=[0.85, 0.08, 0.05, 0.02])
    return params, list(zip(actions, r, dl, dts))


def run_both(params, actions):
    compiled = MuscleBatch(params, build='compiled')
    reference = MuscleBatch(params, build='python')
    assert compiled.build == 'compiled' and reference.build == 'python'
    for n, (action, r, dl, dt) in enumerate(actions):
        label = f'action {n} ({action})'
        if action == 'step':
            assert_same(compiled.step(r, dl, dt), reference.step(r, dl, dt), label)
        elif action == 'set':
            compiled.set_recruitment(r)
            reference.set_recruitment(r)
        elif action == 'reset':
            compiled.reset()
            reference.reset()
        assert_same(compiled.outputs(), reference.outputs(), label + ' outputs()')
    return compiled


@settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(case=cases())
def test_fes_muscles_on_the_compiled_engine_match_the_numpy_engine(case):
    run_both(*case)


def test_a_long_delay_with_commands_piling_up_grows_the_delay_lines():
    """A 31 ms delay, the command changing every 0.1 ms step and given twice
    between steps: far more commands pending than a 1 ms step leaves room for."""
    params = [MuscleParams(emd_s=0.031, tau_act_s=0.01, tau_deact_s=0.01, n_units=30),
              MuscleParams()]
    rng = np.random.default_rng(7)
    actions = []
    for _ in range(200):
        actions.append(('set', rng.uniform(size=2), np.zeros(2), 1e-4))
        actions.append(('step', rng.uniform(size=2), np.full(2, 0.002), 1e-4))
    compiled = run_both(params, actions)
    assert compiled._bundle.cap > 2 * 31 + 4   # grown beyond a 1 ms step's room


def test_the_fes_quadriceps_preset_in_a_batch_of_three(monkeypatch):
    """config/fes_quadriceps.yaml (every feature, 1000 units) beside two paper
    muscles, 0.8 s of a stimulation switched on, off and on again (the muscles
    recruited up and down), long enough for its fatigue to run."""
    from hill_muscle_ros import resources
    from hill_muscle_ros.params_file import load_muscle_params
    quad, _ = load_muscle_params(resources.config_dir() / 'fes_quadriceps.yaml')
    t = np.arange(800) * 1e-3
    r = np.where((t % 0.5) < 0.3, 0.6, 0.0)
    actions = [('step', np.array([rk, rk, 1.0 - rk]),
                np.full(3, 0.004 * np.sin(2 * np.pi * tk)), 1e-3) for tk, rk in zip(t, r)]
    compiled = run_both([quad, MuscleParams(), quad], actions)
    assert compiled.mean_fitness[0] < 1.0   # fatigue really ran
