"""The nodes' shared helpers, without DDS: step schedule, descriptors, throttling."""
import dataclasses
import math
import random

import pytest
from rcl_interfaces.msg import ParameterDescriptor

from hill_muscle_ros.model import MuscleParams
from hill_muscle_ros.nodes._inputs import BadInputWarner
from hill_muscle_ros.nodes._parameters import LIVE_KEEPS_STATE, LIVE_RESETS, field_descriptor
from hill_muscle_ros.nodes._stepping import StepSchedule
from hill_muscle_ros.timebase import NS_PER_S as NS


def test_schedule_runs_floor_of_elapsed_times_rate():
    s = StepSchedule(rate_hz=1000.0, real_time_factor=1.0, start_ns=5 * NS)
    assert s.due(5 * NS + 2_500_000) == 2   # 2.5 ms: two whole steps
    s.steps_done += 2
    assert s.due(5 * NS + 2_999_999) == 0


def test_schedule_counts_a_tick_with_several_steps_as_late():
    s = StepSchedule(rate_hz=1000.0, real_time_factor=1.0, start_ns=0)
    s.steps_done += s.due(1_000_000)
    s.steps_done += s.due(4_000_000)
    assert (s.ticks, s.late_ticks) == (2, 1)


def test_schedule_does_not_drift_over_a_minute_of_jittery_ticks():
    rng = random.Random(3)
    s = StepSchedule(rate_hz=1000.0, real_time_factor=1.0, start_ns=0)
    now = 0
    while now < 60 * NS:
        now += int(rng.uniform(0.2e6, 3e6))      # ticks 0.2 .. 3 ms apart
        s.steps_done += s.due(now)
    assert s.steps_done == math.floor(now * 1000 / NS)


def test_schedule_real_time_factor_scales_steps():
    s = StepSchedule(rate_hz=200.0, real_time_factor=3.0, start_ns=0)
    assert s.due(NS) == 600


def test_schedule_reports_the_longest_interval_between_ticks_and_its_end():
    s = StepSchedule(rate_hz=1000.0, real_time_factor=1.0, start_ns=0)
    assert (s.max_tick_gap_s, s.max_tick_gap_end_ns) == (0.0, None)
    # Start-up (0 to 100 ms) is no gap between ticks; then 1, 34, 1 and 9 ms.
    for now_ns in (100_000_000, 101_000_000, 135_000_000, 136_000_000, 145_000_000):
        s.steps_done += s.due(now_ns)
    assert (s.max_tick_gap_s, s.max_tick_gap_end_ns) == (0.034, 135_000_000)


@pytest.mark.parametrize('field', dataclasses.fields(MuscleParams), ids=lambda f: f.name)
def test_descriptor_comes_from_the_field_metadata(field):
    desc = field_descriptor(field)
    spec = field.metadata
    assert isinstance(desc, ParameterDescriptor)
    assert spec['description'] in desc.description
    if spec['choices'] is not None:
        assert all(c in desc.additional_constraints for c in spec['choices'])
    elif field.type == 'int':
        r = desc.integer_range[0]
        assert (r.from_value, r.to_value) == (spec['low'], spec['high'])
    else:
        assert f'[{spec["unit"]}]' in desc.description
        # No closed range can say "> 0": the bounds are in words, the model checks them.
        assert not desc.floating_point_range
        low = '>=' if spec['low_inclusive'] else '>'
        high = '<=' if spec['high_inclusive'] else '<'
        each = 'each entry ' if field.type.startswith('tuple') else ''
        assert desc.additional_constraints == \
            f'{each}{low} {spec["low"]:g} and {high} {spec["high"]:g} (finite)'
        if field.name == 'k_se_n_per_m':
            assert desc.additional_constraints == '> 0 and <= 1e+12 (finite)'


def test_every_muscle_parameter_has_a_live_change_rule():
    assert sorted(LIVE_KEEPS_STATE + LIVE_RESETS) == sorted(MuscleParams.field_names())


class _Lines:
    """Collects what a logger would print."""

    def __init__(self):
        self.lines = []

    def warning(self, message):
        self.lines.append(message)


def test_bad_input_warnings_are_throttled_per_topic():
    log = _Lines()
    warner = BadInputWarner(log, period_s=60.0)
    for _ in range(3):
        warner.warn('/a', 'bad a')
        warner.warn('/b', 'bad b')
    assert log.lines == ['bad a', 'bad b']


def test_bad_input_warning_reports_how_many_were_suppressed():
    log = _Lines()
    warner = BadInputWarner(log, period_s=0.0)
    warner._period_s = 60.0
    warner.warn('/a', 'first')
    warner.warn('/a', 'second')
    warner._period_s = 0.0
    warner.warn('/a', 'third')
    assert log.lines == ['first', 'third (1 more since the last warning)']


# -- parameter introspection (a real rclpy node, no other process) ----------------

import rclpy  # noqa: E402

from hill_muscle_ros.nodes._overrides import reject_unknown_overrides  # noqa: E402
from hill_muscle_ros.nodes._parameters import (declare_checked,  # noqa: E402
                                               declared_parameter_names, number_descriptor,
                                               parameter_overrides)
from hill_muscle_ros.nodes._process import StartupError  # noqa: E402


@pytest.fixture
def node_with_overrides():
    """A node started with ``-p`` overrides, in a context of its own."""
    context = rclpy.Context()
    rclpy.init(args=['--ros-args', '-p', 'rate_hz:=-5.0', '-p', 'k_se_typo:=3.0',
                     '-p', 'n_units:=1.5'], context=context)
    node = rclpy.create_node('introspection_probe', context=context,
                             start_parameter_services=False)
    yield node
    node.destroy_node()
    rclpy.try_shutdown(context=context)


def test_parameter_overrides_are_the_command_line_values(node_with_overrides):
    # Pins the one place that reads rclpy's private state (no public API in 7.1.6).
    overrides = parameter_overrides(node_with_overrides)
    assert {n: p.value for n, p in overrides.items()} == {
        'rate_hz': -5.0, 'k_se_typo': 3.0, 'n_units': 1.5}


def test_declared_parameter_names_list_what_was_declared(node_with_overrides):
    before = declared_parameter_names(node_with_overrides)
    node_with_overrides.declare_parameter('frame_id', 'muscle')
    assert 'use_sim_time' in before and 'frame_id' not in before
    assert declared_parameter_names(node_with_overrides) == sorted(before + ['frame_id'])


def test_out_of_range_override_names_parameter_value_and_range(node_with_overrides):
    with pytest.raises(StartupError) as err:
        declare_checked(node_with_overrides, 'rate_hz', 1000.0,
                        number_descriptor('step rate', 'Hz', 1.0, 10_000.0))
    message = str(err.value)
    assert message.startswith('parameter `rate_hz` = -5.0 rejected: ')
    assert 'out of range' in message and 'Invalid parameter value' not in message


def test_wrong_type_override_names_the_parameter_and_both_types(node_with_overrides):
    with pytest.raises(StartupError, match=r'parameter `n_units`: got 1\.5 \(float\), '
                                           r'expected a int like 100'):
        declare_checked(node_with_overrides, 'n_units', 100,
                        number_descriptor('motor units', '-', 1, 1000, integer=True))


def test_unknown_override_is_named_with_the_declared_parameters(node_with_overrides):
    node_with_overrides.declare_parameter('frame_id', 'muscle')
    declared = ', '.join(declared_parameter_names(node_with_overrides))
    assert 'frame_id' in declared
    with pytest.raises(StartupError) as err:
        reject_unknown_overrides(node_with_overrides)
    assert str(err.value) == f'unknown parameter `k_se_typo` (got 3.0); this node has: {declared}'


NODE_SCRIPTS = ('simulator', 'protocol_player', 'recorder', 'force_controller',
                'limb_simulator', 'joint_controller')


def test_a_node_process_ends_with_its_status_after_pythons_exit_handlers_and_flushed_output():
    # exit_process skips only the C and C++ exit handlers: an atexit function
    # still runs, and text left in stdout's buffer (a pipe: block-buffered) is written.
    import subprocess
    import sys
    code = ('import atexit, sys\n'
            'from hill_muscle_ros.nodes._process import exit_process\n'
            'atexit.register(lambda: print("exit handler ran", flush=True))\n'
            'sys.stdout.write("buffered, no newline")\n'
            'exit_process(3)\n')
    done = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                          timeout=60)
    assert done.returncode == 3, done.stderr
    assert done.stdout == 'buffered, no newlineexit handler ran\n'


def test_every_node_console_script_ends_its_process_through_exit_process():
    from importlib.metadata import entry_points
    scripts = {ep.name: ep for ep in entry_points(group='console_scripts')
               if ep.module.startswith('hill_muscle_ros.nodes.')}
    assert sorted(scripts) == sorted(NODE_SCRIPTS)
    for name, ep in scripts.items():
        entry = ep.load()
        assert ep.attr == 'process_main', name
        assert entry.__doc__ == f'Console script: {ep.module}.main(), then exit_process.', name


def test_the_plant_of_a_limb_node_leaves_out_the_diagnostics_period_and_the_nodes_own():
    # One params file may set every node's diagnostics period; a limb node or a
    # joint controller must not read it as a key of its plant.
    from rclpy.parameter import Parameter

    from hill_muscle_ros.nodes._diagnostics import DIAGNOSTICS_PERIOD_PARAMETER
    from hill_muscle_ros.nodes._overrides import LIMB_NODE_PARAMETERS, plant_values

    overrides = {name: Parameter(name, value=value) for name, value in (
        (DIAGNOSTICS_PERIOD_PARAMETER, 0.25), ('rate_hz', 500.0),
        ('joint.name', 'knee'), ('qos_overrides./joint_states.publisher.depth', 5))}
    assert plant_values(overrides, LIMB_NODE_PARAMETERS) == {'joint.name': 'knee'}
