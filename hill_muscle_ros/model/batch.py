"""Many independent muscles stepped at once: compiled with numba, or NumPy arrays.

For parameter sweeps and controller tuning: K muscles, each with its own
:class:`~hill_muscle_ros.model.params.MuscleParams` (the four variants may be
mixed) and its own inputs, advance together by one step of the same length.
Each muscle follows exactly the step of :meth:`Muscle.step
<hill_muscle_ros.model.muscle.Muscle.step>` (RK4, recruitment held, MTU
length ramping linearly, the free CE when Eff.f_iso = 0); the tests check the
two agree to 1e-9 N.

Two engines, chosen by ``MuscleBatch(params, engine=...)``:

- ``'numpy'``, the reference: the integration is a fixed number of
  whole-array operations a step, so it scales with K, not with the number of
  units.
- ``'compiled'``: the per-muscle step of :mod:`.kernels` (scalar functions on
  the curves of :mod:`.equations`), compiled by numba into one loop over the
  muscles, vectorised and run on numba's threads for large K; several times
  faster than NumPy at K = 10,000 (BENCHMARKS.md section 3). numba is imported
  when the first compiled batch is built, never with the package; the kernel
  is compiled once and cached on disk. It agrees with the NumPy engine and with
  separate muscles to 1e-9 N (test/test_batch_compiled.py).

The default, ``'auto'``, is the compiled engine if numba can be imported and
the NumPy engine otherwise (or if ``HILL_MUSCLE_ENGINE=python``: :mod:`.engine`),
with the same results; :attr:`MuscleBatch.engine`
says which one runs.

The motor-unit memory of ``multi``/``initial`` muscles is a per-muscle LIFO
stack of runs, touched only for the muscles whose recruitment changed in that
step; its push and pop are one function,
:func:`~hill_muscle_ros.model.memory.stack_update`. The NumPy engine keeps
one :class:`~hill_muscle_ros.model.memory.UnitMemory` per such muscle (Python
lists grown on demand); the compiled engine runs the whole recruitment
bookkeeping in :func:`~hill_muscle_ros.model.kernels.recruit_all` over flat
arrays holding N + 1 runs for each such muscle only, and none for ``single``
or ``instantaneous`` ones: 24 bytes a unit, 240 MB for 10,000 muscles of 1000
units (measured: all of it resident once every stack was pushed, since NumPy
backs large arrays with huge pages where the kernel allows).

Muscles with any FES extension switched on (delay, activation, fatigue, fibre
types, unit lengths: doc/model.md section 7) are stepped as their own
:class:`~hill_muscle_ros.model.fes_muscle.FesMuscle` steps: on the NumPy
engine by one FesMuscle each, the scalar reference; on the compiled engine all
at once by :mod:`.fes_batch_kernels` over one
:class:`~hill_muscle_ros.model.fes_kernels.FesBundle`, the compiled FES muscle
(same results to 1e-9 N, test/test_batch_fes_compiled.py). The arrays of state
and outputs cover every muscle alike.
"""
from __future__ import annotations

import math
from typing import NamedTuple, Sequence

import numpy as np

from . import engine as engines
from . import fes_batch_kernels, fes_kernels, kernels
from .equations import ECC_PLATEAU, FL_A, FL_B, FL_C
from .fes_muscle import FesMuscle
from .memory import UnitMemory
from .muscle import DL_MT_LIMIT_M
from .params import MuscleParams, check_instances
from .substeps import MAX_SUBSTEP_S, substeps_for

#: Rounding offset of M = floor(N R + 0.5) (doc/model.md section 2).
_ROUND_HALF = 0.5

#: Values of ``MuscleBatch(engine=...)``.
ENGINES = ('auto', 'compiled', 'numpy')

#: [s] the step the compiled engine's FES delay lines are first sized for
#: (FesBundle's default); a shorter step, or a delay line found full, grows them.
_FES_DELAY_DT_S = 1e-3


class BatchOutputs(NamedTuple):
    """Outputs of K muscles at one instant; arrays of shape (K,), all SI.

    Same fields and units as :class:`~hill_muscle_ros.model.muscle.MuscleOutputs`.
    """

    t_s: float
    recruitment: np.ndarray
    n_recruited: np.ndarray
    dl_mt_m: np.ndarray
    l_ce_m: np.ndarray
    v_ce_m_per_s: np.ndarray
    f_se_n: np.ndarray
    f_pe_n: np.ndarray
    force_n: np.ndarray
    eff_f_iso_n: np.ndarray
    command: np.ndarray
    mean_fitness: np.ndarray


def _force_length(x: np.ndarray) -> np.ndarray:
    """FL(x) clipped at zero (Eq. 1), elementwise; as curves.force_length."""
    return np.maximum((FL_A * x + FL_B) * x + FL_C, 0.0)


class MuscleBatch:
    """K independent muscles with their own parameters, stepped together.

    :param params: one :class:`MuscleParams` per muscle (K >= 1)
    :param engine: ``'compiled'`` (numba), ``'numpy'`` (whole-array NumPy, the
        reference) or ``'auto'``: compiled if numba imports, else NumPy, with
        the same results either way (1e-9 N). :attr:`engine` tells which runs.
    :raises ValueError: if ``params`` is empty or holds something else, or
        ``engine`` is none of :data:`ENGINES`
    :raises ImportError: if ``engine='compiled'`` and numba cannot be imported
    """

    def __init__(self, params: Sequence[MuscleParams], engine: str = 'auto') -> None:
        if engine not in ENGINES:
            raise ValueError(f'`engine` must be one of {", ".join(ENGINES)}, got {engine!r}')
        params = check_instances(MuscleParams, params, 'params')
        self.params = params
        self.size = len(params)

        def column(name: str) -> np.ndarray:
            return np.array([getattr(p, name) for p in params], dtype=float)

        self._f_iso_max = column('f_iso_max_n')
        self._k_se = column('k_se_n_per_m')
        self._k_pe = column('k_pe_n_per_m')
        self._l_rest = column('l_rest_m')
        self._l_opt = column('l_opt_m')
        self._inv_l_opt = 1.0 / self._l_opt
        self._a = column('fv_a_n')
        self._b = column('fv_b_m_per_s')
        self._a_ecc = column('fv_a_ecc_n')
        self._b_ecc = column('fv_b_ecc_m_per_s')
        self._n_units = column('n_units')
        self._multi = np.array([p.units == 'multi' for p in params])
        self._initial = np.array([p.length == 'initial' for p in params])
        self._all_initial = bool(self._initial.all())
        self._any_initial = bool(self._initial.any())
        fes = [i for i, p in enumerate(params) if not p.fes_defaults]
        #: The compiled kernels (None on the NumPy engine).
        self._kernels = None
        # 'auto' honours HILL_MUSCLE_ENGINE (python: the NumPy engine).
        if engine == 'compiled' or (engine == 'auto' and engines.choice() == engines.COMPILED):
            try:
                self._kernels = kernels.compiled()
            except ImportError:
                if engine == 'compiled':
                    raise
        #: [-] the engine in use: ``'compiled'`` or ``'numpy'``.
        self.engine = 'numpy' if self._kernels is None else 'compiled'
        #: Muscles with an FES extension on, NumPy engine: their scalar engines, by index.
        self._fes = {}
        #: Compiled engine: those muscles' FesBundle (muscle j is batch muscle
        #: _fes_index[j]; None without any).
        self._fes_bundle = None
        if fes and self._kernels is None:
            self._fes = {i: FesMuscle(params[i]) for i in fes}
        elif fes:
            self._fes_index = np.array(fes, dtype=np.int64)
            self._fes_dt_s = _FES_DELAY_DT_S
            self._fes_bundle = fes_kernels.FesBundle([params[i] for i in fes],
                                                     dt_s=self._fes_dt_s)
            self._fes_kernels = fes_batch_kernels.compiled()
        stacked = [i for i, p in enumerate(params)
                   if p.units == 'multi' and p.length == 'initial']
        #: NumPy engine: the multi/initial muscles' memories, by index.
        self._memories = {}
        if self._kernels is None:
            self._memories = {i: UnitMemory(params[i].n_units, params[i].f_iso_max_n,
                                            params[i].l_opt_m) for i in stacked}
        else:
            # Compiled engine: each multi/initial muscle's run stack is the
            # slice of N + 1 entries from its base (sentinel first) of three
            # flat arrays; the top of every other muscle stays 0.
            sizes = np.zeros(self.size, dtype=np.int64)
            sizes[stacked] = self._n_units[stacked].astype(np.int64) + 1
            self._stack_base = np.cumsum(sizes) - sizes
            self._stack_top = np.zeros(self.size, dtype=np.int64)
            n_entries = int(sizes.sum())
            self._stack_count = np.zeros(n_entries, dtype=np.int64)
            self._stack_f_unit = np.zeros(n_entries)
            self._stack_total = np.zeros(n_entries)
            # One row per parameter (kernels.P_*), contiguous per parameter.
            rows = {kernels.P_K_SE: self._k_se, kernels.P_K_PE: self._k_pe,
                    kernels.P_L_REST: self._l_rest, kernels.P_L_OPT: self._l_opt,
                    kernels.P_A: self._a, kernels.P_B: self._b,
                    kernels.P_A_ECC: self._a_ecc, kernels.P_B_ECC: self._b_ecc}
            self._param_rows = np.empty((kernels.N_PARAMS, self.size))
            for row, values in rows.items():
                self._param_rows[row] = values
        self.reset()

    # -- state ---------------------------------------------------------------

    def reset(self) -> None:
        """Return every muscle to the resting state and erase its memory."""
        k = self.size
        self.t_s = 0.0
        self.l_ce_m = self._l_rest.copy()
        self.dl_mt_m = np.zeros(k)
        self.recruitment = np.zeros(k)
        self.n_recruited = np.zeros(k, dtype=np.int64)
        for memory in self._memories.values():
            memory.clear()
        if self._kernels is not None:
            self._stack_top[:] = 0   # the sentinels are never written
        for muscle in self._fes.values():
            muscle.reset()
        if self._fes_bundle is not None:
            # Muscle by muscle (about 30 us each): a copy of the state at rest
            # would double the bundle's memory, 140 kB a muscle of 1000 units.
            for j in range(len(self._fes_index)):
                self._fes_bundle.reset(j)
        self.command = np.zeros(k)
        self.mean_fitness = np.ones(k)
        self._f_iso_single = np.zeros(k)   # [N] single/initial: f_iso at recruitment
        # [N] Eff.f_iso (initial) or Eff.f_iso / FL (instantaneous), as Muscle._gain_n.
        self._gain = np.zeros(k)
        self._v_free = np.zeros(k)
        # The CE velocity output of the last step, which is also the first
        # RK4 stage of the next one while no recruitment changes.
        self._v_ce = np.zeros(k)
        self._v_is_k1 = False

    @property
    def n_runs(self) -> np.ndarray:
        """[-] runs on each muscle's memory stack (0 unless multi/initial)."""
        if self._kernels is not None:
            return self._stack_top.copy()
        runs = np.zeros(self.size, dtype=np.int64)
        for i, memory in self._memories.items():
            runs[i] = memory.n_runs
        return runs

    def _vector(self, values, name: str) -> np.ndarray:
        # A copy: the batch keeps dl_MT as its state, and a caller who refills
        # one input array in place between steps must not change that state.
        v = np.array(values, dtype=float)
        if v.shape == ():
            v = np.full(self.size, float(v))
        if v.shape != (self.size,):
            raise ValueError(f'`{name}` must have shape ({self.size},), got {v.shape}')
        return v

    def set_recruitment(self, recruitment) -> None:
        """Apply recruitment levels now, using each muscle's current CE length.

        :param recruitment: [-] R in [0, 1] per muscle, shape (K,) or a scalar
        :raises ValueError: if any R is outside [0, 1] or not finite; nothing changes
        """
        r = self._vector(recruitment, 'recruitment')
        # Two reductions, NaN-propagating, so the comparison fails on NaN too;
        # the index is sought only on failure (at K = 10,000 each whole-array
        # operation costs about as much as 300 muscles' compiled step).
        if not (r.min() >= 0.0 and r.max() <= 1.0):
            raise self._bad_recruitment(r)
        self._set_recruitment(r, release=True)

    @staticmethod
    def _bad_recruitment(r: np.ndarray) -> ValueError:
        """The error naming the first muscle whose R is outside [0, 1] or NaN."""
        i = int(np.flatnonzero(~((r >= 0.0) & (r <= 1.0)))[0])
        return ValueError(f'`recruitment` must be in [0, 1], got {float(r[i])!r} for muscle {i}')

    @staticmethod
    def _bad_dl_mt(dl: np.ndarray) -> ValueError:
        """The error naming the first muscle whose dl_MT is out of range or NaN."""
        i = int(np.flatnonzero(~(np.abs(dl) <= DL_MT_LIMIT_M))[0])
        return ValueError(f'`dl_mt_m` must be finite and within ±{DL_MT_LIMIT_M} m '
                          f'of rest, got {float(dl[i])!r} for muscle {i}')

    @staticmethod
    def _check_dt(dt_s: float) -> float:
        dt = float(dt_s)
        if not (np.isfinite(dt) and dt > 0.0):
            raise ValueError(f'`dt_s` must be positive and finite, got {dt_s!r}')
        return dt

    def _set_recruitment(self, r: np.ndarray, release: bool, changed: bool = True) -> None:
        """:meth:`set_recruitment` of validated levels ``r`` (a new array, kept).

        :param release: False leaves the released CEs where they are, for the
            compiled step, which releases them itself
        :param changed: False if no R differs from the one in force
        """
        if changed:
            self._apply_recruitment(r)
        if release:
            # Released muscles: the free CE takes up the slack at once (as Muscle).
            self.l_ce_m = np.where(self._eff_f_iso(self.l_ce_m) == 0.0,
                                   self._l_rest + self.dl_mt_m, self.l_ce_m)
        elif self._fes or self._fes_bundle is not None:
            # _copy_state writes into l_ce_m: not into an array already returned.
            self.l_ce_m = self.l_ce_m.copy()
        self.command = r
        for i, muscle in self._fes.items():
            muscle.set_recruitment(float(r[i]))
            self._copy_state(i, muscle)
        if self._fes_bundle is not None:
            rows = np.empty((len(self._fes_index), fes_kernels.N_OUT))
            self._fes_call(self._fes_kernels.give_all, (r,), rows)
            self._copy_fes_state(rows)

    def _fes_call(self, kernel, args: tuple, rows: np.ndarray) -> None:
        """``kernel(F, I, *args, index, done, rows)`` of :mod:`.fes_batch_kernels`
        until every FES muscle is done, growing the delay lines of those whose
        line was full (they were left unchanged)."""
        done = np.zeros(len(self._fes_index), dtype=bool)
        while True:
            bundle = self._fes_bundle
            kernel(bundle.F, bundle.I, *args, self._fes_index, done, rows)
            if done.all():
                return
            # Room for the commands of a step half as long: more than now,
            # since only a muscle with a delay can fill its line.
            self._fes_dt_s *= 0.5
            bundle.ensure_delay(self._fes_dt_s)

    def _copy_fes_state(self, rows: np.ndarray) -> None:
        """_copy_state of every FES muscle of the compiled engine, from
        :mod:`.fes_batch_kernels`' rows."""
        idx = self._fes_index
        self.l_ce_m[idx] = rows[:, fes_batch_kernels.ROW_L_CE]
        self.dl_mt_m[idx] = rows[:, fes_batch_kernels.ROW_DL_MT]
        self.recruitment[idx] = rows[:, fes_batch_kernels.ROW_RECRUITMENT]
        self.n_recruited[idx] = rows[:, fes_batch_kernels.ROW_N_RECRUITED]
        self.command[idx] = rows[:, fes_batch_kernels.ROW_COMMAND]
        self.mean_fitness[idx] = rows[:, fes_batch_kernels.ROW_MEAN_FITNESS]

    def _copy_state(self, i: int, muscle: FesMuscle) -> None:
        """Write an FES muscle's state into the batch arrays."""
        self.l_ce_m[i] = muscle.l_ce_m
        self.dl_mt_m[i] = muscle.dl_mt_m
        self.recruitment[i] = muscle.recruitment
        self.n_recruited[i] = muscle.n_recruited
        self.command[i] = muscle.command
        self.mean_fitness[i] = muscle.mean_fitness

    def _apply_recruitment(self, r: np.ndarray) -> None:
        """Update memories and gains of the muscles whose R changed (validated)."""
        if self._kernels is not None:
            if self._kernels.recruit_all(
                    r, self.recruitment, self.n_recruited, self._gain, self._f_iso_single,
                    self.l_ce_m, self._multi, self._initial, self._n_units, self._f_iso_max,
                    self._l_opt, self._stack_base, self._stack_top, self._stack_count,
                    self._stack_f_unit, self._stack_total):
                self._v_is_k1 = False
            return
        changed = r != self.recruitment
        if not changed.any():
            return
        idx = np.flatnonzero(changed)
        r_new = r[idx]
        r_old = self.recruitment[idx]
        multi = self._multi[idx]
        initial = self._initial[idx]
        f_iso_max = self._f_iso_max[idx]
        m = np.where(multi, np.floor(self._n_units[idx] * r_new + _ROUND_HALF),
                     (r_new > 0.0).astype(float)).astype(np.int64)
        gain = np.where(multi, m / self._n_units[idx] * f_iso_max, r_new * f_iso_max)
        # Single/initial: remember FL at the length where R rose from zero.
        single_initial = ~multi & initial
        if single_initial.any():
            f_single = self._f_iso_single[idx]
            rises = single_initial & (r_old == 0.0) & (r_new > 0.0)
            f_at_l = f_iso_max * _force_length(self.l_ce_m[idx] / self._l_opt[idx])
            f_single = np.where(rises, f_at_l, f_single)
            f_single = np.where(r_new == 0.0, 0.0, f_single)
            self._f_iso_single[idx] = np.where(single_initial, f_single,
                                               self._f_iso_single[idx])
            gain = np.where(single_initial, r_new * f_single, gain)
        # Multi/initial: the LIFO stack per muscle, touched only on a change.
        for j in np.flatnonzero(multi & initial):
            i = int(idx[j])
            gain[j] = self._memories[i].update(int(m[j]), float(self.l_ce_m[i]))
        self.recruitment[idx] = r_new
        self.n_recruited[idx] = m
        self._gain[idx] = gain
        self._v_is_k1 = False

    # -- dynamics ------------------------------------------------------------

    def _eff_f_iso(self, l_ce: np.ndarray) -> np.ndarray:
        """[N] Eff.f_iso of every muscle at CE lengths ``l_ce``."""
        if self._all_initial:
            return self._gain
        # x = l_CE (1 / l_opt), as every engine's step takes it (kernels.eff_f_iso).
        f0 = self._gain * _force_length(l_ce * self._inv_l_opt)
        if self._any_initial:
            f0 = np.where(self._initial, self._gain, f0)
        return f0

    def _velocity(self, l_ce: np.ndarray, dl_mt: np.ndarray,
                  f0: np.ndarray | None = None) -> np.ndarray:
        """[m/s] FV_inv(f_SE, Eff.f_iso) per muscle (Eq. 3 inverted, doc/model.md section 3).

        The four branches are written as clipped forces so that every muscle
        takes the same operations: the concentric term vanishes above F0 and
        the eccentric one below it; with F0 = 0 both are zero. Each term keeps
        the operation order of :func:`~hill_muscle_ros.model.equations.force_velocity_inverse`.
        Operations work in place on two scratch arrays: at K = 10,000 the
        step is bound by memory traffic, not by arithmetic.

        :param f0: [N] Eff.f_iso per muscle, computed at ``l_ce`` if omitted
        """
        if f0 is None:
            f0 = self._eff_f_iso(l_ce)
        f_se = np.subtract(l_ce, self._l_rest)
        np.subtract(dl_mt, f_se, out=f_se)
        f_se *= self._k_se
        return self._velocity_at_force(f_se, f0)

    def _velocity_at_force(self, f_se: np.ndarray, f0: np.ndarray) -> np.ndarray:
        """[m/s] FV_inv at SE force ``f_se`` (clipped at 0 here, in place: the
        SE is slack below) and Eff.f_iso ``f0`` (see :meth:`_velocity`)."""
        np.maximum(f_se, 0.0, out=f_se)
        # Concentric: b (F - F0) / (F + a) with F clipped to [0, F0].
        f = np.minimum(f_se, f0)
        v = np.subtract(f, f0)
        v *= self._b
        f += self._a
        v /= f
        # Eccentric: b' (2F - 2F0) / (3F0 - 2F + a') with F clipped to [F0, 1.5 F0].
        np.maximum(f_se, f0, out=f)
        np.minimum(f, ECC_PLATEAU * f0, out=f)
        f *= 2.0
        ecc = np.subtract(f, 2.0 * f0)
        ecc *= self._b_ecc
        np.subtract(3.0 * f0, f, out=f)
        f += self._a_ecc
        ecc /= f
        v += ecc
        return v

    def step(self, recruitment, dl_mt_m, dt_s: float) -> BatchOutputs:
        """Advance every muscle one step: recruit now, then integrate with R held.

        Muscle i does exactly what ``Muscle(params[i]).step(recruitment[i],
        dl_mt_m[i], dt_s)`` does (``FesMuscle`` for a muscle with FES features
        on): a step longer than 1 ms is integrated in n = ceil(dt / 1 ms)
        equal substeps, R held and dl_MT ramping linearly across them
        (:mod:`.substeps`), on both engines alike.

        :param recruitment: [-] R in [0, 1] per muscle, shape (K,) or a scalar
        :param dl_mt_m: [m] MTU length change at the end of the step, (K,) or scalar
        :param dt_s: [s] step length, > 0, the same for every muscle
        :return: the outputs at the end of the step
        :raises ValueError: on a NaN, infinite or out-of-range input; the state
            is unchanged
        """
        dt = float(dt_s) if isinstance(dt_s, (int, float, np.floating)) else math.nan
        if not (math.isfinite(dt) and dt > MAX_SUBSTEP_S):
            return self._step_one(recruitment, dl_mt_m, dt_s)   # n = 1 (or a bad dt)
        dl1 = self._vector(dl_mt_m, 'dl_mt_m')
        if not (dl1.min() >= -DL_MT_LIMIT_M and dl1.max() <= DL_MT_LIMIT_M):  # and NaN
            raise self._bad_dl_mt(dl1)
        n = substeps_for(dt)
        dl0 = np.array(self.dl_mt_m, dtype=float)
        change = dl1 - dl0
        # The first substep checks the recruitment before changing anything;
        # the later ones give the same R again, which changes nothing. dl_MT
        # as substeps.length_ramp, per muscle, ending exactly at dl1.
        self._step_one(recruitment, dl0 + change * (1 / n), dt / n)
        held = self.command.copy()
        for j in range(2, n):
            self._step_one(held, dl0 + change * (j / n), dt / n)
        return self._step_one(held, dl1, dt / n)

    def _step_one(self, recruitment, dl_mt_m, dt_s: float) -> BatchOutputs:
        """:meth:`step` integrated whole: one substep of at most 1 ms (any
        ``dt_s`` is checked here)."""
        dl1 = self._vector(dl_mt_m, 'dl_mt_m')
        if self._kernels is not None:
            return self._step_compiled(recruitment, dl1, dt_s)
        if not (dl1.min() >= -DL_MT_LIMIT_M and dl1.max() <= DL_MT_LIMIT_M):  # and NaN
            raise self._bad_dl_mt(dl1)
        dt = self._check_dt(dt_s)
        self.set_recruitment(recruitment)

        l0, dl0 = self.l_ce_m, self.dl_mt_m
        f0 = self._eff_f_iso(l0)
        initial = self._all_initial
        k1 = self._v_ce if self._v_is_k1 else self._velocity(l0, dl0, f0)
        half_dt = 0.5 * dt
        dl_mid = 0.5 * (dl0 + dl1)
        # The stages' SE forces as k_SE (dl - (l0 - l_rest)) - k_SE h k, as
        # every engine writes them (kernels.step_one says why).
        from_rest = l0 - self._l_rest
        f_mid = self._k_se * (dl_mid - from_rest)
        f_end = self._k_se * (dl1 - from_rest)
        c_half, c_full = self._k_se * half_dt, self._k_se * dt
        k2 = self._velocity_at_force(f_mid - c_half * k1, f0 if initial else
                                     self._eff_f_iso(l0 + half_dt * k1))
        k3 = self._velocity_at_force(f_mid - c_half * k2, f0 if initial else
                                     self._eff_f_iso(l0 + half_dt * k2))
        k4 = self._velocity_at_force(f_end - c_full * k3, f0 if initial else
                                     self._eff_f_iso(l0 + dt * k3))
        l_rk4 = l0 + dt / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
        l_free = self._l_rest + dl1
        l1 = np.where(f0 > 0.0, l_rk4, l_free)
        f0 = self._eff_f_iso(l1)
        # Nothing recruited, or the instantaneous CE left the FL range within
        # the step: the free CE takes up the SE slack (doc/model.md section 4).
        l1 = np.where(f0 == 0.0, l_free, l1)
        # Eff.f_iso read off the state: at the free length, maybe back in range.
        f0 = self._eff_f_iso(l1)
        v_free = (dl1 - dl0) / dt
        v_ce = np.where(f0 > 0.0, self._velocity(l1, dl1, f0), v_free)

        self.l_ce_m, self.dl_mt_m, self._v_free, self._v_ce = l1, dl1, v_free, v_ce
        self._v_is_k1 = True
        self.t_s += dt
        if self._fes:
            # The vector step above computed these too (the paper's model); the
            # scalar FES engines replace them: same inputs, their own model.
            self._v_ce = v_ce.copy()
            f0 = f0.copy()
            for i, muscle in self._fes.items():
                # FesMuscle.step's one substep, integrated whole as the compiled
                # engine's step_all does (step() above made the substeps; the
                # command is already given and the inputs checked).
                muscle._advance(float(self.command[i]), float(dl1[i]), dt)
                out = muscle.outputs()
                self._copy_state(i, muscle)
                self._v_ce[i] = out.v_ce_m_per_s
                f0[i] = out.eff_f_iso_n
        return self._outputs(f0)

    def _step_compiled(self, recruitment, dl1: np.ndarray, dt_s: float) -> BatchOutputs:
        """:meth:`step` on the compiled engine (``dl1`` a new array, not yet checked).

        The inputs are checked in one compiled pass (kernels.scan_inputs),
        with the same checks, in the same order, as the NumPy engine. The
        recruitment bookkeeping (memories and gains of the muscles whose R
        changed) is kernels.recruit_all, and kernels.step_all does the rest
        of the step: the same operations per muscle as the array code of
        :meth:`step`.
        """
        r = self._vector(recruitment, 'recruitment')
        n_bad_dl, n_bad_r, n_changed = self._kernels.scan_inputs(r, dl1, self.recruitment,
                                                                 DL_MT_LIMIT_M)
        if n_bad_dl:
            raise self._bad_dl_mt(dl1)
        dt = self._check_dt(dt_s)
        if n_bad_r:
            raise self._bad_recruitment(r)
        self._set_recruitment(r, release=False, changed=n_changed > 0)
        out = np.empty((kernels.N_OUTPUTS, self.size))
        kernels.launch(self._kernels, self.size >= kernels.PARALLEL_MIN_K,
                       self.l_ce_m, self.dl_mt_m, dl1, dt, self._gain, self._v_ce,
                       self._v_is_k1, self._initial, self._all_initial, self._param_rows,
                       out)
        l1, v_ce, f0 = out[kernels.OUT_L_CE], out[kernels.OUT_V_CE], out[kernels.OUT_EFF_F_ISO]
        self.l_ce_m, self.dl_mt_m = l1, dl1
        self._v_free, self._v_ce = out[kernels.OUT_V_FREE], v_ce
        self._v_is_k1 = True
        self.t_s += dt
        if self._fes_bundle is not None:
            # As the NumPy engine's FesMuscle.step calls, all in one call.
            self._v_ce = v_ce.copy()
            if dt < self._fes_dt_s:
                self._fes_dt_s = dt
                self._fes_bundle.ensure_delay(dt)
            rows = np.empty((len(self._fes_index), fes_kernels.N_OUT))
            self._fes_call(self._fes_kernels.step_all, (self.command, dl1, dt), rows)
            self._copy_fes_state(rows)
            self._v_ce[self._fes_index] = rows[:, fes_batch_kernels.ROW_V_CE]
            f0[self._fes_index] = rows[:, fes_batch_kernels.ROW_EFF_F_ISO]
            return self._outputs(f0)
        return BatchOutputs(self.t_s, self.recruitment.copy(), self.n_recruited.copy(),
                            dl1, l1, v_ce, out[kernels.OUT_F_SE], out[kernels.OUT_F_PE],
                            out[kernels.OUT_FORCE], f0, self.command,   # new each step
                            self.mean_fitness.copy())

    def outputs(self) -> BatchOutputs:
        """The outputs of every muscle at the current instant."""
        f0 = self._eff_f_iso(self.l_ce_m)
        if not self._v_is_k1:
            v = self._velocity(self.l_ce_m, self.dl_mt_m, f0)
            self._v_ce = np.where(f0 > 0.0, v, self._v_free)
            self._v_is_k1 = True
        if self._fes:
            f0 = f0.copy()
            for i, muscle in self._fes.items():
                out = muscle.outputs()
                self._v_ce[i] = out.v_ce_m_per_s
                f0[i] = out.eff_f_iso_n
        if self._fes_bundle is not None:
            f0 = f0.copy()
            rows = np.empty((len(self._fes_index), fes_kernels.N_OUT))
            bundle = self._fes_bundle
            self._fes_kernels.outputs_all(bundle.F, bundle.I, rows)
            self._v_ce[self._fes_index] = rows[:, fes_batch_kernels.ROW_V_CE]
            f0[self._fes_index] = rows[:, fes_batch_kernels.ROW_EFF_F_ISO]
        return self._outputs(f0)

    def _outputs(self, f0: np.ndarray) -> BatchOutputs:
        l_ce, dl = self.l_ce_m, self.dl_mt_m
        f_se = self._k_se * np.maximum(dl - (l_ce - self._l_rest), 0.0)
        f_pe = self._k_pe * np.maximum(dl, 0.0)
        return BatchOutputs(self.t_s, self.recruitment.copy(), self.n_recruited.copy(),
                            dl, l_ce, self._v_ce, f_se, f_pe, f_se + f_pe, f0.copy(),
                            self.command.copy(), self.mean_fitness.copy())
