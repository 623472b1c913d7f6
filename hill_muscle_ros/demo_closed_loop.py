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
import signal
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Sequence

import numpy as np
import yaml

from .model.protocol import Knots
from .resources import config_dir

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
PROFILE_KEYS = ('name', 'duration_s', 'force_target_n', 'dl_mt_m')
_NS_PER_S = 1e9
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


# -- processes ------------------------------------------------------------------


class Processes:
    """Node subprocesses, each in its own session; all stopped on :meth:`stop_all`."""

    def __init__(self, log_dir: Path, namespace: str) -> None:
        self.log_dir = log_dir
        self.namespace = namespace
        self.procs: dict[str, subprocess.Popen] = {}

    def start(self, name: str, executable: str, ros_args: Sequence[str]) -> subprocess.Popen:
        exe = Path(sys.executable).parent / executable
        log = open(self.log_dir / f'{name}.log', 'wb')
        proc = subprocess.Popen([str(exe), '--ros-args', '-r', f'__ns:={self.namespace}', *ros_args],
                                stdout=log, stderr=subprocess.STDOUT, env=os.environ.copy(),
                                start_new_session=True)
        self.procs[name] = proc
        return proc

    def stop(self, name: str) -> int:
        """SIGINT, then SIGKILL of its process group after :data:`STOP_TIMEOUT_S`."""
        proc = self.procs[name]
        if proc.poll() is None:
            proc.send_signal(signal.SIGINT)
            try:
                proc.wait(timeout=STOP_TIMEOUT_S)
            except subprocess.TimeoutExpired:
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait()
        return proc.returncode

    def stop_all(self) -> None:
        for name in reversed(list(self.procs)):
            self.stop(name)

    def check_alive(self) -> None:
        for name, proc in self.procs.items():
            if proc.poll() is not None:
                log = (self.log_dir / f'{name}.log').read_text(errors='replace')[-2000:]
                raise RuntimeError(f'{name} exited with status {proc.returncode}:\n{log}')


# -- the run ------------------------------------------------------------------------


def run(profile: TargetProfile, out: Path, namespace: str) -> tuple[Path, int]:
    """Run the profile live and record it.

    :return: the bag directory, and [ns] the simulator's stamp at which the
        profile started (its t = 0)
    """
    import rclpy
    from geometry_msgs.msg import WrenchStamped
    from std_msgs.msg import Float64

    from .nodes._common import RELIABLE_QOS

    bag = out / 'bag'
    procs = Processes(out, namespace)
    rclpy.init(args=[])
    node = rclpy.create_node('closed_loop_demo', namespace=namespace)
    try:
        procs.start('simulator', 'simulator', [])
        procs.start('controller', 'force_controller', [])
        procs.start('recorder', 'recorder', [
            '-p', f'output:={bag}', '-p', 'topics:=[' + ','.join(f'"{t}"' for t in RECORDED) + ']'])
        target_pub = node.create_publisher(Float64, 'force_target', RELIABLE_QOS)
        length_pub = node.create_publisher(Float64, 'length_command', RELIABLE_QOS)
        latest = {}
        node.create_subscription(WrenchStamped, 'wrench',
                                 lambda m: latest.__setitem__('stamp', m.header.stamp),
                                 RELIABLE_QOS)

        def sim_now_s() -> float | None:
            stamp = latest.get('stamp')
            return None if stamp is None else stamp.sec + stamp.nanosec / _NS_PER_S

        def spin_until(condition, what: str, timeout_s: float = START_TIMEOUT_S) -> None:
            deadline = time.monotonic() + timeout_s
            while not condition():
                procs.check_alive()
                if time.monotonic() > deadline:
                    raise RuntimeError(f'timed out after {timeout_s:g} s waiting for {what}')
                rclpy.spin_once(node, timeout_sec=0.02)

        # Everyone listens before the profile starts: controller and recorder
        # on the target, simulator and recorder on the length, recorder on the rest.
        spin_until(lambda: (target_pub.get_subscription_count() >= 2
                            and length_pub.get_subscription_count() >= 2
                            and all(node.count_subscribers(t) >= 2
                                    for t in ('force', 'pulse_width', 'wrench'))
                            and sim_now_s() is not None), 'the nodes to start and connect')
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
                rclpy.spin_once(node, timeout_sec=max(0.0, next_tick - time.monotonic()))
            procs.check_alive()
        status = procs.stop('recorder')
        if status != 0:
            raise RuntimeError(f'recorder exited with status {status}; see {out}/recorder.log')
    finally:
        procs.stop_all()
        node.destroy_node()
        rclpy.try_shutdown()
    return bag, round(t0 * _NS_PER_S)


def plot(bag: Path, png: Path, profile: TargetProfile, t0_ns: int,
         namespace: str) -> dict[str, float]:
    """Target and force (top), pulse width (bottom), against time, from the bag.

    :return: summary numbers (RMS and largest tracking error, counts)
    """
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    from .recording.reader import read_bag

    title = profile.name
    data = read_bag(bag)
    wrench = data.topic(f'{namespace}/wrench')
    target = data.topic(f'{namespace}/force_target')
    pw = data.topic(f'{namespace}/pulse_width')
    dl = data.topic(f'{namespace}/length_command')
    # Stamps are the simulator's time; receive times are on the same (system)
    # clock, as the nodes run without sim time.
    t0 = t0_ns
    t_f = (wrench.stamps_ns() - t0) / _NS_PER_S
    force = wrench.values()
    t_target = (target.log_time_ns - t0) / _NS_PER_S
    target_v = target.values()
    keep = (t_f >= 0.0) & (t_f <= profile.duration_s)
    t_f, force = t_f[keep], force[keep]
    # The target in force at each force sample (zero-order hold, as the controller sees it).
    idx = np.clip(np.searchsorted(t_target, t_f, side='right') - 1, 0, len(target_v) - 1)
    err = force - target_v[idx]

    fig, (ax_f, ax_pw) = plt.subplots(2, 1, sharex=True, figsize=(9, 6),
                                      gridspec_kw={'height_ratios': [2, 1]})
    ax_f.step(t_target, target_v, where='post', color='0.4', lw=2, label='target F* [N]')
    ax_f.plot(t_f, force, color='tab:red', lw=1, label='force F [N]')
    ax_dl = ax_f.twinx()
    ax_dl.plot((dl.log_time_ns - t0) / _NS_PER_S, dl.values() * 1e3, color='tab:green',
               lw=1, ls='--', label='stretch ΔL_MT [mm]')
    ax_dl.set_ylabel('ΔL_MT [mm]')
    ax_f.set_ylabel('force [N]')
    ax_f.set_title(f'{title}: force controller closed around the simulated muscle')
    lines = ax_f.get_legend_handles_labels()
    more = ax_dl.get_legend_handles_labels()
    ax_f.legend(lines[0] + more[0], lines[1] + more[1], loc='upper left')
    ax_pw.step((pw.log_time_ns - t0) / _NS_PER_S, pw.values() * 1e6, where='post',
               color='tab:blue', lw=1)
    ax_pw.set_ylabel('pulse width [µs]')
    ax_pw.set_xlabel('time [s] (simulated, from the start of the profile)')
    for ax in (ax_f, ax_pw):
        ax.grid(alpha=0.3)
    ax_pw.set_xlim(0.0, profile.duration_s + TAIL_S)
    fig.tight_layout()
    png.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(png, dpi=120)
    plt.close(fig)
    return {'rms_error_n': float(np.sqrt(np.mean(err ** 2))),
            'max_abs_error_n': float(np.abs(err).max()),
            **{f'count {name}': float(n) for name, n in data.counts().items()}}


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

    def on_sigterm(signum, frame):
        raise KeyboardInterrupt  # the same clean-up as Ctrl-C

    signal.signal(signal.SIGTERM, on_sigterm)
    try:
        profile = TargetProfile.from_yaml(args.profile or default_profile())
        if out.exists() and any(out.iterdir()):
            raise ProfileError(f'{out}: exists and is not empty; choose another --out')
        out.mkdir(parents=True, exist_ok=True)
        bag, t0_ns = run(profile, out, args.namespace)
        png = out / 'closed_loop.png'
        summary = plot(bag, png, profile, t0_ns, args.namespace)
    except KeyboardInterrupt:
        print('interrupted: every node stopped', file=sys.stderr)
        return 130
    except (ProfileError, RuntimeError) as err:
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
