"""The limb's plain data: the plant, a step's inputs and outputs, protocols and results.

A limb is one joint moved by several muscles (doc/model.md section 9). The
joint angle theta [rad] is that of the distal segment from hanging vertical,
positive in extension against gravity; omega = d theta / dt. With muscle i an
extensor (s_i = +1, it shortens as theta grows) or a flexor (s_i = -1), a
constant moment arm r_i and its total force F_i = f_SE + f_PE:

    J domega/dt = sum_i s_i r_i F_i - m g l_c sin(theta) - K (theta - theta_eq)
                  - B omega + tau_ext(t)
    dl_MT,i = -s_i r_i (theta - theta_ref,i)

This module holds what describes a limb and what goes in and out of it, and
no dynamics: the joint (:class:`JointParams`), its muscles
(:class:`LimbMuscle`), the plant (:class:`LimbPlant`, parsed from a plant
file), the checks of a step's inputs (:func:`check_step_inputs`), its outputs
(:class:`LimbOutputs`), limb protocols (:class:`LimbProtocol`) and offline
results (:class:`LimbResult`, :func:`limb_columns`). The dynamics are the flat
kernels of :mod:`.kernels`, stepped by :class:`~.limb.Limb`.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping, NamedTuple, Sequence

import numpy as np

from ..muscle import DL_MT_LIMIT_M, check_recruitment
from ..params import PULSED_MODEL, _FLOAT_MAX, MuscleParams, _float, _spec, finite_float
from ..protocol import (Knots, ProtocolError, PulseProtocol, _parse_channel, _parse_knots,
                        check_protocol_keys, commands_from_pulse_widths, safe_load_yaml)

#: [-] s of each action: +1 for an extensor, -1 for a flexor.
ACTIONS = {'extensor': 1.0, 'flexor': -1.0}
#: [rad] Largest |angle| parameter: two turns; a larger one is a unit error
#: (degrees for radians).
ANGLE_LIMIT_RAD = 4.0 * math.pi
#: [N m] Largest |external torque| accepted: far beyond any limb, it only
#: turns a unit error into a message.
TORQUE_LIMIT_N_M = 1.0e4


@dataclass(frozen=True)
class JointParams:
    """The joint and its moving segment(s).

    :param name: joint name (``joint_states``)
    :param inertia_kg_m2: [kg m^2] moment of inertia about the joint (J)
    :param mass_kg: [kg] mass of the moving segment(s) (m)
    :param com_distance_m: [m] joint to centre of mass (l_c)
    :param gravity_m_per_s2: [m/s^2] gravitational acceleration (g)
    :param stiffness_n_m_per_rad: [N m/rad] passive joint stiffness (K)
    :param equilibrium_rad: [rad] angle where the passive spring is slack (theta_eq)
    :param damping_n_m_s_per_rad: [N m s/rad] passive joint damping (B)
    :param initial_angle_rad: [rad] angle at t = 0 (theta_0)
    """

    name: str = 'knee'
    inertia_kg_m2: float = field(default=0.428, metadata=_spec(
        'kg m^2', 'moment of inertia about the joint J', low=0.0, high=_FLOAT_MAX))
    mass_kg: float = field(default=4.27, metadata=_spec(
        'kg', 'mass of the moving segment(s) m', low=0.0, high=_FLOAT_MAX,
        low_inclusive=True))
    com_distance_m: float = field(default=0.261, metadata=_spec(
        'm', 'joint to centre of mass l_c', low=0.0, high=_FLOAT_MAX, low_inclusive=True))
    gravity_m_per_s2: float = field(default=9.81, metadata=_spec(
        'm/s^2', 'gravitational acceleration g', low=0.0, high=_FLOAT_MAX,
        low_inclusive=True))
    stiffness_n_m_per_rad: float = field(default=15.3, metadata=_spec(
        'N m/rad', 'passive joint stiffness K', low=0.0, high=_FLOAT_MAX,
        low_inclusive=True))
    equilibrium_rad: float = field(default=0.0, metadata=_spec(
        'rad', 'angle where the passive spring is slack theta_eq', low=-ANGLE_LIMIT_RAD,
        high=ANGLE_LIMIT_RAD, low_inclusive=True))
    damping_n_m_s_per_rad: float = field(default=0.41, metadata=_spec(
        'N m s/rad', 'passive joint damping B', low=0.0, high=_FLOAT_MAX,
        low_inclusive=True))
    initial_angle_rad: float = field(default=0.0, metadata=_spec(
        'rad', 'angle at t = 0 theta_0', low=-ANGLE_LIMIT_RAD, high=ANGLE_LIMIT_RAD,
        low_inclusive=True))

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not self.name.strip():
            raise ValueError(f'`joint.name` must be a non-empty string, got {self.name!r}')
        for f in dataclasses.fields(self):
            if f.name != 'name':
                object.__setattr__(self, f.name,
                                   _float(f'joint.{f.name}', getattr(self, f.name), f.metadata))


@dataclass(frozen=True)
class LimbMuscle:
    """One muscle on the joint.

    :param name: the muscle's name (topic namespace, CSV column prefix)
    :param action: ``extensor`` (s = +1) or ``flexor`` (s = -1)
    :param moment_arm_m: [m] constant moment arm (r)
    :param reference_angle_rad: [rad] angle where dl_MT = 0 (theta_ref)
    :param params: the muscle's parameters, every variant and FES feature
    """

    name: str
    action: str
    moment_arm_m: float
    reference_angle_rad: float
    params: MuscleParams

    def __post_init__(self) -> None:
        if self.action not in ACTIONS:
            raise ValueError(f'`{self.name}.action` must be one of {", ".join(ACTIONS)}, '
                             f'got {self.action!r}')
        arm = finite_float(self.moment_arm_m) if not isinstance(self.moment_arm_m, bool) else None
        if arm is None or not 0.0 < arm <= 1.0:
            raise ValueError(f'`{self.name}.moment_arm_m` must be in (0, 1] m, '
                             f'got {self.moment_arm_m!r}')
        ref = (finite_float(self.reference_angle_rad)
               if not isinstance(self.reference_angle_rad, bool) else None)
        if ref is None or abs(ref) > ANGLE_LIMIT_RAD:
            raise ValueError(f'`{self.name}.reference_angle_rad` must be within '
                             f'±{ANGLE_LIMIT_RAD:.4g} rad, got {self.reference_angle_rad!r}')
        object.__setattr__(self, 'moment_arm_m', arm)
        object.__setattr__(self, 'reference_angle_rad', ref)

    @property
    def sign(self) -> float:
        """[-] s: +1 for an extensor, -1 for a flexor."""
        return ACTIONS[self.action]

    def dl_mt(self, theta_rad: float) -> float:
        """[m] MTU length change at joint angle ``theta_rad``: -s r (theta - theta_ref)."""
        return -self.sign * self.moment_arm_m * (theta_rad - self.reference_angle_rad)


#: Keys of a muscle's section of the plant file besides its MuscleParams fields.
MUSCLE_KEYS = ('action', 'moment_arm_m', 'reference_angle_rad')
#: Keys of the plant file's top level.
PLANT_KEYS = ('joint', 'muscles')


@dataclass(frozen=True)
class LimbPlant:
    """A joint and the muscles on it.

    :param joint: the joint
    :param muscles: the muscles, in order (none: the passive pendulum)
    """

    joint: JointParams
    muscles: tuple[LimbMuscle, ...]

    def __post_init__(self) -> None:
        names = [m.name for m in self.muscles]
        if len(set(names)) != len(names):
            raise ValueError(f'`muscles` must have distinct names, got {names!r}')

    @classmethod
    def from_mapping(cls, values: Mapping[str, Any], *, source: str = 'plant',
                     ignore: Sequence[str] = ()) -> 'LimbPlant':
        """Build a plant from ``ros__parameters`` of a plant file.

        Nested mappings (``joint: {inertia_kg_m2: ...}``) and ROS's dotted
        names (``joint.inertia_kg_m2``) are both accepted.

        :param ignore: top-level keys that belong to a node, not the plant
        :raises ValueError: naming the file and the key on any defect
        """
        tree = _nest(values, source)
        unknown = sorted(k for k in tree if k not in PLANT_KEYS
                         and k not in tree.get('muscles', []) and k not in ignore)
        if unknown:
            raise ValueError(f'{source}: unknown key `{unknown[0]}` (a muscle must be '
                             f'listed in `muscles`; known: joint, muscles)')
        try:
            joint = tree.get('joint', {})
            if not isinstance(joint, Mapping):
                raise ValueError(f'`joint` must be a mapping, got {joint!r}')
            known = {f.name for f in dataclasses.fields(JointParams)}
            bad = sorted(k for k in joint if k not in known)
            if bad:
                raise ValueError(f'unknown key `joint.{bad[0]}` (known: '
                                 f'{", ".join(sorted(known))})')
            joint_params = JointParams(**joint)
            names = tree.get('muscles', [])
            if (not isinstance(names, list)
                    or not all(isinstance(n, str) and n for n in names)):
                raise ValueError(f'`muscles` must be a list of names, got {names!r}')
            muscles = []
            for name in names:
                section = tree.get(name)
                if not isinstance(section, Mapping):
                    raise ValueError(f'muscle `{name}` is listed in `muscles` but has no '
                                     f'section `{name}`')
                for key in ('action', 'moment_arm_m'):
                    if key not in section:
                        raise ValueError(f'missing key `{name}.{key}`')
                values = {k: v for k, v in section.items() if k not in MUSCLE_KEYS}
                params = MuscleParams.from_mapping(values, source=f'`{name}`')
                muscles.append(LimbMuscle(name, section['action'], section['moment_arm_m'],
                                          section.get('reference_angle_rad', 0.0), params))
            return cls(joint_params, tuple(muscles))
        except (TypeError, ValueError) as err:
            raise ValueError(f'{source}: {err}') from None


def _nest(values: Mapping[str, Any], source: str) -> dict[str, Any]:
    """Dotted names (``joint.mass_kg``) into nested mappings, merged with nested ones."""
    if not isinstance(values, Mapping):
        raise ValueError(f'{source}: expected a mapping of parameters, got {values!r}')
    tree: dict[str, Any] = {}
    for key, value in values.items():
        parts = str(key).split('.')
        node = tree
        for part in parts[:-1]:
            node = node.setdefault(part, {})
            if not isinstance(node, dict):
                raise ValueError(f'{source}: `{key}` conflicts with a value of `{part}`')
        if isinstance(value, Mapping) and isinstance(node.get(parts[-1]), dict):
            node[parts[-1]].update(value)
        else:
            node[parts[-1]] = dict(value) if isinstance(value, Mapping) else value
    return tree


class LimbOutputs(NamedTuple):
    """The limb at one instant (SI); per-muscle arrays in the plant's order.

    :param t_s: [s] time
    :param theta_rad: [rad] joint angle (theta)
    :param omega_rad_per_s: [rad/s] joint angular velocity (omega)
    :param muscle_torque_n_m: [N m] net muscle torque sum s_i r_i F_i
    :param command: [-] each muscle's recruitment command u
    :param recruitment: [-] each muscle's recruitment R (activation)
    :param dl_mt_m: [m] each muscle's MTU length change
    :param l_ce_m: [m] each muscle's CE length
    :param force_n: [N] each muscle's force f_SE + f_PE
    """

    t_s: float
    theta_rad: float
    omega_rad_per_s: float
    muscle_torque_n_m: float
    command: tuple
    recruitment: tuple
    dl_mt_m: tuple
    l_ce_m: tuple
    force_n: tuple


def stretch_message(muscle: str, dl_mt_m: float, theta_rad: float) -> str:
    """The error of a limb step that left ``muscle`` stretched beyond ±DL_MT_LIMIT_M.

    :param dl_mt_m: [m] its MTU length change (dl_MT)
    :param theta_rad: [rad] the joint angle (theta)
    """
    return (f'muscle `{muscle}` is stretched {dl_mt_m:.4g} m from rest at '
            f'{math.degrees(theta_rad):.1f} deg: beyond ±{DL_MT_LIMIT_M} m; '
            'check its moment arm')


def check_step_inputs(plant: LimbPlant, commands: Sequence[float],
                      external_torque_n_m: float, dt_s: float) -> tuple[list[float], float]:
    """A limb step's inputs, checked as :meth:`.limb.Limb.step` takes them.

    :param plant: the joint and its muscles
    :param commands: [-] recruitment command u of each muscle, in [0, 1]
    :param external_torque_n_m: [N m] external torque (tau_ext)
    :param dt_s: [s] step length, > 0
    :return: ([-] each muscle's command u as a float, [N m] tau_ext as a float)
    :raises ValueError: naming the input on a bad value
    """
    if len(commands) != len(plant.muscles):
        raise ValueError(f'`commands` must have one value per muscle '
                         f'({len(plant.muscles)}), got {len(commands)}')
    us = [check_recruitment(u, f'{m.name}.command') for u, m in zip(commands, plant.muscles)]
    tau = float(external_torque_n_m)
    if not abs(tau) <= TORQUE_LIMIT_N_M:
        raise ValueError(f'`external_torque_n_m` must be finite and within '
                         f'±{TORQUE_LIMIT_N_M:g} N m, got {external_torque_n_m!r}')
    if not (math.isfinite(dt_s) and dt_s > 0.0):
        raise ValueError(f'`dt_s` must be positive and finite, got {dt_s!r}')
    return us, tau


# -- protocols and offline results -------------------------------------------------

LIMB_PROTOCOL_KEYS = ('name', 'duration_s', 'muscles', 'external_torque_n_m')
#: What a muscle's entry of a limb protocol gives: a level (pulse width or
#: recruitment) or, for a ``ding2003`` muscle, pulse trains per channel.
LIMB_STIMULATION_KEYS = ('pulse_width_s', 'recruitment', 'channels')


@dataclass(frozen=True)
class LimbProtocol:
    """Inputs per muscle (pulse width, recruitment or pulse trains per channel)
    and an external torque.

    :param name: human-readable name
    :param duration_s: [s] length of the protocol
    :param stimulation: per muscle name, ``(key, knots)`` with key
        ``pulse_width_s`` or ``recruitment``, or ``('channels', trains)``: a
        tuple of :class:`~hill_muscle_ros.model.trains.ChannelTrain`, channel 1
        first (a ``ding2003`` muscle's, as a muscle's pulse protocol gives them)
    :param external_torque_n_m: [N m] knots of the external torque
    """

    name: str
    duration_s: float
    stimulation: dict
    external_torque_n_m: Knots

    @classmethod
    def from_mapping(cls, data: Any, source: str = '<protocol>') -> 'LimbProtocol':
        """Validate a parsed limb protocol.

        :raises ProtocolError: naming the file, key and entry on any defect
        """
        duration_s = check_protocol_keys(data, source, LIMB_PROTOCOL_KEYS,
                                         ('name', 'duration_s', 'muscles'))
        muscles = data['muscles']
        if not isinstance(muscles, dict) or not muscles:
            raise ProtocolError(f'{source}: `muscles` must map muscle names to inputs, '
                                f'got {muscles!r}')
        stimulation = {}
        for name, inputs in muscles.items():
            where = f'muscles.{name}'
            if not isinstance(inputs, dict):
                raise ProtocolError(f'{source}: `{where}` must be a mapping, got {inputs!r}')
            given = [k for k in LIMB_STIMULATION_KEYS if k in inputs]
            extra = [k for k in inputs if k not in LIMB_STIMULATION_KEYS]
            if len(given) != 1 or extra:
                raise ProtocolError(f'{source}: `{where}` must give exactly one of '
                                    f'`pulse_width_s`, `recruitment` or `channels`, got '
                                    f'{sorted(inputs)}')
            key = given[0]
            if key == 'channels':
                raw = inputs[key]
                if not isinstance(raw, list) or not raw:
                    raise ProtocolError(f'{source}: `{where}.channels` must be a non-empty list '
                                        f'of channels (mappings with keys frequency_hz, '
                                        f'pulse_width_s, ...), got {raw!r}')
                trains = tuple(_parse_channel(entry, f'{source}: muscle `{name}`', c)
                               for c, entry in enumerate(raw, 1))
                stimulation[str(name)] = (key, trains)
                continue
            if key == 'recruitment':
                knots = _parse_knots(inputs[key], source, f'{where}.{key}', 0.0, 1.0,
                                     'in [0, 1]')
            else:
                knots = _parse_knots(inputs[key], source, f'{where}.{key}', 0.0, math.inf,
                                     'non-negative')
            stimulation[str(name)] = (key, knots)
        torque = _parse_knots(data.get('external_torque_n_m', [[0.0, 0.0]]), source,
                              'external_torque_n_m', -TORQUE_LIMIT_N_M, TORQUE_LIMIT_N_M,
                              f'within ±{TORQUE_LIMIT_N_M:g} N m')
        return cls(str(data['name']), duration_s, stimulation, torque)

    @classmethod
    def from_yaml(cls, path) -> 'LimbProtocol':
        """Load and validate a limb protocol file."""
        path = Path(path)
        try:
            data = safe_load_yaml(path.read_text(encoding='utf-8'))
        except (OSError, UnicodeDecodeError) as err:
            raise ProtocolError(f'{path}: cannot read protocol file: {err}') from None
        except Exception as err:   # yaml.YAMLError, without importing yaml here
            raise ProtocolError(f'{path}: not valid YAML: {err}') from None
        return cls.from_mapping(data, source=str(path))

    def check_plant(self, plant: LimbPlant) -> None:
        """Check that every muscle the protocol names is in ``plant`` and takes
        its kind of input: ``channels`` a ``ding2003`` muscle, a level any other.

        :raises ProtocolError: naming the protocol, the muscle and the model
        """
        names = [m.name for m in plant.muscles]
        missing = [n for n in self.stimulation if n not in names]
        if missing:
            raise ProtocolError(f'protocol `{self.name}`: muscle `{missing[0]}` is not in '
                                f'the plant (muscles: {", ".join(names)})')
        for m in plant.muscles:
            if m.name not in self.stimulation:
                continue
            key = self.stimulation[m.name][0]
            pulsed = m.params.activation_model == PULSED_MODEL
            if key == 'channels' and not pulsed:
                raise ProtocolError(f'protocol `{self.name}`: muscle `{m.name}` is given '
                                    f'`channels` (pulse trains): it needs `activation_model: '
                                    f'{PULSED_MODEL}`, got {m.params.activation_model!r}')
            if key != 'channels' and pulsed:
                raise ProtocolError(f'protocol `{self.name}`: muscle `{m.name}` has '
                                    f'`activation_model: {PULSED_MODEL}`: it is driven by '
                                    f'pulse trains, give it `channels`, not `{key}`')

    def commands(self, t_s: np.ndarray, plant: LimbPlant) -> np.ndarray:
        """[-] commands u, shape (len(t_s), muscles): each muscle's pulse widths
        through its own recruitment curve; a muscle the protocol omits, or one
        driven by ``channels`` (:meth:`pulses`), gets 0.

        :raises ProtocolError: as :meth:`check_plant`
        """
        self.check_plant(plant)
        out = np.zeros((len(t_s), len(plant.muscles)))
        for i, m in enumerate(plant.muscles):
            if m.name not in self.stimulation:
                continue
            key, knots = self.stimulation[m.name]
            if key == 'channels':
                continue
            values = np.asarray(knots(t_s), dtype=float)
            if key == 'recruitment':
                out[:, i] = values
            else:
                out[:, i] = commands_from_pulse_widths(values, m.params)
        return out


    def pulses(self, plant: LimbPlant) -> list[tuple[float, int, int, float]]:
        """Every pulse of the muscles driven by ``channels``, as the limb takes
        them, each checked against its muscle's ``stimulator`` (as
        :func:`~hill_muscle_ros.model.simulate.protocol_pulses` checks a
        muscle's).

        :return: ``(instant [s] (sent + emd_s), muscle index, 0-based channel,
            u)`` rows in time order (a stable sort: muscle by muscle, each in
            its own order, at an equal instant)
        :raises ProtocolError: as :meth:`check_plant`, or naming the muscle,
            the channel, the field and the value of a pulse its stimulator
            would refuse, or more channels than the muscle has
        """
        from ..simulate import protocol_pulses   # model.simulate imports the muscle
        self.check_plant(plant)
        rows = []
        for i, m in enumerate(plant.muscles):
            entry = self.stimulation.get(m.name)
            if entry is None or entry[0] != 'channels':
                continue
            one = PulseProtocol(f'protocol `{self.name}`: muscle `{m.name}`', self.duration_s,
                                entry[1], Knots(np.zeros(1), np.zeros(1)))
            try:
                times, channels, commands = protocol_pulses(one, m.params)
            except ValueError as err:
                raise ProtocolError(str(err)) from None
            rows += [(float(t), i, int(c), float(u))
                     for t, c, u in zip(times, channels, commands)]
        rows.sort(key=lambda r: r[0])
        return rows


@dataclass(frozen=True)
class LimbResult:
    """Time series of an offline limb run: one sample per step from t = 0.

    :param t_s: [s] sample times
    :param columns: CSV column name to array (``theta_rad``, ``<muscle>_force_n``, ...)
    """

    t_s: np.ndarray
    columns: dict

    def __getitem__(self, name: str) -> np.ndarray:
        return self.columns[name]


MUSCLE_COLUMNS = ('command', 'recruitment', 'dl_mt_m', 'l_ce_m', 'force_n')


def limb_columns(plant: LimbPlant) -> list[str]:
    """CSV columns: ``t_s, theta_rad, omega_rad_per_s``, then per muscle
    ``<name>_command, <name>_recruitment, <name>_dl_mt_m, <name>_l_ce_m, <name>_force_n``,
    then per ``ding2003`` muscle ``a_<name>_<c>`` for each of its channels c = 1, 2, ...
    (the channel's activation a_c)."""
    cols = ['t_s', 'theta_rad', 'omega_rad_per_s']
    for m in plant.muscles:
        cols += [f'{m.name}_{c}' for c in MUSCLE_COLUMNS]
    for m in plant.muscles:
        if m.params.activation_model == PULSED_MODEL:
            cols += [f'a_{m.name}_{c}' for c in range(1, m.params.n_channels + 1)]
    return cols
