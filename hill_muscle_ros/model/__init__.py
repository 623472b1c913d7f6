"""The model core: pure Python and NumPy, no ROS.

The equations (Eq. 1, Eq. 3 and the FES laws, :mod:`.equations`), the one
engine over flat state (:mod:`hill_muscle_ros.model.muscle.kernels`, the limb's kernels), the facades
over it (:class:`Muscle`, :class:`MuscleBatch`, the limb's), parameters,
protocols and the offline simulation loops.
"""
from .muscle.batch import BatchOutputs, MuscleBatch
from .command_track import MAX_KNOTS, CommandTrack
from .equations import force_length, force_velocity, force_velocity_inverse
from .limb import LimbBatch, LimbBatchOutputs, LimbOutOfRange, simulate_limb_batch
from .memory import recruited_units
from .muscle import (DL_MT_LIMIT_M, Muscle, MuscleOutputs, check_recruitment,
                     recruitment_from_pulse_width)
from .params import LENGTH_CHOICES, UNITS_CHOICES, MuscleParams
from .protocol import Knots, Protocol, ProtocolError
from .simulate import COLUMNS, SimulationResult, simulate

__all__ = [
    'BatchOutputs', 'COLUMNS', 'CommandTrack', 'MAX_KNOTS',
    'DL_MT_LIMIT_M', 'Knots', 'LENGTH_CHOICES', 'Muscle', 'MuscleBatch', 'MuscleOutputs',
    'MuscleParams', 'Protocol', 'ProtocolError', 'SimulationResult',
    'UNITS_CHOICES', 'check_recruitment', 'force_length', 'force_velocity',
    'force_velocity_inverse', 'recruited_units', 'recruitment_from_pulse_width', 'simulate',
    'LimbBatch', 'LimbBatchOutputs', 'LimbOutOfRange', 'simulate_limb_batch',
]
