"""A live run of the real nodes, as the tests that record one need it: the
simulator, the protocol player and the recorder (three processes over DDS),
the player started only once both listeners are up, the recorder stopped with
SIGINT at the protocol's end."""
import signal
from pathlib import Path
from typing import Any

from geometry_msgs.msg import WrenchStamped

from hill_muscle_ros.demo import default_lookahead_s
from hill_muscle_ros.model import Protocol
from hill_muscle_ros.nodes.recorder import subscriptions_node_name
from ros_helpers import DEFAULT_TIMEOUT_S, ProcessGroup, Probe, node_command

#: [s] the length goes this far ahead of time, as in the demo at real time.
LOOKAHEAD_S = default_lookahead_s(1.0)
#: [s] allowance beyond the protocol's duration for the player to start and finish.
PLAYER_SLACK_S = 60.0


def wait_until_recording(probe: Probe, ns: str, procs: list) -> None:
    """The recorder is up and spinning (it answers its parameter service), and the
    graph shows it subscribed to the simulator's wrench."""
    probe.wait_until_serving(f'{ns}/recorder', DEFAULT_TIMEOUT_S, procs)
    probe.wait_for_endpoints(f'{ns}/wrench', publisher=f'{ns}/simulator',
                             subscriber='/' + subscriptions_node_name('recorder'),
                             timeout_s=DEFAULT_TIMEOUT_S, watch=procs)


def record_live_run(tmp: Path, ns: str, protocol_file: Path, *,
                    sim_params: dict[str, Any] | None = None,
                    probe_name: str = 'live_probe',
                    lookahead_s: float = LOOKAHEAD_S) -> dict[str, Any]:
    """Play ``protocol_file`` to the simulator in namespace ``ns`` and record it.

    :param tmp: directory for the bag (``tmp/bag``) and the processes' logs
    :param sim_params: the simulator's parameters (default: its defaults)
    :param lookahead_s: [s] the player's ``lookahead_s``
    :return: ``bag`` (its directory), ``status`` (the recorder's exit status),
        ``log`` (the recorder's output), ``probe_wrenches`` (the wrenches a
        probe in this process received) and ``sim_log`` (the simulator's
        output, its exit statistics included: late knots, longest tick gap)
    """
    bag = tmp / 'bag'
    duration_s = Protocol.from_yaml(protocol_file).duration_s
    with ProcessGroup(tmp) as procs, Probe(probe_name) as probe:
        seen = probe.record(f'{ns}/wrench', WrenchStamped)
        sim = procs.start('simulator', node_command('simulator', ns=ns, params=sim_params))
        rec = procs.start('recorder', node_command('recorder', ns=ns,
                                                   params={'output': str(bag)}))
        probe.wait_for_messages(seen, 1, procs=[sim, rec])
        # The recorder holds the muscle at rest before the protocol starts.
        wait_until_recording(probe, ns, [sim, rec])
        # Both listeners, the simulator and the recorder, before the first knot.
        player = procs.start('player', node_command(
            'protocol_player', ns=ns, params={'protocol': str(protocol_file),
                                              'min_subscribers': 2,
                                              'lookahead_s': lookahead_s}))
        probe.spin_until(lambda: player.returncode is not None, 'the end of the protocol',
                         timeout_s=duration_s + PLAYER_SLACK_S, procs=[sim, rec])
        assert player.returncode == 0, player.describe()
        rec.popen.send_signal(signal.SIGINT)
        status = rec.wait()
        received = list(seen.messages)
        rec_log = rec.output()
    # After the group stopped the simulator: its exit statistics are in its log.
    return {'bag': bag, 'status': status, 'log': rec_log, 'probe_wrenches': received,
            'sim_log': sim.output()}
