"""The LIFO run stack equals the paper's per-unit memory (Eq. 2)."""
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hill_muscle_ros.model import Muscle, MuscleParams, NaiveUnitMemory, UnitMemory
from hill_muscle_ros.model.memory import recruited_units

P = MuscleParams()

recruitments = st.floats(min_value=0.0, max_value=1.0)
lengths = st.floats(min_value=0.02, max_value=0.2)


@settings(max_examples=300, deadline=None)
@given(st.sampled_from([1, 7, 1000, 100_000]),
       st.lists(st.tuples(recruitments, lengths), min_size=1, max_size=200))
def test_lifo_stack_equals_naive_per_unit_array(n_units, sequence):
    lifo = UnitMemory(n_units, P.f_iso_max_n, P.l_opt_m)
    naive = NaiveUnitMemory(n_units, P.f_iso_max_n, P.l_opt_m)
    for r, l_ce in sequence:
        m = recruited_units(r, n_units)
        assert lifo.update(m, l_ce) == pytest.approx(naive.update(m, l_ce), abs=1e-9)
        assert lifo.n_recruited == naive.n_recruited == m


@settings(max_examples=50, deadline=None)
@given(st.lists(st.tuples(recruitments, st.floats(min_value=-0.02, max_value=0.02)),
                min_size=1, max_size=300))
def test_multi_initial_muscle_force_equals_one_with_naive_memory(sequence):
    """Full muscle run: swap the LIFO memory for the naive one; forces agree to 1e-9 N."""
    params = MuscleParams(units='multi', length='initial')
    fast, slow = Muscle(params), Muscle(params)
    slow._memory = NaiveUnitMemory(params.n_units, params.f_iso_max_n, params.l_opt_m)
    for r, dl in sequence:
        a = fast.step(r, dl, 1e-3)
        b = slow.step(r, dl, 1e-3)
        assert a.force_n == pytest.approx(b.force_n, abs=1e-9)
        assert a.eff_f_iso_n == pytest.approx(b.eff_f_iso_n, abs=1e-9)


def test_recruited_units_rounds_half_up():
    assert [recruited_units(r, 1000) for r in (0.0, 0.0004, 0.0005, 0.5, 1.0)] == \
        [0, 0, 1, 500, 1000]


def test_total_does_not_drift_after_many_changes():
    """Totals are rebuilt from the run below, so a return to a level is exact."""
    mem = UnitMemory(1000, P.f_iso_max_n, P.l_opt_m)
    mem.update(400, 0.125)
    base = mem.eff_f_iso
    for k in range(10_000):
        mem.update(400 + (k % 600) + 1, 0.08 + 1e-6 * k)
        mem.update(400, 0.1)
    assert mem.eff_f_iso == base
    assert mem.n_runs == 1


def test_de_recruiting_everything_erases_the_memory():
    mem = UnitMemory(1000, P.f_iso_max_n, P.l_opt_m)
    mem.update(300, 0.1)
    mem.update(900, 0.12)
    mem.update(0, 0.1)
    assert (mem.eff_f_iso, mem.n_recruited, mem.n_runs) == (0.0, 0, 0)


def test_highest_units_are_de_recruited_first():
    mem = UnitMemory(1000, P.f_iso_max_n, P.l_opt_m)
    mem.update(500, 0.100)   # FL = 1
    mem.update(1000, 0.125)  # FL(1.25)
    mem.update(600, 0.09)    # drop 400 of the FL(1.25) units
    f_unit = P.f_iso_max_n / 1000
    assert mem.eff_f_iso == pytest.approx(500 * f_unit + 100 * f_unit * 0.8264375)
