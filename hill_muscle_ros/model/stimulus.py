"""From stimulus to recruitment: the recruitment curve, the electromechanical
delay and the first-order activation (doc/model.md section 7.1-7.2).

Pure Python; every law here is written once and used by the scalar engine,
the batch, the limb, the protocol player and the CLI.

- The recruitment curve maps a pulse width PW [s] to the recruitment command
  u in [0, 1].
- The delay shifts the command by ``emd_s``: u_d(t) = u(t - emd_s), 0 before
  (the engine's ring buffer, :mod:`.muscle.kernels`).
- The activation a follows da/dt = (u_d - a) / tau, tau = ``tau_act_s`` while
  u_d > a and ``tau_deact_s`` otherwise; a is the recruitment R.

u_d is piecewise constant, so a has a closed form on each piece,
a(t) = u_d + (a0 - u_d) exp(-(t - t0) / tau), and so has the instant at which
it crosses a level: the instants at which units are recruited.
"""
from __future__ import annotations

import math

from .equations import equivalent_pulse_width
from .params import MuscleParams


def command_from_pulse_width(pulse_width_s: float, params: MuscleParams,
                             name: str = 'pulse_width_s') -> float:
    """Recruitment command u of an FES pulse: the recruitment curve.

    ``linear`` (the paper): u = PW / PW_max. ``threshold_linear`` (Veltink et
    al. 1992): u = (PW - PW_th) / (PW_max - PW_th). ``exponential`` (Ding et al.
    2007): u = 1 - exp(-(PW - PW_th) / PW_scale) above the threshold, 0 below.
    Each is then clipped to [0, 1]: below threshold nothing is recruited, and
    above saturation every unit already is. That is the stimulator's physics,
    not a correction. Negative or non-finite widths raise.

    :param pulse_width_s: [s] stimulation pulse width (PW)
    :param params: the muscle's parameters (curve, PW_max, PW_th, PW_scale)
    :param name: what to call the value in the error message (e.g. the topic)
    :return: [-] recruitment command u in [0, 1]
    """
    pw = float(pulse_width_s)
    if not (math.isfinite(pw) and pw >= 0.0):
        raise ValueError(f'`{name}` must be finite and non-negative, '
                         f'got {pulse_width_s!r}')
    curve = params.recruitment_curve
    if curve == 'linear':
        return min(pw / params.pw_max_s, 1.0)
    above = pw - params.pw_threshold_s
    if above <= 0.0:
        return 0.0
    if curve == 'threshold_linear':
        return min(above / (params.pw_max_s - params.pw_threshold_s), 1.0)
    return -math.expm1(-above / params.pw_scale_s)


def pulse_width_for_command(command: float, params: MuscleParams,
                            name: str = 'recruitment') -> float:
    """[s] The pulse width that gives command ``command``: the curve inverted.

    ``linear`` and ``threshold_linear`` reach u = 1 at ``pw_max_s``; u = 0 is
    given by a zero width. The exponential curve reaches u = 1 only at an
    infinite width, so it cannot be inverted there.

    :param command: [-] recruitment command u in [0, 1]
    :param params: the muscle's parameters (curve, PW_max, PW_th, PW_scale)
    :raises ValueError: for u outside [0, 1], or u = 1 on the exponential curve
    """
    u = float(command)
    if not 0.0 <= u <= 1.0:
        raise ValueError(f'`{name}` must be in [0, 1], got {command!r}')
    if u == 0.0:
        return 0.0
    curve = params.recruitment_curve
    if curve == 'linear':
        return u * params.pw_max_s
    if curve == 'threshold_linear':
        return params.pw_threshold_s + u * (params.pw_max_s - params.pw_threshold_s)
    if u == 1.0:
        raise ValueError(f'`{name}` = 1 needs an infinite pulse width on the exponential '
                         'recruitment curve; give the protocol in pulse widths')
    return params.pw_threshold_s - params.pw_scale_s * math.log1p(-u)


def time_constant(params: MuscleParams, a: float, u_d: float) -> float:
    """[s] tau in force: ``tau_act_s`` while u_d > a, else ``tau_deact_s``."""
    return params.tau_act_s if u_d > a else params.tau_deact_s


def pulse_command(pulse_width_s: float, current_a: float | None, params: MuscleParams) -> float:
    """[-] The fraction u of a channel's territory a pulse recruits: the recruitment
    curve at the equivalent width PW_eq (doc/model.md section 10).

    With a current I, PW_eq is the width that recruits the same units at
    ``current_ref_a`` under the strength-duration law
    (:func:`~.equations.equivalent_pulse_width`); without one, PW_eq = PW. A
    pulse that excites more than any width at I_ref would recruits every unit.

    :param pulse_width_s: [s] pulse width (PW), >= 0
    :param current_a: [A] pulse current (I), >= 0, or ``None`` for ``current_ref_a``
    :param params: the muscle's parameters (curve, chronaxie, reference current)
    :return: [-] u in [0, 1]
    """
    pw = pulse_width_s
    if current_a is not None:
        pw = equivalent_pulse_width(pulse_width_s, current_a, params.current_ref_a,
                                    params.chronaxie_s)
        if pw == math.inf:
            return 1.0
    return command_from_pulse_width(pw, params)
