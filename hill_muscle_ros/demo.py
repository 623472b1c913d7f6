"""``make demo``: a live run over ROS 2, recorded, read back, plotted and summarised.

1. starts the simulator, the recorder and then the protocol player as three
   separate ROS processes, on a DDS domain of their own, localhost only;
2. waits for the protocol to end (the player exits);
3. stops the recorder with SIGINT, so the bag is closed properly;
4. reads the bag back with :func:`hill_muscle_ros.recording.reader.read_bag`;
5. writes ``<bag>/force.png``: force and inputs against time, from the bag;
6. prints the force at the end of each second (next to the offline
   simulation of the same protocol), the message count per topic and the bag.

Every child runs in its own process group and is stopped (SIGINT, then
SIGKILL of the group) when the demo ends, whatever the reason: normal end,
error, Ctrl-C, SIGTERM or SIGHUP. Children also get SIGTERM from the kernel
if the demo itself dies (``PR_SET_PDEATHSIG``).

With ``--real-time-factor X`` the run goes faster (or slower) than real
time on simulated time: the simulator publishes ``/clock`` and runs X
simulated seconds per second of the steady clock (``publish_clock:=true``,
``real_time_factor:=X``); the player and the recorder use it
(``use_sim_time:=true``), so the bag's times are simulated seconds from the
simulator's start.

On sim time the length goes ahead of time: the player sends it as
``length_command_stamped`` knots ``--lookahead`` seconds ahead (default
:func:`default_lookahead_s`, which grows with the real-time factor), so the
simulator reaches each length exactly at its time whatever the DDS latency;
the stimulation stays on its plain topic and reaches the simulator one DDS
latency late. The player starts only when the simulator and the recorder are
subscribed to every output (``min_subscribers`` 2), so the bag has the
protocol from its first message; time 0 of the analysis is then the first
knot's stamp, the protocol's start on the player's clock.

Run: ``python -m hill_muscle_ros.demo [--protocol I|II|PATH] [--units ...] [--length ...]
[--real-time-factor X] [--lookahead S]``.
"""
from __future__ import annotations

import argparse
import contextlib
import ctypes
import datetime as _dt
import os
import re
import signal
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np

from .domain_lock import lock_free_domain
from .model import LENGTH_CHOICES, UNITS_CHOICES, MuscleParams, Protocol, simulate
from .params_file import load_muscle_params
from .resources import default_params_file, protocol_path

PROG = 'python -m hill_muscle_ros.demo'
DEFAULT_RUNS_DIR = Path('runs')
#: Domains 101..199: clear of 0 (most users' default) and of the 1..100 the
#: test suite uses, within the range Fast DDS maps to valid UDP ports.
DEMO_DOMAIN_BASE, DEMO_DOMAIN_SPAN = 101, 99
#: [s] how long the simulator and the recorder may take to start.
STARTUP_TIMEOUT_S = 60.0
#: [s] allowance beyond the protocol's duration for the player to start and end.
PLAYER_SLACK_S = 60.0
#: [s] how long a child may take to exit after SIGINT before its group is killed.
STOP_TIMEOUT_S = 15.0
#: [s] poll period while waiting on children.
POLL_S = 0.05
#: Units on the plot (the bag and the topics are SI).
US_PER_S, MM_PER_M = 1e6, 1e3
NS_PER_S = 1_000_000_000
#: prctl option that sends a signal to a child when its parent dies (Linux).
_PR_SET_PDEATHSIG = 1
#: [s] shortest look-ahead of the stamped length commands, in simulated time.
MIN_LOOKAHEAD_S = 0.05
#: [s] of wall time the length is sent ahead: the knot crosses two DDS hops
#: (/clock to the player, the player to the simulator), each 1.5 ms at the
#: median and 2.7 ms at p99 for a bare rclpy echo and 5-9 ms through the
#: simulator's tick (BENCHMARKS.md section 5), and a Python process on a busy
#: 2-core machine is descheduled for tens of ms now and then (measured: a
#: knot 65 ms of wall time late with a CPU-bound job on the other core): 0.1 s
#: is about twenty typical latencies. It costs nothing but a later start (the
#: protocol begins one look-ahead after the player does).
LOOKAHEAD_WALL_S = 0.1
#: Subscribers the player waits for on each output: the simulator and the recorder.
DEMO_MIN_SUBSCRIBERS = 2


class DemoError(RuntimeError):
    """The demo could not complete; the message says which step and why."""


# --------------------------------------------------------------------------- processes

def _die_with_parent() -> None:  # runs in the child between fork and exec
    # A demo started in the background of a script inherits SIGINT ignored;
    # the nodes must still stop cleanly on the SIGINT the demo sends them.
    signal.signal(signal.SIGINT, signal.SIG_DFL)
    try:
        ctypes.CDLL(None, use_errno=True).prctl(_PR_SET_PDEATHSIG, signal.SIGTERM)
    except (OSError, AttributeError):
        pass  # not Linux: the try/finally in the parent still stops the children


class Child:
    """One ROS process of the demo, in its own process group, logging to a file."""

    def __init__(self, name: str, cmd: list[str], log_path: Path, env: dict[str, str]) -> None:
        self.name = name
        self.log_path = log_path
        self._log = open(log_path, 'wb')
        self.popen = subprocess.Popen(cmd, stdout=self._log, stderr=subprocess.STDOUT, env=env,
                                      start_new_session=True, preexec_fn=_die_with_parent)

    def output(self) -> str:
        return self.log_path.read_text(encoding='utf-8', errors='replace')

    def poll(self) -> int | None:
        return self.popen.poll()

    def stop(self, timeout_s: float = STOP_TIMEOUT_S) -> int:
        """SIGINT (a clean stop), then SIGKILL of the whole group after ``timeout_s``."""
        if self.popen.poll() is None:
            try:
                self.popen.send_signal(signal.SIGINT)
                self.popen.wait(timeout=timeout_s)
            except subprocess.TimeoutExpired:
                self.kill()
        self._log.close()
        return self.popen.returncode

    def kill(self) -> None:
        try:
            os.killpg(self.popen.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
        self.popen.wait()

    def tail(self, chars: int = 2000) -> str:
        return f'--- {self.name} log ({self.log_path}):\n{self.output()[-chars:]}'


def _wait(condition, what: str, timeout_s: float, children: Sequence[Child]) -> None:
    deadline = time.monotonic() + timeout_s
    while not condition():
        dead = [c for c in children if c.poll() is not None]
        if dead:
            raise DemoError(f'{dead[0].name} exited ({dead[0].poll()}) while waiting for '
                            f'{what}\n{dead[0].tail()}')
        if time.monotonic() > deadline:
            raise DemoError(f'timed out after {timeout_s:g} s waiting for {what}\n'
                            + '\n'.join(c.tail() for c in children))
        time.sleep(POLL_S)


#: Lock file that claims a demo domain on this machine while a run uses it.
_DOMAIN_LOCK_PATTERN = 'hill_muscle_ros_demo_domain_{}.lock'


@contextlib.contextmanager
def claimed_domain():
    """Claim a DDS domain for one run: yields its ID, locked until the block ends.

    Two demos on one domain would mix their topics (and, on sim time, their
    /clock): each run holds an exclusive lock file on its domain, so
    concurrent runs on one machine (tests, benchmarks, users) never share one.
    ``HILL_MUSCLE_DEMO_DOMAIN`` asks for a given domain; the run waits for it
    (up to :data:`STARTUP_TIMEOUT_S`) if another run holds it. Otherwise the
    first free one of 101..199, starting at one picked by the process ID.
    """
    wanted = os.environ.get('HILL_MUSCLE_DEMO_DOMAIN')
    if wanted is not None:
        candidates = [int(wanted)]
    else:
        start = os.getpid() % DEMO_DOMAIN_SPAN
        candidates = [DEMO_DOMAIN_BASE + (start + i) % DEMO_DOMAIN_SPAN
                      for i in range(DEMO_DOMAIN_SPAN)]
    deadline = time.monotonic() + STARTUP_TIMEOUT_S
    while True:
        claimed = lock_free_domain(candidates, _DOMAIN_LOCK_PATTERN)
        if claimed is not None:
            domain, lock = claimed
            try:
                yield domain
            finally:
                lock.close()   # releases the lock
            return
        if time.monotonic() > deadline:
            raise DemoError(f'every DDS domain of {candidates[0]}..{candidates[-1]} is held by '
                            f'another demo run on this machine after {STARTUP_TIMEOUT_S:g} s')
        time.sleep(POLL_S)


def ros_environment(domain_id: int | None = None) -> dict[str, str]:
    """The children's environment: an isolated DDS domain, discovery on this host only.

    :param domain_id: the ROS_DOMAIN_ID (see :func:`claimed_domain`); ``None``:
        ``HILL_MUSCLE_DEMO_DOMAIN`` or one picked by the process ID, unclaimed
    """
    env = os.environ.copy()
    if domain_id is None:
        domain_id = int(env.get('HILL_MUSCLE_DEMO_DOMAIN',
                                DEMO_DOMAIN_BASE + os.getpid() % DEMO_DOMAIN_SPAN))
    env.update(ROS_DOMAIN_ID=str(domain_id), ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST',
               PYTHONUNBUFFERED='1', RCUTILS_LOGGING_BUFFERED_STREAM='0',
               RCUTILS_COLORIZED_OUTPUT='0')
    env.pop('ROS_STATIC_PEERS', None)
    return env


def _node(module: str, *ros_args: str) -> list[str]:
    return [sys.executable, '-m', f'hill_muscle_ros.nodes.{module}', '--ros-args', *ros_args]


# --------------------------------------------------------------------------- the run

@dataclass
class DemoConfig:
    protocol: str = 'II'
    units: str | None = None
    length: str | None = None
    runs_dir: Path = DEFAULT_RUNS_DIR
    name: str | None = None
    #: [-] simulated seconds per clock second on sim time (/clock); None: the
    #: default run on the wall clock, as without the option.
    real_time_factor: float | None = None
    #: [s] of simulated time the length is sent ahead (length_command_stamped);
    #: 0: the plain length_command; None: :func:`default_lookahead_s` on sim
    #: time, the plain length_command on the wall clock.
    lookahead_s: float | None = None

    def lookahead(self) -> float:
        """[s] the look-ahead this run uses (see :attr:`lookahead_s`)."""
        if self.lookahead_s is not None:
            return self.lookahead_s
        return 0.0 if self.real_time_factor is None else default_lookahead_s(
            self.real_time_factor)


def default_lookahead_s(real_time_factor: float) -> float:
    """[s] look-ahead for a run at ``real_time_factor``: :data:`LOOKAHEAD_WALL_S`
    of wall time in simulated time, at least :data:`MIN_LOOKAHEAD_S`."""
    return max(MIN_LOOKAHEAD_S, LOOKAHEAD_WALL_S * real_time_factor)


def _run_name(config: DemoConfig) -> str:
    stamp = _dt.datetime.now(_dt.timezone.utc).strftime('%Y-%m-%dT%H-%M-%SZ')
    label = config.protocol if config.protocol in ('I', 'II') else Path(config.protocol).stem
    return config.name or f'demo_protocol_{label}_{stamp}'


def record_live_run(config: DemoConfig, bag_dir: Path, protocol: Protocol,
                    log_dir: Path) -> None:
    """Run simulator, recorder and player; return once the bag is closed."""
    with claimed_domain() as domain:
        _record_live_run(config, bag_dir, protocol, log_dir, ros_environment(domain))


def _record_live_run(config: DemoConfig, bag_dir: Path, protocol: Protocol, log_dir: Path,
                     env: dict[str, str]) -> None:
    from .nodes.recorder import READY_MESSAGE
    spec = config.protocol if config.protocol in ('I', 'II') else str(Path(config.protocol)
                                                                        .resolve())
    muscle = [f'{k}:={v}' for k, v in (('units', config.units), ('length', config.length)) if v]
    sim_args = ['--params-file', str(default_params_file())]
    for override in muscle:
        sim_args += ['-p', override]
    rtf = config.real_time_factor
    # On sim time the simulator is the clock; the others follow /clock.
    sim_time_args = [] if rtf is None else ['-p', 'use_sim_time:=true']
    if rtf is not None:
        sim_args += ['-p', 'publish_clock:=true', '-p', f'real_time_factor:={float(rtf)!r}']
        # The stimulation watchdog counts simulated time, but the player's
        # messages come at its wall-clock scheduling: the same wall-clock
        # tolerance (a player descheduled for 50 ms at RTF 10 tripped 0.5 s).
        _, settings = load_muscle_params(default_params_file())
        timeout_s = float(settings.get('input_timeout_s', 0.0)) * max(1.0, float(rtf))
        sim_args += ['-p', f'input_timeout_s:={timeout_s!r}']
    lookahead_s = config.lookahead()
    rec_args = ['-p', f'output:={bag_dir}', *sim_time_args]
    player_args = ['-p', f'protocol:={spec}', '-p', f'lookahead_s:={float(lookahead_s)!r}',
                   '-p', f'min_subscribers:={DEMO_MIN_SUBSCRIBERS}',
                   '-p', f'wait_for_subscribers_s:={STARTUP_TIMEOUT_S!r}', *sim_time_args]
    children: list[Child] = []
    try:
        sim = Child('simulator', _node('simulator', *sim_args), log_dir / 'simulator.log', env)
        children.append(sim)
        rec = Child('recorder', _node('recorder', *rec_args), log_dir / 'recorder.log', env)
        children.append(rec)
        # The recorder receives the simulator (the muscle at rest) before the
        # player starts: the plain-length analysis on sim time anchors time 0
        # on the last wrench at rest (see protocol_start_ns), and on sim time
        # the recorder's log times are its clock when it takes a message, so
        # a recorder still busy starting up (measured: 0.1 s of wall time, 1 s
        # of simulated time at RTF 10) would log the protocol's first
        # messages late. The player's min_subscribers 2 then guarantees that
        # the recorder also gets the player's first message.
        _wait(lambda: READY_MESSAGE in rec.output() and '/wrench (' in rec.output(),
              'the recorder to receive the simulator', STARTUP_TIMEOUT_S, children)
        player = Child('protocol_player', _node('protocol_player', *player_args),
                       log_dir / 'protocol_player.log', env)
        children.append(player)
        on_sim_time = '' if rtf is None else f', sim time at real_time_factor {rtf:g}'
        ahead = '' if lookahead_s == 0.0 else f', length sent {lookahead_s:g} s ahead'
        print(f'running {protocol.name} ({protocol.duration_s:g} s) over ROS 2 '
              f'(ROS_DOMAIN_ID={env["ROS_DOMAIN_ID"]}{on_sim_time}{ahead}) ...', flush=True)
        _wait(lambda: player.poll() is not None, 'the protocol to end',
              (protocol.duration_s + lookahead_s) / (rtf or 1.0) + STARTUP_TIMEOUT_S
              + PLAYER_SLACK_S, [sim, rec])
        if player.poll() != 0:
            raise DemoError(f'the protocol player failed ({player.poll()})\n{player.tail()}')
        if rec.stop() != 0:
            raise DemoError(f'the recorder failed ({rec.popen.returncode})\n{rec.tail()}')
        # The simulator logs its timing statistics as it exits.
        sim.stop()
    finally:
        for child in reversed(children):
            child.stop()


#: The player's topic of length knots sent ahead (``lookahead_s`` > 0).
STAMPED_TOPIC = 'length_command_stamped'


def stamped_length(bag):
    """The bag's ``length_command_stamped`` knots, or ``None`` if it has none."""
    if bag.has_topic(STAMPED_TOPIC) and bag.topic(STAMPED_TOPIC).count:
        return bag.topic(STAMPED_TOPIC)
    return None


def protocol_start_ns(bag, sim_time: bool = False) -> int:
    """[ns] when the protocol started, on the recorder's receive clock.

    With the length sent ahead (``length_command_stamped`` in the bag, from
    its first message on), the stamp of the first knot: the player's time 0,
    exactly, in the simulator's stamp clock.

    With ``sim_time`` (a run on /clock) and a protocol that starts with
    stimulation, the simulator's time instead: the stamp of its last
    ``wrench`` at rest before the first non-zero force. The recorder's sim
    time receive clock only advances with its polling and /clock (coarse at
    a high real-time factor), and the first non-zero force may be stamped up
    to a tick's worth of steps late (a tick runs real_time_factor steps and
    publishes the last one); but the stimulation arrived between the two
    ticks, so it acted from the step after the last rest stamp.

    The player's first message, if the bag has it (its sequence number is 1).
    If the recorder matched the player late (slow DDS discovery) and the
    protocol starts with stimulation, the simulator's first non-zero force
    marks the start instead, to within a step and the DDS latency. Otherwise
    the first recorded message minus the missed periods (approximate).
    """
    knots = stamped_length(bag)
    if knots is not None and (not len(knots.sequence) or knots.sequence[0] <= 1):
        return int(knots.stamps_ns()[0])
    stim = stimulation_topic(bag)
    if sim_time and stim.values()[0] > 0.0:
        wrench = bag.topic('wrench')
        active = np.flatnonzero(wrench.values() > 0.0)
        if len(active) and active[0] > 0:
            return int(wrench.stamps_ns()[active[0] - 1])
    first_seq = int(stim.sequence[0]) if len(stim.sequence) else 1
    if first_seq <= 1:
        return int(stim.log_time_ns[0])
    wrench = bag.topic('wrench')
    active = np.flatnonzero(wrench.values() > 0.0)
    # Valid only if the bag holds the muscle at rest before the onset.
    if stim.values()[0] > 0.0 and len(active) and active[0] > 0:
        return int(wrench.stamps_ns()[active[0]])
    period_ns = int(np.median(np.diff(stim.log_time_ns))) if stim.count > 1 else 0
    return int(stim.log_time_ns[0]) - (first_seq - 1) * period_ns


def stimulation_topic(bag):
    """The player's stimulation topic in a bag: ``pulse_width`` or ``recruitment``."""
    for name in ('pulse_width', 'recruitment'):
        if bag.has_topic(name) and bag.topic(name).count:
            return bag.topic(name)
    raise DemoError(f'{bag.path}: no pulse_width or recruitment messages: {bag.counts()}')


def live_force_at(bag, times_s: Sequence[float], sim_time: bool = False) -> list[float]:
    """[N] the recorded force at each time since the protocol started.

    The force is the last ``wrench`` stamped at or before that time; time 0
    is the player's first message (:func:`protocol_start_ns`, with
    ``sim_time`` for a run on /clock). NaN before the first wrench.
    """
    return [f for _, f in live_samples_at(bag, times_s, sim_time)]


def live_samples_at(bag, times_s: Sequence[float],
                    sim_time: bool = False) -> list[tuple[float, float]]:
    """([s], [N]) the recorded sample each time reads: its time and force.

    As :func:`live_force_at`, with the time of the sample since the protocol
    started. The simulator publishes once per tick, the last of the tick's
    steps, so at real_time_factor X the sample read at a time may be up to X
    steps older: a force changing at 13 N/s (Protocol II's ramps) moves
    0.13 N in 10 ms. Comparing it with the offline force at the sample's own
    time measures the simulation, not the publishing rate. (NaN, NaN) before
    the first wrench.
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


def simulator_lag_s(bag) -> float | None:
    """[s] from the player's first non-zero stimulation to the simulator's first force.

    A healthy run reacts within a few steps. The player starts when *a*
    subscriber matches, which may be the recorder; if DDS discovery between
    the player and the simulator is slow (a heavily loaded machine), the
    simulator misses the start of the protocol and this lag shows it.
    ``None`` if the protocol does not start with stimulation.
    """
    stim = stimulation_topic(bag)
    values = stim.values()
    if not len(values) or values[0] <= 0.0 or stim.sequence[0] > 1:
        return None
    wrench = bag.topic('wrench')
    active = np.flatnonzero(wrench.values() > 0.0)
    if not len(active):
        return float('inf')
    return (int(wrench.log_time_ns[active[0]]) - int(stim.log_time_ns[0])) / NS_PER_S


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


def analyse(bag_dir: Path, protocol: Protocol, params: MuscleParams,
            rate_hz: float, plot_path: Path, real_time_factor: float | None = None) -> str:
    """Read the bag, write the plot, and return the summary text.

    :param real_time_factor: [-] set for a run on sim time (see :class:`DemoConfig`)
    """
    from .recording.reader import read_bag
    bag = read_bag(bag_dir)
    if not bag.has_topic('wrench') or not bag.topic('wrench').count:
        raise DemoError(f'{bag_dir}: no wrench messages from the simulator: {bag.counts()}')
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
    for t, (t_live, live) in zip(times, samples):
        # The offline force at the recorded sample's own time (see live_samples_at).
        off = float(offline.force_n[offline.at(t_live if np.isfinite(t_live) else t)])
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
    _plot(plot_path, protocol, t_force, force, (stim.log_time_ns - t0) / NS_PER_S,
          stim.values(), stim_name, t_length, length, offline)
    lines.append(f'bag:  {bag_dir}  (open with `ros2 bag info`, Foxglove, PlotJuggler, rosbags)')
    lines.append(f'plot: {plot_path}')
    return '\n'.join(lines)


def _plot(path: Path, protocol: Protocol, t_force, force, t_stim, stim, stim_name,
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


def run_demo(config: DemoConfig) -> int:
    """The whole demo; returns the exit status."""
    start = time.monotonic()
    try:
        protocol = Protocol.from_yaml(protocol_path(config.protocol))
        params, node_settings = load_muscle_params(default_params_file())
        overrides = {k: v for k, v in (('units', config.units), ('length', config.length)) if v}
        params = params.replace(**overrides) if overrides else params
    except ValueError as err:
        raise DemoError(str(err)) from None
    rate_hz = float(node_settings.get('rate_hz', 1000.0))
    bag_dir = config.runs_dir / _run_name(config)
    if bag_dir.exists():
        raise DemoError(f'{bag_dir} exists: choose another name')
    log_dir = config.runs_dir / 'logs' / bag_dir.name
    log_dir.mkdir(parents=True, exist_ok=True)
    record_live_run(config, bag_dir, protocol, log_dir)
    print(analyse(bag_dir, protocol, params, rate_hz, bag_dir / 'force.png',
                  config.real_time_factor))
    if config.real_time_factor is not None:
        stats = simulator_stats((log_dir / 'simulator.log').read_text(errors='replace'))
        if stats is not None:
            print(f'simulator: {stats.steps} steps in {stats.steady_s:.3f} s of steady time: '
                  f'achieved real-time factor {stats.achieved_rtf(rate_hz):.2f}, '
                  f'{stats.steps_behind} steps behind at exit, '
                  f'{stats.catch_up_warnings} catch-up warnings (throttled to 1/s), '
                  f'{stats.late_knots} late length knots (look-ahead '
                  f'{config.lookahead():g} s)')
    print(f'logs: {log_dir}')
    print(f'demo wall time: {time.monotonic() - start:.1f} s')
    return 0


@dataclass
class SimulatorStats:
    """The timing statistics the simulator logs as it exits."""
    steps: int
    steady_s: float
    ticks: int
    late_ticks: int
    steps_behind: int
    #: warnings that more steps were due than one tick may catch up (throttled to 1/s)
    catch_up_warnings: int
    #: length_command_stamped knots that arrived after their time
    late_knots: int = 0

    def achieved_rtf(self, rate_hz: float) -> float:
        """[-] simulated seconds per second of the steady clock, over the node's life."""
        return self.steps / rate_hz / self.steady_s if self.steady_s > 0 else float('nan')


_STATS_RE = re.compile(r'ran (\d+) steps in ([\d.]+) s of steady time .*?, (\d+) ticks, '
                       r'(\d+) late, (-?\d+) steps behind at exit')
_CATCH_UP_MARK = 'steps due after a stall or overload'
_LATE_KNOTS_RE = re.compile(r'(\d+) late length_command_stamped knots')


def simulator_stats(log_text: str) -> SimulatorStats | None:
    """Parse the simulator's exit statistics from its log; None if it has none."""
    match = _STATS_RE.search(log_text)
    if match is None:
        return None
    steps, steady_s, ticks, late, behind = match.groups()
    late_knots = _LATE_KNOTS_RE.search(log_text)
    return SimulatorStats(int(steps), float(steady_s), int(ticks), int(late), int(behind),
                          log_text.count(_CATCH_UP_MARK),
                          int(late_knots.group(1)) if late_knots else 0)


class _Stop(Exception):
    pass


def _raise_stop(signum, _frame):
    raise _Stop(signal.Signals(signum).name)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog=PROG, description=__doc__.split('\n\n')[0])
    parser.add_argument('--protocol', default='II', metavar='{I,II,PATH}',
                        help='protocol to play (default: II)')
    parser.add_argument('--units', choices=UNITS_CHOICES + ('',), default='',
                        help='motor units (default: config/muscle.yaml)')
    parser.add_argument('--length', choices=LENGTH_CHOICES + ('',), default='',
                        help='length in FL (default: config/muscle.yaml)')
    parser.add_argument('--runs-dir', type=Path, default=DEFAULT_RUNS_DIR, metavar='DIR',
                        help='where the run directory goes (default: runs)')
    parser.add_argument('--name', help='run directory name (default: demo_protocol_<P>_<UTC>)')
    parser.add_argument('--real-time-factor', type=_positive_float, metavar='X',
                        help='run on sim time, X simulated seconds per clock second '
                             '(simulator publish_clock, player and recorder use_sim_time); '
                             'default: the wall clock, no /clock')
    parser.add_argument('--lookahead', type=_non_negative_float, metavar='S',
                        help='send the length S simulated seconds ahead '
                             '(length_command_stamped); 0: the plain length_command; '
                             f'default: on sim time max({MIN_LOOKAHEAD_S:g}, '
                             f'{LOOKAHEAD_WALL_S:g} x X), on the wall clock 0')
    return parser


def _non_negative_float(text: str) -> float:
    value = float(text)
    if not (np.isfinite(value) and value >= 0.0):
        raise argparse.ArgumentTypeError(f'must be a non-negative number, got {text!r}')
    return value


def _positive_float(text: str) -> float:
    value = float(text)
    if not (np.isfinite(value) and value > 0.0):
        raise argparse.ArgumentTypeError(f'must be a positive number, got {text!r}')
    return value


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    config = DemoConfig(args.protocol, args.units or None, args.length or None,
                        args.runs_dir, args.name, args.real_time_factor, args.lookahead)
    # SIGINT (even if inherited ignored), SIGTERM and SIGHUP unwind like
    # Ctrl-C, so the finally blocks stop the children.
    signal.signal(signal.SIGINT, signal.default_int_handler)
    for sig in (signal.SIGTERM, signal.SIGHUP):
        signal.signal(sig, _raise_stop)
    try:
        return run_demo(config)
    except DemoError as err:
        print(f'demo failed: {err}', file=sys.stderr)
        return 1
    except (KeyboardInterrupt, _Stop):
        print('demo interrupted; every process it started has been stopped', file=sys.stderr)
        return 130


if __name__ == '__main__':
    sys.exit(main())
