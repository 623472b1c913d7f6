"""MuscleBatch on both builds steps each muscle exactly as a separate Muscle.

The batch runs the one engine (model/muscle/batch_kernels.py over the muscle's
kernels), compiled by numba or as plain Python. Both builds must agree with
each other and with separate `Muscle` runs to 1e-9 N, on all four variants,
with the recruitment held and changing; a batch asked for the compiled build
without numba raises, and importing the package never imports numba.

numba is a runtime requirement, so these tests do not skip without it: they fail.
"""
import dataclasses
import math
import subprocess
import sys

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from hill_muscle_ros.model import Muscle, MuscleParams
from hill_muscle_ros.model.muscle import batch_kernels as fes_batch_kernels
from hill_muscle_ros.model.muscle import kernels as muscle_kernels
from hill_muscle_ros.model.muscle.batch import MuscleBatch

from test_model_engines import muscle_params


#: The module takes about 7 CPU-s: scheduled among the first (conftest).
pytestmark = pytest.mark.slow

#: [N] bound on compiled vs plain batch and vs separate muscles (as test_model_batch).
ATOL_N = 1e-9
#: [m], [m/s] bounds on CE length and velocity (as test_model_batch).
ATOL_STATE = 1e-12
#: Output fields that are forces [N].
FORCE_FIELDS = ('f_se_n', 'f_pe_n', 'force_n', 'eff_f_iso_n')
#: Output fields that must be identical: counts and the inputs echoed.
EXACT_FIELDS = ('recruitment', 'n_recruited', 'dl_mt_m', 'command', 'mean_fitness')


#: Units of a muscle that stands in for a drawn 1e6-unit muscle (see one_large_muscle).
STAND_IN_UNITS = 1000


def one_large_muscle(params: list, keep_large: bool) -> list:
    """``params`` with at most one muscle of 1e6 units, and none unless
    ``keep_large``: every other one drawn with 1e6 gets STAND_IN_UNITS. A
    1e6-unit muscle costs ~0.1-0.3 s of array set-up for each build and
    nothing more per step than 1000 units, and was most of these tests' time;
    a case that keeps one (its state laid out before or after the others')
    still tests the large layout."""
    seen = False
    kept = []
    for p in params:
        if p.n_units >= 1_000_000:
            if seen or not keep_large:
                p = dataclasses.replace(p, n_units=STAND_IN_UNITS)
            seen = True
        kept.append(p)
    return kept


@st.composite
def batch_case(draw, max_hold: int, params=None):
    """K parameter sets (variants mixed, or drawn from ``params``) and (T, K)
    inputs, each muscle's R held for 1..``max_hold`` steps (1: R may change on
    every step)."""
    k = draw(st.integers(1, 6))
    params = one_large_muscle(draw(st.lists(muscle_params() if params is None else params,
                                            min_size=k, max_size=k)),
                              keep_large=draw(st.integers(0, 3)) == 3)
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


def pinned_case(max_hold: int, seed: int = 3):
    """A fixed case of :func:`batch_case`: a 1e6-unit muscle between a 7-unit and
    a 1000-unit one, the four variants among four muscles, R held ``max_hold``
    steps at a time through 0 and 1, 40 steps of 1 ms."""
    params = [MuscleParams(n_units=7, units='single', length='instantaneous'),
              MuscleParams(n_units=1_000_000, units='multi', length='initial'),
              MuscleParams(n_units=1000, units='multi',
                           length='instantaneous', fv_b_m_per_s=1.0, fv_b_ecc_m_per_s=1.0),
              MuscleParams(n_units=1, units='single', length='initial')]   # the four variants
    rng = np.random.default_rng(seed)
    n_steps = 40
    held = np.repeat(np.arange(0, n_steps, max_hold), max_hold)[:n_steps]
    r = rng.choice([0.0, 0.3, 0.77, 1.0], size=(n_steps, 4))[held]
    dl = rng.uniform(-0.02, 0.02, size=(n_steps, 4))[held]
    return params, r, dl, 1e-3


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
    """Step the compiled batch, the plain batch and separate muscles alike."""
    params, r, dl, dt = case
    compiled = MuscleBatch(params, build='compiled')
    reference = MuscleBatch(params, build='python')
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


@settings(max_examples=20, deadline=None)
@given(batch_case(max_hold=10))
@example(pinned_case(max_hold=10))
def test_compiled_equals_plain_and_separate_muscles_with_recruitment_held(case):
    run_three_ways(case)


@settings(max_examples=20, deadline=None)
@given(batch_case(max_hold=1))
@example(pinned_case(max_hold=1))
def test_compiled_equals_plain_and_separate_muscles_with_recruitment_changing(case):
    run_three_ways(case)


#: multi/initial muscles with few units, so the segment stacks grow deep, fill,
#: drop whole segments and split them.
multi_initial_few_units = muscle_params().map(
    lambda p: dataclasses.replace(p, units='multi', length='initial',
                                  n_units=min(p.n_units, 7)))


def _multi_initial_few_units(case):
    params, *rest = case
    return ([dataclasses.replace(p, units='multi', length='initial', n_units=min(p.n_units, 7))
             for p in params], *rest)


@settings(max_examples=40, deadline=None)
@given(batch_case(max_hold=1, params=multi_initial_few_units))
@example(_multi_initial_few_units(pinned_case(max_hold=1)))
def test_memory_stacks_equal_plain_and_separate_muscles_with_recruitment_changing(case):
    run_three_ways(case)


def test_all_four_variants_on_the_compiled_engine_follow_their_own_model():
    variants = [MuscleParams(units=u, length=length)
                for u in ('multi', 'single') for length in ('initial', 'instantaneous')]
    batch = MuscleBatch(variants, build='compiled')
    muscles = [Muscle(p) for p in variants]
    for k in range(3000):
        r = 0.5 if k < 1500 else 1.0   # Protocol II's step in recruitment
        dl = 0.01 * math.sin(k * 1e-3)
        out = batch.step(r, dl, 1e-3)
        refs = [m.step(r, dl, 1e-3) for m in muscles]
        np.testing.assert_allclose(out.force_n, [x.force_n for x in refs], rtol=0, atol=ATOL_N)
    assert np.ptp(out.force_n) > 1.0   # the variants really differ


def test_fes_muscles_in_a_compiled_batch_follow_the_plain_batch():
    params = [MuscleParams(), MuscleParams(fatigue='riener', tau_fatigue_s=[0.5]),
              MuscleParams(units='single', tau_act_s=0.03, tau_deact_s=0.05)]
    compiled = MuscleBatch(params, build='compiled')
    reference = MuscleBatch(params, build='python')
    for k in range(600):
        r = 0.0 if k < 50 else (0.8 if k < 400 else 0.3)
        dl = 0.004 * math.sin(2 * math.pi * k / 300)
        assert_outputs_agree(compiled.step(r, dl, 1e-3), reference.step(r, dl, 1e-3),
                             f'step {k}')
    assert compiled.mean_fitness[1] < 1.0   # fatigue really ran


@pytest.mark.parametrize('engine', ['compiled', 'python'])
def test_outputs_and_state_are_not_shared_with_the_callers_arrays(engine):
    params = [MuscleParams(), MuscleParams(length='instantaneous'),
              MuscleParams(fatigue='riener', tau_fatigue_s=[0.5])]
    batch = MuscleBatch(params, build=engine)
    fresh = MuscleBatch(params, build=engine)
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


def test_a_full_memory_and_back_down_matches_separate_muscles():
    # Every unit recruited one at a time (N runs, the stack full), then
    # de-recruited one at a time, the CE length moving all the while.
    n_units = 7
    params = [MuscleParams(n_units=n_units), MuscleParams(n_units=n_units, f_iso_max_n=60.0)]
    batch = MuscleBatch(params, build='compiled')
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


def test_reset_erases_the_memory():
    params = [MuscleParams(), MuscleParams(units='single')]
    batch = MuscleBatch(params, build='compiled')
    fresh = MuscleBatch(params, build='compiled')
    for k in range(100):
        batch.step(0.2 + 0.7 * (k % 3) / 2, 0.003 * math.sin(k / 10), 1e-3)
    batch.reset()
    np.testing.assert_array_equal(batch.n_runs, 0)
    for k in range(100):
        r = 0.9 - 0.4 * (k % 4) / 3
        dl = 0.002 * math.cos(k / 7)
        assert_outputs_agree(batch.step(r, dl, 1e-3), fresh.step(r, dl, 1e-3), f'step {k}')


def test_without_numba_the_compiled_engine_asked_for_raises(monkeypatch):
    monkeypatch.setitem(sys.modules, 'numba', None)   # import numba raises ImportError
    monkeypatch.setattr(muscle_kernels, '_compiled', None)
    monkeypatch.setattr(fes_batch_kernels, '_compiled', None)
    with pytest.raises(ImportError, match='numba'):
        MuscleBatch([MuscleParams()], build='compiled')


def test_an_unknown_build_is_refused_by_name():
    with pytest.raises(ValueError, match="`build` must be 'compiled', 'python' or None, "
                                         "got 'cuda'"):
        MuscleBatch([MuscleParams()], build='cuda')


def test_package_import_and_a_plain_batch_import_no_numba():
    code = ('import sys; import hill_muscle_ros; from hill_muscle_ros.tools import cli; '
            'cli.build_parser(); import hill_muscle_ros.model.muscle.batch as b; '
            'from hill_muscle_ros.model import MuscleParams; '
            'b.MuscleBatch([MuscleParams()], build="python").step(0.5, 0.0, 1e-3); '
            'print("numba" in sys.modules, "llvmlite" in sys.modules)')
    out = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                         check=True).stdout
    assert out.strip() == 'False False'


@pytest.mark.parametrize('engine', ['compiled', 'python'])
@pytest.mark.parametrize('kwargs, message', [
    ({'recruitment': [0.5, math.nan]}, '`recruitment` must be in [0, 1], got nan for muscle 1'),
    ({'recruitment': [1.2, 0.5]}, '`recruitment` must be in [0, 1], got 1.2 for muscle 0'),
    ({'dl_mt_m': [0.0, -math.inf]}, '`dl_mt_m` must be finite and within ±1.0 m of rest, '
                                    'got -inf for muscle 1'),
    ({'dl_mt_m': [0.0, 0.0, 0.0]}, '`dl_mt_m` must have shape (2,), got (3,)'),
    ({'dt_s': math.nan}, '`dt_s` must be positive and finite, got nan'),
    # Two bad inputs: dl_MT is named first, as by Muscle.step.
    ({'dl_mt_m': [2.0, 0.0], 'recruitment': [-1.0, 0.5]}, '`dl_mt_m` must be finite'),
    ({'dt_s': 0.0, 'recruitment': [-1.0, 0.5]}, '`dt_s` must be positive'),
])
def test_bad_input_raises_the_same_error_on_both_builds_and_changes_nothing(
        engine, kwargs, message):
    batch = MuscleBatch([MuscleParams(), MuscleParams(length='instantaneous')], build=engine)
    for _ in range(50):
        batch.step([0.7, 0.3], [0.003, 0.001], 1e-3)
    before = batch.outputs()
    args = {'recruitment': [0.7, 0.3], 'dl_mt_m': [0.003, 0.001], 'dt_s': 1e-3, **kwargs}
    with pytest.raises(ValueError) as err:
        batch.step(**args)
    assert str(err.value).startswith(message)
    for a, b in zip(before, batch.outputs()):
        np.testing.assert_array_equal(a, b)
