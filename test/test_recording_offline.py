"""Offline runs as bags: same topics and types as a live run, values exactly those of
the core simulation, stamped in simulated time, readable by every promised reader."""
import numpy as np
import pytest
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from rosbags.highlevel import AnyReader
from rosbags.rosbag2 import Reader

from hill_muscle_ros.model import MuscleParams, Protocol, simulate
from hill_muscle_ros.recording import BagOutputError
from hill_muscle_ros.recording.offline import write_simulation_bag
from hill_muscle_ros.recording.reader import read_bag
from hill_muscle_ros.timebase import NS_PER_S
from hill_muscle_ros.tools import cli

RATE_HZ = 1000.0
#: The topics and types a live run with the simulator and the player records.
LIVE_TOPICS = {
    '/pulse_width': 'std_msgs/msg/Float64',
    '/length_command': 'std_msgs/msg/Float64',
    '/force': 'std_msgs/msg/Float64',
    '/ce_length': 'std_msgs/msg/Float64',
    '/wrench': 'geometry_msgs/msg/WrenchStamped',
}


@pytest.fixture(scope='module')
def run(protocol_paths, tmp_path_factory):
    protocol = Protocol.from_yaml(protocol_paths['II'])
    params = MuscleParams()
    result = simulate(protocol, params, RATE_HZ)
    path = tmp_path_factory.mktemp('offline') / 'protocol_II'
    write_simulation_bag(path, result, params, protocol)
    return path, result, params, protocol


@pytest.fixture(scope='module')
def run_bag(run):
    """The offline bag read once by the package's reader (0.35 CPU-s a read)
    for the tests that check what it holds."""
    return read_bag(run[0])


def test_offline_bag_has_the_live_topics_and_types(run):
    path, *_ = run
    with Reader(path) as reader:
        assert {c.topic: c.msgtype for c in reader.connections} == LIVE_TOPICS


def test_every_sample_is_in_the_bag_once_per_topic(run, run_bag):
    path, result, *_ = run
    assert run_bag.counts() == {topic: len(result.t_s) for topic in LIVE_TOPICS}


def test_outputs_are_the_core_simulation_exactly(run, run_bag):
    path, result, *_ = run
    bag = run_bag
    np.testing.assert_array_equal(bag.topic('force').values(), result.force_n)
    np.testing.assert_array_equal(bag.topic('wrench').values(), result.force_n)
    np.testing.assert_array_equal(bag.topic('ce_length').values(), result.l_ce_m)


def test_everything_is_stamped_in_simulated_time(run, run_bag):
    path, result, *_ = run
    bag = run_bag
    expected = np.round(result.t_s * NS_PER_S).astype(np.int64)
    for topic in LIVE_TOPICS:
        np.testing.assert_array_equal(bag.topic(topic).log_time_ns, expected)
    np.testing.assert_array_equal(bag.topic('wrench').stamps_ns(), expected)


def test_inputs_are_what_the_player_publishes(run, run_bag):
    path, result, params, protocol = run
    bag = run_bag
    before_end = result.t_s < protocol.duration_s
    pw = bag.topic('pulse_width').values()
    np.testing.assert_allclose(pw[before_end] / params.pw_max_s,
                               result.recruitment[before_end], rtol=0, atol=1e-12)
    assert pw[-1] == 0.0  # the player's final zero stimulation
    np.testing.assert_allclose(bag.topic('length_command').values(), result.dl_mt_m,
                               rtol=0, atol=1e-15)


def test_recruitment_output_publishes_r(tmp_path, protocol_paths):
    protocol = Protocol.from_yaml(protocol_paths['I'])
    params = MuscleParams()
    result = simulate(protocol, params, 100.0)
    write_simulation_bag(tmp_path / 'bag', result, params, protocol, output='recruitment')
    values = read_bag(tmp_path / 'bag').topic('recruitment').values()
    np.testing.assert_array_equal(values[:-1], result.recruitment[:-1])


def test_anyreader_reads_the_offline_bag(run):
    path, result, *_ = run
    with AnyReader([path]) as reader:
        conns = [c for c in reader.connections if c.topic == '/wrench']
        forces = [reader.deserialize(raw, c.msgtype).wrench.force.x
                  for c, _, raw in reader.messages(connections=conns)]
    assert forces == list(result.force_n)


def test_mcap_ros2_reads_the_offline_bag(run):
    path, result, *_ = run
    with open(path / f'{path.name}_0.mcap', 'rb') as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        forces = [d.data for *_, d in reader.iter_decoded_messages(topics=['/force'])]
    assert forces == list(result.force_n)


def test_unknown_output_is_rejected(tmp_path, run):
    _, result, params, protocol = run
    with pytest.raises(ValueError, match='`output` must be one of'):
        write_simulation_bag(tmp_path / 'bag', result, params, protocol, output='current')


def test_existing_bag_is_never_overwritten(run):
    path, result, params, protocol = run
    before = (path / f'{path.name}_0.mcap').read_bytes()
    with pytest.raises(BagOutputError):
        write_simulation_bag(path, result, params, protocol)
    assert (path / f'{path.name}_0.mcap').read_bytes() == before


def test_cli_simulate_bag_writes_the_same_run(tmp_path, run, capsys):
    # The command's entry function in this process: what it writes is the
    # claim, and `simulate`'s console script runs in test_cli.py (a second
    # interpreter here re-imported numpy, numba's kernels and the bag
    # libraries: 2.4 CPU-s).
    _, result, *_ = run
    assert cli.main(['simulate', '--protocol', 'II', '--bag', str(tmp_path / 'cli_bag')]) == 0, \
        capsys.readouterr().err
    np.testing.assert_array_equal(read_bag(tmp_path / 'cli_bag').topic('force').values(),
                                  result.force_n)


def test_cli_simulate_bag_refuses_a_non_empty_directory(tmp_path, capsys):
    # The command's entry function in this process, as in the test above.
    (tmp_path / 'old.txt').write_text('keep')
    assert cli.main(['simulate', '--protocol', 'II', '--bag', str(tmp_path)]) != 0
    assert 'not empty' in capsys.readouterr().err
    assert [p.name for p in tmp_path.iterdir()] == ['old.txt']
