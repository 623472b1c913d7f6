"""The limb over flat arrays: :class:`~hill_muscle_ros.model.limb.Limb`'s step as plain
functions for Python and numba.

The joint and its muscles are integrated together exactly as
:meth:`Limb.step <hill_muscle_ros.model.limb.Limb.step>` does it: each
muscle plans its recruitment changes of the step, the events of all muscles
are taken in time order (a stable sort: each muscle keeps its own order), the
joint and every CE length are integrated with RK4 up to each event, with as
many substeps as the stiffest CE needs; a quasi-static CE is out of the RK4
state (its SE carries :func:`~.fes_muscle.quasi_static_force` of its MTU's
velocity). The muscles are those of
:mod:`.fes_kernels` (every variant and FES feature), their equations the
shared ones; the joint's are written here once and are the reference's
(the reference's ``_forces`` and ``_rk4`` are the readable form of the same
sums, checked against these to 1e-9 rad and 1e-9 N by test_limb_compiled).

:func:`simulate_limb_compiled` is :func:`~hill_muscle_ros.model.limb.simulate_limb`
on the compiled engine; ``simulate_limb`` calls it when
:func:`~hill_muscle_ros.model.engine.choice` is ``compiled``.
:class:`CompiledLimb` is :class:`~hill_muscle_ros.model.limb.Limb`'s
step-by-step interface on the compiled step (for
:class:`~hill_muscle_ros.model.limb_batch.LimbBatch` and the KneeAngle-v0
environment; :func:`make_limb` and :func:`step_engine` choose).
"""
from __future__ import annotations

import math  # the joint's equations (limb.py), compiled over this scope, call it
import sys
import types
from typing import Sequence

import numpy as np

from . import equations, fes_kernels, fes_muscle, limb, memory, stimulus, unit_pool, units
from .equations import (QUASI_STATIC_RATE_PER_S, SINE_SERIES_MAX_RAD, activation_at,
                        joint_acceleration_sin, mtu_length_change, parallel_force, rk4_update,
                        series_force, sine_near, substep_count)
from .muscle import DL_MT_LIMIT_M
from .fes_kernels import (A_END, DELAY_FULL, H_DQT, H_EVT, H_FP, H_FS, H_IP, H_JS, I_INITIAL,
                          I_MULTI, I_N, J_DCOUNT, J_DHEAD, J_NEV, J_NREC, OK, P_K_PE, P_K_SE,
                          P_L_REST, S_CMD, S_DL, S_L, S_R, S_T, S_UD, TIME_TOL_S, FesBundle,
                          ScratchPool, apply, begin_interval, eff_f_iso, eff_f_iso_inline,
                          end_interval, give_command, hdr, peak_rate, plan, quasi_force, rate_at,
                          set_piece, settle_now, tau_for, velocity)
from .memory import recruited_units
from .substeps import repeat_rows, substeps_for

# Entries of the limb's float array ``L``: the joint, its state, an RK4 step's
# angular velocities and accelerations at its four stages (scratch of
# limb_rk4), then per muscle (from L_MUSCLES, L_PER_MUSCLE each) its action
# sign, moment arm and reference angle.
(L_INERTIA, L_MASS, L_GRAVITY, L_COM, L_STIFFNESS, L_EQUILIBRIUM, L_DAMPING, L_THETA,
 L_OMEGA, L_T, L_TAU) = range(11)
L_STAGE_OMEGA = 11
L_STAGE_ALPHA = L_STAGE_OMEGA + 4
L_MUSCLES = L_STAGE_ALPHA + 4
M_SIGN, M_ARM, M_REF = range(3)
L_PER_MUSCLE = 3
# Rows of the stage scratch ``W`` (rows of muscles): CE lengths of the four
# stages, CE velocities of the four stages, free flags, quasi-static flags,
# F0 at the step's start, middle and end where it does not depend on l_CE,
# steady flags (:func:`plan_steady`) and a steady muscle's activation at the
# step's end.
(W_L1, W_L2, W_L3, W_L4, W_V1, W_V2, W_V3, W_V4, W_FREE, W_QUASI, W_F0A, W_F0M,
 W_F0B, W_STEADY, W_A_END) = range(15)
N_W = 15
#: Status of a limb step beyond fes_kernels' OK and DELAY_FULL: muscle i is
#: stretched out of range at the step's end (status DL_OUT_OF_RANGE + i).
DL_OUT_OF_RANGE = 2
#: A failed run returns -(k STATUS_BASE + status), k the failed step: more than
#: any status (DL_OUT_OF_RANGE + the number of muscles).
STATUS_BASE = 1 << 20


def muscle_slot(i):
    """Index in ``L`` of muscle ``i``'s entries."""
    return L_MUSCLES + L_PER_MUSCLE * i


def dl_mt(L, i, theta):
    """[m] muscle ``i``'s MTU length change at ``theta``: -s r (theta - theta_ref)."""
    j = muscle_slot(i)
    return mtu_length_change(L[j + M_SIGN] * L[j + M_ARM], theta, L[j + M_REF])


def length_free(I, i):
    """True if muscle ``i``'s F0 does not depend on l_CE (``length: initial``):
    a step then takes it once per stage instant (W_F0A, W_F0M, W_F0B)."""
    return I[hdr(I, i, H_IP) + I_INITIAL] != 0


def plan_steady(F, I, W, i, t0, t1):
    """Plan the multi muscle ``i``'s step [t0, t1] without its event table if
    no unit joins or leaves in it; return whether it did.

    Steady: no delayed command switches before ``t1``, and the activation (a
    monotone piece) rounds to the units recruited now at ``t1`` too (the test
    :func:`~.fes_kernels.plan_events` makes). :func:`~.fes_kernels.plan`
    would then give only the activation's piece from ``t0`` and its value at
    ``t1``: the piece is set here, the value kept in ``W`` for the step's end
    (:func:`limb_step`). With no unit recruited the muscle rests (:func:`resting`)
    and :func:`limb_integrate` takes F0 = 0 without asking the pool. In the
    knee extension the hamstrings rest throughout, and the quadriceps is
    steady except while units join or leave.
    """
    fs, js, ip = hdr(I, i, H_FS), hdr(I, i, H_JS), hdr(I, i, H_IP)
    if I[ip + I_MULTI] == 0:
        return False
    if I[js + J_DCOUNT] > 0 and F[hdr(I, i, H_DQT) + I[js + J_DHEAD]] < t1 - TIME_TOL_S:
        return False   # plan would take the switch
    a, u_d = F[fs + S_R], F[fs + S_UD]
    tau = tau_for(F, I, i, a, u_d) if u_d != a else 0.0
    if tau == 0.0:
        if u_d != a:
            return False   # a jump
        a_end = a
    else:
        a_end = activation_at(a, u_d, tau, t1 - t0)
        if recruited_units(a_end, I[ip + I_N]) != I[js + J_NREC]:
            return False
    set_piece(F, I, i, t0, a, u_d, tau)
    W[W_A_END, i] = a_end
    W[W_STEADY, i] = 1.0
    return True


def resting(F, I, W, i):
    """True if muscle ``i`` is steady in this step (:func:`plan_steady`) with no
    unit recruited: its F0 is 0 throughout the step."""
    return W[W_STEADY, i] != 0.0 and I[hdr(I, i, H_JS) + J_NREC] == 0


def settle_ce(F, I, i, t):
    """After an event of muscle ``i`` at ``t``: a CE without F0 is free (limb_step)."""
    fs = hdr(I, i, H_FS)
    if eff_f_iso_inline(F, I, i, F[fs + S_L], t) == 0.0:
        F[fs + S_L] = F[hdr(I, i, H_FP) + P_L_REST] + F[fs + S_DL]


def stage_f0(F, I, W, i, l, stage, t):
    """[N] F0 of muscle ``i`` at RK4 stage ``stage`` (a row W_L1..W_L4 of ``W``),
    CE length ``l``, instant ``t``: limb_rk4's where it does not depend on l_CE."""
    if length_free(I, i):
        return W[W_F0A + (stage + 1) // 2, i]   # stages 1, 2, 3, 4: start, mid, mid, end
    return eff_f_iso(F, I, i, l, t)


def forces(F, I, L, W, nm, theta, sin_theta, omega, stage, t, v_row):
    """[rad/s^2] the joint's angular acceleration at one RK4 stage, and each CE's
    velocity into row ``v_row`` of ``W`` (Limb._forces).

    :param sin_theta: sin ``theta``
    :param stage: row of ``W`` holding the stage's CE lengths
    """
    torque = 0.0
    for i in range(nm):
        j = muscle_slot(i)
        fp = hdr(I, i, H_FP)
        s_r = L[j + M_SIGN] * L[j + M_ARM]
        dl = mtu_length_change(s_r, theta, L[j + M_REF])
        if W[W_FREE, i] != 0.0:
            f_se = 0.0
            W[v_row, i] = -s_r * omega          # the free CE follows its MTU
        elif W[W_QUASI, i] != 0.0:
            f_se = quasi_force(F, I, i, -s_r * omega, stage_f0(F, I, W, i, W[stage, i], stage, t))
            W[v_row, i] = -s_r * omega          # and so does the quasi-static one
        else:
            l = W[stage, i]
            f_se = series_force(F[fp + P_K_SE], dl, l, F[fp + P_L_REST])
            W[v_row, i] = velocity(F, I, i, l, dl, stage_f0(F, I, W, i, l, stage, t))
        torque += s_r * (f_se + parallel_force(F[fp + P_K_PE], dl))
    return joint_acceleration_sin(torque, theta, sin_theta, omega, L[L_TAU], L[L_INERTIA],
                                  L[L_MASS], L[L_GRAVITY], L[L_COM], L[L_STIFFNESS],
                                  L[L_EQUILIBRIUM], L[L_DAMPING])


def stage_f0s(F, I, W, i, l, s0, mid, s1):
    """F0 of a length-free muscle ``i`` at a step's start, middle and end into ``W``
    (rows W_F0A, W_F0M, W_F0B: a loop, so that the F0 is compiled in once)."""
    for j in range(3):
        t = s0 if j == 0 else (mid if j == 1 else s1)
        W[W_F0A + j, i] = eff_f_iso_inline(F, I, i, l, t)


def limb_rk4(F, I, L, W, nm, s0, s1, have_f0):
    """One RK4 step of the joint and every CE over [s0, s1] (Limb._rk4).

    :param have_f0: True if ``W`` holds the F0s of [s0, s1] of the length-free
        muscles already (limb_integrate's, for an interval of one step)
    """
    h = s1 - s0
    mid = s0 + 0.5 * h
    for i in range(nm):
        fs = hdr(I, i, H_FS)
        l = F[fs + S_L]
        W[W_L1, i] = l
        if length_free(I, i):
            if not have_f0:
                stage_f0s(F, I, W, i, l, s0, mid, s1)
            free = W[W_F0A, i] == 0.0 and W[W_F0B, i] == 0.0
        else:
            free = eff_f_iso(F, I, i, l, s0) == 0.0 and eff_f_iso(F, I, i, l, s1) == 0.0
        W[W_FREE, i] = 1.0 if free else 0.0
    th, om = L[L_THETA], L[L_OMEGA]
    # The four stages as a loop, so that forces (and the muscle's equations in
    # it) is compiled in once rather than four times: the same arithmetic
    # (stage k + 1 at th + c h omega_k, om + c h alpha_k, c = 1/2, 1/2, 1).
    th_k, om_k = th, om
    # The stages' sines from the step's first (sine_near), libm where a stage
    # is farther than its series reaches.
    sin_th, cos_th = math.sin(th), math.cos(th)
    for k in range(4):
        t = s0 if k == 0 else (mid if k < 3 else s1)
        d = th_k - th
        sin_k = sine_near(sin_th, cos_th, d) if abs(d) <= SINE_SERIES_MAX_RAD else math.sin(th_k)
        a_k = forces(F, I, L, W, nm, th_k, sin_k, om_k, W_L1 + k, t, W_V1 + k)
        L[L_STAGE_OMEGA + k] = om_k
        L[L_STAGE_ALPHA + k] = a_k
        if k < 3:
            c_h = h if k == 2 else 0.5 * h
            th_k, om_k = th + c_h * om_k, om + c_h * a_k
            for i in range(nm):
                W[W_L2 + k, i] = W[W_L1, i] + c_h * W[W_V1 + k, i]
    theta = rk4_update(th, h, L[L_STAGE_OMEGA], L[L_STAGE_OMEGA + 1], L[L_STAGE_OMEGA + 2],
                       L[L_STAGE_OMEGA + 3])
    L[L_THETA] = theta
    L[L_OMEGA] = rk4_update(om, h, L[L_STAGE_ALPHA], L[L_STAGE_ALPHA + 1],
                            L[L_STAGE_ALPHA + 2], L[L_STAGE_ALPHA + 3])
    for i in range(nm):
        fs = hdr(I, i, H_FS)
        dl = dl_mt(L, i, theta)
        l = rk4_update(W[W_L1, i], h, W[W_V1, i], W[W_V2, i], W[W_V3, i], W[W_V4, i])
        fp = hdr(I, i, H_FP)
        f0 = stage_f0(F, I, W, i, l, W_L4, s1)
        if W[W_FREE, i] != 0.0 or f0 == 0.0:
            l = F[fp + P_L_REST] + dl
        elif W[W_QUASI, i] != 0.0:
            s_r = L[muscle_slot(i) + M_SIGN] * L[muscle_slot(i) + M_ARM]
            l = F[fp + P_L_REST] + dl - quasi_force(F, I, i, -s_r * L[L_OMEGA], f0) / F[
                fp + P_K_SE]
        F[fs + S_L] = l
        F[fs + S_DL] = dl


def limb_integrate(F, I, L, W, nm, s0, s1):
    """RK4 of the joint and every CE over [s0, s1], no recruitment change inside,
    the quasi-static CEs out of it, cut as the stiffest other CE needs
    (Limb._integrate)."""
    h = s1 - s0
    if h <= 0.0:
        return
    for i in range(nm):
        begin_interval(F, I, i, s0, s1)
    n = 1
    mid = s0 + 0.5 * h
    for i in range(nm):
        fs = hdr(I, i, H_FS)
        l, dl = F[fs + S_L], F[fs + S_DL]
        if resting(F, I, W, i):
            # Nothing recruited in the step: F0 = 0, rate 0, as the pool would say.
            W[W_F0A, i] = 0.0
            W[W_F0M, i] = 0.0
            W[W_F0B, i] = 0.0
            W[W_QUASI, i] = 0.0
            continue
        if length_free(I, i):
            # peak_rate's three instants are those of a single RK4 step over [s0, s1].
            stage_f0s(F, I, W, i, l, s0, mid, s1)
            rate = max(rate_at(F, I, i, l, dl, W[W_F0A, i]),
                       max(rate_at(F, I, i, l, dl, W[W_F0M, i]),
                           rate_at(F, I, i, l, dl, W[W_F0B, i])))
        else:
            rate = peak_rate(F, I, i, l, dl, s0, s1)
        quasi = rate >= QUASI_STATIC_RATE_PER_S
        W[W_QUASI, i] = 1.0 if quasi else 0.0
        if not quasi:
            n = max(n, substep_count(h, rate))
    for j in range(n):
        a = s0 + h * j / n
        b = s1 if j == n - 1 else s0 + h * (j + 1) / n
        limb_rk4(F, I, L, W, nm, a, b, n == 1)
    for i in range(nm):
        end_interval(F, I, i, s1)


def limb_step(F, I, L, W, TT, TI, nm, us, tau, dt, dl_limit, give):
    """One step with each muscle's command ``us[i]`` and the external torque held
    (Limb.step, inputs already checked).

    :param give: False if the commands ``us`` were given at this instant already
        (:func:`limb_give`, or the step before with the same commands): giving
        a muscle its own command again at the same instant changes nothing

    :param TT: [s] timeline instants, room for every muscle's events
    :param TI: (2, len(TT)) int64 timeline muscle and event indices
    :param dl_limit: [m] largest |dl_MT| at the step's end
    :return: :data:`OK`, :data:`DELAY_FULL`, or :data:`DL_OUT_OF_RANGE` + i
    """
    t0 = L[L_T]
    t1 = t0 + dt
    L[L_TAU] = tau
    n_events = 0
    for i in range(nm):
        fs = hdr(I, i, H_FS)
        F[fs + S_T] = t0
        if give and not give_command(F, I, i, us[i]):
            return DELAY_FULL
        if plan_steady(F, I, W, i, t0, t1):
            settle_ce(F, I, i, t0)   # what applying plan's piece at t0 would be followed by
            continue
        W[W_STEADY, i] = 0.0
        plan(F, I, i, t0, t1)
        evt = hdr(I, i, H_EVT)
        for e in range(I[hdr(I, i, H_JS) + J_NEV]):
            # Insertion into the sorted timeline after every equal instant: stable.
            instant = F[evt + e]
            k = n_events
            while k > 0 and TT[k - 1] > instant:
                TT[k] = TT[k - 1]
                TI[0, k] = TI[0, k - 1]
                TI[1, k] = TI[1, k - 1]
                k -= 1
            TT[k] = instant
            TI[0, k] = i
            TI[1, k] = e
            n_events += 1
    s = t0
    for k in range(n_events):
        instant = TT[k]
        i = TI[0, k]
        limb_integrate(F, I, L, W, nm, s, instant)
        apply(F, I, i, TI[1, k], instant)
        settle_ce(F, I, i, instant)   # released: the CE is free now
        s = max(s, instant)
    limb_integrate(F, I, L, W, nm, s, t1)
    L[L_T] = t1
    for i in range(nm):
        fs = hdr(I, i, H_FS)
        if W[W_STEADY, i] != 0.0:
            F[fs + S_R] = W[W_A_END, i]   # plan's end of the step (A_END) and what follows it
            settle_ce(F, I, i, t1)
        F[fs + S_T] = t1
        settle_now(F, I, i)
    for i in range(nm):
        if not abs(dl_mt(L, i, L[L_THETA])) <= dl_limit:
            return DL_OUT_OF_RANGE + i
    return OK


def limb_give(F, I, nm, us):
    """Each muscle's command ``us[i]`` now where it differs from its last one, as a
    sample of simulate_limb gives it.

    :return: :data:`OK`, or :data:`DELAY_FULL` (the muscles before have their commands)
    """
    for i in range(nm):
        if us[i] != F[hdr(I, i, H_FS) + S_CMD]:
            if not give_command(F, I, i, us[i]):
                return DELAY_FULL
    return OK


def limb_record(F, I, L, nm, row):
    """The limb's outputs now into ``row``: t, theta, omega, then per muscle its
    command, recruitment, dl_MT, l_CE and force (simulate_limb's columns)."""
    row[0] = L[L_T]
    row[1] = L[L_THETA]
    row[2] = L[L_OMEGA]
    for i in range(nm):
        fs, fp = hdr(I, i, H_FS), hdr(I, i, H_FP)
        dl, l = F[fs + S_DL], F[fs + S_L]
        f = series_force(F[fp + P_K_SE], dl, l, F[fp + P_L_REST]) + parallel_force(
            F[fp + P_K_PE], dl)
        base = 3 + 5 * i
        row[base] = F[fs + S_CMD]
        row[base + 1] = F[fs + S_R]
        row[base + 2] = dl
        row[base + 3] = l
        row[base + 4] = f


def limb_hold(F, I, L, W, TT, TI, nm, us, tau, dt, dl_limit, n, target, acc, row):
    """``n`` steps with the commands ``us`` and the torque held, the outputs of the
    last into ``row``; ``acc[0]`` the sum over the steps of (theta - target)^2
    at each step's end (a tracking environment's control period).

    :param target: [rad] the angle the squared errors are taken from
    :return: :data:`OK`, or the first failed step's status (``acc`` and ``row``
        then as after that step)
    """
    sq = 0.0
    status = OK
    for k in range(n):
        status = limb_step(F, I, L, W, TT, TI, nm, us, tau, dt, dl_limit, k == 0)
        if status != OK:
            break
        d = L[L_THETA] - target
        sq += d * d
    acc[0] = sq
    limb_record(F, I, L, nm, row)
    return status


def limb_run(F, I, L, W, TT, TI, nm, u, tau, dt, dl_limit, rows):
    """simulate_limb's loop: the commands of t_0 given, then per step the step and
    the next sample's commands; the sample of t_k in ``rows[k]``.

    :param u: [-] (steps, nm) commands per sample
    :param tau: [N m] (steps,) external torque per sample
    :return: samples written (all on success); on a failed step k,
        -(k STATUS_BASE + status)
    """
    for i in range(nm):
        if not give_command(F, I, i, u[0, i]):
            return -DELAY_FULL
    limb_record(F, I, L, nm, rows[0])
    for k in range(u.shape[0] - 1):
        status = limb_step(F, I, L, W, TT, TI, nm, u[k], tau[k], dt, dl_limit, False)
        if status != OK:
            return -(k * STATUS_BASE + status)
        for i in range(nm):
            if u[k + 1, i] != F[hdr(I, i, H_FS) + S_CMD]:
                if not give_command(F, I, i, u[k + 1, i]):
                    return -(k * STATUS_BASE + DELAY_FULL)
        limb_record(F, I, L, nm, rows[k + 1])
    return u.shape[0]


#: What :func:`limb_entry` does: :func:`limb_run`; :func:`limb_hold` (one step is
#: CompiledLimb.advance); :func:`limb_give`, then :func:`limb_record`; :func:`limb_record`.
MODE_RUN, MODE_HOLD, MODE_GIVE, MODE_RECORD = range(4)


def limb_entry(F, I, L, W, TT, TI, nm, mode, u, tau, dt, dl_limit, n, target, acc, rows):
    """The compiled limb's one entry point: ``mode`` (MODE_*) chooses the work.

    One entry rather than one per kind of call, because numba links the whole
    FES muscle into every compiled function that calls it and optimises it
    again there: each entry point more cost seconds of a cold compile.

    :param u: [-] (samples, nm) commands; MODE_HOLD and MODE_GIVE take row 0
    :param tau: [N m] external torque per sample; MODE_HOLD takes entry 0
    :param rows: outputs (limb_record's columns); all but MODE_RUN write row 0
    :param n: MODE_HOLD's steps; ``target``, ``acc`` as :func:`limb_hold`'s
    :return: as the function the mode runs; MODE_RECORD :data:`OK`
    """
    if mode == MODE_RUN:
        return limb_run(F, I, L, W, TT, TI, nm, u, tau, dt, dl_limit, rows)
    if mode == MODE_HOLD:
        return limb_hold(F, I, L, W, TT, TI, nm, u[0], tau[0], dt, dl_limit, n, target, acc,
                         rows[0])
    status = OK
    if mode == MODE_GIVE:
        status = limb_give(F, I, nm, u[0])
    limb_record(F, I, L, nm, rows[0])
    return status


# -- the limb's arrays ---------------------------------------------------------------------

class LimbArrays:
    """The flat state of a limb: its muscles' :class:`~.fes_kernels.FesBundle`, the
    joint array ``L``, the stage scratch ``W`` and the timeline ``TT``/``TI``.

    :param plant: the joint and its muscles
    :param dt_s: [s] the step the delay lines are sized for
    :param pool: where a run's arrays come from and go back to (:meth:`give_back`),
        or None for arrays of their own
    """

    def __init__(self, plant, dt_s: float, pool: ScratchPool | None = None) -> None:
        self.plant = plant
        self.nm = nm = len(plant.muscles)
        self._pool = pool
        self.bundle = FesBundle([m.params for m in plant.muscles], dt_s, pool)
        self.L = np.zeros(L_MUSCLES + L_PER_MUSCLE * max(nm, 1))
        j = plant.joint
        self.L[[L_INERTIA, L_MASS, L_GRAVITY, L_COM, L_STIFFNESS, L_EQUILIBRIUM,
                L_DAMPING]] = (j.inertia_kg_m2, j.mass_kg, j.gravity_m_per_s2,
                               j.com_distance_m, j.stiffness_n_m_per_rad, j.equilibrium_rad,
                               j.damping_n_m_s_per_rad)
        for i, m in enumerate(plant.muscles):
            slot = muscle_slot(i)
            self.L[slot + M_SIGN] = m.sign
            self.L[slot + M_ARM] = m.moment_arm_m
            self.L[slot + M_REF] = m.reference_angle_rad
        self.W = np.zeros((N_W, max(nm, 1)))
        self._size_timeline()
        self.L[L_THETA] = plant.joint.initial_angle_rad
        self._place_ces()   # the new bundle is at rest already

    def _size_timeline(self) -> None:
        total = sum(int(self.bundle.I[i * fes_kernels.N_HDR + fes_kernels.H_CAPEV])
                    for i in range(self.nm))
        # limb_step writes a step's timeline (entries 0 .. n_events - 1) before
        # it reads it: a handed-back one needs no zeros.
        empty = np.zeros if self._pool is None else self._pool.empty
        self.TT = empty((max(total, 1),))
        self.TI = empty((2, max(total, 1)), dtype=np.int64)

    def give_back(self) -> None:
        """Hand the run's large arrays back to the pool; these arrays are not
        used after this."""
        if self._pool is not None:
            self._pool.give_back(self.bundle.F, self.bundle.I, self.TT, self.TI)

    def reset(self) -> None:
        """Limb.reset: theta_0, at rest, each CE at l_rest + dl_MT(theta_0)."""
        self.L[L_THETA] = self.plant.joint.initial_angle_rad
        self.L[L_OMEGA] = self.L[L_T] = self.L[L_TAU] = 0.0
        for i in range(self.nm):
            self.bundle.reset(i)
        self._place_ces()

    def _place_ces(self) -> None:
        """Each CE at l_rest + dl_MT(theta)."""
        for i, m in enumerate(self.plant.muscles):
            fs = self.bundle.view(i, 'fs')
            fs[S_DL] = dl = dl_mt(self.L, i, self.L[L_THETA])
            fs[S_L] = m.params.l_rest_m + dl

    def stretch_message(self, i: int) -> str:
        """Limb.step's error for muscle ``i`` stretched out of range now."""
        theta = self.L[L_THETA]
        return limb.stretch_message(self.plant.muscles[i].name, dl_mt(self.L, i, theta), theta)

    def ensure_delay(self, dt_s: float) -> None:
        """Room in the delay lines and the timeline for steps of ``dt_s``."""
        cap = self.bundle.cap
        self.bundle.ensure_delay(dt_s)
        if self.bundle.cap != cap:
            self._size_timeline()


#: The arrays of the runs of :func:`simulate_limb_compiled` and :func:`run_limb_batch`
#: (each thread its own): one run's, reused by the next of the same layout.
_POOL = ScratchPool()


# -- compiling ------------------------------------------------------------------------------

#: [-] muscle-steps (steps times muscles) of one run from which ``simulate_limb``
#: loads the compiled limb when it is not loaded yet (``HILL_MUSCLE_ENGINE=auto``,
#: :func:`.engine.use_compiled`). Measured: loading costs 0.82 s with a warm
#: cache, and the compiled limb saves about 135 us a muscle-step on the knee
#: preset (282 against 11.7 us a step, two muscles; both BENCHMARKS.md,
#: bench_limb_compiled.py) and 65 us on the ankle preset's one muscle (66.6
#: against 2.5 us a step, 6 s at a 0.5 command from 0.5 to 3.5 s, by hand):
#: loading pays from about 6,000-13,000 muscle-steps.
RUN_MIN_MUSCLE_STEPS = 10_000

#: The joint's equations (model/limb.py), compiled over this module's scope.
_EQUATIONS = ('mtu_length_change', 'joint_acceleration_sin', 'sine_near')
_KERNELS = ('muscle_slot', 'dl_mt', 'length_free', 'plan_steady', 'resting', 'settle_ce',
            'stage_f0', 'stage_f0s', 'forces', 'limb_rk4', 'limb_integrate', 'limb_step',
            'limb_give', 'limb_record', 'limb_hold', 'limb_run', 'limb_entry')
#: Compiled into their one caller by numba's own inlining: :func:`forces` into
#: the loop over the stages of :func:`limb_rk4`, and that into
#: :func:`limb_integrate`. A call between compiled functions passes each array
#: as its fields, seven words apiece, and these are the step's innermost
#: calls. The knee extension compiled: 3.58-3.61 -> 3.17-3.20 ms a run (by
#: hand, alternating, median of 61 each); a cold compile of the limb 17.3 ->
#: 17.6 s. Inlining limb_integrate into limb_step as well gained 1 % more for
#: 9 s more of compiling.
#:
#: A multi/initial muscle's F0 is compiled into the step too
#: (:func:`~.fes_kernels.eff_f_iso_inline`, in :func:`stage_f0s` and
#: :func:`settle_ce`), and the stages and F0's three instants became loops so
#: that each is compiled in once. By hand (the knee extension, the two
#: alternating in separate processes, 20 runs a sample, median of 31 pair
#: ratios): 3.18 -> 2.79 ms a run (0.877x); a cold compile of the limb 26.0 ->
#: 26.7 s. With the four stages written out instead, the same gain cost 15 s
#: more of compiling, and inlining the whole of eff_f_iso, minutes.
_INTO_STEP = ('forces', 'limb_rk4')
#: Compiled into :func:`limb_entry` by numba's own inlining (each has one call
#: site there), so that they are no compiled functions of their own each
#: holding the muscle's code again.
_INTO_ENTRY = ('limb_give', 'limb_record', 'limb_hold', 'limb_run')
#: The modules whose code the kernels inline: their digest names the cache entries.
_DIGEST_OF = (equations, stimulus, memory, units, unit_pool, fes_muscle, fes_kernels, limb)
_compiled = None


def loaded() -> bool:
    """True if the compiled limb is built in this process (:func:`compiled`)."""
    return _compiled is not None


def compiled() -> types.SimpleNamespace:
    """The numba-compiled limb kernels, calling :func:`.fes_kernels.compiled`'s muscle.

    :raises ImportError: if numba cannot be imported
    """
    global _compiled
    if _compiled is not None:
        return _compiled
    from . import engine
    scope = fes_kernels.scope_calling(
        globals(), ('apply', 'begin_interval', 'eff_f_iso', 'eff_f_iso_inline', 'end_interval',
                    'give_command',
                    'set_piece', 'tau_for', 'recruited_units', 'activation_at',
                    'hdr', 'plan', 'settle_now', 'peak_rate', 'quasi_force', 'rate_at',
                    'substep_count',
                    'velocity', 'series_force', 'parallel_force', 'rk4_update'))
    leaf = {'error_model': 'numpy', 'inline': 'always'}
    body = {'error_model': 'numpy'}
    options = {name: body for name in _KERNELS}
    options.update({name: leaf for name in _EQUATIONS + ('muscle_slot', 'dl_mt', 'length_free',
                                                         'plan_steady', 'resting', 'settle_ce',
                                                         'stage_f0', 'stage_f0s')
                    + _INTO_STEP + _INTO_ENTRY})

    # The one entry point, with its signature: compiled (or loaded) here, never
    # at a first step.
    def entry_signature(numba):
        f8, i8 = numba.float64, numba.int64
        c1, c2 = f8[::1], f8[:, ::1]
        return i8(c1, i8[::1], c1, c2, c1, i8[:, ::1], i8, i8, c2, c1, f8, f8, i8, f8, c1, c2)

    # limb_step is called with a constant ``give`` (limb_run) and a computed one
    # (limb_hold): without a signature numba would compile it for each.
    def step_signature(numba):
        f8, i8 = numba.float64, numba.int64
        c1, c2 = f8[::1], f8[:, ::1]
        return i8(c1, i8[::1], c1, c2, c1, i8[:, ::1], i8, c1, f8, f8, f8, numba.boolean)

    _compiled = engine.compile_functions(
        scope, _EQUATIONS + _KERNELS, digest_of=_DIGEST_OF + (sys.modules[__name__],),
        signatures={'limb_entry': entry_signature, 'limb_step': step_signature},
        options=options)
    return _compiled


def _run(arrays: LimbArrays, u: np.ndarray, tau: np.ndarray, dt_s: float, kernels):
    """limb_run on ``arrays``: (rows, None), or (rows, (k, message)) when step k
    stretched a muscle out of range (the message is Limb.step's)."""
    arrays.ensure_delay(dt_s)
    nm = arrays.nm
    u = np.ascontiguousarray(u, dtype=float).reshape(len(tau), nm)
    tau = np.ascontiguousarray(tau, dtype=float)
    # Every row is written (limb_record's every column) unless the run fails,
    # and the rows of a failed run are not returned.
    rows = np.empty((len(tau), 3 + 5 * nm))
    b = arrays.bundle
    entry = (kernels or sys.modules[__name__]).limb_entry
    done = entry(b.F, b.I, arrays.L, arrays.W, arrays.TT, arrays.TI, nm, MODE_RUN, u, tau,
                 float(dt_s), DL_MT_LIMIT_M, 0, 0.0, np.zeros(1), rows)
    if done >= 0:
        return rows, None
    k, status = divmod(-done, STATUS_BASE)
    if status == DELAY_FULL:   # delay_capacity bounds the commands pending
        raise RuntimeError(f'a muscle\'s delay line overflowed at step {k}')
    return rows, (k, arrays.stretch_message(status - DL_OUT_OF_RANGE))


def run_limb(arrays: LimbArrays, u: np.ndarray, tau: np.ndarray, dt_s: float,
             kernels=None) -> np.ndarray:
    """simulate_limb's loop on ``arrays`` (from its current state): the rows of
    :func:`~hill_muscle_ros.model.limb.limb_columns`, the time column from the state.

    :param u: [-] (samples, muscles) commands, checked in [0, 1]
    :param tau: [N m] (samples,) external torque, checked
    :param kernels: :func:`compiled`, or None for the plain functions
    :raises ValueError: as Limb.step, when a muscle is stretched out of range
    """
    rows, failure = _run(arrays, u, tau, dt_s, kernels)
    if failure is not None:
        raise ValueError(failure[1])
    return rows


def run_limb_batch(plants, u: np.ndarray, tau: np.ndarray, dt_s: float,
                   sample_indices, kernels=None) -> tuple[np.ndarray, np.ndarray]:
    """:func:`~hill_muscle_ros.model.limb_batch.simulate_limb_batch`'s loop, compiled:
    each plant run alone (a limb's result does not depend on the others').

    :param u: [-] (samples, K, muscles) checked commands, the last sample the last wanted
    :param tau: [N m] (samples,) checked external torque
    :param sample_indices: step indices to sample, ascending
    :return: ([rad] theta (K, S), [N] force (K, M, S))
    :raises LimbOutOfRange: for the first limb out of range, at the earliest step
        (the batch steps every limb before the next step)
    """
    from .limb_batch import LimbOutOfRange
    kernels = compiled() if kernels is None else kernels
    idx = np.asarray(sample_indices, dtype=np.int64)
    nm = len(plants[0].muscles) if plants else 0
    theta = np.empty((len(plants), len(idx)))
    force = np.empty((len(plants), nm, len(idx)))
    failures = []
    for k, plant in enumerate(plants):
        arrays = LimbArrays(plant, dt_s, _POOL)
        try:
            rows, failure = _run(arrays, u[:, k, :], tau, dt_s, kernels)
        finally:
            arrays.give_back()
        if failure is not None:
            failures.append((failure[0], k, failure[1]))
            continue
        theta[k] = rows[idx, 1]
        for m in range(nm):
            force[k, m] = rows[idx, 3 + 5 * m + 4]
    if failures:
        _, k, message = min(failures)
        raise LimbOutOfRange(k, message)
    return theta, force


def simulate_limb_compiled(plant, protocol, rate_hz: float = 1000.0, kernels=None):
    """:func:`~hill_muscle_ros.model.limb.simulate_limb` on the compiled engine.

    :param kernels: :func:`compiled` (the default), or this module for the plain functions
    :return: the :class:`~hill_muscle_ros.model.limb.LimbResult`, or None if a
        command or the torque is outside what Limb.step accepts: the Python loop
        then raises the error that names the value and the step
    """
    from .limb import TORQUE_LIMIT_N_M, LimbResult, limb_columns
    from .simulate import sample_times
    t = sample_times(protocol.duration_s, rate_hz)
    u = np.asarray(protocol.commands(t, plant), dtype=float)
    tau = np.asarray(protocol.external_torque_n_m(t), dtype=float)
    if not (np.all((u >= 0.0) & (u <= 1.0)) and np.all(np.abs(tau) <= TORQUE_LIMIT_N_M)):
        return None
    dt = 1.0 / rate_hz
    # Substeps of at most 1 ms with the samples' inputs held (model/substeps.py),
    # as Limb.step takes them; the samples are every n-th row.
    n = substeps_for(dt)
    h = dt / n
    if n > 1:
        u, tau = repeat_rows(u, n), repeat_rows(tau, n)
    arrays = LimbArrays(plant, h, _POOL)
    try:
        rows = run_limb(arrays, u, tau, h, compiled() if kernels is None else kernels)[::n]
    finally:
        arrays.give_back()
    rows[:, 0] = t
    return LimbResult(t, dict(zip(limb_columns(plant), rows.T)))


# -- step by step ---------------------------------------------------------------------------

#: [s] The step the delay lines of a :class:`CompiledLimb` are first sized for
#: (the 1 kHz of the presets); a step of another length resizes them, keeping the state.
FIRST_DT_S = 1e-3


def step_engine(requested: str | None = None) -> str:
    """The engine of a limb stepped one call at a time: :data:`.engine.COMPILED`
    or :data:`.engine.PYTHON`.

    A step-by-step limb cannot know how long it will run, so ``None`` follows
    :func:`.engine.use_compiled` with no work to repay the loading: compiled once
    the compiled limb is loaded in this process (or with
    ``HILL_MUSCLE_ENGINE=compiled``), Python otherwise.

    :param requested: ``'compiled'``, ``'python'`` or ``None``
    :raises ValueError: on any other value
    """
    from . import engine
    if requested is None:
        return engine.COMPILED if engine.use_compiled(0, 1, loaded()) else engine.PYTHON
    if requested not in (engine.COMPILED, engine.PYTHON):
        raise ValueError(f'`engine` must be {engine.COMPILED!r}, {engine.PYTHON!r} or None, '
                         f'got {requested!r}')
    return requested


class CompiledLimb:
    """:class:`~hill_muscle_ros.model.limb.Limb`'s step-by-step interface on the
    compiled limb (:func:`compiled`): the same outputs to 1e-9 rad and 1e-9 N, the
    same errors, the same state after a bad input (unchanged) or a muscle
    stretched out of range (the step taken, as Limb leaves it).

    Building the first one in a process loads the compiled limb: about 0.8 s
    from numba's disk cache, about 30 s when it compiles (a clean clone, or
    after an edit of the model's code).

    :param plant: the joint and its muscles
    :param kernels: :func:`compiled` (the default), or this module for the plain functions
    :param row: where :meth:`advance` writes the outputs (``limb_record``'s
        columns: t, theta, omega, then per muscle command, recruitment,
        dl_MT, l_CE, force), e.g. a row of a batch's array; default its own
    """

    def __init__(self, plant, kernels=None, row: np.ndarray | None = None) -> None:
        self.plant = plant
        self.joint = plant.joint
        self._kernels = compiled() if kernels is None else kernels
        self.arrays = LimbArrays(plant, FIRST_DT_S)
        self._dt = FIRST_DT_S
        nm = self.arrays.nm
        self.row = np.zeros(3 + 5 * nm) if row is None else row
        self._us = np.zeros(nm)
        self._acc = np.zeros(1)
        # limb_entry's 2-D views of the row and the commands, and its torque array.
        self._rows = self.row[np.newaxis, :]
        self._u = self._us[np.newaxis, :]
        self._tau = np.zeros(1)
        self._s_r = [m.sign * m.moment_arm_m for m in plant.muscles]
        self.reset()

    def reset(self) -> None:
        """theta = theta_0, omega = 0, each CE at l_rest + dl_MT(theta_0), nothing recruited."""
        a = self.arrays
        a.reset()
        self._entry(MODE_RECORD, 0.0, 0, 0.0)

    @property
    def t_s(self) -> float:
        """[s] time."""
        return float(self.arrays.L[L_T])

    @property
    def theta_rad(self) -> float:
        """[rad] joint angle (theta)."""
        return float(self.arrays.L[L_THETA])

    @property
    def omega_rad_per_s(self) -> float:
        """[rad/s] joint angular velocity (omega)."""
        return float(self.arrays.L[L_OMEGA])

    @property
    def external_torque_n_m(self) -> float:
        """[N m] the external torque of the last step (tau_ext)."""
        return float(self.arrays.L[L_TAU])

    def _entry(self, mode: int, dt_s: float, n_steps: int, target_rad: float) -> int:
        """limb_entry on this limb's arrays, commands :attr:`_us`, torque :attr:`_tau`."""
        a = self.arrays
        b = a.bundle
        return self._kernels.limb_entry(b.F, b.I, a.L, a.W, a.TT, a.TI, a.nm, mode, self._u,
                                        self._tau, dt_s, DL_MT_LIMIT_M, n_steps, target_rad,
                                        self._acc, self._rows)

    def _failed(self, status: int) -> None:
        if status == DELAY_FULL:   # delay_capacity bounds the commands pending
            raise RuntimeError('a muscle\'s delay line overflowed')
        raise ValueError(self.arrays.stretch_message(status - DL_OUT_OF_RANGE))

    def give_commands(self, us: Sequence[float]) -> None:
        """Give each muscle its checked command now where it differs from its last
        one (a sample of simulate_limb; LimbBatch.give_commands)."""
        self._us[:] = us
        status = self._entry(MODE_GIVE, 0.0, 0, 0.0)
        if status != OK:
            self._failed(status)

    def advance(self, us: Sequence[float], tau: float, dt_s: float) -> None:
        """:meth:`step` of checked inputs, the outputs into :attr:`row` only.

        :raises ValueError: as Limb.step, on a muscle stretched out of range
        """
        # n = ceil(dt / 1 ms) substeps of dt / n, inputs held (model/substeps.py),
        # as Limb.step; one at 1 kHz.
        n = substeps_for(dt_s)
        h = dt_s / n
        a = self.arrays
        if h != self._dt:
            a.ensure_delay(h)
            self._dt = h
        self._us[:] = us
        self._tau[0] = tau
        status = self._entry(MODE_HOLD, h, n, 0.0)   # n steps: limb_step, limb_record
        if status != OK:
            self._failed(status)

    def hold(self, us: Sequence[float], tau: float, dt_s: float, n_steps: int,
             target_rad: float) -> float:
        """``n_steps`` calls of :meth:`advance` with checked inputs held, in one
        compiled call; the outputs of the last in :attr:`row`.

        :param target_rad: [rad] angle theta* of the squared errors
        :return: [rad^2] sum over the steps of (theta - theta*)^2 at each step's end
        :raises ValueError: as Limb.step, on a muscle stretched out of range
            (the limb is left after that step)
        """
        a = self.arrays
        if dt_s != self._dt:
            a.ensure_delay(dt_s)
            self._dt = dt_s
        self._us[:] = us
        self._tau[0] = tau
        status = self._entry(MODE_HOLD, dt_s, n_steps, target_rad)
        if status != OK:
            self._failed(status)
        return float(self._acc[0])

    def step(self, commands: Sequence[float], external_torque_n_m: float, dt_s: float):
        """Advance one step: each muscle's command and the external torque held
        over it (:meth:`Limb.step <hill_muscle_ros.model.limb.Limb.step>`).

        :param commands: [-] recruitment command u of each muscle, in [0, 1]
        :param external_torque_n_m: [N m] external torque (tau_ext)
        :param dt_s: [s] step length, > 0
        :return: the :class:`~hill_muscle_ros.model.limb.LimbOutputs` at the step's end
        :raises ValueError: naming the input on a bad value (the state is
            unchanged), or the muscle stretched out of range
        """
        us, tau = limb.check_step_inputs(self.plant, commands, external_torque_n_m, dt_s)
        self.advance(us, tau, float(dt_s))
        return self.outputs()

    def outputs(self):
        """The :class:`~hill_muscle_ros.model.limb.LimbOutputs` at the current instant."""
        row = self.row.tolist()
        cols = [row[3 + j::5] for j in range(5)]
        torque = 0.0
        for s_r, f in zip(self._s_r, cols[4]):
            torque += s_r * f
        return limb.LimbOutputs(row[0], row[1], row[2], torque, *(tuple(c) for c in cols))


def make_limb(plant, engine: str | None = None):
    """A :class:`~hill_muscle_ros.model.limb.Limb`, or a :class:`CompiledLimb` when
    :func:`step_engine` of ``engine`` is compiled (the first loads the compiled
    limb: about 0.8 s, about 30 s if it compiles)."""
    from . import engine as engines
    if step_engine(engine) == engines.COMPILED:
        return CompiledLimb(plant)
    return limb.Limb(plant)
