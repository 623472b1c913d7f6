"""The cost of ``hill-muscle fit``: section 8 of BENCHMARKS.md (``make bench``).

A three-parameter fit (``f_iso_max_n``, ``k_se_n_per_m``, ``fv_a_n``, off
their defaults) of Protocol II at 1 kHz (6 s, 6001 force samples), from a bag
written by ``hill-muscle simulate --bag``, started from the defaults:

- :func:`hill_muscle_ros.tools.fit.fit_parameters` alone (the least squares, every
  replay of the recording included), and
- reading the bag into a recording (:func:`hill_muscle_ros.tools.fit.load_muscle_recording`).

The goal: the whole fit within :data:`FIT_TARGET_S` on this 2-core machine.

The limb (``hill-muscle fit --plant``), timed the same way: the ankle preset
(config/ankle.yaml) with three values off the preset (``tibialis_anterior.f_iso_max_n``,
``joint.damping_n_m_s_per_rad``, ``joint.stiffness_n_m_per_rad``), a 6 s protocol of
two lifts of the foot at 1 kHz, its bag written as the limb node publishes
(``joint_states``, ``tibialis_anterior/pulse_width``), the fit started from the
preset, ``runs`` times without a warm-up.

Run this section alone while developing (prints its Markdown)::

    .venv/bin/python benchmarks/run_all.py --only fit --runs 5
"""
from __future__ import annotations

import dataclasses
import os
import tempfile
import time
from pathlib import Path

import yaml
from rclpy.serialization import serialize_message
from rclpy.time import Time
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64

from timing import Stats, repeat

from hill_muscle_ros import resources
from hill_muscle_ros.model import MuscleParams, engine
from hill_muscle_ros.model.limb import LimbProtocol, simulate_limb
from hill_muscle_ros.params_file import load_plant
from hill_muscle_ros.recording.bag_writer import BagWriter
from hill_muscle_ros.timebase import NS_PER_S
from hill_muscle_ros.tools import cli, fit

#: The parameters of the simulated subject, off the defaults (45 N, 10 kN/m, 10 N).
TRUTH = {'f_iso_max_n': 52.0, 'k_se_n_per_m': 8000.0, 'fv_a_n': 13.0}
#: [s] goal for the three-parameter fit of a 6 s protocol.
FIT_TARGET_S = 10.0
#: The limb's subject: the ankle preset's 600 N, 0.82 N m s/rad and 20.4 N m/rad moved.
LIMB_TRUTH = {'tibialis_anterior.f_iso_max_n': 520.0, 'joint.damping_n_m_s_per_rad': 1.0,
              'joint.stiffness_n_m_per_rad': 17.0}
#: Worker processes of the parallel limb fit (``--jobs``): the machine's two cores.
LIMB_JOBS = 2
#: [s] the window of the timed ``--edge-search`` (test_fit's).
EDGE_SEARCH_S = 0.02
#: The builds the edge search is timed on (``HILL_MUSCLE_ENGINE``).
EDGE_ENGINES = (engine.COMPILED, engine.PYTHON)
#: Runs of the edge search on the plain build (each about 40 s: hundreds of
#: runs of the recording at about 0.1 ms a step), in the first rounds.
PLAIN_EDGE_RUNS = 3
#: [Hz] the limb's step rate (the preset's).
LIMB_RATE_HZ = 1000.0
#: 6 s: the foot lifted by 370 us pulses for 1.5 s, let fall, lifted again by 300 us.
LIMB_PROTOCOL = {'name': 'two ankle lifts', 'duration_s': 6.0,
                 'muscles': {'tibialis_anterior': {'pulse_width_s': [
                     [0.5, 0.0], [0.5, 0.00037], [2.0, 0.00037], [2.0, 0.0],
                     [3.5, 0.0], [3.5, 0.0003], [5.0, 0.0003], [5.0, 0.0]]}}}


def _truth_bag(root: Path) -> Path:
    params = root / 'truth.yaml'
    params.write_text(yaml.safe_dump({'/**': {'ros__parameters': dict(TRUTH)}}))
    bag = root / 'bag'
    if cli.main(['simulate', '--protocol', 'II', '--params', str(params), '--bag',
                 str(bag), '--csv', str(root / 'run.csv')]) != 0:
        raise RuntimeError('hill-muscle simulate --bag failed')
    return bag


def _limb_bag(root: Path) -> Path:
    """The truth ankle's run written as the limb node publishes it, in simulated time."""
    start, _ = load_plant(resources.config_dir() / 'ankle.yaml')
    (ta,) = start.muscles
    truth = dataclasses.replace(
        start, joint=dataclasses.replace(start.joint, damping_n_m_s_per_rad=1.0,
                                         stiffness_n_m_per_rad=17.0),
        muscles=(dataclasses.replace(ta, params=ta.params.replace(f_iso_max_n=520.0)),))
    protocol = LimbProtocol.from_mapping(LIMB_PROTOCOL)
    result = simulate_limb(truth, protocol, LIMB_RATE_HZ)
    _, knots = protocol.stimulation['tibialis_anterior']
    bag = root / 'limb_bag'
    with BagWriter(bag) as writer:
        writer.add_topic('/joint_states', 'sensor_msgs/msg/JointState')
        writer.add_topic('/tibialis_anterior/pulse_width', 'std_msgs/msg/Float64')
        state = JointState()
        state.name = [truth.joint.name]
        for k, t in enumerate(result.t_s):
            t_ns = round(float(t) * NS_PER_S)
            pw = float(knots(float(t))) if t < protocol.duration_s else 0.0
            writer.write('/tibialis_anterior/pulse_width',
                         serialize_message(Float64(data=pw)), t_ns)
            state.header.stamp = Time(nanoseconds=t_ns).to_msg()
            state.position = [float(result['theta_rad'][k])]
            writer.write('/joint_states', serialize_message(state), t_ns, t_ns)
    return bag


def run_limb(runs: int) -> dict:
    """The limb's load and fit, ``runs`` times each (no warm-up: each fit is long)."""
    with tempfile.TemporaryDirectory() as tmp:
        bag = _limb_bag(Path(tmp))
        start, _ = load_plant(resources.config_dir() / 'ankle.yaml')
        load = repeat(lambda: fit.load_limb_recording(bag, start), runs)
        recording = fit.load_limb_recording(bag, start)
        names = fit.parse_plant_fit_names(','.join(LIMB_TRUTH), start)
        replay = fit.LimbReplay(recording)
        simulation = repeat(lambda: replay.angle(start), runs, warmup=0)
        last = {}

        def one_fit():
            last['result'] = fit.fit_parameters(replay, recording.angle_rad, start, names,
                                                quantity='joint angle', unit='rad')
        solve = repeat(one_fit, runs, warmup=0)

        def parallel_fit():
            with fit.LimbReplay(recording, jobs=LIMB_JOBS) as workers:
                last['parallel'] = fit.fit_parameters(workers, recording.angle_rad, start,
                                                      names, quantity='joint angle',
                                                      unit='rad')
        # CPU: the worker processes' (reaped when the pool closes, inside the run).
        parallel = repeat(parallel_fit, runs, warmup=0, children=True)
    result = last['result']
    if list(last['parallel'].estimates) != list(result.estimates):
        raise RuntimeError('the fit in worker processes differs from the fit in one')
    return {'load': load, 'simulation': simulation, 'fit': solve, 'parallel': parallel,
            'samples': len(recording.angle_rad), 'estimates': list(result.estimates),
            'evaluations': result.n_evaluations}


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
        edge = run_edge_search(recording, start, names, runs)
    result = last['result']
    return {'load': load, 'fit': solve, 'samples': len(recording.force_n),
            'estimates': list(result.estimates), 'evaluations': result.n_evaluations,
            'edge': edge, 'limb': run_limb(runs)}


def run_edge_search(recording, start, names, runs: int) -> dict:
    """Wall and CPU time [s] of the fit with ``--edge-search`` (:data:`EDGE_SEARCH_S`)
    on each build, the runs alternating between them (``HILL_MUSCLE_ENGINE``) after
    one unrecorded compiled run (which loads the compiled muscle); the plain build
    in the first :data:`PLAIN_EDGE_RUNS` rounds only."""
    max_shift = round(EDGE_SEARCH_S * recording.rate_hz)
    wall = {name: [] for name in EDGE_ENGINES}
    cpu = {name: [] for name in EDGE_ENGINES}
    moves = {}
    saved = os.environ.get(engine.ENV_VAR)
    try:
        for i in range(runs + 1):
            for name in EDGE_ENGINES:
                if name == engine.PYTHON and not 0 < i <= PLAIN_EDGE_RUNS:
                    continue
                os.environ[engine.ENV_VAR] = name
                c0, t0 = time.process_time(), time.perf_counter()
                moves[name] = fit.fit_with_aligned_edges(recording, start, names,
                                                         max_shift)[2]
                if i:
                    wall[name].append(time.perf_counter() - t0)
                    cpu[name].append(time.process_time() - c0)
    finally:
        if saved is None:
            os.environ.pop(engine.ENV_VAR, None)
        else:
            os.environ[engine.ENV_VAR] = saved
    if moves[engine.PYTHON] != moves[engine.COMPILED]:
        raise RuntimeError(f'the edge search moved {moves} on the two engines')
    return {'stats': {e: Stats.of(wall[e], cpu[e]) for e in EDGE_ENGINES},
            'runs_expected': fit.edge_search_runs(recording, len(names), max_shift)}


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
    edge = results['edge']['stats']
    add(f'The same fit with `--edge-search {EDGE_SEARCH_S:g}` (`fit_with_aligned_edges`: '
        'fit, move each stimulation change to the best of the steps within the window, '
        'fit again until the moves settle), on each build (`HILL_MUSCLE_ENGINE`), the '
        'runs alternating after one unrecorded compiled run, the plain build in the first '
        f'{PLAIN_EDGE_RUNS} rounds only. Its replays are judged together '
        f'(at most {results["edge"]["runs_expected"]} runs of the recording). Every run is '
        'one `Muscle` on the build `HILL_MUSCLE_ENGINE` chooses: `compiled` (the default '
        'where numba is installed) or `python`, the same kernels as plain Python.')
    add('')
    add('| build | runs | wall [s] | CPU [s] |')
    add('| --- | ---: | ---: | ---: |')
    for name in EDGE_ENGINES:
        add(f'| {name} | {edge[name].runs} | {edge[name].fmt()} | {edge[name].cpu.median:.3f} |')
    add('')
    ratio = edge[engine.PYTHON].median / edge[engine.COMPILED].median
    add(f'- Plain Python / compiled: **{ratio:.1f}x** (wall medians).')
    add('')
    limb = results['limb']
    limb_total = limb['load'].median + min(limb['fit'].median, limb['parallel'].median)
    add('The limb, `hill-muscle fit --plant`: the ankle preset with '
        f'{", ".join(f"`{k}` = {v:g}" for k, v in LIMB_TRUTH.items())}, a 6 s protocol '
        '(two lifts of the foot) at 1 kHz written as the limb node publishes it; the fit '
        f'of those three from the preset, on {limb["samples"]} joint angles '
        '(median, min to max of the runs, no warm-up).')
    add('')
    add('| part | wall [s] | CPU [s] |')
    add('| --- | ---: | ---: |')
    add(f'| reading the bag (`load_limb_recording`) | {limb["load"].fmt()} | '
        f'{limb["load"].cpu.median:.3f} |')
    add(f'| one simulation of the 6 s (`simulate_limb`) | {limb["simulation"].fmt()} | '
        f'{limb["simulation"].cpu.median:.3f} |')
    add(f'| the least squares (`fit_parameters`, {limb["evaluations"]} evaluations of '
        f'4 simulations) | {limb["fit"].fmt()} | {limb["fit"].cpu.median:.3f} |')
    add(f'| the same in {LIMB_JOBS} worker processes (`--jobs {LIMB_JOBS}`; CPU of the '
        f'workers) | {limb["parallel"].fmt()} | {limb["parallel"].cpu.median:.3f} |')
    add('')
    add(f'- Estimates: {", ".join(f"{v:.6g}" for v in limb["estimates"])} '
        f'(truth {", ".join(f"{v:g}" for v in LIMB_TRUTH.values())}).')
    limb_ok = limb_total <= FIT_TARGET_S
    add(f'- The same {FIT_TARGET_S:g} s goal for the limb (the faster of the two): '
        f'**{limb_total:.2f} s** — ' + ('met.' if limb_ok else
                                          'NOT met: every evaluation runs the limb four '
                                          'times (the estimate and one forward difference '
                                          'per parameter), each in pure Python (RK4 of the '
                                          'joint and the CE on sub-steps).'))
    add('')
