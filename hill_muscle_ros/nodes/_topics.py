"""The package's topics on a node: QoS overrides, publishers and subscriptions.

- :data:`PACKAGE_TOPICS` (with :data:`DIAGNOSTICS_TOPIC`): the topics a QoS
  override may name.
- :func:`overridable_publisher` and :func:`overridable_subscription`: the
  standard ``qos_overrides.<topic>.<publisher|subscription>.<policy>``
  parameters on every publisher and subscription, checked at start-up by
  :func:`check_qos_overrides`.
- :func:`publish_last`: a stopping node's last messages, acknowledged.

The QoS profiles themselves (:data:`~hill_muscle_ros.qos.RELIABLE_QOS`,
:data:`~hill_muscle_ros.qos.OUTPUT_QOS`) are in :mod:`hill_muscle_ros.qos`.
"""
from __future__ import annotations

import copy
import time
from typing import Any, Callable

from rclpy.exceptions import (InvalidParameterTypeException,
                              InvalidParameterValueException)
from rclpy.node import Node
from rclpy.duration import Duration
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.qos_overriding_options import InvalidQosOverridesError, QoSOverridingOptions
from rclpy.parameter import Parameter

from ._parameters import declared_parameter_names, parameter_overrides
from ._process import StartupError

#: Absolute by ROS convention: one diagnostics topic per graph.
DIAGNOSTICS_TOPIC = '/diagnostics'

#: Every parameter of a QoS override starts with this (rclpy's naming).
QOS_OVERRIDES_PREFIX = 'qos_overrides.'
#: The entity kinds of ``qos_overrides.<topic>.<kind>.<policy>``.
QOS_OVERRIDE_KINDS = ('publisher', 'subscription')
#: The policies a user may override on the package's publishers and
#: subscriptions: rclpy's default set (history, depth, reliability). Durability
#: stays volatile: a late joiner must not be sent old commands.
QOS_OVERRIDE_POLICIES = tuple(p.name.lower() for p in
                              QoSOverridingOptions.with_default_policies().policy_kinds)
#: Accepted values of the enum policies (rclpy maps the names to its enums;
#: ``unknown`` is not a profile anyone can ask for).
QOS_POLICY_VALUES = {
    'history': tuple(m.lower() for m in HistoryPolicy.__members__ if m != 'UNKNOWN'),
    'reliability': tuple(m.lower() for m in ReliabilityPolicy.__members__ if m != 'UNKNOWN'),
}
#: Topics of the package's nodes, as they name them (relative names resolve in
#: a node's namespace and through its remappings): a QoS override of any of
#: them is valid in a shared ``/**`` section, as other nodes' parameters are.
PACKAGE_TOPICS = ('pulse_width', 'recruitment', 'stimulation', 'length_command',
                  'length_command_stamped', 'force', 'ce_length', 'wrench',
                  'recruitment_state', 'fitness', 'activation', 'force_target', '/clock',
                  DIAGNOSTICS_TOPIC)


def _qos_override_parts(name: str) -> tuple[str, str, str] | None:
    """``(topic, kind, policy)`` of ``qos_overrides.<topic>.<kind>.<policy>``, else ``None``.

    ROS names have no dots, so the last two dots split the kind and the policy off.
    """
    parts = name[len(QOS_OVERRIDES_PREFIX):].rsplit('.', 2)
    return tuple(parts) if len(parts) == 3 else None


def check_qos_override(name: str, value: Any, topics: Any) -> None:
    """Validate one ``qos_overrides.*`` override: its name, then its value.

    :param name: the parameter name, ``qos_overrides.<topic>.<kind>.<policy>``
    :param value: its value from the params file or ``-p``
    :param topics: the resolved topic names an override may name
    :raises StartupError: naming the parameter, the value and what is accepted
    """
    form = (f'a QoS override is `qos_overrides.<topic>.<{"|".join(QOS_OVERRIDE_KINDS)}>'
            f'.<{"|".join(QOS_OVERRIDE_POLICIES)}>`')
    parts = _qos_override_parts(name)
    if parts is None:
        raise StartupError(f'unknown parameter `{name}` (got {value!r}): {form}')
    topic, kind, policy = parts
    if kind not in QOS_OVERRIDE_KINDS or policy not in QOS_OVERRIDE_POLICIES:
        raise StartupError(f'unknown parameter `{name}` (got {value!r}): {form}')
    if topic not in topics:
        raise StartupError(f'unknown parameter `{name}` (got {value!r}): `{topic}` is none of '
                           f'the package\'s topics here ({", ".join(sorted(topics))}); a QoS '
                           'override names the topic resolved (namespace included)')
    if policy == 'depth':
        # bool is an int in Python; a depth of true is a typo, not 1.
        if not isinstance(value, int) or isinstance(value, bool) or value < 1:
            raise StartupError(f'parameter `{name}` = {value!r} rejected: the depth must be an '
                               'integer of at least 1')
    elif not isinstance(value, str) or value not in QOS_POLICY_VALUES[policy]:
        raise StartupError(f'parameter `{name}` = {value!r} rejected: expected one of '
                           f'{", ".join(QOS_POLICY_VALUES[policy])}')


def check_qos_overrides(node: Node, names: Any, extra_topics: Any = ()) -> None:
    """Validate the node's ``qos_overrides.*`` overrides among ``names``.

    An override may name any of :data:`PACKAGE_TOPICS` as this node resolves
    it (one ``/**`` section may configure every node), any of ``extra_topics``
    (resolved names), or any topic of a QoS parameter the node has declared.

    :raises StartupError: on the first invalid one (see :func:`check_qos_override`)
    """
    topics = {node.resolve_topic_name(t) for t in PACKAGE_TOPICS} | set(extra_topics)
    for declared in declared_parameter_names(node):
        if declared.startswith(QOS_OVERRIDES_PREFIX):
            topics.add(_qos_override_parts(declared)[0])
    overrides = parameter_overrides(node)
    for name in sorted(names):
        if name.startswith(QOS_OVERRIDES_PREFIX):
            check_qos_override(name, overrides[name].value, topics)


def qos_overrides_of(node: Node) -> list[Parameter]:
    """The node's ``qos_overrides.*`` overrides, e.g. to hand to a helper node."""
    return [p for n, p in parameter_overrides(node).items() if n.startswith(QOS_OVERRIDES_PREFIX)]


def overridable_qos(qos: QoSProfile) -> tuple[QoSProfile, QoSOverridingOptions]:
    """A copy of ``qos`` and the options that let rclpy override it.

    rclpy writes the overrides into the profile it is given, so a shared
    profile (:data:`OUTPUT_QOS`) must never be passed itself: one override
    would change every later publisher of the process.
    """
    return copy.copy(qos), QoSOverridingOptions.with_default_policies()


def _created_with_overrides(create: Callable[..., Any], node: Node, topic: str,
                            *args: Any, **kwargs: Any) -> Any:
    """Run ``create`` and turn rclpy's errors on a bad override into a :class:`StartupError`.

    :func:`check_qos_overrides` has normally caught them at start-up already.
    """
    try:
        return create(*args, **kwargs)
    except (InvalidQosOverridesError, InvalidParameterTypeException,
            InvalidParameterValueException, RuntimeError) as err:
        raise StartupError(f'QoS override of `{node.resolve_topic_name(topic)}` rejected: '
                           f'{err}') from None


def overridable_publisher(node: Node, msg_type: Any, topic: str, qos: QoSProfile,
                          **kwargs: Any) -> Any:
    """``node.create_publisher`` with ``qos`` as the default and the standard overrides.

    Declares ``qos_overrides.<topic>.publisher.{history,depth,reliability}``
    (read-only) with ``qos``'s values; ``--params-file`` or ``-p`` may set them.

    :raises StartupError: on an invalid override value
    """
    profile, options = overridable_qos(qos)
    return _created_with_overrides(node.create_publisher, node, topic, msg_type, topic,
                                   profile, qos_overriding_options=options, **kwargs)


def overridable_subscription(node: Node, msg_type: Any, topic: str, callback: Callable,
                             qos: QoSProfile, **kwargs: Any) -> Any:
    """``node.create_subscription`` with ``qos`` as the default and the standard overrides.

    Declares ``qos_overrides.<topic>.subscription.{history,depth,reliability}``.

    :raises StartupError: on an invalid override value
    """
    profile, options = overridable_qos(qos)
    return _created_with_overrides(node.create_subscription, node, topic, msg_type, topic,
                                   callback, profile, qos_overriding_options=options, **kwargs)


#: [s] how long a node that stops waits for its subscribers to acknowledge
#: its last messages (reliable QoS). Without a wait, a zero stimulation
#: published on exit could die with the process (rmw_fastrtps publishes
#: asynchronously; 2 of 4 controller stops lost it on a loaded machine).
#: Fast DDS readers acknowledge on the writer's heartbeat, every 3 s by
#: default, so the wait often ends by this timeout, not by the
#: acknowledgement: its job is to keep the writer alive until the message
#: is out.
FINAL_ACK_TIMEOUT_S = 1.0


def publish_last(publishers_and_messages, timeout_s: float = FINAL_ACK_TIMEOUT_S) -> bool:
    """Publish each message and wait until every subscriber acknowledged it.

    :param publishers_and_messages: (publisher, message) pairs
    :param timeout_s: [s] longest wait, for all of them together
    :return: whether every publisher's messages were acknowledged in time
    """
    pairs = list(publishers_and_messages)
    for pub, msg in pairs:
        pub.publish(msg)
    deadline = time.monotonic() + timeout_s   # one wait for all, not one each
    acked = True
    for pub, _ in pairs:
        left = max(deadline - time.monotonic(), 0.0)
        acked = pub.wait_for_all_acked(Duration(seconds=left)) and acked
    return acked
