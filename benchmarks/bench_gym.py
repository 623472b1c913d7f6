"""The Gymnasium vector environments: the section "Gymnasium vector
environments" of BENCHMARKS.md (``make bench``).

For each environment, K = :data:`NUM_ENVS` sub-environments with their default
settings (ForceTracking-v0: the paper's muscle, every FES feature off;
KneeAngle-v0: the knee preset, whose muscles have delay, activation and
fatigue on) stepped with the same seeded random actions, uniform in the
action Box, by

- the native vector environment, ``gymnasium.make_vec(id, num_envs=K)``
  (:mod:`hill_muscle_ros.gym.vector`), and
- ``gymnasium.vector.SyncVectorEnv`` of K single environments, the one
  gymnasium builds around any environment.

A run is the timed vector steps of :data:`ENVS` after a seeded reset and its
untimed steps; the two are timed alternately, run by run, so that load from other
processes falls on both alike. The rate is environment steps (control periods
of one sub-environment) per second of wall time, and the ratio is that of the
two medians.

The goal: the native ForceTracking vector environment at least
:data:`TARGET_RATIO` times as fast as SyncVectorEnv at K = 256.

Run this section alone while developing (prints its Markdown)::

    .venv/bin/python benchmarks/run_all.py --only gym --runs 5
"""
from __future__ import annotations

import functools
import time
from pathlib import Path

import gymnasium as gym
import numpy as np
from gymnasium.vector import SyncVectorEnv

from timing import Stats

import hill_muscle_ros.gym as hgym
from hill_muscle_ros.model.limb import kernels as limb_kernels

#: [-] Sub-environments per vector environment.
NUM_ENVS = 256
#: [-] Goal: native over SyncVectorEnv, ForceTracking-v0 at K = NUM_ENVS.
TARGET_RATIO = 20.0
#: Per row: the environment id, its keyword arguments (both vector forms get
#: them; SyncVectorEnv gets the bare single class, no wrappers), the vector
#: steps after the reset that are not timed, and those timed: ForceTracking,
#: the first second of each episode (20 ms periods); the knee, periods after
#: the first, whose limb steps cost far more (1000 units with per-unit fatigue
#: in each of two muscles, and the joint): 20 on the compiled limb (about 0.5 ms
#: per period and limb), 1 on the Python limb (20-45 ms per period and limb,
#: 5-12 s per vector step here). The knee's first period is not timed: the
#: preset's 31 ms delay leaves it without recruitment.
ENVS = {'ForceTracking-v0': (hgym.FORCE_TRACKING_ID, {}, 0, 50),
        'KneeAngle-v0, compiled limb': (hgym.KNEE_ANGLE_ID, {'engine': 'compiled'}, 1, 20),
        'KneeAngle-v0, Python limb': (hgym.KNEE_ANGLE_ID, {'engine': 'python'}, 1, 1)}
#: The single environment class of each id.
SINGLE = {hgym.FORCE_TRACKING_ID: hgym.ForceTrackingEnv,
          hgym.KNEE_ANGLE_ID: hgym.KneeAngleEnv}
#: Rows of the knee on each engine, for the speed-up line.
KNEE_COMPILED, KNEE_PYTHON = 'KneeAngle-v0, compiled limb', 'KneeAngle-v0, Python limb'
#: Seed of the episodes and of the actions.
SEED = 20240601
#: The output of one run of examples/train_force_tracking.py, recorded by hand
#: (its '#' lines say how): the training takes minutes, too long for make bench.
TRAINING_RUN = Path(__file__).resolve().parent / 'gym_training_run.txt'


def _actions(space: gym.spaces.Box, n_steps: int, seed: int) -> list[np.ndarray]:
    """``n_steps`` batches of K actions uniform in the single action Box."""
    rng = np.random.default_rng(seed)
    return [rng.uniform(space.low, space.high, size=(NUM_ENVS, space.shape[0]))
            .astype(np.float32) for _ in range(n_steps)]


def _timed(env, actions: list[np.ndarray], skip: int) -> tuple[float, float]:
    """Wall and CPU time [s] of stepping ``env`` through ``actions`` from a
    seeded reset, the first ``skip`` of them untimed."""
    env.reset(seed=SEED)
    for a in actions[:skip]:
        env.step(a)
    c0, t0 = time.process_time(), time.perf_counter()
    for a in actions[skip:]:
        env.step(a)
    return time.perf_counter() - t0, time.process_time() - c0


def _compare(label: str, runs: int) -> dict:
    """Native and SyncVectorEnv rates [env steps/s] of row ``label``, measured alternately."""
    env_id, kwargs, skip, n_steps = ENVS[label]
    single = functools.partial(SINGLE[env_id], **kwargs)
    # The first compiled knee of the process loads the compiled limb here.
    was_loaded = limb_kernels.loaded()
    t0 = time.perf_counter()
    native = gym.make_vec(env_id, num_envs=NUM_ENVS, **kwargs)
    construct_s = time.perf_counter() - t0
    sync = SyncVectorEnv([single for _ in range(NUM_ENVS)])
    actions = _actions(sync.single_action_space, skip + n_steps, SEED)
    # Warm-up: first calls, caches, the batch engine's compiled kernel.
    _timed(native, actions[:skip + 1], skip)
    _timed(sync, actions[:skip + 1], skip)
    wall = {'native': [], 'sync': []}
    cpu = {'native': [], 'sync': []}
    for _ in range(runs):
        for name, env in (('native', native), ('sync', sync)):
            w, c = _timed(env, actions, skip)
            wall[name].append(w)
            cpu[name].append(c)
    n = NUM_ENVS * n_steps
    rates = {name: Stats.of(wall[name], cpu[name]).inverted(n) for name in wall}
    native.close()
    sync.close()
    return {'native': rates['native'], 'sync': rates['sync'],
            'ratio': rates['native'].median / rates['sync'].median, 'steps': n_steps,
            'native_class': type(native.unwrapped).__name__, 'construct_s': construct_s,
            'loaded_before': was_loaded}


def run(runs: int) -> dict:
    """Every row's rates, ForceTracking first."""
    return {label: _compare(label, runs) for label in ENVS}


def write_section(add, results: dict) -> None:
    """The section of BENCHMARKS.md from :func:`run`'s results."""
    add('## Gymnasium vector environments')
    add('')
    add(f'`benchmarks/bench_gym.py`. K = {NUM_ENVS} sub-environments with default settings '
        '(ForceTracking-v0: the paper\'s muscle, FES features off; KneeAngle-v0: the knee '
        'preset, delay, activation and fatigue on), the same seeded random actions (uniform '
        'in the Box: the recruitment changes every period) for the native vector '
        'environment (`gymnasium.make_vec`) and for `gymnasium.vector.SyncVectorEnv` of K '
        'single environments, timed alternately run by run from a seeded reset (KneeAngle: '
        'after one untimed period, which the preset\'s 31 ms delay leaves without '
        'recruitment). Rates in environment steps (20 ms control periods of one '
        'sub-environment, 20 model steps each) per second of wall time; in brackets, per '
        'second of the process\'s CPU time (all its threads). KneeAngle-v0 on each limb '
        'build (its `engine` option): the compiled kernels (the default where numba is '
        'installed) and the same functions as plain Python.')
    add('')
    add('| environment | timed vector steps per run | native [env steps/s] | SyncVectorEnv '
        '[env steps/s] | native / Sync |')
    add('| --- | ---: | ---: | ---: | ---: |')
    for label, r in results.items():
        add(f'| {label} (`{r["native_class"]}`) | {r["steps"]} | {r["native"].fmt()} '
            f'[cpu {r["native"].cpu.median:.3g}] | {r["sync"].fmt()} '
            f'[cpu {r["sync"].cpu.median:.3g}] | **{r["ratio"]:.1f}x** |')
    add('')
    ratio = results['ForceTracking-v0']['ratio']
    line = (f'- Target: the native ForceTracking-v0 vector environment at least '
            f'{TARGET_RATIO:g}x SyncVectorEnv at K = {NUM_ENVS}: **{ratio:.1f}x** — '
            f'{"met" if ratio >= TARGET_RATIO else "NOT met"}.')
    if ratio < TARGET_RATIO:
        line += (' Missed since the muscle is written once: both sides now step the same '
                 'compiled kernels, the native environment its K muscles in one `MuscleBatch` '
                 '(a serial loop over them, section 3) and each SyncVectorEnv sub-environment '
                 'its own `Muscle`, so the native one saves only SyncVectorEnv\'s '
                 'per-environment Python overhead. The 42.7x of the bench of 2026-12-04 '
                 '09:55 UTC set the vectorised compiled batch, gone now, against `Muscle`\'s '
                 'own Python step.')
    add(line)
    fast, slow = results[KNEE_COMPILED], results[KNEE_PYTHON]
    add(f'- KneeAngle-v0 (no target): native / Sync {fast["ratio"]:.1f}x on the compiled limb, '
        f'{slow["ratio"]:.1f}x on the Python limb. Its vector environment steps each limb '
        'alone (`LimbBatch`; compiled: one call per limb and period), as the single '
        'environment does, so it saves only the per-environment overhead of SyncVectorEnv, '
        'small beside the limb\'s own steps.')
    add(f'- The compiled limb against the Python limb: native '
        f'{fast["native"].median / slow["native"].median:.1f}x, SyncVectorEnv '
        f'{fast["sync"].median / slow["sync"].median:.1f}x the environment steps per second. '
        f'Building the compiled native environment (K = {NUM_ENVS}) took '
        f'{fast["construct_s"]:.2f} s'
        + (' (the compiled limb was loaded already).' if fast['loaded_before'] else
           ', loading the compiled limb from numba\'s disk cache, numba itself imported by '
           'the ForceTracking rows (when it compiles, in a clean clone, about 30 s: section '
           '"The limb and the FES muscle, compiled").'))
    add('')
    if TRAINING_RUN.exists():
        lines = TRAINING_RUN.read_text(encoding='utf-8').splitlines()
        add('### Training a policy (`examples/train_force_tracking.py`, recorded by hand)')
        add('')
        add(' '.join(line.lstrip('# ') for line in lines if line.startswith('#')))
        add('The PI is `ForceController` with its default gains and the model feedforward; '
            'both are scored on the same five seeded episodes (seeds 1000-1004).')
        add('')
        add('```text')
        for line in lines:
            if not line.startswith('#'):
                add(line)
        add('```')
        add('')
