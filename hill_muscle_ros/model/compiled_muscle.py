"""One FES muscle stepped on the compiled kernels, with ``Muscle``'s interface.

:class:`CompiledFesMuscle` keeps a :class:`~.fes_muscle.FesMuscle`'s state in a
one-muscle :class:`~.fes_kernels.FesBundle` and advances it with the compiled
:func:`~.fes_kernels.muscle_run`, one step per :meth:`CompiledFesMuscle.step`
(the simulator node's tick). It agrees with ``FesMuscle`` to rounding
(test/test_compiled_muscle.py) and costs far less per step, most of all while
the last units of a relative-FV muscle let go (benchmarks/muscle_node_tick.py).
Only the calls the node makes are here: :meth:`~CompiledFesMuscle.step`,
:meth:`~CompiledFesMuscle.reset`, :meth:`~CompiledFesMuscle.outputs` and
``dl_mt_m``. A muscle with every FES feature off is the paper's
:class:`~.muscle.Muscle`, whose Python step is already cheap.
"""
from __future__ import annotations

import math

import numpy as np

from . import fes_kernels
from .fes_kernels import N_OUT, S_DL, FesBundle
from .muscle import MuscleOutputs, check_dl_mt, check_recruitment
from .params import MuscleParams
from .substeps import length_ramp, substeps_for

#: Index of ``n_recruited`` in :class:`MuscleOutputs` (an int there, a float in the kernels').
_N_RECRUITED = MuscleOutputs._fields.index('n_recruited')


def _as_outputs(row: np.ndarray) -> MuscleOutputs:
    """A kernel output row as :class:`MuscleOutputs` (Python floats, the count an int)."""
    values = row.tolist()
    values[_N_RECRUITED] = int(values[_N_RECRUITED])
    return MuscleOutputs(*values)


def loaded() -> bool:
    """True if the compiled FES muscle's kernels are loaded in this process, so
    that building a :class:`CompiledFesMuscle` compiles nothing (well under a second)."""
    return fes_kernels.loaded()


class CompiledFesMuscle:
    """An FES muscle (any variant and feature) on the compiled kernels.

    Loads :func:`.fes_kernels.compiled` (numba; compiles once if its cache
    has no copy), so build it where a compile may take its time, not in a
    time-critical callback.

    :param params: the muscle's parameters
    :raises ImportError: if numba cannot be imported
    """

    def __init__(self, params: MuscleParams) -> None:
        self.params = params
        self._kernels = fes_kernels.compiled()
        self._bundle = FesBundle([params])
        self._r = np.zeros(1)
        self._dl = np.zeros(1)
        self._out = np.zeros((1, N_OUT))
        self._fs = self._bundle.view(0, 'fs')
        self._dt_ready_s = math.nan   # the step the delay line was last sized for

    def reset(self) -> None:
        """Return to rest: no command, a = 0, every unit fresh and unrecruited."""
        self._bundle.reset(0)

    @property
    def dl_mt_m(self) -> float:
        """[m] MTU length change from rest (dl_MT) now."""
        return float(self._fs[S_DL])

    def outputs(self) -> MuscleOutputs:
        """The outputs at the current instant (FesMuscle.outputs)."""
        return _as_outputs(self._bundle.outputs(0, self._kernels))

    def step(self, recruitment: float, dl_mt_m: float, dt_s: float) -> MuscleOutputs:
        """Advance one step with command u = ``recruitment`` given at its start,
        in n = ceil(dt / 1 ms) substeps (:mod:`.substeps`), as ``FesMuscle.step``.

        :param recruitment: [-] recruitment command u in [0, 1]
        :param dl_mt_m: [m] MTU length change at the end of the step (dl_MT)
        :param dt_s: [s] step length, > 0
        :return: the outputs at the end of the step
        :raises ValueError: on a NaN, infinite or out-of-range input (as
            FesMuscle.step, in its order); the state is unchanged
        """
        u, dl = check_recruitment(recruitment), check_dl_mt(dl_mt_m)
        if not (math.isfinite(dt_s) and dt_s > 0.0):
            raise ValueError(f'`dt_s` must be positive and finite, got {dt_s!r}')
        # n = ceil(dt / 1 ms) substeps of dt / n (model/substeps.py): one at 1 kHz.
        n = substeps_for(dt_s)
        h = float(dt_s) / n
        if h != self._dt_ready_s:
            # Grows the delay line for a shorter step; the arrays move, so the
            # view of the state is taken anew.
            self._bundle.ensure_delay(h)
            self._fs = self._bundle.view(0, 'fs')
            self._dt_ready_s = h
        if n == 1:
            r, dls, out = self._r, self._dl, self._out
            r[0] = u
            dls[0] = dl
        else:
            r = np.full(n, u)
            dls = np.array(length_ramp(self.dl_mt_m, dl, n))
            out = np.empty((n, N_OUT))
        bundle = self._bundle
        done = self._kernels.muscle_run(bundle.F, bundle.I, 0, r, dls, h, r, False, out)
        if done != n:   # delay_capacity bounds the commands pending
            raise RuntimeError(f'the delay line of the compiled muscle overflowed '
                               f'(emd_s {self.params.emd_s!r}, dt_s {dt_s!r})')
        return _as_outputs(out[-1])
