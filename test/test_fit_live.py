"""``hill-muscle fit`` on a live recording: the simulator node with non-default
muscle parameters, driven by the protocol player over DDS and recorded by the
recorder (three processes, this run's own ROS_DOMAIN_ID), and the fit recovers
the parameters from the bag.

What DDS timing does to the inputs, and so the tolerances:

- The length is exact as long as every knot arrives before its stamp. The
  player sends it ahead as stamped knots (``lookahead_s``), the simulator
  reaches each knot at its stamp, and the fit interpolates the same knots at
  the same stamps.
- The stimulation is not. It goes on the plain ``pulse_width`` topic at its
  time; the simulator applies a message from the first step of its next tick,
  while the bag stamps it with the recorder's receive time. In two recorded
  runs of this test the three changes (onset, the step at 3 s, the release)
  acted -4/-5/-1 ms and -2/-1/-13 ms from their stamps. One step off leaves a
  residual as large as the force's jump there (40 N at the release), and the
  plain fit of those two bags missed ``fv_a_n`` by 4.1 % and 9.2 %, since the
  Hill constant shows only while the CE moves, right after the changes.
  ``--edge-search`` moves each change to the step that best explains the force
  (within ±:data:`EDGE_SEARCH_S`), so that error is gone: the second run's
  aligned fit is exact (residual RMS 4e-6 N).
- What remains is a knot that arrives after its stamp, under load: in the first
  run 2 of 3347 knots came 15 ms late at the start of the ramp, the simulator's
  length was up to 0.29 mm off the knots for a few ms (read back from its force
  and CE length), and the aligned fit gave ``f_iso_max_n`` 0.04 %,
  ``k_se_n_per_m`` 0.59 % and ``fv_a_n`` 0.83 % off. The tolerances allow
  about three times that; they stay well inside the distance the fit travels
  (the defaults are 13 %, 25 % and 23 % off). That run's player sent the knots
  0.1 s ahead (the demo's look-ahead); this test sends them
  :data:`LOOKAHEAD_S` ahead, so a knot is late only if DDS takes longer than
  that to deliver it, and the fit sees the length the simulator ran. The
  simulator's exit line (late knots, longest tick gap) is quoted on failure.
"""
import os

import pytest

from hill_muscle_ros.params_file import load_muscle_params
from hill_muscle_ros.tools import cli
from live_run import record_live_run

# alone: the length knots are sent a fixed time ahead of the plant.
pytestmark = [pytest.mark.ros]

#: The simulated subject (the defaults are 45 N, 10 kN/m and 10 N): as in test_fit.
TRUTH = {'f_iso_max_n': 52.0, 'k_se_n_per_m': 8000.0, 'fv_a_n': 13.0}
#: [s] the window of --edge-search. Moves of 13 ms were seen on an idle
#: machine; with a compiler busy on the other core a fresh-clone run saw -16 ms
#: and two moves at the edge of a 30 ms window (the fit then missed
#: ``f_iso_max_n`` by 0.8 %). The simulator itself catches up at most 0.1 s of
#: clock time per tick; a recorder that falls further behind than that is
#: overloaded, which its diagnostics report.
EDGE_SEARCH_S = 0.1
#: [s] the player's look-ahead of the length knots. A reliable sample that UDP
#: dropped comes again on the writer's next heartbeat (0.1 s here), and a
#: Python process on a busy 2-core machine can be descheduled for tens of ms:
#: 1 s is ten heartbeats. It costs a start one look-ahead later, nothing else.
LOOKAHEAD_S = 1.0
#: Relative tolerance of each estimate: about three times the errors of the
#: aligned fit of the run with late knots (0.04 %, 0.59 %, 0.83 %).
TOLERANCE = {'f_iso_max_n': 0.002, 'k_se_n_per_m': 0.02, 'fv_a_n': 0.025}


def _record_live_run(tmp, ns, protocol_file):
    run = record_live_run(tmp, ns, protocol_file, sim_params=TRUTH, probe_name='fit_live_probe',
                          lookahead_s=LOOKAHEAD_S)
    assert run['status'] == 0, run['log']
    return run['bag'], simulator_statistics(run['sim_log'])


def simulator_statistics(log: str) -> str:
    """The simulator's exit line (steps, tick gaps, late knots), or a note that it is missing."""
    lines = [line for line in log.splitlines() if 'late length_command_stamped knots' in line]
    return lines[-1] if lines else f'(no exit statistics in the simulator log: {log[-500:]!r})'


@pytest.fixture(scope='module')
def live_bag(tmp_path_factory, protocol_paths):
    tmp = tmp_path_factory.mktemp('fit_live')
    return _record_live_run(tmp, f'/fit_live{os.getpid()}', protocol_paths['II'])


def test_fit_recovers_the_simulator_parameters_from_a_live_bag(live_bag, tmp_path, capsys):
    bag, statistics = live_bag
    status = cli.main(['fit', '--bag', str(bag), '--fit', ','.join(TRUTH),
                       '--edge-search', str(EDGE_SEARCH_S),
                       '--out', str(tmp_path / 'fitted.yaml')])
    out, err = capsys.readouterr()
    assert status == 0, err
    moves = next(line for line in out.splitlines() if 'stimulation changes moved by' in line)
    fitted, _ = load_muscle_params(tmp_path / 'fitted.yaml')
    for name, truth in TRUTH.items():
        assert getattr(fitted, name) == pytest.approx(truth, rel=TOLERANCE[name]), (
            name, moves, statistics, out)
