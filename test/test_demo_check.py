"""``make demo``'s verdict: it fails, with a line that says where and by how
much, when the live force misses the offline one at a checkpoint by more than
:data:`~hill_muscle_ros.demo.LIVE_OFFLINE_TOLERANCE_N`. Offline: the live run
and its analysis are stood in for (the run itself is ``test_demo.py``)."""
import pytest

from hill_muscle_ros import demo
from hill_muscle_ros.demo import (LIVE_OFFLINE_TOLERANCE_N, DemoError,
                                  check_live_against_offline)
from hill_muscle_ros.recording.analysis import Checkpoint, LiveRunSummary

#: The measured live run shifted 150 ms: 1.5 N off at 1.95 s and 4.95 s.
SHIFTED = [Checkpoint(0.95, 18.595, 18.595), Checkpoint(1.95, 30.159, 31.659),
           Checkpoint(4.95, 27.378, 25.896)]
#: A healthy live run: within 0.031 N.
HEALTHY = [Checkpoint(0.95, 18.595, 18.595), Checkpoint(1.95, 31.690, 31.659),
           Checkpoint(4.95, 25.872, 25.896)]


def test_checkpoints_within_the_tolerance_pass():
    check_live_against_offline(HEALTHY)


def test_a_checkpoint_beyond_the_tolerance_fails_naming_the_worst():
    with pytest.raises(DemoError, match=r'more than 0\.1 N \(LIVE_OFFLINE_TOLERANCE_N\) at 2 of '
                                        r'3 checkpoints; worst at t = 1\.950 s: live 30\.159 N, '
                                        r'offline 31\.659 N, difference -1\.500 N'):
        check_live_against_offline(SHIFTED)


def test_a_checkpoint_without_a_live_reading_fails():
    with pytest.raises(DemoError, match='worst at t = 0.950 s: live nan N'):
        check_live_against_offline([Checkpoint(0.95, float('nan'), 18.595), *HEALTHY[1:]])


def test_the_tolerance_is_a_tenth_of_a_newton():
    assert LIVE_OFFLINE_TOLERANCE_N == 0.1


def test_demo_exits_1_with_the_reason_when_live_misses_offline(tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(demo, 'record_live_run', lambda *args: None)
    monkeypatch.setattr(demo, 'analyse', lambda *args: LiveRunSummary('the table', SHIFTED))
    status = demo.main(['--runs-dir', str(tmp_path), '--name', 'shifted'])
    out, err = capsys.readouterr()
    assert status == 1
    assert 'the table' in out
    assert err.startswith('demo failed: live force differs from the offline simulation by '
                          'more than 0.1 N')


def test_demo_failure_names_the_simulators_longest_tick_gap(tmp_path, monkeypatch, capsys):
    # A stalled simulator is the first thing to rule out when live misses offline.
    def run(config, bag_dir, protocol, log_dir):
        (log_dir / 'simulator.log').write_text(
            '[INFO] [1.0] [simulator.stats]: ran 8916 steps, longest gap between ticks '
            '138.0 ms (ended at steady time 1529.591110 s)\n')
    monkeypatch.setattr(demo, 'record_live_run', run)
    monkeypatch.setattr(demo, 'analyse', lambda *args: LiveRunSummary('the table', SHIFTED))
    assert demo.main(['--runs-dir', str(tmp_path), '--name', 'stalled']) == 1
    assert "the simulator's longest gap between ticks was 138.0 ms" in capsys.readouterr().err
