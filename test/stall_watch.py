"""Telling an external stall (the machine) from a fault of the product.

On a shared 2-core machine any process can be kept from a CPU for tens or
hundreds of milliseconds, and no timing claim of a 1 kHz loop survives that.
A test may repeat a run for that reason only, and only when it has measured
it. :class:`StallWatcher` measures it with the kernel's own account: a
thread in the test process reads, every :data:`SAMPLE_S`, the scheduler
statistics of the main thread of the test process and of every process it
started (``/proc/<pid>/schedstat``: time on a CPU, and time **ready to run
but waiting for a CPU**). A window in which a process's main thread waited
that way for :data:`DEFAULT_STALL_S` or more is an external stall: the
machine, not the process, held it up. A node that stalls by itself (blocked
on a lock, asleep in a call, a slow callback) does not wait for a CPU, so it
never counts. The kernel keeps counting while the sampler itself is held up,
so a late sample loses no stall time, only resolution.

:func:`repeat_only_on_external_stall` runs a measurement and checks it; a
failed check is repeated only if the watcher saw such a stall inside that
run, and the stall is printed. A failure without one fails at once.
"""
from __future__ import annotations

import os
import threading
import time
import warnings
from collections import deque
from typing import Any, Callable

#: [s] how often the schedulers' counters are read.
SAMPLE_S = 0.005
#: [s] how often the list of processes started by the test is refreshed.
REFRESH_S = 0.2
#: [s] waiting for a CPU this long within one :data:`WINDOW_FACTOR` x window
#: counts as an external stall: five of the simulator's 1 kHz steps, half a
#: control period of the 100 Hz controller, far above the few ms of
#: scheduling jitter of a busy 2-core machine.
DEFAULT_STALL_S = 0.05
#: The window is this many times the stall: waiting for half of it or more
#: means the machine, not the process, set the pace.
WINDOW_FACTOR = 2.0
#: Runs in all, at most, when each failed one had a measured external stall.
DEFAULT_ATTEMPTS = 3
#: Characters of a measurement quoted in a failure message.
QUOTE_CHARS = 600
#: [s] samples older than this are dropped (longer than any measured run).
HISTORY_S = 600.0


def _read_stat(pid: str) -> tuple[int, str] | None:
    """(parent pid, name) of a process from ``/proc/<pid>/stat``, or None if gone."""
    try:
        with open(f'/proc/{pid}/stat', 'rb') as f:
            stat = f.read().decode(errors='replace')
    except OSError:
        return None
    # "pid (comm) state ppid ...": comm may hold spaces and parentheses.
    return (int(stat[stat.rindex(')') + 2:].split()[1]),
            stat[stat.index('(') + 1:stat.rindex(')')])


def _descendants(root: int, known: dict[int, tuple[int, str]] | None = None) -> dict[int, str]:
    """Process ids and names of every process below ``root`` (from /proc).

    :param known: pid -> (parent pid, name) from the last call, updated in
        place: a process outside the last tree is not read again (its parent
        cannot become one of ours), which made the refresh a few reads
        instead of one per process on the machine. One inside is, as an
        ``exec`` renames it.
    """
    known = {} if known is None else known
    last_tree = _tree(root, known)
    present = set()
    for entry in os.scandir('/proc'):
        if not entry.name.isdigit():
            continue
        pid = int(entry.name)
        present.add(pid)
        if pid in known and pid not in last_tree:
            continue
        parent_and_name = _read_stat(entry.name)
        if parent_and_name is None:
            present.discard(pid)   # gone meanwhile
            known.pop(pid, None)
        else:
            known[pid] = parent_and_name
    for pid in known.keys() - present:
        del known[pid]
    return _tree(root, known)


def _tree(root: int, known: dict[int, tuple[int, str]]) -> dict[int, str]:
    """The processes below ``root`` in ``known`` (pid -> (parent pid, name))."""
    children: dict[int, list[int]] = {}
    for pid, (ppid, _) in known.items():
        children.setdefault(ppid, []).append(pid)
    found, todo = {}, list(children.get(root, []))
    while todo:
        pid = todo.pop()
        found[pid] = known[pid][1]
        todo += children.get(pid, [])
    return found


def _open_schedstat(pid: int) -> int | None:
    """A descriptor of ``/proc/<pid>/schedstat``, or None if the process is gone.

    Kept open and re-read with ``pread``: an open and a close per sample was
    ten times the cost of the read, most of the watcher's 5 % of a core."""
    try:
        return os.open(f'/proc/{pid}/schedstat', os.O_RDONLY)
    except OSError:
        return None


def _wait_ns(fd: int) -> int | None:
    """[ns] time the main thread has waited for a CPU (from its open
    ``schedstat``), or None if the process is gone."""
    try:
        return int(os.pread(fd, 256, 0).split()[1])
    except (OSError, IndexError, ValueError):
        return None


class StallWatcher:
    """Samples the CPU waiting time of this process and its descendants (a context manager).

    :param stall_s: [s] waiting for a CPU this long within ``WINDOW_FACTOR x
        stall_s`` is an external stall
    """

    def __init__(self, stall_s: float = DEFAULT_STALL_S) -> None:
        self.stall_s = stall_s
        self._root = os.getpid()
        #: per process: deque of (monotonic s, cumulative wait ns)
        self._samples: dict[tuple[int, str], deque[tuple[float, int]]] = {}
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name='stall_watch', daemon=True)

    def __enter__(self) -> 'StallWatcher':
        self._thread.start()
        return self

    def __exit__(self, *_exc: Any) -> None:
        self._stop.set()
        self._thread.join()

    def _run(self) -> None:
        #: (pid, name) -> open schedstat descriptor (None: the process is gone)
        fds: dict[tuple[int, str], int | None] = {}
        known: dict[int, tuple[int, str]] = {}
        next_refresh = 0.0
        try:
            while not self._stop.wait(SAMPLE_S):
                now = time.monotonic()
                if now >= next_refresh:
                    watched = {(self._root, 'pytest')} | set(_descendants(self._root, known).items())
                    for key in fds.keys() - watched:
                        if fds[key] is not None:
                            os.close(fds[key])
                        del fds[key]
                    for key in watched - fds.keys():
                        fds[key] = _open_schedstat(key[0])
                    next_refresh = now + REFRESH_S
                with self._lock:
                    for key, fd in fds.items():
                        wait_ns = None if fd is None else _wait_ns(fd)
                        if wait_ns is None:
                            continue
                        samples = self._samples.setdefault(key, deque())
                        samples.append((now, wait_ns))
                        while samples and samples[0][0] < now - HISTORY_S:
                            samples.popleft()
        finally:
            for fd in fds.values():
                if fd is not None:
                    os.close(fd)

    def stalls(self, from_s: float, to_s: float) -> list[tuple[str, float, float]]:
        """External stalls that overlap ``[from_s, to_s]`` of ``time.monotonic()``.

        :return: ``(process, start_s, waited_s, span_s)`` of the worst window of
            each process that waited for a CPU ``stall_s`` or more within
            ``WINDOW_FACTOR x stall_s`` (``span_s``: the window, longer when the
            sampler itself was held up)
        """
        window_s = WINDOW_FACTOR * self.stall_s
        found = []
        with self._lock:
            series = {key: list(samples) for key, samples in self._samples.items()}
        for (pid, name), samples in series.items():
            samples = [s for s in samples if from_s - window_s <= s[0] <= to_s + window_s]
            worst, worst_at, worst_span, j = 0.0, 0.0, 0.0, 0
            for i in range(1, len(samples)):
                # The earliest sample j with samples[i] - samples[j] within the window
                # (a single long interval counts whole: the sampler itself was held up).
                while j < i - 1 and samples[i][0] - samples[j][0] > window_s:
                    j += 1
                waited_s = (samples[i][1] - samples[j][1]) / 1e9
                if waited_s > worst:
                    worst, worst_at = waited_s, samples[j][0]
                    worst_span = samples[i][0] - samples[j][0]
            if worst >= self.stall_s:
                found.append((f'{name}[{pid}]', worst_at, worst, worst_span))
        return found


class RepeatedOnStall(UserWarning):
    """A timing test repeated a run after a measured external stall. A
    warning, so that pytest's warnings summary names every repeat with its
    test and cause, and the run's last line counts them (conftest), rather
    than a line in a passing test's captured output that nobody sees."""


def report_repeat(message: str) -> None:
    """Print ``message`` (a repeated run and its measured cause) and warn
    with it as :class:`RepeatedOnStall`."""
    print(f'\n{message}')
    warnings.warn(message, RepeatedOnStall, stacklevel=2)


def repeat_only_on_external_stall(run: Callable[[], Any], check: Callable[[Any], str | None],
                                  watcher: StallWatcher,
                                  attempts: int = DEFAULT_ATTEMPTS,
                                  report: Callable[[Any], None] | None = None) -> Any:
    """Run ``run()`` and ``check`` its result; repeat only after a measured external stall.

    :param run: makes one measurement and returns it
    :param check: returns ``None`` if the measurement passes, else what failed
    :param watcher: the running :class:`StallWatcher`
    :param attempts: runs in all, at most
    :param report: called with each measurement, before it is judged (the
        real-time table's row: conftest's ``realtime_claim``)
    :return: the first passing measurement
    :raises AssertionError: on a failure without an external stall
    :raises pytest.skip.Exception: when every run failed, each with a measured
        external stall: the machine, not the product, is then what was measured
    """
    tried = []
    for attempt in range(1, attempts + 1):
        start_s = time.monotonic()
        result = run()
        if report is not None:
            report(result)
        failure = check(result)
        if failure is None:
            return result
        stalls = watcher.stalls(start_s, time.monotonic())
        if not stalls:
            raise AssertionError(f'{failure}, and no process of the test waited '
                                 f'{watcher.stall_s * 1e3:.0f} ms for a CPU within '
                                 f'{WINDOW_FACTOR * watcher.stall_s * 1e3:.0f} ms during the '
                                 f'run: {str(result)[:QUOTE_CHARS]}')
        worst = max(stalls, key=lambda s: s[2])
        report_repeat(f'REPEATED run {attempt} of {attempts}: {failure}; the machine kept '
                      f'{len(stalls)} process(es) of the test from a CPU, worst {worst[0]} '
                      f'waiting {worst[2] * 1e3:.0f} ms within {worst[3] * 1e3:.0f} ms')
        tried.append((failure, worst[0], round(worst[2] * 1e3)))
    import pytest   # only here: the watcher itself is plain Python
    pytest.skip(f'not judged: all {attempts} runs failed, each with an external stall '
                f'measured (failure, process, ms waiting for a CPU): {tried}')
