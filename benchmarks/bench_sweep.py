"""Throughput of ``hill-muscle sweep``: the "Parameter sweeps" section of
BENCHMARKS.md (``make bench``).

Parameter sets per second of :func:`hill_muscle_ros.tools.sweep.run_sweep`, the
command's engine, for

- the muscle: :data:`MUSCLE_SETS` sets of Protocol II (6 s at 1 kHz), a grid
  of ``f_iso_max_n`` x ``k_se_n_per_m`` on the shipped muscle, and
- the knee: :data:`KNEE_SETS` plants of the shipped knee preset (delay,
  activation and fatigue on) replaying the knee extension to
  :data:`KNEE_SECONDS` s, a grid of the quadriceps' ``f_iso_max_n`` x the
  joint's stiffness,

each in this process (``--workers 0``, no Dask), on a fresh LocalCluster of
2 worker processes (``--workers 2``): the simulation alone (the time the
command reports, from the first task to the last result) and with the
cluster's start and stop, and on a warm LocalCluster of 2 (one cluster, a
sweep already run on it: the workers have imported the package, as with
``--scheduler``). Chunks are the command's defaults.

And the cost of a :class:`~hill_muscle_ros.model.limb.LimbBatch` step
per limb against K separate :class:`~hill_muscle_ros.model.limb.Limb` s stepped
in a loop, the knee's first second of the knee extension.

Run this section alone while developing (prints its Markdown)::

    .venv/bin/python benchmarks/run_all.py --only sweep --runs 5
"""
from __future__ import annotations

import dataclasses
import time

import numpy as np

from timing import Stats, repeat

from hill_muscle_ros.model import LimbBatch
from hill_muscle_ros.model.limb import Limb, LimbProtocol
from hill_muscle_ros.model.simulate import sample_times
from hill_muscle_ros.params_file import load_plant
from hill_muscle_ros.resources import config_dir
from hill_muscle_ros.tools import sweep

#: [Hz] step rate of every run here (the presets' and the command's default).
RATE_HZ = 1000.0
#: Muscle sweep: a 16 x 16 grid; 256 sets are one chunk per worker of 2.
MUSCLE_GRID = {'f_iso_max_n': {'low': 30.0, 'high': 60.0, 'n': 16},
               'k_se_n_per_m': {'low': 5e3, 'high': 2e4, 'n': 16, 'log': True}}
MUSCLE_SETS = 256
#: Knee sweep: 4 x 2 plants, two chunks of the automatic size (4) per worker of 2.
KNEE_GRID = {'quadriceps.f_iso_max_n': {'low': 1000.0, 'high': 1500.0, 'n': 4},
             'joint.stiffness_n_m_per_rad': [15.3, 25.0]}
KNEE_SETS = 8
#: [s] the knee sets replay the knee extension to here (stimulated from 0.5 s).
KNEE_SECONDS = 2.0
#: Limbs per batch in the LimbBatch-vs-separate-limbs comparison.
LIMB_COUNTS = (1, 8)
#: [s] the comparison steps the knee extension from 0 to here.
LIMB_WINDOW_S = 1.0
#: Workers of the LocalCluster runs.
CLUSTER_WORKERS = 2


def _specs() -> dict:
    config = config_dir()
    muscle = sweep.parse_spec({'protocol': 'II', 'sample_times_s': [1.0, 6.0],
                               'vary': MUSCLE_GRID})
    knee = sweep.parse_spec({'plant': 'knee.yaml', 'protocol': 'protocols/knee_extension.yaml',
                             'sample_times_s': [0.5 * KNEE_SECONDS, KNEE_SECONDS],
                             'vary': KNEE_GRID},
                            'bench', config)
    assert len(muscle.sets) == MUSCLE_SETS and len(knee.sets) == KNEE_SETS
    return {'muscle': muscle, 'knee': knee}


def _throughput(spec, runs: int, workers: int) -> tuple[Stats, Stats | None]:
    """Sets per second of ``run_sweep``: (simulation alone, with cluster start and stop)."""
    sim, whole = [], []
    for i in range(runs + 1):   # the first run warms up (imports, caches)
        t0 = time.perf_counter()
        result = sweep.run_sweep(spec, workers=workers)
        wall = time.perf_counter() - t0
        if not result.complete or result.n_sets != len(spec.sets):
            raise RuntimeError(f'sweep incomplete: {result.n_sets} of {len(spec.sets)} sets')
        if i:
            sim.append(result.elapsed_s)
            whole.append(wall)
        print(f'    {workers} workers: {len(spec.sets) / result.elapsed_s:.3g} sets/s '
              f'({len(spec.sets) / wall:.3g} with start-up)', flush=True)
    n = len(spec.sets)
    return (Stats.of(sim).inverted(n),
            Stats.of(whole).inverted(n) if workers else None)


def _warm_throughput(spec, runs: int) -> Stats:
    """Sets per second of ``run_on_client`` on one LocalCluster, after a first sweep."""
    import logging

    from distributed import Client, LocalCluster

    elapsed = []
    with LocalCluster(n_workers=CLUSTER_WORKERS, threads_per_worker=1, processes=True,
                      dashboard_address=None, silence_logs=logging.ERROR) as cluster, \
            Client(cluster) as client:
        for i in range(runs + 1):
            result = sweep.run_on_client(spec, client)
            if not result.complete:
                raise RuntimeError('sweep incomplete on the warm cluster')
            if i:
                elapsed.append(result.elapsed_s)
            print(f'    warm cluster: {len(spec.sets) / result.elapsed_s:.3g} sets/s',
                  flush=True)
    return Stats.of(elapsed).inverted(len(spec.sets))


def _limb_costs(runs: int) -> dict:
    """[us] per limb-step: LimbBatch of K knees vs K separate Limbs, same commands."""
    config = config_dir()
    base = load_plant(config / 'knee.yaml')[0]
    protocol = LimbProtocol.from_yaml(config / 'protocols' / 'knee_extension.yaml')
    t = sample_times(LIMB_WINDOW_S, RATE_HZ)
    n_steps = len(t) - 1
    dt = 1.0 / RATE_HZ
    rows = {}
    for k in LIMB_COUNTS:
        quad = base.muscles[0]
        plants = [dataclasses.replace(base, muscles=(dataclasses.replace(
            quad, params=dataclasses.replace(quad.params, f_iso_max_n=f)), base.muscles[1]))
            for f in np.linspace(1000.0, 1500.0, k)]
        u = np.stack([protocol.commands(t, p) for p in plants], axis=1)   # (steps, K, M)
        batch = LimbBatch(plants)
        limbs = [Limb(p) for p in plants]

        def run_batch():
            step = batch.step_commands
            for j in range(n_steps):
                step(u[j], 0.0, dt)

        def reset_limbs():
            for limb in limbs:
                limb.reset()

        def run_limbs():
            for j in range(n_steps):
                for i, limb in enumerate(limbs):
                    limb.step(u[j, i], 0.0, dt)

        s_batch = repeat(run_batch, runs, setup=batch.reset).scaled(1e6 / (k * n_steps))
        s_limbs = repeat(run_limbs, runs, setup=reset_limbs).scaled(1e6 / (k * n_steps))
        rows[k] = (s_batch, s_limbs)
        print(f'  K={k}: LimbBatch {s_batch.fmt()} us/limb-step, separate Limbs '
              f'{s_limbs.fmt()}', flush=True)
    return rows


def run(runs: int) -> dict:
    """Every measurement of the section, ``runs`` runs each (medians, min and max)."""
    specs = _specs()
    out = {'throughput': {}, 'chunks': {}}
    for name, spec in specs.items():
        print(f'  {name}: {len(spec.sets)} sets', flush=True)
        out['throughput'][name] = {w: _throughput(spec, runs, w)
                                   for w in (0, CLUSTER_WORKERS)}
        out['throughput'][name]['warm'] = _warm_throughput(spec, runs)
        out['chunks'][name] = [len(r) for r in sweep.chunk_ranges(
            len(spec.sets), CLUSTER_WORKERS, None, sweep.execution._max_chunk(spec))]
    out['limb'] = _limb_costs(runs)
    return out


def write_section(add, results: dict) -> None:
    """The "Parameter sweeps" section of BENCHMARKS.md from :func:`run`'s results."""
    def cpu(s: Stats) -> str:
        return s.cpu.fmt() if s.cpu else '-'

    add('## 9. Parameter sweeps')
    add('')
    add('`benchmarks/bench_sweep.py`: parameter sets per second of `hill-muscle sweep`\'s '
        'engine (`hill_muscle_ros.tools.sweep.run_sweep`) in this process (`--workers 0`, '
        f'no Dask) and on a fresh LocalCluster of {CLUSTER_WORKERS} worker processes '
        f'(`--workers {CLUSTER_WORKERS}`), default chunks. "Simulation" is the time the '
        'command reports (first task to last result), which on a fresh cluster includes '
        'each worker importing the package for its first task; "with start-up" adds '
        'starting and stopping the cluster; "warm" reuses one cluster that has already run '
        'the sweep once (as a running cluster given by `--scheduler` would). Median (min to '
        'max) of the runs; the machine has 2 cores shared with the rest of the load, so 2 '
        'workers can at best double the rate.')
    add('')
    add('| sweep | sets | chunks on 2 workers | in-process [sets/s] | 2 workers, fresh: '
        'simulation [sets/s] | fresh, with start-up [sets/s] | 2 workers, warm [sets/s] |')
    add('| --- | ---: | --- | ---: | ---: | ---: | ---: |')
    labels = {'muscle': 'muscle: Protocol II (6 s), `f_iso_max_n` x `k_se_n_per_m`',
              'knee': f'knee preset: knee extension to {KNEE_SECONDS:g} s, quadriceps '
                      '`f_iso_max_n` x joint stiffness'}
    for name, rows in results['throughput'].items():
        local, _ = rows[0]
        sim, whole = rows[CLUSTER_WORKERS]
        n = MUSCLE_SETS if name == 'muscle' else KNEE_SETS
        chunks = ' + '.join(str(c) for c in results['chunks'][name])
        add(f'| {labels[name]} | {n} | {chunks} | {local.fmt()} | {sim.fmt()} | '
            f'{whole.fmt()} | {rows["warm"].fmt()} |')
    add('')
    for name, rows in results['throughput'].items():
        local, warm = rows[0][0].median, rows['warm'].median
        add(f'- {name}: 2 warm workers run {warm / local:.2f}x the in-process rate (wall '
            'medians).')
    add('- Two workers can only gain where two cores are free: with a load average above the '
        'core count (the comment above) they compete with the rest of the machine for the '
        'same cores, and a fresh cluster also pays for its start and for importing the '
        'package in each worker.')
    add('')
    add('### A batch of limbs against separate limbs')
    add('')
    add('`LimbBatch.step_commands` on K knee plants (the quadriceps\' `f_iso_max_n` from '
        f'1000 to 1500 N) against K `Limb.step` calls in a loop, the same commands: the '
        f'first {LIMB_WINDOW_S:g} s of the knee extension at 1 kHz (stimulation from 0.5 s). '
        'Cost per limb and step.')
    add('')
    add('| K | LimbBatch wall [us/limb-step] | CPU | separate Limbs wall [us/limb-step] | CPU '
        '| batch / separate (wall medians) |')
    add('| ---: | ---: | ---: | ---: | ---: | ---: |')
    for k, (s_batch, s_limbs) in results['limb'].items():
        add(f'| {k} | {s_batch.fmt()} | {cpu(s_batch)} | {s_limbs.fmt()} | {cpu(s_limbs)} | '
            f'{s_batch.median / s_limbs.median:.2f} |')
    add('')
    add('- The batch steps each limb with its own `Limb` (every limb has its own '
        'recruitment instants within a step), so it costs what K separate limbs cost plus '
        'gathering the arrays; a knee sweep is bound by the limb\'s step, the limb\'s and '
        'the muscle\'s kernels on the build `HILL_MUSCLE_ENGINE` chooses (compiled where '
        'numba imports).')
    add('')
