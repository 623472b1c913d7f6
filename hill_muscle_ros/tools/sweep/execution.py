"""Running a sweep's tasks: in this process, or on a Dask cluster (a local one
started for the sweep, or an existing one given by its scheduler's address).

Dask is imported only by the functions that need it. Ctrl-C cancels the
unfinished tasks and keeps the finished ones; the log filters here drop the
two records our own cluster writes when it is closed on purpose.
"""
from __future__ import annotations

import contextlib
import logging
import os
import signal
import sys
import threading
import time
from dataclasses import dataclass
from typing import Callable

from .simulation import (MAX_AUTO_CHUNK, MAX_AUTO_LIMB_CHUNK, chunk_ranges, run_chunk,
                         run_limb_chunk)
from .spec import SweepError, SweepSpec

#: [s] how long to wait for an existing scheduler to answer.
CONNECT_TIMEOUT_S = 10.0
#: Width of the text progress bar, in characters.
PROGRESS_WIDTH = 30


def _chunk_task(spec: SweepSpec) -> Callable[..., dict]:
    """The task that simulates a chunk of the spec's sets."""
    return run_chunk if spec.plant is None else run_limb_chunk


def _max_chunk(spec: SweepSpec) -> int:
    return MAX_AUTO_CHUNK if spec.plant is None else MAX_AUTO_LIMB_CHUNK


class Progress:
    """A one-line text progress bar on a stream (no tqdm)."""

    def __init__(self, total_sets: int, stream=None) -> None:
        self.total = total_sets
        self.done = 0
        self.stream = sys.stderr if stream is None else stream
        self.start = time.perf_counter()

    def advance(self, n_sets: int) -> None:
        self.done += n_sets
        filled = PROGRESS_WIDTH * self.done // max(self.total, 1)
        elapsed = time.perf_counter() - self.start
        end = '\n' if self.done >= self.total else ''
        self.stream.write(f'\r[{"#" * filled}{"." * (PROGRESS_WIDTH - filled)}] '
                          f'{self.done}/{self.total} sets, {elapsed:.1f} s{end}')
        self.stream.flush()


@dataclass
class SweepResult:
    """What :func:`run_sweep` computed.

    :param results: the finished chunks (see :func:`run_chunk`)
    :param complete: False if the sweep was interrupted
    :param elapsed_s: [s] wall time of the simulation, cluster start-up excluded
    """

    results: list
    complete: bool
    elapsed_s: float

    @property
    def n_sets(self) -> int:
        return sum(len(r['set_ids']) for r in self.results)


def run_local(spec: SweepSpec, chunk: int | None = None,
              on_chunk: Callable[[int], None] | None = None) -> SweepResult:
    """Run every chunk in this process, without Dask (a reference and a fallback)."""
    results = []
    task = _chunk_task(spec)
    start = time.perf_counter()
    try:
        for ids in chunk_ranges(len(spec.sets), 0, chunk, _max_chunk(spec)):
            results.append(task(list(ids), [spec.sets[i] for i in ids], spec.protocol,
                                spec.rate_hz, spec.sample_indices))
            if on_chunk:
                on_chunk(len(ids))
    except KeyboardInterrupt:
        return SweepResult(results, False, time.perf_counter() - start)
    return SweepResult(results, True, time.perf_counter() - start)


def run_on_client(spec: SweepSpec, client, chunk: int | None = None,
                  on_chunk: Callable[[int], None] | None = None) -> SweepResult:
    """Run the chunks as tasks on a Dask client's cluster.

    On Ctrl-C the unfinished tasks are cancelled and the finished ones kept.
    """
    from distributed import as_completed

    n_workers = max(len(client.scheduler_info(n_workers=-1)['workers']), 1)
    start = time.perf_counter()
    # The protocol goes to every worker once rather than with each task. A key
    # of its own (hash=False): a content-hashed key is shared with an earlier
    # sweep's copy, which the scheduler may be releasing just then, and the
    # tasks that need it would be cancelled.
    [protocol] = client.scatter([spec.protocol], broadcast=True, hash=False)
    task = _chunk_task(spec)
    futures = [client.submit(task, list(ids), [spec.sets[i] for i in ids], protocol,
                             spec.rate_hz, spec.sample_indices, pure=False)
               for ids in chunk_ranges(len(spec.sets), n_workers, chunk, _max_chunk(spec))]
    results = []
    completed = None

    def keep(res) -> None:
        results.append(res)
        if on_chunk:
            on_chunk(len(res['set_ids']))

    try:
        # The results come with the futures, fetched by the client's own
        # thread: this thread calls nothing that waits on it until a task
        # fails. A Ctrl-C inside such a wait (``Future.result``) that came
        # before the wait's coroutine had started made distributed's
        # ``sync`` cancel a future it did not have yet: a NameError that
        # tornado printed with its traceback (distributed 2026.8.0; 1 of 45
        # interrupted sweeps at idle priority beside two busy cores).
        completed = as_completed(futures, with_results=True, raise_errors=False)
        for future, res in completed:
            if future.status != 'finished':
                error = SweepError(f'a sweep task {future.status} on the cluster: '
                                   f'{_task_error(future)}')
                _cancel_and_settle(client, futures, completed, keep)
                raise error
            keep(res)
    except KeyboardInterrupt:
        _cancel_and_settle(client, futures, completed, keep)
        return SweepResult(results, False, time.perf_counter() - start)
    return SweepResult(results, True, time.perf_counter() - start)


#: [s] bound on the wait for the futures' last results after a Ctrl-C or a
#: failed task (:func:`_cancel_and_settle`).
SETTLE_TIMEOUT_S = CONNECT_TIMEOUT_S
#: [s] how often that wait looks for them.
SETTLE_POLL_S = 0.02


def _cancel_and_settle(client, futures, completed, keep: Callable) -> None:
    """Cancel the unfinished ``futures``, then take what ``completed`` (their
    ``as_completed(with_results=True)``, None before it exists) still hands out, at most
    :data:`SETTLE_TIMEOUT_S`: a finished task's result goes to ``keep``.

    The client's thread fetches each finished task's result; the cluster
    closed while one was still on its way left that fetch a
    ``CommClosedError``, which tornado printed with its traceback (1 of 75
    interrupted sweeps at idle priority beside two busy cores). A second
    Ctrl-C stops the wait.
    """
    try:
        client.cancel([f for f in futures if not f.done()])
        deadline = time.monotonic() + SETTLE_TIMEOUT_S
        while completed is not None and not completed.is_empty() and time.monotonic() < deadline:
            if not completed.has_ready():
                time.sleep(SETTLE_POLL_S)
                continue
            future, res = next(completed)
            if future.status == 'finished':
                keep(res)
    except KeyboardInterrupt:
        pass


def _task_error(future) -> str:
    """What went wrong with a task that did not finish, in one line."""
    try:
        err = future.exception(timeout=CONNECT_TIMEOUT_S)
    except Exception as cancelled:   # a cancelled future raises instead
        err = cancelled
    return f'{type(err).__name__}: {err}'


def run_sweep(spec: SweepSpec, scheduler: str | None = None, workers: int | None = None,
              chunk: int | None = None, progress: Progress | None = None) -> SweepResult:
    """Run a sweep: here (``workers == 0``), on a new LocalCluster of ``workers``
    processes (default: the core count), or on the cluster at ``scheduler``.

    :raises SweepError: if Dask is missing or the scheduler does not answer
    """
    on_chunk = progress.advance if progress else None
    if workers == 0 and scheduler is None:
        return run_local(spec, chunk, on_chunk)
    try:
        from distributed import Client, LocalCluster
    except ImportError as err:
        raise SweepError(f'sweeps on Dask need the `sweep` extra (pip install '
                         f'dask distributed pyarrow): {err}') from None
    if scheduler is not None:
        try:
            client = Client(scheduler, timeout=f'{CONNECT_TIMEOUT_S}s')
        except (OSError, TimeoutError, ValueError) as err:
            raise SweepError(f'--scheduler {scheduler}: cannot connect: {err}') from None
        with client:
            return run_on_client(spec, client, chunk, on_chunk)
    n = workers if workers is not None else (os.cpu_count() or 1)
    # One thread per worker process: the batch engine holds the GIL.
    with _sigint_ignored():
        # The worker processes inherit the ignored Ctrl-C (and Python leaves an
        # ignored SIGINT ignored): a terminal's Ctrl-C reaches the whole process
        # group, and only this process should act on it, cancelling the tasks
        # and closing the cluster in order, not the workers dying mid-task.
        cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True,
                               dashboard_address=None, silence_logs=logging.ERROR)
    # The scheduler runs in this process: the filter stays until it is closed.
    scheduler_log = logging.getLogger('distributed.scheduler')
    quiet = ClientGoneFilter()
    scheduler_log.addFilter(quiet)
    try:
        with cluster, Client(cluster) as client:
            quiet.client = client
            client.register_plugin(quiet_heartbeat_on_close(), name=QUIET_HEARTBEAT_PLUGIN)
            return run_on_client(spec, client, chunk, on_chunk)
    finally:
        scheduler_log.removeFilter(quiet)


#: What a Dask worker logs when a heartbeat to the scheduler fails
#: (``distributed.worker.Worker.heartbeat``, distributed 2026.8.0).
HEARTBEAT_FAILED = 'Failed to communicate with scheduler during heartbeat'
#: The name the plugin of :func:`quiet_heartbeat_on_close` is registered under.
QUIET_HEARTBEAT_PLUGIN = 'hill_muscle_ros-quiet-heartbeat-on-close'


def quiet_heartbeat_on_close():
    """A Dask worker plugin that drops one log record: the heartbeat failure a
    worker logs, with a traceback, when its own close cut the heartbeat that
    was on the wire.

    ``Worker.close`` marks the worker closing, then closes its connection pool;
    a heartbeat still waiting for the scheduler's answer then fails with
    ``CommClosedError`` and is logged at ERROR (dask/distributed#7105). On our
    own cluster, which this process closes on purpose (at the end, or after
    Ctrl-C), that record says nothing; it came in 2 of 54 Ctrl-C'd sweeps on
    a loaded machine, the worker closing both times. The same failure in a worker that is
    not closing is kept. (A class built here: ``WorkerPlugin`` comes with the
    optional ``sweep`` extra, and Dask pickles it by value.)
    """
    from distributed.diagnostics.plugin import WorkerPlugin

    class QuietHeartbeatOnClose(WorkerPlugin):
        def setup(self, worker) -> None:
            logging.getLogger('distributed.worker').addFilter(
                HeartbeatOnCloseFilter(worker))

    return QuietHeartbeatOnClose()


class HeartbeatOnCloseFilter(logging.Filter):
    """Drop :data:`HEARTBEAT_FAILED` while ``worker`` is closing or closed."""

    def __init__(self, worker) -> None:
        super().__init__()
        self.worker = worker

    def filter(self, record: logging.LogRecord) -> bool:
        if not record.getMessage().startswith(HEARTBEAT_FAILED):
            return True
        from distributed.core import Status
        return self.worker.status not in (Status.closing, Status.closed,
                                          Status.closing_gracefully)


#: What the scheduler logs, at CRITICAL with a traceback, when it tells a
#: client that has closed its connection that a result is in memory
#: (``distributed.scheduler.Scheduler.report``, distributed 2026.8.0).
CLIENT_GONE = 'Closed comm <BatchedSend: closed> while trying to write'


class ClientGoneFilter(logging.Filter):
    """Drop :data:`CLIENT_GONE` once our own client is closing or closed.

    After Ctrl-C this process closes its client, then its cluster, on
    purpose; a task that finished meanwhile makes the scheduler report its
    result to the closed client, and that record (seen once, in the Ctrl-C
    test of a loaded fresh-clone run) says nothing. The same record while
    the client is open is kept.
    """

    def __init__(self) -> None:
        super().__init__()
        self.client = None

    def filter(self, record: logging.LogRecord) -> bool:
        if not record.getMessage().startswith(CLIENT_GONE) or self.client is None:
            return True
        return self.client.status not in ('closing', 'closed')


@contextlib.contextmanager
def _sigint_ignored():
    """Ignore SIGINT in this block (only the main thread can set handlers)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)
