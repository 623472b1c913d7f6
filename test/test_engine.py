"""The engine: compiled and plain builds of one muscle's run agree; the choice of build.

`Muscle` runs the kernels of model/muscle/kernels.py compiled by numba, or the same
functions as plain Python (``HILL_MUSCLE_ENGINE=python``). Both builds must give
the same 12 output columns and leave the muscle in the same state, on all four
variants of the paper's model, with R held, changing on every step, released
to zero, and given again after the step (``r_end``, as `simulate` passes it),
split over two calls anywhere. The engine choice (HILL_MUSCLE_ENGINE), the
in-memory fallback without a writable numba cache and the lazy import of numba
are checked in fresh processes.

numba is a runtime requirement, so these tests do not skip without it: they fail.
"""
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from hill_muscle_ros import resources
from hill_muscle_ros.model import Muscle, MuscleParams, Protocol, engine, simulate

from engines import compiled, plain
from test_model_engines import muscle_params

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


def pinned_case(units: str, length: str, mode: str, n_units: int):
    """A fixed :func:`run_case`: R through 0 and 1 held and changing, dl_MT
    ramping 8 cm out and back (a fast CE at 5 ms steps leaves the FL range),
    split inside the run."""
    params = MuscleParams(n_units=n_units, units=units, length=length,
                          fv_b_m_per_s=1.5, fv_b_ecc_m_per_s=0.05)
    r = np.array([0.0, 1.0, 1.0, 0.4, 0.4, 0.4, 0.0, 0.73, 1.0, 0.0, 0.0, 0.5] * 3)
    dl = np.interp(np.linspace(0.0, 1.0, len(r)), [0.0, 0.4, 1.0], [0.0, 0.08, -0.03])
    r_end = {'none': None, 'next': np.append(r[1:], 0.2), 'random': r[::-1].copy()}[mode]
    return params, r, dl, r_end, 5e-3, 13


def run_columns(muscle: Muscle, r, dl, dt, r_end) -> np.ndarray:
    """`Muscle.run_array` with its columns as a (12, n) array."""
    return muscle.run_array(r, dl, dt, r_end).T.reshape(len(FIELDS), len(dl))


def assert_same_state(compiled: Muscle, reference: Muscle) -> None:
    for name in ('t_s', 'l_ce_m', 'dl_mt_m', 'recruitment', 'command', 'n_recruited',
                 'n_runs', 'mean_fitness'):
        assert getattr(compiled, name) == pytest.approx(getattr(reference, name), abs=ATOL), name
    np.testing.assert_allclose(compiled.outputs(), reference.outputs(), rtol=0, atol=ATOL)


@settings(max_examples=25, deadline=None)
@given(run_case())
@example(pinned_case('multi', 'initial', 'next', 1_000_000))
@example(pinned_case('single', 'instantaneous', 'random', 1000))
@example(pinned_case('multi', 'instantaneous', 'none', 7))
def test_compiled_run_gives_the_plain_runs_columns_and_state(case):
    params, r, dl, r_end, dt, split = case
    reference, built = plain(params), compiled(params)
    # In two calls, split anywhere: the state written back carries the run on.
    parts = [slice(0, split), slice(split, len(dl))]
    expected = np.concatenate(
        [run_columns(reference, r[s], dl[s], dt, None if r_end is None else r_end[s])
         for s in parts], axis=1)
    got = np.concatenate(
        [run_columns(built, r[s], dl[s], dt, None if r_end is None else r_end[s])
         for s in parts], axis=1)
    for row, name in enumerate(FIELDS):
        np.testing.assert_allclose(got[row], expected[row], rtol=0, atol=ATOL, err_msg=name)
    assert_same_state(built, reference)


@pytest.mark.parametrize('amplitude_m', [0.1, -0.1])
@pytest.mark.parametrize('units', ['multi', 'single'])
def test_an_instantaneous_ce_leaving_and_reentering_the_fl_range_alike_on_both_builds(
        units, amplitude_m):
    # A fast CE (b = b' = 1 m/s) and 5 ms steps: the free CE follows its MTU
    # stretched or shortened by 0.1 m out of the FL range; recruited there,
    # Eff.f_iso is zero and the CE stays free; on the way back its free length
    # re-enters the range and it resists again.
    params = MuscleParams(units=units, length='instantaneous', fv_b_m_per_s=1.0,
                          fv_b_ecc_m_per_s=1.0)
    dl = np.concatenate([np.linspace(0.0, amplitude_m, 50), np.full(50, amplitude_m),
                         np.linspace(amplitude_m, 0.0, 100)])
    r = np.concatenate([np.zeros(50), np.ones(len(dl) - 50)])
    reference, built = plain(params), compiled(params)
    expected = run_columns(reference, r, dl, 5e-3, None)
    f0 = expected[FIELDS.index('eff_f_iso_n')]
    assert f0[-1] > 0.0 and (f0 == 0.0).any()   # the case is reached, and left
    got = run_columns(built, r, dl, 5e-3, None)
    np.testing.assert_allclose(got, expected, rtol=0, atol=ATOL)
    assert_same_state(built, reference)


def test_simulate_gives_the_same_result_on_both_builds(monkeypatch):
    protocol = Protocol.from_yaml(resources.protocol_path('II'))
    monkeypatch.setenv(engine.ENV_VAR, 'compiled')
    got = simulate(protocol)
    monkeypatch.setenv(engine.ENV_VAR, 'python')
    expected = simulate(protocol)
    for name in FIELDS:
        np.testing.assert_allclose(getattr(got, name), getattr(expected, name),
                                   rtol=0, atol=ATOL, err_msg=name)


def run_python(code: str, **env) -> subprocess.CompletedProcess:
    """Run ``code`` in a fresh interpreter with ``env`` added to the environment."""
    return subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                          check=True, env={**os.environ, **env}, timeout=120)


#: For each engine named on the command line, in order and in one process: sets
#: it in the environment, simulates a short protocol, then builds a batch on the
#: default build; prints the value, the engine chosen, whether numba was
#: imported by then, and the batch's build.
ENGINE_PROBE = '''
import os, sys
from hill_muscle_ros.model import MuscleBatch, MuscleParams, Protocol, engine, simulate
for value in sys.argv[1:]:
    os.environ[engine.ENV_VAR] = value
    simulate(Protocol.from_mapping({"name": "probe", "duration_s": 0.05,
                                    "recruitment": [[0.0, 0.5]], "dl_mt_m": [[0.0, 0.0]]}))
    print(value, engine.choice(), "numba" in sys.modules, MuscleBatch([MuscleParams()]).build)
'''


def test_the_engine_in_the_environment_decides_simulate_and_batch():
    """One fresh process (numba's kernels loaded once, not once a value): python
    first, which must not import numba; then auto, which must import it and run
    the compiled build; then compiled. The engine is read at each run, not
    fixed at the first."""
    lines = subprocess.run([sys.executable, '-c', ENGINE_PROBE, 'python', 'auto', 'compiled'],
                           capture_output=True, text=True, check=True, timeout=120,
                           env={**os.environ, engine.ENV_VAR: 'python'}).stdout.splitlines()
    assert [line.split() for line in lines] == [
        ['python', 'python', 'False', 'python'],
        ['auto', 'compiled', 'True', 'compiled'],
        ['compiled', 'compiled', 'True', 'compiled'],
    ]


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


def test_without_a_writable_cache_the_kernels_compile_in_memory_and_warn_once(tmp_path):
    # NUMBA_CACHE_DIR below a regular file cannot be created (even by root),
    # and the locators are limited to that one, so numba finds no cache place.
    blocker = tmp_path / 'a_file'
    blocker.write_text('')
    cache_dir = blocker / 'numba_cache'
    # The model's equations compiled as every kernel set is (engine.compile_functions):
    # the same code path as the muscle's kernels, at a fraction of their compile
    # time (those took 70 s of CPU here, compiled in memory).
    code = '''
import warnings
from hill_muscle_ros.model import engine, equations
warnings.simplefilter('always')
names = ['force_length', 'series_force', 'force_velocity_inverse']
args = {'force_length': (1.1,), 'series_force': (1000.0, 0.01, 0.12, 0.125),
        'force_velocity_inverse': (20.0, 30.0, 10.0, 0.5, 10.0, 0.5)}
with warnings.catch_warnings(record=True) as caught:
    # Three functions compiled, each of which finds no cache: one warning.
    built = engine.compile_functions(vars(equations), names)
    got = [getattr(built, n)(*args[n]) for n in names]
print(len(caught), got == [getattr(equations, n)(*args[n]) for n in names])
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
    code = ('import sys; import hill_muscle_ros; from hill_muscle_ros.tools import cli; '
            'from hill_muscle_ros.model import Muscle, engine, simulate; '
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
