"""The FES unit memory against a plain per-unit model: for random recruitment
sequences and random settings, the segment stack with common fatigue clocks
gives the same Eff.f_iso and mean fitness as one array slot per unit."""
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hill_muscle_ros.model import MuscleParams
from hill_muscle_ros.model.equations import force_length
from engines import KernelPool as UnitPool

#: [N] two exact evaluations of the same sum, differing in rounding only.
SUM_TOL_N = 1e-9


class NaivePool:
    """One slot per unit along the order: type, f_max, c, stored x_o, fitness."""

    def __init__(self, p: MuscleParams):
        n = p.n_units
        total = sum(p.fibre_fractions)
        ends = [math.floor(n * c / total + 0.5) for c in np.cumsum(p.fibre_fractions)]
        unit_type = np.zeros(n, dtype=int)
        for k in range(1, len(ends)):
            unit_type[ends[k - 1]:ends[k]] = k
        weights = np.array(p.per_type('fibre_force_weights'))
        f_unit = p.f_iso_max_n * weights[unit_type] / weights[unit_type].sum()
        if p.recruitment_order == 'size':
            order = np.arange(n)
        elif p.recruitment_order == 'reverse':
            order = np.concatenate([np.flatnonzero(unit_type == k)
                                    for k in reversed(range(len(ends)))])
        else:
            order = np.random.default_rng(p.recruitment_seed).permutation(n)
        self.type = unit_type[order]
        self.f = f_unit[order]
        phi = (math.sqrt(5) - 1) / 2
        pos = np.arange(1, n + 1)
        self.c = 1 + p.unit_length_spread * (2 * np.mod(pos * phi, 1.0) - 1)
        self.x_o = np.zeros(n)
        self.mu = np.ones(n)
        self.m = 0
        self.t = 0.0
        self.p = p

    def advance(self, t):
        p, dt = self.p, t - self.t
        if p.fatigue == 'riener' and dt > 0:
            mu_min = np.array(p.per_type('fatigue_min'))[self.type]
            t_fat = np.array(p.per_type('tau_fatigue_s'))[self.type]
            t_rec = np.array(p.per_type('tau_recovery_s'))[self.type]
            rec = np.arange(p.n_units) < self.m
            self.mu = np.where(rec, mu_min + (self.mu - mu_min) * np.exp(-dt / t_fat),
                               1 - (1 - self.mu) * np.exp(-dt / t_rec))
        self.t = t

    def update(self, m, x, t):
        self.advance(t)
        if m > self.m:
            self.x_o[self.m:m] = x
        self.m = m

    def eff_f_iso(self, x, t):
        self.advance(t)
        arg = self.x_o if self.p.length == 'initial' else np.full(self.p.n_units, x)
        fl = np.array([force_length(v) for v in self.c * arg])
        return float(np.sum((self.f * fl * self.mu)[:self.m]))


settings_strategy = st.fixed_dictionaries({
    'n_units': st.integers(1, 300),
    'length': st.sampled_from(['initial', 'instantaneous']),
    'fatigue': st.sampled_from(['none', 'riener']),
    'fibre_fractions': st.lists(st.floats(0.0, 3.0), min_size=1, max_size=3).filter(
        lambda f: sum(f) > 0),
    'recruitment_order': st.sampled_from(['size', 'reverse', 'random']),
    'recruitment_seed': st.integers(0, 2**32),
    'unit_length_spread': st.sampled_from([0.0, 0.1, 0.3, 0.49]),
})


@st.composite
def scenario(draw):
    s = draw(settings_strategy)
    k = len(s['fibre_fractions'])
    s['fibre_force_weights'] = draw(st.lists(st.floats(0.1, 5.0), min_size=k, max_size=k))
    s['fatigue_min'] = draw(st.lists(st.floats(0.0, 1.0), min_size=k, max_size=k))
    s['tau_fatigue_s'] = draw(st.lists(st.floats(0.01, 50.0), min_size=k, max_size=k))
    s['tau_recovery_s'] = draw(st.lists(st.floats(0.01, 80.0), min_size=k, max_size=k))
    n = s['n_units']
    events = draw(st.lists(st.tuples(st.integers(0, n), st.floats(0.3, 1.8),
                                     st.floats(0.0, 3.0)), min_size=1, max_size=25))
    return MuscleParams(**s), events


@settings(max_examples=150, deadline=None)
@given(scenario())
def test_segment_memory_equals_the_naive_per_unit_model(case):
    params, events = case
    pool, naive = UnitPool(params), NaivePool(params)
    t = 0.0
    for m, x, dt in events:
        t += dt
        pool.update(m, x, t)
        naive.update(m, x, t)
        for probe_x, probe_dt in ((x, 0.0), (1.1 * x, 0.5 * dt)):
            probe_t = t + probe_dt
            pool.advance_to(probe_t)
            assert pool.eff_f_iso(probe_x, probe_t) == \
                pytest.approx(naive.eff_f_iso(probe_x, probe_t), abs=SUM_TOL_N)
            assert pool.mean_fitness(probe_t) == \
                pytest.approx(float(naive.mu.mean()), abs=1e-12)
            np.testing.assert_allclose(pool.fitness_profile(probe_t), naive.mu, atol=1e-12)
        t += 0.5 * dt


@settings(max_examples=100, deadline=None)
@given(scenario())
def test_fitness_always_stays_between_fatigue_min_and_one(case):
    params, events = case
    pool = UnitPool(params)
    mu_min = np.array(params.per_type('fatigue_min'))[pool.layout.types_of(0, params.n_units)]
    t = 0.0
    for m, x, dt in events:
        t += dt
        pool.update(m, x, t)
        mu = pool.fitness_profile(t + dt)
        assert np.all(mu >= mu_min - 1e-12) and np.all(mu <= 1.0 + 1e-12)


def _types_in_order(order, fractions=(0.3, 0.7), n=100):
    pool = UnitPool(MuscleParams(n_units=n, fibre_fractions=fractions,
                                 recruitment_order=order))
    return pool.layout.types_of(0, n)


def test_size_order_recruits_the_first_type_first():
    types = _types_in_order('size')
    assert types.tolist() == [0] * 30 + [1] * 70


def test_reverse_order_recruits_the_last_type_first():
    types = _types_in_order('reverse')
    assert types.tolist() == [1] * 70 + [0] * 30


def test_random_order_is_the_seeded_numpy_permutation():
    n = 100
    unit_type = np.array([0] * 30 + [1] * 70)
    expected = unit_type[np.random.default_rng(0).permutation(n)]
    assert _types_in_order('random').tolist() == expected.tolist()


def test_type_blocks_end_at_the_rounded_cumulative_fractions():
    pool = UnitPool(MuscleParams(n_units=10, fibre_fractions=(1.0, 1.0, 1.0)))
    # floor(10 * [1/3, 2/3, 1] + 0.5) = [3, 7, 10]
    assert pool.layout.type_counts == [3, 4, 3]


def test_force_weights_keep_the_whole_muscle_at_f_iso_max():
    params = MuscleParams(n_units=10, fibre_fractions=(0.4, 0.6), fibre_force_weights=(1.0, 3.0))
    pool = UnitPool(params)
    pool.update(10, 1.0, 0.0)          # all recruited at optimal length: FL = 1
    assert pool.eff_f_iso(1.0, 0.0) == pytest.approx(params.f_iso_max_n, rel=1e-15)
    # A fast unit is three times as strong as a slow one.
    assert pool.layout.f_max[1] == pytest.approx(3.0 * pool.layout.f_max[0], rel=1e-15)
