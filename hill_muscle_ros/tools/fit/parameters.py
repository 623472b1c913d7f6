"""What a fit estimates: the fitted quantities, named as the user names them.

:class:`FitParameter` is one real field (or one list entry) of the muscle's
:class:`~hill_muscle_ros.model.params.MuscleParams`, :class:`PlantParameter`
one of a limb plant, named as the plant file does (``joint.damping_n_m_s_per_rad``,
``quadriceps.f_iso_max_n``); the parsers turn ``--fit NAME[,NAME...]`` into
them. :class:`FitError` is every user error of a fit.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any, Sequence

from ...model import MuscleParams
from ...model.limb import JointParams, LimbPlant
from ...model.plant_fields import (GEOMETRY_FIELDS, JOINT_PART, PARAMS, PlantNameError,
                                   plant_field, plant_value, replaced_plant)


class FitError(ValueError):
    """A user error of a fit (bag, topic, parameter name): the message names it."""


class NotIdentifiableError(FitError):
    """The force does not determine some of the fitted parameters.

    :param names: the parameters concerned
    :param message: why, in words
    """

    def __init__(self, names: Sequence[str], message: str) -> None:
        super().__init__(message)
        self.names = tuple(names)


@dataclass(frozen=True)
class FitParameter:
    """One fitted quantity: a float field of the parameters, or one entry of a
    per-fibre-type list (``tau_fatigue_s`` for a list of one, ``tau_fatigue_s[1]``).

    :param field: the dataclass field name
    :param index: the list entry, or ``None`` for a float field
    :param unit: the field's unit
    :param low: lower bound of the field's range
    :param high: upper bound of the field's range
    :param named_by_index: the user wrote ``field[i]`` (else a list of one: ``field``)
    """

    field: str
    index: int | None
    unit: str
    low: float
    high: float
    named_by_index: bool = False

    @property
    def name(self) -> str:
        """The name as the user writes it in ``--fit``."""
        return f'{self.field}[{self.index}]' if self.named_by_index else self.field

    def get(self, params: Any) -> float:
        value = getattr(params, self.field)
        return float(value if self.index is None else value[self.index])

    def set(self, params: Any, value: float) -> Any:
        """A copy of ``params`` with this quantity set (validated on construction)."""
        if self.index is None:
            return params.replace(**{self.field: float(value)})
        values = list(getattr(params, self.field))
        values[self.index] = float(value)
        return params.replace(**{self.field: tuple(values)})


def parse_fit_names(text: str, params: MuscleParams, prefix: str = '') -> list[FitParameter]:
    """The fitted quantities that ``--fit NAME[,NAME...]`` names.

    :param text: comma-separated field names, optionally ``name[i]`` for a list entry
    :param params: the start parameters (for list lengths)
    :param prefix: what the user wrote before these names (``quadriceps.`` on a
        limb), for the messages
    :raises FitError: naming an unknown, repeated or non-float name
    """
    fields = {f.name: f for f in dataclasses.fields(MuscleParams)}
    out: list[FitParameter] = []
    for raw in text.split(','):
        name = raw.strip()
        if not name:
            raise FitError(f'--fit: empty parameter name in {text!r}')
        field_name, index = name, None
        if name.endswith(']') and '[' in name:
            field_name, _, rest = name[:-1].partition('[')
            try:
                index = int(rest)
            except ValueError:
                raise FitError(f'--fit: `{prefix}{name}`: the index must be an integer') from None
        f = fields.get(field_name)
        if f is None:
            raise FitError(f'--fit: unknown parameter `{prefix}{name}` (fittable: '
                           f'{", ".join(fittable_names())})')
        spec = f.metadata
        if spec['choices'] is not None or f.type == 'int':
            raise FitError(f'--fit: `{prefix}{name}` cannot be fitted: it is not a real number '
                           f'({"a choice" if spec["choices"] else "an integer"})')
        is_list = f.type.startswith('tuple')
        if is_list:
            n = len(getattr(params, field_name))
            if index is None:
                if n != 1:
                    raise FitError(f'--fit: `{prefix}{name}` has {n} entries: name one, e.g. '
                                   f'`{prefix}{field_name}[0]`')
                index = 0
            elif not 0 <= index < n:
                raise FitError(f'--fit: `{prefix}{name}`: index out of range, the start '
                               f'parameters give {n} entries')
        elif index is not None:
            raise FitError(f'--fit: `{prefix}{name}`: `{field_name}` is not a list')
        param = FitParameter(field_name, index if is_list else None, spec['unit'],
                             float(spec['low']), float(spec['high']), name != field_name)
        if any(p.name == param.name for p in out):
            raise FitError(f'--fit: `{prefix}{param.name}` is named twice')
        out.append(param)
    return out


def fittable_names() -> list[str]:
    """Names of the fields that can be fitted (real numbers and lists of them)."""
    return [f.name for f in dataclasses.fields(MuscleParams)
            if f.metadata['choices'] is None and f.type != 'int']


@dataclass(frozen=True)
class PlantParameter:
    """One fitted quantity of a limb plant, named as the plant file's ROS parameter
    (``joint.damping_n_m_s_per_rad``, ``quadriceps.f_iso_max_n``,
    ``quadriceps.moment_arm_m``, ``quadriceps.tau_fatigue_s[1]``).

    :param part: ``joint`` or the muscle's name
    :param inner: the field within :class:`~hill_muscle_ros.model.limb.JointParams`,
        :class:`~hill_muscle_ros.model.limb.LimbMuscle` (its geometry) or the
        muscle's :class:`~hill_muscle_ros.model.params.MuscleParams`
    :param where: ``joint``, ``geometry`` or ``params``
        (:mod:`~hill_muscle_ros.model.plant_fields`)
    """

    part: str
    inner: FitParameter
    where: str

    @property
    def name(self) -> str:
        """The name as the user writes it in ``--fit``."""
        return f'{self.part}.{self.inner.name}'

    @property
    def path(self) -> str:
        """The plant field's dotted name (a list's, without the entry)."""
        return f'{self.part}.{self.inner.field}'

    @property
    def field(self) -> str:
        return self.inner.field

    @property
    def unit(self) -> str:
        return self.inner.unit

    @property
    def low(self) -> float:
        return self.inner.low

    @property
    def high(self) -> float:
        return self.inner.high

    def get(self, plant: LimbPlant) -> float:
        value = plant_value(plant, self.path)
        return float(value if self.inner.index is None else value[self.inner.index])

    def set(self, plant: LimbPlant, value: float) -> LimbPlant:
        """A copy of ``plant`` with this quantity set (validated on construction)."""
        new: float | tuple[float, ...] = float(value)
        if self.inner.index is not None:
            values = list(plant_value(plant, self.path))
            values[self.inner.index] = float(value)
            new = tuple(values)
        return replaced_plant(plant, {self.path: new})


def plant_fittable_names(plant: LimbPlant) -> list[str]:
    """The patterns of fittable names of ``plant`` (for the messages)."""
    joint = [f.name for f in dataclasses.fields(JointParams) if f.name != 'name']
    return ([f'{JOINT_PART}.{{{",".join(joint)}}}']
            + [f'{m.name}.{{{",".join(GEOMETRY_FIELDS)}}} or {m.name}.<muscle parameter>'
               for m in plant.muscles])


def parse_plant_fit_names(text: str, plant: LimbPlant) -> list[PlantParameter]:
    """The fitted quantities of a limb that ``--fit NAME[,NAME...]`` names.

    Each name is ``<part>.<field>``, the plant file's parameter name: ``joint.``
    and a field of the joint, or a muscle's name and ``moment_arm_m``,
    ``reference_angle_rad`` or one of its muscle parameters (a list entry as
    ``quadriceps.tau_fatigue_s[1]``).

    :raises FitError: naming an unknown, repeated or non-real name
    """
    out: list[PlantParameter] = []
    for raw in text.split(','):
        name = raw.strip()
        if not name:
            raise FitError(f'--fit: empty parameter name in {text!r}')
        path, bracket, _ = name.partition('[')   # a list entry names the list's field
        try:
            where = plant_field(path, plant)
        except PlantNameError as err:
            raise FitError(f'--fit: {err}') from None
        if where.where == PARAMS:
            muscle = next(m for m in plant.muscles if m.name == where.part)
            [inner] = parse_fit_names(name.partition('.')[2], muscle.params,
                                      prefix=f'{where.part}.')
        elif bracket:
            raise FitError(f'--fit: `{name}`: `{where.field}` is not a list')
        else:
            inner = FitParameter(where.field, None, where.unit, where.low, where.high)
        param = PlantParameter(where.part, inner, where.where)
        if any(p.name == param.name for p in out):
            raise FitError(f'--fit: `{param.name}` is named twice')
        out.append(param)
    return out
