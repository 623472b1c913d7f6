"""Gymnasium environments on the muscle and limb models (optional: needs gymnasium).

Importing this package registers:

- ``hill_muscle_ros/ForceTracking-v0``: :class:`~.force_tracking.ForceTrackingEnv`,
  one muscle, a pulse width per control period, a force target to track
  (``gymnasium.make_vec(..., num_envs=K)`` gives
  :class:`~.vector.ForceTrackingVectorEnv`, K of them on the batch engine);
- ``hill_muscle_ros/KneeAngle-v0``: :class:`~.knee_angle.KneeAngleEnv`, the
  knee preset, a pulse width per muscle, an angle target to track
  (``make_vec`` gives :class:`~.vector.KneeAngleVectorEnv`).

Install with ``pip install hill_muscle_ros[gym]`` (or ``pip install gymnasium``).
The rest of the package does not need gymnasium.
"""
try:
    import gymnasium
except ImportError as err:   # name the extra that brings it
    raise ImportError('hill_muscle_ros.gym needs gymnasium: pip install '
                      '"hill_muscle_ros[gym]" (or gymnasium==1.4.0)') from err

from .force_tracking import ForceTrackingEnv
from .knee_angle import KneeAngleEnv
from .vector import ForceTrackingVectorEnv, KneeAngleVectorEnv

FORCE_TRACKING_ID = 'hill_muscle_ros/ForceTracking-v0'
KNEE_ANGLE_ID = 'hill_muscle_ros/KneeAngle-v0'

# Importing twice (a reload) must not re-register: gymnasium would warn.
if FORCE_TRACKING_ID not in gymnasium.registry:
    gymnasium.register(id=FORCE_TRACKING_ID,
                       entry_point='hill_muscle_ros.gym.force_tracking:ForceTrackingEnv',
                       vector_entry_point='hill_muscle_ros.gym.vector:ForceTrackingVectorEnv')
if KNEE_ANGLE_ID not in gymnasium.registry:
    gymnasium.register(id=KNEE_ANGLE_ID,
                       entry_point='hill_muscle_ros.gym.knee_angle:KneeAngleEnv',
                       vector_entry_point='hill_muscle_ros.gym.vector:KneeAngleVectorEnv')

__all__ = ['FORCE_TRACKING_ID', 'ForceTrackingEnv', 'ForceTrackingVectorEnv', 'KNEE_ANGLE_ID',
           'KneeAngleEnv', 'KneeAngleVectorEnv']
