"""The nodes' shared helpers, without DDS: step schedule, descriptors, throttling."""
import dataclasses
import math
import random

import pytest
from rcl_interfaces.msg import ParameterDescriptor

from hill_muscle_ros.model import MuscleParams
from hill_muscle_ros.nodes._common import (LIVE_KEEPS_STATE, LIVE_RESETS, BadInputWarner,
                                           StepSchedule, field_descriptor)

NS = 1_000_000_000


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
        r = desc.floating_point_range[0]
        assert (r.from_value, r.to_value) == (spec['low'], spec['high'])


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
