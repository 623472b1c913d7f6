"""The limb's dynamics over flat arrays: plain functions that Python runs and numba compiles.

These functions are the limb: :class:`~.limb.Limb` steps them one call at a
time, :func:`~.simulate.simulate_limb` and the batches run them over whole
protocols, and :func:`.engine.kernels` chooses whether the plain functions
run as Python or their numba build (:func:`compiled`) does; there is no
other implementation.

One step (:func:`limb_step`): each muscle plans its recruitment changes of
the step (its delayed command switches and the instants at which units join
or leave), the events of all muscles are taken in time order (a stable sort:
each muscle keeps its own order), and the joint and every CE length are
integrated together with RK4 up to each event (:func:`limb_integrate`), in as
many substeps as the stiffest CE needs. A muscle with nothing recruited has a
free CE that follows its MTU (f_SE = 0). A CE that relaxes faster than
:data:`~hill_muscle_ros.model.equations.QUASI_STATIC_RATE_PER_S` (few units
left with ``fv_scaling: relative``) is quasi-static over the interval: it
moves with its MTU, its SE carries the force Eq. 3 gives that velocity
(:func:`~hill_muscle_ros.model.muscle.kernels.quasi_force`), and it leaves the
RK4 state (doc/model.md section 7.6). The muscles are those of
:mod:`~hill_muscle_ros.model.muscle.kernels` (every variant and FES feature);
the equations, the joint's included, are :mod:`~hill_muscle_ros.model.equations`.

State: the muscles' :class:`~hill_muscle_ros.model.muscle.state.FesBundle`
(``F``, ``I``), the joint array ``L`` (``L_*`` entries), the stage scratch
``W`` (``W_*`` rows) and a step's timeline ``TT``/``TI``, held together by
:class:`~.arrays.LimbArrays`.
"""
from __future__ import annotations

import math  # the joint's equations, compiled over this scope, call it
import sys
import types

from .. import equations, memory, stimulus, units
from ..muscle import ding as muscle_ding
from ..muscle import kernels as muscle_kernels
from ..muscle import pool as muscle_pool
from ..muscle import state as muscle_state
from ..equations import (QUASI_STATIC_RATE_PER_S, SINE_SERIES_MAX_RAD, activation_at,
                         joint_acceleration_sin, mtu_length_change, parallel_force, rk4_update,
                         series_force, sine_near, substep_count)
from ..muscle.state import (D_A, DELAY_FULL, H_DQT, H_EVT, H_FP, H_FS, H_IP, H_JS, I_DING,
                            I_INITIAL, I_MULTI, I_N, I_NCH, J_DCOUNT, J_DHEAD, J_NEV, J_NREC, OK,
                            P_K_PE, P_K_SE, P_L_REST, S_CMD, S_DL, S_L, S_R, S_T, S_UD,
                            TIME_TOL_S, hdr)
from ..muscle.ding import (ding_clocks, ding_commit, ding_f_iso, ding_pulse, ding_settle,
                           ding_slot, ding_stages)
from ..muscle.kernels import (apply, begin_interval, eff_f_iso, eff_f_iso_inline, end_interval,
                              give_command, peak_rate, plan, quasi_force, rate_at, set_piece,
                              settle_now, tau_for, velocity)
from ..memory import recruited_units

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
#: Status of a limb step beyond the muscle's OK and DELAY_FULL: muscle i is
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


def pulsed(I, i):
    """True if muscle ``i`` is driven by pulses (``activation_model: ding2003``):
    no command, no plan; its channels' pulses are events of the step and its
    activations are integrated by the joint's RK4 (:func:`limb_rk4`)."""
    return I[hdr(I, i, H_IP) + I_DING] != 0


def length_free(I, i):
    """True if muscle ``i``'s F0 does not depend on l_CE (``length: initial``):
    a step then takes it once per stage instant (W_F0A, W_F0M, W_F0B). Never
    for a pulsed muscle, whose F0 follows its channels' activations."""
    ip = hdr(I, i, H_IP)
    return I[ip + I_INITIAL] != 0 and I[ip + I_DING] == 0


def plan_steady(F, I, W, i, t0, t1):
    """Plan the multi muscle ``i``'s step [t0, t1] without its event table if
    no unit joins or leaves in it; return whether it did.

    Steady: no delayed command switches before ``t1``, and the activation (a
    monotone piece) rounds to the units recruited now at ``t1`` too (the test
    :func:`~hill_muscle_ros.model.muscle.kernels.plan_events` makes). :func:`~hill_muscle_ros.model.muscle.kernels.plan`
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
    if pulsed(I, i):
        f0 = ding_f_iso(F, I, i, F[fs + S_L], t, -1)
    else:
        f0 = eff_f_iso_inline(F, I, i, F[fs + S_L], t)
    if f0 == 0.0:
        F[fs + S_L] = F[hdr(I, i, H_FP) + P_L_REST] + F[fs + S_DL]


def stage_f0(F, I, W, i, l, stage, t):
    """[N] F0 of muscle ``i`` at RK4 stage ``stage`` (a row W_L1..W_L4 of ``W``),
    CE length ``l``, instant ``t``: limb_rk4's where it does not depend on l_CE;
    a pulsed muscle's with its channels' activations at that stage
    (:func:`~hill_muscle_ros.model.muscle.ding.ding_stages`, rows W_L1..W_L4
    being its stages 0..3)."""
    if length_free(I, i):
        return W[W_F0A + (stage + 1) // 2, i]   # stages 1, 2, 3, 4: start, mid, mid, end
    if pulsed(I, i):
        return ding_f_iso(F, I, i, l, t, stage - W_L1)
    return eff_f_iso(F, I, i, l, t)


def forces(F, I, L, W, nm, theta, sin_theta, omega, stage, t, v_row):
    """[rad/s^2] the joint's angular acceleration at one RK4 stage, and each CE's
    velocity into row ``v_row`` of ``W``.

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
    """One RK4 step of the joint and every CE over [s0, s1]; a quasi-static CE is put
    where its SE carries its force at the end, a free one on its MTU.

    :param have_f0: True if ``W`` holds the F0s of [s0, s1] of the length-free
        muscles already (limb_integrate's, for an interval of one step)
    """
    h = s1 - s0
    mid = s0 + 0.5 * h
    for i in range(nm):
        fs = hdr(I, i, H_FS)
        l = F[fs + S_L]
        W[W_L1, i] = l
        if pulsed(I, i):
            # The channels' a at the four stages of this step (and its end),
            # their fitness clocks over it: ding_rk4's coupling, in the joint's RK4.
            ding_stages(F, I, i, h)
            ding_clocks(F, I, i, s0)
            free = (ding_f_iso(F, I, i, l, s0, 0) == 0.0
                    and ding_f_iso(F, I, i, l, s1, 3) == 0.0)
        elif length_free(I, i):
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
        if pulsed(I, i):
            ding_commit(F, I, i, h)
            f0 = ding_f_iso(F, I, i, l, s1, -1)   # a at the step's end
        else:
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
    (:func:`~hill_muscle_ros.model.equations.substep_count`)."""
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
        if pulsed(I, i):
            # ding_integrate's bound: the activations now and a = 1 (a < 1 always).
            rate = max(rate_at(F, I, i, l, dl, ding_f_iso(F, I, i, l, s0, -1)),
                       rate_at(F, I, i, l, dl, ding_f_iso(F, I, i, l, s0, 4)))
        elif length_free(I, i):
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


def pulses_due(PT, j, t1):
    """The index past the pulses from ``j`` on that act before ``t1`` (within
    TIME_TOL_S of it: the next step's), as :func:`~hill_muscle_ros.model.muscle.kernels.ding_run`
    takes a step's pulses."""
    while j < PT.shape[0] and PT[j] < t1 - TIME_TOL_S:
        j += 1
    return j


def limb_step(F, I, L, W, TT, TI, nm, us, tau, dt, dl_limit, give, PT, PI, PU, j0, j1):
    """One step with each muscle's command ``us[i]`` and the external torque held
    (:meth:`.limb.Limb.step`'s work, inputs already checked), and the pulses
    ``j0 .. j1 - 1`` of the pulsed muscles, each at its own instant.

    The step is cut at every event of a command-driven muscle and at every
    pulse of a pulsed one, in time order (at an equal instant the events
    first); between them the joint, every CE and every channel's activation
    are integrated together (:func:`limb_integrate`).

    :param us: [-] each muscle's recruitment command u, in [0, 1]
    :param tau: [N m] the external torque tau_ext
    :param dt: [s] the step's length
    :param give: False if the commands ``us`` were given at this instant already
        (:func:`limb_give`, or the step before with the same commands): giving
        a muscle its own command again at the same instant changes nothing
    :param TT: [s] timeline instants, room for every muscle's events
    :param TI: (2, len(TT)) int64 timeline muscle and event indices
    :param dl_limit: [m] largest |dl_MT| at the step's end
    :param PT: [s] pulse instants (when each acts), not decreasing
    :param PI: (2, len(PT)) int64 each pulse's muscle and 0-based channel
    :param PU: [-] the fraction u of its channel's territory each pulse recruits
    :param j0: the step's first pulse; ``j1`` one past its last (:func:`pulses_due`)
    :return: :data:`OK`, :data:`DELAY_FULL`, or :data:`DL_OUT_OF_RANGE` + i
    """
    t0 = L[L_T]
    t1 = t0 + dt
    L[L_TAU] = tau
    n_events = 0
    for i in range(nm):
        fs = hdr(I, i, H_FS)
        F[fs + S_T] = t0
        if pulsed(I, i):
            W[W_STEADY, i] = 0.0
            continue
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
    k = 0
    p = j0
    while k < n_events or p < j1:
        if p < j1 and (k == n_events or PT[p] < TT[k]):
            # A pulse, at its own instant (ding_advance's clamp to the step).
            instant = min(max(PT[p], s), t1)
            i = PI[0, p]
            limb_integrate(F, I, L, W, nm, s, instant)
            ding_pulse(F, I, i, PI[1, p], PU[p], instant)
            p += 1
        else:
            instant = TT[k]
            i = TI[0, k]
            limb_integrate(F, I, L, W, nm, s, instant)
            apply(F, I, i, TI[1, k], instant)
            k += 1
        settle_ce(F, I, i, instant)   # released: the CE is free now
        s = max(s, instant)
    limb_integrate(F, I, L, W, nm, s, t1)
    L[L_T] = t1
    for i in range(nm):
        fs = hdr(I, i, H_FS)
        if pulsed(I, i):
            F[fs + S_T] = t1
            ding_settle(F, I, i, t1)   # release after a quiet second, fatigue clocks
            continue
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
        if not pulsed(I, i) and us[i] != F[hdr(I, i, H_FS) + S_CMD]:
            if not give_command(F, I, i, us[i]):
                return DELAY_FULL
    return OK


def limb_record(F, I, L, nm, row):
    """The limb's outputs now into ``row``: t, theta, omega, then per muscle its
    command, recruitment, dl_MT, l_CE and force, then each pulsed muscle's
    channels' activations a_c (simulate_limb's columns)."""
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
    base = 3 + 5 * nm
    for i in range(nm):
        if pulsed(I, i):
            for c in range(I[hdr(I, i, H_IP) + I_NCH]):
                row[base] = F[hdr(I, ding_slot(I, i, c), H_FS) + D_A]
                base += 1


def limb_hold(F, I, L, W, TT, TI, nm, us, tau, dt, dl_limit, n, target, acc, row, PT, PI, PU):
    """``n`` steps with the commands ``us`` and the torque held, the pulses
    (``PT``, ``PI``, ``PU``, as :func:`limb_step`'s) at their instants, the
    outputs of the last into ``row``; ``acc[0]`` the sum over the steps of
    (theta - target)^2 at each step's end (a tracking environment's control period).

    :param target: [rad] the angle the squared errors are taken from
    :return: :data:`OK`, or the first failed step's status (``acc`` and ``row``
        then as after that step)
    """
    sq = 0.0
    status = OK
    j = 0
    for k in range(n):
        j1 = pulses_due(PT, j, L[L_T] + dt)
        status = limb_step(F, I, L, W, TT, TI, nm, us, tau, dt, dl_limit, k == 0, PT, PI, PU,
                           j, j1)
        j = j1
        if status != OK:
            break
        d = L[L_THETA] - target
        sq += d * d
    acc[0] = sq
    limb_record(F, I, L, nm, row)
    return status


def limb_run(F, I, L, W, TT, TI, nm, u, tau, dt, dl_limit, rows, PT, PI, PU):
    """simulate_limb's loop: the commands of t_0 given, then per step the step and
    the next sample's commands; the sample of t_k in ``rows[k]``. The pulses
    (``PT``, ``PI``, ``PU``, as :func:`limb_step`'s) act at their instants.

    :param u: [-] (steps, nm) commands per sample
    :param tau: [N m] (steps,) external torque per sample
    :return: samples written (all on success); on a failed step k,
        -(k STATUS_BASE + status)
    """
    for i in range(nm):
        if not pulsed(I, i) and not give_command(F, I, i, u[0, i]):
            return -DELAY_FULL
    limb_record(F, I, L, nm, rows[0])
    j = 0
    for k in range(u.shape[0] - 1):
        j1 = pulses_due(PT, j, L[L_T] + dt)
        status = limb_step(F, I, L, W, TT, TI, nm, u[k], tau[k], dt, dl_limit, False, PT, PI,
                           PU, j, j1)
        j = j1
        if status != OK:
            return -(k * STATUS_BASE + status)
        for i in range(nm):
            if not pulsed(I, i) and u[k + 1, i] != F[hdr(I, i, H_FS) + S_CMD]:
                if not give_command(F, I, i, u[k + 1, i]):
                    return -(k * STATUS_BASE + DELAY_FULL)
        limb_record(F, I, L, nm, rows[k + 1])
    return u.shape[0]


#: What :func:`limb_entry` does: :func:`limb_run`; :func:`limb_hold` (one step is
#: Limb.advance); :func:`limb_give`, then :func:`limb_record`; :func:`limb_record`.
MODE_RUN, MODE_HOLD, MODE_GIVE, MODE_RECORD = range(4)


def limb_entry(F, I, L, W, TT, TI, nm, mode, u, tau, dt, dl_limit, n, target, acc, rows, PT,
               PI, PU):
    """The compiled limb's one entry point: ``mode`` (MODE_*) chooses the work.

    One entry rather than one per kind of call, because numba links the whole
    FES muscle into every compiled function that calls it and optimises it
    again there: each entry point more cost seconds of a cold compile.

    :param u: [-] (samples, nm) commands; MODE_HOLD and MODE_GIVE take row 0
    :param tau: [N m] external torque per sample; MODE_HOLD takes entry 0
    :param rows: outputs (limb_record's columns); all but MODE_RUN write row 0
    :param n: MODE_HOLD's steps; ``target``, ``acc`` as :func:`limb_hold`'s
    :param PT: pulses of the pulsed muscles (MODE_RUN and MODE_HOLD), with ``PI``
        and ``PU`` as :func:`limb_step`'s; all of them act within the run
    :return: as the function the mode runs; MODE_RECORD :data:`OK`
    """
    if mode == MODE_RUN:
        return limb_run(F, I, L, W, TT, TI, nm, u, tau, dt, dl_limit, rows, PT, PI, PU)
    if mode == MODE_HOLD:
        return limb_hold(F, I, L, W, TT, TI, nm, u[0], tau[0], dt, dl_limit, n, target, acc,
                         rows[0], PT, PI, PU)
    status = OK
    if mode == MODE_GIVE:
        status = limb_give(F, I, nm, u[0])
    limb_record(F, I, L, nm, rows[0])
    return status


# -- compiling ------------------------------------------------------------------------------

#: The joint's equations (:mod:`~hill_muscle_ros.model.equations`), compiled over
#: this module's scope.
_EQUATIONS = ('mtu_length_change', 'joint_acceleration_sin', 'sine_near')
_KERNELS = ('muscle_slot', 'dl_mt', 'pulsed', 'length_free', 'pulses_due', 'plan_steady',
            'resting', 'settle_ce',
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
#: (:func:`~hill_muscle_ros.model.muscle.kernels.eff_f_iso_inline`, in :func:`stage_f0s` and
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
_DIGEST_OF = (equations, stimulus, memory, units, muscle_state, muscle_pool, muscle_ding,
              muscle_kernels)
_compiled = None


def loaded() -> bool:
    """True if the compiled limb is built in this process (:func:`compiled`)."""
    return _compiled is not None


def compiled() -> types.SimpleNamespace:
    """The numba-compiled limb kernels, calling :func:`hill_muscle_ros.model.muscle.kernels.compiled`'s muscle.

    :raises ImportError: if numba cannot be imported
    """
    global _compiled
    if _compiled is not None:
        return _compiled
    from .. import engine
    scope = muscle_kernels.scope_calling(
        globals(), ('apply', 'begin_interval', 'eff_f_iso', 'eff_f_iso_inline', 'end_interval',
                    'give_command',
                    'set_piece', 'tau_for', 'recruited_units', 'activation_at',
                    'hdr', 'plan', 'settle_now', 'peak_rate', 'quasi_force', 'rate_at',
                    'substep_count',
                    'velocity', 'series_force', 'parallel_force', 'rk4_update',
                    'ding_clocks', 'ding_commit', 'ding_f_iso', 'ding_pulse', 'ding_settle',
                    'ding_slot', 'ding_stages'))
    leaf = {'error_model': 'numpy', 'inline': 'always'}
    body = {'error_model': 'numpy'}
    options = {name: body for name in _KERNELS}
    options.update({name: leaf for name in _EQUATIONS + ('muscle_slot', 'dl_mt', 'pulsed',
                                                         'length_free', 'pulses_due',
                                                         'plan_steady', 'resting', 'settle_ce',
                                                         'stage_f0', 'stage_f0s')
                    + _INTO_STEP + _INTO_ENTRY})

    # The one entry point, with its signature: compiled (or loaded) here, never
    # at a first step.
    def entry_signature(numba):
        f8, i8 = numba.float64, numba.int64
        c1, c2 = f8[::1], f8[:, ::1]
        return i8(c1, i8[::1], c1, c2, c1, i8[:, ::1], i8, i8, c2, c1, f8, f8, i8, f8, c1, c2,
                  c1, i8[:, ::1], c1)

    # limb_step is called with a constant ``give`` (limb_run) and a computed one
    # (limb_hold): without a signature numba would compile it for each.
    def step_signature(numba):
        f8, i8 = numba.float64, numba.int64
        c1, c2 = f8[::1], f8[:, ::1]
        return i8(c1, i8[::1], c1, c2, c1, i8[:, ::1], i8, c1, f8, f8, f8, numba.boolean, c1,
                  i8[:, ::1], c1, i8, i8)

    _compiled = engine.compile_functions(
        scope, _EQUATIONS + _KERNELS, digest_of=_DIGEST_OF + (sys.modules[__name__],),
        signatures={'limb_entry': entry_signature, 'limb_step': step_signature},
        options=options)
    return _compiled
