"""The virtual motor units as FES recruits them: fibre types, recruitment order
and per-unit lengths (doc/model.md sections 7.3-7.5).

Units are numbered 1..N. Fibre type k owns a contiguous block of them, with
block ends floor(N cumsum(fractions) / sum(fractions) + 0.5); a unit of type k
has maximal force f_max,k = f_iso_max w_k / sum of w over all N units. The
recruitment order lists the units in the order they are recruited; everything
below works on *positions* p = 0..N-1 along that order, so the recruited set is
always the prefix [0, M).

The unit at position p sees the CE length scaled by
c_p = 1 + s (2 frac((p + 1) phi) - 1), phi = (sqrt(5) - 1) / 2: any prefix of
the order spreads evenly over [1 - s, 1 + s].

:class:`UnitLayout` answers, for a range of positions and a normalised length x,
the sum over its units of f_max FL(c x), per fibre type, in O(1): FL (Eq. 1) is
a parabola, so that sum is A x^2 sum(c^2) + B x sum(c) + C n, read from prefix
sums, as long as no unit of the range falls outside FL's support (where FL is
clipped to 0). When some may, the sum is taken unit by unit over the range.
"""
from __future__ import annotations

import math

import numpy as np

from .equations import FL_A, FL_B, FL_C
from .params import MuscleParams, type_block_ends

#: The golden-ratio conjugate (sqrt(5) - 1) / 2 of the length-spread sequence.
PHI = (math.sqrt(5.0) - 1.0) / 2.0

#: The roots of FL (Eq. 1): FL(x) > 0 exactly for FL_ROOT_LOW < x < FL_ROOT_HIGH.
_DISCRIMINANT = math.sqrt(FL_B * FL_B - 4.0 * FL_A * FL_C)
FL_ROOT_LOW = (-FL_B + _DISCRIMINANT) / (2.0 * FL_A)
FL_ROOT_HIGH = (-FL_B - _DISCRIMINANT) / (2.0 * FL_A)


def unit_length_scale(position, spread: float):
    """[-] c_p of the unit at 0-based position ``position`` of the order (a float,
    or an array of them: the same operations element by element).

    Plain arithmetic, so that the compiled engine (model/muscle/kernels.py) runs it too.
    """
    frac = ((position + 1.0) * PHI) % 1.0
    return 1.0 + spread * (2.0 * frac - 1.0)


def length_scale(positions: np.ndarray, spread: float) -> np.ndarray:
    """[-] c_p of the units at 0-based positions ``positions`` of the order."""
    return unit_length_scale(np.asarray(positions, dtype=float), spread)


def fl_clear(x: float, spread: float) -> bool:
    """True if no unit scale c in [1 - s, 1 + s] puts c x off FL's support.

    :param x: [-] CE length over optimal length
    :param spread: [-] unit length spread s
    """
    return FL_ROOT_LOW < x * (1.0 - spread) and x * (1.0 + spread) < FL_ROOT_HIGH


def type_fl_sum(f_max: float, x: float, spread: float, n: float, c1: float,
                c2: float) -> float:
    """[N] f_max sum of FL(c x) over units of one type with moments n, sum c,
    sum c^2: the parabola summed over the moments.

    Valid when no unit is off FL's support (:func:`fl_clear`), or with no
    spread (c = 1 for all: FL(x) clipped once).

    :param f_max: [N] one unit's maximal force (f_max,k)
    :param x: [-] CE length over optimal length
    :param spread: [-] unit length spread s
    """
    if spread == 0.0:
        fl = (FL_A * x + FL_B) * x + FL_C
        return f_max * fl * n if fl > 0.0 else 0.0
    return f_max * (FL_A * x * x * c2 + FL_B * x * c1 + FL_C * n)


class UnitLayout:
    """Types, maximal forces and length scales of the units along the order.

    :param params: the muscle's parameters (``multi``)
    """

    def __init__(self, params: MuscleParams) -> None:
        n = params.n_units
        self.n_units = n
        self.n_types = k = params.n_fibre_types
        self.spread = params.unit_length_spread
        ends = type_block_ends(n, params.fibre_fractions)
        starts = [0] + ends[:-1]
        counts = [e - s for s, e in zip(starts, ends)]
        weights = params.per_type('fibre_force_weights')
        total_weight = sum(c * w for c, w in zip(counts, weights))
        #: [N] maximal force of one unit of each type (f_max,k)
        self.f_max = [params.f_iso_max_n * w / total_weight for w in weights]
        self.type_counts = counts
        order = params.recruitment_order
        # Type of each position, as contiguous blocks where the order keeps them.
        if order == 'size':
            self._blocks = list(zip(starts, ends))
            self._type_of = None
        elif order == 'reverse':
            blocks, pos = [None] * k, 0
            for t in reversed(range(k)):
                blocks[t] = (pos, pos + counts[t])
                pos += counts[t]
            self._blocks = blocks
            self._type_of = None
        else:
            unit_type = np.repeat(np.arange(k, dtype=np.int8), counts)
            perm = np.random.default_rng(params.recruitment_seed).permutation(n)
            self._type_of = unit_type[perm]
            self._blocks = None
        self._prefix = None
        if self._type_of is not None or self.spread > 0.0:
            self._build_prefix_sums()

    def _build_prefix_sums(self) -> None:
        """Per type, prefix sums over positions of 1, c and c^2 (O(N K) memory)."""
        n, k = self.n_units, self.n_types
        c = length_scale(np.arange(n), self.spread)
        types = self.types_of(0, n)
        prefix = np.zeros((k, 3, n + 1))
        for t in range(k):
            mask = (types == t).astype(float)
            np.cumsum(mask, out=prefix[t, 0, 1:])
            np.cumsum(mask * c, out=prefix[t, 1, 1:])
            np.cumsum(mask * c * c, out=prefix[t, 2, 1:])
        self._prefix = prefix

    def types_of(self, p0: int, p1: int) -> np.ndarray:
        """Fibre type of each position in [p0, p1)."""
        if self._type_of is not None:
            return self._type_of[p0:p1]
        out = np.empty(p1 - p0, dtype=np.int8)
        for t, (b0, b1) in enumerate(self._blocks):
            lo, hi = max(b0, p0), min(b1, p1)
            if hi > lo:
                out[lo - p0:hi - p0] = t
        return out

    def moments(self, p0: int, p1: int) -> list[tuple[float, float, float]]:
        """Per type: (n, sum c, sum c^2) over the units at positions [p0, p1)."""
        if self._prefix is None:
            out = []
            for b0, b1 in self._blocks:
                m = float(max(0, min(b1, p1) - max(b0, p0)))
                out.append((m, m, m))
            return out
        d = self._prefix[:, :, p1] - self._prefix[:, :, p0]
        return [tuple(row) for row in d.tolist()]

    def fl_sums(self, p0: int, p1: int, x: float,
                moments: list[tuple[float, float, float]] | None = None) -> list[float]:
        """Per type: f_max,k x sum of FL(c_p x) over its units in [p0, p1).

        :param x: [-] CE length over optimal length, before the unit scale c_p
        :param moments: :meth:`moments` of the range, if already at hand
        """
        s = self.spread
        if s == 0.0 or fl_clear(x, s):
            # No unit can leave FL's support: the parabola summed over moments.
            m = moments if moments is not None else self.moments(p0, p1)
            return [type_fl_sum(f, x, s, *mk) for f, mk in zip(self.f_max, m)]
        # Some units may be off the FL range: clip unit by unit, O(p1 - p0).
        cx = length_scale(np.arange(p0, p1), s) * x
        fl = np.maximum((FL_A * cx + FL_B) * cx + FL_C, 0.0)
        types = self.types_of(p0, p1)
        sums = np.bincount(types, weights=fl, minlength=self.n_types)
        return [f * float(v) for f, v in zip(self.f_max, sums)]


def order_units(params: MuscleParams) -> np.ndarray:
    """The unit (0-based number) at each position of the recruitment order.

    ``size``: unit p at position p; ``reverse``: the type blocks in reverse
    order, ascending unit number inside each; ``random``:
    ``default_rng(recruitment_seed).permutation(N)`` (doc/model.md section 7.4).
    """
    n = params.n_units
    if params.recruitment_order == 'size':
        return np.arange(n)
    if params.recruitment_order == 'random':
        return np.random.default_rng(params.recruitment_seed).permutation(n)
    ends = type_block_ends(n, params.fibre_fractions)
    starts = [0] + ends[:-1]
    return np.concatenate([np.arange(starts[t], ends[t]) for t in reversed(range(len(ends)))])


def channel_positions(params: MuscleParams) -> list[np.ndarray]:
    """Positions along the recruitment order of each channel's territory, ascending.

    Channel c owns the units of block c of ``default_rng(channel_seed).permutation(N)``,
    with block ends as the fibre types' (:func:`type_block_ends` of
    ``channel_fractions``); inside its territory a channel recruits along the
    muscle's recruitment order (doc/model.md section 10).
    """
    n = params.n_units
    perm = np.random.default_rng(params.channel_seed).permutation(n)
    ends = type_block_ends(n, params.channel_fractions)
    channel_of_unit = np.empty(n, dtype=np.int64)
    start = 0
    for c, end in enumerate(ends):
        channel_of_unit[perm[start:end]] = c
        start = end
    channel_of_position = channel_of_unit[order_units(params)]
    return [np.flatnonzero(channel_of_position == c) for c in range(len(ends))]
