"""One params file for every node: a shared ``/**`` section may carry the other
nodes' parameters, which a node passes over; a key no node has stops it."""
from __future__ import annotations

import pytest

from hill_muscle_ros.resources import default_params_file
from ros_helpers import ProcessGroup, node_command

pytestmark = pytest.mark.ros

#: [s] a node that fails on its parameters does so at once; this is ample.
EXIT_TIMEOUT_S = 60.0


def test_player_given_the_simulators_params_file_passes_over_its_keys(tmp_path):
    """config/muscle.yaml holds simulator keys; the player starts anyway and
    fails only because nobody subscribes within its (short) wait."""
    with ProcessGroup(tmp_path) as procs:
        proc = procs.start('player', node_command(
            'protocol_player', params_files=[default_params_file()],
            params={'wait_for_subscribers_s': 0.5}))
        status = proc.wait(EXIT_TIMEOUT_S)
        out = proc.output()
    assert status != 0
    assert 'unknown parameter' not in out
    assert 'subscriber' in out


def test_player_stops_on_a_key_no_node_has(tmp_path):
    with ProcessGroup(tmp_path) as procs:
        proc = procs.start('player', node_command('protocol_player',
                                                  params={'protocoll': 'II'}))
        status = proc.wait(EXIT_TIMEOUT_S)
        out = proc.output()
    assert status != 0
    assert "unknown parameter `protocoll` (got 'II')" in out
    assert 'Traceback' not in out
