"""The model's step as plain scalar functions, for Python and numba: the batch
and the single muscle's offline run.

:class:`~hill_muscle_ros.model.batch.MuscleBatch`'s compiled engine runs
:func:`step_all` compiled by numba; the same functions run unchanged as plain
Python (slowly: they are for the tests, not for use). They are written once:
the curves are those of :mod:`.equations` (Eq. 1, the springs, Eq. 3 inverted)
and the integrator is the RK4 step of :meth:`Muscle.step
<hill_muscle_ros.model.muscle.Muscle.step>` (recruitment held, MTU length
ramping linearly, the free CE when Eff.f_iso = 0; doc/model.md section 4).

:func:`run_muscle` is :meth:`Muscle.run
<hill_muscle_ros.model.muscle.Muscle.run>`'s loop over a whole protocol for
one muscle of the paper's model, built from the same :func:`step_one` and
:func:`recruit_one`; :func:`run_compiled` runs it compiled on a ``Muscle``
(``simulate`` does where that pays: :func:`.engine.use_compiled`).

:func:`compiled` (the batch's kernels) and :func:`compiled_run` (the run)
build the numba versions through :func:`.engine.compile_functions`: numba is
imported there and only there, so importing this module (or the package)
never loads it. Each function is compiled from its own code object with the
names it calls bound to their compiled versions, and cached on disk, so only
the first process compiles. numba's cache notices a change of this file but
not of :mod:`.equations` or :mod:`.memory`, which the kernels inline: so the
kernels' cache entries carry a digest of ``equations.py`` and ``memory.py`` in
their names, and an edited curve or stack compiles anew.

:func:`recruit_all` is the recruitment bookkeeping (M, gains, the run stacks
of ``multi``/``initial`` muscles through :func:`.memory.stack_update`, the
code :class:`~hill_muscle_ros.model.memory.UnitMemory` runs): :func:`recruit_one`
in one serial loop touching only the muscles whose R changed.

Threads: :func:`step_all` runs its loop over muscles on numba's threads
(``numba.set_num_threads``, ``NUMBA_NUM_THREADS``; all cores by default) when
the batch has at least :data:`PARALLEL_MIN_K` muscles. On cores busy with
other work a second thread gains nothing (BENCHMARKS.md section 3): set one
thread there. The OpenMP layer's threads wait passively
(``OMP_WAIT_POLICY=PASSIVE`` unless set: :func:`.engine.import_numba`), since spinning
ones made things far worse on busy cores. numba's ``workqueue`` threading
layer aborts the process if two Python threads launch a loop at once, so
launches are serialised by :data:`LAUNCH_LOCK`.
"""
from __future__ import annotations

import threading
import types

from . import engine, equations, memory
from .equations import force_length, force_velocity_inverse, parallel_force, series_force
from .memory import recruited_units, stack_update

#: The loop over muscles; the compiled build binds this name to ``numba.prange``.
prange = range

#: Serialises launches of the parallel loop (see the module docstring).
LAUNCH_LOCK = threading.Lock()

#: [-] smallest K whose loop runs on every numba thread; smaller batches run
#: on the calling thread alone. Measured on the 2-core VM of BENCHMARKS.md (the
#: kernel alone, one thread against two, OpenMP threads waiting passively):
#: 130 us against 130-140 us a step at K = 10,000, 385 against 260 us at
#: 30,000, 1.35 against 0.74 ms at 100,000; waking the second thread costs
#: about what it saves at 10,000.
PARALLEL_MIN_K = 20_000

#: Rows of the parameter matrix of :func:`step_all`, one per muscle parameter
#: it needs.
P_K_SE, P_K_PE, P_L_REST, P_L_OPT, P_A, P_B, P_A_ECC, P_B_ECC = range(8)
N_PARAMS = 8

#: Rows of the output matrix of :func:`step_all`.
(OUT_L_CE, OUT_V_CE, OUT_EFF_F_ISO, OUT_V_FREE, OUT_F_SE, OUT_F_PE,
 OUT_FORCE) = range(7)
N_OUTPUTS = 7


def eff_f_iso(l_ce_m: float, gain_n: float, l_opt_m: float, initial: bool) -> float:
    """[N] Eff.f_iso from the recruitment's gain (see ``Muscle._gain_n``).

    :param l_ce_m: [m] CE length (l_CE), used by the instantaneous variants
    :param gain_n: [N] Eff.f_iso (initial) or Eff.f_iso / FL (instantaneous)
    :param l_opt_m: [m] CE optimal length (l_opt)
    :param initial: True for the ``initial`` length variants
    """
    if initial:
        return gain_n
    # x = l_CE (1 / l_opt): the step takes FL seven times at one l_opt, and
    # LLVM computes the reciprocal once where it would divide seven times (the
    # batch of four mixed variants: 8 % a step). Every engine of the paper's
    # model takes x so, since at the ends of the FL range one rounding of x
    # decides whether the CE is free.
    return gain_n * force_length(l_ce_m * (1.0 / l_opt_m))


def ce_velocity(l_ce_m: float, dl_mt_m: float, f0_n: float, k_se: float, l_rest_m: float,
                a: float, b: float, a_ecc: float, b_ecc: float) -> float:
    """[m/s] d l_CE / dt = FV_inv(f_SE, F0): Eq. 3 inverted at the tendon force.

    :param l_ce_m: [m] CE length (l_CE)
    :param dl_mt_m: [m] MTU length change from rest (dl_MT)
    :param f0_n: [N] Eff.f_iso (F0)
    :param k_se: [N/m] SE stiffness; the rest as :func:`.force_velocity_inverse`
    """
    return force_velocity_inverse(series_force(k_se, dl_mt_m, l_ce_m, l_rest_m), f0_n,
                                  a, b, a_ecc, b_ecc)


def step_one(l0: float, dl0: float, dl1: float, dt: float, gain: float, k1_prev: float,
             have_k1: bool, initial: bool, k_se: float, l_rest: float, l_opt: float,
             a: float, b: float, a_ecc: float, b_ecc: float) -> tuple:
    """One muscle's step with the recruitment already applied: what
    :meth:`MuscleBatch.step <hill_muscle_ros.model.batch.MuscleBatch.step>` does
    to each muscle after its recruitment bookkeeping.

    Every muscle takes the same operations: the cases (released CE, free CE,
    RK4) are chosen by conditional expressions after computing both sides,
    not by branches around the RK4 stages, so that LLVM vectorises the loop
    over muscles (measured: about 3x faster than the same step with
    branches). With Eff.f_iso = 0 the unused RK4 stages are finite (Eq. 3
    inverted gives 0 there), so computing them is harmless.

    :param l0: [m] CE length at the start (l_CE)
    :param dl0: [m] dl_MT at the start
    :param dl1: [m] dl_MT at the end
    :param dt: [s] step length
    :param gain: [N] the recruitment's gain (see :func:`eff_f_iso`)
    :param k1_prev: [m/s] v_CE at the end of the last step, the first RK4 stage
        if ``have_k1`` (recruitment unchanged since)
    :param initial: True for the ``initial`` length variants
    :param k_se: [N/m] SE stiffness (k_SE)
    :param l_rest: [m] CE length at rest (l_rest)
    :param l_opt: [m] CE optimal length (l_opt)
    :param a: [N] concentric Hill constant (a)
    :param b: [m/s] concentric Hill constant (b)
    :param a_ecc: [N] eccentric constant (a')
    :param b_ecc: [m/s] eccentric constant (b')
    :return: ([m] l_CE, [m/s] v_CE, [N] Eff.f_iso, [m/s] v of the free CE) at the end
    """
    f0 = eff_f_iso(l0, gain, l_opt, initial)
    # Released (nothing recruited, or outside the FL range): the free CE takes
    # up the slack at once, as MuscleBatch.set_recruitment does.
    l0 = l_rest + dl0 if f0 == 0.0 else l0
    f0 = eff_f_iso(l0, gain, l_opt, initial)
    l_free = l_rest + dl1
    k1 = k1_prev if have_k1 else ce_velocity(l0, dl0, f0, k_se, l_rest, a, b, a_ecc, b_ecc)
    half_dt = 0.5 * dt
    dl_mid = 0.5 * (dl0 + dl1)
    # Each stage's SE force k_SE (dl - (l0 + h k - l_rest)), written as
    # k_SE (dl - (l0 - l_rest)) - k_SE h k: the first term is a constant of
    # the step, so a stage waits on the last one's k for a multiply and a
    # subtraction only (one muscle's compiled run, Protocol II: 254 -> 213 us).
    # Every engine's stages are written so. (Below zero the SE is slack, as
    # series_force's zero: Eq. 3 inverted takes the same branch.)
    from_rest = l0 - l_rest
    f_mid = k_se * (dl_mid - from_rest)
    f_end = k_se * (dl1 - from_rest)
    c_half = k_se * half_dt
    c_full = k_se * dt
    l = l0 + half_dt * k1
    k2 = force_velocity_inverse(f_mid - c_half * k1, eff_f_iso(l, gain, l_opt, initial),
                                a, b, a_ecc, b_ecc)
    l = l0 + half_dt * k2
    k3 = force_velocity_inverse(f_mid - c_half * k2, eff_f_iso(l, gain, l_opt, initial),
                                a, b, a_ecc, b_ecc)
    l = l0 + dt * k3
    k4 = force_velocity_inverse(f_end - c_full * k3, eff_f_iso(l, gain, l_opt, initial),
                                a, b, a_ecc, b_ecc)
    # h / 6 before the stages' sum: the division leaves the chain of the four
    # stages, each waiting on the last (one muscle's compiled run, Protocol II:
    # 0.0406 -> 0.036-0.037 us a step). Every engine's RK4 update is written so.
    l1 = l0 + dt / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
    l1 = l1 if f0 > 0.0 else l_free
    f0 = eff_f_iso(l1, gain, l_opt, initial)
    # The instantaneous CE left the FL range within the step: the free CE,
    # whose Eff.f_iso is read at its new length (back inside the range, maybe).
    l1 = l_free if f0 == 0.0 else l1
    f0 = eff_f_iso(l1, gain, l_opt, initial)
    v_free = (dl1 - dl0) / dt
    v1 = ce_velocity(l1, dl1, f0, k_se, l_rest, a, b, a_ecc, b_ecc)
    v1 = v1 if f0 > 0.0 else v_free
    return l1, v1, f0, v_free


def step_muscle(i: int, l0, dl0, dl1, dt: float, gain, k1_prev, have_k1: bool,
                initial: bool, params, out) -> None:
    """Step muscle ``i`` of the arrays (:func:`step_one`) and write its outputs
    (the arguments as :func:`step_all`'s; ``initial`` is this muscle's)."""
    k_se, l_rest, d1 = params[P_K_SE, i], params[P_L_REST, i], dl1[i]
    l1, v1, f0, v_free = step_one(
        l0[i], dl0[i], d1, dt, gain[i], k1_prev[i], have_k1, initial, k_se, l_rest,
        params[P_L_OPT, i], params[P_A, i], params[P_B, i], params[P_A_ECC, i],
        params[P_B_ECC, i])
    f_se = series_force(k_se, d1, l1, l_rest)
    f_pe = parallel_force(params[P_K_PE, i], d1)
    out[OUT_L_CE, i] = l1
    out[OUT_V_CE, i] = v1
    out[OUT_EFF_F_ISO, i] = f0
    out[OUT_V_FREE, i] = v_free
    out[OUT_F_SE, i] = f_se
    out[OUT_F_PE, i] = f_pe
    out[OUT_FORCE, i] = f_se + f_pe


def step_all(l0, dl0, dl1, dt: float, gain, k1_prev, have_k1: bool, initial,
             all_initial: bool, params, out, parallel: bool) -> None:
    """Step every muscle (:func:`step_one`) and write its outputs.

    :param l0: [m] (K,) CE lengths at the start
    :param dl0: [m] (K,) dl_MT at the start
    :param dl1: [m] (K,) dl_MT at the end
    :param dt: [s] step length
    :param gain: [N] (K,) the recruitments' gains
    :param k1_prev: [m/s] (K,) v_CE at the end of the last step
    :param have_k1: True if ``k1_prev`` is the first RK4 stage of every muscle
    :param initial: (K,) bool, True for the ``initial`` length variants
    :param all_initial: True if every muscle is an ``initial`` one: the loop
        where that is a constant leaves FL out (vectorised, both variants are
        evaluated for every muscle otherwise)
    :param params: (N_PARAMS, K) parameters, one row per ``P_*`` index (rows,
        not columns: contiguous per parameter, as the vector loop loads them)
    :param out: (N_OUTPUTS, K) written: l_CE [m], v_CE [m/s], Eff.f_iso [N],
        v of the free CE [m/s], f_SE [N], f_PE [N], force [N]
    :param parallel: True to run the loop over muscles on numba's threads,
        False on the calling thread alone (see :data:`PARALLEL_MIN_K`)
    """
    # The serial loops are plain loops of this function, not a parallel loop
    # on one thread: numba.set_num_threads around each call cost 15 us a step
    # of 10,000 muscles (about 200 us in all).
    if parallel and all_initial:
        for i in prange(l0.shape[0]):
            step_muscle(i, l0, dl0, dl1, dt, gain, k1_prev, have_k1, True, params, out)
    elif parallel:
        for i in prange(l0.shape[0]):
            step_muscle(i, l0, dl0, dl1, dt, gain, k1_prev, have_k1, initial[i], params, out)
    elif all_initial:
        for i in range(l0.shape[0]):
            step_muscle(i, l0, dl0, dl1, dt, gain, k1_prev, have_k1, True, params, out)
    else:
        for i in range(l0.shape[0]):
            step_muscle(i, l0, dl0, dl1, dt, gain, k1_prev, have_k1, initial[i], params, out)


def recruit_one(r_new: float, r_old: float, f_iso_single: float, l_ce: float, multi: bool,
                initial: bool, n_units: float, f_iso_max: float, l_opt: float, count, f_unit,
                total, base: int, top: int) -> tuple:
    """Apply a new recruitment level to one muscle: the bookkeeping of
    ``Muscle._apply_recruitment`` (M, the gain, the force at recruitment of a
    ``single``/``initial`` muscle, the run stack of a ``multi``/``initial``
    one through :func:`.memory.stack_update`).

    :param r_new: [-] the new recruitment level, validated, != ``r_old``
    :param r_old: [-] the recruitment in force
    :param f_iso_single: [N] single/initial: f_iso at recruitment so far
    :param l_ce: [m] CE length now (l_CE)
    :param multi: True for a ``multi`` muscle
    :param initial: True for an ``initial`` muscle
    :param n_units: [-] N as a float
    :param f_iso_max: [N] f_iso_max
    :param l_opt: [m] l_opt
    :param count: [-] int64 the run stack's cumulative unit counts (multi/initial)
    :param f_unit: [N] the run stack's forces per unit
    :param total: [N] the run stack's cumulative forces
    :param base: index of the muscle's sentinel in the three stack arrays
    :param top: [-] runs on the stack now
    :return: ([-] M, [N] gain, [N] f_iso at recruitment, [-] runs on the stack)
    """
    if multi:
        m = recruited_units(r_new, n_units)
        if initial:
            top = stack_update(count, f_unit, total, base, top, m, l_ce, f_iso_max / n_units,
                               l_opt)
            g = total[base + top]
        else:
            g = m / n_units * f_iso_max
    else:
        m = 1 if r_new > 0.0 else 0
        if initial:
            # Remember FL at the length where R rose from zero.
            if r_new == 0.0:
                f_iso_single = 0.0
            elif r_old == 0.0:
                f_iso_single = f_iso_max * force_length(l_ce / l_opt)
            g = r_new * f_iso_single
        else:
            g = r_new * f_iso_max
    return m, g, f_iso_single, top


def recruit_all(r, r_now, n_recruited, gain, f_iso_single, l_ce, multi, initial, n_units,
                f_iso_max, l_opt, stack_base, stack_top, count, f_unit, total) -> int:
    """Apply new recruitment levels: the bookkeeping of the muscles whose R changed.

    What :meth:`MuscleBatch._apply_recruitment
    <hill_muscle_ros.model.batch.MuscleBatch._apply_recruitment>` does on the
    NumPy engine: :func:`recruit_one` for each muscle whose R changed.

    :param r: [-] (K,) validated new recruitment levels
    :param r_now: [-] (K,) recruitment in force; updated
    :param n_recruited: [-] (K,) int64 M per muscle; updated
    :param gain: [N] (K,) the gains; updated
    :param f_iso_single: [N] (K,) single/initial: f_iso at recruitment; updated
    :param l_ce: [m] (K,) CE lengths now (l_CE)
    :param multi: (K,) bool, True for ``multi`` muscles
    :param initial: (K,) bool, True for ``initial`` muscles
    :param n_units: [-] (K,) N as floats
    :param f_iso_max: [N] (K,) f_iso_max
    :param l_opt: [m] (K,) l_opt
    :param stack_base: (K,) int64 index of each multi/initial muscle's sentinel
        in ``count``, ``f_unit``, ``total`` (N + 1 entries each; unused for others)
    :param stack_top: (K,) int64 runs on each stack; updated
    :param count: [-] int64 the stacks' cumulative unit counts
    :param f_unit: [N] the stacks' forces per unit
    :param total: [N] the stacks' cumulative forces
    :return: the number of muscles whose R changed
    """
    n_changed = 0
    for i in range(r.shape[0]):
        r_new = r[i]
        if r_new == r_now[i]:
            continue
        n_changed += 1
        m, g, f_single, top = recruit_one(r_new, r_now[i], f_iso_single[i], l_ce[i], multi[i],
                                          initial[i], n_units[i], f_iso_max[i], l_opt[i],
                                          count, f_unit, total, stack_base[i], stack_top[i])
        f_iso_single[i] = f_single
        stack_top[i] = top
        r_now[i] = r_new
        n_recruited[i] = m
        gain[i] = g
    return n_changed


#: Entries of the state vector of :func:`run_muscle`: what ``Muscle.run``
#: reads from and writes back to the muscle (M as a float).
(S_T, S_L_CE, S_DL_MT, S_V_FREE, S_R, S_M, S_GAIN, S_F_ISO_SINGLE, S_V_CE) = range(9)
N_STATE = 9
#: Rows of the output matrix of :func:`run_muscle`: the fields of
#: :class:`~hill_muscle_ros.model.muscle.MuscleOutputs`, in their order.
(RUN_T, RUN_R, RUN_M, RUN_DL_MT, RUN_L_CE, RUN_V_CE, RUN_F_SE, RUN_F_PE, RUN_FORCE,
 RUN_EFF_F_ISO, RUN_COMMAND, RUN_FITNESS) = range(12)
N_RUN_OUTPUTS = 12


def run_muscle(r_start, dl_end, r_end, dt: float, state, top: int, multi: bool,
               initial: bool, n_units: float, f_iso_max: float, params, count, f_unit, total,
               out, first: int) -> int:
    """``Muscle.run`` of one muscle of the paper's model over whole input sequences.

    Step k: apply ``r_start[k]`` (:func:`recruit_one` at the CE length of that
    instant), integrate (:func:`step_one`), apply ``r_end[k]`` (a release
    frees the CE at once), write the outputs. Sequenced as ``Muscle.run``:
    Eff.f_iso is read off the state after every change of the CE length, so
    a CE freed after leaving the FL range (instantaneous variants) resists
    again if its free length is back inside the range.

    :param r_start: [-] (n,) R held over each step, validated
    :param dl_end: [m] (n,) dl_MT at the end of each step, validated
    :param r_end: [-] (n,) R applied after each step, validated
    :param dt: [s] step length
    :param state: (N_STATE,) the muscle's state at the start, ``S_*`` entries;
        updated to the state at the end (``S_V_CE``: v_CE there)
    :param top: [-] runs on the run stack now (multi/initial)
    :param multi: True for a ``multi`` muscle
    :param initial: True for an ``initial`` muscle
    :param n_units: [-] N as a float
    :param f_iso_max: [N] f_iso_max
    :param params: (N_PARAMS,) the parameters, one per ``P_*`` index
    :param count: [-] int64 the run stack's cumulative unit counts, N + 1
        entries for a multi/initial muscle (sentinel first), updated
    :param f_unit: [N] the run stack's forces per unit, updated
    :param total: [N] the run stack's cumulative forces, updated
    :param out: (N_RUN_OUTPUTS, first + n) or wider, written: row ``RUN_*`` of
        step k at column ``first + k``
    :param first: column of the first step's outputs in ``out``
    :return: [-] runs on the run stack at the end
    """
    k_se, k_pe, l_rest, l_opt = params[P_K_SE], params[P_K_PE], params[P_L_REST], params[P_L_OPT]
    a, b, a_ecc, b_ecc = params[P_A], params[P_B], params[P_A_ECC], params[P_B_ECC]
    t = state[S_T]
    l = state[S_L_CE]
    dl0 = state[S_DL_MT]
    v_free = state[S_V_FREE]
    r_now = state[S_R]
    m_now = int(state[S_M])
    gain = state[S_GAIN]
    f_single = state[S_F_ISO_SINGLE]
    # f0 and v: the outputs at the current instant; v is also the first RK4
    # stage of the next step while R is held (the same state, the same inputs).
    f0 = eff_f_iso(l, gain, l_opt, initial)
    v = ce_velocity(l, dl0, f0, k_se, l_rest, a, b, a_ecc, b_ecc) if f0 > 0.0 else v_free
    for k in range(dl_end.shape[0]):
        dl1 = dl_end[k]
        r = r_start[k]
        if r != r_now:
            m_now, gain, f_single, top = recruit_one(r, r_now, f_single, l, multi, initial,
                                                     n_units, f_iso_max, l_opt, count, f_unit,
                                                     total, 0, top)
            r_now = r
            f0 = eff_f_iso(l, gain, l_opt, initial)
            if f0 > 0.0:
                v = ce_velocity(l, dl0, f0, k_se, l_rest, a, b, a_ecc, b_ecc)
        if f0 > 0.0:
            l, v, f0, v_free = step_one(l, dl0, dl1, dt, gain, v, True, initial, k_se, l_rest,
                                        l_opt, a, b, a_ecc, b_ecc)
        else:
            # The free CE, without recruited force (gain 0) over the step, as
            # Muscle.run; then Eff.f_iso at its new length.
            l, v, f0, v_free = step_one(l, dl0, dl1, dt, 0.0, v, False, initial, k_se,
                                        l_rest, l_opt, a, b, a_ecc, b_ecc)
            f0 = eff_f_iso(l, gain, l_opt, initial)
            if f0 > 0.0:
                v = ce_velocity(l, dl1, f0, k_se, l_rest, a, b, a_ecc, b_ecc)
        r = r_end[k]
        if r != r_now:
            m_now, gain, f_single, top = recruit_one(r, r_now, f_single, l, multi, initial,
                                                     n_units, f_iso_max, l_opt, count, f_unit,
                                                     total, 0, top)
            r_now = r
            f0 = eff_f_iso(l, gain, l_opt, initial)
            if f0 == 0.0:
                # Released at this instant: the free CE takes up the slack at
                # once, so the sample shows f_SE = 0 (as Muscle.run).
                l = l_rest + dl1
                f0 = eff_f_iso(l, gain, l_opt, initial)   # read off the state
            v = ce_velocity(l, dl1, f0, k_se, l_rest, a, b, a_ecc, b_ecc) if f0 > 0.0 else v_free
        dl0 = dl1
        t += dt
        f_se = series_force(k_se, dl1, l, l_rest)
        f_pe = parallel_force(k_pe, dl1)
        j = first + k
        out[RUN_T, j] = t
        out[RUN_R, j] = r_now
        out[RUN_M, j] = m_now
        out[RUN_DL_MT, j] = dl1
        out[RUN_L_CE, j] = l
        out[RUN_V_CE, j] = v
        out[RUN_F_SE, j] = f_se
        out[RUN_F_PE, j] = f_pe
        out[RUN_FORCE, j] = f_se + f_pe
        out[RUN_EFF_F_ISO, j] = f0
        out[RUN_COMMAND, j] = r_now
        out[RUN_FITNESS, j] = 1.0   # no fatigue in the paper's model
    state[S_T] = t
    state[S_L_CE] = l
    state[S_DL_MT] = dl0
    state[S_V_FREE] = v_free
    state[S_R] = r_now
    state[S_M] = m_now
    state[S_GAIN] = gain
    state[S_F_ISO_SINGLE] = f_single
    state[S_V_CE] = v
    return top


def scan_inputs(r, dl1, r_now, dl_limit_m: float) -> tuple:
    """Check a step's inputs and compare R with the one in force, in one pass.

    Counts, so that the loop has no early exit and vectorises; the caller
    looks for the first culprit only when a count is not zero.

    :param r: [-] (K,) recruitment of the step
    :param dl1: [m] (K,) dl_MT at the end of the step
    :param r_now: [-] (K,) recruitment in force
    :param dl_limit_m: [m] largest |dl_MT| accepted
    :return: muscles with dl_MT out of range or NaN, with R outside [0, 1] or
        NaN, and with R different from ``r_now``
    """
    n_bad_dl = 0
    n_bad_r = 0
    n_changed = 0
    for i in range(r.shape[0]):
        n_bad_dl += not (-dl_limit_m <= dl1[i] <= dl_limit_m)   # NaN too
        n_bad_r += not (0.0 <= r[i] <= 1.0)
        n_changed += r[i] != r_now[i]
    return n_bad_dl, n_bad_r, n_changed


def launch(kernels: types.SimpleNamespace, parallel: bool, *args) -> None:
    """Call the compiled :func:`step_all` on all numba threads or on the calling one.

    :param kernels: the compiled kernels (:func:`compiled`)
    :param parallel: False to run on the calling thread only, e.g. for a
        small batch (numba's number of threads is left as it is either way)
    :param args: the arguments of :func:`step_all` but ``parallel``
    """
    if not parallel:
        kernels.step_all(*args, False)
        return
    with LAUNCH_LOCK:
        kernels.step_all(*args, True)


#: The functions :func:`compiled` compiles: helpers of other modules, then
#: this module's, callees before callers.
_CURVES = (force_length, force_velocity_inverse, series_force, parallel_force)
_KERNELS = ('eff_f_iso', 'ce_velocity', 'step_one', 'step_muscle', 'step_all',
            'scan_inputs', 'recruited_units', 'stack_update', 'recruit_one', 'recruit_all')
#: The compiled namespace once built (None until then).
_compiled = None


#: Helpers called from many places (eff_f_iso 12 times, ce_velocity 9, counting
#: step_one's calls in each of its callers) compiled once each, not inlined by
#: numba (engine.HELPER_OPTIONS): numba's inlining types and lowers the body
#: again at every call, which made these kernels' cold compile about 2.5 times
#: as long (CPU seconds, benchmarks/compile_cost.py). LLVM still inlines them.
_CALLED_OFTEN = {'eff_f_iso': {'error_model': 'numpy'}, 'ce_velocity': {'error_model': 'numpy'}}


def _step_all_signature(numba):
    f8, c1, c2 = numba.float64, numba.float64[::1], numba.float64[:, ::1]
    return numba.void(c1, c1, c1, f8, c1, c1, numba.boolean, numba.boolean[::1],
                      numba.boolean, c2, c2, numba.boolean)


def _scan_inputs_signature(numba):
    c1 = numba.float64[::1]
    return numba.types.UniTuple(numba.int64, 3)(c1, c1, c1, numba.float64)


def _recruit_all_signature(numba):
    c1, i1, b1 = numba.float64[::1], numba.int64[::1], numba.boolean[::1]
    return numba.int64(c1, c1, i1, c1, c1, c1, b1, b1, c1, c1, c1, i1, i1, i1, c1, c1)


#: numba's ``parallel`` option for :func:`step_all`: its loops over muscles run
#: on the threads (prange), and nothing else is looked for, as the kernel has
#: no array expression, reduction or comprehension to turn into parallel
#: loops. Compiling it cold took 13.0 s against 15.5 s with ``parallel=True``
#: (6.4 s serial), and it runs as fast: a step of 10,000 multi/initial muscles
#: (MuscleBatch.step, 200 steps, 5 repeats) took 99-105 us against 99-113 us.
#: (Those were measured with the helpers inlined by numba; with
#: :data:`_CALLED_OFTEN` the whole batch set compiles in about 4 s,
#: BENCHMARKS.md "Compiling the kernels".)
PRANGE_ONLY = {'prange': True, 'fusion': False, 'comprehension': False, 'setitem': False,
               'reduction': False, 'numpy': False, 'stencil': False, 'inplace_binop': False}


def compiled() -> types.SimpleNamespace:
    """The numba-compiled kernels of the batch: ``step_all`` (parallel over muscles) and the rest.

    Imports numba on the first call (:func:`.engine.import_numba`) and compiles
    ``step_all``, ``scan_inputs`` and ``recruit_all`` with their signatures, or
    loads them from numba's on-disk cache (BENCHMARKS.md section 3 gives both
    costs); the cache names carry a digest of ``equations.py`` and ``memory.py``.

    :raises ImportError: if numba cannot be imported
    """
    global _compiled
    if _compiled is None:
        # The kernels themselves take the checks of numba's default error model
        # where they are not the vector loop; see engine.HELPER_OPTIONS.
        _compiled = engine.compile_functions(
            globals(), _KERNELS, foreign=_CURVES, digest_of=(equations, memory),
            signatures={'step_all': _step_all_signature,
                        'scan_inputs': _scan_inputs_signature,
                        'recruit_all': _recruit_all_signature},
            options={'step_all': {'error_model': 'numpy', 'parallel': PRANGE_ONLY},
                     'scan_inputs': {},
                     'recruit_all': {'error_model': 'numpy'}, **_CALLED_OFTEN},
            bind={'prange': lambda numba: numba.prange})
    return _compiled


#: The functions :func:`compiled_run` compiles (only ``run_muscle`` with its
#: signature: a process loads one function from the cache).
_RUN_KERNELS = ('eff_f_iso', 'ce_velocity', 'step_one', 'recruited_units', 'stack_update',
                'recruit_one', 'run_muscle')
#: The compiled run once built (None until then).
_compiled_run = None

#: [-] steps of one run from which ``simulate`` loads the compiled run when it
#: is not loaded yet (``HILL_MUSCLE_ENGINE=auto``, :func:`.engine.use_compiled`).
#: Measured (BENCHMARKS.md, bench_compiled.py): loading costs about 0.85 s with
#: a warm cache (import numba 0.4 s; numba's set-up on its first call 0.45 s,
#: of which 0.2 s is scipy.linalg, which numba imports), and the compiled run
#: saves 1.0-1.8 us a step against the Python loop (R held mostly / changing
#: every step), so loading pays from about 470,000-850,000 steps; from 500,000
#: (8 min 20 s at 1 kHz) a long run never loses much either way.
RUN_MIN_STEPS = 500_000


def run_loaded() -> bool:
    """True if the compiled run is built in this process (:func:`compiled_run`)."""
    return _compiled_run is not None


def _run_muscle_signature(numba):
    f8, c1, i1 = numba.float64, numba.float64[::1], numba.int64[::1]
    return numba.int64(c1, c1, c1, f8, c1, numba.int64, numba.boolean, numba.boolean, f8, f8,
                       c1, i1, c1, c1, numba.float64[:, ::1], numba.int64)


def compiled_run() -> types.SimpleNamespace:
    """The numba-compiled :func:`run_muscle` (and its helpers), built on first use.

    Only ``run_muscle`` is compiled with a signature, so a process with a warm
    cache loads one function (BENCHMARKS.md gives the cost of both cases).

    :raises ImportError: if numba cannot be imported
    """
    global _compiled_run
    if _compiled_run is None:
        _compiled_run = engine.compile_functions(
            globals(), _RUN_KERNELS, foreign=_CURVES, digest_of=(equations, memory),
            signatures={'run_muscle': _run_muscle_signature},
            options={'run_muscle': {'error_model': 'numpy'}, **_CALLED_OFTEN})
    return _compiled_run


def run_compiled(muscle, r_start, dl_mt_end_m, dt_s: float, r_end=None, out=None,
                 first: int = 0):
    """:meth:`Muscle.run <hill_muscle_ros.model.muscle.Muscle.run>` compiled:
    the same steps, the same state afterwards, the outputs as one array.

    For the paper's model only (a plain ``Muscle``, every FES extension off).
    Inputs are not validated, as ``Muscle.run``'s.

    :param muscle: the :class:`~hill_muscle_ros.model.muscle.Muscle`; its
        state and memory are read here and written back
    :param r_start: [-] (n,) recruitment R held over each step
    :param dl_mt_end_m: [m] (n,) dl_MT at the end of each step
    :param dt_s: [s] step length, > 0
    :param r_end: [-] (n,) R applied after each step (default ``r_start``)
    :param out: (N_RUN_OUTPUTS, first + n) C-contiguous float array to write
        into (a new one of (N_RUN_OUTPUTS, n) if omitted)
    :param first: column of the first step's outputs in ``out``
    :return: ``out``: row ``RUN_*`` (the fields of ``MuscleOutputs`` in their
        order) of step k at column ``first + k``
    """
    import numpy as np   # the model's arrays; numpy is imported with the package anyway

    run = compiled_run().run_muscle
    p = muscle.params
    r_start = np.ascontiguousarray(r_start, dtype=float)
    dl_end = np.ascontiguousarray(dl_mt_end_m, dtype=float)
    r_end = r_start if r_end is None else np.ascontiguousarray(r_end, dtype=float)
    state = np.empty(N_STATE)
    state[S_T], state[S_L_CE], state[S_DL_MT] = muscle.t_s, muscle.l_ce_m, muscle.dl_mt_m
    state[S_V_FREE], state[S_R], state[S_M] = muscle._v_free, muscle.recruitment, muscle.n_recruited
    state[S_GAIN], state[S_F_ISO_SINGLE] = muscle._gain_n, muscle._f_iso_single_n
    params = np.empty(N_PARAMS)
    params[P_K_SE], params[P_K_PE] = p.k_se_n_per_m, p.k_pe_n_per_m
    params[P_L_REST], params[P_L_OPT] = p.l_rest_m, p.l_opt_m
    params[P_A], params[P_B] = p.fv_a_n, p.fv_b_m_per_s
    params[P_A_ECC], params[P_B_ECC] = p.fv_a_ecc_n, p.fv_b_ecc_m_per_s
    # The run stack (multi/initial): UnitMemory's lists, copied into arrays
    # of N + 1 entries (room for every push) and back.
    mem = muscle._memory
    stacked = muscle._multi and muscle._initial
    size = p.n_units + 1 if stacked else 1
    top = mem._top
    count = np.zeros(size, dtype=np.int64)
    f_unit = np.zeros(size)
    total = np.zeros(size)
    if stacked:
        count[:top + 1] = mem._count[:top + 1]
        f_unit[:top + 1] = mem._f_unit[:top + 1]
        total[:top + 1] = mem._total[:top + 1]
    if out is None:
        out = np.empty((N_RUN_OUTPUTS, dl_end.shape[0]))
    elif not (out.shape[0] == N_RUN_OUTPUTS and out.shape[1] >= first + dl_end.shape[0]):
        raise ValueError(f'`out` must have shape ({N_RUN_OUTPUTS}, >= {first + dl_end.shape[0]}), '
                         f'got {out.shape}')
    top = run(r_start, dl_end, r_end, float(dt_s), state, top, muscle._multi, muscle._initial,
              float(p.n_units), p.f_iso_max_n, params, count, f_unit, total, out, first)
    if stacked:
        mem._count = count[:top + 1].tolist()
        mem._f_unit = f_unit[:top + 1].tolist()
        mem._total = total[:top + 1].tolist()
        mem._top = top
    muscle.t_s, muscle.l_ce_m, muscle.dl_mt_m = float(state[S_T]), float(state[S_L_CE]), \
        float(state[S_DL_MT])
    muscle._v_free, muscle.recruitment = float(state[S_V_FREE]), float(state[S_R])
    muscle.n_recruited = int(state[S_M])
    muscle._gain_n, muscle._f_iso_single_n = float(state[S_GAIN]), float(state[S_F_ISO_SINGLE])
    muscle._v_end = (muscle.l_ce_m, muscle.dl_mt_m, muscle._gain_n, float(state[S_V_CE]))
    return out
