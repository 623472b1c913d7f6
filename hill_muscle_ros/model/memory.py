"""The motor-unit memory: which units are recruited and at what CE length.

Units are always recruited in a fixed order (1..M) and de-recruited in reverse
(doc/model.md section 2), so the recruited set is a prefix and the memory is a
last-in-first-out stack of *runs*: units recruited at the same instant share
one CE length and hence one isometric force per unit. Each run stores the
running totals up to and including itself, so the effective isometric force
is read off the top of the stack and never accumulates rounding drift.

:class:`UnitMemory` costs O(1) amortised per change, independent of the
number of units. :class:`NaiveUnitMemory` is the plain per-unit array the
paper describes; it is the reference the tests and benchmarks compare with.

The stack's push and pop are written once, in :func:`stack_update`, a plain
function over three arrays (or lists) and a top index: :class:`UnitMemory`
calls it as Python on lists, and the batch's compiled engine
(:mod:`.kernels`) compiles it with numba over per-muscle slices of flat
arrays.
"""
from __future__ import annotations

import numpy as np

from .equations import force_length


def recruited_units(recruitment: float, n_units: int) -> int:
    """Number of recruited units M = floor(N R + 0.5) (doc/model.md section 2).

    :param recruitment: [-] recruitment R in [0, 1]
    :param n_units: [-] number of virtual units N
    :return: [-] M, in [0, N]
    """
    return int(n_units * recruitment + 0.5)


def stack_update(count, f_unit, total, base: int, top: int, m: int, l_ce_m: float,
                 f_unit_max_n: float, l_opt_m: float) -> int:
    """Recruit or de-recruit on a run stack so that exactly units 1..m are recruited.

    The stack is held in ``count``, ``f_unit`` and ``total`` from index
    ``base`` on: entry ``base`` is the sentinel run (no units, no force, never
    written) and ``base + top`` the top run. A push writes entry
    ``base + top + 1``, so the caller leaves room for it: at most N + 1 entries
    (runs hold at least one unit each). Plain Python on lists or arrays, and
    compiled by numba for the batch (:mod:`.kernels`).

    :param count: [-] cumulative number of units up to each run
    :param f_unit: [N] isometric force of each unit of each run
    :param total: [N] cumulative isometric force up to each run (Eff.f_iso)
    :param base: index of this stack's sentinel in the three arrays
    :param top: [-] runs on the stack now (0: nothing recruited)
    :param m: [-] number of units to have recruited (M), in [0, N]
    :param l_ce_m: [m] CE length at this instant (l_CE), stored as l_o_j
    :param f_unit_max_n: [N] f_iso_max / N, one unit's force at FL = 1
    :param l_opt_m: [m] CE optimal length (l_opt)
    :return: [-] the new number of runs; Eff.f_iso is ``total[base + top]``
    """
    i = base + top
    below = count[i]
    if m > below:
        # Newly recruited units remember the current CE length.
        f_new = f_unit_max_n * force_length(l_ce_m / l_opt_m)
        i += 1
        count[i] = m
        f_unit[i] = f_new
        total[i] = total[i - 1] + (m - below) * f_new
    elif m < below:
        # De-recruit the highest units first: drop whole runs, then trim one.
        while i > base and count[i - 1] >= m:
            i -= 1
        if count[i] != m:
            count[i] = m
            total[i] = total[i - 1] + (m - count[i - 1]) * f_unit[i]
    return i - base


class UnitMemory:
    """LIFO stack of recruitment runs; implements Eq. (2) of the paper.

    Eff.f_iso = sum over recruited units j of ``f_iso_max / N * FL(l_o_j / l_opt)``.

    :param n_units: [-] number of virtual motor units (N)
    :param f_iso_max_n: [N] maximal isometric force (f_iso_max)
    :param l_opt_m: [m] CE optimal length (l_opt)
    """

    __slots__ = ('_f_unit_max', '_l_opt', '_top', '_count', '_f_unit', '_total')

    def __init__(self, n_units: int, f_iso_max_n: float, l_opt_m: float) -> None:
        self._f_unit_max = f_iso_max_n / n_units
        self._l_opt = l_opt_m
        # The stack of stack_update, in lists grown on demand (never past
        # N + 1 entries), so a memory costs what its deepest stack needs.
        # Index 0 is the sentinel run "no units, no force".
        self._top = 0
        self._count = [0]       # cumulative number of units up to each run
        self._f_unit = [0.0]    # [N] isometric force of each unit in the run
        self._total = [0.0]     # [N] cumulative isometric force up to each run

    def clear(self) -> None:
        """De-recruit every unit and erase its memory."""
        self._top = 0

    @property
    def n_recruited(self) -> int:
        """[-] number of recruited units M."""
        return self._count[self._top]

    @property
    def eff_f_iso(self) -> float:
        """[N] effective isometric force of the recruited units (Eff.f_iso, Eq. 2)."""
        return self._total[self._top]

    @property
    def n_runs(self) -> int:
        """Number of runs on the stack (units recruited at distinct instants)."""
        return self._top

    def update(self, m: int, l_ce_m: float) -> float:
        """Recruit or de-recruit so that exactly the units 1..m are recruited.

        Newly recruited units store the current CE length; de-recruited units
        (always the highest-numbered) lose their memory (:func:`stack_update`).

        :param m: [-] number of units to have recruited (M), in [0, N]
        :param l_ce_m: [m] CE length at this instant (l_CE), stored as l_o_j
        :return: [N] the new Eff.f_iso
        """
        if self._top + 1 == len(self._count):   # room for a push
            self._count.append(0)
            self._f_unit.append(0.0)
            self._total.append(0.0)
        top = self._top = stack_update(self._count, self._f_unit, self._total, 0, self._top,
                                       m, l_ce_m, self._f_unit_max, self._l_opt)
        return self._total[top]


class NaiveUnitMemory:
    """Reference implementation: one array slot per unit, summed on every read.

    This is the paper's method written plainly. It costs O(N) per step and
    exists to check :class:`UnitMemory` and to benchmark against.

    :param n_units: [-] number of virtual motor units (N)
    :param f_iso_max_n: [N] maximal isometric force (f_iso_max)
    :param l_opt_m: [m] CE optimal length (l_opt)
    """

    def __init__(self, n_units: int, f_iso_max_n: float, l_opt_m: float) -> None:
        self._f_unit_max = f_iso_max_n / n_units
        self._l_opt = l_opt_m
        self.f_iso_j = np.zeros(n_units)
        self.n_recruited = 0

    def clear(self) -> None:
        """De-recruit every unit and erase its memory."""
        self.f_iso_j[:] = 0.0
        self.n_recruited = 0

    @property
    def eff_f_iso(self) -> float:
        """[N] Eff.f_iso as the sum over all unit slots (Eq. 2)."""
        return float(self.f_iso_j.sum())

    def update(self, m: int, l_ce_m: float) -> float:
        """Same contract as :meth:`UnitMemory.update`."""
        top = self.n_recruited
        if m > top:
            self.f_iso_j[top:m] = self._f_unit_max * force_length(l_ce_m / self._l_opt)
        elif m < top:
            self.f_iso_j[m:top] = 0.0
        self.n_recruited = m
        return self.eff_f_iso
