"""The batch API steps K muscles exactly like K separate `Muscle`s."""
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hill_muscle_ros.model import Muscle, MuscleParams
from hill_muscle_ros.model.muscle.batch import MuscleBatch

from test_batch_compiled import one_large_muscle
from test_model_engines import muscle_params

#: [N] bound on batch vs single-muscle runs (the batch follows Muscle.step exactly).
ATOL_N = 1e-9


@st.composite
def batch_case(draw):
    """K parameter sets (variants mixed) and a (T, K) input sequence.

    Each muscle holds its recruitment for a random number of steps, so steps
    where only some muscles change occur, as well as steps where none do.
    """
    k = draw(st.integers(1, 6))
    params = one_large_muscle(draw(st.lists(muscle_params(), min_size=k, max_size=k)),
                              keep_large=draw(st.integers(0, 3)) == 3)
    n_steps = draw(st.integers(1, 80))
    r = np.empty((n_steps, k))
    dl = np.empty((n_steps, k))
    levels = st.floats(0.0, 1.0) | st.just(0.0) | st.just(1.0)
    for j in range(k):
        t = 0
        while t < n_steps:
            hold = draw(st.integers(1, 10))
            r[t:t + hold, j] = draw(levels)
            dl[t:t + hold, j] = draw(st.floats(-0.02, 0.02))
            t += hold
    dt = draw(st.sampled_from([1e-4, 1e-3]))
    return params, r, dl, dt


@settings(max_examples=20, deadline=None)
@given(batch_case())
def test_batch_equals_separate_muscles_to_1e_9_newton(case):
    params, r, dl, dt = case
    batch = MuscleBatch(params)
    muscles = [Muscle(p) for p in params]
    for rk, dlk in zip(r, dl):
        out = batch.step(rk, dlk, dt)
        for i, m in enumerate(muscles):
            ref = m.step(rk[i], dlk[i], dt)
            assert out.force_n[i] == pytest.approx(ref.force_n, abs=ATOL_N)
            assert out.f_se_n[i] == pytest.approx(ref.f_se_n, abs=ATOL_N)
            assert out.eff_f_iso_n[i] == pytest.approx(ref.eff_f_iso_n, abs=ATOL_N)
            assert out.l_ce_m[i] == pytest.approx(ref.l_ce_m, abs=1e-12)
            assert out.v_ce_m_per_s[i] == pytest.approx(ref.v_ce_m_per_s, abs=1e-12)
            assert out.n_recruited[i] == ref.n_recruited


def test_all_four_variants_in_one_batch_follow_their_own_model():
    variants = [MuscleParams(units=u, length=length)
                for u in ('multi', 'single') for length in ('initial', 'instantaneous')]
    batch = MuscleBatch(variants)
    muscles = [Muscle(p) for p in variants]
    for k in range(3000):
        r = 0.5 if k < 1500 else 1.0   # Protocol II's step in recruitment
        dl = 0.01 * math.sin(k * 1e-3)
        out = batch.step(r, dl, 1e-3)
        refs = [m.step(r, dl, 1e-3) for m in muscles]
        np.testing.assert_allclose(out.force_n, [x.force_n for x in refs], rtol=0, atol=ATOL_N)
    # The variants really differ, so the batch kept them apart.
    assert np.ptp(out.force_n) > 1.0


def test_reset_returns_every_muscle_to_rest():
    batch = MuscleBatch([MuscleParams(), MuscleParams(units='single')])
    for _ in range(100):
        batch.step([1.0, 0.4], [0.005, 0.0], 1e-3)
    batch.reset()
    out = batch.outputs()
    np.testing.assert_array_equal(out.force_n, 0.0)
    np.testing.assert_array_equal(out.l_ce_m, [p.l_rest_m for p in batch.params])
    np.testing.assert_array_equal(batch.n_runs, 0)


def test_scalar_inputs_apply_to_every_muscle():
    batch = MuscleBatch([MuscleParams()] * 3)
    out = batch.step(0.5, 0.0, 1e-3)
    np.testing.assert_array_equal(out.n_recruited, [500, 500, 500])


@pytest.mark.parametrize('kwargs, name', [
    ({'recruitment': [0.5, math.nan]}, 'recruitment'),
    ({'recruitment': [0.5, 1.2]}, 'recruitment'),
    ({'dl_mt_m': [0.0, math.inf]}, 'dl_mt_m'),
    ({'dl_mt_m': [0.0, 0.0, 0.0]}, 'dl_mt_m'),
    ({'dt_s': 0.0}, 'dt_s'),
])
def test_bad_batch_input_raises_and_leaves_the_state_unchanged(kwargs, name):
    batch = MuscleBatch([MuscleParams(), MuscleParams(length='instantaneous')])
    for _ in range(50):
        batch.step([0.7, 0.3], [0.003, 0.001], 1e-3)
    before = batch.outputs()
    args = {'recruitment': [0.7, 0.3], 'dl_mt_m': [0.003, 0.001], 'dt_s': 1e-3, **kwargs}
    with pytest.raises(ValueError, match=f'`{name}`'):
        batch.step(**args)
    after = batch.outputs()
    for a, b in zip(before, after):
        np.testing.assert_array_equal(a, b)


def test_empty_batch_is_rejected():
    with pytest.raises(ValueError, match='`params`'):
        MuscleBatch([])


@pytest.mark.parametrize('engine', ['python', 'compiled'])
def test_a_step_longer_than_1_ms_is_substepped_as_separate_muscles_do(engine):
    """Steps of 2.5 ms and 4 ms (3 and 4 substeps): every muscle of the batch,
    the paper's four variants and an FES muscle (delay, activation), ends each
    step where its own Muscle.step (which substeps) ends."""
    params = [MuscleParams(units=u, length=length)
              for u in ('multi', 'single') for length in ('initial', 'instantaneous')]
    params.append(MuscleParams(emd_s=0.005, tau_act_s=0.02, tau_deact_s=0.03, n_units=50))
    batch = MuscleBatch(params, build=engine)
    muscles = [Muscle(p) for p in params]
    for k in range(200):
        dt = 2.5e-3 if k % 3 else 4e-3
        r = (0.3, 0.8, 0.0)[(k // 40) % 3]
        dl = 0.01 * math.sin(0.05 * k)
        out = batch.step(r, dl, dt)
        refs = [m.step(r, dl, dt) for m in muscles]
        np.testing.assert_allclose(out.force_n, [x.force_n for x in refs], rtol=0, atol=ATOL_N)
        np.testing.assert_allclose(out.l_ce_m, [x.l_ce_m for x in refs], rtol=0, atol=1e-12)
        np.testing.assert_array_equal(out.n_recruited, [x.n_recruited for x in refs])
