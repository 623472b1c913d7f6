"""What a new user meets first: each mistake gets a message
that says what to do, or the behaviour the user expected.

Offline where it can be: the CLI's ``main()`` in this process, a node's
start-up checks as functions, node processes that stop before DDS, and, for
the parameters, a node in this process (no other process). Only the limb
nodes started without a plant file create their participants (marked ``ros``).
"""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
import rclpy
from rclpy.parameter import Parameter

from hill_muscle_ros import resources
from hill_muscle_ros.model.limb import LimbPlant
from hill_muscle_ros.nodes._overrides import require_muscles
from hill_muscle_ros.nodes._parameters import (declare_checked, declare_muscle_parameters,
                                               number_descriptor)
from hill_muscle_ros.nodes._process import StartupError, check_params_files, params_file_arguments
from hill_muscle_ros.params_file import load_muscle_params, load_plant
from hill_muscle_ros.tools import cli

HILL_MUSCLE = Path(sys.executable).with_name('hill-muscle')


def run_cli(*args, timeout=120):
    """The console script in a subprocess: exit status, stdout, stderr."""
    return subprocess.run([str(HILL_MUSCLE), *map(str, args)], capture_output=True,
                          text=True, timeout=timeout)


# -- a --params-file that does not exist -------------------------------------------


def test_params_files_are_the_arguments_after_params_file_inside_ros_args():
    args = ['prog', '--params-file', 'not_ros.yaml', '--ros-args', '--params-file', 'a.yaml',
            '-p', 'x:=1', '--', '--params-file', 'app.yaml', '--ros-args',
            '--params-file', 'b.yaml']
    assert params_file_arguments(args) == ['a.yaml', 'b.yaml']


def test_a_missing_params_file_stops_start_up_naming_it(tmp_path):
    missing = tmp_path / 'knee_typo.yaml'
    with pytest.raises(StartupError) as err:
        check_params_files(['prog', '--ros-args', '--params-file', str(missing)])
    assert str(err.value) == (f'cannot start: the parameters file {missing} (--params-file) '
                              'does not exist')


def test_a_directory_as_params_file_stops_start_up_naming_it(tmp_path):
    with pytest.raises(StartupError, match=r'parameters file .* \(--params-file\) is not a file'):
        check_params_files(['prog', '--ros-args', '--params-file', str(tmp_path)])


def test_a_node_given_a_missing_params_file_exits_1_naming_it_without_the_quoting_hint(
        tmp_path):
    missing = tmp_path / 'muscle_typo.yaml'
    proc = run_cli('simulator', '--ros-args', '--params-file', missing)
    assert proc.returncode == 1, proc.stderr
    assert f'the parameters file {missing} (--params-file) does not exist' in proc.stderr
    assert 'quote values' not in proc.stderr


def test_a_malformed_params_file_gets_no_quoting_hint(tmp_path):
    bad = tmp_path / 'bad.yaml'
    bad.write_text('a: [\n')
    proc = run_cli('simulator', '--ros-args', '--params-file', bad)
    assert proc.returncode == 1, proc.stderr
    assert "Couldn't parse params file" in proc.stderr
    assert 'quote values' not in proc.stderr


def test_an_unparsable_p_override_still_gets_the_quoting_hint():
    proc = run_cli('simulator', '--ros-args', '-p', 'topics:=[a, b:pkg/msg/T]')
    assert proc.returncode == 1, proc.stderr
    assert 'quote values that contain ":" or ","' in proc.stderr


# -- protocol names ------------------------------------------------------------------

REPO = Path(__file__).resolve().parents[1]
KNEE = REPO / 'config' / 'knee.yaml'
KNEE_EXTENSION = REPO / 'config' / 'protocols' / 'knee_extension.yaml'


def run_main(capsys, *args):
    """``main()`` in this process: exit status, stdout, stderr."""
    status = cli.main([str(a) for a in args])
    out = capsys.readouterr()
    return status, out.out, out.err


@pytest.mark.parametrize('spec', ['ii', 'Ii'])
def test_builtin_protocol_names_are_accepted_in_any_case(tmp_path, capsys, spec):
    lower, upper = tmp_path / 'lower.csv', tmp_path / 'upper.csv'
    assert run_main(capsys, 'simulate', '--protocol', spec, '--rate', 100, '--csv', lower)[0] == 0
    assert run_main(capsys, 'simulate', '--protocol', 'II', '--rate', 100, '--csv', upper)[0] == 0
    assert lower.read_text() == upper.read_text()


def test_a_file_named_like_a_builtin_in_lower_case_is_the_file(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / 'ii').write_text('name: mine\n')
    assert resources.protocol_path('ii') == Path('ii')
    assert resources.protocol_path('II') == resources.config_dir() / 'protocols' / \
        'protocol_II.yaml'


def test_a_missing_protocol_file_names_the_builtin_protocols(tmp_path, capsys):
    missing = tmp_path / 'III'
    status, _, err = run_main(capsys, 'simulate', '--protocol', missing)
    assert status == 2
    assert err == (f'hill-muscle: error: {missing}: no such protocol file; the built-in '
                   'protocols are I and II\n')


@pytest.mark.parametrize('spec', ['II', 'i'])
def test_a_builtin_protocol_with_a_plant_says_it_is_single_muscle_and_names_a_limb_protocol(
        capsys, spec):
    status, _, err = run_main(capsys, 'simulate', '--plant', KNEE, '--protocol', spec)
    assert status == 2
    assert err.startswith(f'hill-muscle: error: --protocol {spec}: the built-in protocols I '
                          'and II are single-muscle protocols; a limb (--plant) plays a limb '
                          'protocol file, with inputs per muscle, e.g. ')
    assert err.rstrip().endswith('knee_extension.yaml')
    assert 'No such file' not in err


def test_a_muscle_protocol_file_with_a_plant_says_a_limb_plays_a_limb_protocol(capsys):
    muscle_protocol = resources.protocol_path('II')
    status, _, err = run_main(capsys, 'simulate', '--plant', KNEE, '--protocol', muscle_protocol)
    assert status == 2
    assert err.startswith(f'hill-muscle: error: {muscle_protocol} is a single-muscle protocol '
                          '(`recruitment`); a limb (--plant) plays a limb protocol file')


def test_a_limb_protocol_without_plant_hints_to_add_plant(capsys):
    status, _, err = run_main(capsys, 'simulate', '--protocol', KNEE_EXTENSION)
    assert status == 2
    assert err == (f'hill-muscle: error: {KNEE_EXTENSION} is a limb protocol (`muscles`: '
                   "inputs per muscle): add --plant with the limb's plant file, e.g. "
                   f'--plant {resources.knee_plant_file()}\n')


def test_a_malformed_muscle_protocol_keeps_its_own_message(tmp_path, capsys):
    bad = tmp_path / 'typo.yaml'
    bad.write_text('name: x\nduration_s: 1.0\nrecruitmnet: {times_s: [0.0], values: [0.0]}\n')
    status, _, err = run_main(capsys, 'simulate', '--protocol', bad)
    assert status == 2
    assert 'unknown key `recruitmnet`' in err and '--plant' not in err


# -- the limb nodes without a plant file ----------------------------------------------


def test_a_plant_without_muscles_stops_start_up_naming_params_file_and_the_knee_preset():
    with pytest.raises(StartupError) as err:
        require_muscles(LimbPlant.from_mapping({}))
    assert str(err.value) == (
        '`muscles` must name at least one muscle, got none: give the plant file with '
        '--ros-args --params-file PLANT.yaml, e.g. the knee preset '
        f'{resources.knee_plant_file()}')


def test_the_named_knee_preset_is_a_plant_file_with_muscles():
    plant, _ = load_plant(resources.knee_plant_file())
    require_muscles(plant)   # no error
    assert plant.joint.name == 'knee' and plant.muscles


@pytest.mark.ros
@pytest.mark.unpaced
@pytest.mark.parametrize('command', ['limb', 'joint-controller'])
def test_a_limb_node_started_without_a_plant_file_exits_1_saying_how_to_give_one(command):
    proc = run_cli(command)
    assert proc.returncode == 1, proc.stderr
    assert '`muscles` must name at least one muscle, got none: give the plant file with ' \
           '--ros-args --params-file PLANT.yaml' in proc.stderr
    assert str(resources.knee_plant_file()) in proc.stderr
    assert 'Traceback' not in proc.stderr


# -- integers for floating-point parameters -------------------------------------------

#: What a ROS user writes: integers for double parameters, and for a double array.
INTEGER_PARAMS = ('/**:\n  ros__parameters:\n    f_iso_max_n: 45\n    rate_hz: 500\n'
                  '    tau_fatigue_s: [30]\n')


@pytest.fixture
def params_node(tmp_path):
    """A node (no other process) started with ``--params-file`` of INTEGER_PARAMS and
    ``-p k_se_n_per_m:=20000``, in a context of its own; its muscle parameters declared."""
    params = tmp_path / 'muscle.yaml'
    params.write_text(INTEGER_PARAMS)
    context = rclpy.Context()
    rclpy.init(args=['--ros-args', '--params-file', str(params), '-p', 'k_se_n_per_m:=20000'],
               context=context)
    node = rclpy.create_node('integer_params_probe', context=context,
                             start_parameter_services=False)
    node.muscle = declare_muscle_parameters(node)
    node.params_file = params
    yield node
    node.destroy_node()
    rclpy.try_shutdown(context=context)


def test_a_node_reads_an_integer_in_its_params_file_as_a_double(params_node):
    assert params_node.muscle.f_iso_max_n == 45.0
    assert isinstance(params_node.muscle.f_iso_max_n, float)
    param = params_node.get_parameter('f_iso_max_n')
    assert (param.type_, param.value) == (Parameter.Type.DOUBLE, 45.0)


def test_a_node_reads_an_integer_array_in_its_params_file_as_doubles(params_node):
    assert params_node.muscle.tau_fatigue_s == (30.0,)
    assert params_node.get_parameter('tau_fatigue_s').type_ == Parameter.Type.DOUBLE_ARRAY


def test_a_node_reads_an_integer_p_override_as_a_double(params_node):
    assert params_node.muscle.k_se_n_per_m == 20000.0
    assert isinstance(params_node.muscle.k_se_n_per_m, float)


def test_a_node_parameter_outside_the_muscle_reads_an_integer_as_a_double(params_node):
    rate = declare_checked(params_node, 'rate_hz', 1000.0,
                           number_descriptor('step rate', 'Hz', 1.0, 10_000.0))
    assert (rate, type(rate)) == (500.0, float)


def test_the_cli_and_a_node_read_the_same_integer_params_file_alike(params_node):
    offline, settings = load_muscle_params(params_node.params_file)
    assert offline.replace(k_se_n_per_m=20000.0) == params_node.muscle
    assert settings['rate_hz'] == 500


def test_a_live_change_may_give_an_integer_to_a_double_parameter(params_node):
    [result] = params_node.set_parameters([Parameter('f_iso_max_n', Parameter.Type.INTEGER,
                                                     50)])
    assert result.successful, result.reason
    param = params_node.get_parameter('f_iso_max_n')
    assert (param.type_, param.value) == (Parameter.Type.DOUBLE, 50.0)


def test_an_integer_parameter_keeps_its_integer_type(params_node):
    [result] = params_node.set_parameters([Parameter('n_units', Parameter.Type.INTEGER, 50)])
    assert result.successful, result.reason
    assert params_node.get_parameter('n_units').type_ == Parameter.Type.INTEGER


def test_a_float_for_an_integer_parameter_is_still_rejected_live(params_node):
    [result] = params_node.set_parameters([Parameter('n_units', Parameter.Type.DOUBLE, 50.5)])
    assert not result.successful


def test_the_cli_reads_an_integer_for_a_double_as_the_double(tmp_path, capsys):
    runs = {}
    for text in ('45', '45.0'):
        params = tmp_path / f'muscle_{text}.yaml'
        params.write_text(f'/**:\n  ros__parameters:\n    f_iso_max_n: {text}\n'
                          '    rate_hz: 200\n')
        out = tmp_path / f'run_{text}.csv'
        status, _, err = run_main(capsys, 'simulate', '--protocol', 'I', '--params', params,
                                  '--csv', out)
        assert status == 0, err
        runs[text] = out.read_text()
    assert runs['45'] == runs['45.0']
    assert len(runs['45'].splitlines()) == 1 + 200 * 6 + 1   # header, 6 s at 200 Hz, t = 0
