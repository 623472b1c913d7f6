"""The step of a ``ding2003`` muscle: the CE and every channel's activation
integrated together, the step split at each pulse (doc/model.md section 10).

The same RK4 as the level-driven muscle's (:mod:`.kernels`), with the CE's
isometric force read at the stages of the channels' activations
(:func:`.ding.ding_stages`); a pulse acts at its own instant, not at a step
end. :func:`.kernels.ding_run` runs it step by step, and compiles it with
the rest (:func:`.kernels.compiled`).
"""
from __future__ import annotations

from ..equations import QUASI_STATIC_RATE_PER_S, rk4_update, substep_count
from .ding import ding_clocks, ding_commit, ding_f_iso, ding_pulse, ding_settle, ding_stages
from .ce import quasi_force, rate_at, velocity
from .state import H_FP, H_FS, P_K_SE, P_L_REST, S_DL, S_L, S_T, S_V_FREE, hdr


def ding_rk4(F, I, i, s0, s1, t0, dl0, rate):
    """One RK4 step of l_CE and every channel's a over [s0, s1], no pulse inside."""
    fs, fp = hdr(I, i, H_FS), hdr(I, i, H_FP)
    h = s1 - s0
    ding_stages(F, I, i, h)
    ding_clocks(F, I, i, s0)
    l = F[fs + S_L]
    dl_a = dl0 + rate * (s0 - t0)
    dl_b = dl0 + rate * (s1 - t0)
    f0 = ding_f_iso(F, I, i, l, s0, 0)
    f0_end = ding_f_iso(F, I, i, l, s1, 3)
    if f0 > 0.0 or f0_end > 0.0:
        mid, dl_m = s0 + 0.5 * h, 0.5 * (dl_a + dl_b)
        k1 = velocity(F, I, i, l, dl_a, f0)
        l2 = l + 0.5 * h * k1
        k2 = velocity(F, I, i, l2, dl_m, ding_f_iso(F, I, i, l2, mid, 1))
        l3 = l + 0.5 * h * k2
        k3 = velocity(F, I, i, l3, dl_m, ding_f_iso(F, I, i, l3, mid, 2))
        l4 = l + h * k3
        k4 = velocity(F, I, i, l4, dl_b, ding_f_iso(F, I, i, l4, s1, 3))
        l = rk4_update(l, h, k1, k2, k3, k4)
    else:
        l = F[fp + P_L_REST] + dl_b   # the free CE takes up the SE slack
    ding_commit(F, I, i, h)
    if ding_f_iso(F, I, i, l, s1, -1) == 0.0:
        l = F[fp + P_L_REST] + dl_b   # no recruited unit holds the CE in the FL range
    F[fs + S_L] = l


def ding_integrate(F, I, i, s0, s1, t0, dl0, rate):
    """l_CE and the channels' a over [s0, s1], no pulse inside: RK4 steps
    bounded by the CE's relaxation rate, or quasi-static where it is stiff."""
    fs, fp = hdr(I, i, H_FS), hdr(I, i, H_FP)
    h = s1 - s0
    if h <= 0.0:
        return
    l = F[fs + S_L]
    dl_a = dl0 + rate * (s0 - t0)
    dl_b = dl0 + rate * (s1 - t0)
    # The CE's relaxation rate over the step, bounded at both ends of the
    # force's range: the activations now, and a = 1 (a < 1 always), at both
    # ends of the ramp.
    f_now = ding_f_iso(F, I, i, l, s0, -1)
    f_top = ding_f_iso(F, I, i, l, s0, 4)
    peak = max(max(rate_at(F, I, i, l, dl_a, f_now), rate_at(F, I, i, l, dl_b, f_now)),
               max(rate_at(F, I, i, l, dl_a, f_top), rate_at(F, I, i, l, dl_b, f_top)))
    if peak >= QUASI_STATIC_RATE_PER_S:
        ding_stages(F, I, i, h)
        ding_clocks(F, I, i, s0)
        ding_commit(F, I, i, h)
        f = quasi_force(F, I, i, rate, ding_f_iso(F, I, i, l, s1, -1))
        F[fs + S_L] = F[fp + P_L_REST] + dl_b - f / F[fp + P_K_SE]
        return
    n = substep_count(h, peak)
    for j in range(n):
        a = s0 + h * j / n
        b = s1 if j == n - 1 else s0 + h * (j + 1) / n
        ding_rk4(F, I, i, a, b, t0, dl0, rate)


def ding_advance(F, I, i, pt, pc, pu, j0, j1, dl1, dt):
    """One step of ``dt``, dl_MT ramping to ``dl1``, with the pulses j0..j1-1 of
    (``pt`` [s] time, ``pc`` 0-based channel, ``pu`` [-] command u), each
    acting at its own instant within the step."""
    fs = hdr(I, i, H_FS)
    t0, dl0 = F[fs + S_T], F[fs + S_DL]
    t1 = t0 + dt
    rate = (dl1 - dl0) / dt
    s = t0
    for j in range(j0, j1):
        tp = min(max(pt[j], s), t1)
        ding_integrate(F, I, i, s, tp, t0, dl0, rate)
        ding_pulse(F, I, i, pc[j], pu[j], tp)
        free_if_idle(F, I, i, tp, dl0 + rate * (tp - t0))
        s = tp
    ding_integrate(F, I, i, s, t1, t0, dl0, rate)
    F[fs + S_V_FREE] = rate
    F[fs + S_DL] = dl1
    F[fs + S_T] = t1
    ding_settle(F, I, i, t1)
    free_if_idle(F, I, i, t1, dl1)


def free_if_idle(F, I, i, t, dl):
    """A CE with no isometric force left at ``t`` (its units released by a pulse
    or by the quiet channel's release) is free at once: it takes up the SE's
    slack, l_CE = l_rest + dl_MT, and the tendon carries nothing."""
    fs, fp = hdr(I, i, H_FS), hdr(I, i, H_FP)
    if ding_f_iso(F, I, i, F[fs + S_L], t, -1) == 0.0:
        F[fs + S_L] = F[fp + P_L_REST] + dl
