"""The cost of ``hill-muscle fit``: section 8 of BENCHMARKS.md (``make bench``).

A three-parameter fit (``f_iso_max_n``, ``k_se_n_per_m``, ``fv_a_n``, off
their defaults) of Protocol II at 1 kHz (6 s, 6001 force samples), from a bag
written by ``hill-muscle simulate --bag``, started from the defaults:

- :func:`hill_muscle_ros.fit.fit_parameters` alone (the least squares, every
  replay of the recording included), and
- reading the bag into a recording (:func:`hill_muscle_ros.fit.load_muscle_recording`).

The goal: the whole fit within :data:`FIT_TARGET_S` on this 2-core machine.

Run this section alone while developing (prints its Markdown)::

    .venv/bin/python benchmarks/run_all.py --only fit --runs 5
"""
from __future__ import annotations

import tempfile
from pathlib import Path

import yaml

from timing import repeat

from hill_muscle_ros import cli, fit
from hill_muscle_ros.model import MuscleParams

#: The parameters of the simulated subject, off the defaults (45 N, 10 kN/m, 10 N).
TRUTH = {'f_iso_max_n': 52.0, 'k_se_n_per_m': 8000.0, 'fv_a_n': 13.0}
#: [s] goal for the three-parameter fit of a 6 s protocol.
FIT_TARGET_S = 10.0


def _truth_bag(root: Path) -> Path:
    params = root / 'truth.yaml'
    params.write_text(yaml.safe_dump({'/**': {'ros__parameters': dict(TRUTH)}}))
    bag = root / 'bag'
    if cli.main(['simulate', '--protocol', 'II', '--params', str(params), '--bag',
                 str(bag), '--csv', str(root / 'run.csv')]) != 0:
        raise RuntimeError('hill-muscle simulate --bag failed')
    return bag


def run(runs: int) -> dict:
    """Median, min and max of the load and of the fit, over ``runs`` runs each."""
    with tempfile.TemporaryDirectory() as tmp:
        bag = _truth_bag(Path(tmp))
        load = repeat(lambda: fit.load_muscle_recording(bag), runs)
        recording = fit.load_muscle_recording(bag)
        start = MuscleParams()
        names = fit.parse_fit_names(','.join(TRUTH), start)
        last = {}

        def one_fit():
            last['result'] = fit.fit_parameters(fit.MuscleReplay(recording),
                                                recording.force_n, start, names)
        solve = repeat(one_fit, runs)
    result = last['result']
    return {'load': load, 'fit': solve, 'samples': len(recording.force_n),
            'estimates': list(result.estimates), 'evaluations': result.n_evaluations}


def write_section(add, results: dict) -> None:
    """Section 8 of BENCHMARKS.md from :func:`run`'s results."""
    load, solve = results['load'], results['fit']
    total = load.median + solve.median
    add('## 8. Fitting a recording: `hill-muscle fit`')
    add('')
    add('`benchmarks/bench_fit.py`. Protocol II at 1 kHz written by `hill-muscle simulate '
        f'--bag` with {", ".join(f"`{k}` = {v:g}" for k, v in TRUTH.items())}; the fit of '
        f'those three from the defaults, on {results["samples"]} force samples.')
    add('')
    add('| part | wall [s] |')
    add('| --- | ---: |')
    add(f'| reading the bag (`load_muscle_recording`) | {load.fmt()} |')
    add(f'| the least squares (`fit_parameters`, {results["evaluations"]} evaluations) '
        f'| {solve.fmt()} |')
    add('')
    add(f'- Estimates: {", ".join(f"{v:.6g}" for v in results["estimates"])} '
        f'(truth {", ".join(f"{v:g}" for v in TRUTH.values())}).')
    ok = total <= FIT_TARGET_S
    add(f'- Target: the three-parameter fit of a 6 s protocol within {FIT_TARGET_S:g} s: '
        f'**{total:.2f} s** (medians of both parts) — {"met" if ok else "NOT met"}.')
    add('')
