"""``make demo``: a live run over ROS 2, recorded, read back, plotted and summarised.

1. starts the simulator, the recorder and then the protocol player as three
   separate ROS processes, on a DDS domain of their own, localhost only;
2. waits for the protocol to end (the player exits);
3. stops the recorder with SIGINT, so the bag is closed properly;
4. reads the bag back with :func:`hill_muscle_ros.recording.reader.read_bag`;
5. writes ``<bag>/force.png``: force and inputs against time, from the bag;
6. prints the force at the end of each second (next to the offline
   simulation of the same protocol), the message count per topic and the bag;
7. fails (exit status 1, with a line that says where and by how much) if the
   live force differs from the offline one by more than
   :data:`LIVE_OFFLINE_TOLERANCE_N` at one of those checkpoints.

The processes are run by :mod:`hill_muscle_ros.supervisor`: every child
runs in its own process group and is stopped (SIGINT, then SIGKILL of the
group) when the demo ends, whatever the reason: normal end, error, Ctrl-C,
SIGTERM or SIGHUP. Children also get SIGTERM from the kernel if the demo
itself dies (``PR_SET_PDEATHSIG``). Readiness comes from the ROS graph, seen
by a probe node in this process; the bag analysis is
:mod:`hill_muscle_ros.recording.analysis`.

With ``--real-time-factor X`` the run goes faster (or slower) than real
time on simulated time: the simulator publishes ``/clock`` and runs X
simulated seconds per second of the steady clock (``publish_clock:=true``,
``real_time_factor:=X``); the player and the recorder use it
(``use_sim_time:=true``), so the bag's times are simulated seconds from the
simulator's start.

The length goes ahead of time, on the wall clock as on sim time: the player
sends it as ``length_command_stamped`` knots ``--lookahead`` seconds ahead
(default :func:`default_lookahead_s`, 0.1 s on the wall clock, growing with
the real-time factor), so the simulator reaches each length exactly at its
step whatever the DDS latency and however its ticks fall. On the plain
``length_command`` it holds the newest length through each tick, and the force
mid-ramp wandered by up to 0.18 N around the offline one on a quiet machine
(one run of three read 0.100 N off at 1.95 s), too close to
:data:`LIVE_OFFLINE_TOLERANCE_N`; sent ahead, within 0.004 N (four runs);
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
import datetime as _dt
import os
import re
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np

from .domain_lock import lock_free_domain
from .model import LENGTH_CHOICES, UNITS_CHOICES, Protocol
from .params_file import load_muscle_params
from .recording.analysis import BagContentError, Checkpoint, analyse
from .resources import default_params_file, protocol_path
from .supervisor import (GraphProbe, ProcessGroup, StopSignals, SupervisorError,
                         node_command, ros_environment)

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
#: [s] poll period while waiting for a free domain.
POLL_S = 0.05
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
#: [N] most the live force may differ from the offline simulation at a
#: checkpoint (the end of each second) for the demo to pass. Healthy runs
#: agree within 0.004 N on the wall clock and exactly on sim time (the length
#: sent ahead); a protocol shifted by 150 ms missed by 1.5 N and, before
#: this check, exited 0.
LIVE_OFFLINE_TOLERANCE_N = 0.1


class DemoError(RuntimeError):
    """The demo could not complete; the message says which step and why."""


# --------------------------------------------------------------------------- domain

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
    #: 0: the plain length_command; None: :func:`default_lookahead_s` (on the
    #: wall clock, at real-time factor 1).
    lookahead_s: float | None = None

    def lookahead(self) -> float:
        """[s] the look-ahead this run uses (see :attr:`lookahead_s`)."""
        if self.lookahead_s is not None:
            return self.lookahead_s
        return default_lookahead_s(self.real_time_factor or 1.0)


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
    """Run simulator, recorder and player; return once the bag is closed.

    :raises DemoError: if a process fails or a step times out (with its log)
    """
    with claimed_domain() as domain:
        try:
            _record_live_run(config, bag_dir, protocol, log_dir, domain)
        except SupervisorError as err:
            raise DemoError(str(err)) from None


def _node_args(config: DemoConfig, bag_dir: Path) -> tuple[list[str], list[str], list[str]]:
    """``--ros-args`` of the simulator, the recorder and the player."""
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
    rec_args = ['-p', f'output:={bag_dir}', *sim_time_args]
    player_args = ['-p', f'protocol:={spec}', '-p', f'lookahead_s:={float(config.lookahead())!r}',
                   '-p', f'min_subscribers:={DEMO_MIN_SUBSCRIBERS}',
                   '-p', f'wait_for_subscribers_s:={STARTUP_TIMEOUT_S!r}', *sim_time_args]
    return sim_args, rec_args, player_args


def _record_live_run(config: DemoConfig, bag_dir: Path, protocol: Protocol, log_dir: Path,
                     domain: int) -> None:
    from .nodes.recorder import NODE_NAME as RECORDER, subscriptions_node_name
    sim_args, rec_args, player_args = _node_args(config, bag_dir)
    rtf, lookahead_s = config.real_time_factor, config.lookahead()
    env = ros_environment(domain)
    # The probe in this process sees the children's graph: same domain, same discovery range.
    os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = env['ROS_AUTOMATIC_DISCOVERY_RANGE']

    def node(name: str, args: list[str]) -> list[str]:
        return node_command(name, extra_ros_args=args, bin_dir=None)

    with ProcessGroup(log_dir, env, STOP_TIMEOUT_S) as procs, \
            GraphProbe('demo_probe', domain_id=domain) as probe:
        sim = procs.start('simulator', node('simulator', sim_args))
        rec = procs.start('recorder', node('recorder', rec_args))
        # The simulator and the recorder are up and spinning (each answers its
        # parameter service), and the graph shows the recorder subscribed to
        # the simulator's wrench, before the player starts: the plain-length
        # analysis on sim time anchors time 0 on the last wrench at rest (see
        # protocol_start_ns), and on sim time the recorder's log times are its
        # clock when it takes a message, so a recorder still starting up
        # (measured: 0.1 s of wall time, 1 s of simulated time at RTF 10)
        # would log the protocol's first messages late. The player's
        # min_subscribers 2 then guarantees that the recorder also gets the
        # player's first message.
        for name in ('/simulator', f'/{RECORDER}'):
            probe.wait_until_serving(name, STARTUP_TIMEOUT_S, [sim, rec])
        probe.wait_for_endpoints('/wrench', publisher='/simulator',
                                 subscriber='/' + subscriptions_node_name(RECORDER),
                                 timeout_s=STARTUP_TIMEOUT_S, watch=[sim, rec])
        player = procs.start('protocol_player', node('protocol_player', player_args))
        on_sim_time = '' if rtf is None else f', sim time at real_time_factor {rtf:g}'
        ahead = '' if lookahead_s == 0.0 else f', length sent {lookahead_s:g} s ahead'
        print(f'running {protocol.name} ({protocol.duration_s:g} s) over ROS 2 '
              f'(ROS_DOMAIN_ID={domain}{on_sim_time}{ahead}) ...', flush=True)
        procs.wait_until(lambda: player.returncode is not None, 'the protocol to end',
                         (protocol.duration_s + lookahead_s) / (rtf or 1.0) + STARTUP_TIMEOUT_S
                         + PLAYER_SLACK_S, watch=[sim, rec])
        if player.returncode != 0:
            raise DemoError(f'the protocol player failed ({player.returncode})\n'
                            f'{player.describe()}')
        if rec.stop(STOP_TIMEOUT_S) != 0:
            raise DemoError(f'the recorder failed ({rec.returncode})\n{rec.describe()}')
        # The simulator logs its timing statistics as it exits.
        sim.stop(STOP_TIMEOUT_S)


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
    try:
        summary = analyse(bag_dir, protocol, params, rate_hz, bag_dir / 'force.png',
                          config.real_time_factor)
    except BagContentError as err:
        raise DemoError(str(err)) from None
    print(summary.text)
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
    try:
        check_live_against_offline(summary.checkpoints)
    except DemoError as err:
        try:
            gap = _LONGEST_GAP_RE.search((log_dir / 'simulator.log').read_text(errors='replace'))
        except OSError:
            gap = None   # no log to quote: the verdict alone
        if gap is None:
            raise
        # A stalled simulator or player shifts the live run (a busy machine):
        # say so, as that is the first thing to rule out.
        raise DemoError(f'{err}; the simulator\'s longest gap between ticks was '
                        f'{gap.group(1)} ms ({log_dir / "simulator.log"})') from None
    return 0


def check_live_against_offline(checkpoints: Sequence[Checkpoint],
                               tolerance_n: float = LIVE_OFFLINE_TOLERANCE_N) -> None:
    """Fail unless the live force is within ``tolerance_n`` of the offline
    one at every checkpoint (a missing live reading fails too).

    :raises DemoError: naming the worst checkpoint, its difference and the tolerance
    """
    def miss_n(c: Checkpoint) -> float:
        return abs(c.diff_n) if np.isfinite(c.diff_n) else np.inf
    worst = max(checkpoints, key=miss_n, default=None)
    if worst is None or miss_n(worst) <= tolerance_n:
        return
    bad = sum(miss_n(c) > tolerance_n for c in checkpoints)
    raise DemoError(f'live force differs from the offline simulation by more than '
                    f'{tolerance_n:g} N (LIVE_OFFLINE_TOLERANCE_N) at {bad} of '
                    f'{len(checkpoints)} checkpoints; worst at t = {worst.t_s:.3f} s: live '
                    f'{worst.live_n:.3f} N, offline {worst.offline_n:.3f} N, difference '
                    f'{worst.diff_n:+.3f} N')


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
_LONGEST_GAP_RE = re.compile(r'longest gap between ticks ([\d.]+) ms')
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
                             f'default: max({MIN_LOOKAHEAD_S:g}, {LOOKAHEAD_WALL_S:g} x X), '
                             f'X = 1 on the wall clock')
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
    stops = StopSignals()
    try:
        return run_demo(config)
    except (KeyboardInterrupt, DemoError, RuntimeError) as err:
        if isinstance(err, KeyboardInterrupt) or stops.received is not None:
            print('demo interrupted; every process it started has been stopped',
                  file=sys.stderr)
            return 130
        if isinstance(err, DemoError):
            print(f'demo failed: {err}', file=sys.stderr)
            return 1
        raise


if __name__ == '__main__':
    sys.exit(main())
