"""``simulate --plant ... --bag``: the limb run as the limb node's topics, read back by rosbags.

The knee with both kinds of stimulation (the quadriceps by pulse width, the
hamstrings by recruitment) and an external torque: every input the limb node
subscribes and every output it publishes, one message per sample, with the
values of the offline limb run, stamped in simulated time. ``hill-muscle fit
--plant`` replays such a bag to the very angle it holds.
"""
import numpy as np
import pytest
import yaml
from rosbags.highlevel import AnyReader

from hill_muscle_ros import resources
from hill_muscle_ros.model.limb import LimbProtocol, simulate_limb
from hill_muscle_ros.params_file import load_plant
from hill_muscle_ros.timebase import NS_PER_S
from hill_muscle_ros.tools import cli, fit

RATE_HZ = 1000.0
KNEE = resources.config_dir() / 'knee.yaml'
#: [s] the quadriceps' pulse width from 0.05 s, [-] the hamstrings' recruitment
#: from 0.2 s, [N m] a flexing torque from 0.1 s: each input changes once.
PW_ON_S, PW_S = 0.05, 0.0003
R_ON_S, R_LEVEL = 0.2, 0.3
TAU_ON_S, TAU_N_M = 0.1, -2.0
PROTOCOL = {'name': 'knee, every input', 'duration_s': 0.4,
            'muscles': {'quadriceps': {'pulse_width_s': [[PW_ON_S, 0.0], [PW_ON_S, PW_S]]},
                        'hamstrings': {'recruitment': [[0.0, 0.0], [R_ON_S, 0.0],
                                                       [R_ON_S, R_LEVEL]]}},
            'external_torque_n_m': [[0.0, 0.0], [TAU_ON_S, 0.0], [TAU_ON_S, TAU_N_M]]}
FLOAT64, JOINT_STATE = 'std_msgs/msg/Float64', 'sensor_msgs/msg/JointState'
WRENCH = 'geometry_msgs/msg/WrenchStamped'
#: The limb node's topics for the knee (nodes/limb.py): its inputs and its outputs.
LIMB_NODE_TOPICS = {'/quadriceps/pulse_width': FLOAT64, '/hamstrings/recruitment': FLOAT64,
                    '/external_torque': FLOAT64, '/joint_states': JOINT_STATE,
                    '/quadriceps/force': FLOAT64, '/hamstrings/force': FLOAT64,
                    '/quadriceps/wrench': WRENCH, '/hamstrings/wrench': WRENCH}
#: [N m] the net muscle torque is a sum of two products of the forces: rounding only.
TORQUE_TOL_N_M = 1e-9


def _messages(path):
    """topic -> [(log time [ns], message)], read by rosbags (independent of the writer)."""
    out = {}
    with AnyReader([path]) as reader:
        for connection, t_ns, raw in reader.messages():
            out.setdefault(connection.topic, []).append(
                (t_ns, reader.deserialize(raw, connection.msgtype)))
    return out


@pytest.fixture(scope='module')
def knee_bag(tmp_path_factory):
    d = tmp_path_factory.mktemp('limb_bag')
    protocol_path = d / 'knee_every_input.yaml'
    protocol_path.write_text(yaml.safe_dump(PROTOCOL))
    bag = d / 'bag'
    assert cli.main(['simulate', '--plant', str(KNEE), '--protocol', str(protocol_path),
                     '--rate', str(RATE_HZ), '--bag', str(bag)]) == 0
    plant = load_plant(KNEE)[0]
    result = simulate_limb(plant, LimbProtocol.from_mapping(PROTOCOL), RATE_HZ)
    with AnyReader([bag]) as reader:
        types = {c.topic: c.msgtype for c in reader.connections}
    return {'bag': bag, 'plant': plant, 'result': result, 'types': types,
            'messages': _messages(bag)}


def test_the_bag_has_the_limb_nodes_topics_and_types(knee_bag):
    assert knee_bag['types'] == LIMB_NODE_TOPICS


def test_every_topic_has_one_message_per_sample(knee_bag):
    n = len(knee_bag['result'].t_s)
    assert {t: len(m) for t, m in knee_bag['messages'].items()} == {
        t: n for t in LIMB_NODE_TOPICS}


def test_messages_are_logged_at_the_sample_times(knee_bag):
    want = [round(t * NS_PER_S) for t in knee_bag['result'].t_s]
    for topic, messages in knee_bag['messages'].items():
        assert [t_ns for t_ns, _ in messages] == want, topic


def test_joint_states_hold_the_runs_angle_and_velocity_exactly(knee_bag):
    result, states = knee_bag['result'], [m for _, m in knee_bag['messages']['/joint_states']]
    assert all(list(s.name) == ['knee'] for s in states)
    assert [s.position[0] for s in states] == list(result['theta_rad'])
    assert [s.velocity[0] for s in states] == list(result['omega_rad_per_s'])


def test_joint_states_effort_is_the_net_muscle_torque(knee_bag):
    result, plant = knee_bag['result'], knee_bag['plant']
    states = [m for _, m in knee_bag['messages']['/joint_states']]
    torque = sum(m.sign * m.moment_arm_m * result[f'{m.name}_force_n'] for m in plant.muscles)
    np.testing.assert_allclose([s.effort[0] for s in states], torque, rtol=0,
                               atol=TORQUE_TOL_N_M)


@pytest.mark.parametrize('muscle', ['quadriceps', 'hamstrings'])
def test_force_and_wrench_are_the_runs_force_exactly(knee_bag, muscle):
    force = list(knee_bag['result'][f'{muscle}_force_n'])
    messages = knee_bag['messages']
    assert [m.data for _, m in messages[f'/{muscle}/force']] == force
    wrenches = [m for _, m in messages[f'/{muscle}/wrench']]
    assert [w.wrench.force.x for w in wrenches] == force
    assert all(w.header.frame_id == muscle for w in wrenches)


def _stepped(t_s, on_s, value):
    """[-] a knot step: 0 before ``on_s``, ``value`` from it (the last knot wins)."""
    return np.where(t_s >= on_s, value, 0.0)


@pytest.mark.parametrize('topic, on_s, value', [
    ('/quadriceps/pulse_width', PW_ON_S, PW_S), ('/hamstrings/recruitment', R_ON_S, R_LEVEL),
    ('/external_torque', TAU_ON_S, TAU_N_M)])
def test_inputs_are_the_protocols_values_then_zero_at_the_end(knee_bag, topic, on_s, value):
    t = knee_bag['result'].t_s
    want = _stepped(t, on_s, value)
    want[-1] = 0.0   # the player's last message, at the end
    got = [m.data for _, m in knee_bag['messages'][topic]]
    np.testing.assert_array_equal(got, want)


def test_fit_replays_the_bag_to_its_angle_exactly(knee_bag):
    recording = fit.load_limb_recording(knee_bag['bag'], knee_bag['plant'])
    np.testing.assert_array_equal(fit.LimbReplay(recording).predict([knee_bag['plant']])[0],
                                  knee_bag['result']['theta_rad'])


def test_a_used_bag_directory_is_a_user_error(knee_bag, tmp_path, capsys):
    protocol = resources.config_dir() / 'protocols' / 'knee_extension.yaml'
    status = cli.main(['simulate', '--plant', str(KNEE), '--protocol', str(protocol),
                       '--bag', str(knee_bag['bag'])])
    assert status == cli.EXIT_USAGE
    assert str(knee_bag['bag']) in capsys.readouterr().err
