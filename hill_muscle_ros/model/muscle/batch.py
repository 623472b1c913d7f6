"""Many independent muscles stepped at once, on the one engine.

For parameter sweeps, vectorised environments and controller tuning: K
muscles, each with its own :class:`~hill_muscle_ros.model.params.MuscleParams`
(any variant, any FES feature, mixed) and its own inputs, advance together by
one step of the same length. :class:`MuscleBatch` is a thin facade: its state
is one :class:`~hill_muscle_ros.model.muscle.state.FesBundle` holding every
muscle, and a step is one call of :mod:`.batch_kernels`, a loop over the
muscles of the very functions a single :class:`~hill_muscle_ros.model.muscle.facade.Muscle`
runs. Muscle i therefore does exactly what ``Muscle(params[i]).step(...)``
does (tests: to 1e-9 N). The build (numba-compiled, or the same functions as
plain Python) is chosen by :func:`.engine.kernels`, as for the single muscle.

The arrays of state and outputs cover every muscle alike; the outputs of a
step are new arrays, never the batch's own state.
"""
from __future__ import annotations

import math
from typing import NamedTuple, Sequence

import numpy as np

from .. import engine
from ..params import MuscleParams, check_instances
from ..substeps import substeps_for
from . import batch_kernels
from .facade import DL_MT_LIMIT_M
from .state import J_RTOP, N_OUT, FesBundle

#: [s] the step the delay lines are first sized for (FesBundle's default); a
#: shorter step, or a delay line found full, grows them.
_DELAY_DT_S = 1e-3
#: Columns of a kernel output row, in :class:`BatchOutputs`' order.
_FIELDS = range(N_OUT)


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


class MuscleBatch:
    """K independent muscles with their own parameters, stepped together.

    :param params: one :class:`MuscleParams` per muscle (K >= 1)
    :param build: :data:`.engine.COMPILED` or :data:`.engine.PYTHON`, or None
        (the default) for what ``HILL_MUSCLE_ENGINE`` chooses; :attr:`build`
        tells which runs
    :raises ValueError: if ``params`` is empty or holds something else, or a
        ``ding2003`` muscle, or ``build`` is unknown
    :raises ImportError: if the compiled build is asked for and numba cannot be imported
    """

    def __init__(self, params: Sequence[MuscleParams], build: str | None = None) -> None:
        params = check_instances(MuscleParams, params, 'params')
        for i, p in enumerate(params):
            if p.activation_model != 'first_order':
                raise ValueError(f'`params[{i}]` must have `activation_model: first_order` (a '
                                 'batch steps level commands; a ding2003 muscle takes pulses: '
                                 f'run it with Muscle), got {p.activation_model!r}')
        self.params = params
        self.size = len(params)
        self._kernels = engine.kernels(batch_kernels, build)
        #: :data:`.engine.COMPILED` or :data:`.engine.PYTHON`: the build in use.
        self.build = engine.PYTHON if self._kernels is batch_kernels else engine.COMPILED
        self._dt_s = _DELAY_DT_S
        self._bundle = FesBundle(params, dt_s=self._dt_s)
        self._index = np.arange(self.size, dtype=np.int64)
        self.reset()

    # -- state ---------------------------------------------------------------

    def reset(self) -> None:
        """Return every muscle to the resting state and erase its memory."""
        # Muscle by muscle (about 30 us each): a copy of the state at rest
        # would double the bundle's memory, 140 kB a muscle of 1000 units.
        for i in range(self.size):
            self._bundle.reset(i)
        self._out = np.empty((self.size, N_OUT))
        self._kernels.outputs_all(self._bundle.F, self._bundle.I, self._out)

    @property
    def t_s(self) -> float:
        """[s] simulated time (the same for every muscle)."""
        return float(self._out[0, 0])

    def _column(self, j: int) -> np.ndarray:
        return self._out[:, j].copy()

    @property
    def recruitment(self) -> np.ndarray:
        """[-] recruitment R = a in force, per muscle."""
        return self._column(1)

    @property
    def n_recruited(self) -> np.ndarray:
        """[-] recruited units M per muscle."""
        return self._out[:, 2].astype(np.int64)

    @property
    def dl_mt_m(self) -> np.ndarray:
        """[m] MTU length change from rest (dl_MT) per muscle."""
        return self._column(3)

    @property
    def l_ce_m(self) -> np.ndarray:
        """[m] CE length (l_CE) per muscle."""
        return self._column(4)

    @property
    def command(self) -> np.ndarray:
        """[-] the recruitment command u given last, per muscle."""
        return self._column(10)

    @property
    def mean_fitness(self) -> np.ndarray:
        """[-] mean fitness of each muscle's units (1 without fatigue)."""
        return self._column(11)

    @property
    def n_runs(self) -> np.ndarray:
        """[-] groups of units recruited at one instant held by each muscle's
        memory (multi; 0 for single), as :attr:`Muscle.n_runs
        <hill_muscle_ros.model.muscle.Muscle.n_runs>`."""
        return np.array([int(self._bundle.view(i, 'js')[J_RTOP])
                         if p.units == 'multi' else 0 for i, p in enumerate(self.params)],
                        dtype=np.int64)

    # -- inputs ----------------------------------------------------------------

    def _vector(self, values, name: str) -> np.ndarray:
        # A copy: a caller who refills one input array in place between steps
        # must not change what the batch was given.
        v = np.array(values, dtype=float)
        if v.shape == ():
            v = np.full(self.size, float(v))
        if v.shape != (self.size,):
            raise ValueError(f'`{name}` must have shape ({self.size},), got {v.shape}')
        return v

    def _checked_recruitment(self, recruitment) -> np.ndarray:
        r = self._vector(recruitment, 'recruitment')
        # Two reductions, NaN-propagating, so the comparison fails on NaN too;
        # the index is sought only on failure.
        if not (r.min() >= 0.0 and r.max() <= 1.0):
            i = int(np.flatnonzero(~((r >= 0.0) & (r <= 1.0)))[0])
            raise ValueError(f'`recruitment` must be in [0, 1], got {float(r[i])!r} '
                             f'for muscle {i}')
        return r

    def _checked_dl_mt(self, dl_mt_m) -> np.ndarray:
        dl = self._vector(dl_mt_m, 'dl_mt_m')
        if not (dl.min() >= -DL_MT_LIMIT_M and dl.max() <= DL_MT_LIMIT_M):   # and NaN
            i = int(np.flatnonzero(~(np.abs(dl) <= DL_MT_LIMIT_M))[0])
            raise ValueError(f'`dl_mt_m` must be finite and within ±{DL_MT_LIMIT_M} m '
                             f'of rest, got {float(dl[i])!r} for muscle {i}')
        return dl

    @staticmethod
    def _checked_dt(dt_s) -> float:
        dt = float(dt_s) if isinstance(dt_s, (int, float, np.floating)) else math.nan
        if not (math.isfinite(dt) and dt > 0.0):
            raise ValueError(f'`dt_s` must be positive and finite, got {dt_s!r}')
        return dt

    def _call(self, kernel, args: tuple, rows: np.ndarray) -> None:
        """``kernel(F, I, *args, index, done, rows)`` of :mod:`.batch_kernels`
        until every muscle is done, growing the delay lines of those whose
        line was full (they were left unchanged)."""
        done = np.zeros(self.size, dtype=bool)
        while True:
            bundle = self._bundle
            kernel(bundle.F, bundle.I, *args, self._index, done, rows)
            if done.all():
                return
            # Room for the commands of a step half as long: more than now,
            # since only a muscle with a delay can fill its line.
            self._dt_s *= 0.5
            bundle.ensure_delay(self._dt_s)

    def set_recruitment(self, recruitment) -> None:
        """Give recruitment commands now, as :meth:`Muscle.set_recruitment
        <hill_muscle_ros.model.muscle.Muscle.set_recruitment>` does to each.

        :param recruitment: [-] u in [0, 1] per muscle, shape (K,) or a scalar
        :raises ValueError: if any u is outside [0, 1] or not finite; nothing changes
        """
        r = self._checked_recruitment(recruitment)
        self._call(self._kernels.give_all, (r,), np.empty((self.size, N_OUT)))
        self._kernels.outputs_all(self._bundle.F, self._bundle.I, self._out)

    # -- dynamics ------------------------------------------------------------

    def step(self, recruitment, dl_mt_m, dt_s: float) -> BatchOutputs:
        """Advance every muscle one step: give the command now, then integrate with it held.

        Muscle i does exactly what ``Muscle(params[i]).step(recruitment[i],
        dl_mt_m[i], dt_s)`` does: a step longer than 1 ms is integrated in
        n = ceil(dt / 1 ms) equal substeps, the command held and dl_MT ramping
        linearly across them (:mod:`.substeps`).

        :param recruitment: [-] command u in [0, 1] per muscle, shape (K,) or a scalar
        :param dl_mt_m: [m] MTU length change at the end of the step, (K,) or scalar
        :param dt_s: [s] step length, > 0, the same for every muscle
        :return: the outputs at the end of the step
        :raises ValueError: on a NaN, infinite or out-of-range input (dl_MT, then
            the step, then the recruitment, as Muscle.step); the state is unchanged
        """
        dl1 = self._checked_dl_mt(dl_mt_m)
        dt = self._checked_dt(dt_s)
        r = self._checked_recruitment(recruitment)
        n = substeps_for(dt)
        h = dt / n
        if h < self._dt_s:
            self._dt_s = h
            self._bundle.ensure_delay(h)
        dl0 = self._out[:, 3].copy()
        change = dl1 - dl0
        out = self._out
        for j in range(1, n + 1):
            # dl_MT as substeps.length_ramp, per muscle, ending exactly at dl1.
            dl = dl1 if j == n else dl0 + change * (j / n)
            out = np.empty((self.size, N_OUT))
            self._call(self._kernels.step_all, (r, dl, h), out)
        self._out = out
        return self.outputs()

    def outputs(self) -> BatchOutputs:
        """The outputs of every muscle at the current instant (new arrays)."""
        out = self._out
        columns = [out[:, j].copy() for j in _FIELDS]
        columns[0] = float(out[0, 0])
        columns[2] = out[:, 2].astype(np.int64)
        return BatchOutputs(*columns)
