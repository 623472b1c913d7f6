"""A node's own ROS parameters: descriptors, declaring, and reading them back.

- :func:`number_descriptor` and :func:`field_descriptor`: descriptors with the
  unit and range; :func:`field_descriptor` from the model's
  :class:`~hill_muscle_ros.model.MuscleParams` field metadata, so the names,
  units and ranges have a single source.
- :func:`declare_checked`, :func:`declare_muscle_parameters` and
  :func:`declare_spec_fields`: declare them, a bad override as a
  :class:`~._process.StartupError`, and build the params dataclass.
- :func:`parameter_overrides` and :func:`declared_parameter_names`: what the
  node was started with and what it has declared.
"""
from __future__ import annotations

import dataclasses
from typing import Any

from rclpy.exceptions import (InvalidParameterTypeException,
                              InvalidParameterValueException)
from rclpy.node import Node
from rcl_interfaces.msg import (FloatingPointRange, IntegerRange,
                                ParameterDescriptor)
from rcl_interfaces.srv import ListParameters
from rclpy.parameter import Parameter

from ..model import MuscleParams
from ..model.params import CURVE_FIELDS, STIMULATOR_FIELDS, range_constraint
from ._process import StartupError


def number_descriptor(description: str, unit: str, low: float | int, high: float | int, *,
                      integer: bool = False, read_only: bool = False,
                      constraints: str = '') -> ParameterDescriptor:
    """A descriptor with the unit in the description and an inclusive range.

    :param description: what the parameter is
    :param unit: its unit, e.g. ``N/m`` (``-`` for a pure number)
    :param low: lowest accepted value
    :param high: highest accepted value
    :param integer: integer parameter (``IntegerRange``) instead of a double
    :param read_only: the parameter cannot change while the node runs
    :param constraints: extra constraints in words (``additional_constraints``)
    """
    desc = ParameterDescriptor(description=f'[{unit}] {description}', read_only=read_only,
                               additional_constraints=constraints)
    if integer:
        desc.integer_range = [IntegerRange(from_value=int(low), to_value=int(high), step=1)]
    else:
        desc.floating_point_range = [FloatingPointRange(from_value=float(low),
                                                        to_value=float(high), step=0.0)]
    return desc


def field_descriptor(field: dataclasses.Field, *, read_only: bool = False,
                     note: str = '') -> ParameterDescriptor:
    """The descriptor of one :class:`MuscleParams` field, from its metadata.

    :param field: a field of :class:`MuscleParams`
    :param read_only: the parameter cannot change while the node runs
    :param note: appended to the description (e.g. what a live change does)
    """
    spec = field.metadata
    description = spec['description'] + (f' ({note})' if note else '')
    if spec['choices'] is not None:
        return ParameterDescriptor(
            description=description, read_only=read_only,
            additional_constraints=f'one of: {", ".join(spec["choices"])}')
    if field.type == 'int':
        return number_descriptor(description, spec['unit'], spec['low'], spec['high'],
                                 integer=True, read_only=read_only)
    # No floating_point_range: a ROS range is closed, so none can say "> 0"
    # (from_value 0.0 would claim 0 is accepted), and rclpy checks a range
    # before the node's callback, answering with its range text instead of
    # the model's reason. The model checks these bounds; the words say them.
    each = 'each entry ' if field.type.startswith('tuple') else ''
    return ParameterDescriptor(
        description=f'[{spec["unit"]}] {description}', read_only=read_only,
        additional_constraints=f'{each}{range_constraint(spec)} (finite)')


#: Integer types ROS gives a value written without a decimal point (``45``,
#: ``[1, 2]``), and the double types they are read as for a double parameter.
_INTEGER_AS_DOUBLE = {Parameter.Type.INTEGER: Parameter.Type.DOUBLE,
                      Parameter.Type.INTEGER_ARRAY: Parameter.Type.DOUBLE_ARRAY}


def _as_double(param: Parameter, double_type: Parameter.Type) -> Parameter:
    """``param`` (an integer or integer array) as the double type ``double_type``."""
    value = param.value
    value = float(value) if double_type == Parameter.Type.DOUBLE else [float(v) for v in value]
    return Parameter(param.name, double_type, value)


def _is_double(value: Any) -> bool:
    """Whether ``value`` declares a double or double-array parameter."""
    if isinstance(value, (list, tuple)):
        return bool(value) and all(isinstance(v, float) for v in value)
    return isinstance(value, float)


def accept_integers_for_doubles(node: Node) -> None:
    """Let a live change (``ros2 param set``) give an integer to a double
    parameter, as the parameters file and ``-p`` may (:func:`declare_checked`):
    ``45`` is read as ``45.0``, ``[1, 2]`` as ``[1.0, 2.0]``. Once per node.
    """
    if getattr(node, '_hill_muscle_integers_as_doubles', False):
        return

    def to_doubles(params: list[Parameter]) -> list[Parameter]:
        out = []
        for p in params:
            double_type = _INTEGER_AS_DOUBLE.get(p.type_)
            if double_type is not None and node.has_parameter(p.name) \
                    and node.describe_parameter(p.name).type == double_type.value:
                p = _as_double(p, double_type)
            out.append(p)
        return out

    node.add_pre_set_parameters_callback(to_doubles)
    node._hill_muscle_integers_as_doubles = True   # noqa: SLF001 - our own mark


def declare_checked(node: Node, name: str, default: Any,
                    descriptor: ParameterDescriptor) -> Any:
    """Declare a parameter; turn a bad override into a :class:`StartupError`.

    rclpy raises on a wrong type or an out-of-range value from
    ``--params-file`` or ``-p``; the error names the parameter and the value.
    An integer for a double parameter (``f_iso_max_n: 45``) is read as a
    double (``45.0``), as the offline CLI reads the same file, at start-up and
    in a live change (:func:`accept_integers_for_doubles`).

    :return: the parameter's value (override or default)
    """
    accept_integers_for_doubles(node)
    given = parameter_overrides(node).get(name)  # only to quote it
    value = given.value if given is not None else default
    try:
        double_type = _INTEGER_AS_DOUBLE.get(given.type_) if given is not None else None
        if double_type is not None and _is_double(default):
            return node.declare_parameter(name, _as_double(given, double_type).value,
                                          descriptor, ignore_override=True).value
        return node.declare_parameter(name, default, descriptor).value
    except InvalidParameterTypeException:
        raise StartupError(
            f'parameter `{name}`: got {value!r} ({type(value).__name__}), expected a '
            f'{type(default).__name__} like {default!r}') from None
    except InvalidParameterValueException as err:
        # rclpy 7.1.6 keeps the descriptor's reason only inside the message,
        # 'Invalid parameter value (v) for parameter. Reason: <reason>: <name>',
        # with no attribute for it; without that marker the whole message is quoted.
        reason = str(err).split('Reason: ', 1)[-1]
        raise StartupError(f'parameter `{name}` = {value!r} rejected: {reason}') from None


#: What a live change of a muscle parameter does (doc/nodes.md, "Simulator parameters").
#: With ``activation_model: first_order`` the recruitment curve (``pw_max_s``
#: and the curve's fields) and the stimulator's fields only act in the node
#: (a pulse width to the level command, a command checked against the
#: device), so they can change with the state kept.
LIVE_KEEPS_STATE = CURVE_FIELDS + STIMULATOR_FIELDS
#: The model core builds its step from the other parameters once, when the
#: muscle is made, so a live change rebuilds the muscle at rest.
LIVE_RESETS = tuple(n for n in MuscleParams.field_names() if n not in LIVE_KEEPS_STATE)
#: With ``activation_model: ding2003`` the muscle maps each pulse through the
#: curve and the strength-duration law and times its trains itself: only the
#: stimulator whose limits the node checks keeps the state.
PULSED_LIVE_KEEPS_STATE = ('stimulator',)


def keeps_state(name: str, params: MuscleParams) -> bool:
    """Whether a live change of the field ``name`` keeps the state of a muscle
    with ``params`` (see :data:`LIVE_KEEPS_STATE`, :data:`PULSED_LIVE_KEEPS_STATE`)."""
    if params.activation_model == 'first_order':
        return name in LIVE_KEEPS_STATE
    return name in PULSED_LIVE_KEEPS_STATE


def _live_note(name: str) -> str:
    """What a live change of ``name`` does, for its descriptor."""
    if name in PULSED_LIVE_KEEPS_STATE:
        return 'live, state kept'
    if name in LIVE_KEEPS_STATE:
        return ('live; state kept with activation_model first_order, a change resets the '
                'muscle to rest with ding2003')
    return 'live, a change resets the muscle to rest'


def declare_muscle_parameters(node: Node) -> MuscleParams:
    """Declare one ROS parameter per :class:`MuscleParams` field and build it.

    Defaults are the paper's values; overrides come from ``--params-file`` or
    ``-p``. All are live: see :func:`keeps_state`.

    :raises StartupError: naming the parameter and value if any is invalid
    """
    defaults = MuscleParams()
    values = {}
    for f in dataclasses.fields(MuscleParams):
        values[f.name] = declare_checked(node, f.name, getattr(defaults, f.name),
                                         field_descriptor(f, note=_live_note(f.name)))
    try:
        return MuscleParams(**values)
    except ValueError as err:
        raise StartupError(f'parameter {err}') from None


def declare_spec_fields(node: Node, cls: type, read_only: tuple[str, ...] = ()) -> dict:
    """Declare every field of a controller's parameter dataclass, with a
    descriptor from its metadata (unit, range or choices), and return the values.

    :param cls: a frozen dataclass whose fields carry ``_spec`` metadata
    :param read_only: the fields that cannot change while the node runs
    :raises StartupError: on a bad override (:func:`declare_checked`)
    """
    defaults = cls()
    values = {}
    for f in dataclasses.fields(cls):
        spec = f.metadata
        if spec['choices'] is not None:
            descriptor = ParameterDescriptor(
                description=spec['description'],
                additional_constraints=f'one of: {", ".join(spec["choices"])}')
        else:
            descriptor = number_descriptor(spec['description'], spec['unit'], spec['low'],
                                           spec['high'], read_only=f.name in read_only)
        values[f.name] = declare_checked(node, f.name, getattr(defaults, f.name), descriptor)
    return values


def parameter_overrides(node: Node) -> dict[str, Parameter]:
    """The overrides the node was started with (``--params-file``, ``-p``), by name.

    rclpy 7.1.6 has no public accessor for them: ``Node`` keeps them in
    ``_parameter_overrides`` (and the rcl getter is on its private
    ``_rclpy`` node handle). This is the one place that reads that attribute;
    ``test_node_common.py`` pins what it returns, so an rclpy that changes
    it fails there. A copy is returned.
    """
    return dict(node._parameter_overrides)  # noqa: SLF001 - no public API in rclpy 7.1.6


def declared_parameter_names(node: Node) -> list[str]:
    """Every parameter the node has declared, sorted (public ``Node.list_parameters``)."""
    return sorted(node.list_parameters([], ListParameters.Request.DEPTH_RECURSIVE).names)
