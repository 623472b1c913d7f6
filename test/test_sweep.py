"""``hill-muscle sweep``: spec parsing, the numbers, and the runs on Dask.

The reference for every force is :func:`hill_muscle_ros.model.simulate.simulate`,
one parameter set at a time on the scalar engine; the sweep computes them in
batches (:class:`~hill_muscle_ros.model.muscle.batch.MuscleBatch`), here, on a local
Dask cluster and on a scheduler and workers started as separate processes.
Limb sweeps: the reference is :func:`hill_muscle_ros.model.limb.simulate_limb`
on plants built here from the plant file, one at a time.
"""
from __future__ import annotations

import dataclasses
import json
import logging
import math
import os
import re
import signal
import subprocess
import sys
import time
import types
from pathlib import Path

import numpy as np
import pytest
import yaml

from hill_muscle_ros.model import MuscleParams, Protocol, simulate
from hill_muscle_ros.model.limb import LimbProtocol, simulate_limb
from hill_muscle_ros.params_file import load_plant
from hill_muscle_ros.resources import config_dir, protocol_path
from hill_muscle_ros.tools import cli, sweep
from hill_muscle_ros.tools.sweep import (HEARTBEAT_FAILED, QUIET_HEARTBEAT_PLUGIN,
                                         HeartbeatOnCloseFilter, SweepError, load_spec,
                                         parse_spec, quiet_heartbeat_on_close, run_on_client,
                                         run_sweep, simulate_forces)

pq = pytest.importorskip('pyarrow.parquet')

REPO = Path(__file__).resolve().parents[1]
VENV_BIN = Path(sys.executable).parent
#: [N] bound on sweep vs separate runs (the batch engine follows the scalar one to 1e-9).
ATOL_N = 1e-9
#: [s] deadline for a cluster to start, a worker to register or a process to exit.
DEADLINE_S = 60.0
#: [s] polling period while waiting on a condition.
POLL_S = 0.05
#: A small sweep: 2 x 2 x 2 = 8 sets, the four model variants, Protocol II to 2 s.
SMALL = {'protocol': 'II', 'sample_times_s': [0.0, 1.0, 1.5, 2.0],
         'vary': {'f_iso_max_n': [30.0, 60.0], 'units': ['multi', 'single'],
                  'length': ['initial', 'instantaneous']}}
COLUMNS = ['set_id', 'f_iso_max_n', 'units', 'length', 't_s', 'force_n', 'worker']


def reference_forces(spec) -> np.ndarray:
    """[N] force of each set at each sample time, one ``simulate`` run per set."""
    out = np.empty((len(spec.sets), len(spec.sample_times_s)))
    for i, params in enumerate(spec.sets):
        result = simulate(spec.protocol, params, spec.rate_hz)
        out[i] = [result.force_n[round(t * spec.rate_hz)] for t in spec.sample_times_s]
    return out


def write_spec(tmp_path: Path, doc: dict, name: str = 'spec.yaml') -> Path:
    path = tmp_path / name
    path.write_text(yaml.safe_dump(doc, sort_keys=False), encoding='utf-8')
    return path


def forces_of(table, spec) -> np.ndarray:
    """The table's force column as (sets, times), checking its tidy layout."""
    n_sets, n_times = len(spec.sets), len(spec.sample_times_s)
    assert table.num_rows == n_sets * n_times
    assert table.column('set_id').to_pylist() == [i for i in range(n_sets)
                                                  for _ in range(n_times)]
    assert table.column('t_s').to_pylist() == list(spec.sample_times_s) * n_sets
    return np.asarray(table.column('force_n')).reshape(n_sets, n_times)


# --------------------------------------------------------------------------- spec

def test_grid_is_every_combination_of_lists_and_ranges():
    spec = parse_spec({'protocol': 'I', 'sample_times_s': [1.0],
                       'vary': {'k_se_n_per_m': {'low': 5e3, 'high': 2e4, 'n': 3, 'log': True},
                                'f_iso_max_n': {'low': 30.0, 'high': 60.0, 'n': 4},
                                'units': ['multi', 'single']}})
    k_se = [5e3, 1e4, 2e4]   # log-spaced: each a factor 2 from the last
    f_iso = [30.0, 40.0, 50.0, 60.0]
    expected = [(k, f, u) for k in k_se for f in f_iso for u in ('multi', 'single')]
    assert spec.names == ('k_se_n_per_m', 'f_iso_max_n', 'units')
    assert len(spec.values) == len(expected)
    for got, want in zip(spec.values, expected):
        assert got[2] == want[2]
        np.testing.assert_allclose(got[:2], want[:2], rtol=1e-12)
    assert [(p.k_se_n_per_m, p.f_iso_max_n, p.units) for p in spec.sets] == list(spec.values)
    # Parameters not varied keep the base file's values (the paper's defaults).
    assert all(p.l_opt_m == MuscleParams().l_opt_m for p in spec.sets)


LHS = {'protocol': 'I', 'sample_times_s': [1.0], 'samples': 20, 'seed': 7,
       'vary': {'f_iso_max_n': {'low': 30.0, 'high': 60.0},
                'k_se_n_per_m': {'low': 1e3, 'high': 1e5, 'log': True}}}


def test_latin_hypercube_puts_one_sample_in_each_stratum_of_each_parameter():
    spec = parse_spec(LHS)
    f_iso = np.array([v[0] for v in spec.values])
    k_se = np.array([v[1] for v in spec.values])
    # Latin hypercube: the 20 samples fall one in each 20th of each range
    # (of its logarithm for a log range).
    strata_f = np.floor((f_iso - 30.0) / 30.0 * 20).astype(int)
    strata_k = np.floor(np.log10(k_se / 1e3) / 2.0 * 20).astype(int)
    assert sorted(strata_f) == list(range(20))
    assert sorted(strata_k) == list(range(20))


def test_latin_hypercube_repeats_with_its_seed_and_changes_with_another():
    assert parse_spec(LHS).values == parse_spec(LHS).values
    assert parse_spec(LHS).values != parse_spec({**LHS, 'seed': 8}).values


@pytest.mark.parametrize('change, message', [
    ({'vary': {'f_iso_max': [30.0]}}, 'unknown parameter `vary.f_iso_max`'),
    ({'vary': {'f_iso_max_n': {'low': 60.0, 'high': 30.0, 'n': 3}}},
     '`vary.f_iso_max_n.low` must be below `vary.f_iso_max_n.high`, got low=60.0, high=30.0'),
    ({'vary': {'f_iso_max_n': {'low': 30.0, 'high': 60.0, 'n': 1}}},
     '`vary.f_iso_max_n.n` must be an integer >= 2 for a grid, got 1'),
    ({'vary': {'f_iso_max_n': {'low': 0.0, 'high': 60.0, 'n': 3, 'log': True}}},
     '`vary.f_iso_max_n.low` must be positive for a log range, got 0.0'),
    ({'vary': {'f_iso_max_n': {'low': 30.0, 'hi': 60.0, 'n': 3}}},
     'unknown key `vary.f_iso_max_n.hi`'),
    ({'vary': {'n_units': {'low': 10, 'high': 100, 'n': 3}}},
     '`vary.n_units` is not a real-valued parameter'),
    ({'vary': {'f_iso_max_n': [30.0, -3.0]}},
     'parameter set 1 (f_iso_max_n=-3.0): `f_iso_max_n` must be positive'),
    ({'samples': 4, 'vary': {'f_iso_max_n': [30.0, 60.0]}},
     'with `samples`, `vary.f_iso_max_n` must be a range'),
    ({'samples': 0}, '`samples` must be a positive integer, got 0'),
    ({'sample_times_s': [1.0005]}, '`sample_times_s[0]` must be a multiple of the step'),
    ({'sample_times_s': [7.0]}, '`sample_times_s[0]` must be within the protocol, 0..6 s'),
    ({'plant': 'knee.yaml'}, 'with `plant`, `protocol` must be the path of a limb protocol '
                             "(inputs per muscle), got 'II'"),
    ({'vari': {}}, 'unknown key `vari`'),
])
def test_bad_spec_is_an_error_naming_the_key_and_value(change, message):
    doc = {'protocol': 'II', 'sample_times_s': [1.0], 'vary': {'f_iso_max_n': [30.0]}}
    with pytest.raises(SweepError) as err:
        parse_spec({**doc, **change}, 'spec.yaml')
    assert message in str(err.value)


def test_cli_reports_a_bad_spec_in_one_line_with_status_2(tmp_path, capsys):
    spec = write_spec(tmp_path, {**SMALL, 'vary': {'f_iso_max': [30.0]}})
    status = cli.main(['sweep', str(spec), '--out', str(tmp_path / 'out.parquet'),
                       '--workers', '0'])
    err = capsys.readouterr().err
    assert status == cli.EXIT_USAGE
    assert err.startswith(f'hill-muscle: error: {spec}: unknown parameter `vary.f_iso_max`')
    assert 'Traceback' not in err and not (tmp_path / 'out.parquet').exists()



#: A sweep of one set and one sample time, to 0.1 s: the cheapest that writes a table.
TINY = {'protocol': 'II', 'sample_times_s': [0.1], 'vary': {'f_iso_max_n': [30.0]}}


def test_existing_out_file_is_refused_naming_it_and_left_unchanged(tmp_path, capsys):
    out = tmp_path / 'out.parquet'
    out.write_bytes(b'results of yesterday')
    status = cli.main(['sweep', str(write_spec(tmp_path, TINY)), '--out', str(out),
                       '--workers', '0'])
    assert status == cli.EXIT_USAGE
    assert capsys.readouterr().err == (f'hill-muscle: error: {out} exists: pass --overwrite '
                                       'to replace it, or choose another --out\n')
    assert out.read_bytes() == b'results of yesterday'


def test_existing_out_file_is_replaced_with_overwrite(tmp_path, capsys):
    out = tmp_path / 'out.parquet'
    out.write_bytes(b'results of yesterday')
    assert cli.main(['sweep', str(write_spec(tmp_path, TINY)), '--out', str(out),
                     '--workers', '0', '--overwrite']) == 0
    assert pq.read_table(out).num_rows == 1


def test_a_directory_as_out_is_refused_even_with_overwrite(tmp_path, capsys):
    status = cli.main(['sweep', str(write_spec(tmp_path, TINY)), '--out', str(tmp_path),
                       '--workers', '0', '--overwrite'])
    assert status == cli.EXIT_USAGE
    assert f'{tmp_path}: --out is a directory' in capsys.readouterr().err


# --------------------------------------------------------------------------- numbers

def test_batch_forces_equal_separate_simulate_runs_to_1e_9_newton():
    # The four variants, an FES muscle (activation, delay, fatigue: the scalar
    # engine inside the batch) and pulse widths through a threshold curve.
    protocol = Protocol.from_yaml(protocol_path('I'))
    params = [MuscleParams(units=u, length=ln, f_iso_max_n=f)
              for u in ('multi', 'single') for ln in ('initial', 'instantaneous')
              for f in (35.0, 55.0)]
    params.append(MuscleParams(tau_act_s=0.05, tau_deact_s=0.08, emd_s=0.02,
                               fatigue='riener', recruitment_curve='threshold_linear',
                               pw_threshold_s=5e-5))
    indices = [0, 250, 1000, 1999, 3000]
    got = simulate_forces(protocol, params, 1000.0, indices)
    for i, p in enumerate(params):
        want = simulate(protocol, p, 1000.0).force_n[indices]
        np.testing.assert_allclose(got[i], want, rtol=0, atol=ATOL_N)


def test_local_run_writes_the_tidy_table_of_the_reference_forces(tmp_path, capsys):
    spec_path = write_spec(tmp_path, SMALL)
    out = tmp_path / 'out.parquet'
    assert cli.main(['sweep', str(spec_path), '--out', str(out), '--workers', '0']) == 0
    spec = parse_spec(SMALL)
    table = pq.read_table(out)
    assert table.column_names == COLUMNS
    np.testing.assert_allclose(forces_of(table, spec), reference_forces(spec),
                               rtol=0, atol=ATOL_N)
    assert set(table.column('worker').to_pylist()) == {'local'}
    assert table.column('units').to_pylist()[::4] == [v[1] for v in spec.values]
    assert table.schema.metadata[b'hill_muscle_ros.complete'] == b'true'
    assert f'wrote 32 rows to {out}' in capsys.readouterr().out


def test_other_commands_import_no_dask_or_pyarrow():
    code = ('import sys; from hill_muscle_ros.tools import cli; cli.build_parser(); '
            'import hill_muscle_ros.tools.sweep; '
            'print(sorted(m for m in ("dask", "distributed", "pyarrow", "scipy") '
            'if m in sys.modules))')
    out = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                         check=True).stdout
    assert out.strip() == '[]'


# --------------------------------------------------------------------------- Dask

def throughput(n_sets: int, elapsed_s: float) -> str:
    return f'{n_sets / elapsed_s:.1f} sets/s ({n_sets} sets in {elapsed_s:.2f} s)'


#: A sweep big enough to time: 32 sets of Protocol II to 2 s.
TIMED = {'protocol': 'II', 'sample_times_s': [1.0, 2.0],
         'vary': {'f_iso_max_n': {'low': 30.0, 'high': 60.0, 'n': 16},
                  'units': ['multi', 'single']}}
#: Sets per task in the timed runs: 2 tasks per worker of a 2-worker cluster.
TIMED_CHUNK = 8


@pytest.mark.slow
def test_local_cluster_of_two_worker_processes_gives_the_local_numbers(tmp_path, capsys):
    spec = parse_spec(TIMED)
    local = run_sweep(spec, workers=0, chunk=TIMED_CHUNK)
    out = tmp_path / 'out.parquet'
    args = ['sweep', str(write_spec(tmp_path, TIMED)), '--out', str(out),
            '--workers', '2', '--chunk', str(TIMED_CHUNK)]
    start = time.perf_counter()
    assert cli.main(args) == 0
    wall = time.perf_counter() - start
    table = pq.read_table(out)
    local_forces = np.empty((len(spec.sets), 2))
    for res in local.results:
        local_forces[res['set_ids']] = res['force_n']
    np.testing.assert_allclose(forces_of(table, spec), local_forces, rtol=0, atol=ATOL_N)
    workers = set(table.column('worker').to_pylist())
    # Computed in worker processes (their TCP addresses), never in this one.
    assert 1 <= len(workers) <= 2 and all(w.startswith('tcp://127.0.0.1:') for w in workers)
    line = capsys.readouterr().out
    with capsys.disabled():
        print(f'\nsweep throughput, in-process: {throughput(local.n_sets, local.elapsed_s)}; '
              f'LocalCluster of 2: {line.strip().splitlines()[-1]}; '
              f'with cluster start-up {len(spec.sets) / wall:.1f} sets/s')


def wait_for(condition, what: str, deadline_s: float = DEADLINE_S):
    end = time.monotonic() + deadline_s
    while time.monotonic() < end:
        value = condition()
        if value:
            return value
        time.sleep(POLL_S)
    raise AssertionError(f'timed out after {deadline_s} s waiting for {what}')


def stop_group(proc: subprocess.Popen) -> None:
    """Stop a process started in its own session, and everything it started."""
    if proc.poll() is None:
        os.killpg(proc.pid, signal.SIGTERM)
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()


def as_from_a_terminal() -> None:
    """In the child before exec: SIGINT at its default, as a terminal's shell
    starts a foreground command. A pytest started in the background by a
    shell without job control inherits SIGINT ignored, its children too, and
    Python leaves an inherited ignored SIGINT ignored: the sweep then ran all
    its sets through the Ctrl-C and exited 0 (a fresh clone's serial run)."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def group_gone(pgid: int) -> bool:
    try:
        os.killpg(pgid, 0)
    except ProcessLookupError:
        return True
    return False


@pytest.mark.slow
def test_ctrl_c_stops_the_sweep_and_keeps_the_finished_sets(tmp_path):
    # Enough sets that the sweep is still running when the signal lands: with
    # the compiled muscle 40 sets took 2.1 s, and at idle priority beside the
    # ROS tests the test saw the second set done only after the last (exit 0).
    # One worker process: the Ctrl-C reaches it as it reaches each of several
    # (its process group), and a second one's start cost 2 CPU-s; two workers
    # computing one sweep are test_local_cluster_of_two_worker_processes...'s.
    n_sets = 400
    doc = {'protocol': 'II', 'sample_times_s': [1.0, 6.0],
           'vary': {'f_iso_max_n': {'low': 30.0, 'high': 60.0, 'n': n_sets}}}
    out = tmp_path / 'out.parquet'
    # As a user would: its own session, and Ctrl-C to the whole process group.
    proc = subprocess.Popen(
        [str(VENV_BIN / 'hill-muscle'), 'sweep', str(write_spec(tmp_path, doc)),
         '--out', str(out), '--workers', '1', '--chunk', '1'],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, start_new_session=True,
        preexec_fn=as_from_a_terminal)
    try:
        os.set_blocking(proc.stderr.fileno(), False)
        progress = bytearray()

        def two_sets_done():
            try:
                progress.extend(os.read(proc.stderr.fileno(), 4096))
            except BlockingIOError:
                pass
            return f' 2/{n_sets} sets'.encode() in progress or proc.poll() is not None

        wait_for(two_sets_done, 'two finished sets')
        assert proc.poll() is None, 'the sweep ended before it could be interrupted'
        os.killpg(proc.pid, signal.SIGINT)
        os.set_blocking(proc.stderr.fileno(), True)
        _, err = proc.communicate(timeout=DEADLINE_S)
    finally:
        stop_group(proc)
    wait_for(lambda: group_gone(proc.pid), 'the workers to exit')
    assert proc.returncode == 130, err.decode()
    assert 'Traceback' not in err.decode(), err.decode()
    table = pq.read_table(out)
    assert table.schema.metadata[b'hill_muscle_ros.complete'] == b'false'
    ids = sorted(set(table.column('set_id').to_pylist()))
    assert 2 <= len(ids) < n_sets
    spec = parse_spec(doc)
    protocol = spec.protocol
    got = {(r['set_id'], r['t_s']): r['force_n'] for r in table.to_pylist()}
    for i in ids:
        want = simulate(protocol, spec.sets[i]).force_n
        for t in (1.0, 6.0):
            assert math.isclose(got[(i, t)], want[round(t * 1000)], rel_tol=0,
                                abs_tol=ATOL_N)



def worker_log(message: str) -> logging.LogRecord:
    return logging.LogRecord('distributed.worker', logging.ERROR, __file__, 0, message,
                             None, None)


@pytest.mark.parametrize('status, kept', [('running', True), ('closing', False),
                                          ('closing_gracefully', False), ('closed', False)])
def test_a_heartbeat_cut_by_the_workers_own_close_is_dropped_and_no_other_record(status, kept):
    from distributed.core import Status
    keep = HeartbeatOnCloseFilter(types.SimpleNamespace(status=Status[status])).filter
    assert keep(worker_log(HEARTBEAT_FAILED + '.')) is kept
    assert keep(worker_log('Worker stream died during communication')) is True


def test_the_dropped_heartbeat_message_is_the_one_the_pinned_distributed_logs():
    import inspect

    from distributed.worker import Worker
    assert f'"{HEARTBEAT_FAILED}.' in inspect.getsource(Worker.heartbeat)


# --------------------------------------------------------------------------- README

def readme_sweep_section() -> str:
    """The section "Parameter sweeps" of doc/fit_and_sweep.md (the README's
    sweep reference lives there), up to the next section or the end."""
    text = (REPO / 'doc' / 'fit_and_sweep.md').read_text(encoding='utf-8')
    start = text.index('## Parameter sweeps')
    end = text.find('\n## ', start + 1)
    return text[start:end if end >= 0 else len(text)]


def test_readme_spec_is_the_shipped_example_spec():
    section = readme_sweep_section()
    shown = section.split('```yaml\n', 1)[1].split('```', 1)[0]
    shipped = REPO / 'config' / 'sweep_example.yaml'
    assert yaml.safe_load(shown) == yaml.safe_load(shipped.read_text(encoding='utf-8'))


def test_readme_forces_are_those_of_simulate():
    rows = re.findall(r'^ *([\d.]+) N +([\d.]+) N/m +(multi|single) +([\d.]+) N +tcp://',
                      readme_sweep_section(), flags=re.MULTILINE)
    assert len(rows) == 6
    protocol = Protocol.from_yaml(protocol_path('II'))
    spec = parse_spec(yaml.safe_load((REPO / 'config' / 'sweep_example.yaml').read_text()))
    for f_iso, k_se, units, force in rows:
        # doc/fit_and_sweep.md rounds k_se to 0.1 N/m: find the set it shows.
        [params] = [p for p in spec.sets if p.f_iso_max_n == float(f_iso)
                    and abs(p.k_se_n_per_m - float(k_se)) < 0.05 and p.units == units]
        want = simulate(protocol, params).force_n[4000]   # t = 4 s at 1 kHz
        assert f'{want:.3f}' == force


# --------------------------------------------------------------------------- limb

CONFIG = config_dir()
#: [rad] bound on a limb sweep's joint angle vs separate runs.
ATOL_RAD = 1e-9
#: A small knee sweep: 2 x 2 = 4 plants, the knee extension to 1 s (the
#: quadriceps stimulated from 0.5 s, 31 ms of delay).
KNEE = {'plant': 'knee.yaml', 'protocol': 'protocols/knee_extension.yaml',
        'sample_times_s': [0.0, 0.6, 1.0],
        'vary': {'quadriceps.f_iso_max_n': [1000.0, 1500.0],
                 'hamstrings.moment_arm_m': [0.028, 0.035]}}
KNEE_COLUMNS = ['set_id', 'quadriceps.f_iso_max_n', 'hamstrings.moment_arm_m', 't_s',
                'theta_rad', 'quadriceps_force_n', 'hamstrings_force_n', 'worker']


def knee_plants():
    """KNEE's plants built here, in the grid's order (the first entry slowest)."""
    base = load_plant(CONFIG / 'knee.yaml')[0]
    quad, ham = base.muscles
    return [dataclasses.replace(base, muscles=(
        dataclasses.replace(quad, params=dataclasses.replace(quad.params, f_iso_max_n=f)),
        dataclasses.replace(ham, moment_arm_m=arm)))
        for f in (1000.0, 1500.0) for arm in (0.028, 0.035)]


def limb_reference(plants, protocol, rate_hz, times):
    """theta (sets, times) and forces (sets, muscles, times), one simulate_limb per plant."""
    idx = [round(t * rate_hz) for t in times]
    runs = [simulate_limb(p, protocol, rate_hz) for p in plants]
    theta = np.array([r['theta_rad'][idx] for r in runs])
    force = np.array([[r[f'{m.name}_force_n'][idx] for m in p.muscles]
                      for r, p in zip(runs, plants)])
    return theta, force


def limb_columns_of(table, spec):
    """theta (sets, times) and forces (sets, muscles, times) of a limb table."""
    n_sets, n_times = len(spec.sets), len(spec.sample_times_s)
    assert table.num_rows == n_sets * n_times
    assert table.column('set_id').to_pylist() == [i for i in range(n_sets)
                                                  for _ in range(n_times)]
    theta = np.asarray(table.column('theta_rad')).reshape(n_sets, n_times)
    force = np.stack([np.asarray(table.column(f'{m}_force_n')).reshape(n_sets, n_times)
                      for m in spec.muscle_names], axis=1)
    return theta, force


def test_limb_grid_replaces_only_the_named_muscle_and_joint_parameters():
    spec = parse_spec({**KNEE, 'vary': {'quadriceps.f_iso_max_n': [1000.0, 1500.0],
                                        'joint.stiffness_n_m_per_rad': [15.0, 25.0],
                                        'hamstrings.moment_arm_m': [0.03]}},
                      'spec.yaml', CONFIG)
    base = load_plant(CONFIG / 'knee.yaml')[0]
    assert spec.values == ((1000.0, 15.0, 0.03), (1000.0, 25.0, 0.03),
                           (1500.0, 15.0, 0.03), (1500.0, 25.0, 0.03))
    for (f, k, arm), plant in zip(spec.values, spec.sets):
        quad, ham = plant.muscles
        assert quad.params == dataclasses.replace(base.muscles[0].params, f_iso_max_n=f)
        assert ham == dataclasses.replace(base.muscles[1], moment_arm_m=arm)
        assert plant.joint == dataclasses.replace(base.joint, stiffness_n_m_per_rad=k)
    assert spec.rate_hz == 1000.0   # the plant file's rate_hz


@pytest.mark.parametrize('change, message', [
    ({'vary': {'quadriceps.f_iso_max': [1.0]}},
     'unknown parameter `vary.quadriceps.f_iso_max` of muscle `quadriceps` '
     '(known: moment_arm_m, reference_angle_rad, f_iso_max_n,'),
    ({'vary': {'quadriceps.action': ['flexor']}},
     'unknown parameter `vary.quadriceps.action` of muscle `quadriceps`'),
    ({'vary': {'joint.stiffness': [1.0]}},
     'unknown parameter `vary.joint.stiffness` of the joint (known: joint.inertia_kg_m2,'),
    ({'vary': {'joint.name': ['ankle']}}, 'unknown parameter `vary.joint.name` of the joint'),
    ({'vary': {'f_iso_max_n': [1.0]}},
     '`vary.f_iso_max_n`: on a limb, name the joint or the muscle first, as the plant file '
     'does, e.g. `joint.damping_n_m_s_per_rad` or `quadriceps.f_iso_max_n` '
     '(parts: joint, quadriceps, hamstrings)'),
    ({'vary': {'soleus.f_iso_max_n': [1.0]}},
     '`vary.soleus.f_iso_max_n`: the plant has no joint or muscle `soleus` '
     '(parts: joint, quadriceps, hamstrings)'),
    ({'vary': {'quadriceps.f_iso_max_n': [1000.0, -3.0]}},
     'parameter set 1 (quadriceps.f_iso_max_n=-3.0): `f_iso_max_n` must be positive'),
    ({'vary': {'joint.inertia_kg_m2': [0.0]}},
     'parameter set 0 (joint.inertia_kg_m2=0.0): `joint.inertia_kg_m2` must be'),
    ({'vary': {'hamstrings.moment_arm_m': [2.0]}},
     '`hamstrings.moment_arm_m` must be in (0, 1] m, got 2.0'),
    ({'vary': {'quadriceps.n_units': {'low': 10, 'high': 100, 'n': 3}}},
     '`vary.quadriceps.n_units` is not a real-valued parameter'),
    ({'params': 'muscle.yaml'},
     "`params` (a muscle's parameters) and `plant` (a limb) exclude each other"),
    ({'protocol': 'II'}, 'with `plant`, `protocol` must be the path of a limb protocol'),
    ({'plant': 'ankle.yaml'}, "knee_extension.yaml: protocol `knee extension`: muscle "
                              "`quadriceps` is not in the plant (muscles: tibialis_anterior)"),
    ({'sample_times_s': [6.5]}, '`sample_times_s[0]` must be within the protocol, 0..6 s'),
])
def test_bad_limb_spec_is_an_error_naming_the_key_and_value(change, message):
    doc = {**KNEE, 'vary': {'quadriceps.f_iso_max_n': [1000.0]}, **change}
    with pytest.raises(SweepError) as err:
        parse_spec(doc, 'spec.yaml', CONFIG)
    assert message in str(err.value)


def test_local_limb_sweep_writes_the_tidy_table_of_simulate_limb(tmp_path, capsys):
    doc = {**KNEE, 'plant': str(CONFIG / 'knee.yaml'),
           'protocol': str(CONFIG / 'protocols' / 'knee_extension.yaml')}
    out = tmp_path / 'out.parquet'
    assert cli.main(['sweep', str(write_spec(tmp_path, doc)), '--out', str(out),
                     '--workers', '0']) == 0
    spec = parse_spec(doc)
    table = pq.read_table(out)
    assert table.column_names == KNEE_COLUMNS
    theta, force = limb_columns_of(table, spec)
    protocol = LimbProtocol.from_yaml(CONFIG / 'protocols' / 'knee_extension.yaml')
    want_theta, want_force = limb_reference(knee_plants(), protocol, 1000.0,
                                            spec.sample_times_s)
    np.testing.assert_allclose(theta, want_theta, rtol=0, atol=ATOL_RAD)
    np.testing.assert_allclose(force, want_force, rtol=0, atol=ATOL_N)
    # The sets differ where they should: a stronger quadriceps lifts the shank higher.
    assert theta[2, -1] > theta[0, -1] > 0.1
    assert table.column('hamstrings.moment_arm_m').to_pylist()[::3] == [0.028, 0.035] * 2
    assert set(table.column('worker').to_pylist()) == {'local'}
    assert table.schema.metadata[b'hill_muscle_ros.plant'] == b'knee: quadriceps, hamstrings'
    assert f'wrote 12 rows to {out}' in capsys.readouterr().out


def test_limb_driven_out_of_range_stops_the_sweep_naming_the_set(tmp_path, capsys):
    # 1000 N m on the foot (its joint spring of 20.4 N m/rad balances it at
    # 49 rad): damped by 40 N m s/rad (set 0) it creeps there with a time
    # constant of 2 s, 11 rad in 0.5 s, 0.4 m of its muscle's MTU; with the
    # preset's 0.82 (set 1) it spins until the MTU passes 1 m. (Far more
    # damping would make the 1 ms RK4 step unstable: B / J times 1 ms must
    # stay below 2.78.)
    protocol = tmp_path / 'push.yaml'
    protocol.write_text(yaml.safe_dump({
        'name': 'push', 'duration_s': 0.5,
        'muscles': {'tibialis_anterior': {'recruitment': [[0.0, 0.0]]}},
        'external_torque_n_m': [[0.0, 1000.0]]}))
    doc = {'plant': str(CONFIG / 'ankle.yaml'), 'protocol': str(protocol),
           'sample_times_s': [0.5], 'vary': {'joint.damping_n_m_s_per_rad': [40.0, 0.82]}}
    status = cli.main(['sweep', str(write_spec(tmp_path, doc)), '--out',
                       str(tmp_path / 'out.parquet'), '--workers', '0'])
    err = capsys.readouterr().err
    assert status == cli.EXIT_USAGE
    assert 'hill-muscle: error: parameter set 1: muscle `tibialis_anterior` is stretched' in err
    assert 'Traceback' not in err and not (tmp_path / 'out.parquet').exists()


#: KNEE to 0.6 s, for the cluster: two tasks of two plants.
KNEE_CLUSTER = {**KNEE, 'sample_times_s': [0.3, 0.6]}


# --------------------------------------------------------------------------- README, limb

def test_readme_knee_spec_is_the_shipped_knee_example_spec():
    section = readme_sweep_section()
    shown = section.split('```yaml\n')[2].split('```', 1)[0]
    shipped = CONFIG / 'sweep_knee_example.yaml'
    assert yaml.safe_load(shown) == yaml.safe_load(shipped.read_text(encoding='utf-8'))


def test_readme_knee_rows_are_those_of_simulate_limb():
    rows = re.findall(r'^ *([\d.]+) N +([\d.]+) N m/rad +(-?[\d.]+) deg +([\d.]+) N +'
                      r'([\d.]+) N +tcp://', readme_sweep_section(), flags=re.MULTILINE)
    spec = load_spec(CONFIG / 'sweep_knee_example.yaml')
    assert len(rows) == len(spec.sets)
    to_2s = dataclasses.replace(spec.protocol, duration_s=2.0)   # the rows are at 2 s
    for (f_iso, k, theta, quad, ham), plant in zip(rows, spec.sets):
        assert (plant.muscles[0].params.f_iso_max_n, plant.joint.stiffness_n_m_per_rad) == (
            float(f_iso), float(k))
        run = simulate_limb(plant, to_2s, spec.rate_hz)
        k2 = 2000   # t = 2 s at 1 kHz
        assert f'{math.degrees(run["theta_rad"][k2]):.2f}' == theta
        assert f'{run["quadriceps_force_n"][k2]:.1f}' == quad
        assert f'{run["hamstrings_force_n"][k2]:.2f}' == ham


class _FakeClient:
    def __init__(self, status: str) -> None:
        self.status = status


def _scheduler_record(message: str) -> logging.LogRecord:
    return logging.LogRecord('distributed.scheduler', logging.CRITICAL, __file__, 0, message,
                             None, None)


@pytest.mark.parametrize('status', ['closing', 'closed'])
def test_the_schedulers_report_to_our_closed_client_is_dropped(status):
    quiet = sweep.ClientGoneFilter()
    quiet.client = _FakeClient(status)
    assert not quiet.filter(_scheduler_record(sweep.CLIENT_GONE + " {'op': 'key-in-memory'}"))


def test_the_schedulers_report_to_an_open_client_and_other_records_are_kept():
    quiet = sweep.ClientGoneFilter()
    quiet.client = _FakeClient('running')
    assert quiet.filter(_scheduler_record(sweep.CLIENT_GONE + " {'op': 'key-in-memory'}"))
    quiet.client = _FakeClient('closed')
    assert quiet.filter(_scheduler_record('Unexpected worker completed task'))


# --------------------------------------------------------------------------- Dask processes
# Last in the module: the scheduler and workers started once for these tests
# idle at about 0.1 CPU-s a second each until the module ends.

@pytest.fixture(scope='module')
def dask_processes(tmp_path_factory):
    """A scheduler and two workers started as processes, as doc/fit_and_sweep.md
    shows (``dask scheduler``, ``dask worker ADDRESS``), each in its own
    session: its address and the workers it registered. Shared by every test
    that needs a cluster but not its start by the command (each start of a
    cluster cost 2.5 to 6.5 CPU-s); test_local_cluster_of_two_worker_processes...
    and test_ctrl_c_... keep ``--workers 2`` starting its own. Nothing but
    test_the_sweep_plugin_puts_the_filter_in_every_worker_process registers the
    sweep's plugin on these workers (``--scheduler`` does not). At the end
    every process group must be gone."""
    from distributed import Client

    d = tmp_path_factory.mktemp('dask')
    scheduler_file = d / 'scheduler.json'
    logs = [open(d / f'{name}.log', 'wb') for name in ('scheduler', 'w1', 'w2')]
    procs = []
    try:
        procs.append(subprocess.Popen(
            [str(VENV_BIN / 'dask'), 'scheduler', '--port', '0', '--no-dashboard',
             '--scheduler-file', str(scheduler_file)],
            stdout=logs[0], stderr=subprocess.STDOUT, start_new_session=True))
        address = wait_for(lambda: scheduler_file.exists() and scheduler_file.stat().st_size
                           and json.loads(scheduler_file.read_text())['address'],
                           'the scheduler file')
        for log in logs[1:]:
            procs.append(subprocess.Popen(
                [str(VENV_BIN / 'dask'), 'worker', address, '--nthreads', '1',
                 '--no-dashboard'],
                stdout=log, stderr=subprocess.STDOUT, start_new_session=True, cwd=d))
        with Client(address, timeout='30s') as client:
            client.wait_for_workers(2, timeout=DEADLINE_S)
            registered = set(client.scheduler_info(n_workers=-1)['workers'])
        yield types.SimpleNamespace(address=address, registered=registered)
    finally:
        for proc in reversed(procs):
            stop_group(proc)
        for log in logs:
            log.close()
    for proc in procs:
        wait_for(lambda: group_gone(proc.pid), f'process group {proc.pid} to exit')


@pytest.mark.slow
def test_scheduler_and_workers_started_as_processes_compute_the_sweep(tmp_path, capsys,
                                                                      dask_processes):
    assert len(dask_processes.registered) == 2
    out = tmp_path / 'out.parquet'
    args = ['sweep', str(write_spec(tmp_path, TIMED)), '--out', str(out),
            '--scheduler', dask_processes.address, '--chunk', str(TIMED_CHUNK)]
    assert cli.main(args) == 0
    spec = parse_spec(TIMED)
    table = pq.read_table(out)
    np.testing.assert_allclose(forces_of(table, spec), reference_forces(spec),
                               rtol=0, atol=ATOL_N)
    assert set(table.column('worker').to_pylist()) <= dask_processes.registered
    line = capsys.readouterr().out.strip().splitlines()[-1]
    with capsys.disabled():
        print(f'\nsweep throughput, dask scheduler + 2 dask workers: {line}')


@pytest.mark.slow
def test_limb_sweep_on_a_local_cluster_of_two_workers_gives_the_local_numbers(
        tmp_path, dask_processes):
    # The command sends the sets to the shared scheduler and two workers
    # (--scheduler); a cluster the command starts itself (--workers 2) is
    # test_local_cluster_of_two_worker_processes_gives_the_local_numbers' claim.
    doc = {**KNEE_CLUSTER, 'plant': str(CONFIG / 'knee.yaml'),
           'protocol': str(CONFIG / 'protocols' / 'knee_extension.yaml')}
    spec = parse_spec(doc)
    local = run_sweep(spec, workers=0, chunk=2)
    out = tmp_path / 'out.parquet'
    assert cli.main(['sweep', str(write_spec(tmp_path, doc)), '--out', str(out),
                     '--scheduler', dask_processes.address,
                     '--chunk', '2']) == 0
    table = pq.read_table(out)
    assert table.column_names == KNEE_COLUMNS
    theta, force = limb_columns_of(table, spec)
    want_theta = np.empty_like(theta)
    want_force = np.empty_like(force)
    for res in local.results:
        want_theta[res['set_ids']] = res['theta_rad']
        want_force[res['set_ids']] = res['force_n']
    np.testing.assert_allclose(theta, want_theta, rtol=0, atol=ATOL_RAD)
    np.testing.assert_allclose(force, want_force, rtol=0, atol=ATOL_N)
    workers = set(table.column('worker').to_pylist())
    # Computed in the worker processes, never in this one.
    assert 1 <= len(workers) <= 2 and workers <= dask_processes.registered


@pytest.mark.slow
def test_sweeps_back_to_back_on_one_cluster_all_complete(dask_processes):
    # The second sweep's copy of the same protocol must not share a key with
    # the first's, which the scheduler is releasing (its tasks were cancelled).
    from distributed import Client

    spec = parse_spec({**TIMED, 'sample_times_s': [0.2]})
    with Client(dask_processes.address, timeout='30s') as client:
        for _ in range(3):
            result = run_on_client(spec, client, chunk=TIMED_CHUNK)
            assert result.complete and result.n_sets == len(spec.sets)


def test_the_sweep_plugin_puts_the_filter_in_every_worker_process(dask_processes):
    from distributed import Client

    def filters():
        return [type(f).__name__ for f in logging.getLogger('distributed.worker').filters]

    with Client(dask_processes.address, timeout='30s') as client:
        client.register_plugin(quiet_heartbeat_on_close(), name=QUIET_HEARTBEAT_PLUGIN)
        found = client.run(filters)
    assert len(found) == 2
    assert all(names.count('HeartbeatOnCloseFilter') == 1 for names in found.values()), found
