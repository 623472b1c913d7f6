"""The motor-unit memory of the FES model: recruitment memory and per-unit fatigue.

The paper's memory (:class:`~hill_muscle_ros.model.memory.UnitMemory`) is a
LIFO stack of runs of units recruited at the same instant. With per-unit
fatigue (doc/model.md section 7.3) a unit's force is also scaled by its own
fitness mu_j, which falls while the unit is recruited,
d mu / dt = (mu_min - mu) / T_fat, and recovers while it rests,
d mu / dt = (1 - mu) / T_rec.

Units recruited and released at the same instants share their whole history,
so they share their fitness. The units along the recruitment order are
therefore split into *segments* of one history each: the recruited prefix
[0, M) is a stack of segments (each also stores the CE length at which it was
recruited), and the resting suffix [M, N) is another stack. Every recruited
segment's excess fitness mu - mu_min decays by the same factor exp(-dt / T_fat)
in a step, and every resting segment's deficit 1 - mu by exp(-dt / T_rec): so
each is stored divided by a common clock, exp(-(t - t_epoch) / T), and the
totals over the stack are static running sums, read at any instant in O(1)
per fibre type and never accumulating rounding drift. A recruitment change
moves the segments between the stacks it spans and splits at most one.

Cost: O(K) per evaluation for K fibre types; O(K) per segment a recruitment
change spans, and it creates at most one segment. The number of segments is
bounded by N and by twice the number of recruitment changes.
"""
from __future__ import annotations

import math

import numpy as np

from .params import MuscleParams
from .units import UnitLayout, fl_clear
from .equations import FL_A, FL_B, FL_C, moment_force, recruited_excess, resting_deficit

#: Columns of a segment's static sums per fibre type: g = f_max sum FL(c x_o)
#: (``initial``), then the moments n, sum c, sum c^2 of its units.
_G, _N, _C1, _C2 = 0, 1, 2, 3
#: Elapsed time over the fastest time constant after which the common clocks
#: are renormalised: exp(-500) = 7e-218 stays far from underflow, and stored
#: values divided by it (at most e^500 = 1.4e217) far from overflow.
_RENORMALISE_AFTER_TAUS = 500.0



class UnitPool:
    """The recruited prefix of the units and the fitness of every unit.

    :param params: the muscle's parameters (``units: multi``)
    """

    def __init__(self, params: MuscleParams) -> None:
        self.layout = layout = UnitLayout(params)
        self.n_units = params.n_units
        self.k = layout.n_types
        self.initial = params.length == 'initial'
        self.fatigue = params.fatigue == 'riener'
        self.mu_min = np.array(params.per_type('fatigue_min'), dtype=float)
        self.rate_fat = 1.0 / np.array(params.per_type('tau_fatigue_s'), dtype=float)
        self.rate_rec = 1.0 / np.array(params.per_type('tau_recovery_s'), dtype=float)
        self.f_max = np.array(layout.f_max, dtype=float)
        self._renormalise_s = _RENORMALISE_AFTER_TAUS / max(
            float(self.rate_fat.max()), float(self.rate_rec.max()))
        self.reset()

    def reset(self) -> None:
        """Every unit resting and fresh (mu = 1), no memory."""
        k = self.k
        self.m = 0
        self._epoch = 0.0
        # Recruited stack; index 0 is a sentinel "no units".
        self._r_end = [0]
        self._r_x = [0.0]                         # x_o = l_o / l_opt at recruitment
        self._r_exn = [np.zeros(k)]               # (mu - mu_min) / D(t), per type
        self._r_static = [np.zeros((k, 4))]       # cumulative g, n, sum c, sum c^2
        self._r_dyn = [np.zeros((k, 4))]          # cumulative static x exn
        # Resting stack, top (last) = lowest positions: (start, end, dn per type,
        # cumulative n x dn from the bottom); dn = (1 - mu) / H(t).
        self._u = [(0, self.n_units, np.zeros(k), np.zeros(k))]
        self._refresh()

    # -- clocks ----------------------------------------------------------------

    def _decay(self, t_s: float) -> np.ndarray:
        """D_k(t) = exp(-(t - t_epoch) / T_fat,k)."""
        return np.exp(-(t_s - self._epoch) * self.rate_fat)

    def _recovery(self, t_s: float) -> np.ndarray:
        """H_k(t) = exp(-(t - t_epoch) / T_rec,k)."""
        return np.exp(-(t_s - self._epoch) * self.rate_rec)

    def _renormalise(self, t_s: float) -> None:
        """Move the epoch to ``t_s``: multiply every stored value by its clock."""
        d, h = self._decay(t_s), self._recovery(t_s)
        self._r_exn = [e * d for e in self._r_exn]
        self._r_dyn = [x * d[:, None] for x in self._r_dyn]
        self._u = [(a, b, dn * h, cum * h) for a, b, dn, cum in self._u]
        self._epoch = t_s
        self._refresh()

    def advance_to(self, t_s: float) -> None:
        """Keep the clocks in range; call once a step (O(segments) rarely)."""
        if self.fatigue and t_s - self._epoch > self._renormalise_s:
            self._renormalise(t_s)

    # -- recruitment -------------------------------------------------------------

    def _static_row(self, p0: int, p1: int, x_o: float) -> np.ndarray:
        moments = self.layout.moments(p0, p1)
        g = self.layout.fl_sums(p0, p1, x_o, moments) if self.initial else [0.0] * self.k
        return np.array([[gk, *mk] for gk, mk in zip(g, moments)])

    def update(self, m: int, x_ce: float, t_s: float) -> None:
        """Recruit or release so that exactly positions [0, m) are recruited at ``t_s``.

        Newly recruited units store ``x_ce`` = l_ce / l_opt; released units
        (always the last recruited) lose that memory and start to recover.

        :param m: [-] units to have recruited (M), in [0, N]
        :param x_ce: [-] CE length over optimal length at this instant
        :param t_s: [s] the instant
        """
        self.advance_to(t_s)   # the clocks divide here: keep them in range
        if m > self.m:
            self._recruit(m, x_ce, t_s)
        elif m < self.m:
            self._release(m, t_s)
        else:
            return
        self._refresh()

    def _recruit(self, m: int, x_o: float, t_s: float) -> None:
        fatigue = self.fatigue
        if fatigue:
            d, h = self._decay(t_s), self._recovery(t_s)
        pos = self.m
        while pos < m:
            start, end, dn, cum = self._u.pop()
            take = min(end, m)
            if take < end:   # the rest keeps resting
                below = self._u[-1][3] if self._u else np.zeros(self.k)
                n_rest = np.array([mk[0] for mk in self.layout.moments(take, end)])
                self._u.append((take, end, dn, below + n_rest * dn))
            row = self._static_row(pos, take, x_o)
            exn = recruited_excess(dn, h, self.mu_min, d) if fatigue else np.zeros(self.k)
            self._push_recruited(take, x_o, exn, row)
            pos = take
        self.m = m

    def _push_recruited(self, end: int, x_o: float, exn: np.ndarray,
                        row: np.ndarray) -> None:
        if not self.fatigue and not self.initial and len(self._r_end) > 1:
            # Nothing tells these units apart (no stored length, no fitness):
            # one segment for the whole recruited prefix.
            self._r_end[-1] = end
            self._r_static[-1] = self._r_static[-1] + row
            return
        self._r_end.append(end)
        self._r_x.append(x_o)
        self._r_exn.append(exn)
        self._r_static.append(self._r_static[-1] + row)
        self._r_dyn.append(self._r_dyn[-1] + row * exn[:, None])

    def _release(self, m: int, t_s: float) -> None:
        fatigue = self.fatigue
        if fatigue:
            d, h = self._decay(t_s), self._recovery(t_s)
        pos = self.m
        while pos > m:
            start = self._r_end[-2]
            cut = max(start, m)
            x_o, exn = self._r_x[-1], self._r_exn[-1]
            for stack in (self._r_end, self._r_x, self._r_exn, self._r_static, self._r_dyn):
                stack.pop()
            if cut > start:   # the bottom of the segment stays recruited
                self._push_recruited(cut, x_o, exn, self._static_row(start, cut, x_o))
            if not fatigue:
                # Resting units without fatigue are all fresh: one segment.
                end = self._u.pop()[1] if self._u and self._u[-1][0] == pos else pos
                zeros = np.zeros(self.k)
                self._u.append((cut, end, zeros, zeros))
                pos = cut
                continue
            dn = resting_deficit(exn, d, self.mu_min, h)
            below = self._u[-1][3] if self._u else np.zeros(self.k)
            n_rel = np.array([mk[0] for mk in self.layout.moments(cut, pos)])
            self._u.append((cut, pos, dn, below + n_rel * dn))
            pos = cut
        self.m = m

    # -- readings ----------------------------------------------------------------

    def _refresh(self) -> None:
        """Cache the totals the integrator reads at every stage."""
        static, dyn = self._r_static[-1], self._r_dyn[-1]
        weight = self.mu_min if self.fatigue else np.ones(self.k)
        if self.initial:
            self._const = float(weight @ static[:, _G])
            self._dyn_g = dyn[:, _G].tolist() if self.fatigue else []
        else:
            # Per type: mu-weighted moments = weight x static + D(t) x dyn, in
            # plain floats (read at every RK4 stage).
            self._w_static = (static[:, _N:] * weight[:, None]).tolist()
            self._w_dyn = dyn[:, _N:].tolist()
            self._f_max_list = self.f_max.tolist()
        self._rates = self.rate_fat.tolist()
        if self.fatigue:
            # Mean fitness, in plain floats: tired = const - sum dyn_k D_k + sum rest_k H_k.
            self._tired_const = float(((1.0 - self.mu_min) * static[:, _N]).sum())
            self._tired_dyn = dyn[:, _N].tolist()
            self._tired_rest = (self._u[-1][3] if self._u else np.zeros(self.k)).tolist()
            self._rates_rec = self.rate_rec.tolist()

    def eff_f_iso(self, x_ce: float, t_s: float) -> float:
        """[N] Eff.f_iso: the sum of f_max,j FL(c_j x_j) mu_j(t) over recruited units.

        :param x_ce: [-] l_ce / l_opt now (``instantaneous``; unused for ``initial``)
        :param t_s: [s] the instant (fatigue clocks)
        """
        if self.initial:
            f0 = self._const
            if self._dyn_g:
                elapsed = t_s - self._epoch
                for g, rate in zip(self._dyn_g, self._rates):
                    f0 += g * math.exp(-elapsed * rate)
            return f0
        s = self.layout.spread
        clipped = s > 0.0 and not fl_clear(x_ce, s)
        if clipped:
            return self._eff_f_iso_clipped(x_ce, t_s)
        if s == 0.0:
            fl = (FL_A * x_ce + FL_B) * x_ce + FL_C
            if fl <= 0.0:
                return 0.0
            a2 = a1 = 0.0
            a0 = fl
        else:
            a2, a1, a0 = FL_A * x_ce * x_ce, FL_B * x_ce, FL_C
        elapsed = t_s - self._epoch
        total = 0.0
        for k, (f_max, (n, c1, c2)) in enumerate(zip(self._f_max_list, self._w_static)):
            if self.fatigue:
                d = math.exp(-elapsed * self._rates[k])
                dn, dc1, dc2 = self._w_dyn[k]
                n, c1, c2 = n + d * dn, c1 + d * dc1, c2 + d * dc2
            total += moment_force(f_max, a2, a1, a0, n, c1, c2)
        return total

    def _eff_f_iso_clipped(self, x_ce: float, t_s: float) -> float:
        """Eff.f_iso when some units may be off the FL range: segment by segment."""
        d = self._decay(t_s) if self.fatigue else None
        total = 0.0
        for i in range(1, len(self._r_end)):
            p0, p1 = self._r_end[i - 1], self._r_end[i]
            sums = np.array(self.layout.fl_sums(p0, p1, x_ce))
            mu = self.mu_min + self._r_exn[i] * d if self.fatigue else 1.0
            total += float(np.sum(sums * mu))
        return total

    def mean_fitness(self, t_s: float) -> float:
        """[-] mean of mu over all N units (1 without fatigue)."""
        if not self.fatigue:
            return 1.0
        elapsed = t_s - self._epoch
        exp = math.exp
        tired = self._tired_const
        for x, rate in zip(self._tired_dyn, self._rates):
            tired -= x * exp(-elapsed * rate)
        for x, rate in zip(self._tired_rest, self._rates_rec):
            tired += x * exp(-elapsed * rate)
        return 1.0 - tired / self.n_units

    def fitness_profile(self, t_s: float) -> np.ndarray:
        """[-] mu of every unit along the order, O(N): for figures and tests."""
        mu = np.ones(self.n_units)
        if not self.fatigue:
            return mu
        d, h = self._decay(t_s), self._recovery(t_s)
        types = self.layout.types_of(0, self.n_units)
        for i in range(1, len(self._r_end)):
            p0, p1 = self._r_end[i - 1], self._r_end[i]
            mu[p0:p1] = (self.mu_min + self._r_exn[i] * d)[types[p0:p1]]
        for start, end, dn, _ in self._u:
            mu[start:end] = (1.0 - dn * h)[types[start:end]]
        return mu

    @property
    def n_segments(self) -> int:
        """Segments held: recruited plus resting."""
        return len(self._r_end) - 1 + len(self._u)
