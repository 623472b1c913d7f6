"""``make demo``, run by the tests: the helpers, and the run on sim time at
real_time_factor :data:`RTF` (``make demo RTF=10``) once per test run.

The sim-time run serves two modules (a pytest plugin of conftest, so that the
session fixture is one fixture): test_demo checks what the demo writes and
prints on it, test_demo_sim_time the sim-time run's clocks and stamps. It is
the same command, nodes and analysis as the real-time demo, through the same
`make` target, in 0.6 s of wall time instead of 6 s; whether the real-time
run keeps up with the wall clock is a real-time claim (test_demo's
``live_demo``, ``make check-realtime``).
"""
from __future__ import annotations

import os
import re
import subprocess
import time
import uuid
from pathlib import Path

import pytest

from stall_watch import repeat_only_on_external_stall

REPO = Path(__file__).resolve().parents[1]
#: [s] generous: `make` may first check the venv, and the box is shared.
DEMO_TIMEOUT_S = 300
#: The demo's verdict when live misses offline (hill_muscle_ros.demo): a
#: stalled node shifts the live run, so a run that fails on it is repeated
#: only when the stall watcher measured the machine holding a process up.
VERDICT_MARK = 'live force differs from the offline simulation'
#: Runs of one demo in all, at most (see VERDICT_MARK).
MAX_ATTEMPTS = 3
#: The sim-time run's real_time_factor.
RTF = 10.0
#: Added to the run's ROS_DOMAIN_ID for the sim-time demo's processes.
SIM_TIME_DOMAIN_OFFSET = 100


def demo_env(marker: str, **extra: str) -> dict:
    """This process's environment, with a marker every child inherits (to find
    any process the demo left behind) and ``extra``."""
    return {**os.environ, 'HILL_MUSCLE_DEMO_TEST_MARKER': marker, **extra}


def processes_with(marker: str) -> list[int]:
    """PIDs of live processes whose environment carries ``marker``."""
    found = []
    needle = f'HILL_MUSCLE_DEMO_TEST_MARKER={marker}'.encode()
    for entry in Path('/proc').iterdir():
        if not entry.name.isdigit():
            continue
        try:
            if needle in (entry / 'environ').read_bytes():
                status = (entry / 'stat').read_text().split()[2]
                if status != 'Z':
                    found.append(int(entry.name))
        except OSError:
            continue
    return found


def make_demo(runs_dir, *make_vars, marker=None, **env):
    """``make demo RUNS_DIR=runs_dir make_vars...``: (completed process, marker, wall [s])."""
    marker = marker or uuid.uuid4().hex
    start = time.monotonic()
    proc = subprocess.run(['make', '--no-print-directory', 'demo', f'RUNS_DIR={runs_dir}',
                           *make_vars], cwd=REPO, env=demo_env(marker, **env),
                          capture_output=True, text=True, timeout=DEMO_TIMEOUT_S)
    wall_s = time.monotonic() - start
    print(f'make demo {" ".join(make_vars)} took {wall_s:.1f} s')  # measured, not asserted
    return proc, marker, wall_s


def verdict_failure(run) -> str | None:
    """The demo's verdict line if it failed on it, else None (the tests judge the rest)."""
    proc = run[0]
    if proc.returncode != 0 and VERDICT_MARK in proc.stderr:
        return proc.stderr.strip().splitlines()[0]
    return None


def make_demo_judged(tmp_path_factory, stall_watcher, name, *make_vars, **env):
    """:func:`make_demo` in a new directory, repeated only on a measured stall:
    (completed process, marker, wall [s], runs directory)."""
    def one_run():
        tmp = tmp_path_factory.mktemp(name)
        return (*make_demo(tmp, *make_vars, **env), tmp)
    return repeat_only_on_external_stall(one_run, verdict_failure, stall_watcher,
                                         MAX_ATTEMPTS)


def bag_dir(proc) -> Path:
    """The bag directory the demo's summary names (its ``bag:`` line)."""
    return Path(re.search(r'^bag:\s+(\S+)', proc.stdout, re.M).group(1))


@pytest.fixture(scope='session')
def demo_at_rtf(tmp_path_factory, stall_watcher):
    """``make demo RTF=10`` (Protocol II, config/muscle.yaml, sim time), once:
    (completed process, marker, wall [s], runs directory). Its processes use a
    DDS domain of their own, derived from the one conftest locked for this run
    (1..100, so this is 101..200 and unique too): a /clock-driven run must
    leave nothing behind in the domain the later tests use."""
    domain = str(int(os.environ['ROS_DOMAIN_ID']) + SIM_TIME_DOMAIN_OFFSET)
    return make_demo_judged(tmp_path_factory, stall_watcher, 'demo_rtf', f'RTF={RTF:g}',
                            HILL_MUSCLE_DEMO_DOMAIN=domain)
