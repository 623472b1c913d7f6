"""BENCHMARKS.md section "One muscle's offline run, compiled": ``kernels.run_compiled``.

One run measures, on the same machine state:

- the cost a step of one muscle's offline run (multi/initial, N = 1000, 1 ms
  steps) on the compiled run (``kernels.run_compiled``, as ``simulate`` calls
  it), against MuJoCo's muscle actuator stepped from Python
  (``peers.mujoco_runner``) and against the pure-Python loop (``Muscle.run``
  with list columns, as ``simulate`` calls it), on Protocol II and on a
  protocol whose R changes on every step (a triangle, 0 to 1 in each odd
  second, back in each even one); each ratio from back-to-back pairs,
  alternating which side runs first;
- the 60 s protocol's real-time factor in-process: the whole
  ``cli.main(['simulate', ...])`` and ``simulate()`` alone, with the compiled
  run loaded, and on the Python loop;
- the start-up of ``hill-muscle simulate`` on a 1 ms protocol: as it is
  (``HILL_MUSCLE_ENGINE`` unset: so short a run stays on the Python loop),
  and with ``HILL_MUSCLE_ENGINE=compiled`` with a filled and with an empty
  ``NUMBA_CACHE_DIR``; and loading the compiled run alone;
- one call's cost, for the simulator node's once-a-tick ``Muscle.step``:
  the Python step against the compiled kernel called for one step.

Run alone: ``.venv/bin/python benchmarks/run_all.py --only single --runs 5``.
"""
from __future__ import annotations

import compileall
import contextlib
import io
import json
import os
import shlex
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from timing import RUNS_PER_SAMPLE, Stats, repeat

from hill_muscle_ros.model import (Muscle, MuscleOutputs, MuscleParams, Protocol, engine,
                                   kernels, simulate)
from hill_muscle_ros.model.simulate import sample_times
from hill_muscle_ros.resources import protocol_path

HERE = Path(__file__).resolve().parent
REPO = HERE.parent
PROTOCOL_60S = HERE / 'protocol_60s.yaml'
PROTOCOL_STARTUP = HERE / 'protocol_startup.yaml'
DT_S = 1e-3
RATE_HZ = 1000.0
#: Back-to-back pairs per ratio (after one warm-up pair).
PAIRS = 21
#: [s] the triangle protocol: Protocol II's length, R 0 -> 1 -> 0 with period 2 s.
TRIANGLE_PERIOD_S = 2.0
#: Calls per timing of a single step (the node's case).
STEP_CALLS = 20_000

# The targets.
TARGET_VS_MUJOCO = 0.1
TARGET_VS_PYTHON = 0.05
TARGET_RTF = 5000.0
TARGET_STARTUP_S = 1.0

#: In a new interpreter: import numba, then build (load or compile) the
#: compiled run and call it once; prints both as JSON: [s] wall and CPU.
LOAD_RUN = '''
import json, time
t0, c0 = time.perf_counter(), time.process_time()
import numba
t1, c1 = time.perf_counter(), time.process_time()
import numpy as np
from hill_muscle_ros.model import Muscle, kernels
from hill_muscle_ros.tools import cli
t2, c2 = time.perf_counter(), time.process_time()
kernels.run_compiled(Muscle(), np.full(2, 0.5), np.zeros(2), 1e-3)
t3, c3 = time.perf_counter(), time.process_time()
print(json.dumps({'import': [t1 - t0, c1 - c0], 'load': [t3 - t2, c3 - c2]}))
'''


def protocols() -> dict:
    """[-] R and [m] dl_MT at the 1 kHz samples of the two protocols."""
    ii = Protocol.from_yaml(protocol_path('II'))
    t = sample_times(ii.duration_s, RATE_HZ)
    r_ii = np.asarray(ii.command(t, MuscleParams()), dtype=float)
    dl = np.asarray(ii.dl_mt(t), dtype=float)
    phase = (t % TRIANGLE_PERIOD_S) / (0.5 * TRIANGLE_PERIOD_S)
    r_tri = np.where(phase <= 1.0, phase, 2.0 - phase)
    return {'Protocol II': (r_ii, dl),
            'R triangle 0 -> 1 -> 0 every 2 s (R changes every step), Protocol II\'s length':
                (r_tri, dl)}


def compiled_runner(muscle: Muscle, r, dl):
    """One offline run on the compiled loop, as ``simulate`` makes it."""
    r_start, dl_end, r_end = r[:-1].copy(), dl[1:].copy(), r[1:].copy()

    def run():
        muscle.reset()
        muscle.set_recruitment(float(r[0]))
        kernels.run_compiled(muscle, r_start, dl_end, DT_S, r_end)
    return run


def python_runner(muscle: Muscle, r, dl):
    """One offline run on the Python loop, as ``simulate`` makes it (list columns)."""
    r_list, dl_list = r.tolist(), dl.tolist()
    n = len(dl_list) - 1

    def run():
        muscle.reset()
        muscle.set_recruitment(r_list[0])
        columns = [[0.0] * n for _ in range(12)]
        muscle.run(r_list[:-1], dl_list[1:], DT_S, r_end=r_list[1:], columns=columns)
    return run


def paired(a, b, pairs: int = PAIRS, runs_per_sample: int = RUNS_PER_SAMPLE) -> tuple:
    """Times of ``a`` and ``b`` and the ratio a / b over back-to-back pairs.

    The order alternates from pair to pair, so that a load change on the
    shared machine does not always hit the same side; one warm-up pair first.
    Each side of a pair is ``runs_per_sample`` consecutive calls.

    :return: (Stats of a [s], Stats of b [s], Stats of a / b), a call's time
        (a sample's over ``runs_per_sample``)
    """
    ta, tb, ratios = [], [], []
    for i in range(pairs + 1):
        times = {}
        for name, fn in ((('a', a), ('b', b)) if i % 2 == 0 else (('b', b), ('a', a))):
            t0 = time.perf_counter()
            for _ in range(runs_per_sample):
                fn()
            times[name] = (time.perf_counter() - t0) / runs_per_sample
        if i > 0:
            ta.append(times['a'])
            tb.append(times['b'])
            ratios.append(times['a'] / times['b'])
    return Stats.of(ta), Stats.of(tb), Stats.of(ratios)


def bench_per_step() -> dict:
    from peers import mujoco_runner
    import mujoco
    rows = {}
    for name, (r, dl) in protocols().items():
        n_steps = len(dl) - 1
        muscle = Muscle(MuscleParams())
        comp = compiled_runner(muscle, r, dl)
        mj = mujoco_runner(r.tolist(), dl.tolist(), DT_S)
        py = python_runner(Muscle(MuscleParams()), r, dl)
        s_c, s_mj, vs_mj = paired(comp, mj)
        s_c2, s_py, vs_py = paired(comp, py)
        rows[name] = {'n_steps': n_steps, 'compiled': s_c.scaled(1e6 / n_steps),
                      'compiled_2': s_c2.scaled(1e6 / n_steps),
                      'mujoco': s_mj.scaled(1e6 / n_steps), 'python': s_py.scaled(1e6 / n_steps),
                      'vs_mujoco': vs_mj, 'vs_python': vs_py}
        print(f'  {name}: compiled {rows[name]["compiled"].fmt()} us/step, '
              f'/MuJoCo {vs_mj.fmt()}, /Python {vs_py.fmt()}', flush=True)
    return {'rows': rows, 'mujoco': mujoco.__version__}


def bench_rtf(runs: int) -> dict:
    """The 60 s protocol in-process: cli.main and simulate(), compiled (loaded) and Python."""
    args = ['simulate', '--protocol', str(PROTOCOL_60S), '--rate', f'{RATE_HZ:g}']
    protocol = Protocol.from_yaml(PROTOCOL_60S)
    params = MuscleParams()

    def whole():
        with contextlib.redirect_stdout(io.StringIO()):
            if cli.main(args) != 0:
                raise RuntimeError(f'hill-muscle {shlex.join(args)} failed')

    result = {}
    for value in ('auto', 'python'):
        os.environ[engine.ENV_VAR] = value
        try:
            result[value] = (repeat(whole, runs), repeat(lambda: simulate(protocol, params), runs))
        finally:
            del os.environ[engine.ENV_VAR]
        print(f'  60 s protocol, {value}: cli.main {result[value][0].fmt()} s, '
              f'simulate {result[value][1].fmt()} s', flush=True)
    result['duration_s'] = protocol.duration_s
    result['label'] = shlex.join(['.venv/bin/hill-muscle', 'simulate', '--protocol',
                                  PROTOCOL_60S.relative_to(REPO).as_posix(),
                                  '--rate', f'{RATE_HZ:g}'])
    return result


def bench_startup(runs: int) -> dict:
    """`hill-muscle simulate` on a 1 ms protocol as a process: as it is, compiled warm and cold."""
    exe = REPO / '.venv' / 'bin' / 'hill-muscle'
    if not exe.exists():
        exe = Path(sys.executable).with_name('hill-muscle')
    cmd = [str(exe), 'simulate', '--protocol', str(PROTOCOL_STARTUP), '--rate', f'{RATE_HZ:g}']
    # The package's bytecode first, as installing a package writes it (`make
    # bench` does too): the editable install writes none ahead, and under
    # PYTHONDONTWRITEBYTECODE every start compiled the package's source again.
    compileall.compile_dir(str(REPO / 'hill_muscle_ros'), quiet=1)
    base = {k: v for k, v in os.environ.items() if k != engine.ENV_VAR}
    result = {}

    def start(env):
        subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL, env=env)

    result['auto'] = repeat(lambda: start(base), runs, children=True)
    with tempfile.TemporaryDirectory(prefix='numba_cache_') as root:
        env = dict(base, **{engine.ENV_VAR: 'compiled', 'NUMBA_CACHE_DIR': root})
        start(env)   # fills the cache
        result['warm'] = repeat(lambda: start(env), runs, children=True)
        cold_dirs = iter(range(runs + 1))
        result['cold'] = repeat(
            lambda: start(dict(env, NUMBA_CACHE_DIR=os.path.join(root, str(next(cold_dirs))))),
            runs, children=True)
        loads = {'import': [], 'load': [], 'compile': []}
        for i in range(runs):
            for case, cache in (('compile', os.path.join(root, f'l{i}')),
                                ('load', os.path.join(root, f'l{i}'))):
                out = subprocess.run([sys.executable, '-c', LOAD_RUN], check=True, text=True,
                                     capture_output=True,
                                     env=dict(base, NUMBA_CACHE_DIR=cache)).stdout
                got = json.loads(out.strip().splitlines()[-1])
                loads[case].append(got['load'])
                loads['import'].append(got['import'])
        for case, values in loads.items():
            result[f'run_{case}'] = Stats.of([w for w, _ in values], [c for _, c in values])
    result['label'] = shlex.join(['.venv/bin/hill-muscle', 'simulate', '--protocol',
                                  PROTOCOL_STARTUP.relative_to(REPO).as_posix(),
                                  '--rate', f'{RATE_HZ:g}'])
    for case in ('auto', 'warm', 'cold', 'run_import', 'run_load', 'run_compile'):
        print(f'  {case}: {result[case].fmt()} s', flush=True)
    return result


def bench_single_step(runs: int) -> dict:
    """One step a call, as the node makes it: Muscle.step against the compiled kernel."""
    muscle = Muscle(MuscleParams())
    run = kernels.compiled_run().run_muscle
    r1, dl1, out = np.full(1, 0.5), np.zeros(1), np.empty((kernels.N_RUN_OUTPUTS, 1))
    state = np.zeros(kernels.N_STATE)
    state[kernels.S_L_CE] = muscle.params.l_rest_m
    params = np.zeros(kernels.N_PARAMS)
    p = muscle.params
    params[[kernels.P_K_SE, kernels.P_K_PE, kernels.P_L_REST, kernels.P_L_OPT, kernels.P_A,
            kernels.P_B, kernels.P_A_ECC, kernels.P_B_ECC]] = [
        p.k_se_n_per_m, p.k_pe_n_per_m, p.l_rest_m, p.l_opt_m, p.fv_a_n, p.fv_b_m_per_s,
        p.fv_a_ecc_n, p.fv_b_ecc_m_per_s]
    count = np.zeros(p.n_units + 1, dtype=np.int64)
    f_unit, total = np.zeros(p.n_units + 1), np.zeros(p.n_units + 1)
    n_units, f_max = float(p.n_units), p.f_iso_max_n

    def python_steps():
        step = muscle.step
        for _ in range(STEP_CALLS):
            step(0.5, 0.0, DT_S)

    def kernel_steps():
        # The kernel alone on arrays made once: the least a compiled step can
        # cost from Python (numba's dispatch); reading and writing the
        # Muscle's state around it (kernels.run_compiled) costs more.
        top = 0
        for _ in range(STEP_CALLS):
            top = run(r1, dl1, r1, DT_S, state, top, True, True, n_units, f_max, params,
                      count, f_unit, total, out, 0)

    make_outputs = tuple.__new__
    fields = MuscleOutputs

    def kernel_outputs_steps():
        # The same, and the outputs as the node reads them (a MuscleOutputs).
        top = 0
        for _ in range(STEP_CALLS):
            top = run(r1, dl1, r1, DT_S, state, top, True, True, n_units, f_max, params,
                      count, f_unit, total, out, 0)
            make_outputs(fields, out[:, 0].tolist())

    one = Muscle(MuscleParams())

    def wrapper_steps():
        for _ in range(STEP_CALLS // 10):
            kernels.run_compiled(one, r1, dl1, DT_S)

    result = {'python': repeat(python_steps, runs).scaled(1e6 / STEP_CALLS),
              'kernel': repeat(kernel_steps, runs).scaled(1e6 / STEP_CALLS),
              'kernel_outputs': repeat(kernel_outputs_steps, runs).scaled(1e6 / STEP_CALLS),
              'wrapper': repeat(wrapper_steps, runs).scaled(1e6 / (STEP_CALLS // 10))}
    for case, s in result.items():
        print(f'  one step a call, {case}: {s.fmt()} us', flush=True)
    return result


def run(runs: int) -> dict:
    kernels.compiled_run()   # loaded (or compiled) before anything is timed
    import numba
    print('one muscle offline, compiled vs MuJoCo and vs Python', flush=True)
    result = {'numba': numba.__version__, 'per_step': bench_per_step()}
    print('the 60 s protocol in-process', flush=True)
    result['rtf'] = bench_rtf(runs)
    print('start-up', flush=True)
    result['startup'] = bench_startup(runs)
    print('one step a call (the node)', flush=True)
    result['single_step'] = bench_single_step(runs)
    return result


def _cpu(s: Stats) -> str:
    return f'{s.cpu.median:.3g}' if s.cpu is not None else '-'


def _met(ok: bool) -> str:
    return '**met**' if ok else '**not met**'


def write_section(add, m: dict) -> None:
    """The section of BENCHMARKS.md from :func:`run`'s result."""
    add("## One muscle's offline run, compiled (`kernels.run_compiled`)")
    add('')
    add('`benchmarks/bench_compiled.py` (alone: `.venv/bin/python benchmarks/run_all.py --only '
        f'single --runs 5`). The loop of `Muscle.run` compiled by numba {m["numba"]} '
        '(`model/kernels.py`, `run_muscle`, built from the same functions as the batch: '
        '`step_one`, `recruit_one`), as `simulate()` calls it; the paper\'s model, '
        'multi/initial, N = 1000, 1 ms steps. Each ratio is the median over '
        f'{PAIRS} back-to-back pairs (the order alternating), so load on the shared '
        f'machine hits both sides alike; each side of a pair is {RUNS_PER_SAMPLE} consecutive '
        'runs (a compiled run of Protocol II lasts about 0.3 ms: timed one by one, its cost '
        'scattered from 0.037 to 0.061 us a step within one bench). MuJoCo: its muscle actuator stepped from Python '
        f'(`benchmarks/peers.py`, mujoco {m["per_step"]["mujoco"]}). Python: `Muscle.run` with '
        'list columns, `simulate()`\'s plain loop.')
    add('')
    add('| protocol | compiled [us/step] | MuJoCo [us/step] | Python [us/step] | '
        'compiled / MuJoCo | compiled / Python |')
    add('| --- | ---: | ---: | ---: | ---: | ---: |')
    rows = m['per_step']['rows']
    for name, row in rows.items():
        add(f'| {name} | {row["compiled"].fmt()} | {row["mujoco"].fmt()} | '
            f'{row["python"].fmt()} | {row["vs_mujoco"].fmt()} | {row["vs_python"].fmt()} |')
    add('')
    worst_mj = max(row['vs_mujoco'].median for row in rows.values())
    worst_py = max(row['vs_python'].median for row in rows.values())
    add(f'- Target: at most {TARGET_VS_MUJOCO:g}x MuJoCo\'s cost a step: **{worst_mj:.3g}x** '
        f'(the higher of the two protocols) — {_met(worst_mj <= TARGET_VS_MUJOCO)}.')
    add(f'- Target: at most {TARGET_VS_PYTHON:g}x the Python loop\'s cost a step: '
        f'**{worst_py:.3g}x** — {_met(worst_py <= TARGET_VS_PYTHON)}.')
    add('')
    rtf = m['rtf']
    d = rtf['duration_s']
    add(f'The {d:g} s protocol in-process (`{rtf["label"]}`): the whole '
        '`cli.main([\'simulate\', ...])` (reading the files, simulating, printing) and '
        '`simulate()` alone, wall s, real-time factor = simulated / wall time (medians). '
        'Compiled: in a process where the compiled run is loaded (the start-up below pays '
        'for loading it); Python: `HILL_MUSCLE_ENGINE=python`.')
    add('')
    add('| engine | `cli.main` wall [s] | RTF | by CPU time | `simulate()` wall [s] | RTF | '
        'by CPU time |')
    add('| --- | ---: | ---: | ---: | ---: | ---: | ---: |')
    for value, label in (('auto', 'compiled'), ('python', 'Python')):
        whole, sim = rtf[value]
        add(f'| {label} | {whole.fmt()} | {d / whole.median:,.0f}x | '
            f'{d / whole.cpu.median:,.0f}x | {sim.fmt()} | {d / sim.median:,.0f}x | '
            f'{d / sim.cpu.median:,.0f}x |')
    whole, sim = rtf['auto']
    add('')
    add(f'- Target: at least {TARGET_RTF:,.0f}x real time for the {d:g} s protocol excluding '
        f'start-up: the whole command **{d / whole.median:,.0f}x** — '
        f'{_met(d / whole.median >= TARGET_RTF)}; the simulation alone '
        f'**{d / sim.median:,.0f}x** — {_met(d / sim.median >= TARGET_RTF)}.')
    add('')
    st = m['startup']
    add(f'Start-up of `{st["label"]}` (a 1 ms protocol), as a process, wall s '
        '(CPU s of the process in brackets), with the package\'s bytecode compiled '
        'beforehand, as installing it writes it:')
    add('')
    add('| case | wall [s] | CPU [s] |')
    add('| --- | ---: | ---: |')
    add(f'| as shipped (`HILL_MUSCLE_ENGINE` unset: a 1-step run stays on the Python loop, '
        f'numba is not imported) | {st["auto"].fmt()} | {_cpu(st["auto"])} |')
    add(f'| `HILL_MUSCLE_ENGINE=compiled`, numba\'s cache filled (warm) | {st["warm"].fmt()} | '
        f'{_cpu(st["warm"])} |')
    add(f'| `HILL_MUSCLE_ENGINE=compiled`, empty `NUMBA_CACHE_DIR` (cold: compiling) | '
        f'{st["cold"].fmt()} | {_cpu(st["cold"])} |')
    add('')
    add('In a new interpreter: `import numba` '
        f'**{st["run_import"].fmt()} s** ({_cpu(st["run_import"])}); building the compiled '
        'run and its first call with an empty cache (compiling) '
        f'**{st["run_compile"].fmt()} s** ({_cpu(st["run_compile"])}), with the cache filled '
        f'(loading) **{st["run_load"].fmt()} s** ({_cpu(st["run_load"])}).')
    add('')
    warm = st['warm'].median
    add(f'- Target: start-up with a warm cache at most {TARGET_STARTUP_S:g} s: compiled '
        f'**{warm:.3g} s** — {_met(warm <= TARGET_STARTUP_S)}; as shipped '
        f'**{st["auto"].median:.3g} s** — {_met(st["auto"].median <= TARGET_STARTUP_S)}.')
    load = st['run_import'].median + st['run_load'].median
    add(f'- Loading costs about {load:.2g} s (import and cached load), the Python loop about '
        f'{rows["Protocol II"]["python"].median:.2g} us a step more than the compiled one: '
        f'so `simulate()` loads the compiled run only for runs of at least '
        f'{kernels.RUN_MIN_STEPS:,} steps (`kernels.RUN_MIN_STEPS`) and otherwise takes it '
        'only once something loaded it in the process; `HILL_MUSCLE_ENGINE=compiled` '
        'always, `python` never.')
    add('')
    ss = m['single_step']
    saved = ss['python'].median - ss['kernel_outputs'].median
    add(f'One step a call, as the simulator node steps (`Muscle.step` once a tick; '
        f'{STEP_CALLS:,} calls, us a call): the Python step **{ss["python"].fmt()}**; the '
        f'compiled kernel called for one step on arrays made once (numba\'s dispatch of 16 '
        f'arguments) **{ss["kernel"].fmt()}**, and with its outputs made into a '
        f'`MuscleOutputs` **{ss["kernel_outputs"].fmt()}**; with the Muscle\'s state read '
        f'and written around it (`kernels.run_compiled`) **{ss["wrapper"].fmt()}**.')
    add('')
    add(f'- The node keeps the Python step: a compiled step would save at most '
        f'{max(saved, 0.0):.2g} us of a 1000 us tick ({max(saved, 0.0) / 10:.2g} % of a core '
        'at 1 kHz; section 4 gives the node\'s whole cost), for the state kept in arrays '
        'beside the Muscle and numba loaded and the kernel loaded before the node reports '
        'ready (the start-up above). Nothing is compiled at node start-up.')
