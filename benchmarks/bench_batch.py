"""Section 3 of BENCHMARKS.md: many muscles at once (``MuscleBatch``), both engines.

One run measures, on the same machine state:

- muscle-steps/s of the NumPy and the compiled (numba) engine at K = 1, 100
  and 10,000, every FES feature off;
- the compiled / NumPy ratio at K = 10,000 from back-to-back pairs of runs
  (one NumPy run, then one compiled run), so that load on the shared machine
  hits both sides of each ratio alike;
- the compiled engine on 1 and on 2 numba threads (``numba.set_num_threads``)
  at K = 10,000 and 100,000;
- muscles whose recruitment changes on every step (the unit-memory
  bookkeeping: per muscle in Python on the NumPy engine, compiled on the
  compiled one) and muscles with fatigue and activation on (one scalar
  FesMuscle each on the NumPy engine, all together on the compiled FES muscle
  on the compiled one);
- what numba costs before the first step: ``import numba``, and building the
  first compiled batch with an empty cache (compiling) and with the cache
  filled (loading), each in a new interpreter with its own ``NUMBA_CACHE_DIR``.

Run alone: ``.venv/bin/python benchmarks/run_all.py --only batch``.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time

import numpy as np
from timing import Stats, repeat

from hill_muscle_ros.model import MuscleParams, Protocol, kernels
from hill_muscle_ros.model.batch import MuscleBatch
from hill_muscle_ros.model.simulate import sample_times
from hill_muscle_ros.resources import protocol_path

DT_S = 1e-3
RATE_HZ = 1000.0
BATCH_SIZES = (1, 100, 10_000)
#: K of the engine comparison, the thread counts and the slow cases.
K_LARGE = 10_000
#: Protocol II window replayed: it contains the step of R at 3 s, so every
#: muscle's memory changes once.
WINDOW_S = (2.5, 3.5)
#: Steps of the slow case with R changing every step (tens of ms a step).
SLOW_STEPS = 20
#: Steps of the case with FES features on (on the NumPy engine each muscle a
#: scalar FES step, about a second a step at K = 10,000).
FES_STEPS = 5
SEED = 20240601
VARIANTS = (('multi', 'initial'), ('multi', 'instantaneous'), ('single', 'initial'),
            ('single', 'instantaneous'))
ENGINES = ('numpy', 'compiled')
#: Target: the compiled engine at least this many times the NumPy one at K = 10,000.
TARGET_RATIO = 3.0
#: Target kept from before the compiled engine: NumPy at K = 10,000 [muscle-steps/s].
TARGET_RATE = 1e7
#: Thread counts of the compiled engine measured.
THREADS = (1, 2)
#: K of the thread comparison beyond K_LARGE (the first parameter set only).
K_HUGE = 100_000
#: The FES features switched on in the FES case: fatigue and activation dynamics.
FES_FEATURES = dict(fatigue='riener', tau_fatigue_s=[0.5], tau_act_s=0.03, tau_deact_s=0.05)

#: Measures in a new interpreter the import of numba, then the first compiled
#: batch (build + one step), printing both as JSON: [s] wall and CPU.
FIRST_CALL = '''
import json, time
t0, c0 = time.perf_counter(), time.process_time()
import numba
t1, c1 = time.perf_counter(), time.process_time()
from hill_muscle_ros.model import MuscleParams
from hill_muscle_ros.model.batch import MuscleBatch
t2, c2 = time.perf_counter(), time.process_time()
MuscleBatch([MuscleParams()], engine='compiled').step(0.5, 0.0, 1e-3)
t3, c3 = time.perf_counter(), time.process_time()
print(json.dumps({'import': [t1 - t0, c1 - c0], 'first': [t3 - t2, c3 - c2]}))
'''


def parameter_sets(k: int, rng) -> dict:
    f_iso = rng.uniform(30.0, 60.0, k)
    k_se = rng.uniform(5e3, 2e4, k)
    return {
        'multi/initial, f_iso_max and k_se varied': [
            MuscleParams(f_iso_max_n=float(f), k_se_n_per_m=float(s))
            for f, s in zip(f_iso, k_se)],
        'four variants mixed': [
            MuscleParams(units=VARIANTS[i % 4][0], length=VARIANTS[i % 4][1],
                         f_iso_max_n=float(f_iso[i])) for i in range(k)],
    }


def replay(batch: MuscleBatch, r_rows, dl_rows):
    """A function that steps ``batch`` through the input rows (R of step j, dl at its end)."""
    def run():
        step = batch.step
        for j in range(len(dl_rows) - 1):
            step(r_rows[j], dl_rows[j + 1], DT_S)
    return run


def paired_ratio(runs: int, numpy_run, numpy_reset, compiled_run, compiled_reset) -> Stats:
    """NumPy time / compiled time over back-to-back pairs (after one warm-up pair)."""
    ratios = []
    for i in range(runs + 1):
        times = []
        for run, reset in ((numpy_run, numpy_reset), (compiled_run, compiled_reset)):
            reset()
            t0 = time.perf_counter()
            run()
            times.append(time.perf_counter() - t0)
        if i > 0:
            ratios.append(times[0] / times[1])
    return Stats.of(ratios)


def first_call(runs: int) -> dict:
    """import numba, and the first compiled batch with a cold and a filled cache."""
    measured = {'import': [], 'cold': [], 'cached': []}
    with tempfile.TemporaryDirectory(prefix='numba_cache_') as root:
        for i in range(runs):
            for case in ('cold', 'cached'):
                cache = os.path.join(root, str(i))   # new per pair: cold, then cached
                env = dict(os.environ, NUMBA_CACHE_DIR=cache)
                out = subprocess.run([sys.executable, '-c', FIRST_CALL], env=env,
                                     check=True, capture_output=True, text=True).stdout
                got = json.loads(out.strip().splitlines()[-1])
                measured[case].append(got['first'])
                measured['import'].append(got['import'])
    return {case: Stats.of([w for w, _ in values], [c for _, c in values])
            for case, values in measured.items()}


def run(runs: int) -> dict:
    # The package's set-up first (it makes the OpenMP threads wait passively,
    # which must precede numba's first use of its threads).
    numba = kernels.compiled().numba
    protocol = Protocol.from_yaml(protocol_path('II'))
    t = sample_times(protocol.duration_s, RATE_HZ)
    window = (t >= WINDOW_S[0]) & (t <= WINDOW_S[1])
    r = protocol.recruitment(t[window], MuscleParams().pw_max_s)
    dl = protocol.dl_mt(t[window])
    n_steps = len(dl) - 1
    rng = np.random.default_rng(SEED)
    threads_before = numba.get_num_threads()
    result = {'rates': {}, 'ratio': {}, 'threads': {}, 'changing': {}, 'n_steps': n_steps,
              'numba': numba.__version__, 'threads_default': threads_before,
              'layer': None}
    for k in BATCH_SIZES:
        r_k = [np.full(k, x) for x in r]
        dl_k = [np.full(k, x) for x in dl]
        for name, params in parameter_sets(k, rng).items():
            batches = {e: MuscleBatch(params, engine=e) for e in ENGINES}
            for engine, batch in batches.items():
                s = repeat(replay(batch, r_k, dl_k), runs, setup=batch.reset)
                result['rates'][(name, k, engine)] = s.inverted(k * n_steps)
                print(f'  batch {engine} {name} K={k}: '
                      f'{result["rates"][(name, k, engine)].fmt()} muscle-steps/s', flush=True)
            if k == K_LARGE:
                result['ratio'][name] = paired_ratio(
                    runs, replay(batches['numpy'], r_k, dl_k), batches['numpy'].reset,
                    replay(batches['compiled'], r_k, dl_k), batches['compiled'].reset)
                print(f'  compiled / numpy {name}: {result["ratio"][name].fmt()}', flush=True)
                compiled = batches['compiled']
                # K is below kernels.PARALLEL_MIN_K, so the batch runs on one thread
                # by default: lower the bound here to run it on 1 and on 2.
                min_k = kernels.PARALLEL_MIN_K
                kernels.PARALLEL_MIN_K = 1
                try:
                    for threads in THREADS:
                        numba.set_num_threads(threads)
                        s = repeat(replay(compiled, r_k, dl_k), runs, setup=compiled.reset)
                        result['threads'][(name, k, threads)] = s.inverted(k * n_steps)
                        print(f'  compiled on {threads} thread(s): '
                              f'{result["threads"][(name, k, threads)].fmt()}', flush=True)
                finally:
                    numba.set_num_threads(threads_before)
                    kernels.PARALLEL_MIN_K = min_k
    result['layer'] = numba.threading_layer()
    # K = 100,000 (above kernels.PARALLEL_MIN_K: every thread by default).
    k = K_HUGE
    name, params = next(iter(parameter_sets(k, rng).items()))
    compiled = MuscleBatch(params, engine='compiled')
    r_k = [np.full(k, x) for x in r]
    dl_k = [np.full(k, x) for x in dl]
    try:
        for threads in THREADS:
            numba.set_num_threads(threads)
            s = repeat(replay(compiled, r_k, dl_k), runs, setup=compiled.reset)
            result['threads'][(name, k, threads)] = s.inverted(k * n_steps)
            print(f'  compiled K={k} on {threads} thread(s): '
                  f'{result["threads"][(name, k, threads)].fmt()}', flush=True)
    finally:
        numba.set_num_threads(threads_before)
    del compiled, r_k, dl_k

    # Recruitment changing on every step: every multi/initial memory is touched.
    k = K_LARGE
    params = parameter_sets(k, rng)['multi/initial, f_iso_max and k_se varied']
    r_change = [rng.uniform(0.0, 1.0, k) for _ in range(SLOW_STEPS + 1)]
    dl_change = [np.full(k, x) for x in dl[:SLOW_STEPS + 1]]
    for engine in ENGINES:
        batch = MuscleBatch(params, engine=engine)
        s = repeat(replay(batch, r_change, dl_change), runs, setup=batch.reset)
        result['changing'][engine] = s.inverted(k * SLOW_STEPS)
        print(f'  R changing every step, {engine}: {result["changing"][engine].fmt()}',
              flush=True)

    # FES features on: one scalar FesMuscle each (NumPy engine), or all on the
    # compiled FES muscle (compiled engine).
    fes_params = [MuscleParams(f_iso_max_n=float(f), **FES_FEATURES)
                  for f in rng.uniform(30.0, 60.0, k)]
    r_k = [np.full(k, x) for x in r[:FES_STEPS + 1]]
    result['fes'] = {}
    for engine in ENGINES:
        batch = MuscleBatch(fes_params, engine=engine)
        s = repeat(replay(batch, r_k, dl_change[:FES_STEPS + 1]), runs, setup=batch.reset)
        result['fes'][engine] = s.inverted(k * FES_STEPS)
        print(f'  fatigue and activation on ({engine}): {result["fes"][engine].fmt()}',
              flush=True)
        del batch

    result['first_call'] = first_call(runs)
    for case, s in result['first_call'].items():
        print(f'  {case}: {s.fmt()} s', flush=True)
    return result


def _cpu(s: Stats) -> str:
    return f'{s.cpu.median:.3g}' if s.cpu is not None else '-'


def write_section(add, m: dict) -> None:
    """Section 3 of BENCHMARKS.md from :func:`run`'s result."""
    add('## 3. Many muscles at once (`hill_muscle_ros.model.batch.MuscleBatch`)')
    add('')
    add(f'`benchmarks/bench_batch.py` (alone: `.venv/bin/python benchmarks/run_all.py --only '
        f'batch`). K muscles with their own parameters stepped together ({WINDOW_S[0]:g} s to '
        f'{WINDOW_S[1]:g} s of Protocol II, 1 ms steps, {m["n_steps"]} steps, which include '
        'the step of R at 3 s, so every multi/initial memory changes once), every FES feature '
        'off, on both engines: `numpy` (whole-array NumPy, the reference) and `compiled` '
        f'(numba {m["numba"]}, `model/kernels.py`; threading layer `{m["layer"]}`, '
        f'{m["threads_default"]} threads by default, one below K = '
        f'{kernels.PARALLEL_MIN_K:,}). '
        'Muscle-steps per second = K x steps / wall time. CPU time counts every thread of '
        'the process, so on 2 threads it can exceed the wall-time rate\'s share.')
    add('')
    add('| parameter sets | K | engine | muscle-steps/s (wall) | by CPU time |')
    add('| --- | ---: | --- | ---: | ---: |')
    for (name, k, engine), s in m['rates'].items():
        add(f'| {name} | {k:,} | {engine} | {s.fmt()} | {_cpu(s)} |')
    add('')
    pairs = next(iter(m['ratio'].values())).runs
    add(f'Compiled / NumPy at K = {K_LARGE:,}, from {pairs} back-to-back pairs of runs per '
        'set (a NumPy run, then a compiled run; the ratio of each pair):')
    add('')
    add('| parameter sets | compiled / NumPy (wall) |')
    add('| --- | ---: |')
    for name, s in m['ratio'].items():
        add(f'| {name} | {s.fmt()}x |')
    add('')
    add(f'The compiled engine at K = {K_LARGE:,} and {K_HUGE:,} on 1 and on 2 numba threads '
        f'(`numba.set_num_threads`; at K = {K_LARGE:,} with `kernels.PARALLEL_MIN_K` lowered '
        'so that this K runs on every thread), every FES feature off:')
    add('')
    add('| parameter sets | K | threads | muscle-steps/s (wall) | by CPU time |')
    add('| --- | ---: | ---: | ---: | ---: |')
    for (name, k, threads), s in m['threads'].items():
        add(f'| {name} | {k:,} | {threads} | {s.fmt()} | {_cpu(s)} |')
    add('')
    add(f'Slower cases at K = {K_LARGE:,} ({SLOW_STEPS} steps with R changing, {FES_STEPS} '
        'with FES features on):')
    add('')
    add('| case | engine | muscle-steps/s (wall) | by CPU time |')
    add('| --- | --- | ---: | ---: |')
    for engine, s in m['changing'].items():
        add(f'| multi/initial, R drawn anew for every muscle on every step | {engine} | '
            f'{s.fmt()} | {_cpu(s)} |')
    fes_engines = {'numpy': 'numpy (one scalar `FesMuscle` each)',
                   'compiled': 'compiled (all on the compiled FES muscle, one thread)'}
    for engine, s in m['fes'].items():
        add(f'| multi/initial with fatigue (`riener`) and activation (`tau_act_s` 0.03, '
            f'`tau_deact_s` 0.05) on | {fes_engines[engine]} | {s.fmt()} | {_cpu(s)} |')
    add('')
    fc = m['first_call']
    add('What numba costs before the first step, each in a new interpreter with its own '
        '`NUMBA_CACHE_DIR` (wall s, CPU s in brackets): '
        f'`import numba` **{fc["import"].fmt()} s** ({_cpu(fc["import"])}); the first '
        'compiled batch (`MuscleBatch(..., engine=\'compiled\')` and one step) with an empty '
        f'cache, i.e. compiling, **{fc["cold"].fmt()} s** ({_cpu(fc["cold"])}), and with the '
        f'cache filled by that run **{fc["cached"].fmt()} s** ({_cpu(fc["cached"])}). '
        'Importing `hill_muscle_ros` never imports numba (`test/test_batch_compiled.py`).')
    add('')
    worst = min(m['ratio'].values(), key=lambda s: s.median)
    numpy_rate = min(s.median for (name, k, e), s in m['rates'].items()
                     if k == K_LARGE and e == 'numpy')
    add(f'- Target: the compiled engine at least {TARGET_RATIO:g}x the NumPy one at K = '
        f'{K_LARGE:,}, features off: **{worst.median:.3g}x** (median of the pairs, the lower '
        f'of the two sets) — {"**met**" if worst.median >= TARGET_RATIO else "**not met**"}.')
    add(f'- Target: the NumPy engine at least {TARGET_RATE:.0e} muscle-steps/s at K = '
        f'{K_LARGE:,}: **{numpy_rate:.3g}** (slower of the two sets) — '
        f'{"**met**" if numpy_rate >= TARGET_RATE else "**not met**"}.')
    per_change_us = 1e6 / m['changing']['compiled'].median
    add(f'- With R changing on every step the unit-memory bookkeeping runs for every muscle: '
        f'per muscle in Python on the NumPy engine (it dominates there), compiled '
        f'(`kernels.recruit_all`) on the compiled one, {per_change_us:.2g} us a muscle-step '
        f'here in all.')
    fes = m['fes']
    add(f'- With fatigue and activation on, the compiled engine ran '
        f'**{fes["compiled"].median / fes["numpy"].median:.3g}x** the NumPy engine\'s rate '
        '(medians; the same steps, from rest, while the activation rises: the slowest '
        'part of a run).')

    def scaling(k):
        ratios = [s.median / m['threads'][(name, kk, 1)].median
                  for (name, kk, threads), s in m['threads'].items()
                  if kk == k and threads == 2]
        return f'{min(ratios):.2g}-{max(ratios):.2g}x' if len(ratios) > 1 else f'{ratios[0]:.2g}x'
    add(f'- Two threads ran at {scaling(K_LARGE)} the one-thread rate at K = {K_LARGE:,} '
        f'and {scaling(K_HUGE)} at K = {K_HUGE:,} here: at the smaller K waking the second '
        'thread costs about what it saves (more on busy cores), which is why the batch uses '
        f'every thread only from K = {kernels.PARALLEL_MIN_K:,} (`kernels.PARALLEL_MIN_K`).')
    add('- At K = 1 the NumPy engine is dominated by NumPy call overhead; use `Muscle` for '
        'one muscle.')
