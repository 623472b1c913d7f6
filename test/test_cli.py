"""The ``hill-muscle`` command: options, CSV output, errors, node forwarding.

The CSV and the table are compared with the offline core (``simulate``) run on
the same protocol and parameters, never with numbers copied from output.
"""
import importlib.util
import os
import subprocess
import sys
import textwrap
import types
from pathlib import Path

import numpy as np
import pytest

from hill_muscle_ros.model import COLUMNS, MuscleParams, Protocol, engine, force_length, simulate
from hill_muscle_ros.params_file import load_muscle_params
from hill_muscle_ros.resources import default_params_file
from hill_muscle_ros.tools import cli

HILL_MUSCLE = Path(sys.executable).with_name('hill-muscle')
CSV_HEADER = ('t_s,recruitment,dl_mt_m,l_ce_m,v_ce_m_s,f_se_n,f_pe_n,force_n,eff_f_iso_n,'
              'command,mean_fitness')
#: [s] generous: the machine is shared with other test runs.
SUBPROCESS_TIMEOUT_S = 120
#: Shipped parameters; the CLI uses them when --params is not given.
DEFAULT_PARAMS, _ = load_muscle_params(default_params_file())


def run_cli(*args, cwd=None):
    """Run the installed console script; return the completed process."""
    return subprocess.run([str(HILL_MUSCLE), *map(str, args)], capture_output=True,
                          text=True, env=os.environ.copy(), cwd=cwd,
                          timeout=SUBPROCESS_TIMEOUT_S)


def run_main(capsys, *args):
    """Run the command's entry function ``cli.main`` in this process; return
    what a subprocess would: exit status and the text written to each stream."""
    capsys.readouterr()
    status = cli.main([str(a) for a in args])
    out, err = capsys.readouterr()
    return types.SimpleNamespace(returncode=status, stdout=out, stderr=err)


def read_csv(path):
    """Header line and the data as a 2-D array."""
    with open(path, encoding='utf-8') as f:
        header = f.readline().rstrip('\n')
    return header, np.loadtxt(path, delimiter=',', skiprows=1, ndmin=2)


def core(protocol_paths, name, rate_hz=1000.0, **changes):
    """The core simulation that the CLI should reproduce."""
    params = DEFAULT_PARAMS.replace(**changes) if changes else DEFAULT_PARAMS
    return simulate(Protocol.from_yaml(protocol_paths[name]), params, rate_hz)


def assert_csv_equals_result(data, result):
    for i, (attr, header) in enumerate(COLUMNS):
        np.testing.assert_array_equal(data[:, i], getattr(result, attr), err_msg=header)


def write_params(tmp_path, body, name='muscle.yaml'):
    path = tmp_path / name
    path.write_text('/**:\n  ros__parameters:\n' + textwrap.indent(textwrap.dedent(body), '    '))
    return path


# --------------------------------------------------------------------------- help

def test_console_script_help_exits_zero():
    proc = run_cli('--help')
    assert proc.returncode == 0, proc.stderr
    assert 'usage: hill-muscle' in proc.stdout


# In this process (the console script's entry function): a subprocess per
# subcommand re-imported numpy and the package each time, 0.3-0.5 s apiece.
@pytest.mark.parametrize('subcommand', [[], ['simulate'], ['figures'], ['simulator'],
                                        ['player'], ['record'], ['controller']])
def test_help_of_every_subcommand_exits_zero(capsys, subcommand):
    assert cli.main([*subcommand, '--help']) == 0
    assert 'usage: hill-muscle' in capsys.readouterr().out


def test_node_help_says_it_is_a_ros_node_and_how_to_set_parameters(capsys):
    assert cli.main(['simulator', '-h']) == 0
    out = capsys.readouterr().out
    assert 'ROS 2 node' in out
    assert '--ros-args -p NAME:=VALUE' in out
    assert 'ros2 run hill_muscle_ros simulator' in out


# --------------------------------------------------------------------------- CSV

def test_csv_header_is_exact(tmp_path):
    out = tmp_path / 'run.csv'
    assert cli.main(['simulate', '--protocol', 'II', '--rate', '100', '--csv', str(out)]) == 0
    assert read_csv(out)[0] == CSV_HEADER


def test_csv_has_one_row_per_step_from_zero_to_the_end_at_1khz(tmp_path, capsys):
    # In this process: the console script of `simulate` runs in
    # test_malformed_protocol_file_exits_2_naming_file_and_key (a subprocess
    # here cost 1.4 CPU-s for the rows that cli.main writes the same).
    out = tmp_path / 'run.csv'
    proc = run_main(capsys, 'simulate', '--protocol', 'II', '--csv', out)
    assert proc.returncode == 0, proc.stderr
    _, data = read_csv(out)
    assert data.shape == (6001, len(COLUMNS))
    assert data[0, 0] == 0.0 and data[-1, 0] == 6.0


def test_rate_option_sets_the_step(tmp_path):
    out = tmp_path / 'run.csv'
    assert cli.main(['simulate', '--protocol', 'I', '--rate', '100', '--csv', str(out)]) == 0
    _, data = read_csv(out)
    assert len(data) == 601
    np.testing.assert_allclose(np.diff(data[:, 0]), 0.01, rtol=1e-9)


@pytest.mark.parametrize('name', ['I', 'II'])
def test_csv_columns_equal_the_core_simulation_exactly(tmp_path, protocol_paths, name):
    out = tmp_path / 'run.csv'
    assert cli.main(['simulate', '--protocol', name, '--csv', str(out)]) == 0
    assert_csv_equals_result(read_csv(out)[1], core(protocol_paths, name))


def test_protocol_given_as_a_path_is_used(tmp_path, protocol_paths):
    out = tmp_path / 'run.csv'
    assert cli.main(['simulate', '--protocol', str(protocol_paths['I']), '--rate', '200',
                     '--csv', str(out)]) == 0
    assert_csv_equals_result(read_csv(out)[1], core(protocol_paths, 'I', 200.0))


@pytest.mark.parametrize('units,length', [('single', 'initial'), ('multi', 'instantaneous'),
                                          ('single', 'instantaneous')])
def test_units_and_length_options_select_the_variant(tmp_path, protocol_paths, units, length):
    out = tmp_path / 'run.csv'
    assert cli.main(['simulate', '--protocol', 'II', '--units', units, '--length', length,
                     '--rate', '200', '--csv', str(out)]) == 0
    expected = core(protocol_paths, 'II', 200.0, units=units, length=length)
    assert_csv_equals_result(read_csv(out)[1], expected)


def test_options_override_the_variant_in_the_params_file(tmp_path, protocol_paths):
    params = write_params(tmp_path, 'units: single\nlength: instantaneous\n')
    out = tmp_path / 'run.csv'
    assert cli.main(['simulate', '--protocol', 'II', '--params', str(params), '--units', 'multi',
                     '--length', 'initial', '--rate', '200', '--csv', str(out)]) == 0
    expected = simulate(Protocol.from_yaml(protocol_paths['II']),
                        MuscleParams(units='multi', length='initial'), 200.0)
    assert_csv_equals_result(read_csv(out)[1], expected)


#: [s] an isometric hold long enough for f_SE to settle to well below 1 mN.
ISOMETRIC_HOLD_S = 4.0


@pytest.mark.parametrize('f_iso_max_n', [45.0, 90.0])
def test_params_file_f_iso_max_scales_the_steady_isometric_force(tmp_path, f_iso_max_n):
    """R = 1 from rest at constant MTU length with initial length: the CE
    remembers l_rest, so f_SE settles at f_iso_max * FL(l_rest / l_opt)."""
    protocol = tmp_path / 'isometric.yaml'
    protocol.write_text(f'name: isometric\nduration_s: {ISOMETRIC_HOLD_S}\n'
                        'recruitment: [[0.0, 1.0]]\ndl_mt_m: [[0.0, 0.0]]\n')
    params = write_params(tmp_path, f'f_iso_max_n: {f_iso_max_n}\nlength: initial\n')
    out = tmp_path / 'run.csv'
    assert cli.main(['simulate', '--protocol', str(protocol), '--params', str(params),
                     '--csv', str(out)]) == 0
    _, data = read_csv(out)
    p = MuscleParams()
    steady = f_iso_max_n * force_length(p.l_rest_m / p.l_opt_m)
    assert data[-1, [h for _, h in COLUMNS].index('force_n')] == pytest.approx(steady, abs=1e-3)


def test_params_file_rate_is_used_without_rate_option(tmp_path):
    params = write_params(tmp_path, 'rate_hz: 200.0\n')
    out = tmp_path / 'run.csv'
    assert cli.main(['simulate', '--protocol', 'II', '--params', str(params),
                     '--csv', str(out)]) == 0
    assert len(read_csv(out)[1]) == 1201


def test_rate_option_overrides_the_params_file_rate(tmp_path):
    params = write_params(tmp_path, 'rate_hz: 200.0\n')
    out = tmp_path / 'run.csv'
    assert cli.main(['simulate', '--protocol', 'II', '--params', str(params), '--rate', '100',
                     '--csv', str(out)]) == 0
    assert len(read_csv(out)[1]) == 601


def test_csv_parent_directories_are_created(tmp_path):
    out = tmp_path / 'a' / 'b' / 'run.csv'
    assert cli.main(['simulate', '--protocol', 'I', '--rate', '50', '--csv', str(out)]) == 0
    assert out.is_file()


# --------------------------------------------------------------------------- table

def test_table_without_csv_gives_the_core_force_at_the_end_of_each_second(
        capsys, protocol_paths):
    assert cli.main(['simulate', '--protocol', 'II']) == 0
    lines = capsys.readouterr().out.splitlines()
    header = lines[1].split()
    rows = [dict(zip(header, map(float, line.split()))) for line in lines[2:]]
    result = core(protocol_paths, 'II')
    assert [r['t_s'] for r in rows] == [1.0, 2.0, 3.0, 4.0, 5.0, 6.0]
    for row in rows:
        # The table prints the force to 3 decimals.
        assert row['force_n'] == pytest.approx(result.force_n[result.at(row['t_s'])], abs=5e-4)


# --------------------------------------------------------------------------- errors

def assert_user_error(proc, *fragments):
    assert proc.returncode == 2
    assert 'Traceback' not in proc.stderr
    assert proc.stderr.strip().count('\n') == 0, proc.stderr  # one line
    for fragment in fragments:
        assert fragment in proc.stderr


def test_malformed_protocol_file_exits_2_naming_file_and_key(tmp_path):
    bad = tmp_path / 'bad_protocol.yaml'
    bad.write_text('name: bad\nduration_s: 1.0\nrecruitment: [[0.0, 0.5]]\n'
                   'dl_mt_m: [[1.0, 0.0], [0.5, 0.0]]\n')
    assert_user_error(run_cli('simulate', '--protocol', bad), str(bad), 'dl_mt_m')


# The console script itself exits 2 in the test above; the other user errors
# go through its entry function in this process (a subprocess each re-imported
# numpy and the package, 0.3-0.5 s apiece).

def test_protocol_file_with_yaml_syntax_error_exits_2(tmp_path, capsys):
    bad = tmp_path / 'broken.yaml'
    bad.write_text('name: [unclosed\n')
    proc = run_main(capsys, 'simulate', '--protocol', bad)
    assert proc.returncode == 2
    assert 'Traceback' not in proc.stderr and str(bad) in proc.stderr


def test_missing_protocol_file_exits_2(tmp_path, capsys):
    missing = tmp_path / 'nope.yaml'
    assert_user_error(run_main(capsys, 'simulate', '--protocol', missing), str(missing))


def test_params_file_with_unknown_key_exits_2_naming_file_and_key(tmp_path, capsys):
    params = write_params(tmp_path, 'f_iso_max: 45.0\n')
    assert_user_error(run_main(capsys, 'simulate', '--protocol', 'I', '--params', params),
                      str(params), 'f_iso_max')


def test_params_file_with_negative_stiffness_exits_2_naming_file_and_key(tmp_path, capsys):
    params = write_params(tmp_path, 'k_se_n_per_m: -3.0\n')
    assert_user_error(run_main(capsys, 'simulate', '--protocol', 'I', '--params', params),
                      str(params), 'k_se_n_per_m', '-3.0')


def test_params_file_with_bad_rate_exits_2_naming_file_and_key(tmp_path, capsys):
    params = write_params(tmp_path, 'rate_hz: 0.0\n')
    assert_user_error(run_main(capsys, 'simulate', '--protocol', 'I', '--params', params),
                      str(params), 'rate_hz')


@pytest.mark.parametrize('option', [['--rate', '0'], ['--rate', 'fast'], ['--rate', 'nan'],
                                    ['--units', 'many'], ['--length', 'final']])
def test_bad_option_value_exits_2(capsys, option):
    assert cli.main(['simulate', '--protocol', 'I', *option]) == 2
    assert option[0] in capsys.readouterr().err


def test_unwritable_csv_path_exits_2(tmp_path, capsys):
    # A directory where the file should go cannot be written as a file.
    assert_user_error(run_main(capsys, 'simulate', '--protocol', 'I', '--rate', '10', '--csv',
                               tmp_path), str(tmp_path))


# --------------------------------------------------------------------------- nodes

@pytest.fixture
def fake_node(monkeypatch):
    """Replace the simulator's module by a stub that records its argv."""
    calls = []
    module = types.ModuleType('fake_simulator_node')
    module.main = lambda args=None: calls.append(args) or 7
    monkeypatch.setitem(sys.modules, module.__name__, module)
    monkeypatch.setitem(cli.NODE_COMMANDS, 'simulator',
                        cli.NodeCommand(module.__name__, 'simulator', 'run a fake node'))
    return calls


def test_node_command_forwards_ros_args_untouched(fake_node):
    status = cli.main(['simulator', '--ros-args', '-p', 'rate_hz:=500.0', '-r', '__ns:=/leg'])
    assert fake_node == [['hill-muscle simulator', '--ros-args', '-p', 'rate_hz:=500.0',
                          '-r', '__ns:=/leg']]
    assert status == 7


def test_help_after_ros_args_goes_to_the_node(fake_node):
    cli.main(['simulator', '--ros-args', '--help'])
    assert fake_node == [['hill-muscle simulator', '--ros-args', '--help']]


def test_node_help_does_not_import_the_node(monkeypatch, capsys):
    monkeypatch.setitem(cli.NODE_COMMANDS, 'simulator',
                        cli.NodeCommand('hill_muscle_ros.nodes.no_such_node', 'simulator', 'x'))
    assert cli.main(['simulator', '--help']) == 0


def test_missing_node_module_exits_2_with_a_clear_message(monkeypatch, capsys):
    monkeypatch.setitem(cli.NODE_COMMANDS, 'simulator',
                        cli.NodeCommand('hill_muscle_ros.nodes.no_such_node', 'simulator', 'x'))
    assert cli.main(['simulator']) == 2
    err = capsys.readouterr().err
    assert 'hill_muscle_ros.nodes.no_such_node' in err and 'Traceback' not in err


def test_simulate_and_figures_never_import_rclpy(tmp_path):
    code = ('import sys; from hill_muscle_ros.tools import cli; '
            f"cli.main(['simulate', '--protocol', 'II', '--rate', '50', '--csv', {str(tmp_path / 'r.csv')!r}]); "
            "import hill_muscle_ros.tools.figures; "
            "sys.exit(1 if 'rclpy' in sys.modules else 0)")
    proc = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                          env=os.environ.copy(), timeout=SUBPROCESS_TIMEOUT_S)
    assert proc.returncode == 0, proc.stderr


@pytest.mark.ros
@pytest.mark.unpaced
def test_simulator_subcommand_hands_ros_parameters_to_the_real_node():
    """An out-of-range ``rate_hz`` reaches the node, which refuses to start."""
    if importlib.util.find_spec('hill_muscle_ros.nodes.simulator') is None:
        pytest.skip('the simulator node is not written yet')
    proc = run_cli('simulator', '--ros-args', '-p', 'rate_hz:=-1.0')
    assert proc.returncode == 1
    assert 'rate_hz' in proc.stdout + proc.stderr


def test_fes_params_file_with_arrays_runs_and_writes_command_and_mean_fitness(tmp_path):
    params = write_params(tmp_path, 'recruitment_curve: exponential\npw_threshold_s: 0.0001314\n'
                                    'tau_act_s: 0.05\ntau_deact_s: 0.08\nemd_s: 0.02\n'
                                    'fatigue: riener\ntau_fatigue_s: [2.0, 1.0]\n'
                                    'fibre_fractions: [0.5, 0.5]\nrecruitment_order: random\n')
    protocol = tmp_path / 'pw.yaml'
    protocol.write_text('name: pw\nduration_s: 2.0\npulse_width_s: [[0.0, 0.0004]]\n'
                        'dl_mt_m: [[0.0, 0.0]]\n')
    out = tmp_path / 'run.csv'
    assert cli.main(['simulate', '--protocol', str(protocol), '--params', str(params),
                     '--rate', '200', '--csv', str(out)]) == 0
    header, data = read_csv(out)
    assert header == CSV_HEADER
    expected = simulate(Protocol.from_yaml(protocol), MuscleParams(
        recruitment_curve='exponential', pw_threshold_s=0.0001314, tau_act_s=0.05,
        tau_deact_s=0.08, emd_s=0.02, fatigue='riener', tau_fatigue_s=[2.0, 1.0],
        fibre_fractions=[0.5, 0.5], recruitment_order='random'), 200.0)
    assert_csv_equals_result(data, expected)
    assert data[-1][-1] < 1.0    # the units tired


def test_an_unknown_engine_in_the_environment_exits_2_naming_it(monkeypatch, capsys):
    monkeypatch.setenv('HILL_MUSCLE_ENGINE', 'gpu')
    assert cli.main(['simulate', '--protocol', 'II']) == cli.EXIT_USAGE
    assert "`HILL_MUSCLE_ENGINE` must be one of auto, compiled, python, got 'gpu'" in (
        capsys.readouterr().err)


def test_the_compiled_engine_without_numba_exits_2_naming_it(monkeypatch, capsys):
    monkeypatch.setenv('HILL_MUSCLE_ENGINE', 'compiled')
    monkeypatch.setattr(engine, 'numba_available', lambda: False)
    assert cli.main(['simulate', '--protocol', 'II']) == cli.EXIT_USAGE
    assert "`HILL_MUSCLE_ENGINE` is 'compiled', but numba cannot be imported" in (
        capsys.readouterr().err)
