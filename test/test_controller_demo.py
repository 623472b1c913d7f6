"""``make demo-closed-loop``: the closed-loop demo end to end, and interrupted.

A short profile keeps it quick. What must hold: it writes a bag that holds
every recorded topic and a PNG; it leaves no process running, also when it
is interrupted with SIGINT (Ctrl-C) or SIGTERM in mid-run. The whole run goes
on beside the interrupted one (the module's first test), each in a namespace
of its own.
"""
from __future__ import annotations

import itertools
import os
import signal
import subprocess
import sys
import time

import pytest
import yaml

from hill_muscle_ros.demo_closed_loop import RECORDED
from hill_muscle_ros.recording.reader import read_bag
from ros_helpers import ros_env, start_in_background

pytestmark = pytest.mark.ros

_RUNS = itertools.count()
#: [s] deadline for a demo run (start-up of four processes on a loaded machine).
RUN_TIMEOUT_S = 120.0
#: [s] for the demo to clean up after a signal (SIGINT, then SIGKILL, per node).
CLEANUP_TIMEOUT_S = 60.0
SHORT_PROFILE = {'name': 'short', 'duration_s': 1.5,
                 'force_target_n': [[0.0, 0.0], [0.3, 0.0], [0.3, 10.0]],
                 'dl_mt_m': [[0.0, 0.0], [1.0, 0.0], [1.5, 0.005]]}


def demo(tmp_path, duration_s: float = SHORT_PROFILE['duration_s']):
    ns = f'/cldemo_{os.getpid()}_{next(_RUNS)}'
    profile = tmp_path / 'profile.yaml'
    profile.write_text(yaml.safe_dump({**SHORT_PROFILE, 'duration_s': duration_s}))
    out = tmp_path / 'out'
    cmd = [sys.executable, '-m', 'hill_muscle_ros.demo_closed_loop', '--profile', str(profile),
           '--out', str(out), '--namespace', ns]
    return ns, out, cmd


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


@pytest.fixture(scope='module')
def started_run(tmp_path_factory):
    """The short profile, started with the module; a call that waits for it:
    (process result, namespace, output directory). Waited for at the
    module's end if no test did, so that it never outlives it."""
    tmp = tmp_path_factory.mktemp('closed_loop_demo')
    ns, out, cmd = demo(tmp)
    run = start_in_background(cmd, tmp, RUN_TIMEOUT_S)
    yield lambda: (run(), ns, out)
    run()


def test_interrupted_demo_leaves_no_process_running(tmp_path, started_run):
    """First in the module: the whole run (``started_run``) goes on meanwhile."""
    # SIGTERM, as a service manager stops a program. SIGINT and SIGHUP take the
    # same path (supervisor.StopSignals, each signal in test_stop_signals);
    # SIGINT end to end is test_demo's and test_demo_knee's.
    sig = signal.SIGTERM
    ns, out, cmd = demo(tmp_path, duration_s=60.0)
    log = open(tmp_path / 'demo.log', 'wb')
    proc = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, env=ros_env())
    try:
        deadline = time.monotonic() + RUN_TIMEOUT_S
        while b'through simulator' not in (tmp_path / 'demo.log').read_bytes():
            assert proc.poll() is None and time.monotonic() < deadline, \
                (tmp_path / 'demo.log').read_text()
            time.sleep(0.1)
        assert len(processes_in(ns)) == 3
        proc.send_signal(sig)
        status = proc.wait(timeout=CLEANUP_TIMEOUT_S)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        log.close()
        left = processes_in(ns)
        for pid, _ in left:  # this test's own nodes (unique namespace): never leak them
            os.kill(pid, signal.SIGKILL)
    assert status != 0
    assert left == []


def test_demo_writes_a_bag_with_every_topic_and_a_plot(started_run):
    done, ns, out = started_run()
    assert done.returncode == 0, done.stdout + done.stderr
    bag = read_bag(out / 'bag')
    assert bag.complete
    for topic in RECORDED:
        assert bag.topic(f'{ns}/{topic}').count > 0, topic
    assert (out / 'closed_loop.png').stat().st_size > 0
    assert processes_in(ns) == []
