"""A force controller for FES: a feedforward plus a PI loop with anti-windup,
output clamped to [0, PW_max].

The output is a pulse width (``modulate: pulse_width``, the default) or, with
``modulate: frequency``, read as a fraction u = output / PW_max of the range
[``frequency_min_hz``, ``frequency_max_hz``] of a train of pulses of a fixed
width ``pulse_width_s`` on channel 1 (:func:`frequency_command`).

The feedforward is either the inverse recruitment curve (``recruitment``:
R = F* / ff_force_n) or, when the controller is given a nominal muscle model
and the imposed length, the model's inverse dynamics (``model``): the
recruitment that holds the target while the muscle is being stretched or
shortened, through the parallel spring and the force-velocity relation.

This is an example for users to start from, not part of the muscle model.
"""
from __future__ import annotations

import collections
import dataclasses
import math
from dataclasses import dataclass, field

import numpy as np

from ..model.command_track import CommandTrack, check_time
from ..model.equations import force_length, isometric_force_for, parallel_force
from ..model.muscle import check_dl_mt
from ..model.params import MuscleParams
from ..model.stimulator import ChannelCommand, StimulatorProfile, check_channel_command
from ..model.stimulus import command_from_pulse_width, pulse_width_for_command

_DEFAULTS = MuscleParams()
#: [N] force of the default muscle at full recruitment, held at rest length with
#: initial-length memory: f_iso_max FL(l_rest / l_opt) = 37.19 N (doc/model.md section 6).
DEFAULT_FF_FORCE_N = _DEFAULTS.f_iso_max_n * force_length(_DEFAULTS.l_rest_m / _DEFAULTS.l_opt_m)


#: [s/N] and [s/(N s)] default gains, and [s] the reference model's time
#: constant. Tuned offline (muscle at 1 kHz, controller at 100 Hz,
#: ``test/test_control_pi.py``'s loop) for robustness to the loop delay of DDS
#: on a loaded machine rather than for the fastest step. The step 0 -> 20 N
#: overshoots < 0.1 % with up to 50 ms of feedback delay and 3.7 % with 60 ms
#: (``instantaneous``), settling within 2 % in 0.60-0.68 s; the 10 mm/s stretch
#: at 15 N stays within 0.58-0.59 N after its first 100 ms with 5-30 ms.
#: Why not faster: the earlier kp 1.5e-5, ki 3e-4 and 60 ms settled in 0.22 s
#: but overshot 10 % at 30 ms of delay and 29 % at 50 ms, and a fresh-clone
#: run over DDS measured that 10 % (the force a 100 Hz Python node acts on
#: can be tens of ms old when it takes 2000 messages a second). Why not
#: stiffer: during a fast stretch with few units recruited the CE cannot
#: lengthen faster than F0 b' / a' (Eq. 3 saturates), the muscle turns soft
#: and fast, and a larger kp (4e-5) drives the pulse width to zero there and
#: collapses the loop once the delay passes about 8 ms. The model feedforward,
#: not the PI, holds the stretch, so the softer PI costs it nothing.
#: [N] no FES-driven muscle comes near this; a larger input is a unit error or garbage.
DEFAULT_FORCE_LIMIT_N = 1.0e4
DEFAULT_KP_S_PER_N = 1.0e-5
DEFAULT_KI_S_PER_N_S = 1.5e-4
DEFAULT_REFERENCE_TAU_S = 0.15
#: [s] window of the imposed length's rate estimate: long enough to average
#: out DDS arrival jitter over several 1 kHz samples, short enough to see a
#: ramp stop within a fraction of a control period (offline, a 10 ms window
#: doubled the force dip at the end of a 10 mm/s stretch).
DEFAULT_LENGTH_RATE_WINDOW_S = 0.005
#: [s] stamped length set points are read this far ahead: half of a 100 Hz
#: control period, the middle of the interval the pulse width will act over.
DEFAULT_LENGTH_PREVIEW_S = 0.005
#: [s] force feedback older than this stops stimulation. Longer than any
#: stall of a simulator or sensor process that a loop should ride through
#: (hundreds of ms were seen on a loaded 2-core machine), and equal to the
#: simulator's stimulation watchdog (``input_timeout_s``, 0.5 s), so that
#: both ends of the loop give up on a silent peer after the same time.
DEFAULT_FEEDBACK_TIMEOUT_S = 0.5
#: [s] 0: a force target is a set point that holds until the next one (what
#: ``ros2 topic pub --once`` means); a positive value makes it expire.
DEFAULT_TARGET_TIMEOUT_S = 0.0
#: Feedforward choices: the nominal model's inverse dynamics (uses the
#: imposed length), the inverse recruitment curve (force only), or none.
FEEDFORWARD_CHOICES = ('model', 'recruitment', 'none')
#: What the output drives: the pulse width (``pulse_width`` topic, the
#: default), or the frequency of channel 1 at a fixed pulse width
#: (``stimulation`` topic, :func:`frequency_command`).
MODULATE_CHOICES = ('pulse_width', 'frequency')
#: [s] the fixed pulse width of ``modulate: frequency``: 500 us, the paper's
#: PW_max (every unit recruited on its linear curve, so that frequency grades
#: the whole muscle's force) and the widest pulse of the RehaStim 2
#: (pyScienceMode 1.1.5, ``Channel.check_value_param``). Kesar & Binder-Macleod
#: 2006 paired the longest pulses (600 us) with the lowest frequency (11.5 Hz)
#: and found that protocol the least fatiguing.
DEFAULT_MODULATED_PULSE_WIDTH_S = 500e-6
#: [Hz] the frequency range of ``modulate: frequency``: the lowest and the
#: highest frequency of Kesar & Binder-Macleod 2006's three quadriceps protocols
#: (11.5 Hz at 600 us, 30 Hz at 150 us, 60 Hz at 131 us), which gave the same
#: initial force.
DEFAULT_FREQUENCY_MIN_HZ = 11.5
DEFAULT_FREQUENCY_MAX_HZ = 60.0


def _spec(unit: str, description: str, low: float | None = None, high: float | None = None,
          choices: tuple[str, ...] | None = None) -> dict:
    return {'unit': unit, 'description': description, 'low': low, 'high': high,
            'choices': choices}


def check_spec_fields(params) -> None:
    """Validate a frozen controller-parameter dataclass on construction: each
    field of :func:`_spec` metadata is one of its choices, or a finite number
    in its [low, high] range, stored as a float.

    :raises ValueError: naming the first bad field, its range (and unit) and the value
    """
    for f in dataclasses.fields(params):
        value, spec = getattr(params, f.name), f.metadata
        if spec['choices'] is not None:
            if value not in spec['choices']:
                raise ValueError(f'`{f.name}` must be one of {", ".join(spec["choices"])}, '
                                 f'got {value!r}')
            continue
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ValueError(f'`{f.name}` must be a number, got {value!r}')
        if not (math.isfinite(value) and spec['low'] <= value <= spec['high']):
            raise ValueError(f'`{f.name}` must be in [{spec["low"]:g}, {spec["high"]:g}] '
                             f'{spec["unit"]}, got {value!r}')
        object.__setattr__(params, f.name, float(value))


@dataclass(frozen=True)
class ControllerParams:
    """Gains and limits of :class:`ForceController`; validated on construction.

    :param kp_s_per_n: [s/N] proportional gain, pulse width per newton of error
    :param ki_s_per_n_s: [s/(N s)] integral gain
    :param feedforward: ``model`` (the default): the nominal muscle model's
        inverse dynamics, see :meth:`ForceController.feedforward`; it needs the
        model (else it falls back to ``recruitment``). ``recruitment``: the
        inverse recruitment curve R = F* / ff_force_n. ``none``: PI only.
    :param ff_force_n: [N] force expected at full recruitment, for the
        ``recruitment`` feedforward: PW = PW_max F* / ff_force_n. 0 disables it.
    :param pw_max_s: [s] largest pulse width the stimulator may send (PW_max)
    :param rate_hz: [Hz] control and stimulation rate
    :param feedback_timeout_s: [s] stop stimulating if no force arrives this long
        (:class:`ControllerInputs`)
    :param target_timeout_s: [s] stop stimulating if no target arrives this
        long; 0 (the default) keeps a target until the next one, as a set point
    :param reference_tau_s: [s] the PI loop tracks the target through a first-order
        lag of this time constant (a two-degree-of-freedom design): the
        feedforward moves the muscle at once, and the feedback only corrects
        the deviation from the expected rise, so the integral does not wind up
        during a step. 0 makes the feedback track the target itself.
    :param length_rate_window_s: [s] the rate of the imposed length is the
        least-squares slope of the samples received within this window
        (:class:`LengthRate`)
    :param length_preview_s: [s] stamped set points are read this far ahead
        (:class:`ImposedLength`)
    :param force_limit_n: [N] inputs beyond this are rejected (see :meth:`ForceController.check_target`)
    :param modulate: ``pulse_width`` (the default): the output is the pulse
        width sent. ``frequency``: the output, as a fraction of ``pw_max_s``,
        sets the frequency of channel 1 at the fixed ``pulse_width_s``
        (:func:`frequency_command`)
    :param pulse_width_s: [s] the fixed pulse width of ``modulate: frequency``,
        at most ``pw_max_s`` there
    :param frequency_min_hz: [Hz] the frequency of the smallest output above 0
    :param frequency_max_hz: [Hz] the frequency of the output ``pw_max_s``;
        above ``frequency_min_hz``
    :raises ValueError: naming the field, its range and the value
    """

    feedforward: str = field(default=FEEDFORWARD_CHOICES[0], metadata=_spec(
        '-', 'feedforward: model (inverse dynamics of the nominal muscle, uses length_command), '
        'recruitment (inverse recruitment curve) or none', choices=FEEDFORWARD_CHOICES))
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
    feedback_timeout_s: float = field(default=DEFAULT_FEEDBACK_TIMEOUT_S, metadata=_spec(
        's', 'stop stimulating when force feedback is older than this', 1e-3, 1e3))
    target_timeout_s: float = field(default=DEFAULT_TARGET_TIMEOUT_S, metadata=_spec(
        's', 'stop stimulating when the newest force_target is older than this '
        '(0: a target holds until the next one)', 0.0, 1e6))
    reference_tau_s: float = field(default=DEFAULT_REFERENCE_TAU_S, metadata=_spec(
        's', 'time constant of the reference model the feedback tracks (0: the target itself)',
        0.0, 10.0))
    length_rate_window_s: float = field(default=DEFAULT_LENGTH_RATE_WINDOW_S, metadata=_spec(
        's', 'window of the least-squares rate estimate of length_command, for the model '
        'feedforward', 1e-4, 10.0))
    length_preview_s: float = field(default=DEFAULT_LENGTH_PREVIEW_S, metadata=_spec(
        's', 'stamped length set points (length_command_stamped) are read this far ahead',
        0.0, 10.0))
    force_limit_n: float = field(default=DEFAULT_FORCE_LIMIT_N, metadata=_spec(
        'N', 'a force target above this, or a force feedback beyond +-this, is '
        'rejected as garbage', 1e-3, 1e9))
    modulate: str = field(default=MODULATE_CHOICES[0], metadata=_spec(
        '-', 'what the output drives: pulse_width (published on pulse_width) or frequency '
        '(channel 1 at pulse_width_s, its frequency in [frequency_min_hz, frequency_max_hz], '
        'published on stimulation); read-only', choices=MODULATE_CHOICES))
    pulse_width_s: float = field(default=DEFAULT_MODULATED_PULSE_WIDTH_S, metadata=_spec(
        's', 'fixed pulse width of modulate frequency, at most pw_max_s (500 us: the paper\'s '
        'PW_max, the RehaStim 2\'s widest pulse)', 1e-9, 1.0))
    frequency_min_hz: float = field(default=DEFAULT_FREQUENCY_MIN_HZ, metadata=_spec(
        'Hz', 'frequency of the smallest output above 0 in modulate frequency (11.5 Hz: '
        'Kesar & Binder-Macleod 2006)', 1e-3, 1e4))
    frequency_max_hz: float = field(default=DEFAULT_FREQUENCY_MAX_HZ, metadata=_spec(
        'Hz', 'frequency of the output pw_max_s in modulate frequency, above frequency_min_hz '
        '(60 Hz: Kesar & Binder-Macleod 2006)', 1e-3, 1e4))

    def __post_init__(self) -> None:
        check_spec_fields(self)
        if not self.frequency_min_hz < self.frequency_max_hz:
            raise ValueError(f'`frequency_max_hz` must be above `frequency_min_hz` '
                             f'({self.frequency_min_hz!r} Hz), got {self.frequency_max_hz!r}')
        if self.modulate == 'frequency' and not self.pulse_width_s <= self.pw_max_s:
            raise ValueError(f'`pulse_width_s` must be at most `pw_max_s` ({self.pw_max_s!r} '
                             f's) with modulate frequency, got {self.pulse_width_s!r}')


def frequency_command(output_s: float, params: ControllerParams) -> ChannelCommand:
    """Channel 1's command for a controller output in ``modulate: frequency``.

    The output is read as u = ``output_s`` / ``pw_max_s``, clipped to [0, 1].
    u = 0 is no stimulation: pulse width 0 (at ``frequency_min_hz``), as the
    pulse-width output 0 is. Above it the train has the fixed width
    ``pulse_width_s`` and the frequency
    ``frequency_min_hz + u (frequency_max_hz - frequency_min_hz)``, single pulses.

    :param output_s: [s] the controller's output (:meth:`ForceController.update`),
        in [0, ``pw_max_s``]
    :param params: the controller's parameters
    :return: channel 1's command, no current (the muscle's reference current)
    """
    u = min(max(output_s / params.pw_max_s, 0.0), 1.0)
    f_min, f_max = params.frequency_min_hz, params.frequency_max_hz
    if not u > 0.0:
        return ChannelCommand(1, 'single', 0.0, None, f_min)
    f = min(max(f_min + u * (f_max - f_min), f_min), f_max)
    return ChannelCommand(1, 'single', params.pulse_width_s, None, f)


def check_frequency_range(params: ControllerParams, profile: StimulatorProfile) -> None:
    """Check that every command of ``modulate: frequency`` is one the
    stimulator accepts: its ends (the profile's ranges are intervals) and the
    zero stimulation.

    :param params: the controller's parameters
    :param profile: the stimulator
    :raises ValueError: naming the parameter, the field, the channel and the value
    """
    for name, pulse_width_s, f in (
            ('frequency_min_hz', params.pulse_width_s, params.frequency_min_hz),
            ('frequency_max_hz', params.pulse_width_s, params.frequency_max_hz),
            ('frequency_min_hz', 0.0, params.frequency_min_hz)):
        try:
            check_channel_command(profile, 1, f, pulse_width_s, None, 'single')
        except ValueError as err:
            which = (f'`pulse_width_s` {params.pulse_width_s!r} s' if 'pulse_width_s' in str(err)
                     else f'`{name}` {f!r} Hz')
            raise ValueError(f'{which} is refused by the stimulator: {err}') from None


class LengthRate:
    """The imposed MTU length and its rate, from samples as they arrive.

    The rate is the least-squares slope over the last ``window_s``: a
    difference of two samples would amplify the arrival jitter of DDS. With
    fewer than two samples in the window, or the newest older than the
    window, the length is taken as held (rate 0). Samples that span less than
    half the window arrived in a burst (the process was descheduled and got
    them all at once): their arrival times say nothing about the motion, so
    the previous rate is kept. Arrival times are a poor clock on a loaded
    machine; a sender that stamps its set points should use
    ``length_command_stamped`` (:class:`ImposedLength`).

    :param window_s: [s] averaging window
    """

    def __init__(self, window_s: float) -> None:
        self.window_s = window_s
        self._samples: collections.deque[tuple[float, float]] = collections.deque()
        self.dl_mt_m = 0.0  # [m] the newest sample (dl_MT), 0 before the first
        self._rate = 0.0    # [m/s] the last rate estimated from a spread of samples

    def add(self, t_s: float, dl_mt_m: float) -> None:
        """One sample: ``dl_mt_m`` [m] received at ``t_s`` [s]."""
        self._samples.append((t_s, dl_mt_m))
        self.dl_mt_m = dl_mt_m

    def rate(self, now_s: float) -> float:
        """[m/s] least-squares rate over the window ending at ``now_s``."""
        while self._samples and self._samples[0][0] < now_s - self.window_s:
            self._samples.popleft()
        if len(self._samples) < 2:
            self._rate = 0.0
            return 0.0
        t, x = np.array(self._samples).T
        if t[-1] - t[0] >= 0.5 * self.window_s:
            self._rate = float(np.polyfit(t - t[0], x, 1)[0])
        return self._rate


class ImposedLength:
    """What the controller knows of the imposed MTU length: dl_MT and its rate.

    Two sources, the newest message deciding which one is used:

    - plain samples (``length_command``, std_msgs/Float64) with their arrival
      times: :class:`LengthRate`;
    - stamped set points (``length_command_stamped``, sent ahead by a rig or
      player that knows its motion): a :class:`CommandTrack`, read at
      ``now + preview_s``. The stamps are exact where arrival times jitter,
      and reading ahead lets the feedforward act when the motion changes
      rather than a control period and a DDS hop after.

    :param window_s: [s] rate window of the plain samples
    :param preview_s: [s] how far ahead the stamped track is read
    """

    #: [s] half-width of the central difference that gives the track's rate:
    #: the 1 ms of a 1 kHz sender, so that a corner of the track is seen as such.
    RATE_HALF_WIDTH_S = 0.5e-3

    def __init__(self, window_s: float, preview_s: float) -> None:
        self.plain = LengthRate(window_s)
        self.preview_s = preview_s
        self._track: CommandTrack | None = None

    def add_sample(self, t_s: float, dl_mt_m: float) -> None:
        """A plain length command received at ``t_s`` [s]; it becomes the source."""
        self.plain.add(t_s, dl_mt_m)
        self._track = None

    def add_knot(self, stamp_s: float, dl_mt_m: float, now_s: float) -> None:
        """A stamped set point: reach ``dl_mt_m`` [m] at ``stamp_s`` [s],
        received at ``now_s`` [s]; the stamped track becomes the source.

        :raises ValueError: naming the value if it is invalid (the track is unchanged)
        """
        check_time(stamp_s, 'stamp')
        check_dl_mt(dl_mt_m, 'length_command_stamped')
        if self._track is None:
            # From the length known now, not from some earlier time.
            self._track = CommandTrack(self.plain.dl_mt_m, min(now_s, stamp_s),
                                       name='length_command_stamped')
        self._track.add(stamp_s, dl_mt_m)
        self.plain.dl_mt_m = dl_mt_m

    def at(self, now_s: float) -> tuple[float, float]:
        """[m], [m/s] dl_MT and its rate to use at ``now_s`` [s]."""
        track = self._track
        if track is None:
            return self.plain.dl_mt_m, self.plain.rate(now_s)
        if now_s > track.consumed_s:
            track.consume(now_s)
        t, h = max(now_s, track.consumed_s) + self.preview_s, self.RATE_HALF_WIDTH_S
        before, after = track.value_at(np.array([t - h, t + h]))
        return float(track.value_at(t)), float(after - before) / (2.0 * h)


def pulse_width_within(command: float, params: MuscleParams, pw_max_s: float) -> float:
    """[s] The pulse width that recruits ``command`` on a muscle's curve, at
    most ``pw_max_s`` (the exponential curve reaches u = 1 only at an
    infinite width, so a command beyond what ``pw_max_s`` gives is that width).

    :param command: [-] recruitment command u in [0, 1]
    :param params: the muscle (curve, PW_th, PW_scale, PW_max)
    :param pw_max_s: [s] the widest pulse the stimulator sends
    """
    if command >= command_from_pulse_width(pw_max_s, params):
        return pw_max_s
    return min(pulse_width_for_command(command, params), pw_max_s)


class ForceController:
    """PI force control with feedforward and conditional-integration anti-windup.

    ``PW = clip(PW_ff + kp e + ki ∫e, 0, PW_max)`` with ``e = F_ref - F``,
    where ``F_ref`` follows the target ``F*`` through a first-order lag of
    time constant ``reference_tau_s`` (``F_ref = F*`` when it is 0).
    The integrator only moves when the output is not saturated in the
    direction the error pushes, so it never winds up against the clamp.

    :param params: gains and limits
    :param model: the nominal muscle the ``model`` feedforward inverts (the
        controller's belief, not the simulated muscle: it may differ). Without
        it the ``model`` feedforward falls back to ``recruitment``.
    """

    def __init__(self, params: ControllerParams | None = None,
                 model: MuscleParams | None = None) -> None:
        self.params = params if params is not None else ControllerParams()
        self.model = model
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

    def feedforward(self, target_n: float, force_n: float | None = None,
                    dl_mt_m: float = 0.0, v_mt_m_per_s: float = 0.0) -> float:
        """[s] pulse width expected to hold ``target_n`` newtons.

        ``recruitment``: the inverse recruitment curve, PW_max F* / ff_force_n.

        ``model``: the nominal model's inverse dynamics at the imposed length
        dl_MT and its rate. The PE carries ``k_PE dl_MT`` of the target, the
        SE the rest (f_SE*); for the SE to keep carrying f_SE* while the PE
        force changes, the CE must move at ``v_MT + k_PE v_MT / k_SE``; Eq. (3)
        solved for F0 at that force and velocity
        (:func:`~hill_muscle_ros.model.equations.isometric_force_for`) gives the
        effective isometric force to recruit, and ``f_iso_max FL(l_CE / l_opt)``
        per unit of R, at the CE length the measured force implies
        (``l_rest + dl_MT - f_SE / k_SE``), turns it into R. Held at rest
        length this is the recruitment curve again; during a stretch it
        recruits less (the eccentric CE is stronger and the PE takes a share),
        which a PI alone can only learn through a lasting error.

        :param target_n: [N] force target (F*)
        :param force_n: [N] measured force (F), for the CE length; None: F*
        :param dl_mt_m: [m] imposed MTU length change (dl_MT)
        :param v_mt_m_per_s: [m/s] its rate, positive when stretching
        """
        p, m = self.params, self.model
        if p.feedforward == 'none':
            return 0.0
        if p.feedforward == 'recruitment' or m is None:
            if p.ff_force_n == 0.0:
                return 0.0
            return p.pw_max_s * min(max(target_n / p.ff_force_n, 0.0), 1.0)
        f_pe = parallel_force(m.k_pe_n_per_m, dl_mt_m)
        f_se = target_n - f_pe
        if f_se <= 0.0:
            return 0.0     # the passive muscle alone pulls this hard already
        v_ce = v_mt_m_per_s
        if dl_mt_m > 0.0 and m.k_se_n_per_m > 0.0:
            v_ce += v_mt_m_per_s * m.k_pe_n_per_m / m.k_se_n_per_m
        f0 = isometric_force_for(f_se, v_ce, m.fv_a_n, m.fv_b_m_per_s, m.fv_a_ecc_n,
                                 m.fv_b_ecc_m_per_s)
        f_se_now = f_se if force_n is None else max(force_n - f_pe, 0.0)
        l_ce = m.l_rest_m + dl_mt_m - (f_se_now / m.k_se_n_per_m if m.k_se_n_per_m > 0.0 else 0.0)
        per_unit_r = m.f_iso_max_n * force_length(l_ce / m.l_opt_m)
        if per_unit_r <= 0.0:
            return 0.0     # no recruitment makes force at this length: leave it to the PI
        return self._pulse_width_for(min(f0 / per_unit_r, 1.0))

    def _pulse_width_for(self, command: float) -> float:
        """[s] The pulse width that recruits ``command`` on the model's curve,
        at most this controller's PW_max (the exponential curve reaches u = 1
        only at an infinite width)."""
        p, m = self.params, self.model
        if m.recruitment_curve == 'linear':
            return p.pw_max_s * command
        return pulse_width_within(command, m, p.pw_max_s)

    def update(self, target_n: float, force_n: float, dt_s: float,
               dl_mt_m: float = 0.0, v_mt_m_per_s: float = 0.0) -> float:
        """One control period: the pulse width to send now.

        :param target_n: [N] force target (F*)
        :param force_n: [N] measured muscle force (F)
        :param dt_s: [s] time since the previous update
        :param dl_mt_m: [m] imposed MTU length change (dl_MT), for the feedforward
        :param v_mt_m_per_s: [m/s] its rate
        :return: [s] pulse width in [0, PW_max]
        :raises ValueError: on a non-finite input (the state is unchanged)
        """
        for name, value in (('target_n', target_n), ('force_n', force_n), ('dt_s', dt_s),
                            ('dl_mt_m', dl_mt_m), ('v_mt_m_per_s', v_mt_m_per_s)):
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
        unclamped = (self.feedforward(target_n, force_n, dl_mt_m, v_mt_m_per_s)
                     + p.kp_s_per_n * error + self.integral_s)
        pushing_up = error > 0.0
        saturated = (unclamped >= p.pw_max_s and pushing_up) or (unclamped <= 0.0 and not pushing_up)
        if not saturated:
            self.integral_s += p.ki_s_per_n_s * error * dt_s
        return min(max(unclamped, 0.0), p.pw_max_s)


class ControllerInputs:
    """What the controller has heard, and whether it may act on it.

    The controller acts only on inputs it has received: until a force target
    and a fresh force measurement have both arrived it sends no stimulation
    and integrates nothing (a target made up as 0 N would wind the integral
    against the real force). The same holds when the feedback goes stale
    (older than ``feedback_timeout_s``) or, with ``target_timeout_s`` > 0,
    when the target does. Between those, a control period without a new
    force sample (the plant was briefly late) holds the last output instead
    of integrating the old error again: a stall shorter than the timeout is
    ridden through, not turned into a dropout.

    Times are in seconds of the node's clock.

    :param feedback_timeout_s: [s] age at which the force feedback is stale
    :param target_timeout_s: [s] age at which the target is stale; 0: never
    """

    #: :meth:`state` values.
    READY = 'ready'
    NO_TARGET = 'no force_target received yet'
    NO_FEEDBACK = 'no force feedback received yet'
    STALE_FEEDBACK = 'force feedback stale'
    STALE_TARGET = 'force_target stale'

    def __init__(self, feedback_timeout_s: float, target_timeout_s: float = 0.0) -> None:
        self.feedback_timeout_s = feedback_timeout_s
        self.target_timeout_s = target_timeout_s
        self.target_n: float | None = None     # [N] F*, None until one arrives
        self.target_t_s: float | None = None   # [s] when it arrived
        self.force_n: float | None = None      # [N] F, None until one arrives
        self.force_t_s: float | None = None    # [s] when it arrived
        self._force_is_new = False

    def set_target(self, target_n: float, now_s: float) -> None:
        """A validated force target ``target_n`` [N] received at ``now_s`` [s]."""
        self.target_n, self.target_t_s = target_n, now_s

    def set_force(self, force_n: float, now_s: float) -> None:
        """A validated force measurement ``force_n`` [N] received at ``now_s`` [s]."""
        self.force_n, self.force_t_s = force_n, now_s
        self._force_is_new = True

    def state(self, now_s: float) -> str:
        """:data:`READY`, or the reason the controller must not stimulate at ``now_s``."""
        if self.target_n is None:
            return self.NO_TARGET
        if self.force_t_s is None:
            return self.NO_FEEDBACK
        if now_s - self.force_t_s > self.feedback_timeout_s:
            return self.STALE_FEEDBACK
        if self.target_timeout_s > 0.0 and now_s - self.target_t_s > self.target_timeout_s:
            return self.STALE_TARGET
        return self.READY

    def take_new_force(self) -> bool:
        """Whether a force sample arrived since the last call."""
        new, self._force_is_new = self._force_is_new, False
        return new
