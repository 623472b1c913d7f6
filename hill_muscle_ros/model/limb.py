"""A limb: one joint moved by several muscles (doc/model.md section 9).

The joint angle theta [rad] is that of the distal segment from hanging
vertical, positive in extension against gravity; omega = d theta / dt. With
muscle i an extensor (s_i = +1, it shortens as theta grows) or a flexor
(s_i = -1), a constant moment arm r_i and its total force F_i = f_SE + f_PE:

    J domega/dt = sum_i s_i r_i F_i - m g l_c sin(theta) - K (theta - theta_eq)
                  - B omega + tau_ext(t)
    dl_MT,i = -s_i r_i (theta - theta_ref,i)

The state is (theta, omega, l_CE of every muscle), integrated together with
RK4. Each muscle is the single muscle's engine
(:class:`~hill_muscle_ros.model.fes_muscle.FesMuscle`), with every variant and
FES feature: its :meth:`~hill_muscle_ros.model.fes_muscle.FesMuscle.plan`
gives the instants at which its recruitment changes within a step, the limb
integrates the joint and all CE lengths up to each instant of any muscle and
lets that muscle update its memory there, so each unit still stores the CE
length of its own recruitment instant. A muscle with nothing recruited has a
free CE that follows its MTU (f_SE = 0). A muscle whose CE relaxes faster
than :data:`~hill_muscle_ros.model.fes_muscle.QUASI_STATIC_RATE_PER_S` (few
units left with ``fv_scaling: relative``) is quasi-static over the interval:
its CE moves with its MTU, its SE carries the force Eq. 3 gives that velocity,
and it leaves the RK4 state, whose steps are cut for the other CEs only
(doc/model.md section 7.6). The single muscle with an imposed length
(:class:`~hill_muscle_ros.model.muscle.Muscle`) is unchanged.

The external torque and the stimulation are held over each step (zero-order
hold), as the simulator node holds its inputs.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Any, Mapping, NamedTuple, Sequence

import numpy as np

from .equations import (QUASI_STATIC_RATE_PER_S, joint_acceleration, mtu_length_change,
                        parallel_force, rk4_update, series_force, substep_count)
from .fes_muscle import FesMuscle
from .muscle import DL_MT_LIMIT_M, check_recruitment
from .params import _FLOAT_MAX, MuscleParams, _float, _spec, finite_float
from .protocol import (Knots, ProtocolError, _parse_knots, check_protocol_keys,
                       commands_from_pulse_widths, safe_load_yaml)
from .simulate import sample_times, step_count
from .substeps import substeps_for

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
    """A limb step's inputs, checked as :meth:`Limb.step` (and the compiled limb) take them.

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


class Limb:
    """The joint and its muscles, integrated together (see the module docstring).

    :param plant: the joint and its muscles
    """

    def __init__(self, plant: LimbPlant) -> None:
        self.plant = plant
        self.joint = plant.joint
        # Always the FES engine: it exposes the plan of recruitment instants.
        # With every feature off it equals the paper's loop to 1e-9 N (tests).
        self.muscles = [FesMuscle(m.params) for m in plant.muscles]
        self._sign = [m.sign for m in plant.muscles]
        self._arm = [m.moment_arm_m for m in plant.muscles]
        self._ref = [m.reference_angle_rad for m in plant.muscles]
        self.reset()

    def reset(self) -> None:
        """theta = theta_0, omega = 0, each CE at l_rest + dl_MT(theta_0), nothing recruited."""
        self.t_s = 0.0
        self.theta_rad = self.joint.initial_angle_rad
        self.omega_rad_per_s = 0.0
        self.external_torque_n_m = 0.0
        for i, m in enumerate(self.muscles):
            m.reset()
            dl = self._dl_mt(i, self.theta_rad)
            m.dl_mt_m = dl
            m.l_ce_m = m.params.l_rest_m + dl

    def _dl_mt(self, i: int, theta: float) -> float:
        return mtu_length_change(self._sign[i] * self._arm[i], theta, self._ref[i])

    # -- dynamics ---------------------------------------------------------------------

    def _forces(self, theta: float, omega: float, ls: list[float], t: float,
                free: list[bool], quasi: list[bool]) -> tuple[float, list[float]]:
        """Angular acceleration and the CE velocities at one RK4 stage."""
        j = self.joint
        torque = 0.0
        v_ce = []
        for i, m in enumerate(self.muscles):
            p = m.params
            s_r = self._sign[i] * self._arm[i]
            dl = mtu_length_change(s_r, theta, self._ref[i])
            if free[i]:
                f_se = 0.0
                v_ce.append(-s_r * omega)        # the free CE follows its MTU
            elif quasi[i]:
                f_se = m.quasi_static_force(-s_r * omega, ls[i], t)
                v_ce.append(-s_r * omega)        # and so does the quasi-static one
            else:
                l = ls[i]
                f_se = series_force(p.k_se_n_per_m, dl, l, p.l_rest_m)
                v_ce.append(m.ce_velocity(l, dl, t))
            torque += s_r * (f_se + parallel_force(p.k_pe_n_per_m, dl))
        alpha = joint_acceleration(torque, theta, omega, self.external_torque_n_m,
                                   j.inertia_kg_m2, j.mass_kg, j.gravity_m_per_s2,
                                   j.com_distance_m, j.stiffness_n_m_per_rad,
                                   j.equilibrium_rad, j.damping_n_m_s_per_rad)
        return alpha, v_ce

    def _integrate(self, s0: float, s1: float) -> None:
        """RK4 of (theta, omega, l_CE...) over [s0, s1], no recruitment change
        inside; each quasi-static CE (relaxation rate at least
        :data:`~hill_muscle_ros.model.fes_muscle.QUASI_STATIC_RATE_PER_S`) out of
        it, cut into as many equal steps as the stiffest other CE needs
        (:func:`~hill_muscle_ros.model.fes_muscle.substep_count`)."""
        h = s1 - s0
        if h <= 0.0:
            return
        muscles = self.muscles
        for m in muscles:
            m.begin_interval(s0, s1)
        rates = [m.peak_rate(m.l_ce_m, m.dl_mt_m, s0, s1) for m in muscles]
        quasi = [rate >= QUASI_STATIC_RATE_PER_S for rate in rates]
        n = max([substep_count(h, rate) for rate, q in zip(rates, quasi) if not q],
                default=1)
        for i in range(n):
            a = s0 + h * i / n
            b = s1 if i == n - 1 else s0 + h * (i + 1) / n
            self._rk4(a, b, quasi)
        for m in muscles:
            m.end_interval(s1)

    def _rk4(self, s0: float, s1: float, quasi: list[bool]) -> None:
        """One RK4 step of the joint and every CE over [s0, s1]; a quasi-static CE
        is put where its SE carries its force at the end."""
        h = s1 - s0
        muscles = self.muscles
        free = [m.free(m.l_ce_m, s0, s1) for m in muscles]
        th, om = self.theta_rad, self.omega_rad_per_s
        ls = [m.l_ce_m for m in muscles]
        mid = s0 + 0.5 * h
        a1, v1 = self._forces(th, om, ls, s0, free, quasi)
        th2, om2 = th + 0.5 * h * om, om + 0.5 * h * a1
        ls2 = [l + 0.5 * h * v for l, v in zip(ls, v1)]
        a2, v2 = self._forces(th2, om2, ls2, mid, free, quasi)
        th3, om3 = th + 0.5 * h * om2, om + 0.5 * h * a2
        ls3 = [l + 0.5 * h * v for l, v in zip(ls, v2)]
        a3, v3 = self._forces(th3, om3, ls3, mid, free, quasi)
        th4, om4 = th + h * om3, om + h * a3
        ls4 = [l + h * v for l, v in zip(ls, v3)]
        a4, v4 = self._forces(th4, om4, ls4, s1, free, quasi)
        self.theta_rad = rk4_update(th, h, om, om2, om3, om4)
        self.omega_rad_per_s = rk4_update(om, h, a1, a2, a3, a4)
        for i, m in enumerate(muscles):
            dl = self._dl_mt(i, self.theta_rad)
            l = rk4_update(ls[i], h, v1[i], v2[i], v3[i], v4[i])
            if free[i] or m.eff_f_iso(l, s1) == 0.0:
                l = m.params.l_rest_m + dl
            elif quasi[i]:
                s_r = self._sign[i] * self._arm[i]
                f = m.quasi_static_force(-s_r * self.omega_rad_per_s, l, s1)
                l = m.params.l_rest_m + dl - f / m.params.k_se_n_per_m
            m.l_ce_m, m.dl_mt_m = l, dl

    def step(self, commands: Sequence[float], external_torque_n_m: float,
             dt_s: float) -> LimbOutputs:
        """Advance one step: each muscle's command and the external torque held over it.

        A step longer than 1 ms is integrated in n = ceil(dt / 1 ms) equal
        substeps with the inputs held (:mod:`.substeps`): ``dt_s`` is how
        often the caller samples, not the integrator's step.

        :param commands: [-] recruitment command u of each muscle, in [0, 1]
        :param external_torque_n_m: [N m] external torque (tau_ext)
        :param dt_s: [s] step length, > 0
        :return: the outputs at the end of the step
        :raises ValueError: naming the input on a bad value; the state is unchanged
        """
        us, tau = check_step_inputs(self.plant, commands, external_torque_n_m, dt_s)
        n = substeps_for(dt_s)
        for _ in range(n):
            self._advance(us, tau, dt_s / n)
        return self.outputs()

    def _advance(self, us: Sequence[float], tau: float, dt_s: float) -> None:
        """One substep of :meth:`step` (at most 1 ms), the inputs checked.

        :raises ValueError: when a muscle is stretched out of range (the substep taken)
        """
        t0, t1 = self.t_s, self.t_s + dt_s
        self.external_torque_n_m = tau
        timeline = []
        for i, (m, u) in enumerate(zip(self.muscles, us)):
            m.t_s = t0
            m.give_command(u)
            timeline.extend((instant, i, action, value)
                            for instant, action, value in m.plan(t0, t1))
        timeline.sort(key=lambda event: event[0])   # stable: each muscle keeps its order
        s = t0
        for instant, i, action, value in timeline:
            self._integrate(s, instant)
            m = self.muscles[i]
            m.apply(action, value, instant)
            if m.eff_f_iso(m.l_ce_m, instant) == 0.0:
                m.l_ce_m = m.params.l_rest_m + m.dl_mt_m   # released: the CE is free now
            s = max(s, instant)
        self._integrate(s, t1)   # with no muscles there is no instant: the whole step
        self.t_s = t1
        for m in self.muscles:
            m.t_s = t1
            m.settle_now()
        for i, m in enumerate(self.muscles):
            dl = self._dl_mt(i, self.theta_rad)
            if not abs(dl) <= DL_MT_LIMIT_M:
                raise ValueError(stretch_message(self.plant.muscles[i].name, dl,
                                                 self.theta_rad))

    def outputs(self) -> LimbOutputs:
        """The outputs at the current instant."""
        forces, torque = [], 0.0
        for i, m in enumerate(self.muscles):
            p = m.params
            dl, l = m.dl_mt_m, m.l_ce_m
            f = series_force(p.k_se_n_per_m, dl, l, p.l_rest_m) + parallel_force(
                p.k_pe_n_per_m, dl)
            forces.append(f)
            torque += self._sign[i] * self._arm[i] * f
        return LimbOutputs(self.t_s, self.theta_rad, self.omega_rad_per_s, torque,
                           tuple(m.command for m in self.muscles),
                           tuple(m.recruitment for m in self.muscles),
                           tuple(m.dl_mt_m for m in self.muscles),
                           tuple(m.l_ce_m for m in self.muscles), tuple(forces))


# -- protocols and offline simulation -------------------------------------------------

LIMB_PROTOCOL_KEYS = ('name', 'duration_s', 'muscles', 'external_torque_n_m')


@dataclass(frozen=True)
class LimbProtocol:
    """Inputs per muscle (pulse width or recruitment) and an external torque.

    :param name: human-readable name
    :param duration_s: [s] length of the protocol
    :param stimulation: per muscle name, ``(key, knots)`` with key
        ``pulse_width_s`` or ``recruitment``
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
            given = [k for k in ('pulse_width_s', 'recruitment') if k in inputs]
            extra = [k for k in inputs if k not in ('pulse_width_s', 'recruitment')]
            if len(given) != 1 or extra:
                raise ProtocolError(f'{source}: `{where}` must give exactly one of '
                                    f'`pulse_width_s` or `recruitment`, got {sorted(inputs)}')
            key = given[0]
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
        from pathlib import Path
        path = Path(path)
        try:
            data = safe_load_yaml(path.read_text(encoding='utf-8'))
        except (OSError, UnicodeDecodeError) as err:
            raise ProtocolError(f'{path}: cannot read protocol file: {err}') from None
        except Exception as err:   # yaml.YAMLError, without importing yaml here
            raise ProtocolError(f'{path}: not valid YAML: {err}') from None
        return cls.from_mapping(data, source=str(path))

    def commands(self, t_s: np.ndarray, plant: LimbPlant) -> np.ndarray:
        """[-] commands u, shape (len(t_s), muscles): each muscle's pulse widths
        through its own recruitment curve; a muscle the protocol omits gets 0.

        :raises ProtocolError: if the protocol names a muscle the plant lacks
        """
        names = [m.name for m in plant.muscles]
        missing = [n for n in self.stimulation if n not in names]
        if missing:
            raise ProtocolError(f'protocol `{self.name}`: muscle `{missing[0]}` is not in '
                                f'the plant (muscles: {", ".join(names)})')
        out = np.zeros((len(t_s), len(names)))
        for i, m in enumerate(plant.muscles):
            if m.name not in self.stimulation:
                continue
            key, knots = self.stimulation[m.name]
            values = np.asarray(knots(t_s), dtype=float)
            if key == 'recruitment':
                out[:, i] = values
            else:
                out[:, i] = commands_from_pulse_widths(values, m.params)
        return out


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
    ``<name>_command, <name>_recruitment, <name>_dl_mt_m, <name>_l_ce_m, <name>_force_n``."""
    cols = ['t_s', 'theta_rad', 'omega_rad_per_s']
    for m in plant.muscles:
        cols += [f'{m.name}_{c}' for c in MUSCLE_COLUMNS]
    return cols


def simulate_limb(plant: LimbPlant, protocol: LimbProtocol,
                  rate_hz: float = 1000.0) -> LimbResult:
    """Run a limb protocol from the initial state at a fixed step of 1 / ``rate_hz``.

    The sample at t_k shows the state at t_k with the commands of t_k given;
    the step from t_k holds the commands and the external torque of t_k.
    The loop runs compiled (:mod:`.limb_kernels`, the same results to 1e-9 rad
    and 1e-9 N) where that pays: once it is loaded in the process, or for runs
    of at least :data:`.limb_kernels.RUN_MIN_MUSCLE_STEPS` steps times muscles;
    ``HILL_MUSCLE_ENGINE=compiled`` always, ``python`` never (:mod:`.engine`).
    """
    from . import engine, limb_kernels
    work = step_count(protocol.duration_s, rate_hz) * len(plant.muscles)
    if engine.use_compiled(work, limb_kernels.RUN_MIN_MUSCLE_STEPS, limb_kernels.loaded()):
        result = limb_kernels.simulate_limb_compiled(plant, protocol, rate_hz)
        if result is not None:
            return result
    limb = Limb(plant)
    t = sample_times(protocol.duration_s, rate_hz)
    u = protocol.commands(t, plant)
    tau = np.asarray(protocol.external_torque_n_m(t), dtype=float)
    dt = 1.0 / rate_hz
    n = len(plant.muscles)
    rows = np.empty((len(t), 3 + n * len(MUSCLE_COLUMNS)))

    def record(k: int, out: LimbOutputs) -> None:
        rows[k, :3] = (out.t_s, out.theta_rad, out.omega_rad_per_s)
        for i in range(n):
            rows[k, 3 + i * 5:8 + i * 5] = (out.command[i], out.recruitment[i],
                                            out.dl_mt_m[i], out.l_ce_m[i], out.force_n[i])

    for i, m in enumerate(limb.muscles):
        m.give_command(float(u[0, i]))
    record(0, limb.outputs())
    for k in range(len(t) - 1):
        limb.step(u[k], float(tau[k]), dt)
        for i, m in enumerate(limb.muscles):
            if u[k + 1, i] != m.command:   # the command of t_(k+1) shows in its sample
                m.give_command(float(u[k + 1, i]))
        record(k + 1, limb.outputs())
    rows[:, 0] = t
    return LimbResult(t, dict(zip(limb_columns(plant), rows.T)))
