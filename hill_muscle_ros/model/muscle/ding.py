"""The channels of a ``ding2003`` muscle on the flat state: pulses, Ding's
activation per channel and its frequency-dependent fatigue (doc/model.md
section 10), plain functions for numba and Python.

Each channel c is a *slot* of the bundle (:mod:`.state`): a unit pool of its
own (:mod:`.pool`) over its territory, with the states of Ding et al. 2003,
normalised: CN, the pulse sum S = sum R_i exp(-(t - t_i) / tau_c) and
a = F / (A (tau1 + tau2)). The muscle's isometric force is
sum_c a_c(t) Eff.f_iso_c(l_CE, t).

Between pulses CN and S have closed forms (:func:`~.equations.ding_cn_at`);
a follows Ding's force law, integrated by the same classical RK4 step as
l_CE and coupled to it: :func:`ding_stages` gives a at the four stages of
the step, at which the CE's RK4 reads Eff.f_iso (``stage`` 0-3). A pulse
jumps S by R_i and sets the channel's recruited units, at its own instant.

Fatigue: a recruited unit of channel c follows Riener's law with a = a_c(t),
mu' = -lambda(a_c) mu + q(a_c): every recruited unit of the channel (and
type) sees the same affine flow, mu(t) = alpha(t) z + beta(t), which the
pool reads from the slot's clock (:func:`~.pool.fatigue_alpha`).
:func:`ding_clocks` sets that clock over each RK4 step with a_c held at its
mean over the step (its change over 1 ms is tiny against T_fat), so the
cost stays O(K) per channel and step, whatever N.
"""
from __future__ import annotations

import math

from ..equations import ding_cn_at, ding_pulse_weight, ding_rate, riener_limit, riener_rate
from ..memory import recruited_units
from .pool import (fatigue_alpha, fatigue_beta, forget_eff_f_iso, per_type, pool_advance_to,
                   pool_eff_f_iso, pool_mean_fitness, pool_update)
from .state import (D_A, D_CN, D_NEXT, D_STAGE, D_SUM, D_TLAST, D_U, H_CLK, H_FP, H_FS, H_IP,
                    H_JS, H_TP, I_CH0, I_FATIGUE, I_K, I_N, I_NCH, J_NREC, K_ALPHA0, K_BETA0,
                    K_BETA_INF, K_LAM, K_S0, N_CLK, P_KM, P_L_OPT, P_R0, P_REL_A, P_TAU1,
                    P_TAU2, P_TAU_C, RELEASE_QUIET_S, S_CMD, S_L, S_R, T_MU_MIN, T_RATE_FAT,
                    T_RATE_REC, hdr)


def ding_slot(I, i, c):
    """Header row of channel ``c`` (0-based) of muscle ``i``."""
    return I[hdr(I, i, H_IP) + I_CH0] + c


def ding_f_iso(F, I, i, l, t, stage):
    """[N] Eff.f_iso of a ding2003 muscle at CE length ``l`` and instant ``t``:
    sum_c a_c Eff.f_iso_c, a_c at RK4 stage ``stage`` (0-3), now (-1), or 1
    (4: the bound the force cannot reach, a < 1)."""
    ip, fp = hdr(I, i, H_IP), hdr(I, i, H_FP)
    x = l / F[fp + P_L_OPT]
    total = 0.0
    for c in range(I[ip + I_NCH]):
        j = ding_slot(I, i, c)
        fs = hdr(I, j, H_FS)
        if stage < 0:
            a = F[fs + D_A]
        elif stage < 4:
            a = F[fs + D_STAGE + stage]
        else:
            a = 1.0
        if a > 0.0:
            total += a * pool_eff_f_iso(F, I, j, x, t)
    return total


def ding_stages(F, I, i, h):
    """a of every channel at the four stages of an RK4 step of ``h`` (D_STAGE),
    and at its end (D_NEXT), CN from its closed form at the stage times."""
    ip, fp = hdr(I, i, H_IP), hdr(I, i, H_FP)
    tau_c, km = F[fp + P_TAU_C], F[fp + P_KM]
    tau1, tau2 = F[fp + P_TAU1], F[fp + P_TAU2]
    for c in range(I[ip + I_NCH]):
        fs = hdr(I, ding_slot(I, i, c), H_FS)
        cn0, s0, a0 = F[fs + D_CN], F[fs + D_SUM], F[fs + D_A]
        if cn0 == 0.0 and s0 == 0.0 and a0 == 0.0:   # never stimulated: a stays 0
            for k in range(4):
                F[fs + D_STAGE + k] = 0.0
            F[fs + D_NEXT] = 0.0
            continue
        cn_mid = ding_cn_at(cn0, s0, tau_c, 0.5 * h)
        cn_end = ding_cn_at(cn0, s0, tau_c, h)
        k1 = ding_rate(cn0, a0, km, tau1, tau2)
        a2 = a0 + 0.5 * h * k1
        k2 = ding_rate(cn_mid, a2, km, tau1, tau2)
        a3 = a0 + 0.5 * h * k2
        k3 = ding_rate(cn_mid, a3, km, tau1, tau2)
        a4 = a0 + h * k3
        k4 = ding_rate(cn_end, a4, km, tau1, tau2)
        F[fs + D_STAGE] = a0
        F[fs + D_STAGE + 1] = a2
        F[fs + D_STAGE + 2] = a3
        F[fs + D_STAGE + 3] = a4
        F[fs + D_NEXT] = a0 + h / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)


def ding_commit(F, I, i, h):
    """Every channel's CN, S and a at the end of the RK4 step of ``h`` (after
    :func:`ding_stages`)."""
    ip, fp = hdr(I, i, H_IP), hdr(I, i, H_FP)
    tau_c = F[fp + P_TAU_C]
    for c in range(I[ip + I_NCH]):
        fs = hdr(I, ding_slot(I, i, c), H_FS)
        F[fs + D_CN] = ding_cn_at(F[fs + D_CN], F[fs + D_SUM], tau_c, h)
        F[fs + D_SUM] = F[fs + D_SUM] * math.exp(-h / tau_c)
        F[fs + D_A] = F[fs + D_NEXT]


def ding_clocks(F, I, i, s0):
    """Each fatigued channel's fitness clock from ``s0`` over the RK4 step of
    :func:`ding_stages`: Riener's law with a_c held at its mean over the step."""
    ip = hdr(I, i, H_IP)
    if not I[ip + I_FATIGUE]:
        return
    for c in range(I[ip + I_NCH]):
        j = ding_slot(I, i, c)
        fs = hdr(I, j, H_FS)
        a = 0.5 * (F[fs + D_STAGE] + F[fs + D_NEXT])
        forget_eff_f_iso(F, I, j)
        for k in range(I[hdr(I, j, H_IP) + I_K]):
            clk = hdr(I, j, H_CLK) + k * N_CLK
            alpha = fatigue_alpha(F, I, j, k, s0)
            beta = fatigue_beta(F, I, j, k, s0)
            rate_f = F[per_type(I, j, H_TP, T_RATE_FAT, k)]
            rate_r = F[per_type(I, j, H_TP, T_RATE_REC, k)]
            lam = riener_rate(a, rate_f, rate_r)
            F[clk + K_S0] = s0
            F[clk + K_ALPHA0] = alpha
            F[clk + K_BETA0] = beta
            F[clk + K_LAM] = lam
            F[clk + K_BETA_INF] = riener_limit(a, F[per_type(I, j, H_TP, T_MU_MIN, k)], rate_f,
                                               rate_r, lam)


def ding_totals(F, I, i):
    """The muscle's recruited units M, R = M / N and the command (the units its
    channels' last pulses asked for, over N) from its channels."""
    ip, fs, js = hdr(I, i, H_IP), hdr(I, i, H_FS), hdr(I, i, H_JS)
    m = 0
    asked = 0.0
    for c in range(I[ip + I_NCH]):
        j = ding_slot(I, i, c)
        m += I[hdr(I, j, H_JS) + J_NREC]
        asked += F[hdr(I, j, H_FS) + D_U] * I[hdr(I, j, H_IP) + I_N]
    I[js + J_NREC] = m
    F[fs + S_R] = m / I[ip + I_N]
    F[fs + S_CMD] = asked / I[ip + I_N]


def ding_pulse(F, I, i, c, u, t):
    """A pulse on channel ``c`` at ``t`` (the channels' states already at ``t``)
    asking for the fraction ``u`` of its territory: S jumps by R_i, and the
    channel's recruited units become the first floor(N_c u + 0.5) of its
    territory (LIFO), new ones storing the CE length now."""
    fp, fs = hdr(I, i, H_FP), hdr(I, i, H_FS)
    j = ding_slot(I, i, c)
    fs_j = hdr(I, j, H_FS)
    F[fs_j + D_SUM] += ding_pulse_weight(t - F[fs_j + D_TLAST], F[fp + P_R0], F[fp + P_TAU_C])
    F[fs_j + D_TLAST] = t
    F[fs_j + D_U] = u
    m = recruited_units(u, I[hdr(I, j, H_IP) + I_N])
    pool_update(F, I, j, m, F[fs + S_L] / F[fp + P_L_OPT], t)
    I[hdr(I, j, H_JS) + J_NREC] = m
    ding_totals(F, I, i)


def ding_settle(F, I, i, t):
    """At the end of a step at ``t``: release the units of every channel with no
    pulse for RELEASE_QUIET_S and a below ``release_activation``, and renormalise
    the fatigue clocks when due."""
    ip, fp, fs = hdr(I, i, H_IP), hdr(I, i, H_FP), hdr(I, i, H_FS)
    for c in range(I[ip + I_NCH]):
        j = ding_slot(I, i, c)
        fs_j = hdr(I, j, H_FS)
        if (I[hdr(I, j, H_JS) + J_NREC] > 0 and t - F[fs_j + D_TLAST] >= RELEASE_QUIET_S
                and F[fs_j + D_A] < F[fp + P_REL_A]):
            pool_update(F, I, j, 0, F[fs + S_L] / F[fp + P_L_OPT], t)
            I[hdr(I, j, H_JS) + J_NREC] = 0
            F[fs_j + D_U] = 0.0
        pool_advance_to(F, I, j, t)
    ding_totals(F, I, i)


def ding_mean_fitness(F, I, i, t):
    """[-] mean fitness over all N units of a ding2003 muscle."""
    ip = hdr(I, i, H_IP)
    total = 0.0
    for c in range(I[ip + I_NCH]):
        j = ding_slot(I, i, c)
        total += pool_mean_fitness(F, I, j, t) * I[hdr(I, j, H_IP) + I_N]
    return total / I[ip + I_N]


def ding_activation(F, I, i, out):
    """Each channel's a now into ``out`` (C,)."""
    ip = hdr(I, i, H_IP)
    for c in range(I[ip + I_NCH]):
        out[c] = F[hdr(I, ding_slot(I, i, c), H_FS) + D_A]
