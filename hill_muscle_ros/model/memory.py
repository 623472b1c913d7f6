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
"""
from __future__ import annotations

import numpy as np

from .curves import force_length


def recruited_units(recruitment: float, n_units: int) -> int:
    """Number of recruited units M = floor(N R + 0.5) (doc/model.md section 2).

    :param recruitment: [-] recruitment R in [0, 1]
    :param n_units: [-] number of virtual units N
    :return: [-] M, in [0, N]
    """
    return int(n_units * recruitment + 0.5)


class UnitMemory:
    """LIFO stack of recruitment runs; implements Eq. (2) of the paper.

    Eff.f_iso = sum over recruited units j of ``f_iso_max / N * FL(l_o_j / l_opt)``.

    :param n_units: [-] number of virtual motor units (N)
    :param f_iso_max_n: [N] maximal isometric force (f_iso_max)
    :param l_opt_m: [m] CE optimal length (l_opt)
    """

    __slots__ = ('_f_unit_max', '_l_opt', '_count', '_f_unit', '_total')

    def __init__(self, n_units: int, f_iso_max_n: float, l_opt_m: float) -> None:
        self._f_unit_max = f_iso_max_n / n_units
        self._l_opt = l_opt_m
        # Index 0 is a sentinel run "no units, no force" so that the totals of
        # the run below the top always exist.
        self._count = [0]       # cumulative number of units up to each run
        self._f_unit = [0.0]    # [N] isometric force of each unit in the run
        self._total = [0.0]     # [N] cumulative isometric force up to each run

    def clear(self) -> None:
        """De-recruit every unit and erase its memory."""
        del self._count[1:], self._f_unit[1:], self._total[1:]

    @property
    def n_recruited(self) -> int:
        """[-] number of recruited units M."""
        return self._count[-1]

    @property
    def eff_f_iso(self) -> float:
        """[N] effective isometric force of the recruited units (Eff.f_iso, Eq. 2)."""
        return self._total[-1]

    @property
    def n_runs(self) -> int:
        """Number of runs on the stack (units recruited at distinct instants)."""
        return len(self._count) - 1

    def update(self, m: int, l_ce_m: float) -> float:
        """Recruit or de-recruit so that exactly the units 1..m are recruited.

        Newly recruited units store the current CE length; de-recruited units
        (always the highest-numbered) lose their memory.

        :param m: [-] number of units to have recruited (M), in [0, N]
        :param l_ce_m: [m] CE length at this instant (l_CE), stored as l_o_j
        :return: [N] the new Eff.f_iso
        """
        count = self._count
        top = count[-1]
        if m > top:
            f_unit = self._f_unit_max * force_length(l_ce_m / self._l_opt)
            count.append(m)
            self._f_unit.append(f_unit)
            self._total.append(self._total[-1] + (m - top) * f_unit)
        elif m < top:
            f_unit, total = self._f_unit, self._total
            while len(count) > 1 and count[-2] >= m:
                count.pop()
                f_unit.pop()
                total.pop()
            if count[-1] != m:
                count[-1] = m
                total[-1] = total[-2] + (m - count[-2]) * f_unit[-1]
        return self._total[-1]


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
