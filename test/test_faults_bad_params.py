"""Fault case 6: bad parameters, at start-up and at run time.

What must hold:

- At start-up, a params file with a negative stiffness, an unknown key, or a
  value of the wrong type makes the node exit non-zero, with a message naming
  the parameter and no traceback (simulator and force controller).
- At run time, each bad value is rejected (the reason names it), the node
  keeps running and its parameters are unchanged.
"""
from __future__ import annotations

import itertools
import os
import time

import pytest
import yaml
from std_msgs.msg import Float64

from hill_muscle_ros.model import MuscleParams
from ros_helpers import Probe, ProcessGroup, node_command

pytestmark = [pytest.mark.faults, pytest.mark.ros, pytest.mark.unpaced]

_RUNS = itertools.count()
#: [s] poll period of a process's exit status (no ROS here to spin).
POLL_S = 0.05
#: [s] for a node to fail on a bad parameter.
EXIT_TIMEOUT_S = 60.0

STARTUP_CASES = [
    ('simulator', 'k_se_n_per_m', -10000.0),
    ('simulator', 'k_se_n_per_m', 'stiff'),
    ('simulator', 'n_units', 1000.0),
    ('simulator', 'k_se_typo_n_per_m', 10000.0),
    ('force_controller', 'kp_s_per_n', -1e-5),
    ('force_controller', 'ki_s_per_n_s', 'high'),
    ('force_controller', 'kd_s', 1e-5),
]


def run_until_exit(tmp_path, name: str, cmd: list[str]) -> tuple[int | None, str]:
    """Start ``cmd`` and wait (at most EXIT_TIMEOUT_S) for it to exit: its status and output."""
    with ProcessGroup(tmp_path) as procs:
        proc = procs.start(name, cmd)
        deadline = time.monotonic() + EXIT_TIMEOUT_S
        while proc.returncode is None and time.monotonic() < deadline:
            time.sleep(POLL_S)
        return proc.returncode, proc.output()


@pytest.mark.parametrize('executable, name, value', STARTUP_CASES)
def test_bad_params_file_exits_non_zero_naming_the_parameter(tmp_path, executable, name,
                                                             value):
    params = tmp_path / 'params.yaml'
    params.write_text(yaml.safe_dump({'/**': {'ros__parameters': {name: value}}}))
    status, out = run_until_exit(tmp_path, executable,
                                 node_command(executable, params_files=[params]))
    assert status is not None and status != 0, out
    assert name in out
    assert 'Traceback' not in out


@pytest.mark.parametrize('executable', ['simulator', 'recorder'])
def test_a_command_line_rcl_cannot_parse_exits_non_zero_in_one_line(tmp_path, executable):
    # Unquoted, the ':' of a typed topic breaks rcl's YAML parser before any node exists.
    status, out = run_until_exit(tmp_path, executable, node_command(
        executable, extra_ros_args=['-p', 'topics:=[force, force_target:std_msgs/msg/Float64]']))
    assert status is not None and status != 0, out
    assert 'topics:=' in out
    assert 'Traceback' not in out


RUNTIME_CASES = [
    ('k_se_n_per_m', -1.0), ('k_pe_n_per_m', float('inf')), ('fv_b_m_per_s', 0.0),
    ('units', 'triple'), ('length', 'current'), ('n_units', 0), ('pw_max_s', -5e-4),
    ('rate_hz', 2000.0), ('input_timeout_s', float('nan')),
]


@pytest.fixture(scope='module')
def sim(tmp_path_factory):
    tmp = tmp_path_factory.mktemp('bad_params')
    ns = f'/badp_{os.getpid()}_{next(_RUNS)}'
    with ProcessGroup(tmp) as procs, Probe('bad_params_probe') as probe:
        proc = procs.start('simulator', node_command('simulator', ns=ns,
                                                     params={'rate_hz': 200.0}))
        force = probe.record(f'{ns}/force', Float64)
        probe.wait_for_messages(force, procs=[proc])
        yield {'probe': probe, 'proc': proc, 'node': f'{ns}/simulator', 'force': force}


@pytest.mark.parametrize('name, value', RUNTIME_CASES)
def test_bad_value_at_run_time_is_rejected_and_the_node_is_unchanged(sim, name, value):
    probe, proc, node = sim['probe'], sim['proc'], sim['node']
    names = [*MuscleParams.field_names(), 'rate_hz', 'input_timeout_s', 'frame_id']
    before = probe.get_parameters(node, names, procs=[proc])
    (result,) = probe.set_parameters(node, {name: value}, procs=[proc])
    assert not result.successful
    assert name in result.reason
    assert probe.get_parameters(node, names, procs=[proc]) == before
    probe.wait_for_messages(sim['force'], mark=sim['force'].mark(), procs=[proc])
