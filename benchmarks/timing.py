"""Timing helpers for the benchmarks: repeated runs, median/min/max, the machine."""
from __future__ import annotations

import os
import platform
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

    @classmethod
    def of(cls, values: list[float]) -> 'Stats':
        return cls(statistics.median(values), min(values), max(values), len(values))

    def scaled(self, factor: float) -> 'Stats':
        return Stats(self.median * factor, self.low * factor, self.high * factor, self.runs)

    def inverted(self, numerator: float) -> 'Stats':
        """numerator / value: turns times into rates (min and max swap)."""
        return Stats(numerator / self.median, numerator / self.high, numerator / self.low,
                     self.runs)

    def fmt(self, digits: int = 3) -> str:
        return (f'{self.median:.{digits}g} ({self.low:.{digits}g} to '
                f'{self.high:.{digits}g})')


def repeat(fn: Callable[[], object], runs: int, setup: Callable[[], object] | None = None,
           warmup: int = 1) -> Stats:
    """Wall time [s] of ``fn()`` over ``runs`` runs, after ``warmup`` unrecorded ones."""
    times = []
    for i in range(warmup + runs):
        if setup is not None:
            setup()
        t0 = time.perf_counter()
        fn()
        elapsed = time.perf_counter() - t0
        if i >= warmup:
            times.append(elapsed)
    return Stats.of(times)


def cpu_model() -> str:
    try:
        with open('/proc/cpuinfo', encoding='utf-8') as f:
            for line in f:
                if line.startswith('model name'):
                    return line.split(':', 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or 'unknown'


def load_average() -> str:
    try:
        return ', '.join(f'{x:.2f}' for x in os.getloadavg())
    except OSError:
        return 'unknown'


def machine() -> dict[str, str]:
    return {
        'CPU': cpu_model(),
        'logical cores': str(os.cpu_count()),
        'OS': f'{platform.system()} {platform.release()}',
        'Python': platform.python_version(),
        'NumPy': np.__version__,
    }
