"""Telling an external stall (the machine) from a fault of the product.

On a shared 2-core machine any process can go unscheduled for tens or
hundreds of milliseconds, and no timing claim of a 1 kHz loop survives that.
A test may repeat a run for that reason only, and only when it has measured
it: :class:`StallWatcher` is a separate process that does nothing but sleep
for :data:`WATCH_PERIOD_S` at a time and log every wake-up that came more
than a threshold late. Such a late wake-up means the machine did not run a
ready process for that long, whatever the nodes under test were doing: a
node that stalls by itself (a blocking call, a busy loop) leaves the watcher
on time, since the other core is free for it.

:func:`repeat_only_on_external_stall` runs a measurement and checks it; a
failed check is repeated only if the watcher logged a stall inside that run,
and the stall is printed. A failure without one fails at once.
"""
from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path
from typing import Any, Callable

#: [s] the watcher's sleep: short against the stalls it has to see.
WATCH_PERIOD_S = 0.001
#: [s] a wake-up this late counts as an external stall: five of the
#: simulator's 1 kHz steps, a tenth of the simulator's catch-up window, and
#: far above the few-ms scheduling jitter of an idle 2-core machine.
DEFAULT_STALL_S = 0.05
#: Runs in all, at most, when each failed one had a measured external stall.
DEFAULT_ATTEMPTS = 3
#: Characters of a measurement quoted in a failure message.
QUOTE_CHARS = 600
#: [s] how long the watcher may take to start.
START_TIMEOUT_S = 30.0

_WATCHER = r'''
import sys, time
threshold_ns, period_s, path = int(sys.argv[1]), float(sys.argv[2]), sys.argv[3]
with open(path, 'a', buffering=1) as out:
    out.write('ready\n')
    last = time.monotonic_ns()
    while True:
        time.sleep(period_s)
        now = time.monotonic_ns()
        if now - last > threshold_ns:
            out.write(f'{last} {now}\n')
        last = now
'''


class StallWatcher:
    """A process that logs when the machine left it unscheduled (a context manager).

    :param log_path: file the watcher appends its stalls to
    :param stall_s: [s] a wake-up later than this (beyond the sleep) is logged
    """

    def __init__(self, log_path: Path, stall_s: float = DEFAULT_STALL_S) -> None:
        self.log_path = Path(log_path)
        self.stall_s = stall_s
        self._popen: subprocess.Popen | None = None

    def __enter__(self) -> 'StallWatcher':
        self.log_path.write_text('')
        threshold_ns = round((self.stall_s + WATCH_PERIOD_S) * 1e9)
        self._popen = subprocess.Popen(
            [sys.executable, '-c', _WATCHER, str(threshold_ns), repr(WATCH_PERIOD_S),
             str(self.log_path)], start_new_session=True)
        deadline = time.monotonic() + START_TIMEOUT_S
        while not self.log_path.read_text().startswith('ready'):
            if self._popen.poll() is not None or time.monotonic() > deadline:
                raise RuntimeError(f'the stall watcher did not start '
                                   f'(exit status {self._popen.returncode})')
            time.sleep(WATCH_PERIOD_S)
        return self

    def __exit__(self, *_exc: Any) -> None:
        if self._popen is not None:
            self._popen.kill()
            self._popen.wait()

    @property
    def pid(self) -> int:
        """The watcher's process id."""
        return self._popen.pid

    def stalls(self, from_s: float, to_s: float) -> list[tuple[float, float]]:
        """Stalls that overlap ``[from_s, to_s]`` of ``time.monotonic()``.

        :return: ``(start_s, duration_s)`` of each, in ``time.monotonic()`` seconds
        """
        found = []
        for line in self.log_path.read_text().splitlines()[1:]:
            start_s, end_s = (int(v) / 1e9 for v in line.split())
            if end_s >= from_s and start_s <= to_s:
                found.append((start_s, end_s - start_s))
        return found


def repeat_only_on_external_stall(run: Callable[[], Any], check: Callable[[Any], str | None],
                                  watcher: StallWatcher,
                                  attempts: int = DEFAULT_ATTEMPTS) -> Any:
    """Run ``run()`` and ``check`` its result; repeat only after a measured external stall.

    :param run: makes one measurement and returns it
    :param check: returns ``None`` if the measurement passes, else what failed
    :param watcher: the running :class:`StallWatcher`
    :param attempts: runs in all, at most
    :return: the first passing measurement
    :raises AssertionError: on a failure without an external stall, or when
        every run failed with one
    """
    tried = []
    for attempt in range(1, attempts + 1):
        start_s = time.monotonic()
        result = run()
        failure = check(result)
        if failure is None:
            return result
        stalls = watcher.stalls(start_s, time.monotonic())
        if not stalls:
            raise AssertionError(f'{failure}, with no external stall longer than '
                                 f'{watcher.stall_s * 1e3:.0f} ms measured during the run: '
                                 f'{str(result)[:QUOTE_CHARS]}')
        longest_ms = max(d for _, d in stalls) * 1e3
        print(f'\nREPEATED run {attempt} of {attempts}: {failure}; the machine left the stall '
              f'watcher unscheduled {len(stalls)} time(s), longest {longest_ms:.0f} ms')
        tried.append((failure, longest_ms))
    raise AssertionError(f'all {attempts} runs failed, each with an external stall measured '
                         f'(failure, longest stall in ms): {tried}')
