"""The muscle: state, recruitment memory and one integration step.

The single continuous state is the CE length ``l_ce``; its derivative is the
inverse force-velocity relation evaluated at the tendon force (doc/model.md
section 4). The integrator is the classical fourth-order Runge-Kutta method
(RK4) with the recruitment held and the MTU length following a linear ramp
within the step. At the default 1 ms step it stays within 0.01 N of a
``solve_ivp`` reference at rtol 1e-10 on both of the paper's protocols; forward
Euler would be off by about 0.3 N.
"""
from __future__ import annotations

import math
from typing import Callable, NamedTuple, Sequence

from .equations import (ECC_PLATEAU, FL_A, FL_B, FL_C, force_length, force_velocity_inverse,
                        parallel_force, series_force)
from .memory import UnitMemory, recruited_units
from .params import MuscleParams
from .substeps import MAX_SUBSTEP_S, length_ramp, substeps_for

#: Largest |dl_mt| accepted as an input: far beyond the range where FL is
#: non-zero (l_ce / l_opt outside about 0.4..1.6), so anything larger is
#: a unit error (mm for m) rather than an experiment.
DL_MT_LIMIT_M = 1.0

_tuple_new = tuple.__new__
_INF = math.inf


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
    :param command: [-] recruitment command u given last (before the delay and
        the activation; equal to R in the paper's model)
    :param mean_fitness: [-] mean fitness of all units (1 without fatigue)
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
    command: float
    mean_fitness: float


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


def recruitment_from_pulse_width(pulse_width_s: float, pw_max_s: float,
                                 name: str = 'pulse_width_s') -> float:
    """Recruitment of an FES pulse: R = clip(PW / PW_max, 0, 1).

    Saturation above PW_max is the stimulator's physics, not a correction:
    every unit is already recruited. Negative or non-finite widths raise.

    :param pulse_width_s: [s] stimulation pulse width (PW)
    :param pw_max_s: [s] pulse width that recruits every unit (PW_max)
    :param name: what to call the value in the error message (e.g. the topic)
    :return: [-] recruitment R in [0, 1]
    """
    pw = float(pulse_width_s)
    if not (math.isfinite(pw) and pw >= 0.0):
        raise ValueError(f'`{name}` must be finite and non-negative, '
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

    All stepping goes through one hot loop, :meth:`run`, which advances any
    number of steps over input sequences: :meth:`step` (the ROS node, once a
    tick) calls it with one step, :func:`~hill_muscle_ros.model.simulate.simulate`
    (the CLI) with a whole protocol, or the same loop compiled
    (:func:`~hill_muscle_ros.model.kernels.run_compiled`) where that pays. :meth:`outputs` and :meth:`eff_f_iso`
    evaluate the readable curves of :mod:`.equations` and are the reference the
    tests compare the hot loop against.

    With any FES extension switched on in ``params``, ``Muscle(params)`` makes
    a :class:`~hill_muscle_ros.model.fes_muscle.FesMuscle`, which has the same
    interface; with every FES parameter at its default it is this class, the
    paper's model, with its specialised loop.

    :param params: the muscle's parameters (paper defaults if omitted)
    """

    def __new__(cls, params: MuscleParams | None = None) -> 'Muscle':
        if cls is Muscle and params is not None and not params.fes_defaults:
            from .fes_muscle import FesMuscle   # it subclasses Muscle: imported late
            return super().__new__(FesMuscle)
        return super().__new__(cls)

    def __init__(self, params: MuscleParams | None = None) -> None:
        self.params = params if params is not None else MuscleParams()
        p = self.params
        self._multi = p.units == 'multi'
        self._initial = p.length == 'initial'
        self._memory = UnitMemory(p.n_units, p.f_iso_max_n, p.l_opt_m)
        # The hot loop, built once so that a single step pays no set-up.
        self._run = _hot_loop(self)
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
        # [N] Eff.f_iso (initial) or Eff.f_iso / FL(l_ce / l_opt) (instantaneous):
        # everything the recruitment contributes, so that the hot loop needs
        # only a multiplication to get Eff.f_iso.
        self._gain_n = 0.0
        # Velocity of the free CE when Eff.f_iso = 0 (it follows the MTU).
        self._v_free = 0.0
        # (l_ce, dl_mt, gain, v_ce) at the end of the last run: v_ce is a pure
        # function of the first three, so it is valid whenever they match.
        self._v_end = (math.nan, math.nan, math.nan, math.nan)

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
        self._apply_recruitment(check_recruitment(recruitment))
        if self.eff_f_iso() == 0.0:
            self.l_ce_m = self.params.l_rest_m + self.dl_mt_m   # released: the CE is free

    def _apply_recruitment(self, r: float) -> float:
        """Update the memory for a validated R at the current CE length.

        :param r: [-] recruitment R in [0, 1], already validated
        :return: [N] the new gain (see :meth:`reset`)
        """
        p = self.params
        if self._multi:
            m = recruited_units(r, p.n_units)
            if self._initial:
                gain = self._memory.update(m, self.l_ce_m)
            else:
                gain = m / p.n_units * p.f_iso_max_n
        else:
            m = 1 if r > 0.0 else 0
            if self._initial:
                if r == 0.0:
                    self._f_iso_single_n = 0.0
                elif self.recruitment == 0.0:
                    self._f_iso_single_n = p.f_iso_max_n * force_length(
                        self.l_ce_m / p.l_opt_m)
                gain = r * self._f_iso_single_n
            else:
                gain = r * p.f_iso_max_n
        self.recruitment = r
        self.n_recruited = m
        self._gain_n = gain
        return gain

    def set_pulse_width(self, pulse_width_s: float) -> None:
        """Apply an FES pulse width now, through the recruitment curve
        (:func:`~hill_muscle_ros.model.stimulus.command_from_pulse_width`).

        :param pulse_width_s: [s] stimulation pulse width (PW), >= 0
        """
        from .stimulus import command_from_pulse_width   # stimulus imports params only
        self.set_recruitment(command_from_pulse_width(pulse_width_s, self.params))

    def eff_f_iso(self, l_ce_m: float | None = None) -> float:
        """Effective isometric force (Eff.f_iso) of the four variants.

        Implements Eq. (2) of the paper (multi/initial) and its three
        siblings of doc/model.md section 2. This is the readable reference; the
        hot loop of :meth:`run` computes the same value inline.

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
        # x = l_CE (1 / l_opt), as every engine's step takes it (kernels.eff_f_iso).
        return scale * p.f_iso_max_n * force_length(l_ce * (1.0 / p.l_opt_m))

    def outputs(self) -> MuscleOutputs:
        """The outputs at the current instant, derived from the state.

        Evaluates the readable curves of :mod:`.equations`; :meth:`run` returns
        the same values from its inlined arithmetic.
        """
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
                             v_ce, f_se, f_pe, f_se + f_pe, f0, self.recruitment, 1.0)

    # -- dynamics ------------------------------------------------------------

    def run(self, r_start: Sequence[float], dl_mt_end_m: Sequence[float], dt_s: float,
            r_end: Sequence[float] | None = None,
            columns: Sequence[list] | None = None) -> MuscleOutputs:
        """Advance ``len(dl_mt_end_m)`` steps: the one hot loop of the model.

        Step k applies the recruitment ``r_start[k]`` (new units store the CE
        length of that instant), integrates the CE length over ``dt_s`` with R
        held and the MTU length ramping linearly to ``dl_mt_end_m[k]``, then
        applies ``r_end[k]`` (default: ``r_start[k]``, which changes nothing)
        and evaluates the outputs. :func:`.simulate` passes ``r_end[k] =
        r_start[k + 1]`` so each sample shows the recruitment of its instant.

        The integrator is classical RK4 (doc/model.md section 4). When Eff.f_iso
        is zero the CE offers no resistance and takes the length that makes
        f_SE zero. The curves of :mod:`.equations` (Eq. 1, Eq. 3, the springs)
        are inlined here because function calls dominate a pure-Python step;
        the tests check this loop against them. Inputs are not validated:
        :meth:`step` validates, :func:`.simulate` checks whole arrays.

        :param r_start: [-] recruitment R in [0, 1] held over each step
        :param dl_mt_end_m: [m] MTU length change at the end of each step
        :param dt_s: [s] step length, > 0: the integrator's own step, taken
            whole (:meth:`step` and :func:`.simulate` cut a longer one into
            substeps of at most 1 ms first)
        :param r_end: [-] recruitment applied after each step, before the outputs
        :param columns: if given, twelve preallocated lists in the order of
            :class:`MuscleOutputs`; step k writes index k of each
        :return: the outputs after the last step
        """
        return self._run(r_start, dl_mt_end_m, dt_s, r_end, columns)

    def advance(self, dl_mt_end_m: float, dt_s: float) -> None:
        """Integrate the CE length over one step with the recruitment held.

        The MTU length ramps linearly from its current value to
        ``dl_mt_end_m``; see :meth:`run`. A step longer than 1 ms is
        integrated in substeps, as :meth:`step`'s.

        :param dl_mt_end_m: [m] MTU length change at the end of the step
        :param dt_s: [s] step length, > 0
        """
        self._substeps(self.recruitment, dl_mt_end_m, dt_s)

    def step(self, recruitment: float, dl_mt_m: float, dt_s: float) -> MuscleOutputs:
        """Advance one step: recruit now, then integrate with R held.

        The memory changes only at the start of the step, from the CE length of
        that instant (doc/model.md section 4). A step longer than
        :data:`~.substeps.MAX_SUBSTEP_S` (1 ms) is integrated in n = ceil(dt / 1 ms)
        equal substeps, R held and dl_MT ramping linearly across them
        (:mod:`.substeps`): ``dt_s`` is how often the caller samples, not the
        integrator's step.

        :param recruitment: [-] recruitment R in [0, 1], held over the step
        :param dl_mt_m: [m] MTU length change at the end of the step (dl_MT)
        :param dt_s: [s] step length, > 0
        :return: the outputs at the end of the step
        :raises ValueError: on a NaN, infinite or out-of-range input; the state
            is unchanged
        """
        r, dl = float(recruitment), float(dl_mt_m)
        # One combined check (false for NaN too) keeps the node's tick cheap;
        # the helpers run only to raise the error that names the culprit.
        if not (0.0 <= r <= 1.0 and -DL_MT_LIMIT_M <= dl <= DL_MT_LIMIT_M
                and 0.0 < dt_s < _INF):
            check_dl_mt(dl_mt_m)
            if not (math.isfinite(dt_s) and dt_s > 0.0):
                raise ValueError(f'`dt_s` must be positive and finite, got {dt_s!r}')
            check_recruitment(recruitment)
        return self._substeps(r, dl, dt_s)

    def _substeps(self, r: float, dl_mt_end_m: float, dt_s: float) -> MuscleOutputs:
        """One output step of ``dt_s`` as n = ceil(dt / 1 ms) substeps of the hot
        loop (:mod:`.substeps`), R held and dl_MT ramping linearly across them.

        :param r: [-] recruitment R, validated, held over the step
        :param dl_mt_end_m: [m] dl_MT at the end of the step, validated
        :param dt_s: [s] step length, validated
        :return: the outputs at the end of the step
        """
        if dt_s <= MAX_SUBSTEP_S:   # the node's 1 kHz tick: no lists to build
            return self._run((r,), (dl_mt_end_m,), dt_s, None, None)
        n = substeps_for(dt_s)
        return self._run((r,) * n, length_ramp(self.dl_mt_m, dl_mt_end_m, n), dt_s / n,
                         None, None)


def _hot_loop(muscle: Muscle) -> Callable[..., MuscleOutputs]:
    """Build the one hot loop of a muscle: see :meth:`Muscle.run`.

    The parameters are bound once, as closure constants; the state is read
    from and written back to the muscle on every call, so :meth:`Muscle.reset`,
    :meth:`Muscle.set_recruitment` and the public state attributes stay the
    single source of truth.
    """
    p = muscle.params
    k_se, k_pe, l_rest, l_opt = p.k_se_n_per_m, p.k_pe_n_per_m, p.l_rest_m, p.l_opt_m
    a, b, a_ecc, b_ecc = p.fv_a_n, p.fv_b_m_per_s, p.fv_a_ecc_n, p.fv_b_ecc_m_per_s
    two_b_ecc = 2.0 * b_ecc
    # x = l_CE (1 / l_opt), as every engine's step takes it (kernels.eff_f_iso).
    inv_l_opt = 1.0 / l_opt
    initial = muscle._initial
    apply_recruitment = muscle._apply_recruitment

    def f0_at(l_ce: float, gain: float) -> float:
        """[N] Eff.f_iso at CE length ``l_ce`` (Eq. 1 inlined)."""
        if initial:
            return gain
        x = l_ce * inv_l_opt
        fl = (FL_A * x + FL_B) * x + FL_C
        return gain * fl if fl > 0.0 else 0.0

    def velocity_at_f0(l_ce: float, dl_mt: float, f0: float) -> float:
        """[m/s] d l_ce / dt = FV_inv(f_SE, F0) for a given Eff.f_iso ``f0``;
        the springs and Eq. 3 inlined (the SE spring never pushes: f <= 0 is slack)."""
        return fv_inverse(k_se * (dl_mt - (l_ce - l_rest)), f0)

    def fv_inverse(f: float, f0: float) -> float:
        """[m/s] FV_inv(f, F0): Eq. 3 inverted at SE force ``f`` (slack at or below 0)."""
        if f <= 0.0:
            return -f0 * b / a
        if f <= f0:
            return b * (f - f0) / (f + a)
        if f < ECC_PLATEAU * f0:
            # 2 b' (f - F0) is b' (2 f - 2 F0) exactly: doubling never rounds.
            return two_b_ecc * (f - f0) / (3.0 * f0 - 2.0 * f + a_ecc)
        return f0 * b_ecc / a_ecc

    if initial:
        # Eff.f_iso is the gain itself, fixed while R is held: the RK4 stages
        # call the FV inverse directly (this is the path the node and the
        # benchmarks' multi/initial take, so it saves a call per stage).
        velocity = velocity_at_f0
    else:
        def velocity(l_ce: float, dl_mt: float, gain: float) -> float:
            """[m/s] d l_ce / dt with Eff.f_iso following the CE length (Eq. 1)."""
            x = l_ce * inv_l_opt
            fl = (FL_A * x + FL_B) * x + FL_C
            return velocity_at_f0(l_ce, dl_mt, gain * fl if fl > 0.0 else 0.0)

    def run(r_start: Sequence[float], dl_mt_end_m: Sequence[float], dt: float,
            r_end: Sequence[float] | None,
            columns: Sequence[list] | None) -> MuscleOutputs:
        """:meth:`Muscle.run` of the muscle this loop was built for (``dt`` [s])."""
        half_dt = 0.5 * dt
        c_half, c_full = k_se * half_dt, k_se * dt
        if r_end is None:
            r_end = r_start
        if columns is not None:
            (c_t, c_r, c_m, c_dl, c_l, c_v, c_se, c_pe, c_force, c_f0, c_u, c_mu) = columns
        l = muscle.l_ce_m
        dl0 = muscle.dl_mt_m
        t = muscle.t_s
        v_free = muscle._v_free
        r_now = muscle.recruitment
        m_now = muscle.n_recruited
        gain = muscle._gain_n
        # f0 and v are the outputs at the current instant; while the
        # recruitment is unchanged, v is also the first RK4 stage of the
        # next step (same state, same inputs), so it is computed once.
        f0 = gain if initial else f0_at(l, gain)
        if f0 > 0.0:
            # One call per step (the node's Muscle.step) would otherwise
            # recompute the velocity the previous call ended with: reuse it
            # when the state and the gain are exactly those it was made from.
            cached = muscle._v_end
            v = (cached[3] if cached[0] == l and cached[1] == dl0 and cached[2] == gain
                 else velocity(l, dl0, gain))
        else:
            v = v_free
        for k, dl1 in enumerate(dl_mt_end_m):
            r = r_start[k]
            if r != r_now:
                muscle.l_ce_m = l
                gain = apply_recruitment(r)
                r_now, m_now = r, muscle.n_recruited
                f0 = f0_at(l, gain)
                if f0 > 0.0:
                    v = velocity(l, dl0, gain)
            if f0 > 0.0:
                # The stages' SE forces as k_SE (dl - (l - l_rest)) - k_SE h k,
                # as every engine writes them (kernels.step_one says why).
                from_rest = l - l_rest
                f_mid = k_se * (0.5 * (dl0 + dl1) - from_rest)
                f_end = k_se * (dl1 - from_rest)
                if initial:
                    k2 = fv_inverse(f_mid - c_half * v, gain)
                    k3 = fv_inverse(f_mid - c_half * k2, gain)
                    k4 = fv_inverse(f_end - c_full * k3, gain)
                else:
                    k2 = fv_inverse(f_mid - c_half * v, f0_at(l + half_dt * v, gain))
                    k3 = fv_inverse(f_mid - c_half * k2, f0_at(l + half_dt * k2, gain))
                    k4 = fv_inverse(f_end - c_full * k3, f0_at(l + dt * k3, gain))
                l = l + dt / 6.0 * (v + 2.0 * k2 + 2.0 * k3 + k4)
            else:
                l = l_rest + dl1
            if not initial:
                f0 = f0_at(l, gain)
            if f0 == 0.0:
                # Nothing recruited, or the instantaneous CE left the FL range
                # within the step: the free CE takes up the SE slack (doc/model.md 4).
                l = l_rest + dl1
                if not initial:
                    # The outputs and the next step read the state: Eff.f_iso at
                    # the free length, which may be back inside the FL range.
                    f0 = f0_at(l, gain)
            v_free = (dl1 - dl0) / dt
            dl0 = dl1
            t += dt
            r = r_end[k]
            if r != r_now:
                muscle.l_ce_m = l
                gain = apply_recruitment(r)
                r_now, m_now = r, muscle.n_recruited
                f0 = f0_at(l, gain)
                if f0 == 0.0:
                    # Released at this instant: the free CE takes up the slack
                    # at once, so the sample shows f_SE = 0 (doc/model.md 4).
                    l = l_rest + dl1
                    f0 = f0_at(l, gain)   # as above: read off the state
            v = fv_inverse(k_se * (dl1 - (l - l_rest)), f0) if f0 > 0.0 else v_free
            if columns is not None:
                stretch = dl1 - (l - l_rest)
                f_se = k_se * stretch if stretch > 0.0 else 0.0
                f_pe = k_pe * dl1 if dl1 > 0.0 else 0.0
                c_t[k] = t
                c_r[k] = r_now
                c_m[k] = m_now
                c_dl[k] = dl1
                c_l[k] = l
                c_v[k] = v
                c_se[k] = f_se
                c_pe[k] = f_pe
                c_force[k] = f_se + f_pe
                c_f0[k] = f0
                c_u[k] = r_now
                c_mu[k] = 1.0
        muscle.l_ce_m = l
        muscle.dl_mt_m = dl0
        muscle.t_s = t
        muscle._v_free = v_free
        muscle._v_end = (l, dl0, gain, v)
        stretch = dl0 - (l - l_rest)
        f_se = k_se * stretch if stretch > 0.0 else 0.0
        f_pe = k_pe * dl0 if dl0 > 0.0 else 0.0
        # NamedTuple's generated __new__ is a Python function; building the
        # tuple directly gives the same object at a quarter of the cost.
        return _tuple_new(MuscleOutputs, (t, r_now, m_now, dl0, l, v, f_se, f_pe,
                                          f_se + f_pe, f0, r_now, 1.0))

    return run
