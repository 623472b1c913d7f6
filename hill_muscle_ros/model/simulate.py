"""Offline simulation of a protocol: the loop shared by the CLI and the figures."""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .muscle import Muscle
from .substeps import output_rows, substep_inputs, substeps_for
from .params import PULSED_MODEL, MuscleParams
from .protocol import Protocol, PulseProtocol
from .stimulator import check_channel_command, stimulator_profile
from .stimulus import pulse_command

#: Columns of a simulation result, in CSV order, with their CSV headers.
COLUMNS = (
    ('t_s', 't_s'),
    ('recruitment', 'recruitment'),
    ('dl_mt_m', 'dl_mt_m'),
    ('l_ce_m', 'l_ce_m'),
    ('v_ce_m_per_s', 'v_ce_m_s'),
    ('f_se_n', 'f_se_n'),
    ('f_pe_n', 'f_pe_n'),
    ('force_n', 'force_n'),
    ('eff_f_iso_n', 'eff_f_iso_n'),
    ('command', 'command'),
    ('mean_fitness', 'mean_fitness'),
)

@dataclass(frozen=True)
class SimulationResult:
    """Time series of one offline run, one sample per step from t = 0 to the end.

    Each attribute is a NumPy array of the same length; see
    :class:`~hill_muscle_ros.model.muscle.MuscleOutputs` for units.
    """

    t_s: np.ndarray
    recruitment: np.ndarray
    n_recruited: np.ndarray
    dl_mt_m: np.ndarray
    l_ce_m: np.ndarray
    v_ce_m_per_s: np.ndarray
    f_se_n: np.ndarray
    f_pe_n: np.ndarray
    force_n: np.ndarray
    eff_f_iso_n: np.ndarray
    command: np.ndarray
    mean_fitness: np.ndarray
    #: [-] each channel's activation a_c (samples x C) of a pulse protocol; None
    #: for a level protocol.
    activation: np.ndarray | None = None

    def at(self, t_s: float) -> int:
        """Index of the sample nearest to time ``t_s`` (the earlier of two as near).

        A binary search, since the samples are in time order: the summary
        table reads one sample a second, and scanning a long run for each
        (60 scans of 60,001 samples) cost more than simulating it compiled.
        """
        t = self.t_s
        i = int(np.searchsorted(t, t_s))
        if i == 0:
            return 0
        if i == len(t):
            return i - 1
        return i - 1 if t_s - t[i - 1] <= t[i] - t_s else i


def step_count(duration_s: float, rate_hz: float) -> int:
    """[-] steps of a run: round(duration * rate); :func:`sample_times` has one more.

    :raises ValueError: if ``rate_hz`` is not positive and finite
    """
    if not (math.isfinite(rate_hz) and rate_hz > 0):
        raise ValueError(f'`rate_hz` must be positive and finite, got {rate_hz!r}')
    return int(round(duration_s * rate_hz))


def sample_times(duration_s: float, rate_hz: float) -> np.ndarray:
    """[s] sample instants k / rate for k = 0..round(duration * rate), inclusive.

    Dividing the integer index (rather than accumulating dt) makes whole
    seconds exact, so protocol steps fall exactly on a sample.
    """
    return np.arange(step_count(duration_s, rate_hz) + 1) / rate_hz


def simulate(protocol: Protocol | PulseProtocol, params: MuscleParams | None = None,
             rate_hz: float = 1000.0) -> SimulationResult:
    """Run a protocol from the resting state, sampled every 1 / ``rate_hz``.

    The sample at t_k shows the state at t_k with the command of t_k already
    given (in the paper's model: the recruitment of t_k applied to the
    memory); the step from t_k to t_(k+1) holds the command u(t_k) and ramps
    dl_MT linearly between the protocol's values at the two ends. Pulse
    widths pass through the muscle's recruitment curve.

    The whole run is one call of :meth:`Muscle.run_array
    <hill_muscle_ros.model.muscle.Muscle.run_array>`, on the engine
    :func:`.engine.kernels` chooses (compiled, or ``HILL_MUSCLE_ENGINE=python``).

    The rate is that of the samples, not the integrator's: a step longer than
    :data:`.substeps.MAX_SUBSTEP_S` (1 ms) is integrated in
    n = ceil(dt / 1 ms) equal substeps, the command held and dl_MT ramping
    across them, so any rate gives the same force at the same instants; at
    1 kHz and above n = 1.

    A :class:`~.protocol.PulseProtocol` (``channels:``) runs on a muscle with
    ``activation_model: ding2003``: every pulse is checked against the
    ``stimulator`` and acts at its own instant (:func:`simulate_pulses`).

    :param protocol: the protocol to replay
    :param params: muscle parameters (paper defaults if omitted)
    :param rate_hz: [Hz] sample rate, 1 / dt
    :return: the time series, ``round(duration * rate) + 1`` samples
    """
    if isinstance(protocol, PulseProtocol):
        return simulate_pulses(protocol, params, rate_hz)
    muscle = Muscle(params)
    t = sample_times(protocol.duration_s, rate_hz)
    r = np.asarray(protocol.command(t, muscle.params), dtype=float)
    dl = np.asarray(protocol.dl_mt(t), dtype=float)
    # The protocol validated its knots; interpolation keeps the values in range,
    # so one check of the whole arrays replaces the per-step validation.
    if r.size and not (0.0 <= r.min() and r.max() <= 1.0):
        raise ValueError(f'`recruitment` must be in [0, 1], got {r.min()!r}..{r.max()!r}')
    dt = 1.0 / rate_hz
    muscle.set_recruitment(float(r[0]))
    first = muscle.outputs()
    n_steps = len(t) - 1
    # The engine integrates substeps of at most 1 ms (model/substeps.py): the
    # rate sets the samples only. With n = 1 the inputs are the samples'.
    n = substeps_for(dt)
    r_start, dl_end, r_end = substep_inputs(r, dl, n)
    out = muscle.run_array(r_start, dl_end, dt / n, r_end)[output_rows(n, n_steps)]
    return _result(t, first, out)


def _result(t: np.ndarray, first, out: np.ndarray, **extra) -> SimulationResult:
    """A result from the outputs at t = 0 (``first``, MuscleOutputs) and after
    each step (``out``, one row per later sample); ``extra`` fields as given."""
    fields = {'t_s': t}   # the sample times are the inputs themselves
    for name, value, column in zip(first._fields, first, out.T):
        if name not in fields:
            array = np.empty(len(t), dtype=type(value))
            array[0] = value
            array[1:] = column
            fields[name] = array
    return SimulationResult(**fields, **extra)


def protocol_pulses(protocol: PulseProtocol, params: MuscleParams) -> tuple:
    """Every pulse of ``protocol`` as the muscle takes it, each checked against
    the ``stimulator`` (its width, current and the frequency its burst read).

    :return: ``(times, channels, commands)``: [s] when each acts (sent + ``emd_s``),
        0-based channels and [-] the fraction u of its channel's territory, in
        time order
    :raises ValueError: for more channels than the muscle's, or a pulse the
        stimulator would refuse (naming the field, channel, value and time)
    """
    if len(protocol.channels) > params.n_channels:
        raise ValueError(f'`channels` of protocol {protocol.name!r} must be at most the '
                         f"muscle's {params.n_channels} (`channel_fractions`), got "
                         f'{len(protocol.channels)}')
    profile = stimulator_profile(params.stimulator, params.pw_max_s)
    rows = []
    for c, (train, pulses) in enumerate(zip(protocol.channels, protocol.pulses())):
        for pulse in pulses:
            try:
                check_channel_command(profile, c + 1, train.frequency_at(pulse.time_s),
                                      pulse.pulse_width_s, pulse.current_a, train.mode,
                                      train.burst_interval_s)
            except ValueError as err:
                raise ValueError(f'{protocol.name}: at t = {pulse.time_s:g} s: {err}') from None
            rows.append((pulse.time_s + params.emd_s, c,
                         pulse_command(pulse.pulse_width_s, pulse.current_a, params)))
    rows.sort()
    times = np.array([r[0] for r in rows], dtype=float)
    channels = np.array([r[1] for r in rows], dtype=np.int64)
    commands = np.array([r[2] for r in rows], dtype=float)
    return times, channels, commands


def simulate_pulses(protocol: PulseProtocol, params: MuscleParams | None = None,
                    rate_hz: float = 1000.0) -> SimulationResult:
    """Run a protocol of pulse trains from rest (see :func:`simulate`); the
    result's ``activation`` holds each channel's a_c at the samples.

    :raises ValueError: for a muscle that is not ``ding2003``, or as
        :func:`protocol_pulses`
    """
    muscle = Muscle(params)
    p = muscle.params
    if p.activation_model != PULSED_MODEL:
        raise ValueError(f'protocol {protocol.name!r} gives pulse trains (`channels`): it needs '
                         f'`activation_model: ding2003`, got {p.activation_model!r}')
    times, channels, commands = protocol_pulses(protocol, p)
    t = sample_times(protocol.duration_s, rate_hz)
    dl = np.asarray(protocol.dl_mt(t), dtype=float)
    dt = 1.0 / rate_hz
    now = muscle.pulses_now(times, channels, commands)   # the sample at 0 shows them
    first = muscle.outputs()
    first_activation = muscle.activation
    n_steps = len(t) - 1
    n = substeps_for(dt)
    _, dl_end, _ = substep_inputs(np.zeros_like(dl), dl, n)
    out, act, _ = muscle.run_pulses(times[now:], channels[now:], commands[now:], dl_end,
                                    dt / n)
    rows = output_rows(n, n_steps)
    return _result(t, first, out[rows],
                   activation=np.vstack([first_activation[None, :], act[rows]]))
