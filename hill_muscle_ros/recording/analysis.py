"""What a recorded run says: the analyses of bags that the demos, tests and benchmarks share.

A live run (simulator, protocol player and recorder, ``make demo``) is
compared with the offline simulation of the same protocol: when the protocol
started on the recorder's clock (:func:`protocol_start_ns`), the recorded
force at given times (:func:`live_samples_at`), how late the simulator
reacted (:func:`simulator_lag_s`), the summary table and the plot
(:func:`analyse`). A closed-loop run (force controller and simulator,
``make demo-closed-loop``) is summarised by its tracking error and plotted
(:func:`closed_loop_summary`).

Everything here reads bags with :func:`hill_muscle_ros.recording.reader.read_bag`
and needs no ROS installation; matplotlib is imported only to plot.
"""
from __future__ import annotations

from pathlib import Path
from typing import NamedTuple, Sequence

import numpy as np

from ..model import MuscleParams, Protocol, simulate
from ..playback import FIRST_SAMPLE_SEQUENCE
from ..timebase import NS_PER_S
from .reader import Bag, read_bag

#: Units on the plots (the bag and the topics are SI).
US_PER_S, MM_PER_M = 1e6, 1e3


class BagContentError(ValueError):
    """A bag lacks what an analysis needs (a topic, any message); the message says which."""


#: The player's topic of length knots sent ahead (``lookahead_s`` > 0).
STAMPED_TOPIC = 'length_command_stamped'


def stamped_length(bag: Bag):
    """The bag's ``length_command_stamped`` knots, or ``None`` if it has none."""
    if bag.has_topic(STAMPED_TOPIC) and bag.topic(STAMPED_TOPIC).count:
        return bag.topic(STAMPED_TOPIC)
    return None


def protocol_start_ns(bag: Bag, sim_time: bool = False) -> int:
    """[ns] when the protocol started, on the recorder's receive clock.

    With the length sent ahead (``length_command_stamped`` in the bag, from
    its first message on), the stamp of the first knot: the player's time 0,
    exactly, in the simulator's stamp clock.

    With ``sim_time`` (a run on /clock) and a protocol that starts with
    stimulation, the simulator's time instead: the stamp of its last
    ``wrench`` at rest before the first non-zero force. The recorder's sim
    time receive clock only advances with its polling and /clock (coarse at
    a high real-time factor). The simulator publishes every n-th step
    (``publish_every_n_steps``; by default n = ceil(real_time_factor) at
    1 kHz), on a fixed grid of simulated time that need not line up with its
    ticks, so the stimulation acted at one of the steps after the last rest
    stamp, up to the first non-zero one: this start may be up to n - 1 steps
    early.

    The protocol's first stimulation sample, if the bag has it (its sequence
    number is :data:`~hill_muscle_ros.playback.FIRST_SAMPLE_SEQUENCE`, after
    the rest state). If the recorder matched the player late (slow DDS
    discovery) and the protocol starts with stimulation, the simulator's first
    non-zero force marks the start instead, to within a step and the DDS
    latency. Otherwise the first recorded sample minus the missed periods
    (approximate).
    """
    knots = stamped_length(bag)
    if knots is not None and (not len(knots.sequence) or knots.sequence[0] <= 1):
        return int(knots.stamps_ns()[0])
    stim = stimulation_topic(bag)
    first = first_sample_index(stim)
    if first is None:
        raise BagContentError(f'{bag.path}: no protocol sample on {stim.name}, only the rest '
                              'state')
    if sim_time and stim.values()[first] > 0.0:
        wrench = bag.topic('wrench')
        active = np.flatnonzero(wrench.values() > 0.0)
        if len(active) and active[0] > 0:
            return int(wrench.stamps_ns()[active[0] - 1])
    first_seq = int(stim.sequence[first]) if len(stim.sequence) else FIRST_SAMPLE_SEQUENCE
    if first_seq <= FIRST_SAMPLE_SEQUENCE:
        return int(stim.log_time_ns[first])
    wrench = bag.topic('wrench')
    active = np.flatnonzero(wrench.values() > 0.0)
    # Valid only if the bag holds the muscle at rest before the onset.
    if stim.values()[first] > 0.0 and len(active) and active[0] > 0:
        return int(wrench.stamps_ns()[active[0]])
    samples_ns = stim.log_time_ns[first:]
    period_ns = int(np.median(np.diff(samples_ns))) if len(samples_ns) > 1 else 0
    return int(samples_ns[0]) - (first_seq - FIRST_SAMPLE_SEQUENCE) * period_ns


def first_sample_index(stim) -> int | None:
    """Index in ``stim`` of the protocol's first recorded sample: the first
    message past the player's rest state (sequence numbers from
    :data:`~hill_muscle_ros.playback.FIRST_SAMPLE_SEQUENCE`); ``None`` if
    the bag has only the rest state. A topic recorded without sequence
    numbers (0) is taken as all samples."""
    seq = np.asarray(stim.sequence)
    if not len(seq):
        return 0 if stim.count else None
    past_rest = np.flatnonzero((seq >= FIRST_SAMPLE_SEQUENCE) | (seq == 0))
    return int(past_rest[0]) if len(past_rest) else None


def stimulation_topic(bag: Bag):
    """The player's stimulation topic in a bag: ``pulse_width`` or ``recruitment``.

    :raises BagContentError: if the bag has messages on neither
    """
    for name in ('pulse_width', 'recruitment'):
        if bag.has_topic(name) and bag.topic(name).count:
            return bag.topic(name)
    raise BagContentError(f'{bag.path}: no pulse_width or recruitment messages: '
                          f'{bag.counts()}')


def live_force_at(bag: Bag, times_s: Sequence[float], sim_time: bool = False) -> list[float]:
    """[N] the recorded force at each time since the protocol started.

    The force is the last ``wrench`` stamped at or before that time; time 0
    is the player's first message (:func:`protocol_start_ns`, with
    ``sim_time`` for a run on /clock). NaN before the first wrench.
    """
    return [f for _, f in live_samples_at(bag, times_s, sim_time)]


def live_samples_at(bag: Bag, times_s: Sequence[float],
                    sim_time: bool = False) -> list[tuple[float, float]]:
    """([s], [N]) the recorded sample each time reads: its time and force.

    As :func:`live_force_at`, with the time of the sample since the protocol
    started. The simulator publishes every n-th step (``publish_every_n_steps``;
    by default n = ceil(real_time_factor) at 1 kHz), so the sample read at a
    time may be up to n - 1 steps older: at real_time_factor 10, a force
    changing at 13 N/s (Protocol II's ramps) moves 0.12 N in those 9 ms.
    Comparing it with the offline force at the sample's own time measures the
    simulation, not the publishing rate. (NaN, NaN) before the first wrench.
    """
    wrench = bag.topic('wrench')
    t_force = (wrench.stamps_ns() - protocol_start_ns(bag, sim_time)) / NS_PER_S
    force = wrench.values()
    out = []
    for t in times_s:
        i = int(np.searchsorted(t_force, t, side='right')) - 1
        out.append((float(t_force[i]), float(force[i])) if i >= 0
                   else (float('nan'), float('nan')))
    return out


def simulator_lag_s(bag: Bag) -> float | None:
    """[s] from the protocol's first stimulation sample, if non-zero, to the first force.

    A healthy run reacts within a few steps. The player starts when *a*
    subscriber matches, which may be the recorder; if DDS discovery between
    the player and the simulator is slow (a heavily loaded machine), the
    simulator misses the start of the protocol and this lag shows it.
    ``None`` if the protocol does not start with stimulation.
    """
    stim = stimulation_topic(bag)
    first = first_sample_index(stim)
    if (first is None or stim.values()[first] <= 0.0
            or stim.sequence[first] > FIRST_SAMPLE_SEQUENCE):
        return None
    wrench = bag.topic('wrench')
    active = np.flatnonzero(wrench.values() > 0.0)
    if not len(active):
        return float('inf')
    return (int(wrench.log_time_ns[active[0]]) - int(stim.log_time_ns[first])) / NS_PER_S


#: [s] a simulator reacting later than this to the first stimulation missed the start.
SIMULATOR_LAG_LIMIT_S = 0.1


#: [s] the force "at the end of each second" is read this long before the
#: whole second: protocol events fall on whole seconds (an R step at 3 s makes
#: the force rise at ~150 N/s), so a few ms of DDS and scheduling jitter would
#: swing a reading taken exactly there, and the player's final zero
#: stimulation arrives at the last one.
END_OF_SECOND_MARGIN_S = 0.05


def summary_times(duration_s: float) -> list[float]:
    """[s] the end of each whole second of the protocol (see :data:`END_OF_SECOND_MARGIN_S`)."""
    seconds = [float(s) for s in range(1, int(np.floor(duration_s)) + 1)] or [duration_s]
    return [round(s - END_OF_SECOND_MARGIN_S, 6) for s in seconds]


class Checkpoint(NamedTuple):
    """One row of the summary: the live force next to the offline one."""
    #: [s] the checkpoint (the end of a second of the protocol)
    t_s: float
    #: [N] the recorded force read there (NaN before the first wrench)
    live_n: float
    #: [N] the offline force at the recorded sample's own time
    offline_n: float

    @property
    def diff_n(self) -> float:
        """[N] live minus offline."""
        return self.live_n - self.offline_n


class LiveRunSummary(NamedTuple):
    """What :func:`analyse` found: the text to print and the checkpoints in it."""
    text: str
    checkpoints: list[Checkpoint]


def analyse(bag_dir: Path, protocol: Protocol, params: MuscleParams,
            rate_hz: float, plot_path: Path,
            real_time_factor: float | None = None) -> LiveRunSummary:
    """Read a live run's bag, write its plot, and return the summary.

    The summary is the recorded force at the end of each second next to the
    offline simulation of the same protocol, warnings about a late start,
    the messages per topic, and where the bag and the plot are.

    :param bag_dir: the bag of a live run (simulator, player, recorder)
    :param protocol: the protocol the player played
    :param params: the simulator's muscle parameters
    :param rate_hz: [Hz] the simulator's step rate
    :param plot_path: where the PNG goes
    :param real_time_factor: [-] set for a run on sim time (/clock), else ``None``
    :raises BagContentError: if the bag has no wrench or no stimulation
    """
    bag = read_bag(bag_dir)
    if not bag.has_topic('wrench') or not bag.topic('wrench').count:
        raise BagContentError(f'{bag_dir}: no wrench messages from the simulator: '
                              f'{bag.counts()}')
    stim, wrench = stimulation_topic(bag), bag.topic('wrench')
    stim_name = stim.name.rsplit('/', 1)[-1]
    sim_time = real_time_factor is not None
    t0 = protocol_start_ns(bag, sim_time)
    t_force = (wrench.stamps_ns() - t0) / NS_PER_S
    force = wrench.values()
    offline = simulate(protocol, params, rate_hz)
    times = summary_times(protocol.duration_s)
    samples = live_samples_at(bag, times, sim_time)

    on_sim_time = '' if not sim_time else f' on sim time at real_time_factor {real_time_factor:g}'
    lines = [f'{protocol.name}: units={params.units}, length={params.length}; live run over '
             f'ROS 2{on_sim_time} vs the offline simulation',
             f'{"t_s":>6}  {"live_force_n":>12}  {"offline_force_n":>15}  {"diff_n":>7}']
    checkpoints = []
    for t, (t_live, live) in zip(times, samples):
        # The offline force at the recorded sample's own time (see live_samples_at).
        off = float(offline.force_n[offline.at(t_live if np.isfinite(t_live) else t)])
        checkpoints.append(Checkpoint(t, live, off))
        lines.append(f'{t:6.3f}  {live:12.3f}  {off:15.3f}  {live - off:+7.3f}')
    age_ms = max((t - t_live for t, (t_live, _) in zip(times, samples)
                  if np.isfinite(t_live)), default=float('nan')) * 1e3
    lines.append(f'(live: the last wrench at or before t_s, at most {age_ms:.0f} ms earlier; '
                 'offline: at that sample\'s time)')
    lag = simulator_lag_s(bag)
    # On sim time the receive clock runs real_time_factor times faster.
    if lag is not None and lag > SIMULATOR_LAG_LIMIT_S * (real_time_factor or 1.0):
        lines.append(f'WARNING: the simulator reacted {lag:.3f} s after the first stimulation: '
                     'DDS discovery was slow and it missed the start of the protocol '
                     '(the player starts on its first subscriber). Run the demo again.')
    first_seq = int(stim.sequence[0]) if len(stim.sequence) else 0
    if first_seq > 1:
        lines.append(f'WARNING: the recorder matched the player late (slow DDS discovery); '
                     f'its first {first_seq - 1} messages are not in the bag.')
    lines.append('messages per topic:')
    lines += [f'  {name:<20} {count:6d}' for name, count in bag.counts().items()]
    knots = stamped_length(bag)
    if knots is not None:   # the length at the times it was to be reached
        t_length = (knots.stamps_ns() - t0) / NS_PER_S
        length = np.array([m.point.x for m in knots.messages], dtype=float)
    else:
        plain = bag.topic('length_command')
        t_length, length = (plain.log_time_ns - t0) / NS_PER_S, plain.values()
    _plot_live_run(plot_path, protocol, t_force, force, (stim.log_time_ns - t0) / NS_PER_S,
          stim.values(), stim_name, t_length, length, offline)
    lines.append(f'bag:  {bag_dir}  (open with `ros2 bag info`, Foxglove, PlotJuggler, rosbags)')
    lines.append(f'plot: {plot_path}')
    return LiveRunSummary('\n'.join(lines), checkpoints)


def _plot_live_run(path: Path, protocol: Protocol, t_force, force, t_stim, stim, stim_name,
          t_length, length, offline) -> None:
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    fig, (ax_f, ax_s, ax_l) = plt.subplots(3, 1, sharex=True, figsize=(8, 7),
                                           gridspec_kw={'height_ratios': [3, 1, 1]})
    ax_f.plot(offline.t_s, offline.force_n, color='0.6', lw=3, label='offline simulation')
    ax_f.plot(t_force, force, color='C0', lw=1, label='live, recorded (wrench)')
    ax_f.set_ylabel('force [N]')
    ax_f.set_title(f'{protocol.name}: live run read back from the bag')
    ax_f.legend(loc='best')
    if stim_name == 'pulse_width':
        ax_s.step(t_stim, stim * US_PER_S, where='post', color='C1')
        ax_s.set_ylabel('pulse width [µs]')
    else:
        ax_s.step(t_stim, stim, where='post', color='C1')
        ax_s.set_ylabel('recruitment [-]')
    ax_l.plot(t_length, length * MM_PER_M, color='C2')
    ax_l.set_ylabel('length command [mm]')
    ax_l.set_xlabel('time since the protocol started [s]')
    for ax in (ax_f, ax_s, ax_l):
        ax.grid(True, alpha=0.3)
    ax_l.set_xlim(-0.2, protocol.duration_s + 0.5)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def closed_loop_summary(bag_dir: Path, png: Path, title: str, duration_s: float,
                        t0_ns: int, namespace: str, tail_s: float = 0.0) -> dict[str, float]:
    """Tracking error of a closed-loop run, and its plot: target and force (top),
    pulse width (bottom), against time, from the bag.

    Stamps are the simulator's time and receive times are on the same
    (system) clock, as the nodes of the closed-loop demo run without sim time.

    :param bag_dir: the bag (``force_target``, ``wrench``, ``pulse_width``,
        ``length_command`` in ``namespace``)
    :param png: where the plot goes (its directory is created)
    :param title: the profile's name, for the plot title
    :param duration_s: [s] the profile's duration; the error is taken over [0, duration_s]
    :param t0_ns: [ns] the simulator's stamp at which the profile started (its t = 0)
    :param namespace: the namespace of the topics
    :param tail_s: [s] shown after the profile's end
    :return: ``rms_error_n`` and ``max_abs_error_n`` [N], and ``count <topic>``
        for every topic of the bag
    """
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    data = read_bag(bag_dir)
    wrench = data.topic(f'{namespace}/wrench')
    target = data.topic(f'{namespace}/force_target')
    pw = data.topic(f'{namespace}/pulse_width')
    dl = data.topic(f'{namespace}/length_command')
    t_f = (wrench.stamps_ns() - t0_ns) / NS_PER_S
    force = wrench.values()
    t_target = (target.log_time_ns - t0_ns) / NS_PER_S
    target_v = target.values()
    keep = (t_f >= 0.0) & (t_f <= duration_s)
    t_f, force = t_f[keep], force[keep]
    # The target in force at each force sample (zero-order hold, as the controller sees it).
    idx = np.clip(np.searchsorted(t_target, t_f, side='right') - 1, 0, len(target_v) - 1)
    err = force - target_v[idx]

    fig, (ax_f, ax_pw) = plt.subplots(2, 1, sharex=True, figsize=(9, 6),
                                      gridspec_kw={'height_ratios': [2, 1]})
    ax_f.step(t_target, target_v, where='post', color='0.4', lw=2, label='target F* [N]')
    ax_f.plot(t_f, force, color='tab:red', lw=1, label='force F [N]')
    ax_dl = ax_f.twinx()
    ax_dl.plot((dl.log_time_ns - t0_ns) / NS_PER_S, dl.values() * MM_PER_M, color='tab:green',
               lw=1, ls='--', label='stretch ΔL_MT [mm]')
    ax_dl.set_ylabel('ΔL_MT [mm]')
    ax_f.set_ylabel('force [N]')
    ax_f.set_title(f'{title}: force controller closed around the simulated muscle')
    lines = ax_f.get_legend_handles_labels()
    more = ax_dl.get_legend_handles_labels()
    ax_f.legend(lines[0] + more[0], lines[1] + more[1], loc='upper left')
    ax_pw.step((pw.log_time_ns - t0_ns) / NS_PER_S, pw.values() * US_PER_S, where='post',
               color='tab:blue', lw=1)
    ax_pw.set_ylabel('pulse width [µs]')
    ax_pw.set_xlabel('time [s] (simulated, from the start of the profile)')
    for ax in (ax_f, ax_pw):
        ax.grid(alpha=0.3)
    ax_pw.set_xlim(0.0, duration_s + tail_s)
    fig.tight_layout()
    png.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(png, dpi=120)
    plt.close(fig)
    return {'rms_error_n': float(np.sqrt(np.mean(err ** 2))),
            'max_abs_error_n': float(np.abs(err).max()),
            **{f'count {name}': float(n) for name, n in data.counts().items()}}
