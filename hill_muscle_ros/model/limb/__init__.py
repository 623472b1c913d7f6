"""The limb: one joint moved by several muscles (doc/model.md section 9), written once.

The modules, each on top of the ones before it:

- :mod:`.plant`: the plain data: the joint, its muscles and the plant file,
  a step's inputs and outputs, limb protocols and results (no dynamics);
- :mod:`.kernels`: the dynamics, plain functions over flat arrays that run as
  Python or compiled by numba (:func:`~hill_muscle_ros.model.engine.kernels`
  chooses which, from ``HILL_MUSCLE_ENGINE``);
- :mod:`.arrays`: a limb's flat state (:class:`~.arrays.LimbArrays`);
- :mod:`.limb`: :class:`~.limb.Limb`, the limb stepped one call at a time;
- :mod:`.simulate`: :func:`~.simulate.simulate_limb`, a whole protocol in one call;
- :mod:`.batch`: :class:`~.batch.LimbBatch`, many limbs stepped together, and
  :func:`~.batch.simulate_limb_batch`, a sweep's runs.

Everything a user imports is here too (``from hill_muscle_ros.model.limb
import Limb, LimbPlant, simulate_limb``).
"""
from .batch import LimbBatch, LimbBatchOutputs, LimbOutOfRange, simulate_limb_batch
from .limb import Limb
from .plant import (ACTIONS, ANGLE_LIMIT_RAD, MUSCLE_COLUMNS, TORQUE_LIMIT_N_M, JointParams,
                    LimbMuscle, LimbOutputs, LimbPlant, LimbProtocol, LimbResult,
                    check_step_inputs, limb_columns, stretch_message)
from .simulate import simulate_limb

__all__ = [
    'ACTIONS', 'ANGLE_LIMIT_RAD', 'JointParams', 'Limb', 'LimbBatch', 'LimbBatchOutputs',
    'LimbMuscle', 'LimbOutOfRange', 'LimbOutputs', 'LimbPlant', 'LimbProtocol', 'LimbResult',
    'MUSCLE_COLUMNS', 'TORQUE_LIMIT_N_M', 'check_step_inputs', 'limb_columns',
    'simulate_limb', 'simulate_limb_batch', 'stretch_message',
]
