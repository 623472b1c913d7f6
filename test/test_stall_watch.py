"""The stall watcher logs the time the machine (here: SIGSTOP) kept it from running."""
import os
import signal
import time

import pytest

from stall_watch import StallWatcher, repeat_only_on_external_stall

#: [s] how long the watcher is stopped: well above its threshold.
STOP_S = 0.2
STALL_S = 0.05


def test_a_stopped_watcher_logs_a_stall_of_at_least_the_stop_time(tmp_path):
    with StallWatcher(tmp_path / 'stalls.log', STALL_S) as watcher:
        start = time.monotonic()
        os.kill(watcher.pid, signal.SIGSTOP)
        time.sleep(STOP_S)  # the stimulus: the watcher is not scheduled for this long
        os.kill(watcher.pid, signal.SIGCONT)
        deadline = time.monotonic() + 30.0
        while not watcher.stalls(start, time.monotonic()) and time.monotonic() < deadline:
            time.sleep(0.01)
        stalls = watcher.stalls(start, time.monotonic())
    assert len(stalls) == 1
    assert stalls[0][1] >= STOP_S


def test_a_failed_run_without_an_external_stall_fails_at_once(tmp_path):
    runs = []
    with StallWatcher(tmp_path / 'stalls.log', STALL_S) as watcher:
        watcher.stalls = lambda *_: []  # a measured quiet machine
        with pytest.raises(AssertionError, match='no external stall'):
            repeat_only_on_external_stall(lambda: runs.append(1), lambda _: 'too slow', watcher)
    assert len(runs) == 1


def test_a_failed_run_with_an_external_stall_is_repeated(tmp_path):
    runs = []
    with StallWatcher(tmp_path / 'stalls.log', STALL_S) as watcher:
        watcher.stalls = lambda *_: [(0.0, 0.3)]
        result = repeat_only_on_external_stall(
            lambda: runs.append(1) or len(runs), lambda n: None if n == 2 else 'failed', watcher)
    assert (result, len(runs)) == (2, 2)
