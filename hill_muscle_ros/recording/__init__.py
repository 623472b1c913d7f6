"""Recording to rosbag2 bags (MCAP storage), live and offline, and reading them back.

There is no rosbag2 on PyPI, so the package writes the bags itself, in the
layout rosbag2's MCAP storage plugin (ROS 2 Jazzy) produces: a directory with
``metadata.yaml`` and ``<name>_0.mcap``. ``ros2 bag``, Foxglove, PlotJuggler
and rosbags open them without conversion. The MCAP records are the ``mcap``
library's; :mod:`.bag_writer` says what ``rosbags.rosbag2.Writer`` lacks for
a live recorder.

- :mod:`.bag_writer`: writing a bag; :mod:`.reader`: reading one into NumPy;
- :mod:`.offline`: an offline simulation as a bag with the live topics;
- :mod:`.receipt_clock`: the sim time at a DDS receive instant (a live
  recorder's ``log_time`` on sim time);
- :mod:`.analysis`: what a recorded run says (protocol start, the force at
  given times against the offline simulation, the plots), shared by the
  demos, the tests and the benchmarks.

This package does not import rclpy at module level except where it must
(:mod:`.offline` serialises real message objects).
"""
from .bag_writer import (BagOutputError, BagWriter, message_definition,
                         qos_profile_dict, serialize_qos_profiles, type_description_hash)

__all__ = ['BagOutputError', 'BagWriter', 'message_definition', 'qos_profile_dict',
           'serialize_qos_profiles', 'type_description_hash']
