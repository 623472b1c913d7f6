"""A force controller for FES: feedforward through the inverse recruitment
curve plus a PI loop with anti-windup, output clamped to [0, PW_max].

This is an example for users to start from, not part of the muscle model.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

from ..model.curves import force_length
from ..model.params import MuscleParams

_DEFAULTS = MuscleParams()
#: [N] force of the default muscle at full recruitment, held at rest length with
#: initial-length memory: f_iso_max FL(l_rest / l_opt) = 37.19 N (MODEL.md section 6).
DEFAULT_FF_FORCE_N = _DEFAULTS.f_iso_max_n * force_length(_DEFAULTS.l_rest_m / _DEFAULTS.l_opt_m)


#: [s/N] and [s/(N s)] default gains, and [s] the reference model's time
#: constant. Tuned offline (muscle at 1 kHz, controller at 100 Hz) for
#: robustness to the loop delay of DDS on a loaded machine rather than for the
#: fastest step: with 3-10 ms of feedback delay, 2-5 ms of command delay and up
#: to 10 ms of jitter, the step 0 -> 20 N overshoots < 1 % and settles within
#: 2 % in about 0.22 s, and the 10 mm/s stretch at 15 N stays within 0.72-1.05 N
#: after its first 100 ms (0.72-0.82 N up to 5 ms of delay and 8 ms of jitter).
#: Why not stiffer: during a fast stretch with few units recruited the CE
#: cannot lengthen faster than F0 b' / a' (Eq. 3 saturates), the muscle turns
#: soft and fast, and a larger kp (4e-5) drives the pulse width to zero there
#: and collapses the loop once the delay passes about 8 ms.
#: [N] no FES-driven muscle comes near this; a larger input is a unit error or garbage.
DEFAULT_FORCE_LIMIT_N = 1.0e4
DEFAULT_KP_S_PER_N = 1.5e-5
DEFAULT_KI_S_PER_N_S = 3.0e-4
DEFAULT_REFERENCE_TAU_S = 0.06


def _spec(unit: str, description: str, low: float, high: float) -> dict:
    return {'unit': unit, 'description': description, 'low': low, 'high': high}


@dataclass(frozen=True)
class ControllerParams:
    """Gains and limits of :class:`ForceController`; validated on construction.

    :param kp_s_per_n: [s/N] proportional gain, pulse width per newton of error
    :param ki_s_per_n_s: [s/(N s)] integral gain
    :param ff_force_n: [N] force expected at full recruitment; the feedforward
        inverts R = F / ff_force_n, then PW = R PW_max. 0 disables feedforward.
    :param pw_max_s: [s] largest pulse width the stimulator may send (PW_max)
    :param rate_hz: [Hz] control and stimulation rate
    :param feedback_timeout_s: [s] stop stimulating if no force arrives this long
    :param reference_tau_s: [s] the PI loop tracks the target through a first-order
        lag of this time constant (a two-degree-of-freedom design): the
        feedforward moves the muscle at once, and the feedback only corrects
        the deviation from the expected rise, so the integral does not wind up
        during a step. 0 makes the feedback track the target itself.
    :param force_limit_n: [N] inputs beyond this are rejected (see :meth:`ForceController.check_target`)
    """

    kp_s_per_n: float = field(default=DEFAULT_KP_S_PER_N, metadata=_spec(
        's/N', 'proportional gain (pulse width per newton of force error)', 0.0, 1.0))
    ki_s_per_n_s: float = field(default=DEFAULT_KI_S_PER_N_S, metadata=_spec(
        's/(N s)', 'integral gain', 0.0, 10.0))
    ff_force_n: float = field(default=DEFAULT_FF_FORCE_N, metadata=_spec(
        'N', 'force at full recruitment used by the feedforward (0 disables it)', 0.0, 1e6))
    pw_max_s: float = field(default=_DEFAULTS.pw_max_s, metadata=_spec(
        's', 'largest pulse width sent; also the recruitment scale PW_max', 1e-9, 1.0))
    rate_hz: float = field(default=100.0, metadata=_spec(
        'Hz', 'control and stimulation rate', 1e-3, 1e5))
    feedback_timeout_s: float = field(default=0.2, metadata=_spec(
        's', 'stop stimulating when force feedback is older than this', 1e-3, 1e3))
    reference_tau_s: float = field(default=DEFAULT_REFERENCE_TAU_S, metadata=_spec(
        's', 'time constant of the reference model the feedback tracks (0: the target itself)',
        0.0, 10.0))
    force_limit_n: float = field(default=DEFAULT_FORCE_LIMIT_N, metadata=_spec(
        'N', 'a force target above this, or a force feedback beyond +-this, is '
        'rejected as garbage', 1e-3, 1e9))

    def __post_init__(self) -> None:
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            low, high = f.metadata['low'], f.metadata['high']
            if isinstance(value, bool) or not isinstance(value, (int, float)):
                raise ValueError(f'`{f.name}` must be a number, got {value!r}')
            if not (math.isfinite(value) and low <= value <= high):
                raise ValueError(f'`{f.name}` must be in [{low}, {high}], got {value!r}')
            object.__setattr__(self, f.name, float(value))


class ForceController:
    """PI force control with feedforward and conditional-integration anti-windup.

    ``PW = clip(PW_ff(F*) + kp e + ki ∫e, 0, PW_max)`` with ``e = F_ref - F``,
    where ``F_ref`` follows the target ``F*`` through a first-order lag of
    time constant ``reference_tau_s`` (``F_ref = F*`` when it is 0).
    The integrator only moves when the output is not saturated in the
    direction the error pushes, so it never winds up against the clamp.

    :param params: gains and limits
    """

    def __init__(self, params: ControllerParams | None = None) -> None:
        self.params = params if params is not None else ControllerParams()
        self.reset()

    def reset(self) -> None:
        """Forget the integral; the next output starts from the feedforward."""
        self.integral_s = 0.0  # [s] integral term, in pulse-width units
        self.reference_n: float | None = None  # [N] F_ref; starts at the measured force

    def check_target(self, target_n: float) -> float:
        """Validate a force target (F*).

        :param target_n: [N] force target
        :return: ``target_n``
        :raises ValueError: if it is not finite, negative, or above ``force_limit_n``
        """
        limit = self.params.force_limit_n
        if not (math.isfinite(target_n) and 0.0 <= target_n <= limit):
            raise ValueError(f'`force_target` must be finite and in [0, {limit:g}] N, '
                             f'got {target_n!r}')
        return target_n

    def check_force(self, force_n: float) -> float:
        """Validate a force measurement (F). A slightly negative reading is
        accepted: a real load cell gives one at rest.

        :param force_n: [N] measured force
        :return: ``force_n``
        :raises ValueError: if it is not finite or beyond +-``force_limit_n``
        """
        limit = self.params.force_limit_n
        if not (math.isfinite(force_n) and abs(force_n) <= limit):
            raise ValueError(f'`force` must be finite and within +-{limit:g} N, '
                             f'got {force_n!r}')
        return force_n

    def feedforward(self, target_n: float) -> float:
        """[s] pulse width expected to hold ``target_n`` newtons (inverse recruitment curve)."""
        p = self.params
        if p.ff_force_n == 0.0:
            return 0.0
        return p.pw_max_s * min(max(target_n / p.ff_force_n, 0.0), 1.0)

    def update(self, target_n: float, force_n: float, dt_s: float) -> float:
        """One control period: the pulse width to send now.

        :param target_n: [N] force target (F*)
        :param force_n: [N] measured muscle force (F)
        :param dt_s: [s] time since the previous update
        :return: [s] pulse width in [0, PW_max]
        :raises ValueError: on a non-finite input (the state is unchanged)
        """
        for name, value in (('target_n', target_n), ('force_n', force_n), ('dt_s', dt_s)):
            if not math.isfinite(value):
                raise ValueError(f'`{name}` must be finite, got {value!r}')
        if dt_s <= 0.0:
            raise ValueError(f'`dt_s` must be positive, got {dt_s!r}')
        p = self.params
        if self.reference_n is None:
            self.reference_n = force_n
        blend = 1.0 if p.reference_tau_s == 0.0 else -math.expm1(-dt_s / p.reference_tau_s)
        self.reference_n += (target_n - self.reference_n) * blend
        error = self.reference_n - force_n
        unclamped = self.feedforward(target_n) + p.kp_s_per_n * error + self.integral_s
        pushing_up = error > 0.0
        saturated = (unclamped >= p.pw_max_s and pushing_up) or (unclamped <= 0.0 and not pushing_up)
        if not saturated:
            self.integral_s += p.ki_s_per_n_s * error * dt_s
        return min(max(unclamped, 0.0), p.pw_max_s)
