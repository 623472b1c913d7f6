"""Cold compile cost of each set of compiled kernels (a benchmark, not a test).

A fresh clone compiles every kernel set once (``make test`` prints the sum as
"numba compiling in the pytest processes"). This
measures each set's share: every run is a new Python process on a new, empty
numba cache directory (``NUMBA_CACHE_DIR``), which builds the kernel sets in the order given, and
reports for each the seconds numba spent compiling it
(:func:`hill_muscle_ros.model.engine.compile_seconds` before and after) and
its wall time. A set built on another (the limb's and the batch's kernels
call the compiled muscle) is charged only what it adds; with
``--alone`` each set runs in a process of its own instead, so each pays for
everything it needs.

Usage::

    .venv/bin/python benchmarks/compile_cost.py [--runs 3] [--alone] [--sets muscle limb]

Prints one line per set (median, min and max over the runs) and the total.
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from hill_muscle_ros.model import precompile

#: The repository whose kernels are measured (the child imports from there).
REPO = Path(__file__).resolve().parent.parent

#: The kernel sets, in the order of a test run and of ``hill-muscle compile``
#: (the muscle first: the limb's and the batch's kernels call it): the
#: package's own list, :data:`hill_muscle_ros.model.precompile.KERNEL_SETS`.
SETS = tuple(precompile.KERNEL_SETS)

#: What the measuring process runs: builds the sets named in argv with the
#: package's own builder (precompile.compile_kernel_set), prints JSON.
_CHILD = """
import json, sys, time
from hill_muscle_ros.model import engine, precompile
engine.import_numba()
result = {}
for name in json.loads(sys.argv[1]):
    c0, w0 = engine.compile_seconds(), time.perf_counter()
    precompile.compile_kernel_set(name)
    result[name] = (engine.compile_seconds() - c0, time.perf_counter() - w0)
print(json.dumps(result))
"""


def measure(names: list[str]) -> dict[str, tuple[float, float]]:
    """Build the kernel sets ``names`` in order in a new process on an empty cache.

    :return: name -> ([s] compiling, [s] wall time)
    """
    with tempfile.TemporaryDirectory(prefix='numba-cold-') as cache:
        env = dict(os.environ, NUMBA_CACHE_DIR=cache, HILL_MUSCLE_ENGINE='compiled')
        out = subprocess.run([sys.executable, '-c', _CHILD, json.dumps(names)],
                             env=env, cwd=REPO, check=True, capture_output=True, text=True).stdout
    return {k: tuple(v) for k, v in json.loads(out.splitlines()[-1]).items()}


#: [s] the most a fresh clone's test run may spend compiling
TARGET_COMPILE_S = 60.0
#: What each set is, for the report.
SET_LABELS = {
    'muscle': 'the muscle (`model/muscle/kernels.py`: `Muscle`, the paper\'s model and every '
              'FES feature, on both its run and its parts)',
    'limb': 'the limb (`model/limb/kernels.py`), on the muscle',
    'batch': 'the batch of muscles (`model/muscle/batch_kernels.py`), on the muscle',
}


def collect(names: list[str], runs: int, alone: bool = False) -> dict[str, list]:
    """``runs`` cold builds of the sets ``names``: name -> [([s] compiling, [s] wall)]."""
    samples = {n: [] for n in names}
    for run in range(runs):
        started = time.perf_counter()
        for group in ([[n] for n in names] if alone else [names]):
            for name, value in measure(group).items():
                samples[name].append(value)
        print(f'cold compile, run {run + 1}/{runs}: {time.perf_counter() - started:.1f} s',
              file=sys.stderr, flush=True)
    return samples


def run(runs: int) -> dict:
    """The report's measurement: every set, in a test run's order, ``runs`` times."""
    return {'samples': collect(list(SETS), runs), 'runs': runs}


def _cell(values: list[float]) -> str:
    return f'{statistics.median(values):.1f} ({min(values):.1f} to {max(values):.1f})'


def write_section(add, m: dict) -> None:
    """BENCHMARKS.md's section on the cold compile (``run_all.py``)."""
    samples, runs = m['samples'], m['runs']
    totals = [sum(samples[n][r][0] for n in samples) for r in range(runs)]
    add('## Compiling the kernels (a fresh clone, `benchmarks/compile_cost.py`)')
    add('')
    add(f'Each of {runs} runs is a new Python process on an empty `NUMBA_CACHE_DIR` that '
        'builds every kernel set in the order of a test run and of `hill-muscle compile` '
        '(`.venv/bin/python benchmarks/run_all.py --only compile`); a set that calls another '
        '(the limb and the batch call the compiled muscle) is charged what it adds. Seconds '
        'numba spent compiling (`engine.compile_seconds()`), median (min to max) over the '
        'runs.')
    add('')
    add('| kernel set | compiling [s] | wall [s] |')
    add('| --- | ---: | ---: |')
    for name, values in samples.items():
        add(f'| {SET_LABELS[name]} | {_cell([c for c, _ in values])} | '
            f'{_cell([w for _, w in values])} |')
    add(f'| **all** | **{_cell(totals)}** | |')
    add('')
    ok = statistics.median(totals) <= TARGET_COMPILE_S
    add(f'- Goal: a fresh clone\'s `make test` compiles for at most {TARGET_COMPILE_S:g} s. '
        f'Every kernel set compiled once, cold, in one process: '
        f'**{statistics.median(totals):.1f} s** — '
        f'{"met" if ok else "**not met**"} by this measure. `make test` compiles them '
        'before pytest (`hill-muscle compile`, two processes), and pytest prints what '
        'its own processes compiled after that at its end ("numba compiling in the '
        'pytest processes"); pytest run without `make` compiles '
        'them itself, in processes that the controller starts before its workers, which '
        'wait for them after their first modules; '
        'a test that runs the engine in a subprocess on an unwritable cache compiles the '
        'run once more there. numba caches the machine code in the package\'s '
        '`__pycache__` (or `NUMBA_CACHE_DIR`), so this is paid once per clone or edited '
        'model. What keeps it short: numba inlines only the small leaf equations (its own '
        'inlining types and lowers a function again at every call site, which had made the '
        'cold compile about 60 s); the limb and the batch of muscles have one compiled '
        'entry point each, since every entry point optimises the muscle it calls again; '
        'and a function called with constant arguments gets an explicit signature (the '
        'limb\'s `limb_step`, the muscle\'s `add_event`), which numba otherwise compiles '
        'once per constant. With the muscle written once there are three sets, no longer '
        'five: the paper\'s own run and batch kernels (`model/kernels.py`) are gone.')
    add('')


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--runs', type=int, default=3, help='fresh processes per measurement')
    parser.add_argument('--alone', action='store_true',
                        help='each set in a process of its own (pays for what it calls)')
    parser.add_argument('--sets', nargs='+', choices=SETS, default=list(SETS))
    args = parser.parse_args(argv)
    samples = collect(args.sets, args.runs, args.alone)
    print(f'cold compile, {"each set alone" if args.alone else "in order"}, '
          f'{args.runs} runs: median (min-max) [s]')
    totals = [sum(samples[n][r][0] for n in args.sets) for r in range(args.runs)]
    for name in args.sets:
        comp = [c for c, _ in samples[name]]
        wall = [w for _, w in samples[name]]
        print(f'  {name:12s} compiling {statistics.median(comp):6.1f} '
              f'({min(comp):.1f}-{max(comp):.1f})   wall {statistics.median(wall):6.1f}')
    print(f'  {"total":12s} compiling {statistics.median(totals):6.1f} '
          f'({min(totals):.1f}-{max(totals):.1f})')


if __name__ == '__main__':
    main()
