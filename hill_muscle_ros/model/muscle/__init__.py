"""The muscle, written once: its flat state, its kernels and the facades over them.

- :mod:`.state`: the layout of one or many muscles' state in two flat arrays,
  and :class:`~.state.FesBundle`, which holds it;
- :mod:`.pool`: the unit pool of a ``multi`` muscle (recruitment memory and
  per-unit fatigue) as functions over that state;
- :mod:`.kernels`: the muscle's step (delay, activation, recruitment events,
  RK4 of the CE) as functions over that state, compiled by numba or run as
  plain Python;
- :mod:`.facade`: :class:`Muscle`, one muscle;
- :mod:`.batch` and :mod:`.batch_kernels`: :class:`~.batch.MuscleBatch`, many
  muscles stepped at once by the same functions.
"""
from .facade import (DL_MT_LIMIT_M, Muscle, MuscleOutputs, check_dl_mt, check_recruitment,
                     recruitment_from_pulse_width)

__all__ = ['DL_MT_LIMIT_M', 'Muscle', 'MuscleOutputs', 'check_dl_mt', 'check_recruitment',
           'recruitment_from_pulse_width']
