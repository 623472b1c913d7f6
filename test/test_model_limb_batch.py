"""LimbBatch: K limbs stepped together against K separate limbs.

The reference for limb k of a batch is a ``Limb(plants[k])`` of its own,
driven with the commands of its pulse widths through its own muscles'
recruitment curves, or :func:`~hill_muscle_ros.model.limb.simulate_limb` with
``plants[k]``. The plants are the shipped knee and ankle presets with muscle and
joint parameters changed per limb, so that a limb or muscle taken for another
shows; both presets have delay, activation and fatigue on.
"""
import dataclasses

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hill_muscle_ros.model import LimbBatch, simulate_limb_batch
from hill_muscle_ros.model.limb import Limb, LimbProtocol, simulate_limb
from hill_muscle_ros.model.stimulus import command_from_pulse_width
from hill_muscle_ros.params_file import load_plant
from hill_muscle_ros.resources import config_dir

#: [rad] / [N] bound on batch vs separate runs (the brief asks 1e-9).
ATOL_RAD = 1e-9
ATOL_N = 1e-9
#: [s] step of the random runs (the presets' 1 kHz).
DT_S = 1e-3
#: [s] widest pulse drawn: the presets' PW_max (600 us).
PW_MAX_S = 6e-4
PRESETS = {name: load_plant(config_dir() / f'{name}.yaml')[0] for name in ('knee', 'ankle')}


def varied(plant, f_scale: float, k_se_scale: float, stiffness_scale: float,
           theta0_offset_rad: float):
    """The preset with every muscle's f_iso_max and k_SE and the joint's K scaled,
    and the initial angle moved."""
    muscles = tuple(dataclasses.replace(m, params=dataclasses.replace(
        m.params, f_iso_max_n=m.params.f_iso_max_n * f_scale,
        k_se_n_per_m=m.params.k_se_n_per_m * k_se_scale)) for m in plant.muscles)
    joint = dataclasses.replace(
        plant.joint, stiffness_n_m_per_rad=plant.joint.stiffness_n_m_per_rad * stiffness_scale,
        initial_angle_rad=plant.joint.initial_angle_rad + theta0_offset_rad)
    return dataclasses.replace(plant, joint=joint, muscles=muscles)


@st.composite
def limb_runs(draw):
    """A preset, K varied plants, and per step: pulse widths (steps, K, M),
    external torques (steps, K), and whether the next sample's widths are given
    at the sample instant (as simulate_limb does) or only with the step."""
    preset = PRESETS[draw(st.sampled_from(sorted(PRESETS)))]
    k = draw(st.integers(1, 3))
    plants = [varied(preset, draw(st.floats(0.5, 1.5)), draw(st.floats(0.5, 2.0)),
                     draw(st.floats(0.5, 2.0)), draw(st.floats(-0.2, 0.2)))
              for _ in range(k)]
    n_steps = draw(st.integers(20, 150))
    m = len(preset.muscles)
    pw = np.empty((n_steps, k, m))
    for limb in range(k):
        for muscle in range(m):
            # Piecewise constant: a few switches at random steps, widths across
            # the curve (below threshold, rising, saturated).
            switches = sorted(draw(st.lists(st.integers(0, n_steps - 1), max_size=4)))
            widths = draw(st.lists(st.floats(0.0, PW_MAX_S), min_size=len(switches) + 1,
                                   max_size=len(switches) + 1))
            pw[:, limb, muscle] = widths[0]
            for s, w in zip(switches, widths[1:]):
                pw[s:, limb, muscle] = w
    torque = np.array(draw(st.lists(st.floats(-5.0, 5.0), min_size=k, max_size=k)))
    at_sample = draw(st.booleans())
    return plants, pw, np.broadcast_to(torque, (n_steps, k)), at_sample


@settings(max_examples=12, deadline=None)
@given(limb_runs())
def test_batch_equals_separate_limbs_to_1e_9_on_random_settings_and_pulse_widths(run):
    plants, pw, torque, at_sample = run
    batch = LimbBatch(plants)
    limbs = [Limb(p) for p in plants]

    def commands(k: int, j: int) -> list[float]:
        return [command_from_pulse_width(pw[j, k, i], m.params)
                for i, m in enumerate(plants[k].muscles)]

    for j in range(len(pw)):
        out = batch.step(pw[j], torque[j], DT_S)
        if at_sample and j + 1 < len(pw):
            batch.set_pulse_widths(pw[j + 1])
            out = batch.outputs()
        for k, limb in enumerate(limbs):
            want = limb.step(commands(k, j), float(torque[j, k]), DT_S)
            if at_sample and j + 1 < len(pw):
                limb.give_commands(commands(k, j + 1))   # each that differs, now
                want = limb.outputs()
            assert out.t_s == pytest.approx(want.t_s, abs=1e-15)
            assert abs(out.theta_rad[k] - want.theta_rad) <= ATOL_RAD
            assert abs(out.omega_rad_per_s[k] - want.omega_rad_per_s) <= ATOL_RAD
            np.testing.assert_allclose(out.force_n[k], want.force_n, rtol=0, atol=ATOL_N)
            np.testing.assert_allclose(out.l_ce_m[k], want.l_ce_m, rtol=0, atol=1e-12)
            np.testing.assert_array_equal(out.command[k], want.command)
            np.testing.assert_array_equal(out.recruitment[k], want.recruitment)


def _assert_batch_runs_each_plant_as_simulate_limb(plants, proto, rate_hz, indices):
    """simulate_limb_batch's angles and forces at ``indices`` are each plant's
    simulate_limb's, to 1e-9."""
    theta, force = simulate_limb_batch(plants, proto, rate_hz, indices)
    assert theta.shape == (len(plants), len(indices))
    assert force.shape == (len(plants), 2, len(indices))
    for k, plant in enumerate(plants):
        want = simulate_limb(plant, proto, rate_hz)
        np.testing.assert_allclose(theta[k], want['theta_rad'][indices], rtol=0, atol=ATOL_RAD)
        for i, m in enumerate(plant.muscles):
            np.testing.assert_allclose(force[k, i], want[f'{m.name}_force_n'][indices],
                                       rtol=0, atol=ATOL_N)
    return theta


@pytest.mark.parametrize('preset, protocol', [
    ('knee', 'knee_ramp.yaml'), ('knee', 'knee_extension.yaml')])
def test_simulate_limb_batch_equals_simulate_limb_per_plant(preset, protocol):
    plants = [varied(PRESETS[preset], f, s, kj, 0.0)
              for f, s, kj in ((1.0, 1.0, 1.0), (0.6, 1.7, 1.0), (1.3, 0.8, 2.0))]
    proto = LimbProtocol.from_yaml(config_dir() / 'protocols' / protocol)
    # Every 250 ms to 2.5 s: the ramp's recruitment and the extension's rise.
    theta = _assert_batch_runs_each_plant_as_simulate_limb(plants, proto, 1000.0,
                                                            list(range(0, 2501, 250)))
    # The plants do differ: a batch that ran one plant K times would fail above.
    assert np.ptp(theta[:, -1]) > 0.05


def test_simulate_limb_batch_below_1_khz_takes_the_substeps_of_simulate_limb():
    # At 100 Hz each step is ten substeps of 1 ms with the sample's inputs held,
    # as simulate_limb (and Limb.step) takes it: the same angles and forces
    # (one step of 10 ms was 3e-4 rad and 1.4 N off on this ramp).
    plants = [varied(PRESETS['knee'], f, 1.0, 1.0, 0.0) for f in (1.0, 0.7)]
    proto = LimbProtocol.from_yaml(config_dir() / 'protocols' / 'knee_ramp.yaml')
    # The 7 s ramp, every quarter second.
    theta = _assert_batch_runs_each_plant_as_simulate_limb(plants, proto, 100.0,
                                                            list(range(0, 701, 25)))
    assert np.ptp(theta[:, -1]) > 0.01


def test_plants_with_other_muscles_are_refused_by_name():
    with pytest.raises(ValueError, match=r"`plants\[1\]` must have the muscles of "
                                         r"`plants\[0\]`, \['quadriceps', 'hamstrings'\]"):
        LimbBatch([PRESETS['knee'], PRESETS['ankle']])


def test_no_plants_is_refused():
    with pytest.raises(ValueError, match='at least one LimbPlant'):
        LimbBatch([])


def test_a_plant_that_is_not_a_limb_plant_is_refused_by_index():
    with pytest.raises(ValueError, match=r"`plants\[1\]` must be a LimbPlant, got 'knee'"):
        LimbBatch([PRESETS['knee'], 'knee'])


@pytest.mark.parametrize('kwargs, message', [
    ({'pulse_width_s': [[0.0, -1e-4], [0.0, 0.0]]},
     r'`pulse_width_s\[0, 1\] \(hamstrings\)` must be finite and non-negative, got -0.0001'),
    ({'pulse_width_s': np.zeros((3, 2))},
     r'`pulse_width_s` must have shape \(2, 2\) \(limbs, muscles\), got \(3, 2\)'),
    ({'external_torque_n_m': [0.0, float('nan')]},
     r'`external_torque_n_m\[1\]` must be finite and within ±10000 N m, got nan'),
    ({'dt_s': 0.0}, r'`dt_s` must be positive and finite, got 0.0'),
])
def test_bad_input_names_the_limb_and_muscle_and_moves_no_limb(kwargs, message):
    batch = LimbBatch([PRESETS['knee'], PRESETS['knee']])
    batch.step(3e-4, 0.0, DT_S)
    before = batch.outputs()
    args = {'pulse_width_s': 3e-4, 'external_torque_n_m': 0.0, 'dt_s': DT_S, **kwargs}
    with pytest.raises(ValueError, match=message):
        batch.step(**args)
    after = batch.outputs()
    assert after.t_s == before.t_s
    np.testing.assert_array_equal(after.theta_rad, before.theta_rad)
    np.testing.assert_array_equal(after.l_ce_m, before.l_ce_m)


def test_command_outside_0_1_names_the_limb_and_muscle():
    batch = LimbBatch([PRESETS['ankle']] * 2)
    with pytest.raises(ValueError, match=r'`commands\[1, 0\]` \(tibialis_anterior\) '
                                         r'must be in \[0, 1\], got 1.5'):
        batch.step_commands([[0.2], [1.5]], 0.0, DT_S)


def test_limb_driven_beyond_its_muscles_range_is_named():
    # 1e4 N m on the 0.0197 kg m^2 foot turns it tens of radians within
    # tens of steps: its muscle's MTU passes 1 m.
    batch = LimbBatch([PRESETS['ankle']] * 2)
    with pytest.raises(ValueError, match=r'^limb 1: muscle `tibialis_anterior` is stretched'):
        for _ in range(1000):
            batch.step(0.0, [0.0, 1e4], DT_S)
