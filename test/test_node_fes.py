"""The simulator node with the FES extensions over real DDS: array parameters
from a params file, the recruitment curve on `pulse_width`, and the new
outputs `recruitment_state` (R, the activation) and `fitness`."""
import math

import pytest
import yaml
from std_msgs.msg import Float64
from std_srvs.srv import Trigger

from hill_muscle_ros.model import MuscleParams, engine
from hill_muscle_ros.model.muscle import kernels as muscle_kernels
from hill_muscle_ros.nodes import simulator
from hill_muscle_ros.model.stimulus import command_from_pulse_width
from ros_helpers import Probe, ProcessGroup, RecordingLogger, node_command, ros_env

pytestmark = pytest.mark.ros

RATE_HZ = 200.0
#: A plant with every dynamic feature: Ding's curve, delay, activation,
#: two fibre types in random order, fast fatigue, a length spread.
FES = {
    'recruitment_curve': 'exponential', 'pw_threshold_s': 131.4e-6, 'pw_scale_s': 194.1e-6,
    'emd_s': 0.02, 'tau_act_s': 0.05, 'tau_deact_s': 0.08, 'fv_scaling': 'relative',
    'fatigue': 'riener', 'fatigue_min': [0.2, 0.1], 'tau_fatigue_s': [4.0, 2.0],
    'tau_recovery_s': [6.0, 5.0], 'fibre_fractions': [0.4, 0.6],
    'fibre_force_weights': [1.0, 2.0], 'recruitment_order': 'random',
    'recruitment_seed': 5, 'unit_length_spread': 0.2,
}
PULSE_WIDTH_S = 400e-6
#: [-] R once the activation has settled: a approaches u as exp(-t / tau_act),
#: so after 1 s (20 tau) it is within 2e-9 of it.
SETTLED_TOL = 1e-6


def _fes_command(tmp, ns):
    """The simulator node on FES at RATE_HZ, watchdog off."""
    params = tmp / 'fes.yaml'
    params.write_text(yaml.safe_dump({'/**': {'ros__parameters': dict(
        FES, rate_hz=RATE_HZ, input_timeout_s=0.0)}}))
    return node_command('simulator', ns=ns, params_files=[params])


@pytest.fixture(scope='module')
def fes_sim(tmp_path_factory):
    tmp = tmp_path_factory.mktemp('fes')
    with ProcessGroup(tmp) as procs, Probe() as probe:
        proc = procs.start('fes', _fes_command(tmp, '/fes'))
        recs = {t: probe.record(f'/fes/{t}', Float64)
                for t in ('force', 'recruitment_state', 'fitness')}
        for rec in recs.values():
            probe.wait_for_messages(rec, procs=[proc])
        yield {'probe': probe, 'proc': proc, 'recs': recs}


def _reset(fes_sim):
    response = fes_sim['probe'].call(Trigger, '/fes/reset', Trigger.Request(),
                                     procs=[fes_sim['proc']])
    assert response.success


def test_array_parameters_from_a_params_file_are_the_muscles(fes_sim):
    values = fes_sim['probe'].get_parameters(
        '/fes/simulator', ['fibre_fractions', 'tau_fatigue_s', 'recruitment_order'],
        procs=[fes_sim['proc']])
    assert list(values['fibre_fractions']) == [0.4, 0.6]
    assert list(values['tau_fatigue_s']) == [4.0, 2.0]
    assert values['recruitment_order'] == 'random'


def test_pulse_width_goes_through_the_curve_and_r_settles_at_the_command(fes_sim):
    _reset(fes_sim)
    probe, recs = fes_sim['probe'], fes_sim['recs']
    u = command_from_pulse_width(PULSE_WIDTH_S, MuscleParams(**FES))
    rec = recs['recruitment_state']
    mark = rec.mark()
    probe.publish_when_matched('/fes/pulse_width', Float64(data=PULSE_WIDTH_S),
                               procs=[fes_sim['proc']])
    probe.wait_for_value(rec, lambda r: abs(r - u) < SETTLED_TOL,
                         f'recruitment_state settled at u = {u:.6f}', mark=mark,
                         procs=[fes_sim['proc']])
    # On its way there R only rises (activation from rest, no overshoot).
    values = rec.data_since(mark)
    assert all(b >= a for a, b in zip(values, values[1:]))


def test_fitness_falls_while_stimulated_and_stays_above_fatigue_min(fes_sim):
    _reset(fes_sim)
    probe, recs = fes_sim['probe'], fes_sim['recs']
    rec = recs['fitness']
    mark = rec.mark()
    probe.publish_when_matched('/fes/pulse_width', Float64(data=PULSE_WIDTH_S),
                               procs=[fes_sim['proc']])
    probe.wait_for_value(rec, lambda mu: mu < 0.99, 'mean fitness below 0.99', mark=mark,
                         procs=[fes_sim['proc']])
    assert min(rec.data_since(mark)) >= min(FES['fatigue_min'])


def test_bad_array_parameter_is_rejected_live_naming_it(fes_sim):
    results = fes_sim['probe'].set_parameters('/fes/simulator', {'fibre_fractions': [0.0, 0.0]},
                                              procs=[fes_sim['proc']])
    assert not results[0].successful
    assert '`fibre_fractions` must have a positive sum' in results[0].reason
    results = fes_sim['probe'].set_parameters('/fes/simulator',
                                              {'tau_fatigue_s': [1.0, math.nan]},
                                              procs=[fes_sim['proc']])
    assert not results[0].successful
    assert '`tau_fatigue_s[1]`' in results[0].reason


COMPILED_ENGINE = pytest.mark.skipif(
    not engine.numba_available() or engine.requested() == engine.PYTHON,
    reason='the compiled FES muscle needs numba and HILL_MUSCLE_ENGINE not python')


@COMPILED_ENGINE
def test_by_default_the_node_steps_the_compiled_muscle_loaded_before_it_starts(fes_sim):
    out = fes_sim['proc'].output()
    assert 'muscle engine: compiled, loaded in' in out
    # Loaded in __init__, before the start-up line (logged once the node's
    # publishers, subscriptions, service and timer exist).
    assert out.index('muscle engine: compiled') < out.index(f' muscle, {RATE_HZ:g} Hz, ')


def test_with_the_python_engine_the_node_steps_the_python_muscle(fes_sim, tmp_path):
    ns = '/fes_python'
    probe = fes_sim['probe']
    rec = probe.record(f'{ns}/recruitment_state', Float64)
    u = command_from_pulse_width(PULSE_WIDTH_S, MuscleParams(**FES))
    with ProcessGroup(tmp_path) as procs:
        node = procs.start('fes_python', _fes_command(tmp_path, ns),
                           env=ros_env(**{engine.ENV_VAR: engine.PYTHON}))
        probe.wait_for_messages(rec, procs=[node])
        probe.publish_when_matched(f'{ns}/pulse_width', Float64(data=PULSE_WIDTH_S),
                                   procs=[node])
        probe.wait_for_value(rec, lambda r: abs(r - u) < SETTLED_TOL,
                             f'recruitment_state settled at u = {u:.6f}', procs=[node])
        out = node.output()
    assert f'muscle engine: python ({engine.ENV_VAR}=python)' in out


@COMPILED_ENGINE
def test_a_live_change_rebuilds_the_compiled_muscle_without_compiling(fes_sim):
    probe, proc = fes_sim['probe'], fes_sim['proc']
    for emd_s in (FES['emd_s'] * 2.0, FES['emd_s']):   # and back, for any later test
        results = probe.set_parameters('/fes/simulator', {'emd_s': emd_s}, procs=[proc])
        assert results[0].successful
    line = 'emd_s changed: muscle rebuilt at rest (engine: compiled)'
    probe.spin_until(lambda: proc.output().count(line) == 2, 'two compiled rebuilds logged',
                     procs=[proc])
    out = proc.output()   # loaded at start-up, never again
    assert 'loading the compiled muscle' not in out[out.index(line):]


@COMPILED_ENGINE
def test_a_muscle_with_every_fes_feature_off_runs_on_the_same_compiled_engine():
    logger = RecordingLogger()
    muscle = simulator.load_muscle(MuscleParams(), logger)
    assert muscle.build == engine.COMPILED
    assert logger.lines[-1][1].startswith('muscle engine: compiled, loaded in')


def test_a_compiled_muscle_that_fails_to_load_falls_back_to_python_with_a_warning(monkeypatch):
    def broken():
        raise ImportError('no module named numba')
    monkeypatch.setenv(engine.ENV_VAR, engine.COMPILED)
    monkeypatch.setattr(engine, 'numba_available', lambda: True)
    monkeypatch.setattr(muscle_kernels, 'compiled', broken)
    logger = RecordingLogger()
    muscle = simulator.load_muscle(MuscleParams(**FES), logger)
    assert muscle.build == engine.PYTHON
    assert ('warning', 'the compiled muscle failed to load (ImportError: no module named '
            'numba): the muscle runs on the Python engine') in logger.lines


@COMPILED_ENGINE
def test_a_rebuild_keeps_the_engine_the_node_started_with():
    simulator.load_muscle(MuscleParams(**FES), RecordingLogger())   # loads the kernels, as __init__
    params = MuscleParams(**dict(FES, emd_s=0.03))
    assert simulator.rebuild_muscle(params, True, RecordingLogger()).build == engine.COMPILED
    assert simulator.rebuild_muscle(params, False, RecordingLogger()).build == engine.PYTHON
    assert simulator.rebuild_muscle(MuscleParams(), True,
                                    RecordingLogger()).build == engine.COMPILED
