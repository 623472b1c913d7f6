"""The muscle over flat arrays: the one implementation, for numba and plain Python.

Every muscle of the package runs these functions: :class:`~.muscle.Muscle`
(the CLI, the simulator node, the gym), :class:`~.batch.MuscleBatch` through
:mod:`.fes_batch_kernels`, and each muscle of a limb through the limb's
kernels. They are compiled by numba (:func:`compiled`) or run unchanged as
plain Python (``HILL_MUSCLE_ENGINE=python``: slowly, for debugging), chosen
once by :func:`.engine.kernels`. The equations they evaluate are the scalar
functions of :mod:`.equations` (FL, FV and its inverse, the springs, the
activation's closed form, the fatigue laws, the RK4 update); the FL sums over
a unit layout are in :mod:`.units`. The paper's model is the muscle with every
FES feature off.

The step is split at the instants where the delayed command switches and
where the activation crosses a unit's recruitment level (the closed form gives
those instants), so that each unit stores the CE length of its own
recruitment instant and the force rises when it does, not at the next step.
Within each piece RK4 evaluates the effective isometric force at its stage
times, including the fatigue clocks.

The state's layout and the bundle that holds it are in :mod:`.state`, the unit
pool's functions in :mod:`.pool`; :func:`compiled` compiles the three
modules' functions together.
"""

from __future__ import annotations

import math
import types
from typing import Sequence

import numpy as np

from .. import equations, memory, stimulus, units
from . import ce as ce_module
from . import ding as ding_module
from . import ding_kernels as ding_kernels_module
from . import pool as pool_module
from . import state as state_module
from ..equations import (MAX_EVENTS_PER_PIECE, QUASI_STATIC_RATE_PER_S, activation_at,
                         fitness_at, force_length, parallel_force, piece_activation,
                         riener_limit, riener_rate, rise_start, rk4_update, series_force,
                         substep_count, time_to_reach)
from ..memory import recruited_units
from .ce import quasi_force, rate_at, velocity
from .ding import ding_activation, ding_f_iso, ding_mean_fitness
from .ding_kernels import ding_advance
from .pool import (pool_advance_to, pool_eff_f_iso, pool_eff_f_iso_initial, pool_mean_fitness,
                   pool_update)
from .state import (A_END, A_JUMP, A_PIECE, A_RECRUIT, A_RELEASE, A_RISE, DELAY_FULL, FesBundle,
                    H_CAPDQ, H_DQT, H_DQU, H_EVA, H_EVT, H_EVV, H_FP, H_FS,
                    H_IP, H_JS, I_DING, I_FATIGUE, I_INITIAL, I_MULTI, I_N,
                    J_DCOUNT, J_DHEAD, J_NEV, J_NREC, N_OUT, OK, P_EMD,
                    P_F_ISO_MAX, P_K_PE, P_K_SE, P_L_OPT, P_L_REST, P_MU_MIN0,
                    P_RATE_F0, P_RATE_R0, P_RELEASE, P_TAU_ACT, P_TAU_DEACT,
                    S_CMD, S_DL, S_F_SINGLE, S_L, S_LAW, S_MU, S_PIECE, S_R,
                    S_T, S_UD, S_V_FREE, TIME_TOL_S, hdr)


def delay_push(F, I, i, t, u):
    """Give command ``u`` at ``t``; False if the ring is full."""
    fs, fp, js = hdr(I, i, H_FS), hdr(I, i, H_FP), hdr(I, i, H_JS)
    cap = hdr(I, i, H_CAPDQ)
    n = I[js + J_DCOUNT]
    head = I[js + J_DHEAD]
    last = F[hdr(I, i, H_DQU) + (head + n - 1) % cap] if n > 0 else F[fs + S_UD]
    if u != last:
        if n == cap:
            return False
        k = (head + n) % cap
        F[hdr(I, i, H_DQT) + k] = t + F[fp + P_EMD]
        F[hdr(I, i, H_DQU) + k] = u
        I[js + J_DCOUNT] = n + 1
    return True


def delay_settle(F, I, i, t):
    """Take every switch due at or before ``t``: u_d now."""
    fs, js = hdr(I, i, H_FS), hdr(I, i, H_JS)
    cap = hdr(I, i, H_CAPDQ)
    while I[js + J_DCOUNT] > 0 and F[hdr(I, i, H_DQT) + I[js + J_DHEAD]] <= t + TIME_TOL_S:
        F[fs + S_UD] = F[hdr(I, i, H_DQU) + I[js + J_DHEAD]]
        I[js + J_DHEAD] = (I[js + J_DHEAD] + 1) % cap
        I[js + J_DCOUNT] -= 1
    return F[fs + S_UD]


def eff_f_iso(F, I, i, l, t):
    """[N] Eff.f_iso at CE length ``l`` and instant ``t``."""
    fs, fp, ip = hdr(I, i, H_FS), hdr(I, i, H_FP), hdr(I, i, H_IP)
    if I[ip + I_DING]:
        return ding_f_iso(F, I, i, l, t, -1)
    if I[ip + I_MULTI]:
        return pool_eff_f_iso(F, I, i, l / F[fp + P_L_OPT], t)
    a = piece_activation(F[fs + S_PIECE + 1], F[fs + S_PIECE + 2], F[fs + S_PIECE + 3],
                         t - F[fs + S_PIECE])
    if a <= 0.0:
        return 0.0
    mu = 1.0
    if I[ip + I_FATIGUE]:
        mu = fitness_at(F[fs + S_LAW + 1], F[fs + S_LAW + 2], F[fs + S_LAW + 3],
                        t - F[fs + S_LAW])
    if I[ip + I_INITIAL]:
        f = F[fs + S_F_SINGLE]
    else:
        f = F[fp + P_F_ISO_MAX] * force_length(l / F[fp + P_L_OPT])
    return a * mu * f


def eff_f_iso_inline(F, I, i, l, t):
    """[N] :func:`eff_f_iso`, a multi muscle with ``length: initial`` compiled into
    the caller (:func:`pool_eff_f_iso_initial`), any other muscle by a call.

    Why: a limb's RK4 asks a multi/initial muscle's F0 at every step's three
    instants, and a call between compiled functions passes ``F`` and ``I`` as
    seven words each; compiled in place, the call goes (the knee extension:
    see :data:`hill_muscle_ros.model.limb.kernels._INTO_STEP`). Only this small path is inlined:
    inlining the whole :func:`eff_f_iso` at each of its call sites made a cold
    compile of the limb take 4 minutes instead of 26 s.
    """
    ip = hdr(I, i, H_IP)
    if I[ip + I_MULTI] and I[ip + I_INITIAL]:
        return pool_eff_f_iso_initial(F, I, i, t)
    return eff_f_iso(F, I, i, l, t)


def stiffness_rate(F, I, i, l, dl, t):
    """[1/s] the CE's relaxation rate."""
    return rate_at(F, I, i, l, dl, eff_f_iso(F, I, i, l, t))


def peak_rate(F, I, i, l, dl, s0, s1):
    """[1/s] the CE's relaxation rate over [s0, s1]."""
    r0 = stiffness_rate(F, I, i, l, dl, s0)
    r1 = stiffness_rate(F, I, i, l, dl, s0 + 0.5 * (s1 - s0))
    r2 = stiffness_rate(F, I, i, l, dl, s1)
    return max(r0, max(r1, r2))


def single_fatigue(F, I, i):
    """True for a single muscle with Riener fatigue (the whole-muscle law)."""
    ip = hdr(I, i, H_IP)
    return I[ip + I_MULTI] == 0 and I[ip + I_FATIGUE] != 0


def begin_interval(F, I, i, s0, s1):
    """The single muscle's fitness law over [s0, s1], a held at its midpoint value
   ."""
    fs, fp = hdr(I, i, H_FS), hdr(I, i, H_FP)
    if not single_fatigue(F, I, i):
        return
    a = piece_activation(F[fs + S_PIECE + 1], F[fs + S_PIECE + 2], F[fs + S_PIECE + 3],
                         0.5 * (s0 + s1) - F[fs + S_PIECE])
    a = max(a, 0.0) if a > F[fp + P_RELEASE] else 0.0
    rate_f, rate_r = F[fp + P_RATE_F0], F[fp + P_RATE_R0]
    lam = riener_rate(a, rate_f, rate_r)
    F[fs + S_LAW] = s0
    F[fs + S_LAW + 1] = F[fs + S_MU]
    F[fs + S_LAW + 2] = riener_limit(a, F[fp + P_MU_MIN0], rate_f, rate_r, lam)
    F[fs + S_LAW + 3] = lam


def end_interval(F, I, i, s1):
    """The single muscle's fitness at ``s1``."""
    fs = hdr(I, i, H_FS)
    if single_fatigue(F, I, i):
        F[fs + S_MU] = fitness_at(F[fs + S_LAW + 1], F[fs + S_LAW + 2], F[fs + S_LAW + 3],
                                 s1 - F[fs + S_LAW])


def set_activation(F, I, i, a, t):
    """a = R at ``t``, the memory updated from l_CE now."""
    fs, fp, js, ip = hdr(I, i, H_FS), hdr(I, i, H_FP), hdr(I, i, H_JS), hdr(I, i, H_IP)
    if I[ip + I_MULTI]:
        m = recruited_units(a, I[ip + I_N])
        pool_update(F, I, i, m, F[fs + S_L] / F[fp + P_L_OPT], t)
        I[js + J_NREC] = m
    else:
        if a == 0.0:
            F[fs + S_F_SINGLE] = 0.0
        elif F[fs + S_R] == 0.0:
            F[fs + S_F_SINGLE] = F[fp + P_F_ISO_MAX] * force_length(F[fs + S_L] / F[fp + P_L_OPT])
        I[js + J_NREC] = 1 if a > 0.0 else 0
    F[fs + S_R] = a


def tau_for(F, I, i, a, u_d):
    """[s] tau in force: ``tau_act_s`` while u_d > a, else ``tau_deact_s``."""
    fp = hdr(I, i, H_FP)
    return F[fp + P_TAU_ACT] if u_d > a else F[fp + P_TAU_DEACT]


def set_piece(F, I, i, s0, a0, u_d, tau):
    """The activation's closed form from ``s0``."""
    fs = hdr(I, i, H_FS)
    F[fs + S_PIECE] = s0
    F[fs + S_PIECE + 1] = a0
    F[fs + S_PIECE + 2] = u_d
    F[fs + S_PIECE + 3] = tau


def settle_now(F, I, i):
    """Apply a delayed command due now if the activation follows it at once
   ."""
    fs, fp = hdr(I, i, H_FS), hdr(I, i, H_FP)
    t = F[fs + S_T]
    u_d = delay_settle(F, I, i, t)
    if u_d != F[fs + S_R] and tau_for(F, I, i, F[fs + S_R], u_d) == 0.0:
        set_activation(F, I, i, u_d, t)
        set_piece(F, I, i, t, u_d, u_d, 0.0)
        if eff_f_iso(F, I, i, F[fs + S_L], t) == 0.0:
            F[fs + S_L] = F[fp + P_L_REST] + F[fs + S_DL]


def give_command(F, I, i, u):
    """Queue command ``u`` now and apply what is due;
    False if the delay line is full (nothing changed)."""
    fs = hdr(I, i, H_FS)
    if not delay_push(F, I, i, F[fs + S_T], u):
        return False
    F[fs + S_CMD] = u
    settle_now(F, I, i)
    return True


def add_event(F, I, i, t, action, v0, v1, v2, v3):
    """Append ``(t, action, values)`` to muscle ``i``'s plan."""
    js = hdr(I, i, H_JS)
    n = I[js + J_NEV]
    F[hdr(I, i, H_EVT) + n] = t
    I[hdr(I, i, H_EVA) + n] = action
    F[hdr(I, i, H_EVV) + n * 4 + 0] = v0
    F[hdr(I, i, H_EVV) + n * 4 + 1] = v1
    F[hdr(I, i, H_EVV) + n * 4 + 2] = v2
    F[hdr(I, i, H_EVV) + n * 4 + 3] = v3
    I[js + J_NEV] = n + 1


def group_target(m0, step, count, j):
    """[-] the M of event ``j`` of a piece: every unit, or
    :data:`MAX_EVENTS_PER_PIECE` groups of equal counts (Python's round: half to even)."""
    if count <= MAX_EVENTS_PER_PIECE:
        return m0 + step * (j + 1)
    x = count * (j + 1) / MAX_EVENTS_PER_PIECE
    r = math.floor(x)
    frac = x - r
    if frac > 0.5 or (frac == 0.5 and r % 2 == 1):
        r += 1
    return m0 + step * int(r)


def plan_events(F, I, i, s0, s1, a0, u_d, tau, m0):
    """Recruitment events of a moving piece; returns M at s1."""
    ip = hdr(I, i, H_IP)
    n = I[ip + I_N]
    m1 = recruited_units(activation_at(a0, u_d, tau, s1 - s0), n)
    if m1 == m0:
        return m0
    step = 1 if m1 > m0 else -1
    count = abs(m1 - m0)
    n_events = count if count <= MAX_EVENTS_PER_PIECE else MAX_EVENTS_PER_PIECE
    m = m0
    for j in range(n_events):
        m = group_target(m0, step, count, j)
        level = (m - 0.5) / n if step > 0 else (m + 0.5) / n
        s = s0 + time_to_reach(a0, u_d, tau, level)
        add_event(F, I, i, min(max(s, s0), s1), A_RECRUIT, m, 0.0, 0.0, 0.0)
    return m


def plan(F, I, i, t0, t1):
    """The recruitment changes of the step [t0, t1] into muscle ``i``'s event
    table; consumes the delayed commands due in the step."""
    fs, js = hdr(I, i, H_FS), hdr(I, i, H_JS)
    cap = hdr(I, i, H_CAPDQ)
    I[js + J_NEV] = 0
    a, m = F[fs + S_R], I[js + J_NREC]
    start, u_d = t0, F[fs + S_UD]
    done = False
    while not done:
        # The next piece of constant delayed command.
        s0, piece_u = start, u_d
        s1 = t1
        done = True
        while I[js + J_DCOUNT] > 0 and F[hdr(I, i, H_DQT) + I[js + J_DHEAD]] < t1 - TIME_TOL_S:
            head = I[js + J_DHEAD]
            t_switch, u_next = F[hdr(I, i, H_DQT) + head], F[hdr(I, i, H_DQU) + head]
            I[js + J_DHEAD] = (head + 1) % cap
            I[js + J_DCOUNT] -= 1
            u_d = u_next
            if t_switch > start + TIME_TOL_S:
                s1 = t_switch
                start = t_switch
                done = False
                break
            piece_u = u_next
        if done:
            F[fs + S_UD] = u_d
        a, m = plan_piece(F, I, i, s0, s1, piece_u, a, m)
    add_event(F, I, i, t1, A_END, a, 0.0, 0.0, 0.0)


def plan_piece(F, I, i, s0, s1, u_d, a, m):
    """Events of one piece [s0, s1] of constant delayed command (the loop body of
    :func:`plan`); returns a and M at s1."""
    fp, ip = hdr(I, i, H_FP), hdr(I, i, H_IP)
    multi = I[ip + I_MULTI] != 0
    tau = tau_for(F, I, i, a, u_d) if u_d != a else 0.0
    if tau == 0.0:
        if u_d != a:
            add_event(F, I, i, s0, A_JUMP, u_d, 0.0, 0.0, 0.0)
            a = u_d
            m = recruited_units(a, I[ip + I_N]) if multi else (1 if a > 0.0 else 0)
        add_event(F, I, i, s0, A_PIECE, s0, a, a, 0.0)
        return a, m
    add_event(F, I, i, s0, A_PIECE, s0, a, u_d, tau)
    if multi:
        m = plan_events(F, I, i, s0, s1, a, u_d, tau, m)
        return activation_at(a, u_d, tau, s1 - s0), m
    if a == 0.0:
        add_event(F, I, i, s0, A_RISE, 0.0, 0.0, 0.0, 0.0)
    a1 = activation_at(a, u_d, tau, s1 - s0)
    level = F[fp + P_RELEASE]
    if u_d < a and u_d < level and a1 < level < a:
        s_rel = s0 + time_to_reach(a, u_d, tau, level)
        add_event(F, I, i, s_rel, A_RELEASE, 0.0, 0.0, 0.0, 0.0)
        if u_d > 0.0:   # rising again towards a command below one unit
            tau_act = F[fp + P_TAU_ACT]
            a_rise = rise_start(u_d, tau_act)
            add_event(F, I, i, s_rel, A_PIECE, s_rel, a_rise, u_d, tau_act)
            add_event(F, I, i, s_rel, A_RISE, 0.0, 0.0, 0.0, 0.0)
            a1 = piece_activation(a_rise, u_d, tau_act, s1 - s_rel)
        else:
            add_event(F, I, i, s_rel, A_PIECE, s_rel, 0.0, 0.0, 0.0)
            a1 = 0.0
    return a1, m


def apply(F, I, i, e, t):
    """Apply event ``e`` of muscle ``i``'s plan at ``t``."""
    fs, fp, js, ip = hdr(I, i, H_FS), hdr(I, i, H_FP), hdr(I, i, H_JS), hdr(I, i, H_IP)
    action = I[hdr(I, i, H_EVA) + e]
    if action == A_PIECE:
        v = hdr(I, i, H_EVV) + e * 4
        set_piece(F, I, i, F[v], F[v + 1], F[v + 2], F[v + 3])
    elif action == A_RECRUIT:
        m = int(F[hdr(I, i, H_EVV) + e * 4 + 0])
        pool_update(F, I, i, m, F[fs + S_L] / F[fp + P_L_OPT], t)
        I[js + J_NREC] = m
    elif action == A_JUMP:
        set_activation(F, I, i, F[hdr(I, i, H_EVV) + e * 4 + 0], t)
    elif action == A_RISE:
        F[fs + S_F_SINGLE] = F[fp + P_F_ISO_MAX] * force_length(F[fs + S_L] / F[fp + P_L_OPT])
        I[js + J_NREC] = 1
    elif action == A_RELEASE:
        set_activation(F, I, i, 0.0, t)
    else:   # A_END
        a = F[hdr(I, i, H_EVV) + e * 4 + 0]
        F[fs + S_R] = a
        if not I[ip + I_MULTI]:
            I[js + J_NREC] = 1 if a > 0.0 else 0


def muscle_rk4(F, I, i, s0, s1, t0, dl0, rate):
    """One RK4 step of l_CE over [s0, s1]."""
    fs, fp, ip = hdr(I, i, H_FS), hdr(I, i, H_FP), hdr(I, i, H_IP)
    h = s1 - s0
    initial = I[ip + I_INITIAL] != 0
    l = F[fs + S_L]
    f0 = eff_f_iso(F, I, i, l, s0)
    dl_a = dl0 + rate * (s0 - t0)
    dl_b = dl0 + rate * (s1 - t0)
    f0_end = eff_f_iso(F, I, i, l, s1)
    if f0 > 0.0 or f0_end > 0.0:
        mid, dl_m = s0 + 0.5 * h, 0.5 * (dl_a + dl_b)
        k1 = velocity(F, I, i, l, dl_a, f0)
        l2 = l + 0.5 * h * k1
        if initial:
            f0_mid = eff_f_iso(F, I, i, l2, mid)
            k2 = velocity(F, I, i, l2, dl_m, f0_mid)
            l3 = l + 0.5 * h * k2
            k3 = velocity(F, I, i, l3, dl_m, f0_mid)
            l4 = l + h * k3
            k4 = velocity(F, I, i, l4, dl_b, f0_end)
        else:
            k2 = velocity(F, I, i, l2, dl_m, eff_f_iso(F, I, i, l2, mid))
            l3 = l + 0.5 * h * k2
            k3 = velocity(F, I, i, l3, dl_m, eff_f_iso(F, I, i, l3, mid))
            l4 = l + h * k3
            k4 = velocity(F, I, i, l4, dl_b, eff_f_iso(F, I, i, l4, s1))
        l = rk4_update(l, h, k1, k2, k3, k4)
        if not initial and eff_f_iso(F, I, i, l, s1) == 0.0:
            l = F[fp + P_L_REST] + dl_b   # the instantaneous CE left the FL range
        elif initial and f0_end == 0.0:
            l = F[fp + P_L_REST] + dl_b   # single: released within the piece
    else:
        l = F[fp + P_L_REST] + dl_b       # the free CE takes up the SE slack
    F[fs + S_L] = l


def muscle_integrate(F, I, i, s0, s1, t0, dl0, rate):
    """RK4 of l_CE over [s0, s1], no recruitment change inside."""
    fs = hdr(I, i, H_FS)
    h = s1 - s0
    if h <= 0.0:
        return
    begin_interval(F, I, i, s0, s1)
    l = F[fs + S_L]
    peak = peak_rate(F, I, i, l, dl0 + rate * (s0 - t0), s0, s1)
    if peak >= QUASI_STATIC_RATE_PER_S:
        fp = hdr(I, i, H_FP)
        f = quasi_force(F, I, i, rate, eff_f_iso(F, I, i, l, s1))
        F[fs + S_L] = F[fp + P_L_REST] + dl0 + rate * (s1 - t0) - f / F[fp + P_K_SE]
    else:
        n = substep_count(h, peak)
        for j in range(n):
            a = s0 + h * j / n
            b = s1 if j == n - 1 else s0 + h * (j + 1) / n
            muscle_rk4(F, I, i, a, b, t0, dl0, rate)
    end_interval(F, I, i, s1)


def muscle_advance(F, I, i, u, dl1, dt):
    """One step: command ``u`` given at its start, dl_MT ramping to ``dl1``
   ; returns :data:`OK` or :data:`DELAY_FULL`."""
    fs, js, ip = hdr(I, i, H_FS), hdr(I, i, H_JS), hdr(I, i, H_IP)
    t0, dl0 = F[fs + S_T], F[fs + S_DL]
    t1 = t0 + dt
    if not give_command(F, I, i, u):
        return DELAY_FULL
    rate = (dl1 - dl0) / dt
    plan(F, I, i, t0, t1)
    s = t0
    for e in range(I[js + J_NEV]):
        instant = F[hdr(I, i, H_EVT) + e]
        muscle_integrate(F, I, i, s, instant, t0, dl0, rate)
        apply(F, I, i, e, instant)
        s = instant
    F[fs + S_V_FREE] = rate
    F[fs + S_DL] = dl1
    F[fs + S_T] = t1
    settle_now(F, I, i)
    if I[ip + I_MULTI]:
        pool_advance_to(F, I, i, t1)
    return OK


def muscle_outputs(F, I, i, out):
    """The outputs now into ``out`` (12,), MuscleOutputs' order."""
    fs, fp, js, ip = hdr(I, i, H_FS), hdr(I, i, H_FP), hdr(I, i, H_JS), hdr(I, i, H_IP)
    l, dl, t = F[fs + S_L], F[fs + S_DL], F[fs + S_T]
    r = F[fs + S_R]
    set_piece(F, I, i, t, r, r, 0.0)
    F[fs + S_LAW] = t
    F[fs + S_LAW + 1] = F[fs + S_MU]
    F[fs + S_LAW + 2] = F[fs + S_MU]
    F[fs + S_LAW + 3] = 0.0
    f_se = series_force(F[fp + P_K_SE], dl, l, F[fp + P_L_REST])
    f_pe = parallel_force(F[fp + P_K_PE], dl)
    f0 = eff_f_iso(F, I, i, l, t)
    v = velocity(F, I, i, l, dl, f0) if f0 > 0.0 else F[fs + S_V_FREE]
    out[0] = t
    out[1] = r
    out[2] = I[js + J_NREC]
    out[3] = dl
    out[4] = l
    out[5] = v
    out[6] = f_se
    out[7] = f_pe
    out[8] = f_se + f_pe
    out[9] = f0
    out[10] = F[fs + S_CMD]
    if I[ip + I_DING]:
        out[11] = ding_mean_fitness(F, I, i, t)
    elif I[ip + I_MULTI]:
        out[11] = pool_mean_fitness(F, I, i, t)
    else:
        out[11] = F[fs + S_MU]


def muscle_run(F, I, i, r_start, dl_end, dt, r_end, have_r_end, out):
    """Advance ``len(dl_end)`` steps, outputs of step k in ``out[k]``.

    :return: the number of steps done (fewer if the delay line filled up)
    """
    fs = hdr(I, i, H_FS)
    for k in range(dl_end.shape[0]):
        if muscle_advance(F, I, i, r_start[k], dl_end[k], dt) != OK:
            return k
        if have_r_end and r_end[k] != F[fs + S_CMD]:
            if not give_command(F, I, i, r_end[k]):
                return k
        muscle_outputs(F, I, i, out[k])
    return dl_end.shape[0]


def ding_run(F, I, i, pt, pc, pu, dl_end, dt, out, act):
    """Advance ``len(dl_end)`` steps with the pulses (``pt``, ``pc``, ``pu``) in
    time order; a pulse at t belongs to the step [t0, t1) that holds it (within
    TIME_TOL_S of t0: that step). Outputs of step k in ``out[k]``, the channels'
    a in ``act[k]``.

    :return: the index of the first pulse not used (at or after the last step's end)
    """
    fs = hdr(I, i, H_FS)
    j = 0
    n_pulses = pt.shape[0]
    for k in range(dl_end.shape[0]):
        t1 = F[fs + S_T] + dt
        j1 = j
        while j1 < n_pulses and pt[j1] < t1 - TIME_TOL_S:
            j1 += 1
        ding_advance(F, I, i, pt, pc, pu, j, j1, dl_end[k], dt)
        j = j1
        muscle_outputs(F, I, i, out[k])
        ding_activation(F, I, i, act[k])
    return j


def _plain() -> types.SimpleNamespace:
    """This module's plain functions, as a namespace like :func:`compiled`'s."""
    import sys
    return sys.modules[__name__]


#: The shared equations of other modules, compiled over :func:`compile_scope`
#: (which holds the constants they read), small enough to inline.
_EQUATIONS = ('force_length', 'force_velocity', 'force_velocity_inverse', 'series_force',
              'parallel_force', 'rk4_update', 'activation_at', 'time_to_reach',
              'piece_activation', 'rise_start', 'fitness_at', 'riener_rate', 'riener_limit',
              'fes_velocity', 'quasi_static_force', 'relaxation_rate', 'substep_count',
              'recruited_units', 'fl_clear', 'type_fl_sum', 'moment_force', 'recruited_excess',
              'resting_deficit', 'ding_pulse_weight', 'ding_cn_at', 'ding_rate')


#: The engine's functions (:mod:`.state`, :mod:`.pool` and this module's), callees
#: before callers.
_KERNELS = ('hdr', 'scratch', 'forget_eff_f_iso', 'per_type', 'per_sum', 'moment',
            'fatigue_alpha', 'fatigue_beta',
            'delay_push', 'delay_settle', 'pool_static_row', 'pool_push_recruited',
            'pool_clocks', 'pool_advance_to', 'pool_recruit', 'pool_release', 'pool_update',
            'pool_eff_f_iso_clipped', 'pool_eff_f_iso_initial', 'pool_eff_f_iso',
            'pool_mean_fitness', 'ding_slot', 'ding_f_iso', 'ding_stages', 'ding_commit',
            'ding_clocks', 'ding_totals', 'ding_pulse', 'ding_settle', 'ding_mean_fitness',
            'ding_activation', 'eff_f_iso', 'eff_f_iso_inline', 'velocity', 'rate_at',
            'stiffness_rate', 'peak_rate', 'quasi_force', 'single_fatigue', 'begin_interval',
            'end_interval', 'set_activation', 'tau_for', 'set_piece', 'settle_now',
            'give_command', 'add_event', 'group_target', 'plan_events', 'plan_piece', 'plan',
            'apply', 'muscle_rk4', 'muscle_integrate', 'muscle_advance', 'muscle_outputs',
            'muscle_run', 'ding_rk4', 'ding_integrate', 'free_if_idle', 'ding_advance',
            'ding_run')


#: The modules whose code the kernels inline: their digest names the cache entries.
_DIGEST_OF = (equations, stimulus, memory, units, state_module, pool_module, ce_module,
              ding_module, ding_kernels_module)


#: The compiled namespace once built (None until then).
_compiled = None


def compile_scope() -> dict:
    """The names the kernels are compiled over: this module's globals, over those of
    the modules whose functions they compile with them (:data:`_EQUATIONS`
    read their own module's constants; :mod:`.state` and :mod:`.pool` hold
    the layout and the pool's functions)."""
    scope = {}
    for module in (units, memory, stimulus, equations, state_module, pool_module, ce_module,
                   ding_module, ding_kernels_module):
        scope.update(vars(module))
    scope.update(globals())
    return scope


def loaded() -> bool:
    """True if the compiled kernels are built in this process (:func:`compiled`)."""
    return _compiled is not None


def compiled() -> types.SimpleNamespace:
    """The numba-compiled kernels (imports numba on the first call).

    The entry points have explicit signatures, so they are compiled, or loaded
    from numba's disk cache, here and once.

    :raises ImportError: if numba cannot be imported
    """
    global _compiled
    if _compiled is not None:
        return _compiled
    from .. import engine   # imports numba lazily
    import sys
    this = sys.modules[__name__]
    leaf = {'error_model': 'numpy', 'inline': 'always'}
    body = {'error_model': 'numpy'}
    options = {name: leaf for name in _EQUATIONS}
    options.update({name: body for name in _KERNELS})
    # pool_eff_f_iso into its one caller, eff_f_iso, which every RK4 stage and
    # event asks: one call less each (the knee extension compiled: 2.74-2.94 ->
    # 2.63-2.82 ms a run, by hand, alternating; a cold compile 0.8 s more).
    # eff_f_iso_inline's small path into the limb's step (see its docstring),
    # and the whole-muscle fatigue's interval bounds, asked twice per muscle
    # each RK4 interval, into theirs (the knee extension: 0.944x and 0.980x
    # on either core, alternating, 31 pair ratios; a cold compile 0.7 s more).
    # The fatigue clocks (fatigue_alpha, fatigue_beta) stay calls: inlined into
    # every pool function they made a cold compile of the muscle and the limb
    # 113 s instead of 78 s, for no measurable gain (Protocol II 2.56 against
    # 2.49 ms, the knee extension 4.12 against 4.01 ms, by hand).
    options.update({name: leaf for name in ('hdr', 'scratch', 'forget_eff_f_iso', 'per_type',
                                            'ding_slot',
                                            'per_sum', 'moment', 'pool_eff_f_iso_initial',
                                            'pool_eff_f_iso', 'eff_f_iso_inline',
                                            'single_fatigue', 'begin_interval',
                                            'end_interval')})

    def run_signature(numba):
        f8, i8 = numba.float64, numba.int64
        c1, c2 = f8[::1], f8[:, ::1]
        return i8(c1, i8[::1], i8, c1, c1, f8, c1, numba.boolean, c2)

    # add_event is called with a constant action at each call site, for which
    # numba would compile it once per action (the literal value is in its
    # argument type): one signature, one compile.
    def add_event_signature(numba):
        f8, i8 = numba.float64, numba.int64
        return numba.types.none(f8[::1], i8[::1], i8, f8, i8, f8, f8, f8, f8)

    def ding_run_signature(numba):
        f8, i8 = numba.float64, numba.int64
        c1, c2 = f8[::1], f8[:, ::1]
        return i8(c1, i8[::1], i8, c1, i8[::1], c1, c1, f8, c2, c2)

    _compiled = engine.compile_functions(
        compile_scope(), _EQUATIONS + _KERNELS, digest_of=_DIGEST_OF + (this,),
        signatures={'muscle_run': run_signature, 'add_event': add_event_signature,
                    'ding_run': ding_run_signature},
        options=options)
    return _compiled


def scope_calling(scope: dict, names: Sequence[str]) -> dict:
    """A copy of a module's globals ``scope`` in which ``names`` are bound to
    this module's compiled functions: the scope in which kernels built on the
    compiled FES muscle (the batch's, the limb's) are compiled.

    :raises ImportError: if numba cannot be imported
    """
    muscle = compiled()
    bound = dict(scope)
    for name in names:
        bound[name] = getattr(muscle, name)
    return bound


def run_inputs(r_start, dl_end_m, r_end=None) -> tuple:
    """The inputs of :func:`muscle_run` as its compiled signature takes them:
    float arrays, contiguous and writable (a read-only view, e.g. of a
    recording, is copied).

    :return: ``(r_start, dl_end, r_end, have_r_end)``, ``r_end`` being ``r_start``
        when none is given
    """
    def array(values):
        return np.require(values, dtype=float, requirements=('C', 'W'))
    r_start = array(r_start)
    have_end = r_end is not None
    return r_start, array(dl_end_m), array(r_end) if have_end else r_start, have_end


def run_muscle(bundle: FesBundle, i: int, r_start, dl_end_m, dt_s: float, r_end=None,
               kernels=None) -> np.ndarray:
    """Run muscle ``i`` of ``bundle`` for ``len(dl_end_m)`` steps.

    :param r_start: [-] command given at the start of each step
    :param dl_end_m: [m] dl_MT at the end of each step
    :param dt_s: [s] step length
    :param r_end: [-] command given at the end of each step, or None
    :param kernels: :func:`compiled`, or None for the plain functions
    :return: (steps, N_OUT) outputs at the end of each step, MuscleOutputs' order
    """
    bundle.ensure_delay(dt_s)
    r_start, dl_end, r_end, have_end = run_inputs(r_start, dl_end_m, r_end)
    out = np.zeros((len(dl_end), N_OUT))
    done = (kernels or _plain()).muscle_run(bundle.F, bundle.I, i, r_start, dl_end,
                                            float(dt_s), r_end, have_end, out)
    if done != len(dl_end):   # delay_capacity bounds the commands pending
        raise RuntimeError(f'the delay line of muscle {i} overflowed at step {done}')
    return out
