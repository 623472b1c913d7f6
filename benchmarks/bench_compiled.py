"""BENCHMARKS.md section "One muscle's offline run, compiled and plain": ``Muscle.run_array``.

The muscle is written once (``hill_muscle_ros/model/muscle/kernels.py``) and
runs either compiled by numba or as the very same functions in plain Python
(``Muscle(params, build=...)``, ``HILL_MUSCLE_ENGINE``). One run measures, on
the same machine state:

- the cost a step of one muscle's offline run (multi/initial, N = 1000, 1 ms
  steps, every FES feature off: the paper's model) through
  ``Muscle.run_array`` as ``simulate`` calls it, on the compiled build,
  against MuJoCo's muscle actuator stepped from Python
  (``peers.mujoco_runner``) and against the plain-Python build of the same
  functions, on Protocol II and on a protocol whose R changes on every step
  (a triangle, 0 to 1 in each odd second, back in each even one); each ratio
  from back-to-back pairs, alternating which side runs first;
- the 60 s protocol's real-time factor in-process: the whole
  ``cli.main(['simulate', ...])`` and ``simulate()`` alone, on either build;
- the start-up of ``hill-muscle simulate`` on a 1 ms protocol as a process:
  as shipped (``HILL_MUSCLE_ENGINE`` unset: compiled, numba imported and the
  kernels loaded from the package's cache), on the plain build
  (``HILL_MUSCLE_ENGINE=python``: numba never imported), and compiled with a
  filled and with an empty ``NUMBA_CACHE_DIR``; and loading the compiled
  muscle alone in a new interpreter;
- one call's cost, for the simulator node's once-a-tick ``Muscle.step``: on
  either build, and the compiled kernel called for one step on its arrays.

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

from hill_muscle_ros.model import Muscle, MuscleParams, Protocol, engine, simulate
from hill_muscle_ros.model.muscle import kernels as muscle_kernels
from hill_muscle_ros.model.muscle.state import N_OUT, FesBundle
from hill_muscle_ros.model.simulate import sample_times
from hill_muscle_ros.resources import protocol_path
from hill_muscle_ros.tools import cli

HERE = Path(__file__).resolve().parent
REPO = HERE.parent
PROTOCOL_60S = HERE / 'protocol_60s.yaml'
PROTOCOL_STARTUP = HERE / 'protocol_startup.yaml'
DT_S = 1e-3
RATE_HZ = 1000.0
#: Back-to-back pairs per ratio against MuJoCo (after one warm-up pair).
PAIRS = 21
#: Back-to-back pairs per ratio against the plain build (after one warm-up
#: pair): a plain run of Protocol II takes about half a second.
PLAIN_PAIRS = 7
#: [s] the triangle protocol: Protocol II's length, R 0 -> 1 -> 0 with period 2 s.
TRIANGLE_PERIOD_S = 2.0
#: Calls per timing of a single step (the node's case), compiled and plain.
STEP_CALLS = 20_000
PLAIN_STEP_CALLS = 2_000
#: Cold start-ups (each compiles the muscle's kernels, about 15 s).
COLD_RUNS = 3

# The targets.
TARGET_VS_MUJOCO = 0.1
TARGET_VS_PLAIN = 0.05
TARGET_RTF = 5000.0
TARGET_STARTUP_S = 1.0
#: The simulator node's tick at rate_hz 1000 [us].
TICK_US = 1000.0

#: In a new interpreter: import numba, then build (load) the compiled muscle
#: and run it for two steps; prints both as JSON: [s] wall and CPU.
LOAD_RUN = '''
import json, time
t0, c0 = time.perf_counter(), time.process_time()
import numba
t1, c1 = time.perf_counter(), time.process_time()
import numpy as np
from hill_muscle_ros.model import Muscle
from hill_muscle_ros.tools import cli
t2, c2 = time.perf_counter(), time.process_time()
Muscle(build='compiled').run_array(np.full(2, 0.5), np.zeros(2), 1e-3)
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


def runner(muscle: Muscle, r, dl):
    """One offline run of ``muscle`` (on its build), as ``simulate`` makes it:
    ``Muscle.run_array`` over the whole protocol; returns its outputs."""
    r_start, dl_end, r_end = r[:-1].copy(), dl[1:].copy(), r[1:].copy()

    def run():
        muscle.reset()
        muscle.set_recruitment(float(r[0]))
        return muscle.run_array(r_start, dl_end, DT_S, r_end)
    return run


def paired(a, b, pairs: int = PAIRS, runs_a: int = RUNS_PER_SAMPLE,
           runs_b: int = RUNS_PER_SAMPLE) -> tuple:
    """Times of ``a`` and ``b`` and the ratio a / b over back-to-back pairs.

    The order alternates from pair to pair, so that a load change on the
    shared machine does not always hit the same side; one warm-up pair first.
    Each side of a pair is ``runs_a`` (``runs_b``) consecutive calls.

    :return: (Stats of a [s], Stats of b [s], Stats of a / b), a call's time
        (a sample's over its runs)
    """
    ta, tb, ratios = [], [], []
    sides = (('a', a, runs_a), ('b', b, runs_b))
    for i in range(pairs + 1):
        times = {}
        for name, fn, n in (sides if i % 2 == 0 else sides[::-1]):
            t0 = time.perf_counter()
            for _ in range(n):
                fn()
            times[name] = (time.perf_counter() - t0) / n
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
        comp = runner(Muscle(MuscleParams(), build=engine.COMPILED), r, dl)
        plain = runner(Muscle(MuscleParams(), build=engine.PYTHON), r, dl)
        # The same functions on either build: the largest force difference.
        diff = float(np.max(np.abs(comp()[:, 8] - plain()[:, 8])))
        mj = mujoco_runner(r.tolist(), dl.tolist(), DT_S)
        s_c, s_mj, vs_mj = paired(comp, mj)
        s_c2, s_py, vs_py = paired(comp, plain, PLAIN_PAIRS, RUNS_PER_SAMPLE, 1)
        rows[name] = {'n_steps': n_steps, 'compiled': s_c.scaled(1e6 / n_steps),
                      'compiled_2': s_c2.scaled(1e6 / n_steps),
                      'mujoco': s_mj.scaled(1e6 / n_steps), 'python': s_py.scaled(1e6 / n_steps),
                      'vs_mujoco': vs_mj, 'vs_python': vs_py, 'diff': diff}
        print(f'  {name}: compiled {rows[name]["compiled"].fmt()} us/step, '
              f'plain {rows[name]["python"].fmt()} us/step, /MuJoCo {vs_mj.fmt()}, '
              f'/plain {vs_py.fmt()}, max |force difference| {diff:.2g} N', flush=True)
    return {'rows': rows, 'mujoco': mujoco.__version__}


def bench_rtf(runs: int) -> dict:
    """The 60 s protocol in-process: cli.main and simulate(), on either build."""
    args = ['simulate', '--protocol', str(PROTOCOL_60S), '--rate', f'{RATE_HZ:g}']
    protocol = Protocol.from_yaml(PROTOCOL_60S)
    params = MuscleParams()

    def whole():
        with contextlib.redirect_stdout(io.StringIO()):
            if cli.main(args) != 0:
                raise RuntimeError(f'hill-muscle {shlex.join(args)} failed')

    result = {}
    saved = os.environ.get(engine.ENV_VAR)
    for value in (engine.COMPILED, engine.PYTHON):
        os.environ[engine.ENV_VAR] = value
        try:
            result[value] = (repeat(whole, runs), repeat(lambda: simulate(protocol, params), runs))
        finally:
            if saved is None:
                del os.environ[engine.ENV_VAR]
            else:
                os.environ[engine.ENV_VAR] = saved
        print(f'  60 s protocol, {value}: cli.main {result[value][0].fmt()} s, '
              f'simulate {result[value][1].fmt()} s', flush=True)
    result['duration_s'] = protocol.duration_s
    result['label'] = shlex.join(['.venv/bin/hill-muscle', 'simulate', '--protocol',
                                  PROTOCOL_60S.relative_to(REPO).as_posix(),
                                  '--rate', f'{RATE_HZ:g}'])
    return result


def bench_startup(runs: int) -> dict:
    """`hill-muscle simulate` on a 1 ms protocol as a process: as shipped, plain,
    compiled warm and cold; and loading the compiled muscle alone."""
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

    # As shipped: the kernels load from the package's own cache, which this
    # process filled when it first ran the compiled build.
    result['auto'] = repeat(lambda: start(base), runs, children=True)
    result['python'] = repeat(lambda: start(dict(base, **{engine.ENV_VAR: engine.PYTHON})),
                              runs, children=True)
    with tempfile.TemporaryDirectory(prefix='numba_cache_') as root:
        env = dict(base, **{engine.ENV_VAR: engine.COMPILED, 'NUMBA_CACHE_DIR': root})
        start(env)   # fills the cache
        result['warm'] = repeat(lambda: start(env), runs, children=True)
        cold_dirs = iter(range(COLD_RUNS + 1))
        result['cold'] = repeat(
            lambda: start(dict(env, NUMBA_CACHE_DIR=os.path.join(root, str(next(cold_dirs))))),
            min(runs, COLD_RUNS), children=True)
        loads = {'import': [], 'load': []}
        for _ in range(runs):
            out = subprocess.run([sys.executable, '-c', LOAD_RUN], check=True, text=True,
                                 capture_output=True, env=dict(base, NUMBA_CACHE_DIR=root)).stdout
            got = json.loads(out.strip().splitlines()[-1])
            for case in loads:
                loads[case].append(got[case])
        for case, values in loads.items():
            result[f'run_{case}'] = Stats.of([w for w, _ in values], [c for _, c in values])
    result['label'] = shlex.join(['.venv/bin/hill-muscle', 'simulate', '--protocol',
                                  PROTOCOL_STARTUP.relative_to(REPO).as_posix(),
                                  '--rate', f'{RATE_HZ:g}'])
    for case in ('auto', 'python', 'warm', 'cold', 'run_import', 'run_load'):
        print(f'  {case}: {result[case].fmt()} s', flush=True)
    return result


def bench_single_step(runs: int) -> dict:
    """One step a call, as the node makes it: Muscle.step on either build, and the
    compiled kernel alone."""
    params = MuscleParams()
    compiled, plain = Muscle(params, build=engine.COMPILED), Muscle(params, build=engine.PYTHON)

    def steps(muscle, calls):
        def run():
            step = muscle.step
            for _ in range(calls):
                step(0.5, 0.0, DT_S)
        return run

    # The kernel alone, on a one-muscle bundle's arrays made once: the least a
    # compiled step costs from Python (numba's dispatch of its 9 arguments);
    # Muscle.step adds the checks, the bundle's arrays and the MuscleOutputs.
    run = muscle_kernels.compiled().muscle_run
    bundle = FesBundle([params])
    F, I = bundle.F, bundle.I
    r1, dl1, out = np.full(1, 0.5), np.zeros(1), np.zeros((1, N_OUT))

    def kernel_steps():
        for _ in range(STEP_CALLS):
            run(F, I, 0, r1, dl1, DT_S, r1, False, out)

    result = {'compiled': repeat(steps(compiled, STEP_CALLS), runs).scaled(1e6 / STEP_CALLS),
              'python': repeat(steps(plain, PLAIN_STEP_CALLS),
                               runs).scaled(1e6 / PLAIN_STEP_CALLS),
              'kernel': repeat(kernel_steps, runs).scaled(1e6 / STEP_CALLS)}
    for case, s in result.items():
        print(f'  one step a call, {case}: {s.fmt()} us', flush=True)
    return result


def run(runs: int) -> dict:
    muscle_kernels.compiled()   # loaded (or compiled) before anything is timed
    import numba
    print('one muscle offline, compiled vs MuJoCo and vs the plain build', flush=True)
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


#: What the last bench before the muscle was written once measured (make bench
#: of 2026-12-04 09:55 UTC, this kind of machine), quoted for comparison, never
#: judged: the code it timed is gone (the paper's compiled run ``run_muscle`` of
#: ``model/kernels.py``, and ``Muscle``'s own Python loop and step).
BEFORE = {'date': '2026-12-04 09:55 UTC', 'compiled_us': 0.0391, 'vs_mujoco': 0.0172,
          'python_loop_us': 1.3, 'simulate_rtf': 20_643, 'python_step_us': 1.83,
          'shipped_startup_s': 0.16, 'warm_startup_s': 0.961, 'load_s': 0.327}


def write_section(add, m: dict) -> None:
    """The section of BENCHMARKS.md from :func:`run`'s result."""
    b = BEFORE
    add("## One muscle's offline run, compiled and plain (`Muscle.run_array`)")
    add('')
    add('`benchmarks/bench_compiled.py` (alone: `.venv/bin/python benchmarks/run_all.py --only '
        'single --runs 5`). The muscle is written once, as functions over flat arrays '
        '(`model/muscle/kernels.py`); `Muscle(params, build=...)` runs them compiled by '
        f'numba {m["numba"]} (`build=\'compiled\'`, what `HILL_MUSCLE_ENGINE` unset gives '
        'where numba imports) or as the very same functions in plain Python '
        '(`build=\'python\'`, `HILL_MUSCLE_ENGINE=python`). `simulate()` runs a whole '
        'protocol as one `Muscle.run_array` call, as timed here: the paper\'s model (every '
        'FES feature off), multi/initial, N = 1000, 1 ms steps. Each ratio is the median '
        'over back-to-back pairs, the order alternating, so load on the shared machine hits '
        f'both sides alike: against MuJoCo {PAIRS} pairs of {RUNS_PER_SAMPLE} consecutive '
        f'runs a side; against the plain build {PLAIN_PAIRS} pairs of {RUNS_PER_SAMPLE} '
        'compiled runs and one plain run. MuJoCo: its muscle actuator stepped from Python '
        f'(`benchmarks/peers.py`, mujoco {m["per_step"]["mujoco"]}).')
    add('')
    add('| protocol | compiled [us/step] | MuJoCo [us/step] | plain Python build [us/step] | '
        'compiled / MuJoCo | compiled / plain | max \\|force difference\\| of the builds [N] |')
    add('| --- | ---: | ---: | ---: | ---: | ---: | ---: |')
    rows = m['per_step']['rows']
    for name, row in rows.items():
        add(f'| {name} | {row["compiled"].fmt()} | {row["mujoco"].fmt()} | '
            f'{row["python"].fmt()} | {row["vs_mujoco"].fmt()} | {row["vs_python"].fmt()} | '
            f'{row["diff"]:.2g} |')
    add('')
    worst_mj = max(row['vs_mujoco'].median for row in rows.values())
    worst_py = max(row['vs_python'].median for row in rows.values())
    ii = rows['Protocol II']
    line = (f'- Target: at most {TARGET_VS_MUJOCO:g}x MuJoCo\'s cost a step: **{worst_mj:.3g}x** '
            f'(the higher of the two protocols) — {_met(worst_mj <= TARGET_VS_MUJOCO)}.')
    if worst_mj > TARGET_VS_MUJOCO:
        line += (' Missed because the paper\'s model now runs the one muscle\'s general step '
                 'with every feature off (the delay line, the activation\'s pieces, the '
                 'event planning and the unit pool\'s segment stacks), not a loop of its own: '
                 'the compiled paper-only run it replaced (`run_muscle` of the removed '
                 f'`model/kernels.py`) took {b["compiled_us"]} us a step on Protocol II, '
                 f'{b["vs_mujoco"]}x MuJoCo, in the last bench before the change, of '
                 f'{b["date"]}; {ii["compiled"].median:.3g} us now is '
                 f'{ii["compiled"].median / b["compiled_us"]:.0f}x that (not measured in '
                 'the same run: the code is gone).')
    add(line)
    add(f'- Target: at most {TARGET_VS_PLAIN:g}x the Python build\'s cost a step: '
        f'**{worst_py:.3g}x** — {_met(worst_py <= TARGET_VS_PLAIN)}. Its baseline changed '
        'with the one implementation: it is now the plain-Python run of the same kernels '
        f'({ii["python"].median:.3g} us a step on Protocol II), where it was `Muscle`\'s own '
        f'Python loop, written for speed ({b["python_loop_us"]} us a step in the bench of '
        f'{b["date"]}). So the ratio says what numba buys these functions; against that '
        f'hand-written loop the compiled run now costs about '
        f'{ii["compiled"].median / b["python_loop_us"]:.2g}x, where the paper\'s compiled '
        f'run cost {b["compiled_us"] / b["python_loop_us"]:.2g}x (across the two benches).')
    add('')
    rtf = m['rtf']
    d = rtf['duration_s']
    add(f'The {d:g} s protocol in-process (`{rtf["label"]}`): the whole '
        '`cli.main([\'simulate\', ...])` (reading the files, simulating, printing) and '
        '`simulate()` alone, wall s, real-time factor = simulated / wall time (medians), '
        'with `HILL_MUSCLE_ENGINE` set to each build (the compiled kernels are loaded in '
        'this process before it is timed).')
    add('')
    add('| build | `cli.main` wall [s] | RTF | by CPU time | `simulate()` wall [s] | RTF | '
        'by CPU time |')
    add('| --- | ---: | ---: | ---: | ---: | ---: | ---: |')
    for value, label in ((engine.COMPILED, 'compiled'), (engine.PYTHON, 'plain Python')):
        whole, sim = rtf[value]
        add(f'| {label} | {whole.fmt()} | {d / whole.median:,.0f}x | '
            f'{d / whole.cpu.median:,.0f}x | {sim.fmt()} | {d / sim.median:,.0f}x | '
            f'{d / sim.cpu.median:,.0f}x |')
    whole, sim = rtf[engine.COMPILED]
    add('')
    ok_whole, ok_sim = d / whole.median >= TARGET_RTF, d / sim.median >= TARGET_RTF
    line = (f'- Target: at least {TARGET_RTF:,.0f}x real time for the {d:g} s protocol '
            f'excluding start-up, compiled: the whole command **{d / whole.median:,.0f}x** — '
            f'{_met(ok_whole)}; the simulation alone **{d / sim.median:,.0f}x** — '
            f'{_met(ok_sim)}.')
    if not (ok_whole and ok_sim):
        line += (' Missed for the reason above: a step of the one muscle costs more than '
                 'the paper-only compiled run did (the simulation alone ran at '
                 f'{b["simulate_rtf"]:,}x in the bench of {b["date"]}).')
    add(line)
    add('')
    st = m['startup']
    add(f'Start-up of `{st["label"]}` (a 1 ms protocol), as a process, wall s '
        '(CPU s of the process in brackets), with the package\'s bytecode compiled '
        'beforehand, as installing it writes it:')
    add('')
    add('| case | runs | wall [s] | CPU [s] |')
    add('| --- | ---: | ---: | ---: |')
    add(f'| as shipped (`HILL_MUSCLE_ENGINE` unset: compiled, numba imported and the kernels '
        f'loaded from the package\'s cache) | {st["auto"].runs} | {st["auto"].fmt()} | '
        f'{_cpu(st["auto"])} |')
    add(f'| `HILL_MUSCLE_ENGINE=python` (the plain build: numba never imported) | '
        f'{st["python"].runs} | {st["python"].fmt()} | {_cpu(st["python"])} |')
    add(f'| `HILL_MUSCLE_ENGINE=compiled`, numba\'s cache filled (warm) | {st["warm"].runs} | '
        f'{st["warm"].fmt()} | {_cpu(st["warm"])} |')
    add(f'| `HILL_MUSCLE_ENGINE=compiled`, empty `NUMBA_CACHE_DIR` (cold: compiling the '
        f'muscle\'s kernels) | {st["cold"].runs} | {st["cold"].fmt()} | {_cpu(st["cold"])} |')
    add('')
    add('In a new interpreter: `import numba` '
        f'**{st["run_import"].fmt()} s** ({_cpu(st["run_import"])}); building the compiled '
        'muscle from a filled cache and running it for two steps '
        f'**{st["run_load"].fmt()} s** ({_cpu(st["run_load"])}). The cold compile of each '
        'kernel set is in "Compiling the kernels" below.')
    add('')
    warm, shipped = st['warm'].median, st['auto'].median
    line = (f'- Target: start-up with a warm cache at most {TARGET_STARTUP_S:g} s: compiled '
            f'**{warm:.3g} s** — {_met(warm <= TARGET_STARTUP_S)}; as shipped '
            f'**{shipped:.3g} s** — {_met(shipped <= TARGET_STARTUP_S)}.')
    if max(warm, shipped) > TARGET_STARTUP_S:
        line += (' Missed because of what the start-up loads: the one muscle\'s compiled '
                 'kernels (every FES feature\'s code, the paper\'s model among them) take '
                 f'{st["run_load"].median:.2g} s to load from the cache in a new interpreter, '
                 f'where the paper\'s compiled run took {b["load_s"]} s (the compiled '
                 f'start-up was {b["warm_startup_s"]} s), and as shipped the command now loads '
                 'them for any run (next line).')
    add(line)
    load = st['run_import'].median + st['run_load'].median
    gain_us = ii['python'].median - ii['compiled'].median
    add(f'- Every `Muscle` takes the compiled build where numba imports, whatever the run\'s '
        'length (the step threshold of the paper\'s compiled run, `kernels.RUN_MIN_STEPS`, '
        'went with it), so even a 1 ms `hill-muscle simulate` pays for loading it, about '
        f'{load:.2g} s (import and cached load): the as-shipped start-up above, against '
        f'{b["shipped_startup_s"]} s in the bench of {b["date"]}, when so short a run stayed '
        'on the Python loop. The plain build saves that only for runs shorter than about '
        f'{load / (gain_us * 1e-6):,.0f} steps (it costs {gain_us:.3g} us a step more).')
    add('')
    ss = m['single_step']
    comp, plain, kern = ss['compiled'], ss['python'], ss['kernel']
    add(f'One step a call, as the simulator node steps (`Muscle.step` once a tick; us a '
        f'call): compiled **{comp.fmt()}** ({STEP_CALLS:,} calls), plain Python '
        f'**{plain.fmt()}** ({PLAIN_STEP_CALLS:,} calls); the compiled kernel alone, one '
        'step on a one-muscle bundle\'s arrays made once (numba\'s dispatch of its 9 '
        f'arguments) **{kern.fmt()}**, so `Muscle.step`\'s checks, arrays and '
        f'`MuscleOutputs` add about {max(comp.median - kern.median, 0.0):.2g} us.')
    add('')
    add(f'- The simulator node loads the compiled build before it reports ready (the plain '
        f'one where numba is missing): {comp.median:.2g} us of its {TICK_US:g} us tick, '
        f'{comp.median / TICK_US * 100:.2g} % of a core at 1 kHz (section 4 gives the node\'s '
        f'whole cost); on the plain build {plain.median / TICK_US * 100:.2g} %. `Muscle`\'s '
        f'own Python step, which the node used to run, took {b["python_step_us"]} us in the '
        f'bench of {b["date"]}.')
