"""The paper's method written plainly: the naive baseline of the benchmark.

One array slot per unit holding its stored isometric force, updated on
recruitment and summed on every step (Eq. 2 taken literally), with the same
RK4 integrator and the same scalar curves as the package. Only the memory
differs from ``multi``/``initial``; its cost grows with N. The memory
(:class:`NaiveUnitMemory`) is the benchmark's own, written plainly here: the
package keeps its memory as segment stacks in its one engine
(``hill_muscle_ros/model/muscle/pool.py``), and the test oracle has its own
copy (``test/reference.py``).

:class:`NaiveFesMuscle` does the same for the FES extensions (delay,
activation, per-unit fatigue, fibre types, recruitment order, unit lengths,
relative force-velocity): per-unit arrays of fitness and stored force,
updated every step.
"""
from __future__ import annotations

import math
from collections import deque

import numpy as np

from hill_muscle_ros.model import MuscleParams, recruited_units
from hill_muscle_ros.model.equations import (FL_A, FL_B, FL_C, force_length,
                                             force_velocity_inverse, parallel_force,
                                             series_force)


class NaiveUnitMemory:
    """The paper's memory taken literally (Eq. 2): one array slot per unit
    holding its stored isometric force, summed on every read (O(N)).

    :param n_units: [-] number of virtual motor units (N)
    :param f_iso_max_n: [N] maximal isometric force (f_iso_max)
    :param l_opt_m: [m] CE optimal length (l_opt)
    """

    def __init__(self, n_units: int, f_iso_max_n: float, l_opt_m: float) -> None:
        self._f_unit_max = f_iso_max_n / n_units
        self._l_opt = l_opt_m
        self.f_iso_j = np.zeros(n_units)
        self.n_recruited = 0

    def update(self, m: int, l_ce_m: float) -> float:
        """Recruit or release so that units [0, m) are recruited, new ones at
        CE length ``l_ce_m`` [m]; return [N] Eff.f_iso, the sum over all N slots."""
        top = self.n_recruited
        if m > top:
            self.f_iso_j[top:m] = self._f_unit_max * force_length(l_ce_m / self._l_opt)
        elif m < top:
            self.f_iso_j[m:top] = 0.0
        self.n_recruited = m
        return float(self.f_iso_j.sum())


class NaiveMuscle:
    """multi/initial muscle with a per-unit NumPy memory (O(N) a step)."""

    def __init__(self, params: MuscleParams) -> None:
        self.params = params
        self.memory = NaiveUnitMemory(params.n_units, params.f_iso_max_n, params.l_opt_m)
        self.l_ce_m = params.l_rest_m
        self.dl_mt_m = 0.0

    def step(self, recruitment: float, dl_mt_m: float, dt_s: float) -> float:
        """One step; returns the muscle force [N] at its end."""
        p = self.params
        # The update writes the new units' slots and returns the sum over all N.
        f0 = self.memory.update(recruited_units(recruitment, p.n_units), self.l_ce_m)
        hill = (p.fv_a_n, p.fv_b_m_per_s, p.fv_a_ecc_n, p.fv_b_ecc_m_per_s)

        def rate(l_ce: float, dl_mt: float) -> float:
            f_se = series_force(p.k_se_n_per_m, dl_mt, l_ce, p.l_rest_m)
            return force_velocity_inverse(f_se, f0, *hill)

        l0, dl0, dl1, h = self.l_ce_m, self.dl_mt_m, dl_mt_m, dt_s
        if f0 > 0.0:
            dlm = 0.5 * (dl0 + dl1)
            k1 = rate(l0, dl0)
            k2 = rate(l0 + 0.5 * h * k1, dlm)
            k3 = rate(l0 + 0.5 * h * k2, dlm)
            k4 = rate(l0 + h * k3, dl1)
            l1 = l0 + h * (k1 + 2.0 * k2 + 2.0 * k3 + k4) / 6.0
        else:
            l1 = p.l_rest_m + dl1
        self.l_ce_m, self.dl_mt_m = l1, dl1
        return (series_force(p.k_se_n_per_m, dl1, l1, p.l_rest_m)
                + parallel_force(p.k_pe_n_per_m, dl1))


#: [s] Two instants closer than this are one: a command due at t_k + emd_s
#: takes effect at the step start it falls on, up to the rounding of sums of
#: steps (far below any physiological time).
_TIME_TOLERANCE_S = 1e-9
#: The golden-ratio conjugate of the per-unit length spread.
_PHI = (math.sqrt(5.0) - 1.0) / 2.0


class NaiveFesMuscle:
    """The FES muscle written plainly, one array slot per unit (O(N) a step).

    Multi units only. Everything is a per-unit NumPy array along the
    recruitment order, built from the model's definition, not from the
    package's memory: fibre type, maximal force, length scale, the fitness mu
    of every unit, and the stored isometric force f_max FL(c x_o) of every
    recruited unit. Every step updates every unit's fitness with its exact
    exponential, and sums the recruited units' forces at the RK4 stage times.

    Step-granular like the paper's loop: the delay acts on step starts, and
    the recruitment M = floor(N a + 0.5) is taken from the activation at the
    step start and held over the step (the package splits the step at each
    recruitment instant instead). Its forces therefore differ from the
    package's by the error of holding R over a step, and its cost does not
    depend on how much the recruitment changes. It takes one RK4 step per
    step; the package also cuts an interval into several when the CE is stiff
    (``fv_scaling: relative`` at small Eff.f_iso).

    :param params: the muscle's parameters (``units: multi``)
    """

    def __init__(self, params: MuscleParams) -> None:
        if params.units != 'multi':
            raise ValueError(f'`units` must be multi for NaiveFesMuscle, got {params.units!r}')
        self.params = p = params
        n, k = p.n_units, p.n_fibre_types
        fractions = np.asarray(p.fibre_fractions, dtype=float)
        # Type blocks over unit numbers: ends floor(N cumsum / sum + 0.5).
        ends = np.floor(n * np.cumsum(fractions) / fractions.sum() + 0.5).astype(np.int64)
        counts = np.diff(np.concatenate(([0], ends)))
        unit_type = np.repeat(np.arange(k), counts)
        if p.recruitment_order == 'size':
            type_at = unit_type
        elif p.recruitment_order == 'reverse':
            type_at = np.repeat(np.arange(k)[::-1], counts[::-1])
        else:
            type_at = unit_type[np.random.default_rng(p.recruitment_seed).permutation(n)]
        weights = np.asarray(p.per_type('fibre_force_weights'), dtype=float)
        self.f_max = (p.f_iso_max_n * weights / float(counts @ weights))[type_at]
        frac = np.mod(np.arange(1, n + 1) * _PHI, 1.0)
        self.c = 1.0 + p.unit_length_spread * (2.0 * frac - 1.0)
        self.mu_min = np.asarray(p.per_type('fatigue_min'), dtype=float)[type_at]
        self.tau_fat = np.asarray(p.per_type('tau_fatigue_s'), dtype=float)[type_at]
        self.tau_rec = np.asarray(p.per_type('tau_recovery_s'), dtype=float)[type_at]
        self.fatigue = p.fatigue == 'riener'
        self.initial = p.length == 'initial'
        self._factors_dt = None
        self.reset()

    def reset(self) -> None:
        """At rest: nothing recruited, every unit fresh, no command given."""
        p = self.params
        self.mu = np.ones(p.n_units)
        self.g = np.zeros(p.n_units)          # [N] f_max FL(c x_o) of recruited units
        self.m = 0
        self.a = 0.0
        self.t_s = 0.0
        self.l_ce_m = p.l_rest_m
        self.dl_mt_m = 0.0
        self._pending = deque()               # (instant it takes effect [s], u)
        self.u_d = 0.0

    def _factors(self, dt_s: float):
        """Per-unit decay factors of the fitness over half and whole steps."""
        if self._factors_dt != dt_s:
            self._fat_half = np.exp(-0.5 * dt_s / self.tau_fat)
            self._fat = self._fat_half * self._fat_half
            self._rec = np.exp(-dt_s / self.tau_rec)
            self._factors_dt = dt_s
        return self._fat_half, self._fat, self._rec

    def _unit_forces(self, m: int, x: float) -> np.ndarray:
        """[N] f_max FL(c x) of the units at positions [0, m), FL clipped at 0."""
        cx = self.c[:m] * x
        return self.f_max[:m] * np.maximum((FL_A * cx + FL_B) * cx + FL_C, 0.0)

    def step(self, command: float, dl_mt_m: float, dt_s: float) -> float:
        """One step with command u given at its start; returns the force [N] at its end."""
        p = self.params
        t0, h = self.t_s, dt_s
        self._pending.append((t0 + p.emd_s, command))
        while self._pending and self._pending[0][0] <= t0 + _TIME_TOLERANCE_S:
            self.u_d = self._pending.popleft()[1]
        u_d = self.u_d
        tau = p.tau_act_s if u_d > self.a else p.tau_deact_s
        if tau == 0.0:
            self.a = u_d
        m = int(p.n_units * self.a + 0.5)
        x_now = self.l_ce_m / p.l_opt_m
        if m > self.m:
            self.g[self.m:m] = self._unit_forces(m, x_now)[self.m:m]
        elif m < self.m:
            self.g[m:self.m] = 0.0
        self.m = m
        # Fitness of every unit at the stage times s0, s0 + h/2, s0 + h.
        mu = self.mu
        if self.fatigue:
            fat_half, fat, rec = self._factors(h)
            mu_min, tired = self.mu_min[:m], mu[:m] - self.mu_min[:m]
            mu_r = (mu[:m], mu_min + tired * fat_half[:m], mu_min + tired * fat[:m])
            mu_end = np.empty_like(mu)
            mu_end[:m] = mu_r[2]
            mu_end[m:] = 1.0 - (1.0 - mu[m:]) * rec[m:]
        else:
            mu_r = (mu[:m],) * 3
            mu_end = mu

        def f0_at(stage: int, l_ce: float) -> float:
            if self.initial:
                return float(self.g[:m] @ mu_r[stage])
            return float(self._unit_forces(m, l_ce / p.l_opt_m) @ mu_r[stage])

        def rate(l_ce: float, dl_mt: float, f0: float) -> float:
            share = f0 / p.f_iso_max_n if p.fv_scaling == 'relative' else 1.0
            f_se = series_force(p.k_se_n_per_m, dl_mt, l_ce, p.l_rest_m)
            return force_velocity_inverse(f_se, f0, p.fv_a_n * share, p.fv_b_m_per_s,
                                          p.fv_a_ecc_n * share, p.fv_b_ecc_m_per_s)

        l0, dl0, dl1 = self.l_ce_m, self.dl_mt_m, dl_mt_m
        f0 = f0_at(0, l0)
        if f0 > 0.0:
            dlm = 0.5 * (dl0 + dl1)
            k1 = rate(l0, dl0, f0)
            l2 = l0 + 0.5 * h * k1
            k2 = rate(l2, dlm, f0_at(1, l2))
            l3 = l0 + 0.5 * h * k2
            k3 = rate(l3, dlm, f0_at(1, l3))
            l4 = l0 + h * k3
            k4 = rate(l4, dl1, f0_at(2, l4))
            l1 = l0 + h * (k1 + 2.0 * k2 + 2.0 * k3 + k4) / 6.0
            if f0_at(2, l1) == 0.0:
                l1 = p.l_rest_m + dl1
        else:
            l1 = p.l_rest_m + dl1
        self.mu = mu_end
        if tau > 0.0:
            self.a = u_d + (self.a - u_d) * math.exp(-h / tau)
        self.l_ce_m, self.dl_mt_m, self.t_s = l1, dl1, t0 + h
        return (series_force(p.k_se_n_per_m, dl1, l1, p.l_rest_m)
                + parallel_force(p.k_pe_n_per_m, dl1))
