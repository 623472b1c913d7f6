"""The paper's method written plainly: the naive baseline of the benchmark.

One array slot per unit holding its stored isometric force, updated on
recruitment and summed on every step (Eq. 2 taken literally), with the same
RK4 integrator and the same scalar curves as the package. Only the memory
differs from ``multi``/``initial``; its cost grows with N.
"""
from __future__ import annotations

from hill_muscle_ros.model import MuscleParams, NaiveUnitMemory, recruited_units
from hill_muscle_ros.model.curves import (force_velocity_inverse, parallel_force,
                                          series_force)


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
