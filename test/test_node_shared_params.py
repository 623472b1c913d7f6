"""Parameters files: the one shipped per node loads into that node, and one
file may serve every node: a shared ``/**`` section may carry the other
nodes' parameters, which a node passes over; a key no node has stops it."""
from __future__ import annotations

import math
from pathlib import Path

import pytest
import yaml

from hill_muscle_ros.resources import default_params_file
from ros_helpers import ProcessGroup, Probe, node_command

pytestmark = [pytest.mark.ros, pytest.mark.unpaced]

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


CONFIG = Path(__file__).resolve().parents[1] / 'config'
#: (console script, node name, the node's shipped parameters file, overrides):
#: the overrides keep a node alive while the test reads it (the player gives up
#: when nobody subscribes) or keep its output out of the checkout; an
#: overridden key is not compared.
NODE_FILES = [
    ('simulator', 'simulator', 'muscle.yaml', {}),
    ('force_controller', 'force_controller', 'force_controller.yaml', {}),
    ('protocol_player', 'protocol_player', 'protocol_player.yaml',
     {'wait_for_subscribers_s': 600.0}),
    ('recorder', 'recorder', 'recorder.yaml', {'output': None}),  # None: a tmp directory
]


def _file_parameters(path: Path) -> dict:
    """The ``ros__parameters`` of the file's single ``/**`` section."""
    sections = yaml.safe_load(path.read_text(encoding='utf-8'))
    assert list(sections) == ['/**'], f'{path.name}: expected one /** section'
    return sections['/**']['ros__parameters']


def _same(want, got) -> bool:
    if isinstance(want, float) and isinstance(got, float):
        return math.isclose(want, got, rel_tol=1e-12)
    return want == got and type(want) is type(got)


@pytest.mark.parametrize('executable, node, filename, overrides', NODE_FILES,
                         ids=[case[0] for case in NODE_FILES])
def test_each_nodes_shipped_params_file_sets_its_parameters(tmp_path, executable, node,
                                                            filename, overrides):
    """Started with its file, the node runs and holds every value of the file,
    with the file's type (a key the node does not declare reads back unset)."""
    wanted = _file_parameters(CONFIG / filename)
    overrides = {k: str(tmp_path / 'bag') if v is None else v for k, v in overrides.items()}
    ns = f'/params_file_{executable}'
    with ProcessGroup(tmp_path) as procs, Probe() as probe:
        proc = procs.start(executable, node_command(
            executable, ns=ns, params_files=[CONFIG / filename], params=overrides))
        compared = [k for k in wanted if k not in overrides]
        got = probe.get_parameters(f'{ns}/{node}', compared, procs=[proc])
    wrong = {k: (wanted[k], got[k]) for k in compared if not _same(wanted[k], got[k])}
    assert not wrong, f'{filename}: parameter (file, node): {wrong}'
