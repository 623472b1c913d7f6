"""The compiled run of one muscle (kernels.run_muscle) does exactly what `Muscle.run` does.

`Muscle.run`, the pure-Python loop, is the reference: it is checked against
the readable curves and a `solve_ivp` reference in test_model_muscle.py and
test_model_fastpath.py. The compiled run must give the same 12 output columns
and leave the muscle in the same state, on all four variants, with R held,
changing on every step, released to zero, and applied again after the step
(``r_end``, as `simulate` passes it). The engine choice (HILL_MUSCLE_ENGINE),
the in-memory fallback without a writable numba cache and the lazy import of
numba are checked in fresh processes.

numba is a runtime requirement, so these tests do not skip without it: they fail.
"""
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hill_muscle_ros import resources
from hill_muscle_ros.model import Muscle, MuscleParams, Protocol, engine, kernels, simulate

from test_model_fastpath import muscle_params

#: [N], [m], [m/s] bound on every output column and state, compiled against Python.
ATOL = 1e-9
#: Fields of MuscleOutputs in order, for messages.
FIELDS = Muscle(MuscleParams()).outputs()._fields


@st.composite
def run_case(draw):
    """Parameters, a random (R, dl_MT) sequence and an ``r_end`` mode.

    R is held for 1..8 steps (1: it changes on every step) or released to
    zero; dl_MT follows random linear ramps, wide enough that an
    instantaneous CE can leave the FL range.
    """
    params = draw(muscle_params())
    n_steps = draw(st.integers(1, 200))
    levels = st.floats(0.0, 1.0) | st.just(0.0) | st.just(1.0)
    r = np.empty(n_steps)
    t = 0
    while t < n_steps:
        hold = draw(st.integers(1, 8))
        r[t:t + hold] = draw(levels)
        t += hold
    knots = draw(st.lists(st.floats(-0.08, 0.08), min_size=2, max_size=6))
    dl = np.interp(np.linspace(0.0, 1.0, n_steps), np.linspace(0.0, 1.0, len(knots)), knots)
    mode = draw(st.sampled_from(['none', 'next', 'random']))
    if mode == 'none':
        r_end = None
    elif mode == 'next':   # as simulate: the recruitment of the next instant
        r_end = np.append(r[1:], draw(levels))
    else:
        r_end = np.array(draw(st.lists(levels, min_size=n_steps, max_size=n_steps)))
    dt = draw(st.sampled_from([1e-4, 1e-3, 5e-3]))
    split = draw(st.integers(0, n_steps))
    return params, r, dl, r_end, dt, split


def python_run(muscle: Muscle, r, dl, dt, r_end) -> np.ndarray:
    """`Muscle.run` with its columns as a (12, n) array."""
    columns = [[0.0] * len(dl) for _ in FIELDS]
    muscle.run(r.tolist(), dl.tolist(), dt, None if r_end is None else r_end.tolist(),
               columns)
    return np.array(columns, dtype=float).reshape(len(FIELDS), len(dl))


def assert_same_state(compiled: Muscle, reference: Muscle) -> None:
    for name in ('t_s', 'l_ce_m', 'dl_mt_m', 'recruitment', 'n_recruited', 'n_runs',
                 '_gain_n', '_v_free', '_f_iso_single_n'):
        assert getattr(compiled, name) == pytest.approx(getattr(reference, name), abs=ATOL), name
    np.testing.assert_allclose(compiled.outputs(), reference.outputs(), rtol=0, atol=ATOL)


@settings(max_examples=300, deadline=None)
@given(run_case())
def test_compiled_run_gives_muscle_runs_columns_and_state(case):
    params, r, dl, r_end, dt, split = case
    reference, compiled = Muscle(params), Muscle(params)
    # In two calls, split anywhere: the state written back carries the run on.
    parts = [slice(0, split), slice(split, len(dl))]
    expected = np.concatenate(
        [python_run(reference, r[s], dl[s], dt, None if r_end is None else r_end[s])
         for s in parts], axis=1)
    got = np.concatenate(
        [kernels.run_compiled(compiled, r[s], dl[s], dt, None if r_end is None else r_end[s])
         for s in parts], axis=1)
    for row, name in enumerate(FIELDS):
        np.testing.assert_allclose(got[row], expected[row], rtol=0, atol=ATOL, err_msg=name)
    assert_same_state(compiled, reference)


@pytest.mark.parametrize('amplitude_m', [0.1, -0.1])
@pytest.mark.parametrize('units', ['multi', 'single'])
def test_an_instantaneous_ce_leaving_and_reentering_the_fl_range_as_in_muscle_run(
        units, amplitude_m):
    # A fast CE (b = b' = 1 m/s) and 5 ms steps: stretched or shortened by
    # 0.1 m while fully recruited, the CE passes an end of the FL range within
    # a step, Eff.f_iso drops to zero and the CE is free; on the way back its
    # free length re-enters the range.
    params = MuscleParams(units=units, length='instantaneous', fv_b_m_per_s=1.0,
                          fv_b_ecc_m_per_s=1.0)
    dl = np.concatenate([np.linspace(0.0, amplitude_m, 50), np.full(50, amplitude_m),
                         np.linspace(amplitude_m, 0.0, 100)])
    r = np.ones(len(dl))
    reference, compiled = Muscle(params), Muscle(params)
    expected = python_run(reference, r, dl, 5e-3, None)
    f0 = expected[FIELDS.index('eff_f_iso_n')]
    assert f0[-1] > 0.0 and (f0 == 0.0).any()   # the case is reached, and left
    got = kernels.run_compiled(compiled, r, dl, 5e-3)
    np.testing.assert_allclose(got, expected, rtol=0, atol=ATOL)
    assert_same_state(compiled, reference)


def test_a_freed_ce_back_inside_the_fl_range_resists_again_in_every_loop():
    # A fast CE, a soft tendon and 10 ms steps through a large length swing:
    # at some steps the RK4 length leaves the FL range and the CE is put at
    # its free length, which is inside the range. Every loop reads Eff.f_iso
    # off that state: the sample shows it, and the next step integrates
    # against it, whether run over the sequence, compiled or one call a step.
    params = MuscleParams(units='single', length='instantaneous', f_iso_max_n=88.0,
                          k_se_n_per_m=2600.0, l_opt_m=0.14, fv_a_n=2.3, fv_b_m_per_s=0.93,
                          fv_a_ecc_n=29.0, fv_b_ecc_m_per_s=1.8)
    dl = np.interp(np.linspace(0.0, 1.0, 60), np.linspace(0.0, 1.0, 4),
                   [-0.05, -0.075, 0.074, 0.13])
    r = np.ones(len(dl))
    reference, compiled, stepped = Muscle(params), Muscle(params), Muscle(params)
    expected = python_run(reference, r, dl, 1e-2, None)
    # One RK4 step of 10 ms per call (run: step cuts it into 1 ms substeps).
    one_call_a_step = np.array([stepped.run((1.0,), (d,), 1e-2) for d in dl]).T
    # The case is reached: a CE at its free length (slack tendon) with force on.
    free = expected[FIELDS.index('l_ce_m')] == params.l_rest_m + dl
    assert (free & (expected[FIELDS.index('eff_f_iso_n')] > 0.0)).any()
    np.testing.assert_allclose(one_call_a_step, expected, rtol=0, atol=ATOL)
    got = kernels.run_compiled(compiled, r, dl, 1e-2)
    np.testing.assert_allclose(got, expected, rtol=0, atol=ATOL)
    assert_same_state(compiled, reference)


def simulate_counting(monkeypatch, protocol) -> tuple:
    """simulate(protocol) and the number of compiled runs it made."""
    calls = []
    real = kernels.run_compiled
    monkeypatch.setattr(kernels, 'run_compiled',
                        lambda *a, **kw: calls.append(1) or real(*a, **kw))
    result = simulate(protocol)
    monkeypatch.setattr(kernels, 'run_compiled', real)
    return result, len(calls)


@pytest.fixture
def protocol_ii():
    return Protocol.from_yaml(resources.protocol_path('II'))


def test_simulate_compiled_gives_the_python_loops_result(monkeypatch, protocol_ii):
    monkeypatch.setenv(engine.ENV_VAR, 'compiled')
    compiled, n_compiled = simulate_counting(monkeypatch, protocol_ii)
    monkeypatch.setenv(engine.ENV_VAR, 'python')
    reference, n_python = simulate_counting(monkeypatch, protocol_ii)
    assert (n_compiled, n_python) == (1, 0)
    for name in FIELDS:
        np.testing.assert_allclose(getattr(compiled, name), getattr(reference, name),
                                   rtol=0, atol=ATOL, err_msg=name)


def test_simulate_auto_takes_the_compiled_run_once_it_is_loaded(monkeypatch, protocol_ii):
    monkeypatch.setenv(engine.ENV_VAR, 'auto')
    kernels.compiled_run()
    assert simulate_counting(monkeypatch, protocol_ii)[1] == 1


def test_simulate_auto_loads_the_compiled_run_for_a_long_run_only(monkeypatch, protocol_ii):
    monkeypatch.setenv(engine.ENV_VAR, 'auto')
    monkeypatch.setattr(kernels, '_compiled_run', None)   # not loaded yet
    n_steps = round(protocol_ii.duration_s * 1000.0)
    monkeypatch.setattr(kernels, 'RUN_MIN_STEPS', n_steps + 1)
    assert simulate_counting(monkeypatch, protocol_ii)[1] == 0
    assert not kernels.run_loaded()
    monkeypatch.setattr(kernels, 'RUN_MIN_STEPS', n_steps)
    assert simulate_counting(monkeypatch, protocol_ii)[1] == 1
    assert kernels.run_loaded()


def run_python(code: str, **env) -> subprocess.CompletedProcess:
    """Run ``code`` in a fresh interpreter with ``env`` added to the environment."""
    return subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                          check=True, env={**os.environ, **env}, timeout=120)


#: Simulates a short protocol, then builds a batch with engine='auto'; prints
#: the engine chosen, whether simulate loaded the compiled run and numba, and
#: the batch's engine.
ENGINE_PROBE = '''
import sys
from hill_muscle_ros.model import MuscleBatch, MuscleParams, Protocol, engine, kernels, simulate
simulate(Protocol.from_mapping({"name": "probe", "duration_s": 0.05,
                                "recruitment": [[0.0, 0.5]], "dl_mt_m": [[0.0, 0.0]]}))
print(engine.choice(), kernels.run_loaded(), "numba" in sys.modules,
      MuscleBatch([MuscleParams()]).engine)
'''


@pytest.mark.parametrize('value, expected', [
    ('python', ['python', 'False', 'False', 'numpy']),
    ('auto', ['compiled', 'False', 'False', 'compiled']),   # too short to load numba for
    ('compiled', ['compiled', 'True', 'True', 'compiled']),
])
def test_the_engine_in_the_environment_decides_simulate_and_batch(value, expected):
    assert run_python(ENGINE_PROBE, **{engine.ENV_VAR: value}).stdout.split() == expected


def test_an_unknown_engine_in_the_environment_is_refused_by_name(monkeypatch):
    monkeypatch.setenv(engine.ENV_VAR, 'gpu')
    with pytest.raises(ValueError, match="`HILL_MUSCLE_ENGINE` must be one of auto, "
                                         "compiled, python, got 'gpu'"):
        engine.choice()


def test_engine_compiled_without_numba_raises(monkeypatch):
    monkeypatch.setenv(engine.ENV_VAR, 'compiled')
    monkeypatch.setitem(sys.modules, 'numba', None)   # import numba raises ImportError
    with pytest.raises(ImportError, match='numba'):
        engine.choice()


def test_without_a_writable_cache_the_run_compiles_in_memory_and_warns_once(tmp_path):
    # NUMBA_CACHE_DIR below a regular file cannot be created (even by root),
    # and the locators are limited to that one, so numba finds no cache place.
    blocker = tmp_path / 'a_file'
    blocker.write_text('')
    cache_dir = blocker / 'numba_cache'
    code = '''
import warnings
import numpy as np
from hill_muscle_ros.model import Muscle, MuscleParams, kernels
warnings.simplefilter('always')
with warnings.catch_warnings(record=True) as caught:
    # Eleven functions compiled, each of which finds no cache: one warning.
    out = kernels.run_compiled(Muscle(MuscleParams()), np.full(50, 0.5),
                               np.linspace(0.0, 0.005, 50), 1e-3)
columns = [[0.0] * 50 for _ in range(12)]
Muscle(MuscleParams()).run([0.5] * 50, np.linspace(0.0, 0.005, 50).tolist(), 1e-3,
                           columns=columns)
print(len(caught), np.abs(out - np.array(columns, dtype=float)).max() <= 1e-9)
print(caught[0].category.__name__, caught[0].message)
'''
    out = run_python(code, NUMBA_CACHE_DIR=str(cache_dir),
                     NUMBA_CACHE_LOCATOR_CLASSES='UserProvidedCacheLocator').stdout
    lines = out.splitlines()
    assert lines[0] == '1 True'
    assert lines[1].startswith('CacheUnavailableWarning ')
    assert str(cache_dir) in lines[1]
    assert not Path(cache_dir).exists()


def test_importing_the_package_and_the_engine_does_not_import_numba():
    code = ('import sys; import hill_muscle_ros; from hill_muscle_ros import cli; '
            'from hill_muscle_ros.model import engine, kernels, simulate; '
            'print("numba" in sys.modules, "llvmlite" in sys.modules)')
    assert run_python(code).stdout.split() == ['False', 'False']


def test_compile_seconds_counts_the_time_numba_spends_compiling():
    numba = engine.import_numba()
    before = engine.compile_seconds()

    def add_one(x):
        return x + 1.0

    compiled_add_one = numba.njit(add_one)   # no cache: it compiles here, at its first call
    assert compiled_add_one(1.0) == 2.0
    assert engine.compile_seconds() > before
