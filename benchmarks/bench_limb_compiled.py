"""BENCHMARKS.md section "The limb and the FES muscle, compiled".

One run measures, on the same machine state:

- the knee's real-time factor offline: ``simulate_limb`` of ``config/knee.yaml``
  (quadriceps and hamstrings, 1000 units each, every FES feature of the
  presets) on ``config/protocols/knee_extension.yaml`` (6 s at 1 kHz), on the
  compiled build of the limb's kernels (:mod:`hill_muscle_ros.model.limb.kernels`)
  and on the same functions as plain Python, alternating sample by sample
  (each ten consecutive runs of one build) so that load falls on both alike;
- the same on the protocol's first 3.5 s only (:data:`BEFORE_RELEASE_S`), before
  the quadriceps' stimulation stops: without the release, whose last units
  make the CE stiff until it is quasi-static (see :func:`write_section`);
- one FES muscle's cost a step: the knee's quadriceps alone, its MTU length
  imposed (4 mm sine at 1 Hz), a 0.6 command switched on for 0.3 s of every
  0.5 s, 2 s at 1 ms: :meth:`Muscle.run_array
  <hill_muscle_ros.model.muscle.Muscle.run_array>` on either build;
- the compiled kernels' start: ``limb.kernels.compiled()`` in a fresh
  process (which compiles the muscle's kernels too) with an empty
  ``NUMBA_CACHE_DIR`` (cold) and with the cache that run filled (warm).

Run alone: ``.venv/bin/python benchmarks/run_all.py --only limb --runs 5``.
"""
from __future__ import annotations

import dataclasses
import json
import math
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import yaml

from timing import RUNS_PER_SAMPLE, Stats

from hill_muscle_ros.model import Muscle, engine
from hill_muscle_ros.model.limb import LimbPlant, LimbProtocol, simulate_limb
from hill_muscle_ros.model.limb import kernels as limb_kernels

HERE = Path(__file__).resolve().parent
REPO = HERE.parent
PLANT = REPO / 'config' / 'knee.yaml'
PROTOCOL = REPO / 'config' / 'protocols' / 'knee_extension.yaml'
#: [x] Goal: the two-muscle knee at least this many times real time, compiled.
TARGET_RTF = 2000.0
#: [s] step of every run here (the presets' rate_hz).
DT_S = 1e-3
#: [s] length of the single muscle's run.
MUSCLE_S = 2.0
#: [s] the knee protocol's stimulation stops here (knee_extension.yaml).
BEFORE_RELEASE_S = 3.5

#: A fresh process's start of the compiled kernels: prints the seconds as JSON.
START = ('import json, time; t0 = time.perf_counter(); '
         'from hill_muscle_ros.model.limb import kernels; kernels.compiled(); '
         'print(json.dumps(time.perf_counter() - t0))')


def knee():
    data = yaml.safe_load(PLANT.read_text())['/**']['ros__parameters']
    return LimbPlant.from_mapping(data, ignore=('rate_hz',))


def _timed(fn) -> tuple[float, float]:
    c0, t0 = time.process_time(), time.perf_counter()
    fn()
    return time.perf_counter() - t0, time.process_time() - c0


def _on_engine(value: str, fn):
    old = os.environ.get(engine.ENV_VAR)
    os.environ[engine.ENV_VAR] = value
    try:
        return fn()
    finally:
        if old is None:
            del os.environ[engine.ENV_VAR]
        else:
            os.environ[engine.ENV_VAR] = old


def bench_limb(runs: int, duration_s: float | None = None) -> dict:
    """simulate_limb on the knee, compiled and Python, alternating sample by
    sample, each :data:`timing.RUNS_PER_SAMPLE` consecutive runs (the protocol
    cut to ``duration_s`` if given); a run's time."""
    plant, protocol = knee(), LimbProtocol.from_yaml(PROTOCOL)
    if duration_s is not None:
        protocol = dataclasses.replace(protocol, duration_s=duration_s)
    limb_kernels.compiled()
    sides = {'compiled': ([], []), 'python': ([], [])}
    for i in range(runs + 1):
        order = ('compiled', 'python') if i % 2 == 0 else ('python', 'compiled')
        for side in order:
            def sample():
                for _ in range(RUNS_PER_SAMPLE):
                    simulate_limb(plant, protocol)
            wall, cpu = _timed(lambda: _on_engine(side, sample))
            if i > 0:   # the first pair warms up
                sides[side][0].append(wall / RUNS_PER_SAMPLE)
                sides[side][1].append(cpu / RUNS_PER_SAMPLE)
    result = {side: Stats.of(w, c) for side, (w, c) in sides.items()}
    result['duration_s'] = protocol.duration_s
    for side in ('compiled', 'python'):
        print(f'  limb {side}: {result[side].fmt()} s', flush=True)
    return result


def bench_muscle(runs: int) -> dict:
    """The knee's quadriceps alone, its run on either build, per step."""
    params = knee().muscles[0].params
    t = np.arange(int(round(MUSCLE_S / DT_S))) * DT_S
    r = np.where((t % 0.5) < 0.3, 0.6, 0.0)
    dl = 0.004 * np.sin(2.0 * math.pi * t)
    sides = {'compiled': ([], []), 'python': ([], [])}
    run = {side: (lambda side=side: Muscle(params, build=side).run_array(r, dl, DT_S))
           for side in sides}
    for i in range(runs + 1):
        for side in (('compiled', 'python') if i % 2 == 0 else ('python', 'compiled')):
            wall, cpu = _timed(run[side])
            if i > 0:
                sides[side][0].append(wall / len(t))
                sides[side][1].append(cpu / len(t))
    result = {side: Stats.of(w, c) for side, (w, c) in sides.items()}
    for side in ('compiled', 'python'):
        print(f'  muscle {side}: {result[side].fmt()} s/step', flush=True)
    return result


def bench_start(runs: int) -> dict:
    """limb.kernels.compiled() in fresh processes, empty cache and filled cache."""
    cold, warm = [], []
    with tempfile.TemporaryDirectory(prefix='numba_cache_') as root:
        for i in range(runs):
            env = dict(os.environ, NUMBA_CACHE_DIR=os.path.join(root, str(i)))
            for into in (cold, warm):
                out = subprocess.run([sys.executable, '-c', START], check=True, text=True,
                                     capture_output=True, env=env, cwd=REPO).stdout
                into.append(json.loads(out.strip().splitlines()[-1]))
    result = {'cold': Stats.of(cold), 'warm': Stats.of(warm)}
    for case in ('cold', 'warm'):
        print(f'  start {case}: {result[case].fmt()} s', flush=True)
    return result


def run(runs: int) -> dict:
    print('limb, compiled against Python', flush=True)
    limb = bench_limb(runs)
    print(f'limb, the first {BEFORE_RELEASE_S:g} s', flush=True)
    before = bench_limb(runs, BEFORE_RELEASE_S)
    print('FES muscle, compiled against Python', flush=True)
    muscle = bench_muscle(runs)
    print('compiled kernels, cold and warm start', flush=True)
    start = bench_start(runs)
    return {'limb': limb, 'before': before, 'muscle': muscle, 'start': start, 'runs': runs}


def write_section(add, m: dict) -> None:
    limb, muscle, start = m['limb'], m['muscle'], m['start']
    duration = limb['duration_s']
    rtf = {side: duration / limb[side].median for side in ('compiled', 'python')}
    rtf_cpu = {side: duration / limb[side].cpu.median for side in ('compiled', 'python')}
    add('## The limb and the FES muscle, compiled (`model/limb/kernels.py`, '
        '`model/muscle/kernels.py`)')
    add('')
    add('`benchmarks/bench_limb_compiled.py` (alone: `.venv/bin/python benchmarks/run_all.py '
        f'--only limb --runs {m["runs"]}`). The compiled build agrees with the same functions '
        'run as plain Python to 1e-9 rad and 1e-9 N (`test/test_limb_compiled.py`, '
        '`test/test_fes_compiled.py`). '
        f'The engines alternate sample by sample, each sample {RUNS_PER_SAMPLE} consecutive '
        'runs of one engine (a compiled knee run lasts about 3 ms; timed one by one after a '
        'Python run, which leaves the caches cold, it ran at 1682x in the bench of '
        '2026-12-04 04:59 UTC on this kind of machine); a run\'s time, medians (min to max) '
        'over the samples.')
    add('')
    add('| measurement | compiled | Python | Python / compiled |')
    add('| --- | ---: | ---: | ---: |')
    add(f'| knee (`config/knee.yaml`), `knee_extension.yaml`, {duration:g} s at 1 kHz: '
        f'`simulate_limb` wall [s] | {limb["compiled"].fmt()} | {limb["python"].fmt()} | '
        f'{limb["python"].median / limb["compiled"].median:.3g} |')
    add(f'| the same, real-time factor (wall; CPU) | {rtf["compiled"]:.4g}x; '
        f'{rtf_cpu["compiled"]:.4g}x | {rtf["python"]:.3g}x; {rtf_cpu["python"]:.3g}x | |')
    before = m['before']
    rtf_before = {side: before['duration_s'] / before[side].median
                  for side in ('compiled', 'python')}
    add(f'| the same protocol\'s first {before["duration_s"]:g} s (before the release), '
        f'real-time factor (wall) | {rtf_before["compiled"]:.4g}x | '
        f'{rtf_before["python"]:.3g}x | {rtf_before["compiled"] / rtf_before["python"]:.3g} |')
    add(f'| the knee\'s quadriceps alone (1000 units, every FES feature), {MUSCLE_S:g} s: '
        f'[us/step] | {_us(muscle["compiled"])} | {_us(muscle["python"])} | '
        f'{muscle["python"].median / muscle["compiled"].median:.3g} |')
    add('')
    add(f'- Goal: the two-muscle knee at least {TARGET_RTF:g}x real time compiled: '
        f'**{rtf["compiled"]:.4g}x** wall — '
        f'**{"met" if rtf["compiled"] >= TARGET_RTF else "not met"}**. A call between '
        'compiled functions passes each array as its fields, so the step\'s innermost work '
        'is compiled into one function (limb.kernels._INTO_STEP): the forces of the RK4 '
        'stages (one loop over the stages, so that they are compiled in once), a '
        'multi/initial muscle\'s F0 at the step\'s three instants '
        '(muscle/kernels.py, eff_f_iso_inline) and the fatigue\'s interval bounds. The stages\' '
        'gravity sines come from the step\'s first sine and cosine (equations.sine_near: '
        'libm\'s '
        'sin had been 9 % of a run, by perf). Together, by hand, the code before and after in '
        'two processes alternating on one core: 0.863x and 0.854x the time a run (medians of '
        '31 pair ratios, either core). A run\'s large arrays come from a per-thread pool '
        '(muscle/state.py, ScratchPool): fresh ones faulted on every page, a tenth of the run. '
        'A muscle in whose step no unit joins or leaves is not planned '
        '(limb.kernels.plan_steady; doc/model.md section 4). The quarter second after the '
        'stimulation stops costs more per step: as the last units of the quadriceps leave, '
        '`fv_scaling: relative` shrinks the Hill constants with F0 and the CE\'s relaxation '
        'rate grows as 1 / F0; below 1e5 /s RK4 takes up to 200 steps a millisecond '
        '(h lambda <= 0.5), above it the CE is quasi-static (doc/model.md 7.6). The rows '
        'above show the run with and without that release. While the activation rises or '
        'falls, units join or leave within a step, and each unit\'s instant bounds an RK4 '
        'interval of the joint and both CEs; the rest of the time goes to the step\'s fixed '
        'work for two muscles of 1000 units with every FES feature (the RK4 stages of the '
        'joint and both CEs, F0 from each unit pool with its fatigue, each muscle\'s delay '
        'line and command). The margin over the goal is small, and the speed of these shared '
        'machines varies by about as much from one hour to the next.')
    add(f'- Start of the compiled kernels (`limb.kernels.compiled()`, muscle kernels included) '
        f'in a fresh process: cold (empty `NUMBA_CACHE_DIR`) {start["cold"].fmt()} s, '
        f'warm (cache filled) {start["warm"].fmt()} s.')
    add('')


def _us(s: Stats) -> str:
    return f'{s.median * 1e6:.3g} ({s.low * 1e6:.3g} to {s.high * 1e6:.3g})'
