"""A limb plant's parameters addressed by their dotted names.

The plant file names each parameter ``<part>.<field>``, as the limb node's ROS
parameters do: ``joint.damping_n_m_s_per_rad`` for a field of the joint,
``quadriceps.moment_arm_m`` or ``quadriceps.reference_angle_rad`` for a
muscle's place on the joint, ``quadriceps.f_iso_max_n`` for one of its
:class:`~hill_muscle_ros.model.params.MuscleParams`. The fit (``--fit``) and
the sweep (``vary``) both address a plant this way; this module resolves such
a name, reads the value and builds a plant with values replaced.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any, Mapping

from .limb import ANGLE_LIMIT_RAD, JointParams, LimbMuscle, LimbPlant
from .params import MuscleParams

#: The first part of a name that addresses the joint (the plant file's section).
JOINT_PART = 'joint'
#: Where a name's field lives: the joint, the limb muscle itself (its place on
#: the joint) or the muscle's parameters.
JOINT, GEOMETRY, PARAMS = 'joint', 'geometry', 'params'
#: A muscle's place on the joint, addressable besides its muscle parameters, with
#: its unit and range as :class:`~hill_muscle_ros.model.limb.LimbMuscle` checks it:
#: the moment arm in (0, 1] m, the reference angle within two turns. ``action``
#: is a choice of sign, not a parameter.
GEOMETRY_FIELDS = {'moment_arm_m': ('m', 0.0, 1.0),
                   'reference_angle_rad': ('rad', -ANGLE_LIMIT_RAD, ANGLE_LIMIT_RAD)}

_JOINT_FIELDS = {f.name: f for f in dataclasses.fields(JointParams) if f.name != 'name'}
_GEOMETRY = {f.name: f for f in dataclasses.fields(LimbMuscle) if f.name in GEOMETRY_FIELDS}
_PARAMS = {f.name: f for f in dataclasses.fields(MuscleParams)}


class PlantNameError(ValueError):
    """A dotted name that addresses no parameter of the plant."""


@dataclass(frozen=True)
class PlantField:
    """One parameter of a plant, resolved from its dotted name.

    :param part: ``joint`` or the muscle's name
    :param where: :data:`JOINT`, :data:`GEOMETRY` or :data:`PARAMS`
    :param spec: the dataclass field (of :class:`~hill_muscle_ros.model.limb.JointParams`,
        :class:`~hill_muscle_ros.model.limb.LimbMuscle` or
        :class:`~hill_muscle_ros.model.params.MuscleParams`)
    """

    part: str
    where: str
    spec: dataclasses.Field

    @property
    def field(self) -> str:
        """The field's name within its dataclass."""
        return self.spec.name

    @property
    def name(self) -> str:
        """The dotted name, as the plant file writes it."""
        return f'{self.part}.{self.field}'

    @property
    def unit(self) -> str:
        if self.where == GEOMETRY:
            return GEOMETRY_FIELDS[self.field][0]
        return self.spec.metadata['unit']

    @property
    def low(self) -> float:
        """Lower end of the field's range (a real field; see the dataclass for the ends)."""
        return float(GEOMETRY_FIELDS[self.field][1] if self.where == GEOMETRY
                     else self.spec.metadata['low'])

    @property
    def high(self) -> float:
        """Upper end of the field's range."""
        return float(GEOMETRY_FIELDS[self.field][2] if self.where == GEOMETRY
                     else self.spec.metadata['high'])


def plant_field(name: str, plant: LimbPlant, label: str = '') -> PlantField:
    """Resolve the dotted name ``name`` against ``plant``.

    :param name: ``joint.<field>`` or ``<muscle>.<field>``
    :param plant: the plant whose muscles the name may address
    :param label: what the user wrote before the name (``vary.``), for the messages
    :raises PlantNameError: naming the name and the valid choices
    """
    muscles = [m.name for m in plant.muscles]
    parts = ', '.join([JOINT_PART] + muscles)
    part, dot, field = name.partition('.')
    if not dot or not field:
        raise PlantNameError(
            f'`{label}{name}`: on a limb, name the joint or the muscle first, as the plant '
            f'file does, e.g. `{JOINT_PART}.damping_n_m_s_per_rad` or '
            f'`{muscles[0] if muscles else "muscle"}.f_iso_max_n` (parts: {parts})')
    if part == JOINT_PART:
        spec = _JOINT_FIELDS.get(field)
        if spec is None:
            raise PlantNameError(f'unknown parameter `{label}{name}` of the joint (known: '
                                 f'{", ".join(f"{JOINT_PART}.{k}" for k in _JOINT_FIELDS)})')
        return PlantField(part, JOINT, spec)
    if part not in muscles:
        raise PlantNameError(f'`{label}{name}`: the plant has no joint or muscle `{part}` '
                             f'(parts: {parts})')
    if field in _GEOMETRY:
        return PlantField(part, GEOMETRY, _GEOMETRY[field])
    spec = _PARAMS.get(field)
    if spec is None:
        raise PlantNameError(f'unknown parameter `{label}{name}` of muscle `{part}` (known: '
                             f'{", ".join([*_GEOMETRY, *_PARAMS])})')
    return PlantField(part, PARAMS, spec)


def plant_value(plant: LimbPlant, name: str) -> Any:
    """The value of the parameter ``name`` of ``plant`` (a tuple for a list field).

    :raises PlantNameError: if ``name`` addresses no parameter of ``plant``
    """
    p = plant_field(name, plant)
    if p.where == JOINT:
        return getattr(plant.joint, p.field)
    muscle = next(m for m in plant.muscles if m.name == p.part)
    return getattr(muscle if p.where == GEOMETRY else muscle.params, p.field)


def replaced_plant(plant: LimbPlant, changes: Mapping[str, Any]) -> LimbPlant:
    """A copy of ``plant`` with the parameters ``changes`` (by dotted name) replaced,
    each validated by its own dataclass (the joint, the limb muscle, the muscle's
    parameters) as on construction.

    :raises PlantNameError: if a name addresses no parameter of ``plant``
    :raises ValueError: (or TypeError) for a value its dataclass rejects
    """
    by_where: dict[tuple[str, str], dict[str, Any]] = {}
    for name, value in changes.items():
        p = plant_field(name, plant)
        by_where.setdefault((p.part, p.where), {})[p.field] = value
    joint = by_where.get((JOINT_PART, JOINT))
    muscles = []
    for m in plant.muscles:
        params = by_where.get((m.name, PARAMS))
        geometry = by_where.get((m.name, GEOMETRY), {})
        if params:
            m = dataclasses.replace(m, params=m.params.replace(**params), **geometry)
        elif geometry:
            m = dataclasses.replace(m, **geometry)
        muscles.append(m)
    return dataclasses.replace(
        plant, joint=dataclasses.replace(plant.joint, **joint) if joint else plant.joint,
        muscles=tuple(muscles))
