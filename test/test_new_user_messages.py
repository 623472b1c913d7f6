"""What a new user meets first (issue 34, section 3): each mistake gets a message
that says what to do, or the behaviour the user expected.

Offline where it can be: the CLI's ``main()`` in this process, a node's
start-up checks as functions, and node processes that stop before DDS.
"""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from hill_muscle_ros.nodes._common import (StartupError, check_params_files,
                                           params_file_arguments)

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
