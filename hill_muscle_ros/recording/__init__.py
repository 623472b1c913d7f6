"""Recording to rosbag2 bags (MCAP storage), live and offline, and reading them back.

There is no rosbag2 on PyPI, so the package writes the bags itself, in the
layout rosbag2's MCAP storage plugin (ROS 2 Jazzy) produces: a directory with
``metadata.yaml`` and ``<name>_0.mcap``. ``ros2 bag``, Foxglove, PlotJuggler
and rosbags open them without conversion.

This package does not import rclpy at module level except where it must
(:mod:`.offline` serialises real message objects).
"""
from .bag_writer import (BagOutputError, BagWriter, message_definition,
                         qos_profile_dict, serialize_qos_profiles, type_description_hash)

__all__ = ['BagOutputError', 'BagWriter', 'message_definition', 'qos_profile_dict',
           'serialize_qos_profiles', 'type_description_hash']
