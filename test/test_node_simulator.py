"""The simulator node over real DDS: parameters, inputs, watchdog, reset, namespaces.

Two simulators (``/left`` and ``/right``) are shared by the module, at 200 Hz
to spare the CPU, with the watchdog off; a fixture returns both to rest before
each test. Tests that change a parameter restore it.
"""
import math

import pytest
import yaml
from geometry_msgs.msg import WrenchStamped
from rclpy.parameter_client import AsyncParameterClient
from std_msgs.msg import Float64
from std_srvs.srv import Trigger

from conftest import REPO
from hill_muscle_ros.model import MuscleParams, force_length
from hill_muscle_ros.params_file import load_muscle_params
from ros_helpers import Probe, ProcessGroup, node_command

pytestmark = pytest.mark.ros

MUSCLE_YAML = REPO / 'config' / 'muscle.yaml'
SHARED_RATE_HZ = 200.0
DEFAULTS = MuscleParams()
#: [m] a stretch well inside the FL range
STRETCH_M = 0.010
#: [N] force at STRETCH_M with nothing recruited: only the PE carries load
PE_FORCE_N = DEFAULTS.k_pe_n_per_m * STRETCH_M
#: [N] tolerance on a force that should be constant
FORCE_TOL_N = 0.05
#: [s] of messages to watch for a value that must not change
WATCH_S = 0.5


@pytest.fixture(scope='module')
def shared(tmp_path_factory):
    """The two simulators and a probe, for the whole module; and, started first
    so that they exit while these start, a simulator per bad start-up parameter
    (``bad_startups``: override -> process, waited for by their test)."""
    tmp = tmp_path_factory.mktemp('sim')
    overrides = tmp / 'overrides.yaml'
    overrides.write_text(yaml.safe_dump({'/**': {'ros__parameters': {
        'rate_hz': SHARED_RATE_HZ, 'input_timeout_s': 0.0}}}))
    with ProcessGroup(tmp) as procs, Probe() as probe:
        bad_startups = {override: procs.start(f'bad{i}', node_command(
                            'simulator', params_files=[MUSCLE_YAML],
                            extra_ros_args=['-p', override]))
                        for i, override in enumerate(BAD_STARTUP)}
        sims = {ns: procs.start(ns, node_command('simulator', ns=f'/{ns}',
                                                 params_files=[MUSCLE_YAML, overrides]))
                for ns in ('left', 'right')}
        recs = {ns: {'force': probe.record(f'/{ns}/force', Float64),
                     'ce_length': probe.record(f'/{ns}/ce_length', Float64),
                     'wrench': probe.record(f'/{ns}/wrench', WrenchStamped)}
                for ns in sims}
        for ns in sims:
            probe.wait_for_messages(recs[ns]['force'], procs=sims.values())
        yield {'procs': list(sims.values()), 'sims': sims, 'probe': probe, 'recs': recs,
               'bad_startups': bad_startups}


@pytest.fixture
def sim(shared):
    """The shared simulators, both at rest and publishing."""
    probe = shared['probe']
    for ns in shared['sims']:
        response = probe.call(Trigger, f'/{ns}/reset', Trigger.Request(), procs=shared['procs'])
        assert response.success
        rec = shared['recs'][ns]['force']
        probe.wait_for_value(rec, lambda f: f == 0.0, 'zero force at rest', mark=rec.mark(),
                             procs=shared['procs'])
    return shared


def _settle(sim, ns, topic, predicate, what):
    """Wait for a value on /ns/topic from now on; return its index."""
    rec = sim['recs'][ns][topic]
    return sim['probe'].wait_for_value(rec, predicate, what, mark=rec.mark(), procs=sim['procs'])


def _publish(sim, topic, value):
    sim['probe'].publish_when_matched(topic, Float64(data=value), procs=sim['procs'])


def test_outputs_at_rest_are_zero_force_and_rest_length(sim):
    probe, recs = sim['probe'], sim['recs']['left']
    mark = recs['ce_length'].mark()
    probe.wait_for_messages(recs['ce_length'], mark=mark, procs=sim['procs'])
    assert recs['ce_length'].messages[mark].data == DEFAULTS.l_rest_m
    assert recs['force'].messages[-1].data == 0.0


def test_wrench_carries_force_along_x_in_frame_id(sim):
    _publish(sim, '/left/length_command', STRETCH_M)
    _settle(sim, 'left', 'force', lambda f: abs(f - PE_FORCE_N) < FORCE_TOL_N, 'PE force')
    rec = sim['recs']['left']['wrench']
    mark = rec.mark()

    def stretched_wrench():
        # Wrenches already queued before the stretch may still arrive first.
        return next((m for m in rec.since(mark)
                     if abs(m.wrench.force.x - PE_FORCE_N) < FORCE_TOL_N), None)

    wrench = sim['probe'].spin_until(stretched_wrench, 'a wrench with the PE force along x',
                                     procs=sim['procs'])
    assert wrench.header.frame_id == 'muscle'
    assert all((m.wrench.force.y, m.wrench.force.z) == (0.0, 0.0) for m in rec.since(mark))
    assert all(m.header.frame_id == 'muscle' for m in rec.since(mark))


def test_params_file_values_are_loaded(sim):
    expected, node_keys = load_muscle_params(MUSCLE_YAML)
    names = list(MuscleParams.field_names()) + ['rate_hz', 'frame_id', 'input_timeout_s']
    got = sim['probe'].get_parameters('/left/simulator', names, procs=sim['procs'])
    for name in MuscleParams.field_names():
        value = got[name]
        # A ROS double_array arrives as a list; the model keeps a tuple.
        assert (tuple(value) if isinstance(value, list) else value) == \
            getattr(expected, name), name
    assert got['frame_id'] == node_keys['frame_id']
    # The second params file, later on the command line, wins.
    assert (got['rate_hz'], got['input_timeout_s']) == (SHARED_RATE_HZ, 0.0)


@pytest.mark.parametrize('name, value, reason', [
    # The model's reason, negative or zero alike (no descriptor range answers first).
    ('k_se_n_per_m', -3.0, '`k_se_n_per_m` must be positive and finite, got -3.0'),
    ('k_pe_n_per_m', 0.0, '`k_pe_n_per_m` must be positive and finite, got 0.0'),
    ('k_pe_n_per_m', 1e13, '`k_pe_n_per_m` must be at most 1e+12, got 10000000000000.0'),
    ('units', 'triple', "`units` must be one of multi, single, got 'triple'"),
    # l_rest / l_opt = 125: no force at rest; the reason names both parameters.
    ('l_opt_m', 0.001, 'l_rest_m = 0.125 / l_opt_m = 0.001'),
    ('frame_id', '', "`frame_id` must be a non-empty frame name without a leading '/' "
                     "(tf2 convention), got ''"),
    ('frame_id', '/muscle', "got '/muscle'"),
    # The integer range is exact, so rclpy's check of it is the truth; its text
    # names the parameter and the value too.
    ('n_units', 0, 'Parameter n_units out of range. Min: 1, Max: 1000000000, value: 0'),
])
def test_rejected_live_parameter_gives_reason_naming_it_and_the_value(sim, name, value, reason):
    before = sim['probe'].get_parameters('/left/simulator', [name], procs=sim['procs'])
    results = sim['probe'].set_parameters('/left/simulator', {name: value}, procs=sim['procs'])
    assert not results[0].successful
    assert reason in results[0].reason
    assert name in results[0].reason
    assert sim['probe'].get_parameters('/left/simulator', [name], procs=sim['procs']) == before
    _settle(sim, 'left', 'force', math.isfinite, 'still publishing')


def test_wrong_live_parameter_type_is_rejected_by_rclpy(sim):
    # rclpy's type check runs before any callback; its reason names the types.
    # (An integer is read as the double: test_new_user_messages.)
    results = sim['probe'].set_parameters('/left/simulator', {'f_iso_max_n': '45'},
                                          procs=sim['procs'])
    assert not results[0].successful
    assert 'Wrong parameter type' in results[0].reason


def test_descriptors_state_exactly_what_is_accepted(sim):
    client = AsyncParameterClient(sim['probe'].node, '/left/simulator')
    sim['probe'].spin_until(client.services_are_ready, 'parameter services',
                            procs=sim['procs'])
    future = client.describe_parameters(['k_se_n_per_m', 'n_units', 'frame_id'])
    sim['probe'].spin_until(future.done, 'describe_parameters', procs=sim['procs'])
    k_se, n_units, frame_id = future.result().descriptors
    # "> 0" has no closed range (from_value 0.0 would claim 0 is accepted).
    assert not k_se.floating_point_range
    assert k_se.additional_constraints == '> 0 and <= 1e+12 (finite)'
    assert [(r.from_value, r.to_value, r.step) for r in n_units.integer_range] == \
        [(1, 1_000_000_000, 1)]
    assert frame_id.additional_constraints == "non-empty, without a leading '/'"


def test_read_only_rate_is_rejected_live(sim):
    results = sim['probe'].set_parameters('/left/simulator', {'rate_hz': 500.0},
                                          procs=sim['procs'])
    assert not results[0].successful
    assert 'rate_hz' in results[0].reason


def test_live_stiffness_change_rebuilds_at_rest_and_applies(sim):
    _publish(sim, '/left/length_command', STRETCH_M)
    _settle(sim, 'left', 'force', lambda f: abs(f - PE_FORCE_N) < FORCE_TOL_N, 'PE force')
    k_new = 2.0 * DEFAULTS.k_pe_n_per_m
    try:
        results = sim['probe'].set_parameters('/left/simulator', {'k_pe_n_per_m': k_new},
                                              procs=sim['procs'])
        assert results[0].successful, results[0].reason
        _settle(sim, 'left', 'force', lambda f: f == 0.0, 'zero force at rest')
        _publish(sim, '/left/length_command', STRETCH_M)
        _settle(sim, 'left', 'force', lambda f: abs(f - k_new * STRETCH_M) < FORCE_TOL_N,
                'force with the new k_pe')
    finally:
        sim['probe'].set_parameters('/left/simulator', {'k_pe_n_per_m': DEFAULTS.k_pe_n_per_m},
                                    procs=sim['procs'])


def test_live_pw_max_change_keeps_state(sim):
    _publish(sim, '/left/length_command', STRETCH_M)
    _settle(sim, 'left', 'force', lambda f: abs(f - PE_FORCE_N) < FORCE_TOL_N, 'PE force')
    rec = sim['recs']['left']['force']
    try:
        results = sim['probe'].set_parameters('/left/simulator',
                                              {'pw_max_s': 2.0 * DEFAULTS.pw_max_s},
                                              procs=sim['procs'])
        assert results[0].successful, results[0].reason
        mark = rec.mark()
        sim['probe'].spin_for(WATCH_S)
        forces = rec.data_since(mark)
        assert forces and max(abs(f - PE_FORCE_N) for f in forces) < FORCE_TOL_N
    finally:
        sim['probe'].set_parameters('/left/simulator', {'pw_max_s': DEFAULTS.pw_max_s},
                                    procs=sim['procs'])


def test_live_units_change_resets_to_rest(sim):
    _publish(sim, '/left/length_command', STRETCH_M)
    _settle(sim, 'left', 'force', lambda f: abs(f - PE_FORCE_N) < FORCE_TOL_N, 'PE force')
    try:
        results = sim['probe'].set_parameters('/left/simulator', {'units': 'single'},
                                              procs=sim['procs'])
        assert results[0].successful, results[0].reason
        _settle(sim, 'left', 'force', lambda f: f == 0.0, 'zero force after the reset')
        _settle(sim, 'left', 'ce_length', lambda x: x == DEFAULTS.l_rest_m, 'rest length')
    finally:
        sim['probe'].set_parameters('/left/simulator', {'units': DEFAULTS.units},
                                    procs=sim['procs'])


def test_reset_service_returns_muscle_to_rest(sim):
    _publish(sim, '/left/recruitment', 1.0)
    _publish(sim, '/left/length_command', STRETCH_M)
    _settle(sim, 'left', 'force', lambda f: f > 2.0 * PE_FORCE_N, 'active force')
    response = sim['probe'].call(Trigger, '/left/reset', Trigger.Request(), procs=sim['procs'])
    assert response.success
    _settle(sim, 'left', 'force', lambda f: f == 0.0, 'zero force after reset')
    _settle(sim, 'left', 'ce_length', lambda x: x == DEFAULTS.l_rest_m, 'rest length')


#: A good value per input topic and the steady force it gives at rest length
#: (R = 1 at l_ce = l_rest: f_iso_max * FL(l_rest / l_opt)) or at the stretch.
_FL_REST = force_length(DEFAULTS.l_rest_m / DEFAULTS.l_opt_m)
GOOD_INPUTS = {
    'pulse_width': (DEFAULTS.pw_max_s, DEFAULTS.f_iso_max_n * _FL_REST),
    'recruitment': (1.0, DEFAULTS.f_iso_max_n * _FL_REST),
    'length_command': (STRETCH_M, PE_FORCE_N),
}


def _rejection_line(sim, topic, value_text, log_start, ns='left'):
    """Send a bad value on /ns/topic until a warning names it; return that line.

    Warnings are throttled per topic (1 s): an earlier test may have used this
    second's, so the value is sent again until its own line appears.
    """
    needle = f'ignoring /{ns}/{topic} = {value_text}:'
    pub = sim['probe'].publisher(f'/{ns}/{topic}', Float64)

    def line():
        found = [ln for ln in sim['sims'][ns].output()[log_start:].splitlines()
                 if needle in ln]
        if not found:
            pub.publish(Float64(data=float(value_text)))
        return found[0] if found else None

    sim['probe'].spin_until(lambda: pub.get_subscription_count() > 0,
                            f'a subscriber on /{ns}/{topic}', procs=sim['procs'])
    return sim['probe'].spin_until(line, f'the warning {needle!r}', procs=sim['procs'])


# The three pulse widths go to the two simulators in turn: each warns once a
# second per topic, so the second one need not wait for the first's second.
@pytest.mark.parametrize('ns, topic, value_text, reason', [
    ('left', 'pulse_width', 'nan', '`/left/pulse_width` must be finite and non-negative, got nan'),
    ('right', 'pulse_width', 'inf',
     '`/right/pulse_width` must be finite and non-negative, got inf'),
    ('left', 'pulse_width', '-0.0001',
     '`/left/pulse_width` must be finite and non-negative, got -0.0001'),
    ('left', 'recruitment', 'nan', '`/left/recruitment` must be in [0, 1], got nan'),
    ('left', 'length_command', '-inf',
     '`/left/length_command` must be finite and within ±1.0 m of rest, got -inf'),
])
def test_bad_input_warning_names_the_full_topic_and_the_value(sim, ns, topic, value_text,
                                                              reason):
    log_start = len(sim['sims'][ns].output())
    line = _rejection_line(sim, topic, value_text, log_start, ns)
    assert reason in line
    # A non-finite or negative width is not a unit mix-up.
    assert 'microseconds' not in line


@pytest.mark.parametrize('topic', sorted(GOOD_INPUTS))
def test_nan_and_inf_input_keep_last_good_value(sim, topic):
    good, force_n = GOOD_INPUTS[topic]
    _publish(sim, f'/left/{topic}', good)
    _settle(sim, 'left', 'force', lambda f: abs(f - force_n) < FORCE_TOL_N, 'steady force')
    rec = sim['recs']['left']['force']
    mark = rec.mark()
    for bad in (math.nan, math.inf, -math.inf):
        _publish(sim, f'/left/{topic}', bad)
    sim['probe'].spin_for(WATCH_S)
    forces = rec.data_since(mark)
    assert forces, 'the node stopped publishing'
    assert all(math.isfinite(f) for f in forces)
    assert max(abs(f - force_n) for f in forces) < FORCE_TOL_N
    # The warning names the value (resent while an earlier test's warning
    # holds this topic's throttle second).
    _rejection_line(sim, topic, 'nan', 0)


def test_microsecond_pulse_width_is_rejected_with_hint(sim):
    line = _rejection_line(sim, 'pulse_width', '500.0', len(sim['sims']['left'].output()))
    assert ('`/left/pulse_width` must be at most 100 x pw_max_s (0.05 s), got 500.0. It looks '
            'like microseconds: pulse_width is in seconds (REP 103), e.g. 0.0005 for 500 us'
            in line)
    rec = sim['recs']['left']['force']
    mark = rec.mark()
    sim['probe'].spin_for(WATCH_S)
    assert set(rec.data_since(mark)) == {0.0}


def test_watchdog_drops_recruitment_after_silence(sim):
    probe = sim['probe']
    log_start = len(sim['sims']['left'].output())
    try:
        assert probe.set_parameters('/left/simulator', {'input_timeout_s': 0.3},
                                    procs=sim['procs'])[0].successful
        _publish(sim, '/left/recruitment', 1.0)
        _settle(sim, 'left', 'force', lambda f: f > 1.0, 'active force')
        # No more messages: the watchdog sets R = 0, the free CE unloads at once.
        _settle(sim, 'left', 'force', lambda f: f == 0.0, 'force dropped by the watchdog')
        probe.spin_for(WATCH_S)
        log = sim['sims']['left'].output()[log_start:]
        assert log.count('no pulse_width or recruitment message') == 1
        _publish(sim, '/left/recruitment', 1.0)
        _settle(sim, 'left', 'force', lambda f: f > 1.0, 'force back with the next message')
    finally:
        probe.set_parameters('/left/simulator', {'input_timeout_s': 0.0}, procs=sim['procs'])


def test_namespaced_simulators_do_not_cross_talk(sim):
    right = sim['recs']['right']['force']
    mark = right.mark()
    _publish(sim, '/left/length_command', STRETCH_M)
    _settle(sim, 'left', 'force', lambda f: abs(f - PE_FORCE_N) < FORCE_TOL_N, 'PE force')
    sim['probe'].spin_for(WATCH_S)
    assert right.data_since(mark) and set(right.data_since(mark)) == {0.0}


#: A bad start-up parameter and what the simulator's exit must say of it.
BAD_STARTUP = {
    'k_se_n_per_m:=-3.0': "parameter `k_se_n_per_m` must be positive and finite, got -3.0",
    'l_opt_m:=0.001': 'l_rest_m = 0.125 / l_opt_m = 0.001',
    "frame_id:=''": "parameter `frame_id` must be a non-empty frame name",
    'f_iso_max_n:=true': '`f_iso_max_n`: got True (bool), expected a float',
    'units:=triple': "`units` must be one of multi, single, got 'triple'",
}


@pytest.mark.parametrize('override, needle', list(BAD_STARTUP.items()))
def test_bad_startup_parameter_exits_nonzero_naming_it(shared, override, needle):
    proc = shared['bad_startups'][override]
    status = proc.wait()
    log = proc.output()
    assert status != 0
    assert needle in log
    assert 'Traceback' not in log


def test_exit_statistics_name_the_node_by_its_namespace(tmp_path):
    # Two nodes called quad in two namespaces must not log alike.
    with ProcessGroup(tmp_path) as procs, Probe('stats_probe') as probe:
        proc = procs.start('quad', node_command(
            'simulator', ns='/left_leg', params={'rate_hz': SHARED_RATE_HZ},
            extra_ros_args=['-r', '__node:=quad']))
        force = probe.record('/left_leg/force', Float64)
        probe.wait_for_messages(force, procs=[proc])
        assert proc.stop() == 0
    assert '[left_leg.quad.stats]: ran ' in proc.output()
