"""The muscle's flat state: its layout in two arrays, and the bundle that holds it.

Every function of the engine (:mod:`.kernels`, :mod:`.pool`, the limb's and
the batch's kernels) takes ``F`` (float64) and ``I`` (int64), holding each
muscle's regions (:data:`REGIONS`: parameters, state, unit layout, segment
stacks, delay ring, plan) one after another, with a header per muscle at the
start of ``I`` giving every region's offset, and a muscle index. Two arrays
rather than one per region: a compiled call passes each array's whole
descriptor, and with twenty of them a call cost about 300 ns (measured:
Eff.f_iso of a 50-unit muscle, 307 ns a call with the arrays in a tuple, 53 ns
with these two). :class:`FesBundle` builds them from parameters; a limb's
muscles are muscles 0, 1, ... of one bundle.
"""
from __future__ import annotations

import functools
import math
import threading
from typing import Sequence

import numpy as np

from ..equations import MAX_EVENTS_PER_PIECE
from ..params import PULSED_MODEL, MuscleParams
from ..units import UnitLayout, channel_positions, length_scale


#: Elapsed time over the fastest time constant after which the unit pool's
#: common clocks are renormalised: exp(-500) = 7e-218 stays far from underflow,
#: and stored values divided by it (at most e^500 = 1.4e217) far from overflow.
_RENORMALISE_AFTER_TAUS = 500.0


#: [s] Two instants closer than this are one (the delay line's tolerance). A
#: switch lands at t + emd_s while the step ends are sums of steps: over the
#: emd_s / dt steps between them the sums round by at most a few ulp of t each
#: (about 1e-11 s at t = 1 h), so a switch meant to fall on a step end is
#: within 1e-9 s of it, and no physiological time is that short.
TIME_TOL_S = 1e-9


# Columns of the float parameters ``fp``.
(P_K_SE, P_K_PE, P_L_REST, P_L_OPT, P_A, P_B, P_A_ECC, P_B_ECC, P_F_ISO_MAX, P_TAU_ACT,
 P_TAU_DEACT, P_EMD, P_RELEASE, P_SPREAD, P_RENORM_S, P_MU_MIN0, P_RATE_F0,
 P_RATE_R0, P_TAU_C, P_TAU1, P_TAU2, P_KM, P_R0, P_REL_A) = range(24)


N_FP = 24


#: [s] A ``ding2003`` channel releases its units once it has had no pulse for
#: this long and its activation is below ``release_activation`` (doc/model.md
#: section 10): the time the spec gives, 50 tau_c at the default tau_c.
RELEASE_QUIET_S = 1.0


# Columns of the integer parameters ``ip``. A ``ding2003`` muscle has one
# channel *slot* per channel: a unit pool of its own over the channel's
# territory, laid out after every muscle (I_CH0, I_NCH), marked I_SLOT.
I_MULTI, I_INITIAL, I_RELATIVE, I_FATIGUE, I_N, I_K, I_DING, I_CH0, I_NCH, I_SLOT = range(10)


N_IP = 10


# Rows of the per-type parameters ``tp``.
T_F_MAX, T_MU_MIN, T_RATE_FAT, T_RATE_REC = range(4)


# Columns of the float state ``fs``.
(S_T, S_L, S_DL, S_R, S_CMD, S_F_SINGLE, S_MU, S_V_FREE, S_PIECE, _S1, _S2, _S3, S_LAW,
 _S5, _S6, _S7, S_EPOCH, S_UD, S_CACHE) = range(19)


#: Entries of the cache of Eff.f_iso (multi/initial): instants, values, next slot.
N_CACHE = 2 * 3 + 1


# Columns of a channel slot's float state after the cache (Ding et al. 2003,
# doc/model.md section 10): CN; the pulse sum S = sum R_i exp(-(t - t_i)/tau_c);
# a; the last pulse's instant (-inf before any) and its command u; the
# activation at the four stages of an RK4 step.
# D_NEXT holds a at the end of the RK4 step.
(D_CN, D_SUM, D_A, D_TLAST, D_U, D_STAGE) = range(S_CACHE + N_CACHE, S_CACHE + N_CACHE + 6)
D_NEXT = D_STAGE + 4


N_FS = D_NEXT + 1


# Columns of a channel slot's fatigue clock of one fibre type (region ``clk``,
# 5 per type): recruited units' fitness is mu = alpha(t) z + beta(t), and
# over a piece with the channel's activation held, alpha = alpha0 e^(-lam (t - s0))
# and beta = beta_inf + (beta0 - beta_inf) e^(-lam (t - s0)) (Riener's law).
K_S0, K_ALPHA0, K_BETA0, K_LAM, K_BETA_INF = range(5)


N_CLK = 5


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
 H_DQT, H_DQU, H_EVT, H_EVV, H_SCR, H_CLK,                # in F
 H_IP, H_JS, H_TPOS, H_REND, H_USTART, H_UEND, H_EVA,     # in I
 H_CAPDQ, H_CAPEV, H_K, H_NP1) = range(28)                 # sizes


N_HDR = 28


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
    ('scratch', H_SCR, 'F', lambda n, k, c, e: 10 * k),
    ('clk', H_CLK, 'F', lambda n, k, c, e: N_CLK * k),
    ('ip', H_IP, 'I', lambda n, k, c, e: N_IP),
    ('js', H_JS, 'I', lambda n, k, c, e: N_JS),
    ('tpos', H_TPOS, 'I', lambda n, k, c, e: n),
    ('r_end', H_REND, 'I', lambda n, k, c, e: n + 2),
    ('u_start', H_USTART, 'I', lambda n, k, c, e: n + 2),
    ('u_end', H_UEND, 'I', lambda n, k, c, e: n + 2),
    ('ev_a', H_EVA, 'I', lambda n, k, c, e: e),
)


# Scratch of a pool update, in multiples of K: clocks D and H, resting deficits,
# excesses, a segment's static row (4 K), per-type sums and the fitness floor
# beta (mu_min, or a channel slot's beta(t)).
SCR_D, SCR_H, SCR_DN, SCR_EXN, SCR_ROW, SCR_SUMS, SCR_BETA = 0, 1, 2, 3, 4, 8, 9


def hdr(I, i, h):
    """Header entry ``h`` of muscle ``i`` (an offset or a size)."""
    return I[i * N_HDR + h]


def scratch(I, i, slot):
    """Offset in F of scratch slot ``slot`` (SCR_*) of muscle ``i``."""
    return I[i * N_HDR + H_SCR] + slot * I[i * N_HDR + H_K]


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
        self.slots = _slots(self.params)
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
        bundle.slots = _slots(bundle.params)
        bundle._build(cap)
        for i, p in enumerate(bundle.params):
            bundle._fill(i, p)
        for j, (parent, positions) in enumerate(bundle.slots):
            bundle._fill_slot(len(bundle.params) + j, parent, positions)
        for i in range(len(bundle.params)):
            bundle.reset(i)
        return bundle

    @property
    def n_headers(self) -> int:
        """Muscles and channel slots: the rows of the header."""
        return len(self.params) + len(self.slots)

    def _sizes(self, i: int) -> tuple:
        nm = len(self.params)
        if i >= nm:   # a channel slot: a pool over its territory, no delay line nor plan
            parent, positions = self.slots[i - nm]
            return len(positions), self.params[parent].n_fibre_types, 1, 1
        p = self.params[i]
        return p.n_units, p.n_fibre_types, self.cap, event_capacity(self.cap)

    def _build(self, cap: int) -> None:
        """Lay out the regions for delay lines of ``cap`` commands (F, I zeroed)."""
        self.cap = cap
        nm = self.n_headers
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
        old = {(i, name): self.view(i, name).copy() for i in range(self.n_headers)
               for name, *_ in REGIONS}
        old_cap = self.cap
        self._build(cap)
        for (i, name), values in old.items():
            if i >= len(self.params) and name in ('dq_t', 'dq_u'):
                continue   # a slot's one-entry ring is never used
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
        fp[P_TAU_C], fp[P_TAU1], fp[P_TAU2] = p.ding_tau_c_s, p.ding_tau1_s, p.ding_tau2_s
        fp[P_KM], fp[P_R0] = p.ding_km, p.ding_km + p.ding_r0_offset
        fp[P_REL_A] = p.release_activation
        ip[I_MULTI] = p.units == 'multi'
        ip[I_INITIAL] = p.length == 'initial'
        ip[I_RELATIVE] = p.fv_scaling == 'relative'
        ip[I_FATIGUE] = p.fatigue == 'riener'
        ip[I_N] = n = p.n_units
        ip[I_K] = k = p.n_fibre_types
        ip[I_DING] = p.activation_model == PULSED_MODEL
        if ip[I_DING]:
            ip[I_CH0] = len(self.params) + [parent for parent, _ in self.slots].index(i)
            ip[I_NCH] = p.n_channels
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

    def _fill_slot(self, j: int, parent: int, positions: np.ndarray) -> None:
        """Slot ``j``: the unit pool of one channel of muscle ``parent``, over the
        units at ``positions`` of its recruitment order (ascending): their types,
        length scales and prefix sums, the muscle's parameters."""
        p = self.params[parent]
        self.view(j, 'fp')[:] = self.view(parent, 'fp')
        self.view(j, 'tp')[:] = self.view(parent, 'tp')
        ip = self.view(j, 'ip')
        ip[:] = self.view(parent, 'ip')
        ip[I_N] = n = len(positions)
        ip[I_DING] = ip[I_CH0] = ip[I_NCH] = 0
        ip[I_SLOT] = 1
        k = p.n_fibre_types
        types_ = UnitLayout(p).types_of(0, p.n_units)[positions].astype(np.int64)
        self.view(j, 'tpos')[:] = types_
        c = length_scale(positions, p.unit_length_spread)
        self.view(j, 'cpos')[:] = c
        prefix = self.view(j, 'prefix').reshape(k, 3, n + 1)
        for t in range(k):
            mask = (types_ == t).astype(float)
            prefix[t, 0] = np.concatenate(([0.0], np.cumsum(mask)))
            prefix[t, 1] = np.concatenate(([0.0], np.cumsum(mask * c)))
            prefix[t, 2] = np.concatenate(([0.0], np.cumsum(mask * c * c)))

    def reset(self, i: int) -> None:
        """Muscle ``i`` at rest: no command, every unit fresh and free."""
        nm = len(self.params)
        for j, (parent, _) in enumerate(self.slots):
            if parent == i:
                self._reset_pool(nm + j, self.params[parent])
                fs = self.view(nm + j, 'fs')
                fs[D_TLAST] = -math.inf
        self._reset_pool(i, self.params[i])

    def _reset_pool(self, i: int, p: MuscleParams) -> None:
        """Header row ``i`` (a muscle or a slot) at rest."""
        n = int(self.view(i, 'ip')[I_N])
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
        self.view(i, 'u_end')[0] = n
        clk = self.view(i, 'clk').reshape(-1, N_CLK)
        clk[:, K_S0] = 0.0
        clk[:, K_ALPHA0] = 1.0
        clk[:, K_BETA0] = clk[:, K_BETA_INF] = p.per_type('fatigue_min')
        clk[:, K_LAM] = [1.0 / v for v in p.per_type('tau_fatigue_s')]


def _slots(params: Sequence[MuscleParams]) -> list:
    """The channel slots of ``params``: (muscle index, territory positions) for
    every channel of every ``ding2003`` muscle, in order."""
    return [(i, positions) for i, p in enumerate(params) if p.activation_model == PULSED_MODEL
            for positions in channel_positions(p)]


def fitness_profile(bundle: FesBundle, i: int) -> np.ndarray:
    """[-] mu of every unit of multi muscle ``i`` along the recruitment order now,
    read off its two segment stacks (a ``ding2003`` muscle: each channel's): O(N),
    for figures and tests (not a kernel).

    :raises ValueError: for a ``single`` muscle, which has no units of its own
    """
    ip = bundle.view(i, 'ip')
    if not ip[I_MULTI]:
        raise ValueError('`fitness_profile` needs `units: multi`, got single')
    t = bundle.view(i, 'fs')[S_T]
    if not ip[I_DING]:
        return _pool_profile(bundle, i, t)
    mu = np.ones(int(ip[I_N]))
    nm = len(bundle.params)
    for j, (parent, positions) in enumerate(bundle.slots):
        if parent == i:
            mu[positions] = _pool_profile(bundle, nm + j, t)
    return mu


def _pool_profile(bundle: FesBundle, i: int, t: float) -> np.ndarray:
    """[-] mu along the positions of pool ``i`` (a muscle or a slot) at ``t``."""
    ip, fs, js = bundle.view(i, 'ip'), bundle.view(i, 'fs'), bundle.view(i, 'js')
    n, k = int(ip[I_N]), int(ip[I_K])
    mu = np.ones(n)
    if not ip[I_FATIGUE]:
        return mu
    tp = bundle.view(i, 'tp').reshape(4, k)
    elapsed = t - fs[S_EPOCH]
    h = np.exp(-elapsed * tp[T_RATE_REC])
    if ip[I_SLOT]:
        clk = bundle.view(i, 'clk').reshape(k, N_CLK)
        e = np.exp(-(t - clk[:, K_S0]) * clk[:, K_LAM])
        d = clk[:, K_ALPHA0] * e
        beta = clk[:, K_BETA_INF] + (clk[:, K_BETA0] - clk[:, K_BETA_INF]) * e
    else:
        d, beta = np.exp(-elapsed * tp[T_RATE_FAT]), tp[T_MU_MIN]
    types = bundle.view(i, 'tpos')
    r_end, r_exn = bundle.view(i, 'r_end'), bundle.view(i, 'r_exn').reshape(n + 2, k)
    for seg in range(1, js[J_RTOP] + 1):   # segment 0 is the empty sentinel
        p0, p1 = r_end[seg - 1], r_end[seg]
        mu[p0:p1] = (beta + r_exn[seg] * d)[types[p0:p1]]
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
    bundle.slots = _slots(bundle.params)
    scratch = {'F': [], 'I': []}
    for i in range(bundle.n_headers):
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
