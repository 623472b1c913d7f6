"""Section 3 of BENCHMARKS.md: many muscles at once (``MuscleBatch``), on the one engine.

``MuscleBatch`` is a facade over one bundle of all K muscles' state, stepped
by ``model/muscle/batch_kernels.py``: a serial loop over the muscles of the
single muscle's functions, compiled by numba or run as the same functions in
plain Python (``MuscleBatch(params, build=...)``). One run measures, on the
same machine state:

- muscle-steps/s of the compiled build at K = 1, 100 and 10,000, every FES
  feature off, and of the plain build at K = 1 and 100 (on fewer steps: a
  plain muscle-step takes about 0.1 ms);
- the compiled / plain ratio at K = 10,000 from back-to-back pairs of runs
  over a few steps that include a change of R, so that load on the shared
  machine hits both sides of each ratio alike;
- the engines the one engine replaced, in this run: the NumPy engine and the
  vectorised compiled engine of commit :data:`OLD_ENGINE_COMMIT` (the last
  before the muscle was written once), extracted with ``git archive`` and run
  in a subprocess on the same parameters and inputs at K = 10,000;
- muscles whose recruitment changes on every step, and muscles with fatigue
  and activation on, compiled, at K = 10,000;
- what numba costs before the first step: ``import numba``, and building the
  first compiled batch with an empty cache (compiling) and with the cache
  filled (loading), each in a new interpreter with its own ``NUMBA_CACHE_DIR``.

Run alone: ``.venv/bin/python benchmarks/run_all.py --only batch``.
"""
from __future__ import annotations

import io
import json
import os
import subprocess
import sys
import tarfile
import tempfile
import time
from pathlib import Path

import numpy as np
from timing import Stats, repeat

from hill_muscle_ros.model import MuscleBatch, MuscleParams, Protocol, engine
from hill_muscle_ros.model.muscle import batch_kernels
from hill_muscle_ros.model.simulate import sample_times
from hill_muscle_ros.resources import protocol_path

REPO = Path(__file__).resolve().parent.parent
DT_S = 1e-3
RATE_HZ = 1000.0
BATCH_SIZES = (1, 100, 10_000)
#: K of the build comparison, the previous engines and the slow cases.
K_LARGE = 10_000
#: Protocol II window replayed: it contains the step of R at 3 s, so every
#: muscle's memory changes once.
WINDOW_S = (2.5, 3.5)
#: Steps the plain build is timed on at each K of :data:`PLAIN_SIZES` (the
#: window's first ones; 1000 plain steps of 100 muscles take about 10 s).
PLAIN_SIZES = {1: 1000, 100: 50}
#: [s] start of the steps of the compiled / plain pairs at K = 10,000, and
#: their number: they include the step of R at 3 s.
RATIO_START_S = 2.998
RATIO_STEPS = 4
#: Steps of the slow case with R changing every step.
SLOW_STEPS = 20
#: Steps of the case with FES features on.
FES_STEPS = 5
SEED = 20240601
#: Pairs of new interpreters timing the first compiled batch, cold then cached
#: (a cold one compiles the batch's and the muscle's kernels, about 15 s).
COLD_RUNS = 3
VARIANTS = (('multi', 'initial'), ('multi', 'instantaneous'), ('single', 'initial'),
            ('single', 'instantaneous'))
BUILDS = (engine.COMPILED, engine.PYTHON)
#: Target: the compiled build at least this many times the plain one at
#: K = 10,000 (it asked this of the compiled engine against the NumPy one).
TARGET_RATIO = 3.0
#: Target kept from before the compiled engine, for the NumPy engine at
#: K = 10,000 [muscle-steps/s]; asked now of the one engine, compiled.
TARGET_RATE = 1e7
#: The FES features switched on in the FES case: fatigue and activation dynamics.
FES_FEATURES = dict(fatigue='riener', tau_fatigue_s=[0.5], tau_act_s=0.03, tau_deact_s=0.05)
#: Name of the case with FES features on.
FES_CASE = ('multi/initial with fatigue (`riener`) and activation (`tau_act_s` 0.03, '
            '`tau_deact_s` 0.05) on')
#: The last commit before the muscle was written once: its MuscleBatch had a
#: NumPy engine and a vectorised compiled one (one thread below K = 20,000).
OLD_ENGINE_COMMIT = '8fdcd44'
OLD_ENGINES = ('numpy', 'compiled')

#: Measures in a new interpreter the import of numba, then the first compiled
#: batch (build + one step), printing both as JSON: [s] wall and CPU.
FIRST_CALL = '''
import json, time
t0, c0 = time.perf_counter(), time.process_time()
import numba
t1, c1 = time.perf_counter(), time.process_time()
from hill_muscle_ros.model import MuscleBatch, MuscleParams
t2, c2 = time.perf_counter(), time.process_time()
MuscleBatch([MuscleParams()], build='compiled').step(0.5, 0.0, 1e-3)
t3, c3 = time.perf_counter(), time.process_time()
print(json.dumps({'import': [t1 - t0, c1 - c0], 'first': [t3 - t2, c3 - c2]}))
'''

#: Run by the previous package's own interpreter (cwd: its extracted copy):
#: reads the cases (parameter sets, inputs, engines) as JSON on stdin, times
#: ``runs`` replays after one warm-up on each engine, prints JSON.
OLD_ENGINE_RUN = '''
import json, sys, time
import numpy as np
spec = json.loads(sys.stdin.read())
import hill_muscle_ros
if not hill_muscle_ros.__file__.startswith(spec['root']):
    raise SystemExit(f'imported {hill_muscle_ros.__file__}, not the copy in {spec["root"]}')
from hill_muscle_ros.model import MuscleParams
from hill_muscle_ros.model.batch import MuscleBatch
result = {}
for case in spec['cases']:
    name = case['name']
    params = [MuscleParams(**row) for row in case['rows']]
    k = len(params)
    r_rows = [np.full(k, x) for x in case['r']]
    dl_rows = [np.full(k, x) for x in case['dl']]
    for engine in case['engines']:
        batch = MuscleBatch(params, engine=engine)
        wall, cpu = [], []
        for i in range(spec['runs'] + 1):
            batch.reset()
            c0, t0 = time.process_time(), time.perf_counter()
            for j in range(len(dl_rows) - 1):
                batch.step(r_rows[j], dl_rows[j + 1], 1e-3)
            t1, c1 = time.perf_counter(), time.process_time()
            if i > 0:
                wall.append(t1 - t0)
                cpu.append(c1 - c0)
        result.setdefault(name, {})[engine] = [wall, cpu]
        del batch
print(json.dumps(result))
'''


def parameter_rows(k: int, rng) -> dict:
    """The two parameter sets of K muscles, as MuscleParams keyword dicts."""
    f_iso = rng.uniform(30.0, 60.0, k)
    k_se = rng.uniform(5e3, 2e4, k)
    return {
        'multi/initial, f_iso_max and k_se varied': [
            {'f_iso_max_n': float(f), 'k_se_n_per_m': float(s)} for f, s in zip(f_iso, k_se)],
        'four variants mixed': [
            {'units': VARIANTS[i % 4][0], 'length': VARIANTS[i % 4][1],
             'f_iso_max_n': float(f_iso[i])} for i in range(k)],
    }


def replay(batch: MuscleBatch, r_rows, dl_rows, n_steps: int | None = None):
    """A function that steps ``batch`` through the input rows (R of step j, dl at
    its end), the first ``n_steps`` steps (all of them by default)."""
    steps = len(dl_rows) - 1 if n_steps is None else n_steps

    def run():
        step = batch.step
        for j in range(steps):
            step(r_rows[j], dl_rows[j + 1], DT_S)
    return run


def paired_ratio(runs: int, plain_run, plain_reset, compiled_run, compiled_reset) -> Stats:
    """Plain time / compiled time over back-to-back pairs (after one warm-up pair)."""
    ratios = []
    for i in range(runs + 1):
        times = []
        for run, reset in ((plain_run, plain_reset), (compiled_run, compiled_reset)):
            reset()
            t0 = time.perf_counter()
            run()
            times.append(time.perf_counter() - t0)
        if i > 0:
            ratios.append(times[0] / times[1])
    return Stats.of(ratios)


def first_call(runs: int) -> dict:
    """import numba, and the first compiled batch with a cold and a filled cache
    (``min(runs, COLD_RUNS)`` pairs of new interpreters)."""
    measured = {'import': [], 'cold': [], 'cached': []}
    with tempfile.TemporaryDirectory(prefix='numba_cache_') as root:
        for i in range(min(runs, COLD_RUNS)):
            for case in ('cold', 'cached'):
                cache = os.path.join(root, str(i))   # new per pair: cold, then cached
                env = dict(os.environ, NUMBA_CACHE_DIR=cache)
                env.pop(engine.ENV_VAR, None)
                out = subprocess.run([sys.executable, '-c', FIRST_CALL], env=env,
                                     check=True, capture_output=True, text=True).stdout
                got = json.loads(out.strip().splitlines()[-1])
                measured[case].append(got['first'])
                measured['import'].append(got['import'])
    return {case: Stats.of([w for w, _ in values], [c for _, c in values])
            for case, values in measured.items()}


def old_engines(runs: int, cases: list) -> dict:
    """The batch engines of :data:`OLD_ENGINE_COMMIT` on ``cases``: dicts of a
    ``name``, keyword ``rows`` (one MuscleParams each), the inputs ``r`` and
    ``dl`` (one value per sample, every muscle alike) and the ``engines``.

    The package of that commit is extracted from git history into a temporary
    directory and run there by this interpreter in a subprocess, on its own
    empty ``NUMBA_CACHE_DIR`` (so it compiles its kernels first, untimed).

    :return: {'rates': {(name, engine): Stats [muscle-steps/s]}, 'error': None},
        or {'error': why it could not be measured}
    """
    try:
        archive = subprocess.run(['git', '-C', str(REPO), 'archive', '--format=tar',
                                  OLD_ENGINE_COMMIT, 'hill_muscle_ros'],
                                 check=True, capture_output=True).stdout
        with tempfile.TemporaryDirectory(prefix='old_engine_') as root:
            with tarfile.open(fileobj=io.BytesIO(archive)) as tar:
                tar.extractall(root, filter='data')
            spec = {'root': root, 'runs': runs, 'cases': [
                dict(case, r=[float(x) for x in case['r']], dl=[float(x) for x in case['dl']])
                for case in cases]}
            env = {k: v for k, v in os.environ.items()
                   if k not in (engine.ENV_VAR, 'PYTHONPATH')}
            env['NUMBA_CACHE_DIR'] = os.path.join(root, 'numba_cache')
            out = subprocess.run([sys.executable, '-c', OLD_ENGINE_RUN], input=json.dumps(spec),
                                 cwd=root, env=env, check=True, capture_output=True,
                                 text=True).stdout
        got = json.loads(out.strip().splitlines()[-1])
    except FileNotFoundError as err:
        return {'error': f'git is not available ({err})'}
    except subprocess.CalledProcessError as err:
        tail = (err.stderr or b'')
        tail = tail.decode(errors='replace') if isinstance(tail, bytes) else tail
        return {'error': f'`{" ".join(map(str, err.cmd[:3]))} ...` failed: '
                         f'{tail.strip().splitlines()[-1] if tail.strip() else err.returncode}'}
    except Exception as err:   # report it, never fake a number
        return {'error': f'{type(err).__name__}: {err}'}
    rates = {}
    for case in cases:
        work = len(case['rows']) * (len(case['dl']) - 1)
        for eng, (wall, cpu) in got[case['name']].items():
            rates[(case['name'], eng)] = Stats.of(wall, cpu).inverted(work)
    return {'rates': rates, 'error': None}


def run(runs: int) -> dict:
    numba = batch_kernels.compiled().numba   # loaded (or compiled) before anything is timed
    protocol = Protocol.from_yaml(protocol_path('II'))
    t = sample_times(protocol.duration_s, RATE_HZ)
    window = (t >= WINDOW_S[0] - 1e-9) & (t <= WINDOW_S[1] + 1e-9)
    r = protocol.recruitment(t[window], MuscleParams().pw_max_s)
    dl = protocol.dl_mt(t[window])
    n_steps = len(dl) - 1
    near = (t >= RATIO_START_S - 1e-9) & (t <= RATIO_START_S + RATIO_STEPS / RATE_HZ + 1e-9)
    r_ratio = protocol.recruitment(t[near], MuscleParams().pw_max_s)
    dl_ratio = protocol.dl_mt(t[near])
    rng = np.random.default_rng(SEED)
    result = {'rates': {}, 'ratio': {}, 'changing': None, 'n_steps': n_steps,
              'numba': numba.__version__}
    large_sets = None
    for k in BATCH_SIZES:
        r_k = [np.full(k, x) for x in r]
        dl_k = [np.full(k, x) for x in dl]
        sets = parameter_rows(k, rng)
        if k == K_LARGE:
            large_sets = sets
        for name, rows in sets.items():
            params = [MuscleParams(**row) for row in rows]
            for build in BUILDS:
                if build == engine.PYTHON and k not in PLAIN_SIZES:
                    continue
                steps = n_steps if build == engine.COMPILED else PLAIN_SIZES[k]
                batch = MuscleBatch(params, build=build)
                s = repeat(replay(batch, r_k, dl_k, steps), runs, setup=batch.reset)
                result['rates'][(name, k, build)] = (s.inverted(k * steps), steps)
                print(f'  batch {build} {name} K={k} ({steps} steps): '
                      f'{result["rates"][(name, k, build)][0].fmt()} muscle-steps/s', flush=True)
                del batch
            if k == K_LARGE:
                r_near = [np.full(k, x) for x in r_ratio]
                dl_near = [np.full(k, x) for x in dl_ratio]
                plain = MuscleBatch(params, build=engine.PYTHON)
                compiled = MuscleBatch(params, build=engine.COMPILED)
                result['ratio'][name] = paired_ratio(
                    runs, replay(plain, r_near, dl_near), plain.reset,
                    replay(compiled, r_near, dl_near), compiled.reset)
                print(f'  compiled / plain {name}: {result["ratio"][name].fmt()}', flush=True)
                del plain, compiled
        del r_k, dl_k

    # Recruitment changing on every step: every multi/initial memory is touched.
    k = K_LARGE
    params = [MuscleParams(**row)
              for row in parameter_rows(k, rng)['multi/initial, f_iso_max and k_se varied']]
    r_change = [rng.uniform(0.0, 1.0, k) for _ in range(SLOW_STEPS + 1)]
    dl_change = [np.full(k, x) for x in dl[:SLOW_STEPS + 1]]
    batch = MuscleBatch(params, build=engine.COMPILED)
    s = repeat(replay(batch, r_change, dl_change), runs, setup=batch.reset)
    result['changing'] = s.inverted(k * SLOW_STEPS)
    print(f'  R changing every step, compiled: {result["changing"].fmt()}', flush=True)
    del batch, params

    # FES features on (fatigue and activation), from rest, while the activation rises.
    fes_rows = [dict(f_iso_max_n=float(f), **FES_FEATURES) for f in rng.uniform(30.0, 60.0, k)]
    fes_params = [MuscleParams(**row) for row in fes_rows]
    r_fes, dl_fes = r[:FES_STEPS + 1], dl[:FES_STEPS + 1]
    r_k = [np.full(k, x) for x in r_fes]
    dl_k = [np.full(k, x) for x in dl_fes]
    batch = MuscleBatch(fes_params, build=engine.COMPILED)
    s = repeat(replay(batch, r_k, dl_k), runs, setup=batch.reset)
    result['fes'] = s.inverted(k * FES_STEPS)
    print(f'  fatigue and activation on, compiled: {result["fes"].fmt()}', flush=True)
    del batch, fes_params, r_k, dl_k

    # The engines the one engine replaced, on the same K = 10,000 sets and inputs
    # (with FES features on its compiled engine only: its NumPy engine stepped
    # one scalar FesMuscle each, about a second a step).
    print(f'  the batch engines of {OLD_ENGINE_COMMIT} (git archive, a subprocess)', flush=True)
    cases = [{'name': name, 'rows': rows, 'r': r, 'dl': dl, 'engines': list(OLD_ENGINES)}
             for name, rows in large_sets.items()]
    cases.append({'name': FES_CASE, 'rows': fes_rows, 'r': r_fes, 'dl': dl_fes,
                  'engines': ['compiled']})
    result['old'] = old_engines(runs, cases)
    if result['old']['error']:
        print(f'  not measured: {result["old"]["error"]}', flush=True)
    for (name, eng), s in result['old'].get('rates', {}).items():
        print(f'  {OLD_ENGINE_COMMIT} {eng} {name}: {s.fmt()} muscle-steps/s', flush=True)

    result['first_call'] = first_call(runs)
    for case, s in result['first_call'].items():
        print(f'  {case}: {s.fmt()} s', flush=True)
    return result


def _cpu(s: Stats) -> str:
    return f'{s.cpu.median:.3g}' if s.cpu is not None else '-'


def _met(ok: bool) -> str:
    return '**met**' if ok else '**not met**'


def write_section(add, m: dict) -> None:
    """Section 3 of BENCHMARKS.md from :func:`run`'s result."""
    add('## 3. Many muscles at once (`hill_muscle_ros.model.muscle.batch.MuscleBatch`)')
    add('')
    add(f'`benchmarks/bench_batch.py` (alone: `.venv/bin/python benchmarks/run_all.py --only '
        f'batch`). K muscles with their own parameters stepped together ({WINDOW_S[0]:g} s to '
        f'{WINDOW_S[1]:g} s of Protocol II, 1 ms steps, {m["n_steps"]} steps, which include '
        'the step of R at 3 s, so every multi/initial memory changes once), every FES feature '
        'off. One engine: `MuscleBatch` is a facade over one bundle of all K muscles\' state, '
        'stepped by `model/muscle/batch_kernels.py`, a loop over the muscles of the very '
        'functions one `Muscle` runs, compiled by numba '
        f'{m["numba"]} (`build=\'compiled\'`) or run as the same functions in plain Python '
        '(`build=\'python\'`; at K = 1 and 100 on the window\'s first '
        f'{" and ".join(str(v) for v in PLAIN_SIZES.values())} steps, a plain muscle-step '
        'taking about 0.1 ms). The loop is serial, on one thread: the NumPy engine and the '
        'vectorised compiled engine (two threads from K = 20,000) are gone. Muscle-steps '
        'per second = K x steps / wall time.')
    add('')
    add('| parameter sets | K | build | steps timed | muscle-steps/s (wall) | by CPU time |')
    add('| --- | ---: | --- | ---: | ---: | ---: |')
    for (name, k, build), (s, steps) in m['rates'].items():
        add(f'| {name} | {k:,} | {build} | {steps:,} | {s.fmt()} | {_cpu(s)} |')
    add('')
    pairs = next(iter(m['ratio'].values())).runs
    add(f'Compiled / plain at K = {K_LARGE:,}, from {pairs} back-to-back pairs of runs per '
        f'set (a plain run, then a compiled run, each of the {RATIO_STEPS} steps from '
        f'{RATIO_START_S:g} s, which include the step of R at 3 s; the ratio of each pair):')
    add('')
    add('| parameter sets | compiled / plain (wall) |')
    add('| --- | ---: |')
    for name, s in m['ratio'].items():
        add(f'| {name} | {s.fmt()}x |')
    add('')
    old = m['old']
    compiled_large = {name: s for (name, k, build), (s, _) in m['rates'].items()
                      if k == K_LARGE and build == engine.COMPILED}
    add(f'The engines the one engine replaced, measured in this run: `MuscleBatch` of commit '
        f'`{OLD_ENGINE_COMMIT}` (the last before the muscle was written once), its package '
        'extracted with `git archive` and run in a subprocess of this interpreter (its '
        'kernels compiled first on an empty cache, untimed), on the same K = '
        f'{K_LARGE:,} parameter sets and window; its compiled engine ran on one thread below '
        'K = 20,000, as today\'s does at any K; with FES features on (the first '
        f'{FES_STEPS} steps of the window, from rest) it stepped them one after the other '
        'through its compiled FES muscle, and is timed on its compiled engine only.')
    add('')
    if old['error']:
        add(f'Not measured: {old["error"]}.')
    else:
        add(f'| parameter sets | engine of `{OLD_ENGINE_COMMIT}` | muscle-steps/s (wall) | '
            'by CPU time | today\'s compiled / it (wall medians) |')
        add('| --- | --- | ---: | ---: | ---: |')
        today = dict(compiled_large, **{FES_CASE: m['fes']})
        for (name, eng), s in old['rates'].items():
            ratio = today[name].median / s.median
            label = ('compiled, one FES muscle after the other' if name == FES_CASE else
                     {'numpy': 'NumPy (whole arrays)',
                      'compiled': 'compiled, vectorised over the muscles'}[eng])
            add(f'| {name} | {label} | {s.fmt()} | {_cpu(s)} | {ratio:.3g}x |')
    add('')
    add(f'Slower cases at K = {K_LARGE:,}, compiled ({SLOW_STEPS} steps with R changing, '
        f'{FES_STEPS} with FES features on, from rest while the activation rises):')
    add('')
    add('| case | muscle-steps/s (wall) | by CPU time |')
    add('| --- | ---: | ---: |')
    add(f'| multi/initial, R drawn anew for every muscle on every step | '
        f'{m["changing"].fmt()} | {_cpu(m["changing"])} |')
    add(f'| {FES_CASE} | {m["fes"].fmt()} | {_cpu(m["fes"])} |')
    add('')
    fc = m['first_call']
    add('What numba costs before the first step, each in a new interpreter with its own '
        f'`NUMBA_CACHE_DIR` ({fc["cold"].runs} of each; wall s, CPU s in brackets): '
        f'`import numba` **{fc["import"].fmt()} s** ({_cpu(fc["import"])}); the first '
        'compiled batch (`MuscleBatch(..., build=\'compiled\')` and one step) with an empty '
        'cache, i.e. compiling the batch\'s kernels and the muscle\'s they call, '
        f'**{fc["cold"].fmt()} s** ({_cpu(fc["cold"])}), and with the cache filled by that '
        f'run **{fc["cached"].fmt()} s** ({_cpu(fc["cached"])}). Importing `hill_muscle_ros` '
        'never imports numba.')
    add('')
    worst = min(m['ratio'].values(), key=lambda s: s.median)
    add(f'- Target: the compiled build at least {TARGET_RATIO:g}x the plain one at K = '
        f'{K_LARGE:,}, features off: **{worst.median:.3g}x** (median of the pairs, the lower '
        f'of the two sets) — {_met(worst.median >= TARGET_RATIO)}. It asked this of the '
        'compiled engine against the NumPy engine, which is gone; the plain build runs the '
        'same functions as Python, so the ratio says what numba buys them.')
    rate = min(s.median for s in compiled_large.values())
    line = (f'- Target: at least {TARGET_RATE:.0e} muscle-steps/s at K = {K_LARGE:,} (set for '
            'the NumPy engine; asked now of the one engine, compiled): '
            f'**{rate:.3g}** (slower of the two sets) — {_met(rate >= TARGET_RATE)}.')
    if rate < TARGET_RATE:
        line += (' Missed because of the one implementation: each muscle takes the single '
                 'muscle\'s general step alone (the delay line, the activation\'s pieces, the '
                 'event planning and the unit pool, with every feature off), one after the '
                 'other on one thread, where the engines it replaced stepped the paper\'s '
                 'model over whole arrays of muscles')
        if not old['error']:
            off = {key: s for key, s in old['rates'].items() if key[0] != FES_CASE}
            old_np = min(s.median for (n, e), s in off.items() if e == 'numpy')
            old_c = min(s.median for (n, e), s in off.items() if e == 'compiled')
            line += (f': in this run `{OLD_ENGINE_COMMIT}`\'s NumPy engine made {old_np:.3g} '
                     f'and its compiled one {old_c:.3g} muscle-steps/s (slower sets), '
                     f'{old_np / rate:.2g}x and {old_c / rate:.2g}x today\'s')
        line += '.'
        if not old['error'] and (FES_CASE, 'compiled') in old['rates']:
            was = old['rates'][(FES_CASE, 'compiled')].median
            line += (' Batches with FES features on were stepped one muscle after the other '
                     f'before too: there today\'s rate is {m["fes"].median / was:.2g}x '
                     f'`{OLD_ENGINE_COMMIT}`\'s (the table above).')
    add(line)
    add(f'- With R changing on every step, the unit pool\'s bookkeeping runs in every muscle '
        f'on every step: {1e6 / m["changing"].median:.2g} us a muscle-step, against '
        f'{1e6 / compiled_large["multi/initial, f_iso_max and k_se varied"].median:.2g} us '
        'with R changing once in the window. With fatigue and activation on: '
        f'{1e6 / m["fes"].median:.2g} us a muscle-step (the steps after a rise, the slowest '
        'part of a run).')
    rows = m['rates']
    one = {build: s.median for (name, k, build), (s, _) in rows.items()
           if k == 1 and name == 'multi/initial, f_iso_max and k_se varied'}
    if engine.COMPILED in one:
        add(f'- At K = 1 a compiled batch step costs {1e6 / one[engine.COMPILED]:.2g} us, '
            'most of it the facade\'s checks and arrays around one muscle\'s step: for one '
            'muscle `Muscle.step` costs less ("One muscle\'s offline run").')
