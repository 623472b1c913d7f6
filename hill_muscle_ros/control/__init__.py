"""Example FES controllers: pure Python, no ROS (the node is a thin shell)."""
from .pi import ControllerParams, ForceController

__all__ = ['ControllerParams', 'ForceController']
