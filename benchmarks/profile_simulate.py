"""Profile `simulate()` on Protocol II and write the profiles (``make bench``).

Writes ``benchmarks/profiles/after_cprofile.txt`` (cProfile, sorted by own
time) and ``after_pyinstrument.txt`` (pyinstrument's call tree, if it is
installed). The ``before_*`` files there are the same profiles of the code
before the fast path (commit 5a6fe05), kept for comparison.

Usage::

    .venv/bin/python benchmarks/profile_simulate.py
"""
from __future__ import annotations

import cProfile
import io
import pstats
import sys
import time
from pathlib import Path

from hill_muscle_ros.model import MuscleParams, Protocol, simulate
from hill_muscle_ros.resources import protocol_path

OUT = Path(__file__).resolve().parent / 'profiles'
#: Runs per profile: enough samples for pyinstrument's 0.2 ms interval.
PROFILE_RUNS = 20
TOP_FUNCTIONS = 12


def main() -> int:
    OUT.mkdir(exist_ok=True)
    protocol = Protocol.from_yaml(protocol_path('II'))
    params = MuscleParams()
    simulate(protocol, params)   # warm-up

    t0 = time.perf_counter()
    simulate(protocol, params)
    elapsed = time.perf_counter() - t0
    n_steps = round(protocol.duration_s * 1000)
    header = (f'simulate(Protocol II, multi/initial, 1 kHz): {elapsed * 1e3:.1f} ms, '
              f'{elapsed / n_steps * 1e6:.2f} us/step, {protocol.duration_s / elapsed:.0f}x '
              f'real time (one unprofiled run)\n\n')

    profiler = cProfile.Profile()
    profiler.enable()
    for _ in range(PROFILE_RUNS):
        simulate(protocol, params)
    profiler.disable()
    text = io.StringIO()
    pstats.Stats(profiler, stream=text).sort_stats('tottime').print_stats(TOP_FUNCTIONS)
    (OUT / 'after_cprofile.txt').write_text(
        header + f'cProfile of {PROFILE_RUNS} runs:\n' + text.getvalue(), encoding='utf-8')

    try:
        from pyinstrument import Profiler
    except ImportError:
        print('pyinstrument not installed: skipped its profile', file=sys.stderr)
    else:
        sampler = Profiler(interval=0.0002)
        sampler.start()
        for _ in range(PROFILE_RUNS):
            simulate(protocol, params)
        sampler.stop()
        (OUT / 'after_pyinstrument.txt').write_text(
            header + sampler.output_text(show_all=True), encoding='utf-8')
    print(header.strip())
    print(f'wrote {OUT}/after_*.txt')
    return 0


if __name__ == '__main__':
    sys.exit(main())
