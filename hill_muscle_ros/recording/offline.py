"""Write an offline simulation as a bag with the topics and types of a live run.

A live run has the protocol player publish the stimulation and
``length_command`` and the simulator publish ``force``, ``ce_length`` and
``wrench`` once per step (:func:`write_simulation_bag`). A live limb run has
each muscle's stimulation (``<muscle>/pulse_width`` or
``<muscle>/recruitment``) and ``external_torque`` given to the limb node,
which publishes ``joint_states`` and each muscle's ``<muscle>/force`` and
``<muscle>/wrench`` once per step (:func:`write_limb_bag`). The offline bag
holds the same messages, serialized
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
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64

from ..model import MuscleParams, Protocol
from ..model.limb import LimbPlant, LimbProtocol, LimbResult
from ..model.simulate import SimulationResult
from ..qos import OUTPUT_QOS
from ..timebase import NS_PER_S
from .bag_writer import BagWriter

FLOAT64 = 'std_msgs/msg/Float64'
WRENCH_STAMPED = 'geometry_msgs/msg/WrenchStamped'
JOINT_STATE = 'sensor_msgs/msg/JointState'
#: A limb protocol's stimulation key -> the limb node's topic for it (per muscle).
LIMB_STIMULATION_TOPICS = {'pulse_width_s': 'pulse_width', 'recruitment': 'recruitment'}
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


def write_limb_bag(bag_dir: str | os.PathLike, result: LimbResult, plant: LimbPlant,
                   protocol: LimbProtocol, *, namespace: str = '/') -> Path:
    """Write an offline limb run as a rosbag2 MCAP bag in simulated time, with
    the topics and types the limb node subscribes and publishes.

    Inputs, as a player gives them to the node: each muscle's stimulation on
    ``<muscle>/pulse_width`` [s] or ``<muscle>/recruitment`` [-] (the
    protocol's key; a muscle the protocol omits gets recruitment 0, as the
    limb does) and ``external_torque`` [N m], at each sample t_k < duration,
    and 0 at the end. Outputs at every sample of ``result`` (t = 0 included),
    as the node publishes after each step: ``joint_states`` (the joint's name,
    theta [rad], omega [rad/s], the net muscle torque sum s_i r_i F_i [N m] as
    the effort), each muscle's ``<muscle>/force`` [N] and ``<muscle>/wrench``
    (force along +x, frame_id the muscle's name).

    :param bag_dir: the bag directory (must not exist or be empty)
    :param result: the offline run (:func:`hill_muscle_ros.model.limb.simulate_limb`)
    :param plant: the plant of the run
    :param protocol: the limb protocol that was run
    :param namespace: the namespace of the topics (``/`` for a default live run)
    :return: the bag directory
    :raises hill_muscle_ros.recording.BagOutputError: if the directory cannot be used
    """
    inputs = []   # (topic, [-] or [s] or [N m] knots of the values at the samples)
    for m in plant.muscles:
        key, knots = protocol.stimulation.get(m.name, ('recruitment', None))
        inputs.append((_topic(namespace, f'{m.name}/{LIMB_STIMULATION_TOPICS[key]}'), knots))
    inputs.append((_topic(namespace, 'external_torque'), protocol.external_torque_n_m))
    joint_topic = _topic(namespace, 'joint_states')
    force_topics = [_topic(namespace, f'{m.name}/force') for m in plant.muscles]
    wrench_topics = [_topic(namespace, f'{m.name}/wrench') for m in plant.muscles]
    custom = {'source': 'hill-muscle simulate --plant (offline)', 'protocol': protocol.name,
              'joint': plant.joint.name}
    # [m] s_i r_i of each muscle, in the plant's order (Limb.outputs' torque).
    s_r = [m.sign * m.moment_arm_m for m in plant.muscles]
    forces = [result[f'{m.name}_force_n'] for m in plant.muscles]
    with BagWriter(bag_dir, custom_data=custom) as writer:
        for topic, _ in inputs:
            writer.add_topic(topic, FLOAT64, offered_qos_profiles=[OUTPUT_QOS])
        writer.add_topic(joint_topic, JOINT_STATE, offered_qos_profiles=[OUTPUT_QOS])
        for force_topic, wrench_topic in zip(force_topics, wrench_topics):
            writer.add_topic(force_topic, FLOAT64, offered_qos_profiles=[OUTPUT_QOS])
            writer.add_topic(wrench_topic, WRENCH_STAMPED, offered_qos_profiles=[OUTPUT_QOS])
        joint = JointState()
        joint.name = [plant.joint.name]
        wrenches = [WrenchStamped() for _ in plant.muscles]
        for m, wrench in zip(plant.muscles, wrenches):
            wrench.header.frame_id = m.name   # the muscle's own frame, as the node's
        theta, omega = result['theta_rad'], result['omega_rad_per_s']
        for k, t_s in enumerate(result.t_s):
            t = float(t_s)
            t_ns = round(t * NS_PER_S)
            for topic, knots in inputs:
                value = float(knots(t)) if knots is not None and t < protocol.duration_s else 0.0
                writer.write(topic, serialize_message(Float64(data=value)), t_ns)
            stamp = Time(nanoseconds=t_ns).to_msg()
            torque = 0.0
            for arm, force in zip(s_r, forces):
                torque += arm * float(force[k])
            joint.header.stamp = stamp
            joint.position = [float(theta[k])]
            joint.velocity = [float(omega[k])]
            joint.effort = [torque]
            writer.write(joint_topic, serialize_message(joint), t_ns, t_ns)
            for i, wrench in enumerate(wrenches):
                force = float(forces[i][k])
                writer.write(force_topics[i], serialize_message(Float64(data=force)), t_ns)
                wrench.header.stamp = stamp
                wrench.wrench.force.x = force
                writer.write(wrench_topics[i], serialize_message(wrench), t_ns, t_ns)
    return Path(bag_dir)
