"""A joint-angle controller for an FES-driven limb: model feedforward plus PID
with anti-windup, allocated to the extensors or the flexors.

The controller works in joint torque. The reference theta_ref follows the
target angle theta* at no more than ``reference_rate_rad_per_s`` (a
two-degree-of-freedom design: a step of the target becomes a ramp, which
neither kicks the derivative nor winds the integral, while a target slower
than the limit, such as a 0.2 Hz sine, is followed without lag); omega_ref is
its rate, and with e = theta_ref - theta:

    tau* = tau_hold(theta_ref) + kp e + ki int(e) + kd (omega_ref - omega)

``tau_hold`` is the feedforward through the model: the muscle torque that
holds theta_ref at rest against gravity, the passive joint and the muscles'
parallel springs (:meth:`JointController.hold_torque`). A positive tau* is
asked of the extensors, a negative one of the flexors (no co-contraction).
Each muscle of that group is given the same fraction of its capacity, the
torque it makes at full recruitment at the measured angle,
``r f_iso_max FL((l_rest + dl_MT) / l_opt)`` (the inverse muscle, static, its
tendon stretch neglected), and that fraction, the recruitment R, goes
through the muscle's inverse recruitment curve to a pulse width, at most the
stimulator's ``pw_max_s``. Conditional integration is the anti-windup: the
integral stands still while the group that would have to push harder is at
its limit (or absent).

The feedforward assumes force proportional to R (equal fibre weights) and an
unfatigued muscle; the integral takes up the rest. This is an example for
users to start from, not part of the model.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Callable, Sequence

import numpy as np

from ..model.equations import force_length, parallel_force
from ..model.limb import ANGLE_LIMIT_RAD, Limb, LimbPlant
from ..model.params import MuscleParams
from ..model.stimulus import command_from_pulse_width
from .pi import ControllerInputs, _spec, check_spec_fields, pulse_width_within

#: Default gains and reference rate. Tuned offline on the knee preset with
#: :func:`simulate_joint_control` (limb at 1 kHz, controller at 100 Hz), for
#: robustness to the loop's delay rather than for the fastest step: on top of
#: the ~60 ms from pulse to force (31 ms electromechanical delay, 25-28 ms
#: activation), steps from hanging to 20, 35 and 45 deg overshoot at most
#: 2.4 deg with 2 ms of feedback delay and 4.2 deg with 50 ms, and settle
#: (swing below 1.4 deg after 3 s) at every one of those delays. Stiffer
#: gains (kp 40, ki 40, kd 4, 1.5 rad/s) were quicker at 35 deg but
#: overshot a 20 deg step by 8 deg and rang there with 30 ms of delay: at low
#: recruitment the quadriceps is soft (its eccentric speed is bounded by
#: F0 b' / a') and the knee swings through.
DEFAULT_KP_N_M_PER_RAD = 25.0
DEFAULT_KI_N_M_PER_RAD_S = 25.0
DEFAULT_KD_N_M_S_PER_RAD = 3.0
#: [rad/s] 46 deg/s: a 35 deg step becomes a 0.76 s ramp; a 0.2 Hz sine of
#: 15 deg (at most 0.33 rad/s) is never limited.
DEFAULT_REFERENCE_RATE_RAD_PER_S = 0.8
#: [s] joint state older than this stops stimulation: the limb node's
#: stimulation watchdog (``input_timeout_s``, 0.5 s), so both ends of the
#: loop give up on a silent peer after the same time.
DEFAULT_FEEDBACK_TIMEOUT_S = 0.5
#: [s] 0: a target is a set point that holds until the next one.
DEFAULT_TARGET_TIMEOUT_S = 0.0
#: [Hz] control rate: ten times below the limb's 1 kHz, well above the
#: ~60 ms pulse-to-force delay's bandwidth.
DEFAULT_RATE_HZ = 100.0
FEEDFORWARD_CHOICES = ('model', 'none')
#: [rad/s] |omega| beyond this is not a limb's (garbage or a unit error).
VELOCITY_LIMIT_RAD_PER_S = 1.0e3


@dataclass(frozen=True)
class JointControllerParams:
    """Gains and limits of :class:`JointController`; validated on construction.

    :param feedforward: ``model``: the torque that holds the reference angle
        (:meth:`JointController.hold_torque`); ``none``: PID only
    :param kp_n_m_per_rad: [N m/rad] proportional gain
    :param ki_n_m_per_rad_s: [N m/(rad s)] integral gain
    :param kd_n_m_s_per_rad: [N m s/rad] derivative gain, on omega_ref - omega
    :param reference_rate_rad_per_s: [rad/s] fastest the reference moves
        towards the target; 0 makes the loop track the target itself
    :param control_rate_hz: [Hz] control and stimulation rate (not ``rate_hz``,
        which a shared plant file sets for the limb's steps)
    :param feedback_timeout_s: [s] stop stimulating when no joint state
        arrived for this long
    :param target_timeout_s: [s] stop stimulating when no target arrived for
        this long; 0 keeps a target until the next one
    """

    feedforward: str = field(default=FEEDFORWARD_CHOICES[0], metadata=_spec(
        '-', 'feedforward: model (the torque that holds the reference angle, through the '
        'inverse muscle) or none', choices=FEEDFORWARD_CHOICES))
    kp_n_m_per_rad: float = field(default=DEFAULT_KP_N_M_PER_RAD, metadata=_spec(
        'N m/rad', 'proportional gain', 0.0, 1e5))
    ki_n_m_per_rad_s: float = field(default=DEFAULT_KI_N_M_PER_RAD_S, metadata=_spec(
        'N m/(rad s)', 'integral gain', 0.0, 1e6))
    kd_n_m_s_per_rad: float = field(default=DEFAULT_KD_N_M_S_PER_RAD, metadata=_spec(
        'N m s/rad', 'derivative gain (on the reference velocity minus the joint velocity)',
        0.0, 1e4))
    reference_rate_rad_per_s: float = field(
        default=DEFAULT_REFERENCE_RATE_RAD_PER_S, metadata=_spec(
            'rad/s', 'fastest the reference angle moves towards the target (0: no limit)',
            0.0, 1e3))
    control_rate_hz: float = field(default=DEFAULT_RATE_HZ, metadata=_spec(
        'Hz', 'control and stimulation rate', 1e-3, 1e5))
    feedback_timeout_s: float = field(default=DEFAULT_FEEDBACK_TIMEOUT_S, metadata=_spec(
        's', 'stop stimulating when no joint state arrived for this long', 1e-6, 3600.0))
    target_timeout_s: float = field(default=DEFAULT_TARGET_TIMEOUT_S, metadata=_spec(
        's', 'stop stimulating when no angle_target arrived for this long (0: never)',
        0.0, 3600.0))

    def __post_init__(self) -> None:
        check_spec_fields(self)


#: The controller's parameter names: a plant file shared with the limb node
#: may carry them, and the plant passes over them.
JOINT_CONTROLLER_KEYS = tuple(f.name for f in dataclasses.fields(JointControllerParams))


class JointInputs(ControllerInputs):
    """What the joint controller has heard, and whether it may act on it: the
    force controller's rule (:class:`~hill_muscle_ros.control.pi.ControllerInputs`)
    with an angle target and the joint state as the feedback, whose angle
    fills the base class's feedback slot."""

    NO_TARGET = 'no angle_target received yet'
    NO_FEEDBACK = 'no joint state received yet'
    STALE_FEEDBACK = 'joint state stale'
    STALE_TARGET = 'angle_target stale'

    def __init__(self, feedback_timeout_s: float, target_timeout_s: float = 0.0) -> None:
        super().__init__(feedback_timeout_s, target_timeout_s)
        self.omega_rad_per_s: float | None = None   # [rad/s] None until a joint state

    def set_joint_state(self, theta_rad: float, omega_rad_per_s: float, now_s: float) -> None:
        """A validated joint state received at ``now_s`` [s]."""
        self.omega_rad_per_s = omega_rad_per_s
        self.set_force(theta_rad, now_s)

    @property
    def theta_rad(self) -> float | None:
        """[rad] the last joint angle received, None before one."""
        return self.force_n

    @property
    def target_rad(self) -> float | None:
        """[rad] the last angle target received, None before one."""
        return self.target_n


class JointController:
    """Joint-angle control of a :class:`~hill_muscle_ros.model.limb.LimbPlant`
    (see the module docstring).

    :param plant: the controller's model of the limb (its belief: it may
        differ from the simulated or real limb)
    :param params: gains and limits
    """

    def __init__(self, plant: LimbPlant, params: JointControllerParams | None = None) -> None:
        if not plant.muscles:
            raise ValueError('`muscles` must name at least one muscle to control, got none')
        self.plant = plant
        self.params = params if params is not None else JointControllerParams()
        self.reset()

    def reset(self) -> None:
        """Forget the integral and the reference; the next update starts from
        the measured angle."""
        self.integral_n_m = 0.0                   # [N m] ki int(e)
        self.reference_rad: float | None = None   # [rad] theta_ref
        self.reference_velocity_rad_per_s = 0.0   # [rad/s] omega_ref
        self.torque_n_m = 0.0                     # [N m] tau* of the last update

    # -- checks -----------------------------------------------------------------

    @staticmethod
    def check_angle(value: float, name: str = 'angle_target') -> float:
        """[rad] a finite angle within the plant's angle limit.

        :raises ValueError: naming ``name`` and the value otherwise
        """
        if isinstance(value, bool) or not (isinstance(value, (int, float))
                                           and abs(value) <= ANGLE_LIMIT_RAD):
            raise ValueError(f'`{name}` must be finite and within ±{ANGLE_LIMIT_RAD:.4g} rad, '
                             f'got {value!r}')
        return float(value)

    @staticmethod
    def check_velocity(value: float, name: str = 'velocity') -> float:
        """[rad/s] a finite joint velocity below :data:`VELOCITY_LIMIT_RAD_PER_S`."""
        if isinstance(value, bool) or not (isinstance(value, (int, float))
                                           and abs(value) <= VELOCITY_LIMIT_RAD_PER_S):
            raise ValueError(f'`{name}` must be finite and within '
                             f'±{VELOCITY_LIMIT_RAD_PER_S:g} rad/s, got {value!r}')
        return float(value)

    # -- the model --------------------------------------------------------------

    def hold_torque(self, theta_rad: float) -> float:
        """[N m] muscle torque that holds the joint at rest at ``theta_rad``:
        the static torque balance of the limb's equation of motion,
        m g l_c sin(theta) + K (theta - theta_eq) - sum_i s_i r_i f_PE,i."""
        j = self.plant.joint
        passive = 0.0
        for m in self.plant.muscles:
            passive += m.sign * m.moment_arm_m * parallel_force(m.params.k_pe_n_per_m,
                                                                m.dl_mt(theta_rad))
        return (j.mass_kg * j.gravity_m_per_s2 * j.com_distance_m * math.sin(theta_rad)
                + j.stiffness_n_m_per_rad * (theta_rad - j.equilibrium_rad) - passive)

    def capacities(self, theta_rad: float) -> list[float]:
        """[N m] each muscle's torque magnitude at full recruitment at
        ``theta_rad``: r f_iso_max FL((l_rest + dl_MT) / l_opt)."""
        out = []
        for m in self.plant.muscles:
            p = m.params
            out.append(m.moment_arm_m * p.f_iso_max_n
                       * force_length((p.l_rest_m + m.dl_mt(theta_rad)) / p.l_opt_m))
        return out

    def allocate(self, torque_n_m: float, theta_rad: float) -> tuple[list[float], bool]:
        """Recruitment of each muscle for a muscle torque, and whether the
        group asked is at its limit.

        :param torque_n_m: [N m] muscle torque wanted (tau*)
        :param theta_rad: [rad] the joint angle, for the muscles' lengths
        :return: each muscle's recruitment R in [0, 1], and True if the
            extensors (tau* > 0) or flexors (tau* < 0) cannot give more
        """
        sign = 1.0 if torque_n_m > 0.0 else -1.0
        muscles = self.plant.muscles
        caps = self.capacities(theta_rad)
        group = [i for i, m in enumerate(muscles) if m.sign == sign]
        total = sum(caps[i] * self._reach(i) for i in group)
        recruitment = [0.0] * len(muscles)
        if torque_n_m == 0.0:
            return recruitment, False
        if total <= 0.0:
            return recruitment, True
        fraction = abs(torque_n_m) / total
        for i in group:
            recruitment[i] = min(fraction, 1.0) * self._reach(i)
        return recruitment, fraction >= 1.0

    def _reach(self, i: int) -> float:
        """[-] the largest recruitment muscle ``i``'s curve reaches within its PW_max."""
        p = self.plant.muscles[i].params
        return command_from_pulse_width(p.pw_max_s, p)

    def pulse_widths(self, recruitment: Sequence[float]) -> list[float]:
        """[s] each muscle's pulse width for its recruitment (inverse curve)."""
        return [pulse_width_within(r, m.params, m.params.pw_max_s)
                for r, m in zip(recruitment, self.plant.muscles)]

    # -- one control period -----------------------------------------------------

    def update(self, target_rad: float, theta_rad: float, omega_rad_per_s: float,
               dt_s: float) -> list[float]:
        """One control period: each muscle's pulse width to send now.

        :param target_rad: [rad] angle target (theta*)
        :param theta_rad: [rad] measured joint angle (theta)
        :param omega_rad_per_s: [rad/s] measured joint velocity (omega)
        :param dt_s: [s] time since the previous update
        :return: [s] pulse widths, one per muscle, in the plant's order
        :raises ValueError: on an invalid input (the state is unchanged)
        """
        self.check_angle(target_rad, 'target_rad')
        self.check_angle(theta_rad, 'theta_rad')
        self.check_velocity(omega_rad_per_s, 'omega_rad_per_s')
        if not (math.isfinite(dt_s) and dt_s > 0.0):
            raise ValueError(f'`dt_s` must be positive and finite, got {dt_s!r}')
        p = self.params
        if self.reference_rad is None:
            self.reference_rad = theta_rad
        move = target_rad - self.reference_rad
        if p.reference_rate_rad_per_s > 0.0:
            limit = p.reference_rate_rad_per_s * dt_s
            move = min(max(move, -limit), limit)
        self.reference_rad += move
        self.reference_velocity_rad_per_s = move / dt_s
        error = self.reference_rad - theta_rad
        feedforward = self.hold_torque(self.reference_rad) if p.feedforward == 'model' else 0.0
        torque = (feedforward + p.kp_n_m_per_rad * error + self.integral_n_m
                  + p.kd_n_m_s_per_rad * (self.reference_velocity_rad_per_s - omega_rad_per_s))
        recruitment, saturated = self.allocate(torque, theta_rad)
        # Conditional integration: not while the group that would have to
        # push harder in the error's direction is at its limit.
        if not (saturated and (error > 0.0) == (torque > 0.0)):
            self.integral_n_m += p.ki_n_m_per_rad_s * error * dt_s
        self.torque_n_m = torque
        return self.pulse_widths(recruitment)


def simulate_joint_control(plant: LimbPlant, target: Callable[[float], float],
                           duration_s: float, params: JointControllerParams | None = None,
                           rate_hz: float = 1000.0, feedback_delay_s: float = 0.0,
                           controller_plant: LimbPlant | None = None) -> dict[str, np.ndarray]:
    """The closed loop offline: :class:`JointController` on a
    :class:`~hill_muscle_ros.model.limb.Limb`, as the two nodes run it.

    The limb steps at ``rate_hz``; the controller updates every
    1 / ``params.control_rate_hz`` on the joint state ``feedback_delay_s`` old
    (rounded to steps), and its pulse widths are held until the next update.

    :param plant: the simulated limb
    :param target: [rad] theta*(t)
    :param duration_s: [s] simulated time
    :param params: the controller's gains
    :param rate_hz: [Hz] the limb's step rate
    :param feedback_delay_s: [s] age of the joint state the controller reads
    :param controller_plant: the controller's model; default ``plant``
    :return: arrays ``t_s``, ``target_rad``, ``theta_rad``, ``omega_rad_per_s``
        and ``pulse_width_s`` (steps x muscles), one row per step from t = 0
    """
    controller = JointController(controller_plant or plant, params)
    limb = Limb(plant)
    dt = 1.0 / rate_hz
    n = int(round(duration_s * rate_hz))
    every = max(1, int(round(rate_hz / controller.params.control_rate_hz)))
    delay = int(round(feedback_delay_s * rate_hz))
    t = np.arange(n + 1) * dt
    theta = np.empty(n + 1)
    omega = np.empty(n + 1)
    pw = np.zeros((n + 1, len(plant.muscles)))
    goal = np.array([target(float(x)) for x in t])
    theta[0], omega[0] = limb.theta_rad, limb.omega_rad_per_s
    widths = [0.0] * len(plant.muscles)
    for k in range(n):
        if k % every == 0:
            seen = max(k - delay, 0)
            widths = controller.update(float(goal[k]), float(theta[seen]), float(omega[seen]),
                                       every * dt)
        commands = [command_from_pulse_width(w, m.params)
                    for w, m in zip(widths, plant.muscles)]
        out = limb.step(commands, 0.0, dt)
        theta[k + 1], omega[k + 1] = out.theta_rad, out.omega_rad_per_s
        pw[k + 1] = widths
    return {'t_s': t, 'target_rad': goal, 'theta_rad': theta, 'omega_rad_per_s': omega,
            'pulse_width_s': pw}
