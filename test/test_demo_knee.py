"""``make demo-knee``: the knee demo end to end (brief and short profiles), and interrupted.

The demo runs once per profile (module fixtures); its bag is read back with
rosbags' AnyReader, a reader independent of the package's own. What must hold:
exit 0; every promised topic in the bag with messages; a PNG and a GIF; no
process left running, also after a SIGINT in mid-run, when the bag is still
closed; all on the ``brief`` profile (2.75 s), whose holds are too short to
settle. The knee angle near each held target at the end of its hold is a
claim on the live loop's timing (``make check-realtime``), on the ``short``
profile's 2 s holds.

The run asks for a GIF of :data:`TEST_GIF_FPS` (``--gif-fps``): its frames
were 3.2 of the demo process's 7.8 CPU-s at the default 10 frames/s. That
``make demo-knee`` renders at the default is checked here (its command line,
the parser's default); ``write_gif`` at 10 frames/s is test_limb_cli's.
"""
from __future__ import annotations

import math
import os
import re
import signal
import subprocess
import sys
import time

from pathlib import Path

import numpy as np
import pytest
from PIL import Image
from rosbags.highlevel import AnyReader

from hill_muscle_ros.demo_knee import GIF_FPS, PROFILES, build_parser, plant_file
from hill_muscle_ros.params_file import load_plant
from ros_helpers import ros_env, start_in_background

pytestmark = [pytest.mark.ros, pytest.mark.slow]

REPO = Path(__file__).resolve().parents[1]

#: [s] deadline for a demo run (start-up of three nodes on a loaded machine,
#: the 8.5 s profile, the plot and the GIF); measured ~25 s on an idle machine.
RUN_TIMEOUT_S = 150.0
#: [s] for the demo to clean up after a signal (SIGINT, then SIGKILL, per node).
CLEANUP_TIMEOUT_S = 60.0
#: [s] the end of a hold over which the angle is checked.
END_OF_HOLD_S = 0.1
#: [deg] how close the angle must be to a held target at the end of its hold.
#: Offline, the same controller and plant (simulate_joint_control, the short
#: profile's 2 s holds) end every hold within 0.5 deg of the target with 0 to
#: 20 ms of feedback delay. Live, the knee on this machine ended the 45 and 30
#: deg holds within 0.3 deg; at 20 deg the loop is close to its delay margin
#: (offline: a sustained ±1.3 deg at 20 ms, ±7 deg at 30 ms). 3 deg leaves room
#: for the ripple and a few ms of extra delay, and fails on that oscillation.
ANGLE_TOLERANCE_DEG = 3.0
#: [frames/s] the module runs' GIF: 9 frames of the 8.5 s short profile (~0.4
#: CPU-s to render) where the default 10 frames/s renders 86 (~3.2 CPU-s).
TEST_GIF_FPS = 1.0
#: The profile of the runs that check what the demo writes (every node, topic,
#: plot and GIF in 2.75 s), and that of the settling claim (2 s holds).
BRIEF, SHORT = PROFILES['brief'], PROFILES['short']
PNG_MAGIC = b'\x89PNG\r\n\x1a\n'
GIF_MAGICS = (b'GIF87a', b'GIF89a')


def processes_in(ns: str) -> list[tuple[int, str]]:
    """(pid, command line) of running processes started in namespace ``ns``."""
    found = []
    for pid in os.listdir('/proc'):
        if pid.isdigit():
            try:
                cmdline = open(f'/proc/{pid}/cmdline', 'rb').read().replace(b'\0', b' ').decode()
            except OSError:
                continue
            if f'__ns:={ns} ' in cmdline + ' ':
                found.append((int(pid), cmdline))
    return found


def demo_command(out, ns: str, profile: str, *options: str) -> list[str]:
    return [sys.executable, '-m', 'hill_muscle_ros.demo_knee', '--profile', profile,
            '--out', str(out), '--namespace', ns, *options]


def read_topics(bag_dir) -> dict[str, list[tuple[int, object]]]:
    """Topic name -> [(receive time [ns], decoded message)], with rosbags."""
    topics: dict[str, list[tuple[int, object]]] = {}
    with AnyReader([bag_dir]) as reader:
        for conn, timestamp, raw in reader.messages():
            topics.setdefault(conn.topic, []).append(
                (timestamp, reader.deserialize(raw, conn.msgtype)))
    return topics


def start_demo(tmp_path_factory, profile):
    """Start the demo on ``profile`` and return a call that waits for it:
    (process result, output dir, namespace, wall time [s])."""
    out = tmp_path_factory.mktemp(f'demo_knee_{profile.name}') / 'out'
    ns = f'/kneedemo_{profile.name}_{os.getpid()}'
    started = time.monotonic()
    run = start_in_background(
        demo_command(out, ns, profile.name, '--gif-fps', f'{TEST_GIF_FPS:g}'), out.parent,
        RUN_TIMEOUT_S)
    return lambda: (run(), out, ns, time.monotonic() - started)


def topics_of(run):
    done, out, _, _ = run
    assert done.returncode == 0, done.stdout + done.stderr
    return read_topics(out / 'bag')


@pytest.fixture(scope='module')
def started_run(tmp_path_factory):
    """The brief profile, started once: it runs beside the module's first test
    (the interrupted run), whose nodes are in a namespace of their own. Waited
    for at the module's end if no test did, so that it never outlives it."""
    finished = start_demo(tmp_path_factory, BRIEF)
    yield finished
    finished()


@pytest.fixture(scope='module')
def run(started_run):
    """The brief profile's run, once it has ended."""
    return started_run()


@pytest.fixture(scope='module')
def topics(run):
    return topics_of(run)


@pytest.fixture(scope='module')
def settling_run(tmp_path_factory):
    """The short profile, once (2 s holds: the settling claim)."""
    return start_demo(tmp_path_factory, SHORT)()


def test_sigint_stops_every_node_and_closes_the_bag(tmp_path, started_run):
    """First in the module: the brief run (``started_run``) goes on meanwhile."""
    ns = f'/kneedemo_int_{os.getpid()}'
    out = tmp_path / 'out'
    log_path = tmp_path / 'demo.log'
    with open(log_path, 'wb') as log:
        proc = subprocess.Popen(demo_command(out, ns, 'full'), stdout=log,
                                stderr=subprocess.STDOUT, env=ros_env())
        try:
            deadline = time.monotonic() + RUN_TIMEOUT_S
            while b'profile:' not in log_path.read_bytes():
                assert proc.poll() is None and time.monotonic() < deadline, \
                    log_path.read_text()
                time.sleep(0.1)
            assert len(processes_in(ns)) == 3
            proc.send_signal(signal.SIGINT)
            status = proc.wait(timeout=CLEANUP_TIMEOUT_S)
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait()
            left = processes_in(ns)
            for pid, _ in left:  # this test's own nodes (unique namespace): never leak them
                os.kill(pid, signal.SIGKILL)
    assert status == 130, log_path.read_text()
    assert left == []
    # Closed: metadata.yaml is written at the close, and the bag reads back.
    assert (out / 'bag' / 'metadata.yaml').exists()
    assert len(read_topics(out / 'bag').get(f'{ns}/joint_states', [])) > 0


def test_demo_exits_zero_and_says_where_the_files_are(run):
    done, out, _, _ = run
    assert done.returncode == 0, done.stdout + done.stderr
    for name in ('bag', 'knee.png', 'knee.gif'):
        assert str(out / name) in done.stdout


def test_bag_holds_every_promised_topic_with_messages(run, topics):
    _, _, ns, _ = run
    plant, _ = load_plant(plant_file())
    promised = [f'{ns}/joint_states', f'{ns}/angle_target', '/diagnostics']
    for m in plant.muscles:
        promised += [f'{ns}/{m.name}/{t}' for t in ('pulse_width', 'force', 'wrench')]
    assert {m.name for m in plant.muscles} == {'quadriceps', 'hamstrings'}
    assert {t: len(topics.get(t, [])) > 0 for t in promised} == {t: True for t in promised}


def test_plot_and_gif_are_written(run):
    done, out, _, _ = run
    assert (out / 'knee.png').read_bytes()[:8] == PNG_MAGIC
    assert (out / 'knee.gif').read_bytes()[:6] in GIF_MAGICS
    # One frame per 1 / fps of the profile's simulated time, from 0, as printed.
    with Image.open(out / 'knee.gif') as gif:
        frames = gif.n_frames
    printed = int(re.search(r'knee\.gif \((\d+) frames\)', done.stdout).group(1))
    assert frames == printed == math.floor(BRIEF.duration_s * TEST_GIF_FPS) + 1


def test_make_demo_knee_renders_the_gif_at_the_default_frame_rate():
    """The user's GIF is the default's: ``make demo-knee`` passes no --gif-fps
    (``make -n``: printed, not run), and the default is GIF_FPS (10 frames/s)."""
    proc = subprocess.run(['make', '-n', '--no-print-directory', 'demo-knee'], cwd=REPO,
                          capture_output=True, text=True, check=True)
    command = next(line for line in proc.stdout.splitlines()
                   if '-m hill_muscle_ros.demo_knee' in line)
    assert '--gif-fps' not in command
    assert build_parser().parse_args([]).gif_fps == GIF_FPS == 10.0


@pytest.mark.realtime
def test_angle_is_near_each_held_target_at_the_end_of_its_hold(settling_run, realtime_claim):
    _, _, ns, _ = settling_run
    topics = topics_of(settling_run)
    target = topics[f'{ns}/angle_target']
    t_target = np.array([t for t, _ in target])
    v_target = np.array([m.data for _, m in target])
    joint = topics[f'{ns}/joint_states']
    t_joint = np.array([t for t, _ in joint])
    angle_deg = np.degrees([m.position[0] for _, m in joint])
    # The held steps are the first runs of equal targets, in order.
    starts = np.flatnonzero(np.r_[True, np.diff(v_target) != 0.0])
    ends = np.r_[starts[1:], len(v_target)] - 1
    steps = SHORT.steps_deg
    assert np.degrees(v_target[starts[:len(steps)]]) == pytest.approx(steps, abs=1e-12)
    for k, want in enumerate(steps):
        # The joint states that reached the recorder in the hold's last
        # END_OF_HOLD_S, up to the last message of this target (same clock).
        end_ns = t_target[ends[k]]
        window = (t_joint > end_ns - END_OF_HOLD_S * 1e9) & (t_joint <= end_ns)
        assert window.sum() > 0, f'no joint state at the end of the {want:g} deg hold'
        worst = float(np.max(np.abs(angle_deg[window] - want)))
        realtime_claim(f'knee demo: angle at the end of the {want:g} deg hold',
                       f'{worst:.2f} deg off', f'<= {ANGLE_TOLERANCE_DEG:g} deg')
        assert worst <= ANGLE_TOLERANCE_DEG, (
            f'{want:g} deg hold: the angle was up to {worst:.2f} deg off in its last '
            f'{END_OF_HOLD_S:g} s ({angle_deg[window].min():.2f} to '
            f'{angle_deg[window].max():.2f} deg)')


def test_no_process_is_left_running(run):
    _, _, ns, _ = run
    assert processes_in(ns) == []
