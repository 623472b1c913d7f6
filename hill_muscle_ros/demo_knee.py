"""``make demo-knee``: the joint-angle controller moves the simulated knee.

Starts the limb node, the joint controller and the recorder as three ROS 2
processes in their own namespace, all on the knee plant file
(``config/knee.yaml``: 1 kHz, real time); first it loads the compiled limb
the limb node will run (:func:`load_compiled_limb`: numba compiles it once,
about 30 s, so the node's start does not). Once every subscription is in
place both ways, this process plays an angle profile on ``angle_target``
(std_msgs/Float64, rad) at the controller's rate, against the limb's
simulated time read from the ``joint_states`` stamps: steps to 20, 45 and
30 deg, each held 3 s, then a 0.2 Hz sine of 15 deg around 30 deg for two
periods (``--profile short`` holds each step 2 s and plays half a period,
for the tests). It then stops the recorder cleanly and, from the bag alone,
writes into the run directory:

- ``bag/``: the rosbag2 MCAP bag (``joint_states``, ``angle_target``, each
  muscle's ``pulse_width``, ``force`` and ``wrench``, ``/diagnostics``);
- ``knee.png``: target and angle [deg] above, each muscle's pulse width
  [us] below, against the limb's simulated time;
- ``knee.gif``: the leg as a stick figure (:mod:`hill_muscle_ros.animation`)
  from the recorded joint angle and stimulation.

and prints the RMS tracking error per segment of the profile, the error at
the end of each held step and each muscle's largest pulse width. Every
process it started is stopped on the way out, also when it is interrupted
(Ctrl-C, SIGTERM); the recorder then still closes the bag.

Run: ``python -m hill_muscle_ros.demo_knee [--profile full|short] [--out DIR]
[--gif-fps FPS]``.
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

from .control.joint import DEFAULT_RATE_HZ as CONTROL_RATE_HZ
from .model.limb import LimbPlant, LimbResult
from .model.stimulus import command_from_pulse_width
from .params_file import load_plant
from .resources import config_dir
from .supervisor import (GraphProbe, ProcessGroup, StopSignals, SupervisorError,
                         node_command, ros_environment)
from .timebase import NS_PER_S

#: Default namespace of the demo's nodes, so that it does not cross-talk with
#: another run (``make demo`` uses the root namespace, the closed-loop demo its own).
DEFAULT_NAMESPACE = '/knee_demo'
#: The plant file of all three nodes (the controller's model is the limb).
PLANT_FILE = 'knee.yaml'
#: [Hz] rate at which this process publishes the profile: the controller's.
PROFILE_RATE_HZ = CONTROL_RATE_HZ
#: [s] deadlines: node start-up and discovery on a loaded machine; a clean stop.
START_TIMEOUT_S = 60.0
STOP_TIMEOUT_S = 10.0
#: [s] simulated time after the profile before the recorder stops (last messages in).
TAIL_S = 0.2
#: [s] the end of a held step over which its final error is averaged: long
#: enough to average out the 100 Hz stimulation ripple, short against the hold.
END_OF_HOLD_S = 0.1
#: [frames/s] of simulated time in the GIF: 10 keeps a 19 s run near 200
#: frames (a few MB, a few seconds to render); the motion is slow (0.2 Hz).
GIF_FPS = 10.0
#: [us/s], [deg/rad] display units.
US_PER_S = 1e6
DEG_PER_RAD = 180.0 / math.pi
EXIT_ERROR = 1
EXIT_INTERRUPTED = 130


@dataclass(frozen=True)
class KneeProfile:
    """Angle steps, each held ``hold_s``, then a sine about the last step's angle.

    :param name: ``full``, ``short`` or ``brief``
    :param steps_deg: [deg] the held angles, in order
    :param hold_s: [s] how long each step is held
    :param sine_center_deg: [deg] the sine's mean angle
    :param sine_amplitude_deg: [deg] its amplitude
    :param sine_frequency_hz: [Hz] its frequency
    :param sine_periods: [-] how many periods it plays
    """

    name: str
    steps_deg: tuple[float, ...] = (20.0, 45.0, 30.0)
    hold_s: float = 3.0
    sine_center_deg: float = 30.0
    sine_amplitude_deg: float = 15.0
    sine_frequency_hz: float = 0.2
    sine_periods: float = 2.0

    @property
    def sine_start_s(self) -> float:
        """[s] when the sine starts (after the last held step)."""
        return len(self.steps_deg) * self.hold_s

    @property
    def duration_s(self) -> float:
        """[s] the whole profile."""
        return self.sine_start_s + self.sine_periods / self.sine_frequency_hz

    def target_rad(self, t_s: float) -> float:
        """[rad] theta*(t): the held step at ``t_s``, or the sine after them
        (held at its last value after the end)."""
        t_s = min(max(t_s, 0.0), self.duration_s)
        step = int(t_s // self.hold_s)
        if step < len(self.steps_deg):
            return math.radians(self.steps_deg[step])
        phase = 2.0 * math.pi * self.sine_frequency_hz * (t_s - self.sine_start_s)
        return math.radians(self.sine_center_deg + self.sine_amplitude_deg * math.sin(phase))

    def segments(self) -> list[tuple[str, float, float]]:
        """``(label, start_s, end_s)`` of each held step and of the sine."""
        out = [(f'step {a:g} deg', k * self.hold_s, (k + 1) * self.hold_s)
               for k, a in enumerate(self.steps_deg)]
        out.append((f'sine {self.sine_frequency_hz:g} Hz ±{self.sine_amplitude_deg:g} deg',
                    self.sine_start_s, self.duration_s))
        return out


#: ``full`` is the demo; ``short`` (2 s holds, half a sine period) keeps the test
#: near 20 s: the controller settles a 25 deg step to within 2 deg in well under 1 s.
#: ``brief`` (0.5 s holds, a quarter period) runs every node, topic, plot and
#: GIF of the demo in 2.75 s, with holds too short to judge the tracking by: the
#: tests of what the demo writes use it, the settling claim uses ``short``.
PROFILES = {'full': KneeProfile('full'),
            'short': KneeProfile('short', hold_s=2.0, sine_periods=0.5),
            'brief': KneeProfile('brief', hold_s=0.5, sine_periods=0.25)}


def plant_file() -> Path:
    """The shipped ``config/knee.yaml``."""
    return config_dir() / PLANT_FILE


def recorded_topics(muscles: Sequence[str]) -> list[str]:
    """The recorder's ``topics``: typed entries, so that each is subscribed at start-up."""
    float64, wrench = 'std_msgs/msg/Float64', 'geometry_msgs/msg/WrenchStamped'
    topics = ['joint_states:sensor_msgs/msg/JointState', f'angle_target:{float64}']
    for m in muscles:
        topics += [f'{m}/pulse_width:{float64}', f'{m}/force:{float64}', f'{m}/wrench:{wrench}']
    return topics + ['/diagnostics:diagnostic_msgs/msg/DiagnosticArray']


def topic_names(entries: Sequence[str]) -> list[str]:
    """The topic names of :func:`recorded_topics` entries (without their types)."""
    return [e.partition(':')[0] for e in entries]


def _never_called(_msg: Any) -> None:
    """The limb-time subscription is read by taking, never by an executor."""


# -- the run ------------------------------------------------------------------------


def load_compiled_limb() -> None:
    """Load the limb node's compiled limb here, before any node starts, when the
    node will run it: numba compiles it once (about 30 s) when its disk cache has
    no copy, and the node then loads that copy in about a second instead of
    compiling within its start-up deadline. A failure is the node's to report
    (it falls back to the Python limb)."""
    from .model import engine
    from .model.limb import kernels as limb_kernels
    try:
        if engine.choice() != engine.COMPILED:
            return
        print('loading the compiled limb (the first run compiles it once, about 30 s; '
              'cached afterwards)', flush=True)
        started_s = time.monotonic()
        limb_kernels.compiled()
    except Exception as err:   # noqa: BLE001 -- the limb node falls back to Python, and says so
        print(f'demo-knee: warning: the compiled limb failed to load ({type(err).__name__}: '
              f'{err}); the limb node will run the Python limb', file=sys.stderr, flush=True)
        return
    print(f'compiled limb loaded in {time.monotonic() - started_s:.1f} s '
          f'({engine.compile_seconds():.1f} s of it compiling)', flush=True)


def run(profile: KneeProfile, plant: LimbPlant, out: Path, namespace: str) -> tuple[Path, int]:
    """Run the profile live and record it.

    :return: the bag directory, and [ns] the limb's stamp at which the profile
        started (its t = 0)
    :raises hill_muscle_ros.supervisor.SupervisorError: if a node exits or a wait times out
    :raises RuntimeError: if the recorder does not stop cleanly
    """
    import rclpy
    from diagnostic_msgs.msg import DiagnosticArray
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Float64

    from .nodes._topics import DIAGNOSTICS_TOPIC
    from .nodes.recorder import subscriptions_node_name
    from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy

    from .qos import RELIABLE_QOS

    # Only the newest message, and none resent (matches the limb's reliable publisher).
    newest_only_qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1,
                                 reliability=ReliabilityPolicy.BEST_EFFORT)

    bag = out / 'bag'
    muscles = [m.name for m in plant.muscles]
    entries = recorded_topics(muscles)
    ns = namespace.rstrip('/')
    limb_fqn, controller_fqn = f'{ns}/limb', f'{ns}/joint_controller'
    recorder_fqn = f'{ns}/recorder'
    # The recorder's subscriptions live on a node of their own, which takes no
    # global arguments (no `__ns` remap): it is in the root namespace.
    recorder_subs = '/' + subscriptions_node_name('recorder')

    def node(module: str, **params: Any) -> list[str]:
        return node_command(module, ns=namespace, params=params, params_files=[plant_file()],
                            bin_dir=None)

    # The probe and the nodes share this process's discovery settings (see main).
    with ProcessGroup(out, ros_environment(discovery_range=None), STOP_TIMEOUT_S) as procs, \
            GraphProbe('knee_demo', namespace=namespace) as probe:
        procs.start('limb', node('limb'))
        procs.start('controller', node('joint_controller'))
        recorder = procs.start('recorder', node_command(
            'recorder', ns=namespace, params={'output': str(bag), 'topics': entries},
            bin_dir=None))
        target_pub = probe.node.create_publisher(Float64, 'angle_target', RELIABLE_QOS)
        # The limb's time, from the newest joint state. A callback per message
        # would cost this process a wake-up every 1 ms on a 2-core machine that
        # also runs the three nodes: the subscription keeps only the newest
        # message, on a node the probe's executor does not spin, and is read
        # once per profile tick.
        clock_node = rclpy.create_node('knee_demo_clock', namespace=namespace,
                                       context=probe.context, start_parameter_services=False)
        joint_sub = clock_node.create_subscription(JointState, 'joint_states', _never_called,
                                                   newest_only_qos)
        latest: dict[str, Any] = {}

        # What the recorder reports having received and what the controller
        # reports having heard (their /diagnostics): a subscription in the graph
        # is not yet one matched to the publisher.
        diagnosed: dict[str, dict[str, str]] = {}

        def on_diagnostics(msg: DiagnosticArray) -> None:
            for status in msg.status:
                diagnosed.setdefault(status.hardware_id, {}).update(
                    {kv.key: kv.value for kv in status.values})

        probe.node.create_subscription(DiagnosticArray, DIAGNOSTICS_TOPIC, on_diagnostics,
                                       RELIABLE_QOS)

        def recorder_has(topic: str) -> bool:
            name = topic if topic.startswith('/') else f'{ns}/{topic}'
            return float(diagnosed.get(recorder_fqn, {}).get(f'received[{name}]') or 0) > 0

        def controller_heard_joint_states() -> bool:
            return diagnosed.get(controller_fqn, {}).get('feedback_age_s', '') != ''

        def sim_now_s() -> float | None:
            with joint_sub.handle:
                taken = joint_sub.handle.take_message(JointState, False)
            if taken is not None:
                latest['stamp'] = taken[0].header.stamp
            stamp = latest.get('stamp')
            return None if stamp is None else stamp.sec + stamp.nanosec / NS_PER_S

        def missing() -> list[str]:
            """What is not yet connected (empty when everything is)."""
            checks = {
                # The target reaches the controller and the recorder (matched here).
                'controller and recorder subscribed to angle_target':
                    {controller_fqn, recorder_subs} <= set(probe.subscribers('angle_target'))
                    and target_pub.get_subscription_count() >= 2,
                # The controller hears the limb (its diagnostics say so).
                'controller and recorder subscribed to joint_states':
                    {controller_fqn, recorder_subs} <= set(probe.subscribers('joint_states')),
                'controller receiving joint_states': controller_heard_joint_states(),
                'this process receiving joint_states': sim_now_s() is not None,
            }
            for m in muscles:
                # The limb listens to the controller's pulse widths.
                checks[f'limb and recorder subscribed to the controller\'s {m}/pulse_width'] = (
                    controller_fqn in probe.publishers(f'{m}/pulse_width')
                    and {limb_fqn, recorder_subs} <= set(probe.subscribers(f'{m}/pulse_width')))
            # The recorder has messages of everything but the target, not yet sent.
            for t in topic_names(entries):
                if t != 'angle_target':
                    checks[f'recorder receiving {t}'] = recorder_has(t)
            return [what for what, ok in checks.items() if not ok]

        try:
            probe.spin_until(lambda: not missing(), 'the nodes to start and connect',
                             START_TIMEOUT_S, procs.processes)
        except SupervisorError as err:
            raise SupervisorError(f'{err}\nstill missing: {"; ".join(missing())}') from None
        print(f'{profile.name} profile: {profile.duration_s:g} s through the limb, the joint '
              f'controller and the recorder in {namespace}', flush=True)
        t0 = sim_now_s()
        period_s = 1.0 / PROFILE_RATE_HZ
        next_tick = time.monotonic()
        while True:
            t = sim_now_s() - t0
            if t >= profile.duration_s + TAIL_S:
                break
            target_pub.publish(Float64(data=profile.target_rad(t)))
            next_tick += period_s
            while time.monotonic() < next_tick:
                probe.spin_once(max(0.0, next_tick - time.monotonic()))
            procs.check_alive()
        # Gone from the graph before the recorder stops: it then does not wait
        # for more of the target (a publisher gone quiet) before closing the bag.
        probe.retire_publisher(target_pub, STOP_TIMEOUT_S)
        status = recorder.stop(STOP_TIMEOUT_S)
        if status != 0:
            raise RuntimeError(f'recorder exited with status {status}; see {out}/recorder.log')
        clock_node.destroy_node()
    return bag, round(t0 * NS_PER_S)


# -- the bag read back ---------------------------------------------------------------


@dataclass(frozen=True)
class KneeRun:
    """The recorded run on the limb's simulated time from the profile's start.

    Receive times (the recorder's clock) are carried onto the limb's stamps
    through the joint states, which have both; so a target or a pulse width
    is placed where the limb was when the recorder got it.

    :param t_s: [s] joint-state stamps
    :param theta_rad: [rad] the joint angle
    :param target_t_s: [s] when each target arrived
    :param target_rad: [rad] the targets sent
    :param pulse_width: per muscle, ([s] arrival times, [s] pulse widths)
    """

    t_s: np.ndarray
    theta_rad: np.ndarray
    target_t_s: np.ndarray
    target_rad: np.ndarray
    pulse_width: dict[str, tuple[np.ndarray, np.ndarray]]

    def target_at(self, t_s: np.ndarray) -> np.ndarray:
        """[rad] the target in force at ``t_s`` (zero-order hold, 0 before the first)."""
        idx = np.searchsorted(self.target_t_s, t_s, side='right') - 1
        return np.where(idx >= 0, self.target_rad[np.clip(idx, 0, None)], 0.0)

    def pulse_width_at(self, muscle: str, t_s: np.ndarray) -> np.ndarray:
        """[s] the muscle's pulse width in force at ``t_s`` (zero-order hold, 0 before)."""
        times, widths = self.pulse_width[muscle]
        idx = np.searchsorted(times, t_s, side='right') - 1
        return np.where(idx >= 0, widths[np.clip(idx, 0, None)], 0.0)


def read_run(bag_dir: Path, t0_ns: int, namespace: str, muscles: Sequence[str]) -> KneeRun:
    """The run from the bag (:func:`~hill_muscle_ros.recording.reader.read_bag`)."""
    from .recording.reader import read_bag

    ns = namespace.rstrip('/')
    # Only what is plotted: the 1 kHz force and wrench streams would double the time.
    data = read_bag(bag_dir, [f'{ns}/joint_states', f'{ns}/angle_target',
                              *(f'{ns}/{m}/pulse_width' for m in muscles)])
    joint = data.topic(f'{ns}/joint_states')
    stamps_ns = joint.stamps_ns()

    def on_limb_time(log_time_ns: np.ndarray) -> np.ndarray:
        return (np.interp(log_time_ns, joint.log_time_ns, stamps_ns) - t0_ns) / NS_PER_S

    target = data.topic(f'{ns}/angle_target')
    widths = {}
    for m in muscles:
        pw = data.topic(f'{ns}/{m}/pulse_width')
        widths[m] = (on_limb_time(pw.log_time_ns), pw.values())
    return KneeRun((stamps_ns - t0_ns) / NS_PER_S, joint.values(),
                   on_limb_time(target.log_time_ns), target.values(), widths)


def summarize(run_: KneeRun, profile: KneeProfile) -> dict[str, Any]:
    """Tracking error per segment and at the end of each hold; largest pulse widths.

    :return: ``rms_deg`` (label to [deg]), ``end_error_deg`` (held angle to
        [deg], angle minus target averaged over the hold's last
        :data:`END_OF_HOLD_S`), ``max_pulse_width_us`` (muscle to [us], during
        the profile)
    """
    error_deg = (run_.theta_rad - run_.target_at(run_.t_s)) * DEG_PER_RAD
    rms, end = {}, {}
    for label, start, stop in profile.segments():
        inside = (run_.t_s >= start) & (run_.t_s < stop)
        rms[label] = float(np.sqrt(np.mean(error_deg[inside] ** 2)))
    for k, angle in enumerate(profile.steps_deg):
        stop = (k + 1) * profile.hold_s
        window = (run_.t_s >= stop - END_OF_HOLD_S) & (run_.t_s < stop)
        end[angle] = float(np.mean(error_deg[window]))
    peak = {}
    for m, (times, widths) in run_.pulse_width.items():
        during = (times >= 0.0) & (times <= profile.duration_s)
        peak[m] = float(widths[during].max() * US_PER_S) if during.any() else 0.0
    return {'rms_deg': rms, 'end_error_deg': end, 'max_pulse_width_us': peak}


def plot(run_: KneeRun, profile: KneeProfile, png: Path) -> None:
    """Target and angle [deg] (top), each muscle's pulse width [us] (bottom)."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    fig, (ax_a, ax_pw) = plt.subplots(2, 1, sharex=True, figsize=(9, 6),
                                      gridspec_kw={'height_ratios': [2, 1]})
    ax_a.step(run_.target_t_s, run_.target_rad * DEG_PER_RAD, where='post', color='0.4',
              lw=2, label='target θ* [deg]')
    ax_a.plot(run_.t_s, run_.theta_rad * DEG_PER_RAD, color='tab:red', lw=1,
              label='knee angle θ [deg]')
    ax_a.set_ylabel('angle from hanging [deg]')
    ax_a.set_title(f'{profile.name} profile: joint controller on the simulated knee')
    ax_a.legend(loc='upper left')
    for k, (m, (times, widths)) in enumerate(run_.pulse_width.items()):
        ax_pw.step(times, widths * US_PER_S, where='post', color=f'C{k}', lw=1, label=m)
    ax_pw.set_ylabel('pulse width [µs]')
    ax_pw.set_xlabel('time [s] (the limb\'s simulated time from the start of the profile)')
    ax_pw.legend(loc='upper left')
    for ax in (ax_a, ax_pw):
        ax.grid(alpha=0.3)
    ax_pw.set_xlim(0.0, profile.duration_s + TAIL_S)
    fig.tight_layout()
    png.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(png, dpi=120)
    plt.close(fig)


def animate(run_: KneeRun, plant: LimbPlant, profile: KneeProfile, gif: Path,
            fps: float = GIF_FPS) -> int:
    """The stick-figure GIF (:func:`hill_muscle_ros.animation.write_gif`) of the run.

    Each muscle is coloured by the recruitment its recorded pulse width asks
    for (the muscle's recruitment curve), without the activation dynamics.

    :param fps: [frames/s] frames per second of simulated time
    :return: the number of frames
    """
    from .animation import write_gif   # matplotlib only here

    keep = (run_.t_s >= 0.0) & (run_.t_s <= profile.duration_s)
    t_s = run_.t_s[keep]
    columns = {'theta_rad': run_.theta_rad[keep]}
    for m in plant.muscles:
        widths = run_.pulse_width_at(m.name, t_s)
        columns[f'{m.name}_recruitment'] = np.array(
            [command_from_pulse_width(w, m.params) for w in widths])
    return write_gif(gif, plant, LimbResult(t_s, columns), fps=fps)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog='demo-knee', description='Run an angle profile through the joint controller, the '
        'limb node (config/knee.yaml) and the recorder; write the bag, a plot and a GIF.')
    parser.add_argument('--profile', choices=sorted(PROFILES), default='full',
                        help='full (default): steps held 3 s and two sine periods, '
                             f'{PROFILES["full"].duration_s:g} s; short: '
                             f'{PROFILES["short"].duration_s:g} s and brief: '
                             f'{PROFILES["brief"].duration_s:g} s, for the tests')
    parser.add_argument('--namespace', default=DEFAULT_NAMESPACE,
                        help=f'namespace of the nodes (default {DEFAULT_NAMESPACE})')
    parser.add_argument('--out', type=Path, default=None,
                        help='output directory, must not exist or be empty '
                             '(default: runs/knee_<UTC timestamp>)')
    parser.add_argument('--gif-fps', type=_positive_float, default=GIF_FPS, metavar='FPS',
                        help=f'frames of knee.gif per second of simulated time (default '
                             f'{GIF_FPS:g}); each frame costs ~35 ms of CPU to render, and '
                             f'the tests ask for 1')
    return parser


def _positive_float(text: str) -> float:
    value = float(text)
    if not (math.isfinite(value) and value > 0.0):
        raise argparse.ArgumentTypeError(f'must be a positive number, got {text!r}')
    return value


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    profile = PROFILES[args.profile]
    out = args.out or Path('runs') / _dt.datetime.now(_dt.timezone.utc).strftime(
        'knee_%Y-%m-%dT%H-%M-%SZ')
    os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')

    stops = StopSignals()   # Ctrl-C, SIGTERM, SIGHUP: the same clean-up
    started = time.monotonic()
    try:
        plant, _ = load_plant(plant_file())
        if out.exists() and any(out.iterdir()):
            raise ValueError(f'{out}: exists and is not empty; choose another --out')
        out.mkdir(parents=True, exist_ok=True)
        load_compiled_limb()
        bag, t0_ns = run(profile, plant, out, args.namespace)
        recorded = read_run(bag, t0_ns, args.namespace, [m.name for m in plant.muscles])
        summary = summarize(recorded, profile)
        png, gif = out / 'knee.png', out / 'knee.gif'
        plot(recorded, profile, png)
        frames = animate(recorded, plant, profile, gif, args.gif_fps)
    except (KeyboardInterrupt, ValueError, RuntimeError) as err:
        if isinstance(err, KeyboardInterrupt) or stops.received is not None:
            print(f'interrupted: every node stopped, the bag so far closed in {out / "bag"}',
                  file=sys.stderr)
            return EXIT_INTERRUPTED
        print(f'demo-knee: error: {err}', file=sys.stderr)
        return EXIT_ERROR
    print('tracking error (angle - target), RMS per segment:')
    for label, rms in summary['rms_deg'].items():
        print(f'  {label:24s} {rms:6.2f} deg')
    print('  at the end of each hold: ' + ', '.join(
        f'{a:g} deg {e:+.2f}' for a, e in summary['end_error_deg'].items()) + ' deg')
    print('largest pulse width: ' + ', '.join(
        f'{m} {w:.0f} µs' for m, w in summary['max_pulse_width_us'].items()))
    print(f'bag:  {bag}\nplot: {png}\ngif:  {gif} ({frames} frames)\n'
          f'({time.monotonic() - started:.1f} s)')
    return 0


if __name__ == '__main__':
    sys.exit(main())
