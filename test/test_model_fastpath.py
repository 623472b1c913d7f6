"""The hot loop (`Muscle.run`) equals the readable model built from equations.py.

`Muscle.run` inlines Eq. 1, Eq. 3 and the springs for speed and reuses the
output velocity as the first RK4 stage. The reference here steps the same
muscle with the scalar functions of :mod:`hill_muscle_ros.model.equations` and
:meth:`Muscle.outputs`, exactly as doc/model.md section 4 describes, so any
difference is a bug in the fast path.
"""
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hill_muscle_ros.model import Muscle, MuscleOutputs, MuscleParams, Protocol, simulate
from hill_muscle_ros.model.equations import force_velocity_inverse, series_force

#: Equal up to rounding: the fast path evaluates the same expressions.
ATOL_N = 1e-12
ATOL_M = 1e-15


def muscle_params():
    """Random but physically sensible parameters in every variant."""
    return st.builds(
        MuscleParams,
        f_iso_max_n=st.floats(1.0, 100.0),
        k_se_n_per_m=st.floats(1e3, 5e4),
        k_pe_n_per_m=st.floats(1e2, 1e4),
        l_rest_m=st.floats(0.08, 0.16),
        l_opt_m=st.floats(0.101, 0.14),   # l_rest / l_opt < 1.597: FL at rest > 1 %
        fv_a_n=st.floats(2.0, 40.0),
        # Fast CEs too: at a 10 ms step their RK4 carries the instantaneous CE
        # out of the FL range, and its free length may be back inside it.
        fv_b_m_per_s=st.floats(0.01, 0.1) | st.floats(0.5, 2.0),
        fv_a_ecc_n=st.floats(2.0, 40.0),
        fv_b_ecc_m_per_s=st.floats(0.01, 0.1),
        n_units=st.sampled_from([1, 7, 1000, 1_000_000]),
        units=st.sampled_from(['multi', 'single']),
        length=st.sampled_from(['initial', 'instantaneous']),
    )


def input_sequences(max_size=120):
    """(R, dl_MT) pairs, each held for a few steps so held and changing R both occur."""
    pair = st.tuples(st.floats(0.0, 1.0) | st.just(0.0) | st.just(1.0),
                     st.floats(-0.02, 0.02), st.integers(1, 5))
    return st.lists(pair, min_size=1, max_size=max_size).map(
        lambda seq: [(r, dl) for r, dl, n in seq for _ in range(n)])


def reference_step(m: Muscle, r: float, dl1: float, dt: float):
    """One step of doc/model.md section 4 with RK4, written with the scalar curves."""
    p = m.params
    initial = p.length == 'initial'
    hill = (p.fv_a_n, p.fv_b_m_per_s, p.fv_a_ecc_n, p.fv_b_ecc_m_per_s)
    m.set_recruitment(r)
    f0 = m.eff_f_iso()

    def rate(l_ce, f_se):
        f0_l = f0 if initial else m.eff_f_iso(l_ce)
        return force_velocity_inverse(f_se, f0_l, *hill)

    k_se = p.k_se_n_per_m
    dl0, l0 = m.dl_mt_m, m.l_ce_m
    if f0 > 0.0:
        dlm = 0.5 * (dl0 + dl1)
        h = 0.5 * dt
        # A stage's SE force k_SE (dl - (l0 + h k - l_rest)) rounded as the
        # engines round it: k_SE (dl - (l0 - l_rest)) - k_SE h k (negative when
        # slack, which Eq. 3 inverted takes as series_force's 0).
        f_mid, f_end = k_se * (dlm - (l0 - p.l_rest_m)), k_se * (dl1 - (l0 - p.l_rest_m))
        k1 = rate(l0, series_force(k_se, dl0, l0, p.l_rest_m))
        k2 = rate(l0 + h * k1, f_mid - k_se * h * k1)
        k3 = rate(l0 + h * k2, f_mid - k_se * h * k2)
        k4 = rate(l0 + dt * k3, f_end - k_se * dt * k3)
        l1 = l0 + dt / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)   # h / 6 first, as the engines
    else:
        l1 = p.l_rest_m + dl1
    m.l_ce_m, m.dl_mt_m, m.t_s = l1, dl1, m.t_s + dt
    if not initial and m.eff_f_iso() == 0.0:
        m.l_ce_m = p.l_rest_m + dl1
    m._v_free = (dl1 - dl0) / dt
    return m.outputs()


def assert_outputs_equal(fast, ref):
    assert fast.recruitment == ref.recruitment
    assert fast.n_recruited == ref.n_recruited
    assert fast.dl_mt_m == ref.dl_mt_m
    assert fast.l_ce_m == pytest.approx(ref.l_ce_m, abs=ATOL_M)
    assert fast.v_ce_m_per_s == pytest.approx(ref.v_ce_m_per_s, abs=ATOL_M)
    for name in ('f_se_n', 'f_pe_n', 'force_n', 'eff_f_iso_n'):
        assert getattr(fast, name) == pytest.approx(getattr(ref, name), abs=ATOL_N), name


@settings(max_examples=200, deadline=None)
@given(muscle_params(), input_sequences(), st.sampled_from([1e-4, 1e-3, 2e-3, 1e-2]))
def test_step_equals_the_readable_reference_in_every_variant(params, sequence, dt):
    fast, ref = Muscle(params), Muscle(params)
    for r, dl in sequence:
        # One RK4 step of dt each (run: step cuts a dt above 1 ms into substeps).
        assert_outputs_equal(fast.run((r,), (dl,), dt), reference_step(ref, r, dl, dt))


@settings(max_examples=100, deadline=None)
@given(muscle_params(), input_sequences(), st.sampled_from([1e-3, 1e-2]))
def test_step_outputs_equal_outputs_derived_from_the_state(params, sequence, dt):
    """What the hot loop returns is what the curve-based `outputs()` reads off the state."""
    m = Muscle(params)
    for r, dl in sequence:
        assert_outputs_equal(m.step(r, dl, dt), m.outputs())


@settings(max_examples=60, deadline=None)
@given(muscle_params(), input_sequences(max_size=60), st.sampled_from([1e-3, 1e-2]))
def test_run_over_a_sequence_equals_stepping_one_at_a_time(params, sequence, dt):
    batch, single = Muscle(params), Muscle(params)
    r = [x for x, _ in sequence]
    dl = [x for _, x in sequence]
    columns = [[None] * len(sequence) for _ in range(len(MuscleOutputs._fields))]
    last = batch.run(r, dl, dt, columns=columns)
    for k, (rk, dlk) in enumerate(sequence):
        out = single.run((rk,), (dlk,), dt)   # one RK4 step of dt, as each of the batch's
        assert tuple(col[k] for col in columns) == out
    assert last == out


@pytest.mark.parametrize('units', ['multi', 'single'])
@pytest.mark.parametrize('length', ['initial', 'instantaneous'])
@pytest.mark.parametrize('name', ['I', 'II'])
def test_simulate_equals_the_reference_step_loop(protocol_paths, name, units, length):
    """`simulate` (the CLI's path) samples R(t_k) after each step, like set_recruitment + outputs."""
    proto = Protocol.from_yaml(protocol_paths[name])
    params = MuscleParams(units=units, length=length)
    run = simulate(proto, params, 1000.0)
    r = proto.recruitment(run.t_s, params.pw_max_s)
    dl = proto.dl_mt(run.t_s)
    ref = Muscle(params)
    ref.set_recruitment(r[0])
    rows = [ref.outputs()]
    for k in range(1, len(run.t_s)):
        reference_step(ref, r[k - 1], dl[k], 1e-3)
        ref.set_recruitment(r[k])
        rows.append(ref.outputs())
    for field in ('recruitment', 'n_recruited', 'dl_mt_m', 'l_ce_m', 'v_ce_m_per_s',
                  'f_se_n', 'f_pe_n', 'force_n', 'eff_f_iso_n'):
        expected = np.array([getattr(row, field) for row in rows])
        np.testing.assert_allclose(getattr(run, field), expected, rtol=0, atol=ATOL_N,
                                   err_msg=field)


def test_advance_holds_the_recruitment():
    a, b = Muscle(), Muscle()
    a.set_recruitment(0.6)
    a.advance(0.002, 1e-3)
    assert a.outputs() == b.step(0.6, 0.002, 1e-3)
