"""The limb node over real DDS: joint states, stimulation, bad input, bad plant files.

One limb node on the knee preset (``/leg``, 200 Hz to spare the CPU, watchdog
off, ``publish_clock`` so that a step's stamp is its simulated time from 0) is
shared by the module; a fixture returns it to its initial state before each
test. The bad plant files each start a node of their own, which must exit.
"""
import copy
import math
import signal

import pytest
import yaml
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import WrenchStamped
from rclpy.qos import QoSProfile
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64
from std_srvs.srv import Trigger

from conftest import REPO
from hill_muscle_ros.model import engine
from hill_muscle_ros.model.limb import Limb, LimbProtocol, simulate_limb
from hill_muscle_ros.nodes import limb as limb_node
from hill_muscle_ros.model.stimulus import command_from_pulse_width
from hill_muscle_ros.params_file import load_plant, read_ros_parameters
from ros_helpers import Probe, ProcessGroup, RecordingLogger, node_command, ros_env

pytestmark = pytest.mark.ros

KNEE_YAML = REPO / 'config' / 'knee.yaml'
RATE_HZ = 200.0
NS = '/leg'
PLANT, _ = load_plant(KNEE_YAML)
QUAD, HAM = (m.params for m in PLANT.muscles)
#: Start-up steps (at rest, before any test sends input) compared with the offline run.
REST_STEPS = 100
#: [rad] the node and the offline run step the same model with the same dt.
SAME_MODEL_TOL_RAD = 1e-9
#: [rad] "hanging": the quadriceps' passive force lifts the shank by a fraction of a degree.
HANGING_TOL_RAD = math.radians(1.0)
#: The probe's reader of the joint states: the tests count every step's message,
#: and a reader of the default depth (10, 50 ms at RATE_HZ) drops messages while
#: the test process is descheduled (once in a run of the node files here). 25 s
#: of steps: more than this module's life.
JOINT_QOS = QoSProfile(depth=5000)
#: [s] 300 us, inside the stimulator's range: offline it extends the knee to ~70 deg.
EXTENDING_PW_S = 0.0003
EXTENDED_RAD = math.radians(30.0)
#: Good inputs that garbage must not replace.
GOOD_PW_S = 0.0002
GOOD_RECRUITMENT = 0.1
GOOD_TORQUE_N_M = 1.5
#: [s] deadline for a node with a bad plant file to exit.
EXIT_TIMEOUT_S = 30.0


def _stamp_step(msg) -> int:
    """The step a message belongs to: its stamp is the step's sim time (publish_clock)."""
    return round((msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9) * RATE_HZ)


def _limb_command(tmp, ns):
    """The limb node on the knee at RATE_HZ, watchdog off, publish_clock on."""
    overrides = tmp / 'overrides.yaml'
    overrides.write_text(yaml.safe_dump({'/**': {'ros__parameters': {
        'rate_hz': RATE_HZ, 'input_timeout_s': 0.0, 'publish_clock': True}}}))
    return node_command('limb_simulator', ns=ns, params_files=[KNEE_YAML, overrides])


#: The bad plant files: case -> the key their node's exit must name.
BAD_PLANTS = {
    'unknown muscle': 'vastus',
    'missing moment arm': 'quadriceps.moment_arm_m',
    'negative inertia': 'joint.inertia_kg_m2',
}


def _bad_plant_file(path, case):
    values = copy.deepcopy(read_ros_parameters(KNEE_YAML, 'limb'))
    if case == 'unknown muscle':
        values['muscles'] = ['quadriceps', 'hamstrings', 'vastus']
    elif case == 'missing moment arm':
        del values['quadriceps']['moment_arm_m']
    else:
        values['joint']['inertia_kg_m2'] = -PLANT.joint.inertia_kg_m2
    path.write_text(yaml.safe_dump({'/**': {'ros__parameters': values}}))
    return path


@pytest.fixture(scope='module')
def shared(tmp_path_factory):
    """The limb node, a probe, and the node's first REST_STEPS joint states.

    Started with it, so that they start (and exit) together: a limb node per
    bad plant file (``bad``: case -> process, waited for by their test), and
    the same limb on the Python engine (``python``: its process, and its joint
    states in a deep reader from its first step on)."""
    tmp = tmp_path_factory.mktemp('limb')
    with ProcessGroup(tmp) as procs, Probe() as probe:
        bad = {case: procs.start(f'bad{i}', node_command(
                   'limb_simulator', ns=f'/bad{i}',
                   params_files=[_bad_plant_file(tmp / f'plant{i}.yaml', case)]))
               for i, case in enumerate(BAD_PLANTS)}
        python_ns = f'{NS}_python'
        python_tmp = tmp / 'python'
        python_tmp.mkdir()
        python = {'rec': probe.record(f'{python_ns}/joint_states', JointState, JOINT_QOS),
                  'proc': procs.start('limb_python', _limb_command(python_tmp, python_ns),
                                      env=ros_env(**{engine.ENV_VAR: engine.PYTHON}))}
        node = procs.start('limb', _limb_command(tmp, NS))
        recs = {'joint': probe.record(f'{NS}/joint_states', JointState, JOINT_QOS),
                'force': probe.record(f'{NS}/quadriceps/force', Float64),
                'wrench': probe.record(f'{NS}/quadriceps/wrench', WrenchStamped),
                'diag': probe.record('/diagnostics', DiagnosticArray)}
        probe.wait_for_messages(recs['joint'], REST_STEPS, procs=[node])
        rest = list(recs['joint'].messages)
        yield {'procs': [node], 'node': node, 'probe': probe, 'recs': recs, 'rest': rest,
               'bad': bad, 'python': python}


@pytest.fixture
def leg(shared):
    """The shared limb at its initial state with every input at 0, publishing."""
    probe = shared['probe']
    response = probe.call(Trigger, f'{NS}/reset', Trigger.Request(), procs=shared['procs'])
    assert response.success
    rec = shared['recs']['joint']
    mark = rec.mark()
    probe.spin_until(lambda: any(abs(m.position[0]) < HANGING_TOL_RAD for m in rec.since(mark)),
                     'a hanging knee after reset', procs=shared['procs'])
    return shared


def _publish(leg, topic, value):
    leg['probe'].publish_when_matched(f'{NS}/{topic}', Float64(data=value), procs=leg['procs'])


def _diagnostics(leg, predicate, what):
    """The values of the limb's next /diagnostics status that satisfies ``predicate``."""
    rec = leg['recs']['diag']
    mark = rec.mark()

    def found():
        for msg in rec.since(mark):
            for status in msg.status:
                if status.name.startswith(f'{NS}/limb'):
                    values = {kv.key: kv.value for kv in status.values}
                    if predicate(values):
                        return values
        return None
    return leg['probe'].spin_until(found, what, procs=leg['procs'])


def test_joint_states_name_the_joint_one_value_each_every_step(shared):
    msgs = shared['rest']
    assert all(list(m.name) == [PLANT.joint.name] for m in msgs)
    assert all(len(m.position) == len(m.velocity) == len(m.effort) == 1 for m in msgs)
    steps = [_stamp_step(m) for m in msgs]
    assert steps == list(range(steps[0], steps[0] + len(steps)))   # no step skipped


def _assert_rest_as_offline(msgs):
    """The joint states of a node at rest are the offline run's, step by step."""
    last = _stamp_step(msgs[-1])
    protocol = LimbProtocol.from_mapping({'name': 'rest', 'duration_s': (last + 1) / RATE_HZ,
                                          'muscles': {'quadriceps': {'recruitment': [[0.0, 0.0]]}}})
    offline = simulate_limb(PLANT, protocol, RATE_HZ)
    for m in msgs:
        k = _stamp_step(m)
        assert m.position[0] == pytest.approx(offline['theta_rad'][k], abs=SAME_MODEL_TOL_RAD)
        assert m.velocity[0] == pytest.approx(offline['omega_rad_per_s'][k],
                                              abs=SAME_MODEL_TOL_RAD * RATE_HZ)
        assert abs(m.position[0]) < HANGING_TOL_RAD


def test_at_rest_the_knee_hangs_as_the_offline_model_says(shared):
    _assert_rest_as_offline(shared['rest'])


@pytest.mark.skipif(not engine.numba_available() or engine.requested() == engine.PYTHON,
                    reason='the compiled limb needs numba and HILL_MUSCLE_ENGINE not python')
def test_by_default_the_node_steps_the_compiled_limb_loaded_before_it_starts(shared):
    out = shared['node'].output()
    assert 'limb engine: compiled, loaded in' in out
    # Loaded in __init__, before the start-up line (logged once the node's
    # publishers, subscriptions, service and timer exist).
    assert out.index('limb engine: compiled') < out.index(f'{PLANT.joint.name} with quadriceps')


def test_a_compiled_limb_that_fails_to_load_falls_back_to_python_with_a_warning(monkeypatch):
    def broken():
        raise ImportError('no module named numba')
    monkeypatch.setenv(engine.ENV_VAR, engine.COMPILED)
    monkeypatch.setattr(engine, 'numba_available', lambda: True)
    monkeypatch.setattr(limb_node.limb_kernels, 'compiled', broken)
    logger = RecordingLogger()
    limb = limb_node.load_limb(PLANT, logger)
    assert (type(limb), limb.build) == (Limb, engine.PYTHON)
    assert ('warning', 'the compiled limb failed to load (ImportError: no module named numba): '
            'the limb runs on the Python engine') in logger.lines


def test_an_unknown_engine_falls_back_to_python_naming_the_value(monkeypatch):
    monkeypatch.setenv(engine.ENV_VAR, 'fast')
    logger = RecordingLogger()
    limb = limb_node.load_limb(PLANT, logger)
    assert (type(limb), limb.build) == (Limb, engine.PYTHON)
    assert [level for level, _ in logger.lines] == ['warning']
    assert "`HILL_MUSCLE_ENGINE` must be one of auto, compiled, python, got 'fast'" in \
        logger.lines[0][1]


def test_with_the_python_engine_the_node_steps_the_python_limb_alike(shared):
    probe, rec, node = shared['probe'], shared['python']['rec'], shared['python']['proc']
    probe.wait_for_messages(rec, REST_STEPS, procs=[node])
    out = node.output()
    node.send_signal(signal.SIGINT)   # done with it (the group reaps it)
    assert f'limb engine: python ({engine.ENV_VAR}=python)' in out
    _assert_rest_as_offline(list(rec.messages)[:REST_STEPS])


def test_quadriceps_pulse_width_extends_the_knee(leg):
    rec = leg['recs']['joint']
    mark = rec.mark()
    _publish(leg, 'quadriceps/pulse_width', EXTENDING_PW_S)
    leg['probe'].spin_until(lambda: any(m.position[0] > EXTENDED_RAD for m in rec.since(mark)),
                            'the knee above 30 deg', procs=leg['procs'])
    extended = next(m for m in rec.since(mark) if m.position[0] > EXTENDED_RAD)
    assert extended.effort[0] > 0.0   # the net muscle torque extends


def test_wrench_carries_the_muscle_force_along_x_in_its_frame(leg):
    recs = leg['recs']
    mark_f, mark_w = recs['force'].mark(), recs['wrench'].mark()
    _publish(leg, 'quadriceps/pulse_width', EXTENDING_PW_S)
    wrench = leg['probe'].spin_until(
        lambda: next((w for w in recs['wrench'].since(mark_w) if w.wrench.force.x > 1.0), None),
        'a quadriceps wrench with force', procs=leg['procs'])
    leg['probe'].spin_until(lambda: wrench.wrench.force.x in recs['force'].data_since(mark_f),
                            'the same force on quadriceps/force', procs=leg['procs'])
    assert wrench.header.frame_id == 'quadriceps'
    assert (wrench.wrench.force.y, wrench.wrench.force.z) == (0.0, 0.0)


GARBAGE = {
    'quadriceps/pulse_width': [math.nan, math.inf, -1e-4, 1.0],   # 1 s: microseconds sent as s
    'quadriceps/recruitment': [math.nan, -math.inf, -0.1, 1.5],
    'hamstrings/pulse_width': [math.nan, math.inf, -1e-4, 1.0],
    'hamstrings/recruitment': [math.nan, math.inf, -0.1, 1.5],
    'external_torque': [math.nan, math.inf, -math.inf, 2.0e4],
}


@pytest.mark.faults
def test_garbage_on_every_input_is_ignored_keeping_the_last_good_value(leg):
    good = {'command[quadriceps]': f'{command_from_pulse_width(GOOD_PW_S, QUAD):.6g}',
            'command[hamstrings]': f'{GOOD_RECRUITMENT:.6g}',
            'external_torque_n_m': f'{GOOD_TORQUE_N_M:.6g}'}
    _publish(leg, 'quadriceps/pulse_width', GOOD_PW_S)
    _publish(leg, 'hamstrings/recruitment', GOOD_RECRUITMENT)
    _publish(leg, 'external_torque', GOOD_TORQUE_N_M)
    before = _diagnostics(leg, lambda v: all(v.get(k) == x for k, x in good.items()),
                          'the good inputs held')

    def bad(values, topic):
        return int(values.get(f'bad_inputs[{NS}/{topic}]', 0))
    for topic, values in GARBAGE.items():
        for value in values:
            _publish(leg, topic, value)
    after = _diagnostics(
        leg, lambda v: all(bad(v, t) >= bad(before, t) + len(x) for t, x in GARBAGE.items()),
        'every garbage message counted as rejected')
    assert {k: after[k] for k in good} == good
    assert all(bad(after, t) == bad(before, t) + len(x) for t, x in GARBAGE.items())
    out = leg['node'].output()
    for topic in GARBAGE:
        assert f'ignoring {NS}/{topic} = nan' in out   # the warning names topic and value
    # The node steps on: a joint state after the garbage, with a finite angle.
    rec = leg['recs']['joint']
    mark = rec.mark()
    msg = leg['probe'].wait_for_messages(rec, mark=mark, procs=leg['procs'])[0]
    assert math.isfinite(msg.position[0])


@pytest.mark.faults
@pytest.mark.parametrize('case, key', list(BAD_PLANTS.items()))
def test_bad_plant_file_exits_non_zero_naming_the_key(shared, case, key):
    proc = shared['bad'][case]
    status = proc.wait(EXIT_TIMEOUT_S)
    out = proc.output()
    assert status not in (None, 0), out
    assert f'`{key}`' in out


#: external_torque flood: this many messages as fast as the probe can send,
#: alternating +-FLOOD_TORQUE_N_M with a NaN every FLOOD_NAN_EVERY-th.
FLOOD_MESSAGES = 5000
FLOOD_TORQUE_N_M = 50.0
FLOOD_NAN_EVERY = 7
#: [N m] the last message of the flood: held once the flood has been taken.
FLOOD_LAST_N_M = 3.0
#: Joint states checked after the flood (0.1 s at 200 Hz).
FLOOD_AFTER_STEPS = 20


@pytest.mark.faults
def test_external_torque_flood_breaks_nothing(leg):
    probe, rec = leg['probe'], leg['recs']['joint']
    pub = probe.publisher(f'{NS}/external_torque', Float64)
    probe.spin_until(lambda: pub.get_subscription_count() >= 1, 'the limb subscribed',
                     procs=leg['procs'])
    for k in range(FLOOD_MESSAGES):
        value = math.nan if k % FLOOD_NAN_EVERY == 0 else FLOOD_TORQUE_N_M * (-1) ** k
        pub.publish(Float64(data=value))
    pub.publish(Float64(data=FLOOD_LAST_N_M))
    _diagnostics(leg, lambda v: v.get('external_torque_n_m') == f'{FLOOD_LAST_N_M:.6g}',
                 'the last torque of the flood held')
    assert leg['node'].returncode is None
    # Recorded after the flood: while the probe floods it does not read, so its
    # own reader may drop joint states then; the node's stepping is what counts.
    mark = rec.mark()
    msgs = probe.wait_for_messages(rec, FLOOD_AFTER_STEPS, mark=mark, procs=leg['procs'])
    assert all(math.isfinite(m.position[0]) and math.isfinite(m.velocity[0]) for m in msgs)
    steps = [_stamp_step(m) for m in msgs]
    assert steps == list(range(steps[0], steps[0] + len(steps)))   # stepping goes on


#: [s] watchdog timeout set live for the watchdog test (the module runs with it off).
WATCHDOG_S = 0.2


def test_watchdog_drops_a_silent_muscles_command_to_zero(leg):
    probe = leg['probe']
    results = probe.set_parameters(f'{NS}/limb', {'input_timeout_s': WATCHDOG_S},
                                   procs=leg['procs'])
    try:
        assert all(r.successful for r in results)
        u = f'{command_from_pulse_width(EXTENDING_PW_S, QUAD):.6g}'
        rec = leg['recs']['joint']
        mark = rec.mark()
        _publish(leg, 'quadriceps/pulse_width', EXTENDING_PW_S)   # then silence
        probe.spin_until(lambda: any(m.position[0] > EXTENDED_RAD for m in rec.since(mark)),
                         'the knee above 30 deg', procs=leg['procs'])
        values = _diagnostics(leg, lambda v: v.get('watchdog_tripped[quadriceps]') == 'true',
                              'the quadriceps watchdog tripped')
        assert values['command[quadriceps]'] == '0' != u
        # Unstimulated, the knee falls back towards hanging.
        mark = rec.mark()
        probe.spin_until(lambda: any(m.position[0] < EXTENDED_RAD for m in rec.since(mark)),
                         'the knee back below 30 deg', procs=leg['procs'])
    finally:
        probe.set_parameters(f'{NS}/limb', {'input_timeout_s': 0.0}, procs=leg['procs'])
