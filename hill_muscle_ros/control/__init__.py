"""An example FES force controller (pure Python; the ROS node wraps it)."""
from .pi import (FEEDFORWARD_CHOICES, ControllerInputs, ControllerParams, ForceController,
                 ImposedLength, LengthRate)

__all__ = ['FEEDFORWARD_CHOICES', 'ControllerInputs', 'ControllerParams', 'ForceController',
           'ImposedLength', 'LengthRate']
