"""The pulse-driven muscle (activation_model ding2003): channels, pulses at their
own instants, the stimulator's limits, and what a first_order muscle refuses.
Its forces against an independent reference are in test_ding_reference.py."""
import csv
from pathlib import Path

import numpy as np
import pytest
import yaml
from hypothesis import given, settings, strategies as st

from hill_muscle_ros.model import MuscleParams, simulate
from hill_muscle_ros.model.muscle import Muscle
from hill_muscle_ros.model.protocol import PulseProtocol
from hill_muscle_ros.model.stimulator import ChannelCommand
from hill_muscle_ros.model.units import channel_positions, order_units

from hill_muscle_ros.model import engine
from hill_muscle_ros.tools import cli

REPO = Path(__file__).resolve().parents[1]

DING = dict(activation_model='ding2003', f_iso_max_n=333.87)


def pulses_muscle(build=None, **changes):
    return Muscle(MuscleParams(**{**DING, **changes}), build=build)


def constant_train(channel=1, pw=250e-6, f=33.0, mode='single', current=None):
    return ChannelCommand(channel, mode, pw, current, f)


def test_channel_territories_are_disjoint_and_cover_every_unit_in_their_shares():
    p = MuscleParams(**DING, n_units=1000, channel_fractions=(1.0, 1.0, 2.0))
    territories = channel_positions(p)
    assert [len(t) for t in territories] == [250, 250, 500]
    every = np.concatenate(territories)
    assert sorted(every.tolist()) == list(range(1000))


def test_a_channel_whose_share_rounds_to_no_unit_is_refused_naming_it():
    # 2 units in shares 1 : 0.25 give channel 2 floor(2 * 1.25 / 1.25 + 0.5) -
    # floor(2 * 1 / 1.25 + 0.5) = 0 units: it would take pulses and move nothing.
    with pytest.raises(ValueError, match=r'`channel_fractions` must give every channel at '
                                         r'least one of the 2 units \(`n_units`\), got '
                                         r'\[1.0, 0.25\]: channel 2 gets none'):
        MuscleParams(**DING, n_units=2, channel_fractions=(1.0, 0.25))
    # One unit more and each channel has one: accepted.
    assert [len(t) for t in channel_positions(
        MuscleParams(**DING, n_units=3, channel_fractions=(1.0, 0.25)))] == [2, 1]


def test_a_territory_is_the_channel_seeds_permutation_block_whatever_the_recruitment_order():
    p = MuscleParams(**DING, n_units=50, channel_fractions=(1.0, 1.0),
                     recruitment_order='random', recruitment_seed=3, channel_seed=7)
    units_of_channel_0 = set(np.random.default_rng(7).permutation(50)[:25].tolist())
    order = order_units(p)
    assert {int(order[q]) for q in channel_positions(p)[0]} == units_of_channel_0


def test_a_pulse_recruits_its_share_of_its_channels_territory_at_its_instant():
    m = pulses_muscle(n_units=1000, channel_fractions=(1.0, 1.0))
    # 200 us of 500 us on the linear curve: u = 0.4 of channel 2's 500 units.
    out, _, used = m.run_pulses([0.0004], [1], [0.4], np.zeros(1), 1e-3)
    assert used == 1
    assert out[0][2] == 200            # n_recruited
    assert out[0][1] == pytest.approx(0.2)   # R = M / N


def test_the_activation_starts_at_the_pulse_instant_not_at_the_step_end():
    """A pulse 0.3 ms into a 1 ms step gives the activation of 0.7 ms of Ding's law
    at the step end: the same as a run of 0.1 ms steps, to RK4's error at 1 ms
    (3e-5 of a, measured), while moving the pulse by 0.4 ms changes a by far more."""
    coarse = pulses_muscle()
    _, act_coarse, _ = coarse.run_pulses([0.0003], [0], [1.0], np.zeros(10), 1e-3)
    fine = pulses_muscle()
    _, act_fine, _ = fine.run_pulses([0.0003], [0], [1.0], np.zeros(100), 1e-4)
    assert act_coarse[:, 0] == pytest.approx(act_fine[9::10, 0], rel=1e-4, abs=1e-12)
    shifted = pulses_muscle()
    _, act_shifted, _ = shifted.run_pulses([0.0007], [0], [1.0], np.zeros(10), 1e-3)
    assert act_shifted[-1, 0] < 0.99 * act_coarse[-1, 0]


def test_the_electromechanical_delay_shifts_every_pulse_by_emd():
    base = pulses_muscle()
    base.stimulate([constant_train()])
    out0, _ = base.run_trains(np.zeros(300), 1e-3)
    delayed = pulses_muscle(emd_s=0.040)
    delayed.stimulate([constant_train()])
    out1, _ = delayed.run_trains(np.zeros(300), 1e-3)
    assert np.all(out1[:39, 8] == 0.0)
    assert out1[40:, 8] == pytest.approx(out0[:260, 8], abs=1e-9)


def test_a_channel_quiet_for_a_second_releases_its_units():
    m = pulses_muscle()
    m.run_pulses([0.0], [0], [0.5], np.zeros(2500), 1e-3)
    assert m.n_recruited == 0
    assert m.activation[0] < m.params.release_activation


def test_a_channel_keeps_its_units_between_pulses():
    m = pulses_muscle()
    m.run_pulses([0.0], [0], [0.5], np.zeros(900), 1e-3)
    assert m.n_recruited == 500


def test_a_command_a_rehastim2_refuses_is_rejected_by_field_and_channel_and_the_last_kept():
    m = pulses_muscle(stimulator='rehastim2', channel_fractions=(1.0, 1.0))
    m.stimulate([constant_train(1, pw=300e-6, f=25.0)])
    with pytest.raises(ValueError, match='`pulse_width_s` of channel 2 must be .* on rehastim2, '
                                         'got 0.0006'):
        m.stimulate([constant_train(1, pw=200e-6, f=25.0), constant_train(2, pw=600e-6, f=25.0)])
    with pytest.raises(ValueError, match='`current_a` of channel 1 must be in \\[0, 0.13\\] A on '
                                         'rehastim2, got 0.14'):
        m.stimulate([constant_train(1, pw=200e-6, f=25.0, current=0.140)])
    m.run_trains(np.zeros(10), 1e-3)
    assert m.n_recruited == round(1000 / 2 * 300e-6 / 500e-6)   # the first command's


@pytest.mark.parametrize('build', ['python', 'compiled'])
@settings(max_examples=25, deadline=None)
@given(dt=st.sampled_from([2e-4, 3e-4, 7e-4, 1e-3]),
       runs=st.lists(st.integers(1, 60), min_size=1, max_size=4))
def test_a_command_after_any_run_of_the_trains_is_taken_at_the_muscles_instant(build, dt, runs):
    # The muscle's clock is a sum of steps; the trains must stand exactly there:
    # 24 steps of 0.2 ms end at 0.0048 s, and a command then was refused with
    # "`t1_s` must be >= 0.0048000000000000004 s" (the trains at t + n dt).
    m = pulses_muscle(build)
    m.stimulate([constant_train(1, pw=250e-6)])
    for k, n in enumerate(runs):
        m.run_trains(np.zeros(n), dt)
        m.stimulate([constant_train(1, pw=200e-6 + 10e-6 * k)])
    assert m.t_s == pytest.approx(sum(runs) * dt, rel=1e-12)


def test_a_channel_beyond_the_muscles_is_rejected():
    m = pulses_muscle(channel_fractions=(1.0, 1.0))
    with pytest.raises(ValueError, match='`channel` must be in \\[1, 2\\]'):
        m.stimulate([constant_train(3)])


@pytest.mark.parametrize('frequency_hz', [0.0, -5.0])
def test_a_train_without_a_positive_frequency_is_rejected_at_once_and_the_last_kept(
        frequency_hz):
    # Rejected by the command, not later when the train's first burst reads 1/f.
    m = pulses_muscle(channel_fractions=(1.0, 1.0))
    m.stimulate([constant_train(1, pw=300e-6, f=25.0)])
    with pytest.raises(ValueError, match=f'`frequency_hz` of channel 2 must be .*'
                                         f'got {frequency_hz!r}'):
        m.stimulate([constant_train(1, pw=200e-6, f=25.0),
                     constant_train(2, pw=300e-6, f=frequency_hz)])
    m.run_trains(np.zeros(10), 1e-3)
    assert m.n_recruited == round(1000 / 2 * 300e-6 / 500e-6)   # the first command's


def test_the_plain_pulse_width_is_channel_1_at_frequency_hz():
    m = pulses_muscle(frequency_hz=20.0)
    m.set_pulse_width(250e-6)
    out, _ = m.run_trains(np.zeros(1000), 1e-3)
    rises = np.flatnonzero(np.diff(out[:, 9]) > 0.5)   # Eff.f_iso jumps at each pulse's CN rise
    assert m.n_recruited == 500
    ref = pulses_muscle()
    ref.stimulate([constant_train(1, pw=250e-6, f=20.0)])
    out_ref, _ = ref.run_trains(np.zeros(1000), 1e-3)
    assert out[:, 8] == pytest.approx(out_ref[:, 8], abs=1e-12)
    assert len(rises) > 0


def test_a_ding_muscle_takes_no_recruitment_command():
    m = pulses_muscle()
    with pytest.raises(ValueError, match='driven by pulses'):
        m.step(0.5, 0.0, 1e-3)
    with pytest.raises(ValueError, match='driven by pulses'):
        m.set_recruitment(0.5)


def test_a_first_order_muscle_refuses_pulses_and_pulse_protocols():
    m = Muscle(MuscleParams())
    with pytest.raises(ValueError, match='`stimulate` needs `activation_model: ding2003`'):
        m.stimulate([constant_train()])
    protocol = PulseProtocol.from_mapping({
        'name': 'p', 'duration_s': 0.1, 'dl_mt_m': [[0.0, 0.0]],
        'channels': [{'frequency_hz': [[0.0, 20.0]], 'pulse_width_s': [[0.0, 2e-4]]}]})
    with pytest.raises(ValueError, match='needs `activation_model: ding2003`'):
        simulate(protocol, MuscleParams())


def test_a_pulse_protocol_beyond_the_stimulators_range_is_refused_naming_channel_and_time():
    protocol = PulseProtocol.from_mapping({
        'name': 'too wide', 'duration_s': 0.2, 'dl_mt_m': [[0.0, 0.0]],
        'channels': [{'frequency_hz': [[0.0, 20.0]],
                      'pulse_width_s': [[0.0, 2e-4], [0.1, 2e-4], [0.1, 6e-4]]}]})
    with pytest.raises(ValueError, match='at t = 0.1 s: `pulse_width_s` of channel 1 must be'):
        simulate(protocol, MuscleParams(**DING, stimulator='rehastim2'))


def test_higher_frequency_tires_the_recruited_units_faster():
    def fitness_after(f):
        m = pulses_muscle(fatigue='riener')
        m.stimulate([constant_train(pw=500e-6, f=f)])
        m.run_trains(np.zeros(10_000), 1e-3)
        return m.mean_fitness
    assert fitness_after(50.0) < fitness_after(20.0) < 1.0


def test_fatigue_at_full_activation_matches_rieners_law_per_unit():
    """At a very high frequency a_c stays near its plateau: the recruited units'
    fitness follows Riener's law at that a, mu_inf + (1 - mu_inf) e^(-lambda t)."""
    m = pulses_muscle(fatigue='riener', tau_fatigue_s=(5.0,), tau_recovery_s=(10.0,))
    m.stimulate([constant_train(pw=500e-6, f=150.0)])
    _, act = m.run_trains(np.zeros(3000), 1e-3)
    a = float(np.mean(act[1000:, 0]))   # near-constant after the rise
    fitness_at_1s = m.fitness_profile()
    assert np.ptp(fitness_at_1s) < 1e-12   # one history for every unit
    lam = a / 5.0 + (1 - a) / 10.0
    mu_inf = (0.2 * a / 5.0 + (1 - a) / 10.0) / lam
    # The first second's rise is the only difference: bound it by the law at
    # a = 0 and a = plateau over the whole 3 s.
    assert mu_inf + (1 - mu_inf) * np.exp(-lam * 3.0) <= fitness_at_1s[0] <= 1.0
    assert fitness_at_1s[0] == pytest.approx(mu_inf + (1 - mu_inf) * np.exp(-lam * 2.9), abs=5e-3)


def test_the_compiled_and_plain_builds_agree_on_two_channels_with_fatigue_to_1e9():
    changes = dict(channel_fractions=(1.0, 2.0), fatigue='riener', fibre_fractions=(1.0, 1.0),
                   recruitment_order='random', unit_length_spread=0.2, n_units=300)
    runs = []
    for build in (engine.COMPILED, engine.PYTHON):
        m = pulses_muscle(build=build, **changes)
        m.stimulate([constant_train(1, pw=300e-6, f=40.0, mode='doublet'),
                     constant_train(2, pw=150e-6, f=25.0, current=0.05)])
        out, act = m.run_trains(np.linspace(0.0, 0.01, 800), 1e-3)
        runs.append((out, act))
    assert runs[0][0] == pytest.approx(runs[1][0], abs=1e-9)
    assert runs[0][1] == pytest.approx(runs[1][1], abs=1e-9)


def test_simulate_writes_one_activation_column_per_channel_to_the_csv(tmp_path):
    params = tmp_path / 'ding.yaml'
    params.write_text('/**:\n  ros__parameters:\n    activation_model: ding2003\n'
                      '    channel_fractions: [1.0, 1.0, 1.0, 1.0]\n', encoding='utf-8')
    # The shipped four-channel file cut to its first second (its 180 s took
    # 3 CPU-s): the columns are one per channel whatever the length. The
    # command's entry function in this process (test_cli.py runs the console
    # script of `simulate` itself).
    doc = yaml.safe_load((REPO / 'config' / 'protocols' / 'sdss_four_channels.yaml')
                         .read_text(encoding='utf-8'))
    assert len(doc['channels']) == 4
    protocol = tmp_path / 'sdss_four_channels_1s.yaml'
    protocol.write_text(yaml.safe_dump({**doc, 'duration_s': 1.0}), encoding='utf-8')
    out = tmp_path / 'run.csv'
    assert cli.main(['simulate', '--protocol', str(protocol), '--params', str(params),
                     '--csv', str(out)]) == 0
    with out.open(encoding='utf-8') as f:
        header = next(csv.reader(f))
    assert header[-4:] == ['a_1', 'a_2', 'a_3', 'a_4']


def test_a_batch_of_muscles_refuses_a_pulse_driven_muscle_by_index():
    from hill_muscle_ros.model.muscle.batch import MuscleBatch
    with pytest.raises(ValueError, match='`params\\[1\\]` must have `activation_model: first_order`'):
        MuscleBatch([MuscleParams(), MuscleParams(**DING)])
