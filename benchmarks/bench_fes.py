"""The FES features' cost: section 7 of BENCHMARKS.md (``make bench``).

What it measures, all in this process:

- the cost of ``Muscle.step`` (one call per 1 ms step, the node's path, on
  the build ``Muscle`` takes by default: compiled where numba imports) with
  each FES feature on alone and all together, at N = 1e3 and N = 1e6, on a
  10 s protocol whose pulse width alternates every second (so the recruitment
  changes every second) while the muscle is slowly stretched;
- the single-step costs of the runs with activation dynamics, where the
  recruitment changes within nearly every step;
- a naive per-unit NumPy version of the same model
  (:class:`naive.NaiveFesMuscle`) at the same N;
- the construction of a muscle (random order and prefix sums at N = 1e6);
- the paper's step with every FES feature off against the step before the FES
  extensions existed (``Muscle`` of commit :data:`PRE_FES_COMMIT`, loaded from
  git history), on Protocol II.

Run this section alone while developing (prints its Markdown, or writes it to
``--out``; BENCHMARKS.md is left alone)::

    .venv/bin/python benchmarks/run_all.py --only fes --runs 5
"""
from __future__ import annotations

import gc
import importlib
import importlib.util
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Callable

import numpy as np

from naive import NaiveFesMuscle
from timing import Stats, repeat

from hill_muscle_ros.model import Muscle, MuscleParams, Protocol
from hill_muscle_ros.model.simulate import sample_times
from hill_muscle_ros.model.stimulus import command_from_pulse_width
from hill_muscle_ros.resources import protocol_path

REPO = Path(__file__).resolve().parent.parent

DT_S = 1e-3
RATE_HZ = 1000.0
UNIT_COUNTS = (1_000, 1_000_000)

# -- the protocol ----------------------------------------------------------------
#: [s] Length of the protocol: ten recruitment changes, one per second.
PROTOCOL_S = 10.0
#: [s] Pulse widths alternated every second, low first. On the exponential
#: curve below they give u = 0.30 and u = 0.75: each change moves about
#: 45 % of the units.
PW_LOW_S, PW_HIGH_S = 200e-6, 400e-6
#: [s] Period of the alternation: the recruitment changes once per half period.
PW_PERIOD_S = 2.0
#: [m] MTU stretch over the whole protocol, a slow ramp (0.5 mm/s). It keeps
#: c l_ce / l_opt inside FL's support for every unit with the length spread
#: (at most 1.3 x 1.2 = 1.56 < 1.6), where the memory sums FL from moments.
STRETCH_M = 0.005

# -- the features ------------------------------------------------------------------
#: Ding et al. 2007's curve: threshold pd0 = 131.4 us, scale pdt = 194.1 us
#: (the package's pw_scale_s default). The stimulator side: every row uses it,
#: so every row gets the same command sequence.
CURVE = {'recruitment_curve': 'exponential', 'pw_threshold_s': 131.4e-6,
         'pw_scale_s': 194.1e-6}
#: A 25 ms electromechanical delay, activation 60 ms and deactivation 110 ms.
ACTIVATION = {'emd_s': 0.025, 'tau_act_s': 0.060, 'tau_deact_s': 0.110}
RELATIVE_FV = {'fv_scaling': 'relative'}
#: Riener's law at its defaults (mu_min 0.2, 30 s, 50 s) for every type.
FATIGUE = {'fatigue': 'riener'}
#: Two fibre types, half the units each, the second twice as strong per unit,
#: recruited in random order (seed 0).
TWO_TYPES = {'fibre_fractions': (0.5, 0.5), 'fibre_force_weights': (1.0, 2.0),
             'recruitment_order': 'random'}
SPREAD = {'unit_length_spread': 0.2}
#: The features the N-scaling target names.
TARGET_FEATURES = {**FATIGUE, **TWO_TYPES, **SPREAD}
ALL_FEATURES = {**ACTIVATION, **RELATIVE_FV, **FATIGUE, **TWO_TYPES, **SPREAD}

#: Rows of the step-cost table: (key, label, parameter changes).
CONFIGS = (
    ('curve', 'recruitment curve only (exponential); otherwise the paper\'s model', {}),
    ('activation', 'delay 25 ms + activation 60 / 110 ms', ACTIVATION),
    ('relative', '`fv_scaling: relative`', RELATIVE_FV),
    ('fatigue', '`fatigue: riener`', FATIGUE),
    ('types', 'two fibre types, random order', TWO_TYPES),
    ('spread', '`unit_length_spread: 0.2`', SPREAD),
    ('target', 'fatigue + two types in random order + spread 0.2 (the target\'s set)',
     TARGET_FEATURES),
    ('target_inst', 'the target\'s set, `length: instantaneous`',
     {**TARGET_FEATURES, 'length': 'instantaneous'}),
    ('all', 'all of them (delay, activation, relative F-V, fatigue, two types, spread)',
     ALL_FEATURES),
)
#: Rows also run against the naive per-unit version, and built for the
#: construction table.
NAIVE_CONFIGS = ('target', 'all')
#: Steps of the protocol over which the naive version is timed at N = 1e6:
#: about 25 ms a step, so the whole protocol would take minutes a run. Its
#: per-step work is the same every step (every unit's fitness, sums over the
#: recruited ones), so a short window is representative; the package is timed
#: on the same window for the comparison.
NAIVE_WINDOW_STEPS = 200

# -- the targets -------------------------------------------------------------------
#: N = 1e6 at most this many times N = 1e3 (the target's set of features).
TARGET_N_RATIO = 2.0
#: The paper's step with every FES feature off at most this many times the
#: step before the FES extensions.
TARGET_PRE_FES_RATIO = 1.5
#: The last commit before the FES extensions, and the model files its Muscle needs.
PRE_FES_COMMIT = '7e42f4f'
PRE_FES_FILES = ('curves', 'memory', 'params', 'muscle')
#: Name of the package the pre-FES files are loaded as.
PRE_FES_PACKAGE = '_pre_fes_model'


def params_for(changes: dict, n_units: int) -> MuscleParams:
    return MuscleParams(n_units=n_units, **CURVE, **changes)


def protocol_inputs() -> tuple[list[float], list[float]]:
    """Command u and dl_MT at every sample of the alternating protocol."""
    t = sample_times(PROTOCOL_S, RATE_HZ)
    high = np.mod(t, PW_PERIOD_S) >= 0.5 * PW_PERIOD_S
    pw = np.where(high, PW_HIGH_S, PW_LOW_S)
    curve = params_for({}, 1)
    u = [command_from_pulse_width(x, curve) for x in pw]
    dl = (STRETCH_M * t / PROTOCOL_S).tolist()
    return u, dl


def step_loop(muscle, u, dl, n_steps: int | None = None) -> None:
    """One call per step: command u(t_k) given at the step start, dl ramping to dl(t_k+1)."""
    step = muscle.step
    for k in range(1, (len(dl) if n_steps is None else n_steps + 1)):
        step(u[k - 1], dl[k], DT_S)


def per_step(stats: Stats, n_steps: int) -> Stats:
    return stats.scaled(1e6 / n_steps)   # [us/step]


def alternate(fns: dict[str, Callable[[], object]], runs: int,
              warmup: int = 1) -> dict[str, Stats]:
    """Wall and CPU time [s] of each function, the functions taking turns run by run.

    For a ratio of two costs: load that comes and goes hits both alike.
    """
    wall = {k: [] for k in fns}
    cpu = {k: [] for k in fns}
    for i in range(warmup + runs):
        for name, fn in fns.items():
            c0, t0 = time.process_time(), time.perf_counter()
            fn()
            t1, c1 = time.perf_counter(), time.process_time()
            if i >= warmup:
                wall[name].append(t1 - t0)
                cpu[name].append(c1 - c0)
    return {k: Stats.of(wall[k], cpu[k]) for k in fns}


def bench_steps(runs: int, u, dl) -> dict:
    """Mean cost per step over the protocol, each row at each N."""
    n_steps = len(dl) - 1
    rows = {}
    for key, label, changes in CONFIGS:
        for n in UNIT_COUNTS:
            muscle = Muscle(params_for(changes, n))
            s = per_step(repeat(lambda: step_loop(muscle, u, dl), runs,
                                setup=muscle.reset), n_steps)
            rows[(key, n)] = (s, muscle.build)
            print(f'  {key} N={n}: {s.fmt()} us/step ({muscle.build})', flush=True)
            del muscle
            gc.collect()
    return rows


def bench_single_steps(u, dl) -> dict:
    """One run per activation row and N, every step timed on its own."""
    rows = {}
    for key, _, changes in CONFIGS:
        if 'tau_act_s' not in changes:
            continue
        for n in UNIT_COUNTS:
            muscle = Muscle(params_for(changes, n))
            step, clock = muscle.step, time.perf_counter
            times, moved = [], []
            for k in range(1, len(dl)):
                m0 = muscle.n_recruited
                t0 = clock()
                step(u[k - 1], dl[k], DT_S)
                times.append(clock() - t0)
                moved.append(muscle.n_recruited != m0)
            us = np.array(times) * 1e6
            moved = np.array(moved)
            rows[(key, n)] = {
                'p50': float(np.percentile(us, 50)), 'p99': float(np.percentile(us, 99)),
                'max': float(us.max()), 'moving': int(moved.sum()), 'steps': len(us),
                'mean_moving': float(us[moved].mean()) if moved.any() else 0.0,
                'mean_still': float(us[~moved].mean()) if (~moved).any() else 0.0,
                'segments': muscle.n_runs, 'worst_at_s': float((int(us.argmax()) + 1) * DT_S),
            }
            print(f'  {key} N={n}: single steps p50 {rows[(key, n)]["p50"]:.0f} us, '
                  f'max {rows[(key, n)]["max"]:.0f} us, {muscle.n_runs} segments', flush=True)
            del muscle
            gc.collect()
    return rows


def bench_construction(runs: int) -> dict:
    rows = {}
    for key, _, changes in CONFIGS:
        if key not in NAIVE_CONFIGS:
            continue
        for n in UNIT_COUNTS:
            params = params_for(changes, n)
            rows[(key, n)] = repeat(lambda: Muscle(params), runs).scaled(1e3)   # [ms]
            print(f'  construct {key} N={n}: {rows[(key, n)].fmt()} ms', flush=True)
            gc.collect()
    return rows


def bench_naive(runs: int, u, dl) -> dict:
    """The naive per-unit version, and the package on the same steps."""
    rows = {}
    for key, _, changes in CONFIGS:
        if key not in NAIVE_CONFIGS:
            continue
        for n in UNIT_COUNTS:
            params = params_for(changes, n)
            n_steps = len(dl) - 1 if n == UNIT_COUNTS[0] else NAIVE_WINDOW_STEPS
            naive = NaiveFesMuscle(params)
            s_naive = per_step(repeat(lambda: step_loop(naive, u, dl, n_steps), runs,
                                      setup=naive.reset), n_steps)
            ours = Muscle(params)
            s_ours = per_step(repeat(lambda: step_loop(ours, u, dl, n_steps), runs,
                                     setup=ours.reset), n_steps)
            diff = None
            if n == UNIT_COUNTS[0]:
                # The same model? Largest force difference over the protocol.
                naive.reset()
                ours.reset()
                diff = max(abs(naive.step(u[k - 1], dl[k], DT_S)
                               - ours.step(u[k - 1], dl[k], DT_S).force_n)
                           for k in range(1, len(dl)))
            rows[(key, n)] = (s_naive, s_ours, n_steps, diff)
            print(f'  naive {key} N={n} ({n_steps} steps): {s_naive.fmt()} us/step, '
                  f'ours {s_ours.fmt()}', flush=True)
            del naive, ours
            gc.collect()
    return rows


def load_pre_fes_muscle():
    """``Muscle`` as it was at :data:`PRE_FES_COMMIT`, from git history.

    Its model files are written to a temporary package and imported from
    there (they import each other relatively).

    :return: (the class, None), or (None, why it could not be loaded)
    """
    try:
        with tempfile.TemporaryDirectory(prefix='pre_fes_') as tmp:
            package = Path(tmp) / PRE_FES_PACKAGE
            package.mkdir()
            (package / '__init__.py').write_text('', encoding='utf-8')
            for name in PRE_FES_FILES:
                source = subprocess.run(
                    ['git', '-C', str(REPO), 'show',
                     f'{PRE_FES_COMMIT}:hill_muscle_ros/model/{name}.py'],
                    check=True, capture_output=True, text=True).stdout
                (package / f'{name}.py').write_text(source, encoding='utf-8')
            spec = importlib.util.spec_from_file_location(
                PRE_FES_PACKAGE, package / '__init__.py',
                submodule_search_locations=[str(package)])
            module = importlib.util.module_from_spec(spec)
            sys.modules[PRE_FES_PACKAGE] = module
            try:
                spec.loader.exec_module(module)
                return importlib.import_module(f'{PRE_FES_PACKAGE}.muscle').Muscle, None
            finally:
                for name in [m for m in sys.modules if m.split('.')[0] == PRE_FES_PACKAGE]:
                    del sys.modules[name]
    except FileNotFoundError as err:
        return None, f'git is not available ({err})'
    except subprocess.CalledProcessError as err:
        return None, (f'`git show {PRE_FES_COMMIT}:...` failed: '
                      f'{err.stderr.strip() or err.returncode}')
    except Exception as err:   # report it, never fake a number
        return None, f'{type(err).__name__}: {err}'


def bench_pre_fes(runs: int) -> dict:
    """Today's paper step (defaults) against the pre-FES step on Protocol II."""
    old_cls, error = load_pre_fes_muscle()
    if old_cls is None:
        print(f'  pre-FES step not measured: {error}', flush=True)
        return {'error': error}
    protocol = Protocol.from_yaml(protocol_path('II'))
    t = sample_times(protocol.duration_s, RATE_HZ)
    r = protocol.recruitment(t, MuscleParams().pw_max_s).tolist()
    dl = protocol.dl_mt(t).tolist()
    old, new = old_cls(), Muscle(MuscleParams())
    diff = 0.0
    for k in range(1, len(dl)):
        diff = max(diff, abs(old.step(r[k - 1], dl[k], DT_S).force_n
                             - new.step(r[k - 1], dl[k], DT_S).force_n))

    def timed(muscle):
        def run():
            muscle.reset()
            step_loop(muscle, r, dl)
        return run

    stats = alternate({'old': timed(old), 'new': timed(new)}, runs)
    n_steps = len(dl) - 1
    out = {'old': per_step(stats['old'], n_steps), 'new': per_step(stats['new'], n_steps),
           'diff': diff, 'error': None, 'engine': new.build}
    print(f'  pre-FES {out["old"].fmt()} us/step, today {out["new"].fmt()} us/step', flush=True)
    return out


def run(runs: int) -> dict:
    """Every measurement of the section."""
    u, dl = protocol_inputs()
    results = {'runs': runs}
    print('FES features: step cost per feature', flush=True)
    results['steps'] = bench_steps(runs, u, dl)
    print('FES features: single steps with activation', flush=True)
    results['single'] = bench_single_steps(u, dl)
    print('FES features: naive per-unit version', flush=True)
    results['naive'] = bench_naive(runs, u, dl)
    print('FES features: construction', flush=True)
    results['construction'] = bench_construction(runs)
    print('FES features: every feature off against the pre-FES step', flush=True)
    results['pre_fes'] = bench_pre_fes(runs)
    return results


def _met(ok: bool) -> str:
    return '**met**' if ok else '**not met**'


def _cpu(s: Stats) -> str:
    return f'{s.cpu.median:.3g}' if s.cpu is not None else '-'


def write_section(add, results: dict) -> None:
    """Section 7 of BENCHMARKS.md from :func:`run`'s results."""
    steps, single = results['steps'], results['single']
    naive, construction, pre = results['naive'], results['construction'], results['pre_fes']
    n_lo, n_hi = UNIT_COUNTS
    add('## 7. FES features')
    add('')
    add('`benchmarks/bench_fes.py`. `Muscle.step`, one call per 1 ms step (the node\'s path), '
        'on the build `Muscle` takes by default (the build column; every row runs the same '
        'kernels, `model/muscle/kernels.py`, the features switched by the parameters), '
        f'multi/initial unless said, on a {PROTOCOL_S:g} s protocol: the pulse width '
        f'alternates every {PW_PERIOD_S / 2:g} s between {PW_LOW_S * 1e6:g} and '
        f'{PW_HIGH_S * 1e6:g} us (u = {command_from_pulse_width(PW_LOW_S, params_for({}, 1)):.2f} '
        f'and {command_from_pulse_width(PW_HIGH_S, params_for({}, 1)):.2f} on Ding\'s '
        'exponential curve, threshold 131.4 us, scale 194.1 us, which every row uses), so '
        f'the recruitment changes every second, while the MTU is stretched by '
        f'{STRETCH_M * 1e3:g} mm at a constant rate. Cost per step = the whole run / '
        f'{round(PROTOCOL_S * RATE_HZ)} steps. Fatigue is Riener\'s law at its defaults; '
        'two types: half the units each, force weights 1 and 2, random order (seed 0).')
    add('')
    add(f'| features on | build | N = {n_lo:,} wall [us/step] | N = {n_hi:,} wall [us/step] '
        '| ratio (wall) | ratio (CPU) |')
    add('| --- | --- | ---: | ---: | ---: | ---: |')
    for key, label, _ in CONFIGS:
        (a, engine), (b, _) = steps[(key, n_lo)], steps[(key, n_hi)]
        add(f'| {label} | {engine} | {a.fmt()} | {b.fmt()} | {b.median / a.median:.2f} | '
            f'{b.cpu.median / a.cpu.median:.2f} |')
    add('')
    (a, _), (b, _) = steps[('target', n_lo)], steps[('target', n_hi)]
    ratio = b.median / a.median
    add(f'- Target: with fatigue, two fibre types in random order and a length spread, a '
        f'step at N = {n_hi:,} at most {TARGET_N_RATIO:g}x one at N = {n_lo:,}, the '
        f'recruitment changing every second: **{ratio:.2f}x** (wall medians; '
        f'{b.cpu.median / a.cpu.median:.2f}x in CPU time) — {_met(ratio <= TARGET_N_RATIO)}.')
    (a, _), (b, _) = steps[('all', n_lo)], steps[('all', n_hi)]
    add(f'- With every feature on (activation included) the same ratio is '
        f'**{b.median / a.median:.1f}x**: see the next table.')
    add('')

    add('### Activation dynamics: where the cost goes')
    add('')
    curve = params_for({}, 1)
    du = (command_from_pulse_width(PW_HIGH_S, curve)
          - command_from_pulse_width(PW_LOW_S, curve))
    # Units recruited in the first step after a rise: N du (1 - exp(-dt / tau_act)).
    first_step = n_hi * du * -np.expm1(-DT_S / ACTIVATION['tau_act_s'])
    # Units a decay has still to release when u rises again: N du exp(-(T/2 - emd) / tau_deact).
    left = [n * du * np.exp(-(0.5 * PW_PERIOD_S - ACTIVATION['emd_s'])
                            / ACTIVATION['tau_deact_s']) for n in UNIT_COUNTS]
    rises = ', '.join(f'{x:g}' for x in np.arange(0.5 * PW_PERIOD_S, PROTOCOL_S, PW_PERIOD_S))
    add('With activation the recruitment is a(t), which follows the delayed command with '
        f'time constants of {ACTIVATION["tau_act_s"] * 1e3:g} / '
        f'{ACTIVATION["tau_deact_s"] * 1e3:g} ms, and the step is split at every instant '
        'N a(t) crosses a unit\'s level (each unit stores the CE length of its own '
        f'recruitment instant). A change of u by {du:.2f} moves {n_lo * du:,.0f} units at '
        f'N = {n_lo:,} and {n_hi * du:,.0f} at N = {n_hi:,}, {first_step:,.0f} of them in the '
        f'first step of a rise; a decay has {left[0]:.2g} and {left[1]:.2g} units still to '
        'release when u rises again. At most `MAX_EVENTS_PER_PIECE` (64, `equations.py`) '
        'events are '
        'resolved per piece of a step, larger changes in 64 groups. One run per row, every '
        f'step timed on its own; u rises at t = {rises} s and acts '
        f'{ACTIVATION["emd_s"] * 1e3:g} ms later:')
    add('')
    add('| features on | N | mean [us/step] | single step p50 / p99 / max [us] | worst step at '
        '| steps that recruit or release | their mean [us] | other steps\' mean [us] '
        '| segments held at the end |')
    add('| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |')
    labels = {key: label for key, label, _ in CONFIGS}
    for (key, n), row in single.items():
        add(f'| {labels[key]} | {n:,} | {steps[(key, n)][0].median:.3g} | {row["p50"]:.0f} / '
            f'{row["p99"]:.0f} / {row["max"]:.0f} | t = {row["worst_at_s"]:.3f} s | '
            f'{row["moving"]:,} of {row["steps"]:,} | {row["mean_moving"]:.0f} | '
            f'{row["mean_still"]:.0f} | {row["segments"]:,} |')
    add('')
    worst = max(row['max'] for (key, n), row in single.items() if n == n_hi)
    add('Why it grows with N: a step costs the recruitment events it resolves (at most 64 '
        'per piece) times the work per event, and that work is not constant. A unit '
        'released at its own instant starts a resting segment of its own (its fitness '
        'history is its own), so with activation the memory fragments towards one segment '
        'per unit (last column). A recruitment event moves every resting segment it spans '
        'onto the recruited stack one by one, and a release moves recruited segments back '
        'the same way, so the first steps after a rise take back, one by one, all the '
        'single-unit segments the previous decay left (see when the worst step falls). The '
        'mean cost therefore grows with N until the 64-event bound and the fragmentation '
        f'saturate, and the slowest single step at N = {n_hi:,} took {worst / 1e3:.1f} ms, '
        'against a 1 ms step budget in the node. Without activation a recruitment change '
        'is one event at a step start (compare the rows of the first table).')
    add('')

    add('### Against a naive per-unit NumPy implementation')
    add('')
    add('`benchmarks/naive.py` `NaiveFesMuscle`: the same model with one array slot per unit '
        '(fibre type, maximal force, length scale, fitness, stored isometric force), every '
        'unit\'s fitness updated with its exact exponential every step and the recruited '
        'units summed at the RK4 stage times; the same RK4 and scalar curves. It holds the '
        'recruitment over each step (no splitting at recruitment instants). Max |force '
        f'difference| is over the whole protocol at N = {n_lo:,}: without activation the two '
        'must agree to rounding (the same model, so this checks the baseline); with it, it '
        f'is the error of holding R over a step. At N = {n_hi:,} both are timed on the '
        f'protocol\'s first {NAIVE_WINDOW_STEPS} steps only (the naive version would take '
        'minutes a run over the whole protocol; its work is the same every step).')
    add('')
    add('| features on | N | steps timed | naive wall [us/step] | CPU | `Muscle.step` wall '
        '[us/step] | CPU | naive / ours | max \\|force difference\\| [N] |')
    add('| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |')
    for (key, n), (s_naive, s_ours, n_steps, diff) in naive.items():
        add(f'| {labels[key]} | {n:,} | {n_steps:,} | {s_naive.fmt()} | {_cpu(s_naive)} | '
            f'{s_ours.fmt()} | {_cpu(s_ours)} | {s_naive.median / s_ours.median:.3g}x | '
            f'{"-" if diff is None else f"{diff:.2g}"} |')
    add('')

    add('### Construction')
    add('')
    add('`Muscle(params)`: its one-muscle bundle of flat arrays (`FesBundle`, laid out and '
        'filled), the fibre-type layout, and with a random order or a length spread the '
        'permutation and the per-type prefix sums of 1, c and c^2 over the positions '
        '(3 K (N + 1) floats). Not part of a step.')
    add('')
    add('| features on | N | wall [ms] | CPU [ms] |')
    add('| --- | ---: | ---: | ---: |')
    for (key, n), s in construction.items():
        add(f'| {labels[key]} | {n:,} | {s.fmt()} | {_cpu(s)} |')
    add('')

    add('### Every feature off against the step before the FES extensions')
    add('')
    if pre.get('error'):
        add(f'Not measured: the pre-FES `Muscle` (commit `{PRE_FES_COMMIT}`) could not be '
            f'loaded from git history: {pre["error"]}.')
        return
    old, new = pre['old'], pre['new']
    ratio = new.median / old.median
    add(f'Protocol II at 1 kHz, `Muscle.step` one call per step, multi/initial, N = 1000, '
        f'default parameters. The pre-FES `Muscle` is `hill_muscle_ros/model/muscle.py` of '
        f'commit `{PRE_FES_COMMIT}` with the `curves`, `memory` and `params` modules of that '
        'commit, read with `git show` and imported from a temporary package; the two take '
        f'turns run by run. Today\'s `Muscle` runs the one engine\'s kernels, here on its '
        f'{pre["engine"]} build. '
        + ('Their forces are identical over the protocol.' if pre['diff'] == 0.0 else
           f'Their forces differ by at most {pre["diff"]:.2g} N over the protocol.'))
    add('')
    add('| `Muscle` | wall [us/step] | CPU [us/step] |')
    add('| --- | ---: | ---: |')
    add(f'| before the FES extensions (`{PRE_FES_COMMIT}`) | {old.fmt()} | {_cpu(old)} |')
    add(f'| today, every FES feature off | {new.fmt()} | {_cpu(new)} |')
    add('')
    line = (f'- Target: the scalar step with every FES feature off at most '
            f'{TARGET_PRE_FES_RATIO:g}x the pre-FES step: **{ratio:.2f}x** (wall medians; '
            f'{new.cpu.median / old.cpu.median:.2f}x in CPU time) — '
            f'{_met(ratio <= TARGET_PRE_FES_RATIO)}.')
    if ratio > TARGET_PRE_FES_RATIO:
        line += (' Missed since the muscle is written once: one `Muscle.step` is now a call '
                 'into the compiled kernels through the facade, a fixed cost of a few us a '
                 'call (the checks, numba\'s dispatch, the bundle\'s arrays, the '
                 '`MuscleOutputs`; "One muscle\'s offline run" splits it), about what the '
                 'pre-FES muscle\'s whole Python step cost. A whole run pays the call once '
                 '(`simulate()`, `Muscle.run_array`: the same section).')
    add(line)
