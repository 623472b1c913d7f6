"""An independent fine-tolerance reference for the muscle ODE (test helper).

Integrates d l_ce / dt = FV_inv(f_se, Eff.f_iso) with SciPy's DOP853 at
rtol 1e-10, restarting at every protocol breakpoint: recruitment events
(where the memory changes, from the l_ce of that instant) and MTU ramp kinks.
The memory uses the naive per-unit array, not the LIFO stack under test.
"""
import numpy as np
from scipy.integrate import solve_ivp

from hill_muscle_ros.model import MuscleParams, Protocol
from hill_muscle_ros.model.equations import force_length, force_velocity_inverse, series_force
from hill_muscle_ros.model.memory import recruited_units


class NaiveUnitMemory:
    """Reference implementation: one array slot per unit, summed on every read.

    This is the paper's method written plainly (Eq. 2): the oracle's memory,
    written independently of the engine's segment stacks.

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
        """Recruit or release so that units [0, m) are recruited, new ones at
        CE length ``l_ce_m`` [m]; return [N] Eff.f_iso."""
        top = self.n_recruited
        if m > top:
            self.f_iso_j[top:m] = self._f_unit_max * force_length(l_ce_m / self._l_opt)
        elif m < top:
            self.f_iso_j[m:top] = 0.0
        self.n_recruited = m
        return self.eff_f_iso


def reference_force(protocol: Protocol, params: MuscleParams, t_eval: np.ndarray):
    """Muscle force [N] at ``t_eval`` (which must lie in [0, duration])."""
    p = params
    breaks = np.union1d(protocol.stimulation.breakpoints_s, protocol.dl_mt_m.breakpoints_s)
    breaks = np.union1d(breaks[(breaks > 0) & (breaks < protocol.duration_s)],
                        [0.0, protocol.duration_s])
    memory = NaiveUnitMemory(p.n_units, p.f_iso_max_n, p.l_opt_m)
    f_iso_single = 0.0
    r_prev = 0.0
    l_ce = p.l_rest_m
    force = np.full(t_eval.shape, np.nan)
    hill = (p.fv_a_n, p.fv_b_m_per_s, p.fv_a_ecc_n, p.fv_b_ecc_m_per_s)
    for t0, t1 in zip(breaks[:-1], breaks[1:]):
        r = float(protocol.recruitment(t0, p.pw_max_s))
        if r != float(protocol.recruitment(0.5 * (t0 + t1), p.pw_max_s)):
            raise ValueError('reference supports piecewise-constant recruitment only')
        m = recruited_units(r, p.n_units)
        memory.update(m, l_ce)
        if r > 0 and r_prev == 0:
            f_iso_single = p.f_iso_max_n * force_length(l_ce / p.l_opt_m)
        r_prev = r
        scale = m / p.n_units if p.units == 'multi' else r
        if p.length == 'initial':
            f0_const = memory.eff_f_iso if p.units == 'multi' else r * f_iso_single

            def f0_of(_l, f0=f0_const):
                return f0
        else:
            def f0_of(l, scale=scale):
                return scale * p.f_iso_max_n * force_length(l / p.l_opt_m)

        def rhs(t, y, f0_of=f0_of):
            dl = float(protocol.dl_mt(t))
            f_se = series_force(p.k_se_n_per_m, dl, y[0], p.l_rest_m)
            return [force_velocity_inverse(f_se, f0_of(y[0]), *hill)]

        if f0_of(l_ce) <= 0:
            raise ValueError('reference does not model the free CE')
        sol = solve_ivp(rhs, (t0, t1), [l_ce], method='DOP853', rtol=1e-10, atol=1e-13,
                        dense_output=True, max_step=0.01)
        inside = (t_eval >= t0) & (t_eval <= t1)
        ts = t_eval[inside]
        l_seg = sol.sol(ts)[0]
        dl = np.asarray(protocol.dl_mt(ts))
        f_se = p.k_se_n_per_m * np.maximum(0.0, dl - (l_seg - p.l_rest_m))
        force[inside] = f_se + p.k_pe_n_per_m * np.maximum(0.0, dl)
        l_ce = float(sol.y[0, -1])
    return force
