"""``make demo-closed-loop``: a force-target profile through controller, simulator and recorder.

Starts the simulator, the force controller and the recorder as three ROS 2
processes in their own namespace, plays a target profile (``force_target``
and the rig's ``length_command``, against the simulator's time read from the
``wrench`` stamps) from this process, stops the recorder cleanly, reads the
bag back and writes ``closed_loop.png``: target and force against time, the
pulse width below. Every process it started is stopped on the way out, also
when it is interrupted (Ctrl-C, SIGTERM).

Run: ``python -m hill_muscle_ros.demo_closed_loop [--profile FILE] [--out DIR]``.
"""
from __future__ import annotations

import argparse
import datetime as _dt
import math
import os
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Sequence

import numpy as np
import yaml

from .model.protocol import Knots
from .recording.analysis import closed_loop_summary
from .resources import config_dir
from .supervisor import (GraphProbe, ProcessGroup, StopSignals, node_command,
                         ros_environment)
from .timebase import NS_PER_S

#: Default namespace of the demo's nodes, so that it does not cross-talk with
#: another package's run (``make demo`` uses the root namespace).
DEFAULT_NAMESPACE = '/closed_loop'
#: [Hz] rate at which this process publishes the profile.
PROFILE_RATE_HZ = 100.0
#: [s] deadlines: node start-up and discovery on a loaded machine; a clean stop.
START_TIMEOUT_S = 60.0
STOP_TIMEOUT_S = 10.0
#: [s] simulated time after the profile before the recorder stops (last messages in).
TAIL_S = 0.2
RECORDED = ('force', 'wrench', 'pulse_width', 'force_target', 'length_command')
#: Types of the recorded topics the package's nodes do not publish: the recorder
#: subscribes to them at start-up (``topic:type`` entries), not on discovery.
RECORDED_TYPES = {'force_target': 'std_msgs/msg/Float64'}
PROFILE_KEYS = ('name', 'duration_s', 'force_target_n', 'dl_mt_m')
EXIT_ERROR = 1


class ProfileError(ValueError):
    """A target-profile file is malformed; the message says where and why."""


@dataclass(frozen=True)
class TargetProfile:
    """A force target and a length command against time.

    :param name: shown in the plot title
    :param duration_s: [s] length of the run
    :param force_target_n: [N] F*(t)
    :param dl_mt_m: [m] dl_MT(t), positive = stretch
    """

    name: str
    duration_s: float
    force_target_n: Knots
    dl_mt_m: Knots

    @classmethod
    def from_yaml(cls, path: str | os.PathLike) -> 'TargetProfile':
        """Load a profile; the knots follow the protocol files' rules.

        :raises ProfileError: naming the file and the key on any defect
        """
        try:
            data = yaml.safe_load(Path(path).read_text(encoding='utf-8'))
        except (OSError, UnicodeDecodeError, yaml.YAMLError) as err:
            raise ProfileError(f'{path}: cannot read the profile: {err}') from None
        if not isinstance(data, dict) or set(data) != set(PROFILE_KEYS):
            raise ProfileError(f'{path}: expected exactly the keys {", ".join(PROFILE_KEYS)}')
        duration = data['duration_s']
        if (isinstance(duration, bool) or not isinstance(duration, (int, float))
                or not 0.0 < duration < math.inf):
            raise ProfileError(f'{path}: `duration_s` must be a positive number, got {duration!r}')
        return cls(str(data['name']), float(duration),
                   _knots(data['force_target_n'], path, 'force_target_n'),
                   _knots(data['dl_mt_m'], path, 'dl_mt_m'))


def _knots(raw: Any, path, key: str) -> Knots:
    try:
        arr = np.array(raw, dtype=float)
    except (TypeError, ValueError, OverflowError):
        arr = None
    if arr is None or arr.ndim != 2 or arr.shape[1] != 2 or arr.shape[0] == 0:
        raise ProfileError(f'{path}: `{key}` must be a list of [time_s, value] knots')
    if not np.all(np.isfinite(arr)) or np.any(np.diff(arr[:, 0]) < 0) or arr[0, 0] < 0:
        raise ProfileError(f'{path}: `{key}` needs finite values and non-decreasing times >= 0')
    return Knots(arr[:, 0].copy(), arr[:, 1].copy())


def default_profile() -> Path:
    """The shipped ``config/target_profile.yaml``."""
    return config_dir() / 'target_profile.yaml'


# -- the run ------------------------------------------------------------------------


def run(profile: TargetProfile, out: Path, namespace: str) -> tuple[Path, int]:
    """Run the profile live and record it.

    The nodes are processes of a :class:`~hill_muscle_ros.supervisor.ProcessGroup`
    (logs in ``out``); this process publishes the profile from a
    :class:`~hill_muscle_ros.supervisor.GraphProbe` node, which also tells
    when every node is subscribed.

    :return: the bag directory, and [ns] the simulator's stamp at which the
        profile started (its t = 0)
    :raises hill_muscle_ros.supervisor.SupervisorError: if a node exits or a wait times out
    """
    from diagnostic_msgs.msg import DiagnosticArray
    from geometry_msgs.msg import WrenchStamped
    from std_msgs.msg import Float64

    from .nodes._topics import DIAGNOSTICS_TOPIC
    from .qos import RELIABLE_QOS

    bag = out / 'bag'

    def node(executable: str, **params: Any) -> list[str]:
        return node_command(executable, ns=namespace, params=params, bin_dir=None)

    # The probe and the nodes share this process's discovery settings (see main).
    with ProcessGroup(out, ros_environment(discovery_range=None), STOP_TIMEOUT_S) as procs, \
            GraphProbe('closed_loop_demo', namespace=namespace) as probe:
        procs.start('simulator', node('simulator'))
        procs.start('controller', node('force_controller'))
        topics = [f'{t}:{RECORDED_TYPES[t]}' if t in RECORDED_TYPES else t for t in RECORDED]
        recorder = procs.start('recorder', node('recorder', output=str(bag), topics=topics))
        target_pub = probe.node.create_publisher(Float64, 'force_target', RELIABLE_QOS)
        length_pub = probe.node.create_publisher(Float64, 'length_command', RELIABLE_QOS)
        latest = {}
        probe.node.create_subscription(WrenchStamped, 'wrench',
                                       lambda m: latest.__setitem__('stamp', m.header.stamp),
                                       RELIABLE_QOS)

        # What the recorder itself reports having received (its /diagnostics):
        # a subscription in the graph is not yet one matched to the publisher.
        recorder_fqn = f'{namespace.rstrip("/")}/recorder'
        received: dict[str, float] = {}

        def on_diagnostics(msg: DiagnosticArray) -> None:
            for status in msg.status:
                if status.hardware_id == recorder_fqn:
                    received.update({kv.key: float(kv.value) for kv in status.values
                                     if kv.key.startswith('received[')})

        probe.node.create_subscription(DiagnosticArray, DIAGNOSTICS_TOPIC, on_diagnostics,
                                       RELIABLE_QOS)

        def recorder_has(topic: str) -> bool:
            return received.get(f'received[{namespace.rstrip("/")}/{topic}]', 0.0) > 0.0

        def sim_now_s() -> float | None:
            stamp = latest.get('stamp')
            return None if stamp is None else stamp.sec + stamp.nanosec / NS_PER_S

        # Everyone listens before the profile starts: controller and recorder
        # on the target, simulator and recorder on the length, recorder on the rest.
        probe.spin_until(lambda: (target_pub.get_subscription_count() >= 2
                                  and length_pub.get_subscription_count() >= 2
                                  and all(probe.node.count_subscribers(t) >= 2
                                          for t in ('force', 'pulse_width', 'wrench'))
                                  and sim_now_s() is not None
                                  and all(recorder_has(t) for t in ('force', 'pulse_width',
                                                                     'wrench'))),
                         'the nodes to start and connect', START_TIMEOUT_S, procs.processes)
        print(f'{profile.name}: {profile.duration_s:g} s through simulator, controller and '
              f'recorder in {namespace}', flush=True)
        t0 = sim_now_s()
        period_s = 1.0 / PROFILE_RATE_HZ
        next_tick = time.monotonic()
        while True:
            t = sim_now_s() - t0
            if t >= profile.duration_s + TAIL_S:
                break
            t_prof = min(t, profile.duration_s)
            target_pub.publish(Float64(data=float(profile.force_target_n(t_prof))))
            length_pub.publish(Float64(data=float(profile.dl_mt_m(t_prof))))
            next_tick += period_s
            while time.monotonic() < next_tick:
                probe.spin_once(max(0.0, next_tick - time.monotonic()))
            procs.check_alive()
        # Gone from the graph before the recorder stops: it then does not wait
        # for more of them (publishers gone quiet) before closing the bag.
        for pub in (target_pub, length_pub):
            probe.retire_publisher(pub, STOP_TIMEOUT_S)
        status = recorder.stop(STOP_TIMEOUT_S)
        if status != 0:
            raise RuntimeError(f'recorder exited with status {status}; see {out}/recorder.log')
    return bag, round(t0 * NS_PER_S)


def plot(bag: Path, png: Path, profile: TargetProfile, t0_ns: int,
         namespace: str) -> dict[str, float]:
    """Target and force (top), pulse width (bottom), against time, from the bag.

    :return: summary numbers (RMS and largest tracking error, counts); see
        :func:`hill_muscle_ros.recording.analysis.closed_loop_summary`
    """
    return closed_loop_summary(bag, png, profile.name, profile.duration_s, t0_ns, namespace,
                               TAIL_S)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog='demo-closed-loop', description='Run a force-target profile through the force '
        'controller, the simulator and the recorder; write the bag and a plot.')
    parser.add_argument('--profile', type=Path, default=None,
                        help='target-profile YAML (default: config/target_profile.yaml)')
    parser.add_argument('--namespace', default=DEFAULT_NAMESPACE,
                        help=f'namespace of the nodes (default {DEFAULT_NAMESPACE})')
    parser.add_argument('--out', type=Path, default=None,
                        help='output directory, must not exist or be empty '
                             '(default: runs/closed_loop_<UTC timestamp>)')
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    out = args.out or Path('runs') / _dt.datetime.now(_dt.timezone.utc).strftime(
        'closed_loop_%Y-%m-%dT%H-%M-%SZ')
    os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')

    stops = StopSignals()   # Ctrl-C, SIGTERM, SIGHUP: the same clean-up
    try:
        profile = TargetProfile.from_yaml(args.profile or default_profile())
        if out.exists() and any(out.iterdir()):
            raise ProfileError(f'{out}: exists and is not empty; choose another --out')
        out.mkdir(parents=True, exist_ok=True)
        bag, t0_ns = run(profile, out, args.namespace)
        png = out / 'closed_loop.png'
        summary = plot(bag, png, profile, t0_ns, args.namespace)
    except (KeyboardInterrupt, ProfileError, RuntimeError) as err:
        if isinstance(err, KeyboardInterrupt) or stops.received is not None:
            print('interrupted: every node stopped', file=sys.stderr)
            return 130
        print(f'demo-closed-loop: error: {err}', file=sys.stderr)
        return EXIT_ERROR
    print(f'tracking error: RMS {summary["rms_error_n"]:.3f} N, largest '
          f'{summary["max_abs_error_n"]:.3f} N (at the steps and the stretch)')
    for key, value in summary.items():
        if key.startswith('count '):
            print(f'  {key[6:]}: {value:.0f} messages')
    print(f'bag:  {bag}\nplot: {png}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
