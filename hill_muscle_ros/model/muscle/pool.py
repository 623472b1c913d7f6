"""The unit pool of a ``multi`` muscle on the flat state: recruitment memory and
per-unit fatigue (doc/model.md sections 2 and 7.3), plain functions for numba
and Python.

Units recruited and released at the same instants share their whole history,
so they share their fitness. The units along the recruitment order are split
into segments of one history each: the recruited prefix [0, M) is a stack of
segments (each also stores the CE length at which it was recruited), the
resting suffix [M, N) another. Every recruited segment's excess fitness
mu - mu_min decays by the same factor exp(-dt / T_fat) in a step, and every
resting segment's deficit 1 - mu by exp(-dt / T_rec): so each is stored
divided by a common clock, and the totals over a stack are static running
sums, read at any instant in O(1) per fibre type without rounding drift. A
recruitment change moves the segments between the stacks it spans and splits
at most one. Cost: O(K) per evaluation for K fibre types; O(K) per segment a
change spans.
"""
from __future__ import annotations

import math


from ..equations import (FL_A, FL_B, FL_C, force_length, moment_force, recruited_excess,
                         resting_deficit)
from ..units import fl_clear, type_fl_sum
from .state import (C_C1, C_C2, C_G, C_N, H_CLK, H_CPOS, H_FP, H_FS, H_IP, H_JS, H_K, H_NP1,
                    H_PREFIX, H_RDYN, H_REND, H_REXN, H_RSTATIC, H_RX, H_TP, H_TPOS, H_UCUM,
                    H_UDN, H_UEND, H_USTART, I_FATIGUE, I_INITIAL, I_K, I_N, I_SLOT, J_M,
                    J_RTOP, J_UN, K_ALPHA0, K_BETA0, K_BETA_INF, K_LAM, K_S0, N_CLK, N_HDR,
                    P_RENORM_S, P_SPREAD, SCR_BETA, SCR_D, SCR_DN, SCR_EXN, SCR_H, SCR_ROW,
                    SCR_SUMS, S_CACHE, S_EPOCH, T_F_MAX, T_MU_MIN, T_RATE_FAT, T_RATE_REC, hdr,
                    scratch)


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


def fatigue_alpha(F, I, i, k, t):
    """[-] alpha_k(t): the factor by which recruited units of type ``k`` keep their
    stored excess, mu = beta + alpha z. Recruited units of a level-driven muscle
    tire at a = 1, alpha = D_k(t) = exp(-(t - epoch) / T_fat); a channel slot's
    follow its activation a_c piece by piece (its clock, ``clk``)."""
    if I[hdr(I, i, H_IP) + I_SLOT]:
        c = hdr(I, i, H_CLK) + k * N_CLK
        return F[c + K_ALPHA0] * math.exp(-(t - F[c + K_S0]) * F[c + K_LAM])
    return math.exp(-(t - F[hdr(I, i, H_FS) + S_EPOCH]) * F[per_type(I, i, H_TP, T_RATE_FAT, k)])


def fatigue_beta(F, I, i, k, t):
    """[-] beta_k(t), the fitness a recruited unit of type ``k`` with z = 0 has:
    mu_min at a = 1; a channel slot's from its clock (:func:`fatigue_alpha`)."""
    if I[hdr(I, i, H_IP) + I_SLOT]:
        c = hdr(I, i, H_CLK) + k * N_CLK
        e = math.exp(-(t - F[c + K_S0]) * F[c + K_LAM])
        return F[c + K_BETA_INF] + (F[c + K_BETA0] - F[c + K_BETA_INF]) * e
    return F[per_type(I, i, H_TP, T_MU_MIN, k)]


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
    """D_k(t) and H_k(t), the fatigue and recovery clocks, into F at ``d`` and
    ``h``, and beta_k(t) into the scratch (SCR_BETA)."""
    fs, ip = hdr(I, i, H_FS), hdr(I, i, H_IP)
    elapsed = t - F[fs + S_EPOCH]
    beta = scratch(I, i, SCR_BETA)
    for k in range(I[ip + I_K]):
        F[d + k] = fatigue_alpha(F, I, i, k, t)
        F[h + k] = math.exp(-elapsed * F[per_type(I, i, H_TP, T_RATE_REC, k)])
        F[beta + k] = fatigue_beta(F, I, i, k, t)


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
    if I[ip + I_SLOT]:   # alpha is 1 from now on, beta goes on from its value now
        beta = scratch(I, i, SCR_BETA)
        for k in range(k_types):
            c = hdr(I, i, H_CLK) + k * N_CLK
            F[c + K_S0] = t
            F[c + K_ALPHA0] = 1.0
            F[c + K_BETA0] = F[beta + k]


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
            beta = scratch(I, i, SCR_BETA)
            for k in range(k_types):
                F[exn + k] = recruited_excess(F[dn + k], F[h + k], F[beta + k], F[d + k])
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
        beta = scratch(I, i, SCR_BETA)
        for k in range(k_types):
            dn_k = resting_deficit(F[exn + k], F[d + k], F[beta + k], F[h + k])
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
    f0 = 0.0
    for k in range(k_types):
        w = fatigue_beta(F, I, i, k, t) if fatigue else 1.0
        f0 += w * F[per_sum(I, i, H_RSTATIC, top, k, C_G)]
    if fatigue:
        for k in range(k_types):
            f0 += F[per_sum(I, i, H_RDYN, top, k, C_G)] * fatigue_alpha(F, I, i, k, t)
    slot = int(F[c + 6])
    F[c + slot] = t
    F[c + 3 + slot] = f0
    F[c + 6] = (slot + 1) % 3
    return f0


def pool_eff_f_iso(F, I, i, x_ce, t):
    """[N] Eff.f_iso of the recruited units."""
    fp, js = hdr(I, i, H_FP), hdr(I, i, H_JS)
    ip = hdr(I, i, H_IP)
    if I[ip + I_INITIAL]:
        return pool_eff_f_iso_initial(F, I, i, t)
    top = I[js + J_RTOP]
    if top == 0:
        return 0.0   # nothing recruited: every sum below is exactly zero
    k_types, fatigue = I[ip + I_K], I[ip + I_FATIGUE]
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
        w = fatigue_beta(F, I, i, k, t) if fatigue else 1.0
        n = F[per_sum(I, i, H_RSTATIC, top, k, C_N)] * w
        c1 = F[per_sum(I, i, H_RSTATIC, top, k, C_C1)] * w
        c2 = F[per_sum(I, i, H_RSTATIC, top, k, C_C2)] * w
        if fatigue:
            d = fatigue_alpha(F, I, i, k, t)
            n = n + d * F[per_sum(I, i, H_RDYN, top, k, C_N)]
            c1 = c1 + d * F[per_sum(I, i, H_RDYN, top, k, C_C1)]
            c2 = c2 + d * F[per_sum(I, i, H_RDYN, top, k, C_C2)]
        total += moment_force(F[per_type(I, i, H_TP, T_F_MAX, k)], a2, a1, a0, n, c1, c2)
    return total


def pool_eff_f_iso_clipped(F, I, i, x_ce, t):
    """[N] Eff.f_iso when some units may be off the FL range: segment by segment."""
    js = hdr(I, i, H_JS)
    ip = hdr(I, i, H_IP)
    k_types, fatigue = I[ip + I_K], I[ip + I_FATIGUE]
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
                mu = fatigue_beta(F, I, i, k, t) + F[per_type(I, i, H_REXN, seg, k)] * (
                    fatigue_alpha(F, I, i, k, t))
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
        tired += (1.0 - fatigue_beta(F, I, i, k, t)) * F[per_sum(I, i, H_RSTATIC, top, k, C_N)]
    for k in range(k_types):
        tired -= F[per_sum(I, i, H_RDYN, top, k, C_N)] * fatigue_alpha(F, I, i, k, t)
    for k in range(k_types):
        rest = F[per_type(I, i, H_UCUM, un - 1, k)] if un > 0 else 0.0
        tired += rest * math.exp(-elapsed * F[per_type(I, i, H_TP, T_RATE_REC, k)])
    return 1.0 - tired / I[ip + I_N]
