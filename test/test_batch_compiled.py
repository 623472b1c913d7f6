"""The compiled batch engine (numba) steps muscles exactly like the NumPy one.

The NumPy engine of :class:`MuscleBatch` is the reference (it is checked against
separate `Muscle` runs in test_model_batch.py); the compiled engine must agree
with it and with separate `Muscle` runs to 1e-9 N, on all four variants, with
the recruitment held and changing. Without numba, the batch falls back to the
NumPy engine, and importing the package never imports numba.

numba is a runtime requirement, so these tests do not skip without it: they fail.
Compile time: the kernel is compiled once per checkout and then loaded from
numba's on-disk cache (``cache=True``); every test here shares it.
"""
import dataclasses
import math
import subprocess
import sys

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hill_muscle_ros.model import Muscle, MuscleParams, kernels
from hill_muscle_ros.model.batch import MuscleBatch

from test_model_engines import muscle_params

#: [N] bound on compiled vs NumPy batch and vs separate muscles (as test_model_batch).
ATOL_N = 1e-9
#: [m], [m/s] bounds on CE length and velocity (as test_model_batch).
ATOL_STATE = 1e-12
#: Output fields that are forces [N].
FORCE_FIELDS = ('f_se_n', 'f_pe_n', 'force_n', 'eff_f_iso_n')
#: Output fields that must be identical: counts and the inputs echoed.
EXACT_FIELDS = ('recruitment', 'n_recruited', 'dl_mt_m', 'command', 'mean_fitness')


@st.composite
def batch_case(draw, max_hold: int, params=None):
    """K parameter sets (variants mixed, or drawn from ``params``) and (T, K)
    inputs, each muscle's R held for 1..``max_hold`` steps (1: R may change on
    every step)."""
    k = draw(st.integers(1, 6))
    params = draw(st.lists(muscle_params() if params is None else params, min_size=k,
                           max_size=k))
    n_steps = draw(st.integers(1, 60))
    r = np.empty((n_steps, k))
    dl = np.empty((n_steps, k))
    levels = st.floats(0.0, 1.0) | st.just(0.0) | st.just(1.0)
    for j in range(k):
        t = 0
        while t < n_steps:
            hold = draw(st.integers(1, max_hold))
            r[t:t + hold, j] = draw(levels)
            dl[t:t + hold, j] = draw(st.floats(-0.02, 0.02))
            t += hold
    dt = draw(st.sampled_from([1e-4, 1e-3]))
    return params, r, dl, dt


def _within(a, b, tol) -> bool:
    """|a - b| <= tol everywhere, same shapes: the bound of the asserts below in
    one array operation (numpy.testing's asserts and pytest.approx per value
    were most of this module's time). False on NaN: the asserts judge those."""
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    return a.shape == b.shape and bool(np.all(np.abs(a - b) <= tol))


def _agree(out, ref) -> bool:
    """Whether :func:`assert_outputs_agree` would pass, cheaply; when not, it
    runs its asserts for the message."""
    return (out.t_s == ref.t_s
            and all(_within(getattr(out, n), getattr(ref, n), ATOL_N) for n in FORCE_FIELDS)
            and all(_within(getattr(out, n), getattr(ref, n), ATOL_STATE)
                    for n in ('l_ce_m', 'v_ce_m_per_s'))
            and all(np.array_equal(getattr(out, n), getattr(ref, n)) for n in EXACT_FIELDS))


def assert_outputs_agree(out, ref, label=''):
    """Two BatchOutputs (or a batch row and a MuscleOutputs) agree to the bounds."""
    if _agree(out, ref):
        return
    for name in FORCE_FIELDS:
        np.testing.assert_allclose(getattr(out, name), getattr(ref, name), rtol=0,
                                   atol=ATOL_N, err_msg=f'{name} {label}')
    for name in ('l_ce_m', 'v_ce_m_per_s'):
        np.testing.assert_allclose(getattr(out, name), getattr(ref, name), rtol=0,
                                   atol=ATOL_STATE, err_msg=f'{name} {label}')
    for name in EXACT_FIELDS:
        np.testing.assert_array_equal(getattr(out, name), getattr(ref, name),
                                      err_msg=f'{name} {label}')
    assert out.t_s == ref.t_s


def run_three_ways(case):
    """Step the compiled batch, the NumPy batch and separate muscles alike."""
    params, r, dl, dt = case
    compiled = MuscleBatch(params, engine='compiled')
    reference = MuscleBatch(params, engine='numpy')
    muscles = [Muscle(p) for p in params]
    for k, (rk, dlk) in enumerate(zip(r, dl)):
        out = compiled.step(rk, dlk, dt)
        assert_outputs_agree(out, reference.step(rk, dlk, dt), f'step {k}')
        refs = [m.step(rk[i], dlk[i], dt) for i, m in enumerate(muscles)]
        if (_within(out.force_n, [x.force_n for x in refs], ATOL_N)
                and _within(out.eff_f_iso_n, [x.eff_f_iso_n for x in refs], ATOL_N)
                and _within(out.l_ce_m, [x.l_ce_m for x in refs], ATOL_STATE)
                and np.array_equal(out.n_recruited, [x.n_recruited for x in refs])):
            continue   # the asserts below pass; they run for the message otherwise
        for i, ref in enumerate(refs):
            assert out.force_n[i] == pytest.approx(ref.force_n, abs=ATOL_N)
            assert out.eff_f_iso_n[i] == pytest.approx(ref.eff_f_iso_n, abs=ATOL_N)
            assert out.l_ce_m[i] == pytest.approx(ref.l_ce_m, abs=ATOL_STATE)
            assert out.n_recruited[i] == ref.n_recruited
    np.testing.assert_array_equal(compiled.n_runs, reference.n_runs)
    np.testing.assert_array_equal(compiled.n_runs, [m.n_runs for m in muscles])
    assert_outputs_agree(compiled.outputs(), reference.outputs(), 'outputs()')


@settings(max_examples=80, deadline=None)
@given(batch_case(max_hold=10))
def test_compiled_equals_numpy_and_separate_muscles_with_recruitment_held(case):
    run_three_ways(case)


@settings(max_examples=80, deadline=None)
@given(batch_case(max_hold=1))
def test_compiled_equals_numpy_and_separate_muscles_with_recruitment_changing(case):
    run_three_ways(case)


#: multi/initial muscles with few units, so the run stacks grow deep, fill,
#: drop whole runs and trim them.
multi_initial_few_units = muscle_params().map(
    lambda p: dataclasses.replace(p, units='multi', length='initial',
                                  n_units=min(p.n_units, 7)))


@settings(max_examples=80, deadline=None)
@given(batch_case(max_hold=1, params=multi_initial_few_units))
def test_compiled_run_stacks_equal_numpy_and_separate_muscles_with_recruitment_changing(case):
    run_three_ways(case)


def test_all_four_variants_on_the_compiled_engine_follow_their_own_model():
    variants = [MuscleParams(units=u, length=length)
                for u in ('multi', 'single') for length in ('initial', 'instantaneous')]
    batch = MuscleBatch(variants, engine='compiled')
    muscles = [Muscle(p) for p in variants]
    for k in range(3000):
        r = 0.5 if k < 1500 else 1.0   # Protocol II's step in recruitment
        dl = 0.01 * math.sin(k * 1e-3)
        out = batch.step(r, dl, 1e-3)
        refs = [m.step(r, dl, 1e-3) for m in muscles]
        np.testing.assert_allclose(out.force_n, [x.force_n for x in refs], rtol=0, atol=ATOL_N)
    assert np.ptp(out.force_n) > 1.0   # the variants really differ


def test_fes_muscles_in_a_compiled_batch_follow_their_scalar_engine():
    params = [MuscleParams(), MuscleParams(fatigue='riener', tau_fatigue_s=[0.5]),
              MuscleParams(units='single', tau_act_s=0.03, tau_deact_s=0.05)]
    compiled = MuscleBatch(params, engine='compiled')
    reference = MuscleBatch(params, engine='numpy')
    for k in range(600):
        r = 0.0 if k < 50 else (0.8 if k < 400 else 0.3)
        dl = 0.004 * math.sin(2 * math.pi * k / 300)
        assert_outputs_agree(compiled.step(r, dl, 1e-3), reference.step(r, dl, 1e-3),
                             f'step {k}')
    assert compiled.mean_fitness[1] < 1.0   # fatigue really ran


@pytest.mark.parametrize('engine', ['compiled', 'numpy'])
def test_outputs_and_state_are_not_shared_with_the_callers_arrays(engine):
    params = [MuscleParams(), MuscleParams(length='instantaneous'),
              MuscleParams(fatigue='riener', tau_fatigue_s=[0.5])]
    batch = MuscleBatch(params, engine=engine)
    fresh = MuscleBatch(params, engine=engine)
    r, dl = np.zeros(3), np.zeros(3)
    kept = []
    for k in range(200):
        # One input array refilled in place, as a control loop does.
        r[:] = 0.0 if k % 50 < 5 else 0.6
        dl[:] = 0.003 * math.sin(k / 20)
        out = batch.step(r, dl, 1e-3)
        kept.append(np.copy(out.l_ce_m))
        ref = fresh.step(r.copy(), dl.copy(), 1e-3)
        assert_outputs_agree(out, ref, f'step {k}')
        if k > 0:
            # The previous step's outputs are untouched by this step.
            np.testing.assert_array_equal(previous.l_ce_m, kept[-2])
        previous = out


@pytest.mark.parametrize('lengths', [('initial', 'instantaneous'), ('initial',)])
def test_the_serial_loop_one_thread_and_all_threads_give_the_same_numbers(monkeypatch, lengths):
    import numba
    k = 64
    rng = np.random.default_rng(3)
    params = [MuscleParams(units=('multi', 'single')[i % 2], length=lengths[i // 2 % len(lengths)],
                           f_iso_max_n=float(f)) for i, f in enumerate(rng.uniform(30, 60, k))]
    before = numba.get_num_threads()
    outs = {}
    try:
        # The serial loop (K below PARALLEL_MIN_K), then the parallel loop
        # (this small K on every thread) on one thread and on all of them.
        for threads, min_k in ((1, k + 1), (1, 1), (numba.config.NUMBA_NUM_THREADS, 1)):
            monkeypatch.setattr(kernels, 'PARALLEL_MIN_K', min_k)
            numba.set_num_threads(threads)
            batch = MuscleBatch(params, engine='compiled')
            reference = MuscleBatch(params, engine='numpy')
            inputs = np.random.default_rng(4)
            for j in range(200):
                r = inputs.uniform(0, 1, k) if j % 50 == 0 else batch.recruitment
                dl = 0.005 * math.sin(j / 30)
                out = batch.step(r, dl, 1e-3)
                assert_outputs_agree(out, reference.step(r, dl, 1e-3), f'step {j}')
            outs[threads, min_k] = out
    finally:
        numba.set_num_threads(before)
    serial, *parallel = outs.values()
    for other in parallel:
        for a, b in zip(serial, other):
            np.testing.assert_array_equal(a, b)


def test_a_small_batch_leaves_the_number_of_threads_as_it_was():
    import numba
    batch = MuscleBatch([MuscleParams()] * 3, engine='compiled')
    before = numba.get_num_threads()
    batch.step(0.5, 0.001, 1e-3)
    assert numba.get_num_threads() == before


def test_the_kernel_runs_as_plain_python_with_the_compiled_results():
    # Written once: the same functions, not compiled, give the same numbers.
    params = [MuscleParams(units=u, length=length, f_iso_max_n=40.0 + i)
              for i, (u, length) in enumerate([('multi', 'initial'), ('single', 'initial'),
                                               ('multi', 'instantaneous'),
                                               ('single', 'instantaneous')] * 2)]
    batch = MuscleBatch(params, engine='compiled')
    rng = np.random.default_rng(5)
    batch.step(rng.uniform(0.0, 1.0, len(params)), 0.002, 1e-3)
    args = (batch.l_ce_m, batch.dl_mt_m, rng.uniform(-0.01, 0.01, len(params)), 1e-3,
            batch._gain, batch._v_ce, True, batch._initial, False, batch._param_rows)
    python_out = np.empty((kernels.N_OUTPUTS, len(params)))
    compiled_out = np.empty_like(python_out)
    kernels.step_all(*args, python_out, False)
    kernels.compiled().step_all(*args, compiled_out, False)
    np.testing.assert_array_equal(python_out, compiled_out)


def test_the_recruitment_bookkeeping_runs_as_plain_python_with_the_compiled_results():
    # Written once: kernels.recruit_all and memory.stack_update, not compiled,
    # give the same numbers as compiled, over many changes of every variant.
    params = [MuscleParams(units=u, length=length, n_units=n)
              for u, length, n in [('multi', 'initial', 7), ('single', 'initial', 1000),
                                   ('multi', 'instantaneous', 1000),
                                   ('single', 'instantaneous', 1000),
                                   ('multi', 'initial', 1000)]]
    batches = [MuscleBatch(params, engine='compiled') for _ in range(2)]
    rng = np.random.default_rng(6)
    names = ('recruitment', 'n_recruited', '_gain', '_f_iso_single', '_stack_top',
             '_stack_count', '_stack_f_unit', '_stack_total')
    deepest = 0
    for k in range(300):
        # Mostly partial levels, so stacks grow; 0 and 1 now and then.
        r = rng.choice([0.0, 1.0, *rng.uniform(size=8)], size=len(params))
        l_ce = rng.uniform(0.05, 0.15, len(params))
        changes = []
        for batch, recruit_all in zip(batches, (kernels.recruit_all,
                                                kernels.compiled().recruit_all)):
            batch.l_ce_m = l_ce.copy()
            changes.append(recruit_all(
                r, batch.recruitment, batch.n_recruited, batch._gain, batch._f_iso_single,
                batch.l_ce_m, batch._multi, batch._initial, batch._n_units, batch._f_iso_max,
                batch._l_opt, batch._stack_base, batch._stack_top, batch._stack_count,
                batch._stack_f_unit, batch._stack_total))
        assert changes[0] == changes[1], f'step {k}'
        for name in names:
            np.testing.assert_array_equal(getattr(batches[0], name), getattr(batches[1], name),
                                          err_msg=f'{name} step {k}')
        deepest = max(deepest, batches[0]._stack_top.max())
    assert deepest > 2   # the stacks really held several runs


def test_only_multi_initial_muscles_get_a_run_stack_of_n_plus_one_entries():
    params = [MuscleParams(units='single'), MuscleParams(n_units=7),
              MuscleParams(length='instantaneous'), MuscleParams(n_units=1000),
              MuscleParams(units='single', length='instantaneous')]
    batch = MuscleBatch(params, engine='compiled')
    assert batch._stack_count.size == (7 + 1) + (1000 + 1)
    assert batch._stack_f_unit.size == batch._stack_total.size == batch._stack_count.size
    assert list(batch._stack_base[[1, 3]]) == [0, 8]
    assert MuscleBatch(params[:1] + params[2:3], engine='compiled')._stack_count.size == 0


def test_a_full_run_stack_and_back_down_on_the_compiled_engine_matches_separate_muscles():
    # Every unit recruited one at a time (N runs, the stack full), then
    # de-recruited one at a time, the CE length moving all the while.
    n_units = 7
    params = [MuscleParams(n_units=n_units), MuscleParams(n_units=n_units, f_iso_max_n=60.0)]
    batch = MuscleBatch(params, engine='compiled')
    muscles = [Muscle(p) for p in params]
    levels = [m / n_units for m in range(n_units + 1)]
    for k, r in enumerate(levels + levels[::-1] + levels):
        dl = 0.004 * math.sin(k / 3)
        out = batch.step(r, dl, 1e-3)
        for i, muscle in enumerate(muscles):
            ref = muscle.step(r, dl, 1e-3)
            assert out.eff_f_iso_n[i] == pytest.approx(ref.eff_f_iso_n, abs=ATOL_N)
            assert out.force_n[i] == pytest.approx(ref.force_n, abs=ATOL_N)
        if k == n_units:
            np.testing.assert_array_equal(batch.n_runs, n_units)
    np.testing.assert_array_equal(batch.n_runs, [m.n_runs for m in muscles])


def test_reset_erases_the_run_stacks_of_the_compiled_engine():
    params = [MuscleParams(), MuscleParams(units='single')]
    batch = MuscleBatch(params, engine='compiled')
    fresh = MuscleBatch(params, engine='compiled')
    for k in range(100):
        batch.step(0.2 + 0.7 * (k % 3) / 2, 0.003 * math.sin(k / 10), 1e-3)
    batch.reset()
    np.testing.assert_array_equal(batch.n_runs, 0)
    for k in range(100):
        r = 0.9 - 0.4 * (k % 4) / 3
        dl = 0.002 * math.cos(k / 7)
        assert_outputs_agree(batch.step(r, dl, 1e-3), fresh.step(r, dl, 1e-3), f'step {k}')


def test_without_numba_auto_falls_back_to_numpy_with_the_same_results(monkeypatch):
    params = [MuscleParams(units=u, length=length)
              for u in ('multi', 'single') for length in ('initial', 'instantaneous')]
    compiled = MuscleBatch(params)
    assert compiled.engine == 'compiled'
    monkeypatch.setitem(sys.modules, 'numba', None)   # import numba raises ImportError
    monkeypatch.setattr(kernels, '_compiled', None)
    fallback = MuscleBatch(params)
    assert fallback.engine == 'numpy'
    for k in range(300):
        r = 0.3 if k < 150 else 0.9
        assert_outputs_agree(fallback.step(r, 0.002, 1e-3), compiled.step(r, 0.002, 1e-3))


def test_without_numba_the_compiled_engine_asked_for_raises(monkeypatch):
    monkeypatch.setitem(sys.modules, 'numba', None)
    monkeypatch.setattr(kernels, '_compiled', None)
    with pytest.raises(ImportError, match='numba'):
        MuscleBatch([MuscleParams()], engine='compiled')


def test_an_unknown_engine_is_refused_by_name():
    with pytest.raises(ValueError, match="`engine` must be one of auto, compiled, numpy, "
                                         "got 'cuda'"):
        MuscleBatch([MuscleParams()], engine='cuda')


def test_package_import_and_a_numpy_batch_import_no_numba():
    code = ('import sys; import hill_muscle_ros; from hill_muscle_ros.tools import cli; '
            'cli.build_parser(); import hill_muscle_ros.model.batch as b; '
            'from hill_muscle_ros.model import MuscleParams; '
            'b.MuscleBatch([MuscleParams()], engine="numpy").step(0.5, 0.0, 1e-3); '
            'print("numba" in sys.modules, "llvmlite" in sys.modules)')
    out = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                         check=True).stdout
    assert out.strip() == 'False False'


@pytest.mark.parametrize('engine', ['compiled', 'numpy'])
@pytest.mark.parametrize('kwargs, message', [
    ({'recruitment': [0.5, math.nan]}, '`recruitment` must be in [0, 1], got nan for muscle 1'),
    ({'recruitment': [1.2, 0.5]}, '`recruitment` must be in [0, 1], got 1.2 for muscle 0'),
    ({'dl_mt_m': [0.0, -math.inf]}, '`dl_mt_m` must be finite and within ±1.0 m of rest, '
                                    'got -inf for muscle 1'),
    ({'dl_mt_m': [0.0, 0.0, 0.0]}, '`dl_mt_m` must have shape (2,), got (3,)'),
    ({'dt_s': math.nan}, '`dt_s` must be positive and finite, got nan'),
    # Two bad inputs: dl_MT is named first, as on the NumPy engine.
    ({'dl_mt_m': [2.0, 0.0], 'recruitment': [-1.0, 0.5]}, '`dl_mt_m` must be finite'),
    ({'dt_s': 0.0, 'recruitment': [-1.0, 0.5]}, '`dt_s` must be positive'),
])
def test_bad_input_raises_the_same_error_on_both_engines_and_changes_nothing(
        engine, kwargs, message):
    batch = MuscleBatch([MuscleParams(), MuscleParams(length='instantaneous')], engine=engine)
    for _ in range(50):
        batch.step([0.7, 0.3], [0.003, 0.001], 1e-3)
    before = batch.outputs()
    args = {'recruitment': [0.7, 0.3], 'dl_mt_m': [0.003, 0.001], 'dt_s': 1e-3, **kwargs}
    with pytest.raises(ValueError) as err:
        batch.step(**args)
    assert str(err.value).startswith(message)
    for a, b in zip(before, batch.outputs()):
        np.testing.assert_array_equal(a, b)
