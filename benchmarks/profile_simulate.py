"""Profile `simulate()` on Protocol II on each build and write the profiles (``make bench``).

The muscle is written once and runs compiled by numba or as the very same
functions in plain Python (``HILL_MUSCLE_ENGINE``). Writes, in
``benchmarks/profiles/``:

- ``after_cprofile.txt`` (cProfile, sorted by own time) and
  ``after_pyinstrument.txt`` (pyinstrument's call tree, if it is installed) of
  ``simulate()`` as shipped: on the compiled build, where the Python left is
  the protocol's sampling and the facade around one compiled ``run_array``;
- ``after_python_cprofile.txt`` and ``after_python_pyinstrument.txt``: the
  same on the plain-Python build (``HILL_MUSCLE_ENGINE=python``), where the
  kernels' own functions show.

The ``before_*`` files there are the same profiles of the code before the
fast path (commit 5a6fe05), kept for comparison.

Usage::

    .venv/bin/python benchmarks/profile_simulate.py
"""
from __future__ import annotations

import cProfile
import io
import os
import pstats
import sys
import time
from pathlib import Path

from hill_muscle_ros.model import MuscleParams, Protocol, engine, simulate
from hill_muscle_ros.resources import protocol_path

OUT = Path(__file__).resolve().parent / 'profiles'
#: Runs per profile, by build: enough samples for pyinstrument's 0.2 ms
#: interval (a plain run of Protocol II takes about half a second).
PROFILE_RUNS = {engine.COMPILED: 20, engine.PYTHON: 3}
#: Profile files' name stem, by build.
STEMS = {engine.COMPILED: 'after', engine.PYTHON: 'after_python'}
TOP_FUNCTIONS = 12


def profile(build: str, protocol: Protocol, params: MuscleParams) -> str:
    """Profile ``simulate()`` with ``HILL_MUSCLE_ENGINE=build``; write its files.

    :return: the one-line summary of an unprofiled run
    """
    runs, stem = PROFILE_RUNS[build], STEMS[build]
    saved = os.environ.get(engine.ENV_VAR)
    os.environ[engine.ENV_VAR] = build
    try:
        simulate(protocol, params)   # warm-up (loads the compiled kernels)
        t0 = time.perf_counter()
        simulate(protocol, params)
        elapsed = time.perf_counter() - t0
        n_steps = round(protocol.duration_s * 1000)
        header = (f'simulate(Protocol II, multi/initial, 1 kHz), {build} build '
                  f'(HILL_MUSCLE_ENGINE={build}): {elapsed * 1e3:.1f} ms, '
                  f'{elapsed / n_steps * 1e6:.2f} us/step, {protocol.duration_s / elapsed:.0f}x '
                  f'real time (one unprofiled run)\n\n')

        profiler = cProfile.Profile()
        profiler.enable()
        for _ in range(runs):
            simulate(protocol, params)
        profiler.disable()
        text = io.StringIO()
        pstats.Stats(profiler, stream=text).sort_stats('tottime').print_stats(TOP_FUNCTIONS)
        (OUT / f'{stem}_cprofile.txt').write_text(
            header + f'cProfile of {runs} runs:\n' + text.getvalue(), encoding='utf-8')

        try:
            from pyinstrument import Profiler
        except ImportError:
            print('pyinstrument not installed: skipped its profile', file=sys.stderr)
        else:
            sampler = Profiler(interval=0.0002)
            sampler.start()
            for _ in range(runs):
                simulate(protocol, params)
            sampler.stop()
            (OUT / f'{stem}_pyinstrument.txt').write_text(
                header + sampler.output_text(show_all=True), encoding='utf-8')
    finally:
        if saved is None:
            os.environ.pop(engine.ENV_VAR, None)
        else:
            os.environ[engine.ENV_VAR] = saved
    return header.strip()


def main() -> int:
    OUT.mkdir(exist_ok=True)
    protocol = Protocol.from_yaml(protocol_path('II'))
    params = MuscleParams()
    builds = [engine.PYTHON]
    if engine.numba_available():
        builds.insert(0, engine.COMPILED)
    else:
        print('numba not installed: only the plain build profiled', file=sys.stderr)
    for build in builds:
        print(profile(build, protocol, params))
    print(f'wrote {OUT}/after_*.txt')
    return 0


if __name__ == '__main__':
    sys.exit(main())
