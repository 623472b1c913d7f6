"""Sorting the overrides a node was started with (``--params-file``, ``-p``).

One ``/**`` section of a params file may configure every node of the
package, so a node passes over the other nodes' parameters
(:data:`OTHER_NODE_PARAMETERS`), reads the plant's among them
(:func:`plant_values`, :func:`declare_plant`, :func:`require_muscles`; the
limb node and the joint controller, which one plant file configures) and
stops start-up on a name no node has (:func:`reject_unknown_overrides`).
"""
from __future__ import annotations

import dataclasses
from array import array
from typing import TYPE_CHECKING

from rclpy.exceptions import (InvalidParameterTypeException,
                              InvalidParameterValueException)
from rclpy.node import Node
from rcl_interfaces.msg import ParameterDescriptor
from rclpy.parameter import Parameter

from .. import resources
from ..control.joint import JOINT_CONTROLLER_KEYS
from ..model import MuscleParams
from ..params_file import SIMULATOR_NODE_KEYS
from ._diagnostics import DIAGNOSTICS_PERIOD_PARAMETER
from ._parameters import declared_parameter_names, parameter_overrides
from ._process import StartupError
from ._topics import QOS_OVERRIDES_PREFIX, check_qos_overrides

if TYPE_CHECKING:
    from ..model.limb import LimbPlant

#: Parameters of this package's nodes other than the muscle's and the
#: controller's fields. A shared ``/**`` section of a params file may carry any
#: of them, so a node passes over the other nodes' names.
OTHER_NODE_PARAMETERS = frozenset((
    *SIMULATOR_NODE_KEYS,                                   # simulator
    'protocol', 'output', 'wait_for_subscribers_s',         # protocol_player
    'lookahead_s', 'min_subscribers',
    'topics',                                               # recorder (and `output`)
    *JOINT_CONTROLLER_KEYS,                                 # joint_controller
))
#: Parameters of the limb node that are not part of the plant (the joint
#: controller, configured by the same plant file, passes over them too).
LIMB_NODE_PARAMETERS = ('rate_hz', 'real_time_factor', 'input_timeout_s', 'publish_clock')


def plant_values(overrides: dict[str, Parameter], own: tuple[str, ...] = ()
                 ) -> dict[str, object]:
    """The plant's entries among a node's parameter overrides, by dotted name.

    The node's own parameters (``own``), the other nodes' of the package (one
    ``/**`` section may configure them all), the diagnostics period every node
    declares and QoS overrides are left out; everything else belongs to the
    plant, which rejects what it does not know.

    :param overrides: the node's overrides by name (:func:`parameter_overrides`)
    :param own: the node's own parameter names
    :return: name to Python value; ROS arrays as lists
    """
    values = {}
    for name, param in overrides.items():
        if (name in own or name in OTHER_NODE_PARAMETERS
                or name == DIAGNOSTICS_PERIOD_PARAMETER
                or name.startswith(QOS_OVERRIDES_PREFIX)):
            continue
        value = param.value
        values[name] = list(value) if isinstance(value, (array, tuple)) else value
    return values


def declare_plant(node: Node, values: dict[str, object]) -> None:
    """Declare a plant's parameters read-only, so ``ros2 param`` shows them.

    :raises StartupError: naming a parameter ROS cannot hold
    """
    for name in sorted(values):
        try:
            node.declare_parameter(name, values[name], ParameterDescriptor(
                description='plant parameter (read-only)', read_only=True))
        except (InvalidParameterTypeException, InvalidParameterValueException,
                TypeError) as err:
            raise StartupError(f'plant parameter `{name}` = {values[name]!r}: '
                               f'{err}') from None


def require_muscles(plant: LimbPlant) -> None:
    """Stop start-up for a plant without muscles: the node was most likely
    started without its plant file, and a bare joint would run silently.

    :raises StartupError: naming ``--params-file`` and the shipped knee preset
    """
    if not plant.muscles:
        raise StartupError(
            '`muscles` must name at least one muscle, got none: give the plant file with '
            f'--ros-args --params-file PLANT.yaml, e.g. the knee preset '
            f'{resources.knee_plant_file()}')


def reject_unknown_overrides(node: Node) -> None:
    """Stop start-up on an override that no node of this package has.

    Such a key is a typo (``k_se`` for ``k_se_n_per_m``): running on would
    silently use the default in its place. Keys of this package's other nodes
    are passed over, since one ``/**`` section may configure them all.

    :raises StartupError: naming the first unknown parameter and its value
    """
    from ..control import ControllerParams  # the controller's field names

    declared = declared_parameter_names(node)
    known = (set(declared)
             | set(MuscleParams.field_names())
             | {f.name for f in dataclasses.fields(ControllerParams)}
             | OTHER_NODE_PARAMETERS
             | {DIAGNOSTICS_PERIOD_PARAMETER})   # NodeDiagnostics declares it
    overrides = parameter_overrides(node)
    unknown = sorted(set(overrides) - known)
    # QoS overrides are declared with the publishers, after this check: their
    # names and values are checked against the package's topics instead.
    check_qos_overrides(node, unknown)
    unknown = [n for n in unknown if not n.startswith(QOS_OVERRIDES_PREFIX)]
    if unknown:
        name = unknown[0]
        raise StartupError(
            f'unknown parameter `{name}` (got {overrides[name].value!r}); '
            f'this node has: {", ".join(declared)}')
