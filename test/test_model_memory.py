"""The engine's unit memory (the segment stacks of model/muscle/kernels.py) against
the paper's per-unit memory (Eq. 2), and its LIFO order."""
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hill_muscle_ros.model import MuscleParams
from hill_muscle_ros.model.memory import recruited_units

from engines import KernelPool
from reference import NaiveUnitMemory

P = MuscleParams()

recruitments = st.floats(min_value=0.0, max_value=1.0)
lengths = st.floats(min_value=0.02, max_value=0.2)


def _pool(n_units: int = 1000) -> KernelPool:
    return KernelPool(MuscleParams(n_units=n_units))


def _update(pool: KernelPool, m: int, l_ce_m: float) -> float:
    """Recruit or release to ``m`` units at CE length ``l_ce_m``; return [N] Eff.f_iso."""
    x = l_ce_m / P.l_opt_m
    pool.update(m, x, 0.0)
    return pool.eff_f_iso(x, 0.0)


@settings(max_examples=200, deadline=None)
@given(st.sampled_from([1, 7, 1000, 100_000]),
       st.lists(st.tuples(recruitments, lengths), min_size=1, max_size=200))
def test_segment_stack_equals_naive_per_unit_array(n_units, sequence):
    pool = _pool(n_units)
    naive = NaiveUnitMemory(n_units, P.f_iso_max_n, P.l_opt_m)
    for r, l_ce in sequence:
        m = recruited_units(r, n_units)
        assert _update(pool, m, l_ce) == pytest.approx(naive.update(m, l_ce), abs=1e-9)


def test_recruited_units_rounds_half_up():
    assert [recruited_units(r, 1000) for r in (0.0, 0.0004, 0.0005, 0.5, 1.0)] == \
        [0, 0, 1, 500, 1000]


def test_total_does_not_drift_after_many_changes():
    """Totals are rebuilt from the segment below, so a return to a level is exact."""
    pool = _pool()
    base = _update(pool, 400, 0.125)
    for k in range(10_000):
        _update(pool, 400 + (k % 600) + 1, 0.08 + 1e-6 * k)
        back = _update(pool, 400, 0.1)
    assert back == base


def test_de_recruiting_everything_erases_the_memory():
    pool = _pool()
    _update(pool, 300, 0.1)
    _update(pool, 900, 0.12)
    assert _update(pool, 0, 0.1) == 0.0
    assert _update(pool, 500, 0.1) == pytest.approx(500 * P.f_iso_max_n / 1000, rel=1e-12)


def test_highest_units_are_de_recruited_first():
    pool = _pool()
    _update(pool, 500, 0.100)   # FL = 1
    _update(pool, 1000, 0.125)  # FL(1.25)
    f0 = _update(pool, 600, 0.09)    # drop 400 of the FL(1.25) units
    f_unit = P.f_iso_max_n / 1000
    assert f0 == pytest.approx(500 * f_unit + 100 * f_unit * 0.8264375)
