"""Timing helpers for the benchmarks: repeated runs, median/min/max, the machine."""
from __future__ import annotations

import os
import platform
import resource
import statistics
import time
from dataclasses import dataclass
from typing import Callable

import numpy as np


@dataclass(frozen=True)
class Stats:
    """Summary of repeated measurements of one quantity."""

    median: float
    low: float
    high: float
    runs: int
    #: The same runs measured in CPU time (user + system) instead of wall time.
    cpu: 'Stats | None' = None

    @classmethod
    def of(cls, values: list[float], cpu: list[float] | None = None) -> 'Stats':
        return cls(statistics.median(values), min(values), max(values), len(values),
                   cls.of(cpu) if cpu else None)

    def scaled(self, factor: float) -> 'Stats':
        return Stats(self.median * factor, self.low * factor, self.high * factor, self.runs,
                     self.cpu.scaled(factor) if self.cpu else None)

    def inverted(self, numerator: float) -> 'Stats':
        """numerator / value: turns times into rates (min and max swap)."""
        return Stats(numerator / self.median, numerator / self.high, numerator / self.low,
                     self.runs, self.cpu.inverted(numerator) if self.cpu else None)

    def fmt(self, digits: int = 3) -> str:
        return (f'{self.median:.{digits}g} ({self.low:.{digits}g} to '
                f'{self.high:.{digits}g})')


def _children_cpu_s() -> float:
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def repeat(fn: Callable[[], object], runs: int, setup: Callable[[], object] | None = None,
           warmup: int = 1, children: bool = False) -> Stats:
    """Wall time [s] of ``fn()`` over ``runs`` runs, after ``warmup`` unrecorded ones.

    The CPU time of the same runs is kept in ``.cpu``: this process's
    (``time.process_time``), or with ``children`` that of the subprocesses
    ``fn`` ran. Other load on the machine inflates wall time far more than CPU
    time, so the two together show how much of a number is interference.
    """
    cpu_clock = _children_cpu_s if children else time.process_time
    times, cpu = [], []
    for i in range(warmup + runs):
        if setup is not None:
            setup()
        c0 = cpu_clock()
        t0 = time.perf_counter()
        fn()
        elapsed = time.perf_counter() - t0
        cpu_elapsed = cpu_clock() - c0
        if i >= warmup:
            times.append(elapsed)
            cpu.append(cpu_elapsed)
    return Stats.of(times, cpu)


def cpu_model() -> str:
    try:
        with open('/proc/cpuinfo', encoding='utf-8') as f:
            for line in f:
                if line.startswith('model name'):
                    return line.split(':', 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or 'unknown'


#: Consecutive runs of one side timed as one sample where two builds' or
#: models' runs alternate (bench_compiled, bench_limb_compiled): a compiled run
#: lasts a few ms (Protocol II, the knee), and timed one by one after the other
#: side's run (which leaves the caches cold) its cost scattered by a factor of
#: 1.6 within one bench (the paper's compiled run, 2026-12-04); ten runs a
#: sample average that out, on both sides alike.
RUNS_PER_SAMPLE = 10


#: CPU flags that set how wide numba's vector loops are (LLVM compiles for the
#: host): the vectorised batch engine of before the one engine ran four mixed
#: variants at 4.6e7 muscle-steps/s on an Intel Xeon and 7.4e7 on an AMD EPYC
#: with AVX-512, the same code.
VECTOR_FLAGS = ('avx2', 'fma', 'avx512f')


def vector_flags() -> str:
    """Which of :data:`VECTOR_FLAGS` the CPU has, as /proc/cpuinfo says."""
    try:
        with open('/proc/cpuinfo', encoding='utf-8') as f:
            for line in f:
                if line.startswith('flags'):
                    have = set(line.split(':', 1)[1].split())
                    return ', '.join(f for f in VECTOR_FLAGS if f in have) or 'none of ' + \
                        ', '.join(VECTOR_FLAGS)
    except OSError:
        pass
    return 'unknown'


def load_average() -> str:
    try:
        return ', '.join(f'{x:.2f}' for x in os.getloadavg())
    except OSError:
        return 'unknown'


def machine() -> dict[str, str]:
    return {
        'CPU': cpu_model(),
        'vector instructions': vector_flags(),
        'logical cores': str(os.cpu_count()),
        'OS': f'{platform.system()} {platform.release()}',
        'Python': platform.python_version(),
        'NumPy': np.__version__,
    }
