"""The stall watcher counts the time the machine kept a process ready but off
a CPU, and nothing a process does by itself."""
import os
import subprocess
import sys
import time

import pytest

from stall_watch import RepeatedOnStall, StallWatcher, repeat_only_on_external_stall

STALL_S = 0.05
#: [s] how long the probes below run.
RUN_S = 0.5
#: Busy processes sharing one CPU: each waits for it about 2/3 of the time.
CROWD = 3

BUSY = 'import time\nend = time.monotonic() + {run_s}\nwhile time.monotonic() < end: pass\n'


def test_processes_crowded_onto_one_cpu_are_an_external_stall():
    cpu = min(os.sched_getaffinity(0))
    with StallWatcher(STALL_S) as watcher:
        start = time.monotonic()
        procs = [subprocess.Popen([sys.executable, '-c', BUSY.format(run_s=RUN_S)])
                 for _ in range(CROWD)]
        for p in procs:
            os.sched_setaffinity(p.pid, {cpu})
        for p in procs:
            p.wait()
        time.sleep(0.05)  # one more sample after they end
        stalls = watcher.stalls(start, time.monotonic())
    crowded = {f'python3[{p.pid}]' for p in procs} | {f'python[{p.pid}]' for p in procs}
    assert any(who in crowded and waited >= STALL_S for who, _, waited, _ in stalls), stalls


def test_a_process_that_sleeps_by_itself_is_no_external_stall():
    sleep_s = 1.0
    with StallWatcher(STALL_S) as watcher:
        proc = subprocess.Popen(
            [sys.executable, '-c', f'import time; print("ready", flush=True); time.sleep({sleep_s})'],
            stdout=subprocess.PIPE, text=True)
        proc.stdout.readline()  # started: Python's own start-up needs a CPU, the sleep does not
        start = time.monotonic()
        proc.wait()
        # The sleep alone, clear of the start-up before it and the wake-up after it.
        stalls = watcher.stalls(start + 2 * STALL_S, start + sleep_s - 2 * STALL_S)
    assert not [s for s in stalls if s[0].endswith(f'[{proc.pid}]')], stalls


def test_a_failed_run_without_an_external_stall_fails_at_once():
    runs = []
    with StallWatcher(STALL_S) as watcher:
        watcher.stalls = lambda *_: []  # a measured quiet machine
        with pytest.raises(AssertionError, match='no process of the test waited'):
            repeat_only_on_external_stall(lambda: runs.append(1), lambda _: 'too slow', watcher)
    assert len(runs) == 1


def test_a_failed_run_with_an_external_stall_is_repeated():
    runs = []
    with StallWatcher(STALL_S) as watcher:
        watcher.stalls = lambda *_: [('simulator[1]', 0.0, 0.3, 0.1)]
        with pytest.warns(RepeatedOnStall, match=r'REPEATED run 1 of \d+: failed; .*'
                                                 r'simulator\[1\] waiting 300 ms'):
            result = repeat_only_on_external_stall(
                lambda: runs.append(1) or len(runs), lambda n: None if n == 2 else 'failed',
                watcher)
    assert (result, len(runs)) == (2, 2)
