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

State: two flat arrays, ``F`` (float64) and ``I`` (int64), holding each
muscle's regions (:data:`REGIONS`: parameters, state, unit layout, stacks,
delay ring, plan) one after another, with a header per muscle at the start of
``I`` giving every region's offset; every function takes ``F``, ``I`` and a
muscle index. Two arrays rather than one per region: a compiled call passes
each array's whole descriptor, and with twenty of them a call cost about 300
ns (measured: Eff.f_iso of a 50-unit muscle, 307 ns a call with the arrays
in a tuple, 53 ns with these two). :class:`FesBundle` builds them from
parameters; a limb's muscles are muscles 0, 1, ... of one bundle.

The unit pool (multi): units recruited and released at the same instants
share their whole history, so they share their fitness. The units along the
recruitment order are split into segments of one history each: the recruited
prefix [0, M) is a stack of segments (each also stores the CE length at which
it was recruited), the resting suffix [M, N) another. Every recruited
segment's excess fitness mu - mu_min decays by the same factor exp(-dt / T_fat)
in a step, and every resting segment's deficit 1 - mu by exp(-dt / T_rec): so
each is stored divided by a common clock, and the totals over a stack are
static running sums, read at any instant in O(1) per fibre type without
rounding drift (doc/model.md section 7.3). A recruitment change moves the
segments between the stacks it spans and splits at most one.
"""
from __future__ import annotations

import functools
import math
import threading
import types
from typing import Sequence

import numpy as np

from . import equations, memory, stimulus, units
from .equations import (ECC_PLATEAU, FL_A, FL_B, FL_C, MAX_EVENTS_PER_PIECE, MAX_SUBSTEPS,
                        QUASI_STATIC_RATE_PER_S, RK4_MAX_H_LAMBDA, activation_at, fes_velocity,
                        fitness_at, force_length, force_velocity, force_velocity_inverse,
                        moment_force, parallel_force, piece_activation, quasi_static_force,
                        recruited_excess, relaxation_rate, resting_deficit, riener_limit,
                        riener_rate, rise_start, rk4_update, series_force, substep_count,
                        time_to_reach)
from .memory import recruited_units
from .params import MuscleParams
from .stimulus import DelayLine
from .units import (FL_ROOT_HIGH, FL_ROOT_LOW, PHI, UnitLayout, fl_clear, length_scale,
                    type_fl_sum, unit_length_scale)

#: Elapsed time over the fastest time constant after which the unit pool's
#: common clocks are renormalised: exp(-500) = 7e-218 stays far from underflow,
#: and stored values divided by it (at most e^500 = 1.4e217) far from overflow.
_RENORMALISE_AFTER_TAUS = 500.0
#: [s] two instants closer than this are one (the delay line's tolerance).
TIME_TOL_S = DelayLine.TIME_TOLERANCE_S

# Columns of the float parameters ``fp``.
(P_K_SE, P_K_PE, P_L_REST, P_L_OPT, P_A, P_B, P_A_ECC, P_B_ECC, P_F_ISO_MAX, P_TAU_ACT,
 P_TAU_DEACT, P_EMD, P_RELEASE, P_SPREAD, P_RENORM_S, P_MU_MIN0, P_RATE_F0,
 P_RATE_R0) = range(18)
N_FP = 18
# Columns of the integer parameters ``ip``.
I_MULTI, I_INITIAL, I_RELATIVE, I_FATIGUE, I_N, I_K = range(6)
N_IP = 6
# Rows of the per-type parameters ``tp``.
T_F_MAX, T_MU_MIN, T_RATE_FAT, T_RATE_REC = range(4)
# Columns of the float state ``fs``.
(S_T, S_L, S_DL, S_R, S_CMD, S_F_SINGLE, S_MU, S_V_FREE, S_PIECE, _S1, _S2, _S3, S_LAW,
 _S5, _S6, _S7, S_EPOCH, S_UD, S_CACHE) = range(19)
#: Entries of the cache of Eff.f_iso (multi/initial): instants, values, next slot.
N_CACHE = 2 * 3 + 1
N_FS = S_CACHE + N_CACHE
# Columns of the integer state ``js``.
J_NREC, J_M, J_RTOP, J_UN, J_DHEAD, J_DCOUNT, J_NEV = range(7)
N_JS = 7
# Columns of a recruited segment's static sums per type.
C_G, C_N, C_C1, C_C2 = range(4)
#: Actions of the plan of a step's recruitment changes.
A_PIECE, A_JUMP, A_RECRUIT, A_RISE, A_RELEASE, A_END = range(6)
#: Rows of a muscle's outputs, as :class:`~hill_muscle_ros.model.muscle.MuscleOutputs`.
N_OUT = 12
#: Status of a step: done; the delay line's ring buffer is full (the caller grows it).
OK, DELAY_FULL = 0, 1

# The header of muscle i: I[i * N_HDR + H_*], offsets of its regions in F and I.
(H_FP, H_FS, H_TP, H_PREFIX, H_CPOS, H_RX, H_REXN, H_RSTATIC, H_RDYN, H_UDN, H_UCUM,
 H_DQT, H_DQU, H_EVT, H_EVV, H_SCR,                       # in F
 H_IP, H_JS, H_TPOS, H_REND, H_USTART, H_UEND, H_EVA,     # in I
 H_CAPDQ, H_CAPEV, H_K, H_NP1) = range(27)                 # sizes
N_HDR = 27
#: Regions of a muscle: name, header entry, array ('F' or 'I'), size from (N, K, cap, ecap).
REGIONS = (
    ('fp', H_FP, 'F', lambda n, k, c, e: N_FP),
    ('fs', H_FS, 'F', lambda n, k, c, e: N_FS),
    ('tp', H_TP, 'F', lambda n, k, c, e: 4 * k),
    ('prefix', H_PREFIX, 'F', lambda n, k, c, e: k * 3 * (n + 1)),
    ('cpos', H_CPOS, 'F', lambda n, k, c, e: n),
    ('r_x', H_RX, 'F', lambda n, k, c, e: n + 2),
    ('r_exn', H_REXN, 'F', lambda n, k, c, e: (n + 2) * k),
    ('r_static', H_RSTATIC, 'F', lambda n, k, c, e: (n + 2) * k * 4),
    ('r_dyn', H_RDYN, 'F', lambda n, k, c, e: (n + 2) * k * 4),
    ('u_dn', H_UDN, 'F', lambda n, k, c, e: (n + 2) * k),
    ('u_cum', H_UCUM, 'F', lambda n, k, c, e: (n + 2) * k),
    ('dq_t', H_DQT, 'F', lambda n, k, c, e: c),
    ('dq_u', H_DQU, 'F', lambda n, k, c, e: c),
    ('ev_t', H_EVT, 'F', lambda n, k, c, e: e),
    ('ev_v', H_EVV, 'F', lambda n, k, c, e: 4 * e),
    ('scratch', H_SCR, 'F', lambda n, k, c, e: 9 * k),
    ('ip', H_IP, 'I', lambda n, k, c, e: N_IP),
    ('js', H_JS, 'I', lambda n, k, c, e: N_JS),
    ('tpos', H_TPOS, 'I', lambda n, k, c, e: n),
    ('r_end', H_REND, 'I', lambda n, k, c, e: n + 2),
    ('u_start', H_USTART, 'I', lambda n, k, c, e: n + 2),
    ('u_end', H_UEND, 'I', lambda n, k, c, e: n + 2),
    ('ev_a', H_EVA, 'I', lambda n, k, c, e: e),
)
# Scratch of a pool update, in multiples of K: clocks D and H, resting deficits,
# excesses, a segment's static row (4 K) and per-type sums.
SCR_D, SCR_H, SCR_DN, SCR_EXN, SCR_ROW, SCR_SUMS = 0, 1, 2, 3, 4, 8


def hdr(I, i, h):
    """Header entry ``h`` of muscle ``i`` (an offset or a size)."""
    return I[i * N_HDR + h]


def scratch(I, i, slot):
    """Offset in F of scratch slot ``slot`` (SCR_*) of muscle ``i``."""
    return I[i * N_HDR + H_SCR] + slot * I[i * N_HDR + H_K]


def forget_eff_f_iso(F, I, i):
    """Empty the Eff.f_iso cache of muscle ``i``: its unit pool changed.

    A multi/initial muscle's Eff.f_iso depends on the instant alone between
    pool changes, and an RK4 step asks for it at three instants (start,
    middle, end) up to seven times per muscle, plus the substep count's three:
    the cache keeps the last three instants' values (NaN keys match nothing).
    """
    c = I[i * N_HDR + H_FS] + S_CACHE
    F[c] = math.nan
    F[c + 1] = math.nan
    F[c + 2] = math.nan


# -- the delay line ------------------------------------------------------------------------

def delay_push(F, I, i, t, u):
    """Give command ``u`` at ``t`` (DelayLine.push); False if the ring is full."""
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
    """Take every switch due at or before ``t`` (DelayLine.settle): u_d now."""
    fs, js = hdr(I, i, H_FS), hdr(I, i, H_JS)
    cap = hdr(I, i, H_CAPDQ)
    while I[js + J_DCOUNT] > 0 and F[hdr(I, i, H_DQT) + I[js + J_DHEAD]] <= t + TIME_TOL_S:
        F[fs + S_UD] = F[hdr(I, i, H_DQU) + I[js + J_DHEAD]]
        I[js + J_DHEAD] = (I[js + J_DHEAD] + 1) % cap
        I[js + J_DCOUNT] -= 1
    return F[fs + S_UD]


# -- the unit pool (multi) -------------------------------------------------------------------

def per_type(I, i, h, row, k):
    """Offset in F of entry ``k`` of row ``row`` of a per-type region (header ``h``)."""
    return hdr(I, i, h) + row * hdr(I, i, H_K) + k


def per_sum(I, i, h, seg, k, c):
    """Offset in F of column ``c`` (C_*) of type ``k`` of segment ``seg`` of a
    region of static sums (header H_RSTATIC or H_RDYN)."""
    return hdr(I, i, h) + (seg * hdr(I, i, H_K) + k) * 4 + c


def moment(F, I, i, k, c, p0, p1):
    """Moment ``c`` (0: n, 1: sum c, 2: sum c^2) of type ``k`` over positions [p0, p1)."""
    base = hdr(I, i, H_PREFIX) + (k * 3 + c) * hdr(I, i, H_NP1)
    return F[base + p1] - F[base + p0]


def pool_static_row(F, I, i, p0, p1, x_o, row):
    """Per type: g = f_max sum FL(c x_o) (initial), n, sum c, sum c^2 over [p0, p1)
   , written to F from offset ``row`` (K rows of 4)."""
    fp = hdr(I, i, H_FP)
    ip = hdr(I, i, H_IP)
    k_types, initial = I[ip + I_K], I[ip + I_INITIAL]
    s = F[fp + P_SPREAD]
    clear = s == 0.0 or fl_clear(x_o, s)
    for k in range(k_types):
        n = moment(F, I, i, k, 0, p0, p1)
        c1 = moment(F, I, i, k, 1, p0, p1)
        c2 = moment(F, I, i, k, 2, p0, p1)
        r = row + 4 * k
        F[r + C_N] = n
        F[r + C_C1] = c1
        F[r + C_C2] = c2
        F[r + C_G] = 0.0
        if initial and clear:
            F[r + C_G] = type_fl_sum(F[per_type(I, i, H_TP, T_F_MAX, k)], x_o, s, n, c1, c2)
    if initial and not clear:
        # Some units may be off the FL range: unit by unit (UnitLayout.fl_sums).
        cpos, tpos = hdr(I, i, H_CPOS), hdr(I, i, H_TPOS)
        for p in range(p0, p1):
            F[row + 4 * I[tpos + p] + C_G] += force_length(F[cpos + p] * x_o)
        for k in range(k_types):
            F[row + 4 * k + C_G] = F[per_type(I, i, H_TP, T_F_MAX, k)] * F[row + 4 * k + C_G]


def pool_push_recruited(F, I, i, end, x_o, exn, row):
    """Push a recruited segment; ``exn`` and ``row`` are
    offsets in F of its excesses (K) and its static row (K rows of 4)."""
    ip, js = hdr(I, i, H_IP), hdr(I, i, H_JS)
    top = I[js + J_RTOP]
    k_types = I[ip + I_K]
    if not I[ip + I_FATIGUE] and not I[ip + I_INITIAL] and top > 0:
        # Nothing tells these units apart: one segment for the recruited prefix.
        I[hdr(I, i, H_REND) + top] = end
        for k in range(k_types):
            for c in range(4):
                F[per_sum(I, i, H_RSTATIC, top, k, c)] += F[row + 4 * k + c]
        return
    top += 1
    I[hdr(I, i, H_REND) + top] = end
    F[hdr(I, i, H_RX) + top] = x_o
    for k in range(k_types):
        F[per_type(I, i, H_REXN, top, k)] = F[exn + k]
        for c in range(4):
            F[per_sum(I, i, H_RSTATIC, top, k, c)] = (
                F[per_sum(I, i, H_RSTATIC, top - 1, k, c)] + F[row + 4 * k + c])
            F[per_sum(I, i, H_RDYN, top, k, c)] = (
                F[per_sum(I, i, H_RDYN, top - 1, k, c)] + F[row + 4 * k + c] * F[exn + k])
    I[js + J_RTOP] = top


def pool_clocks(F, I, i, t, d, h):
    """D_k(t) and H_k(t), the fatigue and recovery clocks, into F at ``d`` and ``h``."""
    fs, ip = hdr(I, i, H_FS), hdr(I, i, H_IP)
    elapsed = t - F[fs + S_EPOCH]
    for k in range(I[ip + I_K]):
        F[d + k] = math.exp(-elapsed * F[per_type(I, i, H_TP, T_RATE_FAT, k)])
        F[h + k] = math.exp(-elapsed * F[per_type(I, i, H_TP, T_RATE_REC, k)])


def pool_advance_to(F, I, i, t):
    """Renormalise the clocks when they near underflow."""
    fp, js, ip = hdr(I, i, H_FP), hdr(I, i, H_JS), hdr(I, i, H_IP)
    fs = hdr(I, i, H_FS)
    if not (I[ip + I_FATIGUE]
            and t - F[fs + S_EPOCH] > F[fp + P_RENORM_S]):
        return
    forget_eff_f_iso(F, I, i)
    k_types = I[ip + I_K]
    d, h = scratch(I, i, SCR_D), scratch(I, i, SCR_H)
    pool_clocks(F, I, i, t, d, h)
    for seg in range(I[js + J_RTOP] + 1):
        for k in range(k_types):
            F[per_type(I, i, H_REXN, seg, k)] *= F[d + k]
            for c in range(4):
                F[per_sum(I, i, H_RDYN, seg, k, c)] *= F[d + k]
    for seg in range(I[js + J_UN]):
        for k in range(k_types):
            F[per_type(I, i, H_UDN, seg, k)] *= F[h + k]
            F[per_type(I, i, H_UCUM, seg, k)] *= F[h + k]
    F[fs + S_EPOCH] = t


def pool_recruit(F, I, i, m, x_o, t):
    """Recruit positions [M, m) at ``t`` with CE length ``x_o``."""
    ip, js = hdr(I, i, H_IP), hdr(I, i, H_JS)
    k_types, fatigue = I[ip + I_K], I[ip + I_FATIGUE]
    d, h = scratch(I, i, SCR_D), scratch(I, i, SCR_H)
    if fatigue:
        pool_clocks(F, I, i, t, d, h)
    dn, exn, row = scratch(I, i, SCR_DN), scratch(I, i, SCR_EXN), scratch(I, i, SCR_ROW)
    for k in range(k_types):
        F[exn + k] = 0.0
    pos = I[js + J_M]
    while pos < m:
        un = I[js + J_UN] - 1   # pop the lowest resting segment
        end = I[hdr(I, i, H_UEND) + un]
        for k in range(k_types):
            F[dn + k] = F[per_type(I, i, H_UDN, un, k)]
        take = min(end, m)
        if take < end:   # the rest keeps resting
            I[hdr(I, i, H_USTART) + un] = take
            for k in range(k_types):
                below = F[per_type(I, i, H_UCUM, un - 1, k)] if un > 0 else 0.0
                n_rest = moment(F, I, i, k, 0, take, end)
                F[per_type(I, i, H_UCUM, un, k)] = below + n_rest * F[dn + k]
            un += 1
        I[js + J_UN] = un
        pool_static_row(F, I, i, pos, take, x_o, row)
        if fatigue:
            for k in range(k_types):
                F[exn + k] = recruited_excess(F[dn + k], F[h + k],
                                              F[per_type(I, i, H_TP, T_MU_MIN, k)], F[d + k])
        pool_push_recruited(F, I, i, take, x_o, exn, row)
        pos = take
    I[js + J_M] = m


def pool_release(F, I, i, m, t):
    """Release positions [m, M) at ``t``, the last recruited first."""
    ip, js = hdr(I, i, H_IP), hdr(I, i, H_JS)
    k_types, fatigue = I[ip + I_K], I[ip + I_FATIGUE]
    d, h = scratch(I, i, SCR_D), scratch(I, i, SCR_H)
    if fatigue:
        pool_clocks(F, I, i, t, d, h)
    exn, row = scratch(I, i, SCR_EXN), scratch(I, i, SCR_ROW)
    u_start, u_end = hdr(I, i, H_USTART), hdr(I, i, H_UEND)
    pos = I[js + J_M]
    while pos > m:
        top = I[js + J_RTOP]
        start = I[hdr(I, i, H_REND) + top - 1]
        cut = max(start, m)
        x_o = F[hdr(I, i, H_RX) + top]
        for k in range(k_types):
            F[exn + k] = F[per_type(I, i, H_REXN, top, k)]
        I[js + J_RTOP] = top - 1   # pop
        if cut > start:   # the bottom of the segment stays recruited
            pool_static_row(F, I, i, start, cut, x_o, row)
            pool_push_recruited(F, I, i, cut, x_o, exn, row)
        un = I[js + J_UN]
        if not fatigue:
            # Resting units without fatigue are all fresh: one segment.
            end = pos
            if un > 0 and I[u_start + un - 1] == pos:
                end = I[u_end + un - 1]
                un -= 1
            I[u_start + un] = cut
            I[u_end + un] = end
            for k in range(k_types):
                F[per_type(I, i, H_UDN, un, k)] = 0.0
                F[per_type(I, i, H_UCUM, un, k)] = 0.0
            I[js + J_UN] = un + 1
            pos = cut
            continue
        for k in range(k_types):
            dn_k = resting_deficit(F[exn + k], F[d + k],
                                   F[per_type(I, i, H_TP, T_MU_MIN, k)], F[h + k])
            below = F[per_type(I, i, H_UCUM, un - 1, k)] if un > 0 else 0.0
            F[per_type(I, i, H_UDN, un, k)] = dn_k
            F[per_type(I, i, H_UCUM, un, k)] = below + moment(F, I, i, k, 0, cut, pos) * dn_k
        I[u_start + un] = cut
        I[u_end + un] = pos
        I[js + J_UN] = un + 1
        pos = cut
    I[js + J_M] = m


def pool_update(F, I, i, m, x_ce, t):
    """Recruit or release so that positions [0, m) are recruited."""
    js = hdr(I, i, H_JS)
    pool_advance_to(F, I, i, t)
    forget_eff_f_iso(F, I, i)
    if m > I[js + J_M]:
        pool_recruit(F, I, i, m, x_ce, t)
    elif m < I[js + J_M]:
        pool_release(F, I, i, m, t)


def pool_eff_f_iso_initial(F, I, i, t):
    """[N] Eff.f_iso of the recruited units of a multi muscle with ``length:
    initial``, a function of the instant ``t`` alone:
    from the cache (:func:`forget_eff_f_iso`) if it holds ``t``."""
    js, ip, fs = hdr(I, i, H_JS), hdr(I, i, H_IP), hdr(I, i, H_FS)
    top = I[js + J_RTOP]
    if top == 0:
        return 0.0   # nothing recruited: every sum below is exactly zero
    c = fs + S_CACHE
    for slot in range(3):
        if F[c + slot] == t:
            return F[c + 3 + slot]
    k_types, fatigue = I[ip + I_K], I[ip + I_FATIGUE]
    elapsed = t - F[fs + S_EPOCH]
    f0 = 0.0
    for k in range(k_types):
        w = F[per_type(I, i, H_TP, T_MU_MIN, k)] if fatigue else 1.0
        f0 += w * F[per_sum(I, i, H_RSTATIC, top, k, C_G)]
    if fatigue:
        for k in range(k_types):
            f0 += F[per_sum(I, i, H_RDYN, top, k, C_G)] * math.exp(
                -elapsed * F[per_type(I, i, H_TP, T_RATE_FAT, k)])
    slot = int(F[c + 6])
    F[c + slot] = t
    F[c + 3 + slot] = f0
    F[c + 6] = (slot + 1) % 3
    return f0


def pool_eff_f_iso(F, I, i, x_ce, t):
    """[N] Eff.f_iso of the recruited units."""
    fp, js = hdr(I, i, H_FP), hdr(I, i, H_JS)
    ip, fs = hdr(I, i, H_IP), hdr(I, i, H_FS)
    if I[ip + I_INITIAL]:
        return pool_eff_f_iso_initial(F, I, i, t)
    top = I[js + J_RTOP]
    if top == 0:
        return 0.0   # nothing recruited: every sum below is exactly zero
    k_types, fatigue = I[ip + I_K], I[ip + I_FATIGUE]
    elapsed = t - F[fs + S_EPOCH]
    s = F[fp + P_SPREAD]
    if s > 0.0 and not fl_clear(x_ce, s):
        return pool_eff_f_iso_clipped(F, I, i, x_ce, t)
    if s == 0.0:
        fl = (FL_A * x_ce + FL_B) * x_ce + FL_C
        if fl <= 0.0:
            return 0.0
        a2 = 0.0
        a1 = 0.0
        a0 = fl
    else:
        a2, a1, a0 = FL_A * x_ce * x_ce, FL_B * x_ce, FL_C
    total = 0.0
    for k in range(k_types):
        w = F[per_type(I, i, H_TP, T_MU_MIN, k)] if fatigue else 1.0
        n = F[per_sum(I, i, H_RSTATIC, top, k, C_N)] * w
        c1 = F[per_sum(I, i, H_RSTATIC, top, k, C_C1)] * w
        c2 = F[per_sum(I, i, H_RSTATIC, top, k, C_C2)] * w
        if fatigue:
            d = math.exp(-elapsed * F[per_type(I, i, H_TP, T_RATE_FAT, k)])
            n = n + d * F[per_sum(I, i, H_RDYN, top, k, C_N)]
            c1 = c1 + d * F[per_sum(I, i, H_RDYN, top, k, C_C1)]
            c2 = c2 + d * F[per_sum(I, i, H_RDYN, top, k, C_C2)]
        total += moment_force(F[per_type(I, i, H_TP, T_F_MAX, k)], a2, a1, a0, n, c1, c2)
    return total


def pool_eff_f_iso_clipped(F, I, i, x_ce, t):
    """[N] Eff.f_iso when some units may be off the FL range: segment by segment."""
    fs, js = hdr(I, i, H_FS), hdr(I, i, H_JS)
    ip = hdr(I, i, H_IP)
    k_types, fatigue = I[ip + I_K], I[ip + I_FATIGUE]
    elapsed = t - F[fs + S_EPOCH]
    sums = scratch(I, i, SCR_SUMS)
    r_end, cpos, tpos = hdr(I, i, H_REND), hdr(I, i, H_CPOS), hdr(I, i, H_TPOS)
    total = 0.0
    for seg in range(1, I[js + J_RTOP] + 1):
        for k in range(k_types):
            F[sums + k] = 0.0
        for p in range(I[r_end + seg - 1], I[r_end + seg]):
            F[sums + I[tpos + p]] += force_length(F[cpos + p] * x_ce)
        part = 0.0
        for k in range(k_types):
            mu = 1.0
            if fatigue:
                mu = F[per_type(I, i, H_TP, T_MU_MIN, k)] + F[per_type(I, i, H_REXN, seg, k)] * (
                    math.exp(-elapsed * F[per_type(I, i, H_TP, T_RATE_FAT, k)]))
            part += F[per_type(I, i, H_TP, T_F_MAX, k)] * F[sums + k] * mu
        total += part
    return total


def pool_mean_fitness(F, I, i, t):
    """[-] mean fitness over all N units."""
    fs, js = hdr(I, i, H_FS), hdr(I, i, H_JS)
    ip = hdr(I, i, H_IP)
    if not I[ip + I_FATIGUE]:
        return 1.0
    k_types = I[ip + I_K]
    top, un = I[js + J_RTOP], I[js + J_UN]
    elapsed = t - F[fs + S_EPOCH]
    tired = 0.0
    for k in range(k_types):
        tired += (1.0 - F[per_type(I, i, H_TP, T_MU_MIN, k)]) * F[
            per_sum(I, i, H_RSTATIC, top, k, C_N)]
    for k in range(k_types):
        tired -= F[per_sum(I, i, H_RDYN, top, k, C_N)] * math.exp(
            -elapsed * F[per_type(I, i, H_TP, T_RATE_FAT, k)])
    for k in range(k_types):
        rest = F[per_type(I, i, H_UCUM, un - 1, k)] if un > 0 else 0.0
        tired += rest * math.exp(-elapsed * F[per_type(I, i, H_TP, T_RATE_REC, k)])
    return 1.0 - tired / I[ip + I_N]


# -- the muscle ----------------------------------------------------------------------------------

def eff_f_iso(F, I, i, l, t):
    """[N] Eff.f_iso at CE length ``l`` and instant ``t``."""
    fs, fp, ip = hdr(I, i, H_FS), hdr(I, i, H_FP), hdr(I, i, H_IP)
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
    see :data:`.limb_kernels._INTO_STEP`). Only this small path is inlined:
    inlining the whole :func:`eff_f_iso` at each of its call sites made a cold
    compile of the limb take 4 minutes instead of 26 s.
    """
    ip = hdr(I, i, H_IP)
    if I[ip + I_MULTI] and I[ip + I_INITIAL]:
        return pool_eff_f_iso_initial(F, I, i, t)
    return eff_f_iso(F, I, i, l, t)


def velocity(F, I, i, l, dl, f0):
    """[m/s] d l_CE / dt at F0 = ``f0``."""
    fp, ip = hdr(I, i, H_FP), hdr(I, i, H_IP)
    return fes_velocity(l, dl, f0, F[fp + P_K_SE], F[fp + P_L_REST], F[fp + P_A], F[fp + P_B],
                        F[fp + P_A_ECC], F[fp + P_B_ECC], F[fp + P_F_ISO_MAX],
                        I[ip + I_RELATIVE] != 0)


def rate_at(F, I, i, l, dl, f0):
    """[1/s] the CE's relaxation rate at F0 = ``f0``."""
    fp, ip = hdr(I, i, H_FP), hdr(I, i, H_IP)
    return relaxation_rate(l, dl, f0, F[fp + P_K_SE], F[fp + P_L_REST], F[fp + P_A],
                           F[fp + P_B], F[fp + P_A_ECC], F[fp + P_B_ECC], F[fp + P_F_ISO_MAX],
                           I[ip + I_RELATIVE] != 0)


def stiffness_rate(F, I, i, l, dl, t):
    """[1/s] the CE's relaxation rate."""
    return rate_at(F, I, i, l, dl, eff_f_iso(F, I, i, l, t))


def peak_rate(F, I, i, l, dl, s0, s1):
    """[1/s] the CE's relaxation rate over [s0, s1]."""
    r0 = stiffness_rate(F, I, i, l, dl, s0)
    r1 = stiffness_rate(F, I, i, l, dl, s0 + 0.5 * (s1 - s0))
    r2 = stiffness_rate(F, I, i, l, dl, s1)
    return max(r0, max(r1, r2))


def quasi_force(F, I, i, v, f0):
    """[N] the CE's force moving at ``v`` with F0 = ``f0``."""
    fp, ip = hdr(I, i, H_FP), hdr(I, i, H_IP)
    return quasi_static_force(v, f0, F[fp + P_A], F[fp + P_B],
                              F[fp + P_A_ECC], F[fp + P_B_ECC], F[fp + P_F_ISO_MAX],
                              I[ip + I_RELATIVE] != 0)


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


# -- the plan of a step's recruitment changes ------------------------------------------------

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
        # The next piece of constant delayed command (DelayLine.pieces).
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


# -- one muscle with its MTU length imposed --------------------------------------------------

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
    out[11] = pool_mean_fitness(F, I, i, t) if I[ip + I_MULTI] else F[fs + S_MU]


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


# -- building a bundle ---------------------------------------------------------------------

def delay_capacity(emd_s: float, dt_s: float) -> int:
    """Commands the delay line may hold at once at step ``dt_s``: two a step over
    the delay (one given at a step's start, one at its end), the one in force,
    and one each way for the rounding of the step ends."""
    return 2 * int(math.ceil(emd_s / dt_s)) + 4


def event_capacity(delay_cap: int) -> int:
    """Events a step's plan may hold: each piece (at most one more than the
    pending commands) gives a piece event and up to MAX_EVENTS_PER_PIECE
    recruitments, or a jump, or single's five; one end."""
    return (delay_cap + 1) * (MAX_EVENTS_PER_PIECE + 2) + 1


class FesBundle:
    """The flat state of one or several FES muscles (see the module docstring).

    ``F`` (float64) and ``I`` (int64) hold every muscle's regions
    (:data:`REGIONS`) one after the other; ``I`` starts with a header per
    muscle giving each region's offset. :meth:`view` shows a region as an array.

    :param params: each muscle's parameters (any variant and FES feature)
    :param dt_s: [s] the smallest step the delay lines are sized for;
        :meth:`ensure_delay` grows them for a shorter one
    """

    def __init__(self, params: Sequence[MuscleParams], dt_s: float = 1e-3,
                 pool: 'ScratchPool | None' = None) -> None:
        self.params = list(params)
        cap = max([delay_capacity(p.emd_s, dt_s) for p in self.params], default=4)
        self.cap = cap
        F, I = _fresh_arrays(tuple(self.params), cap)
        if pool is None:
            self.F, self.I = F.copy(), I.copy()
        else:
            kept = _state_ranges(tuple(self.params), cap)
            self.F, self.I = pool.copy(F, kept['F']), pool.copy(I, kept['I'])

    @classmethod
    def _filled(cls, params: tuple, cap: int) -> 'FesBundle':
        """A bundle laid out, filled and reset from scratch (:func:`_fresh_arrays`)."""
        bundle = cls.__new__(cls)
        bundle.params = list(params)
        bundle._build(cap)
        for i, p in enumerate(bundle.params):
            bundle._fill(i, p)
            bundle.reset(i)
        return bundle

    def _sizes(self, i: int) -> tuple:
        p = self.params[i]
        return p.n_units, p.n_fibre_types, self.cap, event_capacity(self.cap)

    def _build(self, cap: int) -> None:
        """Lay out the regions for delay lines of ``cap`` commands (F, I zeroed)."""
        self.cap = cap
        nm = len(self.params)
        offset = {'F': 0, 'I': nm * N_HDR}
        header = np.zeros(nm * N_HDR, dtype=np.int64)
        for i in range(nm):
            n, k, c, e = self._sizes(i)
            for _, h, where, size in REGIONS:
                header[i * N_HDR + h] = offset[where]
                offset[where] += size(n, k, c, e)
            header[i * N_HDR + H_CAPDQ] = c
            header[i * N_HDR + H_CAPEV] = e
            header[i * N_HDR + H_K] = k
            header[i * N_HDR + H_NP1] = n + 1
        self.F = np.zeros(max(offset['F'], 1))
        self.I = np.zeros(offset['I'], dtype=np.int64)
        self.I[:nm * N_HDR] = header

    def view(self, i: int, name: str) -> np.ndarray:
        """Region ``name`` of muscle ``i`` (a writable 1-D view)."""
        for region, h, where, size in REGIONS:
            if region == name:
                start = self.I[i * N_HDR + h]
                return getattr(self, where)[start:start + size(*self._sizes(i))]
        raise KeyError(name)

    def ensure_delay(self, dt_s: float) -> None:
        """Make room in the delay lines for a step of ``dt_s``, keeping the state."""
        cap = max([delay_capacity(p.emd_s, dt_s) for p in self.params], default=4)
        if cap <= self.cap:
            return
        old = {(i, name): self.view(i, name).copy() for i in range(len(self.params))
               for name, *_ in REGIONS}
        old_cap = self.cap
        self._build(cap)
        for (i, name), values in old.items():
            if name in ('dq_t', 'dq_u'):
                js = old[(i, 'js')]
                idx = (js[J_DHEAD] + np.arange(js[J_DCOUNT])) % old_cap
                self.view(i, name)[:len(idx)] = values[idx]
            elif not name.startswith('ev_'):   # the plan is rebuilt every step
                self.view(i, name)[:] = values
        for i in range(len(self.params)):
            self.view(i, 'js')[J_DHEAD] = 0

    def _fill(self, i: int, p: MuscleParams) -> None:
        """The parameters and the unit layout of muscle ``i``."""
        fp, ip = self.view(i, 'fp'), self.view(i, 'ip')
        fp[P_K_SE], fp[P_K_PE] = p.k_se_n_per_m, p.k_pe_n_per_m
        fp[P_L_REST], fp[P_L_OPT] = p.l_rest_m, p.l_opt_m
        fp[P_A], fp[P_B], fp[P_A_ECC], fp[P_B_ECC] = (p.fv_a_n, p.fv_b_m_per_s, p.fv_a_ecc_n,
                                                      p.fv_b_ecc_m_per_s)
        fp[P_F_ISO_MAX] = p.f_iso_max_n
        fp[P_TAU_ACT], fp[P_TAU_DEACT], fp[P_EMD] = p.tau_act_s, p.tau_deact_s, p.emd_s
        fp[P_RELEASE] = 0.5 / p.n_units if p.tau_deact_s > 0.0 else 0.0
        fp[P_SPREAD] = p.unit_length_spread
        rate_fat = [1.0 / v for v in p.per_type('tau_fatigue_s')]
        rate_rec = [1.0 / v for v in p.per_type('tau_recovery_s')]
        fp[P_RENORM_S] = _RENORMALISE_AFTER_TAUS / max(max(rate_fat), max(rate_rec))
        fp[P_MU_MIN0] = p.fatigue_min[0]
        fp[P_RATE_F0], fp[P_RATE_R0] = 1.0 / p.tau_fatigue_s[0], 1.0 / p.tau_recovery_s[0]
        ip[I_MULTI] = p.units == 'multi'
        ip[I_INITIAL] = p.length == 'initial'
        ip[I_RELATIVE] = p.fv_scaling == 'relative'
        ip[I_FATIGUE] = p.fatigue == 'riener'
        ip[I_N] = n = p.n_units
        ip[I_K] = k = p.n_fibre_types
        if p.units != 'multi':
            return
        layout = UnitLayout(p)
        tp = self.view(i, 'tp').reshape(4, k)
        tp[T_F_MAX] = layout.f_max
        tp[T_MU_MIN] = p.per_type('fatigue_min')
        tp[T_RATE_FAT] = rate_fat
        tp[T_RATE_REC] = rate_rec
        types_ = layout.types_of(0, n).astype(np.int64)
        self.view(i, 'tpos')[:] = types_
        prefix = self.view(i, 'prefix').reshape(k, 3, n + 1)
        if layout._prefix is not None:
            prefix[:] = layout._prefix
            self.view(i, 'cpos')[:] = length_scale(np.arange(n), layout.spread)
        else:
            # Blocks of types, no spread: c = 1, every moment is the unit count.
            self.view(i, 'cpos')[:] = 1.0
            for t in range(k):
                prefix[t, :, :] = np.concatenate(([0.0], np.cumsum(types_ == t, dtype=float)))

    def reset(self, i: int) -> None:
        """Muscle ``i`` at rest: no command, every unit fresh and free."""
        p = self.params[i]
        fs, js = self.view(i, 'fs'), self.view(i, 'js')
        fs[:] = 0.0
        fs[S_L] = p.l_rest_m
        fs[S_MU] = 1.0
        fs[S_PIECE:S_PIECE + 4] = (0.0, 0.0, 0.0, 1.0)
        fs[S_LAW:S_LAW + 4] = (0.0, 1.0, 1.0, 0.0)
        fs[S_CACHE:S_CACHE + 3] = math.nan
        js[:] = 0
        js[J_UN] = 1
        for name in ('r_x', 'r_exn', 'r_static', 'r_dyn', 'u_dn', 'u_cum'):
            self.view(i, name)[:] = 0.0
        self.view(i, 'r_end')[0] = 0
        self.view(i, 'u_start')[0] = 0
        self.view(i, 'u_end')[0] = p.n_units

    def outputs(self, i: int, kernels=None) -> np.ndarray:
        """Muscle ``i``'s outputs now (MuscleOutputs' order), by ``kernels``
        (:func:`compiled`; default: this module's plain functions)."""
        out = np.zeros(N_OUT)
        (kernels or _plain()).muscle_outputs(self.F, self.I, i, out)
        return out


def fitness_profile(bundle: FesBundle, i: int) -> np.ndarray:
    """[-] mu of every unit of multi muscle ``i`` along the recruitment order now,
    read off its two segment stacks: O(N), for figures and tests (not a kernel).

    :raises ValueError: for a ``single`` muscle, which has no units of its own
    """
    ip, fs, js = bundle.view(i, 'ip'), bundle.view(i, 'fs'), bundle.view(i, 'js')
    if not ip[I_MULTI]:
        raise ValueError('`fitness_profile` needs `units: multi`, got single')
    n, k = int(ip[I_N]), int(ip[I_K])
    mu = np.ones(n)
    if not ip[I_FATIGUE]:
        return mu
    tp = bundle.view(i, 'tp').reshape(4, k)
    elapsed = fs[S_T] - fs[S_EPOCH]
    d, h = np.exp(-elapsed * tp[T_RATE_FAT]), np.exp(-elapsed * tp[T_RATE_REC])
    types = bundle.view(i, 'tpos')
    r_end, r_exn = bundle.view(i, 'r_end'), bundle.view(i, 'r_exn').reshape(n + 2, k)
    for seg in range(1, js[J_RTOP] + 1):   # segment 0 is the empty sentinel
        p0, p1 = r_end[seg - 1], r_end[seg]
        mu[p0:p1] = (tp[T_MU_MIN] + r_exn[seg] * d)[types[p0:p1]]
    u_start, u_end = bundle.view(i, 'u_start'), bundle.view(i, 'u_end')
    u_dn = bundle.view(i, 'u_dn').reshape(n + 2, k)
    for seg in range(js[J_UN]):
        p0, p1 = u_start[seg], u_end[seg]
        mu[p0:p1] = (1.0 - u_dn[seg] * h)[types[p0:p1]]
    return mu


class ScratchPool(threading.local):
    """Arrays of a run's transient state, handed back after the run and reused
    by the next run of this thread that needs the same shape and dtype.

    A new array of more than glibc's mmap threshold (128 KiB) is mapped fresh
    and every page of it faults on first touch; glibc also returns a freed top
    of the heap to the system. A knee's run takes about 1.1 MB of such state
    (its bundle's ``F`` and ``I``, the timeline), and its page faults were
    0.2-0.4 ms of a 3.2 ms compiled run (by hand: the same process with
    glibc's thresholds raised ran in 2.75 ms). Runs of the same layout
    (``simulate_limb`` again, a fit's or a sweep's runs of one plant's
    muscles) then write into memory already mapped; a step-by-step limb
    (``CompiledLimb``) keeps arrays of its own. One array per shape and dtype
    is kept, per thread (a sweep's threads run at once).
    """

    def __init__(self) -> None:
        self._free: dict = {}

    def copy(self, a: np.ndarray, ranges=None) -> np.ndarray:
        """A copy of ``a``, in a handed-back array of its shape if there is one.

        :param ranges: (start, stop) ranges of the 1-D ``a`` that hold state; in
            a handed-back array only these are copied (the rest is scratch that
            every step writes before it reads). None: all of ``a``.
        """
        out = self._free.pop((a.shape, a.dtype.str), None)
        if out is None:
            return a.copy()
        if ranges is None:
            np.copyto(out, a)
        else:
            for start, stop in ranges:
                out[start:stop] = a[start:stop]
        return out

    def empty(self, shape: tuple, dtype=float) -> np.ndarray:
        """An array of ``shape`` to be written before it is read, handed back or new."""
        out = self._free.pop((tuple(shape), np.dtype(dtype).str), None)
        return np.empty(shape, dtype=dtype) if out is None else out

    def give_back(self, *arrays: np.ndarray) -> None:
        """Hand ``arrays`` back: their owner does not use them any more."""
        for a in arrays:
            self._free[(a.shape, a.dtype.str)] = a


#: Parameter sets whose fresh arrays are kept (:func:`_fresh_arrays`): the
#: muscles of a fit, a sweep's worker or a gym's environments are few.
FRESH_ARRAYS_KEPT = 32


@functools.lru_cache(maxsize=FRESH_ARRAYS_KEPT)
def _fresh_arrays(params: tuple, cap: int) -> tuple:
    """``F`` and ``I`` of a new :class:`FesBundle` of ``params`` (read-only: the
    bundle copies them). Laying out 1000 units (order, types, prefix sums) took
    most of a short compiled run's time: 0.45 of the 0.53 ms a knee's
    simulate_limb spends before its first step (cProfile, by hand)."""
    bundle = FesBundle._filled(params, cap)
    bundle.F.flags.writeable = False
    bundle.I.flags.writeable = False
    return bundle.F, bundle.I


@functools.lru_cache(maxsize=FRESH_ARRAYS_KEPT)
def _state_ranges(params: tuple, cap: int) -> dict:
    """The (start, stop) ranges of ``F`` and ``I`` of a bundle of ``params``
    outside the event tables (``ev_*``): a step plans its events into them
    (``add_event``, counted from J_NEV = 0) before it reads them, so a run's
    arrays taken from a :class:`ScratchPool` need only these copied. The knee's
    event tables are 414 of its 862 KB."""
    F, I = _fresh_arrays(params, cap)
    bundle = FesBundle.__new__(FesBundle)
    bundle.params, bundle.cap, bundle.F, bundle.I = list(params), cap, F, I
    scratch = {'F': [], 'I': []}
    for i in range(len(params)):
        sizes = bundle._sizes(i)
        for name, h, where, size in REGIONS:
            if name.startswith('ev_'):
                start = int(I[i * N_HDR + h])
                scratch[where].append((start, start + size(*sizes)))
    kept = {}
    for where, length in (('F', F.shape[0]), ('I', I.shape[0])):
        ranges, at = [], 0
        for start, stop in sorted(scratch[where]):
            if start > at:
                ranges.append((at, start))
            at = max(at, stop)
        if at < length:
            ranges.append((at, length))
        kept[where] = tuple(ranges)
    return kept


def _plain() -> types.SimpleNamespace:
    """This module's plain functions, as a namespace like :func:`compiled`'s."""
    import sys
    return sys.modules[__name__]


# -- compiling ------------------------------------------------------------------------------

#: The shared equations of other modules, compiled over this module's scope
#: (whose imports include the constants they read), small enough to inline.
_EQUATIONS = ('force_length', 'force_velocity', 'force_velocity_inverse', 'series_force',
              'parallel_force', 'rk4_update', 'activation_at', 'time_to_reach',
              'piece_activation', 'rise_start', 'fitness_at', 'riener_rate', 'riener_limit',
              'fes_velocity', 'quasi_static_force', 'relaxation_rate', 'substep_count',
              'recruited_units', 'fl_clear', 'type_fl_sum', 'moment_force', 'recruited_excess',
              'resting_deficit')
#: This module's functions, callees before callers.
_KERNELS = ('hdr', 'scratch', 'forget_eff_f_iso', 'per_type', 'per_sum', 'moment',
            'delay_push', 'delay_settle', 'pool_static_row', 'pool_push_recruited',
            'pool_clocks', 'pool_advance_to', 'pool_recruit', 'pool_release', 'pool_update',
            'pool_eff_f_iso_clipped', 'pool_eff_f_iso_initial', 'pool_eff_f_iso',
            'pool_mean_fitness', 'eff_f_iso', 'eff_f_iso_inline', 'velocity', 'rate_at',
            'stiffness_rate', 'peak_rate', 'quasi_force', 'single_fatigue', 'begin_interval',
            'end_interval', 'set_activation', 'tau_for', 'set_piece', 'settle_now',
            'give_command', 'add_event', 'group_target', 'plan_events', 'plan_piece', 'plan',
            'apply', 'muscle_rk4', 'muscle_integrate', 'muscle_advance', 'muscle_outputs',
            'muscle_run')
#: The modules whose code the kernels inline: their digest names the cache entries.
_DIGEST_OF = (equations, stimulus, memory, units)
#: The compiled namespace once built (None until then).
_compiled = None




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
    from . import engine   # imports numba lazily
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
    options.update({name: leaf for name in ('hdr', 'scratch', 'forget_eff_f_iso', 'per_type',
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

    _compiled = engine.compile_functions(
        globals(), _EQUATIONS + _KERNELS, digest_of=_DIGEST_OF + (this,),
        signatures={'muscle_run': run_signature, 'add_event': add_event_signature},
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
    r_start = np.ascontiguousarray(r_start, dtype=float)
    dl_end = np.ascontiguousarray(dl_end_m, dtype=float)
    have_end = r_end is not None
    r_end = np.ascontiguousarray(r_end if have_end else r_start, dtype=float)
    out = np.zeros((len(dl_end), N_OUT))
    done = (kernels or _plain()).muscle_run(bundle.F, bundle.I, i, r_start, dl_end,
                                            float(dt_s), r_end, have_end, out)
    if done != len(dl_end):   # delay_capacity bounds the commands pending
        raise RuntimeError(f'the delay line of muscle {i} overflowed at step {done}')
    return out
