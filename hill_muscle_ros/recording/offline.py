"""Write an offline simulation as a bag with the topics and types of a live run.

A live run has the protocol player publish the stimulation and
``length_command`` and the simulator publish ``force``, ``ce_length`` and
``wrench`` once per step. The offline bag holds the same messages, serialized
by rclpy from real message objects (byte-identical CDR to what the nodes
publish), each stamped with its simulated time: ``log_time``,
``publish_time`` and the wrench's ``header.stamp`` are all t_k = k / rate
since 0. Offline and live bags therefore open side by side in the same tools
and with :func:`hill_muscle_ros.recording.reader.read_bag`.
"""
from __future__ import annotations

import os
from pathlib import Path

from geometry_msgs.msg import WrenchStamped
from rclpy.serialization import serialize_message
from rclpy.time import Time
from std_msgs.msg import Float64

from ..model import MuscleParams, Protocol
from ..model.simulate import SimulationResult
from ..qos import OUTPUT_QOS
from ..timebase import NS_PER_S
from .bag_writer import BagWriter

FLOAT64 = 'std_msgs/msg/Float64'
WRENCH_STAMPED = 'geometry_msgs/msg/WrenchStamped'
#: The player's stimulation topics (its ``output`` parameter).
STIMULATION_TOPICS = ('pulse_width', 'recruitment')
DEFAULT_FRAME_ID = 'muscle'


def _topic(namespace: str, name: str) -> str:
    return namespace.rstrip('/') + '/' + name


def write_simulation_bag(bag_dir: str | os.PathLike, result: SimulationResult,
                         params: MuscleParams, protocol: Protocol, *,
                         frame_id: str = DEFAULT_FRAME_ID, output: str = 'pulse_width',
                         namespace: str = '/') -> Path:
    """Write ``result`` as a rosbag2 MCAP bag in simulated time.

    Inputs are written at each step t_k < duration, as the player publishes
    them, plus the final zero stimulation at the end; outputs at every sample
    of ``result`` (t = 0 included).

    :param bag_dir: the bag directory (must not exist or be empty)
    :param result: the offline run (:func:`hill_muscle_ros.model.simulate`)
    :param params: the muscle parameters of the run (for PW_max)
    :param protocol: the protocol that was run
    :param frame_id: ``header.frame_id`` of the wrench, as the simulator's parameter
    :param output: ``pulse_width`` or ``recruitment``, as the player's parameter
    :param namespace: the namespace of the topics (``/`` for a default live run)
    :return: the bag directory
    :raises ValueError: on an unknown ``output``
    :raises hill_muscle_ros.recording.BagOutputError: if the directory cannot be used
    """
    if output not in STIMULATION_TOPICS:
        raise ValueError(f'`output` must be one of {", ".join(STIMULATION_TOPICS)}, '
                         f'got {output!r}')
    stim_topic, length_topic = _topic(namespace, output), _topic(namespace, 'length_command')
    force_topic, ce_topic = _topic(namespace, 'force'), _topic(namespace, 'ce_length')
    wrench_topic = _topic(namespace, 'wrench')
    custom = {'source': 'hill-muscle simulate (offline)', 'protocol': protocol.name,
              'units': params.units, 'length': params.length}
    with BagWriter(bag_dir, custom_data=custom) as writer:
        for topic, type_name in ((stim_topic, FLOAT64), (length_topic, FLOAT64),
                                 (force_topic, FLOAT64), (ce_topic, FLOAT64),
                                 (wrench_topic, WRENCH_STAMPED)):
            # What the live publishers (the player's and the simulator's outputs) offer.
            writer.add_topic(topic, type_name, offered_qos_profiles=[OUTPUT_QOS])
        wrench = WrenchStamped()
        wrench.header.frame_id = frame_id
        for k, t_s in enumerate(result.t_s):
            t_ns = round(float(t_s) * NS_PER_S)
            if t_s < protocol.duration_s:
                stim = protocol.stimulation_command(float(t_s), output, params)
                dl_mt = float(protocol.dl_mt(float(t_s)))
            else:
                # The player's last messages: the final length and zero stimulation.
                stim, dl_mt = 0.0, float(protocol.dl_mt(protocol.duration_s))
            writer.write(stim_topic, serialize_message(Float64(data=stim)), t_ns)
            writer.write(length_topic, serialize_message(Float64(data=dl_mt)), t_ns)
            force = float(result.force_n[k])
            writer.write(force_topic, serialize_message(Float64(data=force)), t_ns)
            writer.write(ce_topic, serialize_message(Float64(data=float(result.l_ce_m[k]))),
                         t_ns)
            wrench.header.stamp = Time(nanoseconds=t_ns).to_msg()
            wrench.wrench.force.x = force
            writer.write(wrench_topic, serialize_message(wrench), t_ns, t_ns)
    return Path(bag_dir)
