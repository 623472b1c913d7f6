"""The muscle: state, recruitment memory and one integration step.

The single continuous state is the CE length ``l_ce``; its derivative is the
inverse force-velocity relation evaluated at the tendon force (MODEL.md
section 4). The integrator is the classical fourth-order Runge-Kutta method
(RK4) with the recruitment held and the MTU length following a linear ramp
within the step. At the default 1 ms step it stays within 0.01 N of a
``solve_ivp`` reference at rtol 1e-10 on both of the paper's protocols; forward
Euler would be off by about 0.3 N.
"""
from __future__ import annotations

import math
from typing import NamedTuple

from .curves import force_length, force_velocity_inverse, parallel_force, series_force
from .memory import UnitMemory, recruited_units
from .params import MuscleParams

#: Largest |dl_mt| accepted as an input: far beyond the range where FL is
#: non-zero (l_ce / l_opt outside about 0.4..1.6), so anything larger is
#: a unit error (mm for m) rather than an experiment.
DL_MT_LIMIT_M = 1.0


class MuscleOutputs(NamedTuple):
    """The muscle's outputs at one instant (all SI).

    :param t_s: [s] simulated time
    :param recruitment: [-] recruitment R in force at this instant
    :param n_recruited: [-] recruited units M (``single``: 1 if R > 0 else 0)
    :param dl_mt_m: [m] MTU length change from rest (dl_MT)
    :param l_ce_m: [m] CE length (l_CE)
    :param v_ce_m_per_s: [m/s] CE velocity (v_CE), negative when shortening
    :param f_se_n: [N] series elastic force (f_SE), equal to the CE force
    :param f_pe_n: [N] parallel elastic force (f_PE)
    :param force_n: [N] muscle force f_SE + f_PE
    :param eff_f_iso_n: [N] effective isometric force (Eff.f_iso, F0)
    """

    t_s: float
    recruitment: float
    n_recruited: int
    dl_mt_m: float
    l_ce_m: float
    v_ce_m_per_s: float
    f_se_n: float
    f_pe_n: float
    force_n: float
    eff_f_iso_n: float


def check_recruitment(recruitment: float, name: str = 'recruitment') -> float:
    """Validate a recruitment value; raise ``ValueError`` naming it otherwise.

    :param recruitment: [-] recruitment R
    :param name: what to call the value in the error message
    :return: [-] R as a float, in [0, 1]
    """
    r = float(recruitment)
    if not 0.0 <= r <= 1.0:  # also false for NaN
        raise ValueError(f'`{name}` must be in [0, 1], got {recruitment!r}')
    return r


def recruitment_from_pulse_width(pulse_width_s: float, pw_max_s: float) -> float:
    """Recruitment of an FES pulse: R = clip(PW / PW_max, 0, 1).

    Saturation above PW_max is the stimulator's physics, not a correction:
    every unit is already recruited. Negative or non-finite widths raise.

    :param pulse_width_s: [s] stimulation pulse width (PW)
    :param pw_max_s: [s] pulse width that recruits every unit (PW_max)
    :return: [-] recruitment R in [0, 1]
    """
    pw = float(pulse_width_s)
    if not (math.isfinite(pw) and pw >= 0.0):
        raise ValueError(f'`pulse_width_s` must be finite and non-negative, '
                         f'got {pulse_width_s!r}')
    return min(pw / pw_max_s, 1.0)


def check_dl_mt(dl_mt_m: float, name: str = 'dl_mt_m') -> float:
    """Validate an MTU length change; raise ``ValueError`` naming it otherwise.

    :param dl_mt_m: [m] MTU length change from rest (dl_MT)
    :param name: what to call the value in the error message
    :return: [m] dl_MT as a float
    """
    dl = float(dl_mt_m)
    if not -DL_MT_LIMIT_M <= dl <= DL_MT_LIMIT_M:  # also false for NaN
        raise ValueError(f'`{name}` must be finite and within ±{DL_MT_LIMIT_M} m '
                         f'of rest, got {dl_mt_m!r}')
    return dl


class Muscle:
    """One Hill-type muscle-tendon unit with the motor-unit memory.

    Use :meth:`step` to advance by ``dt`` and read the returned
    :class:`MuscleOutputs`; :meth:`reset` returns to the resting state.

    :param params: the muscle's parameters (paper defaults if omitted)
    """

    def __init__(self, params: MuscleParams | None = None) -> None:
        self.params = params if params is not None else MuscleParams()
        p = self.params
        self._multi = p.units == 'multi'
        self._initial = p.length == 'initial'
        self._memory = UnitMemory(p.n_units, p.f_iso_max_n, p.l_opt_m)
        self.reset()

    # -- state ---------------------------------------------------------------

    def reset(self) -> None:
        """Return to the unique resting state and erase the motor-unit memory."""
        self.t_s = 0.0
        self.l_ce_m = self.params.l_rest_m
        self.dl_mt_m = 0.0
        self.recruitment = 0.0
        self.n_recruited = 0
        self._memory.clear()
        # Single/initial: the isometric force of the one unit, fixed at recruitment.
        self._f_iso_single_n = 0.0
        # Velocity of the free CE when Eff.f_iso = 0 (it follows the MTU).
        self._v_free = 0.0

    @property
    def n_runs(self) -> int:
        """Distinct recruitment instants held in the memory (multi/initial)."""
        return self._memory.n_runs

    def set_recruitment(self, recruitment: float) -> None:
        """Apply a recruitment level now, using the current CE length for new units.

        Idempotent: applying the same level again changes nothing.

        :param recruitment: [-] recruitment R in [0, 1]
        :raises ValueError: if R is outside [0, 1] or not finite
        """
        r = check_recruitment(recruitment)
        p = self.params
        if self._multi:
            m = recruited_units(r, p.n_units)
            if self._initial:
                self._memory.update(m, self.l_ce_m)
        else:
            m = 1 if r > 0.0 else 0
            if self._initial:
                if r == 0.0:
                    self._f_iso_single_n = 0.0
                elif self.recruitment == 0.0:
                    self._f_iso_single_n = p.f_iso_max_n * force_length(
                        self.l_ce_m / p.l_opt_m)
        self.recruitment = r
        self.n_recruited = m

    def set_pulse_width(self, pulse_width_s: float) -> None:
        """Apply an FES pulse width now: R = clip(PW / PW_max, 0, 1).

        :param pulse_width_s: [s] stimulation pulse width (PW), >= 0
        """
        self.set_recruitment(recruitment_from_pulse_width(pulse_width_s,
                                                          self.params.pw_max_s))

    def eff_f_iso(self, l_ce_m: float | None = None) -> float:
        """Effective isometric force (Eff.f_iso) of the four variants.

        Implements Eq. (2) of the paper (multi/initial) and its three
        siblings of MODEL.md section 2.

        :param l_ce_m: [m] CE length for the instantaneous variants
            (the current one if omitted)
        :return: [N] Eff.f_iso
        """
        p = self.params
        if self._initial:
            if self._multi:
                return self._memory.eff_f_iso
            return self.recruitment * self._f_iso_single_n if self.recruitment > 0 else 0.0
        l_ce = self.l_ce_m if l_ce_m is None else l_ce_m
        scale = self.n_recruited / p.n_units if self._multi else self.recruitment
        return scale * p.f_iso_max_n * force_length(l_ce / p.l_opt_m)

    def outputs(self) -> MuscleOutputs:
        """The outputs at the current instant, derived from the state."""
        p = self.params
        l_ce, dl = self.l_ce_m, self.dl_mt_m
        f_se = series_force(p.k_se_n_per_m, dl, l_ce, p.l_rest_m)
        f_pe = parallel_force(p.k_pe_n_per_m, dl)
        f0 = self.eff_f_iso()
        if f0 > 0.0:
            v_ce = force_velocity_inverse(f_se, f0, p.fv_a_n, p.fv_b_m_per_s,
                                          p.fv_a_ecc_n, p.fv_b_ecc_m_per_s)
        else:
            v_ce = self._v_free
        return MuscleOutputs(self.t_s, self.recruitment, self.n_recruited, dl, l_ce,
                             v_ce, f_se, f_pe, f_se + f_pe, f0)

    # -- dynamics ------------------------------------------------------------

    def _v_ce(self, l_ce: float, dl_mt: float, f0_held: float) -> float:
        """Right-hand side d l_ce / dt = FV_inv(f_se, Eff.f_iso) (MODEL.md section 4)."""
        p = self.params
        f0 = f0_held if self._initial else self.eff_f_iso(l_ce)
        stretch = dl_mt - (l_ce - p.l_rest_m)
        f_se = p.k_se_n_per_m * stretch if stretch > 0.0 else 0.0
        return force_velocity_inverse(f_se, f0, p.fv_a_n, p.fv_b_m_per_s,
                                      p.fv_a_ecc_n, p.fv_b_ecc_m_per_s)

    def advance(self, dl_mt_end_m: float, dt_s: float) -> None:
        """Integrate the CE length over one step with the recruitment held.

        The MTU length ramps linearly from its current value to
        ``dl_mt_end_m``. Classical RK4; when Eff.f_iso is zero the CE offers
        no resistance and takes the length that makes f_SE zero.

        :param dl_mt_end_m: [m] MTU length change at the end of the step
        :param dt_s: [s] step length, > 0
        """
        p = self.params
        dl0 = self.dl_mt_m
        dl1 = dl_mt_end_m
        l0 = self.l_ce_m
        f0 = self.eff_f_iso()
        if f0 > 0.0:
            h = dt_s
            dlm = 0.5 * (dl0 + dl1)
            k1 = self._v_ce(l0, dl0, f0)
            k2 = self._v_ce(l0 + 0.5 * h * k1, dlm, f0)
            k3 = self._v_ce(l0 + 0.5 * h * k2, dlm, f0)
            k4 = self._v_ce(l0 + h * k3, dl1, f0)
            l1 = l0 + h * (k1 + 2.0 * k2 + 2.0 * k3 + k4) / 6.0
        else:
            l1 = p.l_rest_m + dl1
        self.l_ce_m = l1
        self.dl_mt_m = dl1
        self.t_s += dt_s
        if not self._initial and self.eff_f_iso() == 0.0:
            # The instantaneous CE left the FL range within the step: it is
            # free again, so it takes up the SE slack (MODEL.md section 4).
            self.l_ce_m = p.l_rest_m + dl1
        self._v_free = (dl1 - dl0) / dt_s

    def step(self, recruitment: float, dl_mt_m: float, dt_s: float) -> MuscleOutputs:
        """Advance one step: recruit now, then integrate with R held.

        The memory changes only at the start of the step, from the CE length of
        that instant (MODEL.md section 4).

        :param recruitment: [-] recruitment R in [0, 1], held over the step
        :param dl_mt_m: [m] MTU length change at the end of the step (dl_MT)
        :param dt_s: [s] step length, > 0
        :return: the outputs at the end of the step
        :raises ValueError: on a NaN, infinite or out-of-range input; the state
            is unchanged
        """
        dl = check_dl_mt(dl_mt_m)
        if not (math.isfinite(dt_s) and dt_s > 0.0):
            raise ValueError(f'`dt_s` must be positive and finite, got {dt_s!r}')
        self.set_recruitment(recruitment)
        self.advance(dl, dt_s)
        return self.outputs()
