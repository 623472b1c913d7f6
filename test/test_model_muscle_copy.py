"""``copy.deepcopy(muscle)``: a muscle in the same state that goes on as the
original would, to the last bit, on the build it was made on, and apart from it.

The fit's edge search replays a recording's moves of one stimulation change from
a copy of the muscle saved before the change (test_fit); these tests are the
copy's side of that: random FES muscles (delay, activation, fatigue, fibre
types, recruitment orders) and pulse-driven ``ding2003`` muscles, random
protocols, both builds of the kernels.
"""
import copy

import numpy as np
import pytest
from hypothesis import assume, given, settings, strategies as st

from hill_muscle_ros.model import Muscle, MuscleParams
from hill_muscle_ros.model.engine import COMPILED, PYTHON
from hill_muscle_ros.model.stimulator import ChannelCommand

# One part of a protocol: commands held 1-20 steps (through 0 and 1), some
# given at a step's end too, dl_MT a random walk of a few mm, dt 0.2-2 ms.
from test_fes_compiled import protocols as command_runs

#: Hypothesis examples per test and build: the plain build stays quick with at
#: most MAX_UNITS units and 200 steps a part.
EXAMPLES = 20
#: The most units of a random muscle: a copy's per-unit state is an array
#: whatever its length, and 40 units already spread over three fibre types and
#: every channel; 150 made the plain build 7 times slower beside make test's
#: ROS run (10.5 s).
MAX_UNITS = 40
BUILDS = [PYTHON, COMPILED]


def _params(**fields):
    try:
        return MuscleParams(**fields)
    except ValueError:   # a combination the parameters refuse: not a muscle
        assume(False)


@st.composite
def fes_params(draw):
    """Any recruitment-driven muscle: the paper's four variants and every FES
    feature that gives it state (delay line, activation, fatigue, fibre types)."""
    units = draw(st.sampled_from(['multi', 'single']))
    k = draw(st.integers(1, 3)) if units == 'multi' else 1
    return _params(units=units, length=draw(st.sampled_from(['initial', 'instantaneous'])),
                   n_units=draw(st.integers(3, MAX_UNITS)),
                   emd_s=draw(st.sampled_from([0.0, 0.0005, 0.0123])),
                   tau_act_s=draw(st.sampled_from([0.0, 0.004, 0.025])),
                   tau_deact_s=draw(st.sampled_from([0.0, 0.006, 0.028])),
                   fatigue=draw(st.sampled_from(['none', 'riener'])),
                   fatigue_min=tuple(draw(st.floats(0.0, 0.9)) for _ in range(k)),
                   tau_fatigue_s=tuple(draw(st.sampled_from([0.05, 0.5, 30.0]))
                                       for _ in range(k)),
                   tau_recovery_s=tuple(draw(st.sampled_from([0.08, 1.0, 50.0]))
                                        for _ in range(k)),
                   fibre_fractions=tuple(draw(st.floats(0.1, 1.0)) for _ in range(k)),
                   recruitment_order=draw(st.sampled_from(['size', 'reverse', 'random'])),
                   recruitment_seed=draw(st.integers(0, 5)))


def _same_outputs(a, b):
    """Two muscles' outputs now, equal to the last bit (NaN where the other has NaN:
    a channel given no unit has no mean fitness)."""
    np.testing.assert_array_equal(np.array(a.outputs()), np.array(b.outputs()), strict=True)


def _run(muscle, part):
    r_start, r_end, dl, dt = part
    return muscle.run_array(r_start, dl, dt, r_end)


@pytest.mark.parametrize('build', BUILDS)
@settings(max_examples=EXAMPLES)
@given(params=fes_params(), before=command_runs(), after=command_runs())
def test_a_copied_muscle_steps_exactly_as_the_original(build, params, before, after):
    # ``after`` may take a shorter step than ``before``: the copy's delay line
    # then grows on its own, as the original's does.
    muscle = Muscle(params, build=build)
    _run(muscle, before)
    twin = copy.deepcopy(muscle)
    assert twin.build == build
    _same_outputs(twin, muscle)
    np.testing.assert_array_equal(_run(twin, after), _run(muscle, after), strict=True)
    _same_outputs(twin, muscle)
    if params.units == 'multi':
        np.testing.assert_array_equal(twin.fitness_profile(), muscle.fitness_profile())


@pytest.mark.parametrize('build', BUILDS)
def test_stepping_a_copy_leaves_the_original_as_it_was(build):
    params = MuscleParams(emd_s=0.0123, tau_act_s=0.025, tau_deact_s=0.028, fatigue='riener',
                          fibre_fractions=(0.5, 0.5), tau_fatigue_s=(4.0, 0.8),
                          tau_recovery_s=(8.0, 2.0), fatigue_min=(0.2, 0.1),
                          recruitment_order='random', n_units=120)
    before = (np.resize([0.3, 0.8, 0.0, 0.6], 300), None, np.linspace(0.0, 0.008, 300), 1e-3)
    after = (np.resize([0.9, 0.1], 200), None, np.linspace(0.008, -0.004, 200), 1e-3)
    muscle, untouched = Muscle(params, build=build), Muscle(params, build=build)
    _run(muscle, before)
    _run(untouched, before)
    twin = copy.deepcopy(muscle)
    # The copy is driven elsewhere, with a shorter step (its delay line grows) ...
    _run(twin, (np.ones(400), None, np.full(400, -0.01), 2e-4))
    twin.set_recruitment(0.0)
    # ... and the original goes on exactly as a muscle never copied.
    assert muscle.outputs() == untouched.outputs() != twin.outputs()
    np.testing.assert_array_equal(_run(muscle, after), _run(untouched, after), strict=True)
    np.testing.assert_array_equal(muscle.fitness_profile(), untouched.fitness_profile())


# --------------------------------------------------------------------------- ding2003

@st.composite
def pulsed_params(draw):
    channels = draw(st.integers(1, 3))
    return _params(activation_model='ding2003', f_iso_max_n=333.87,
                   n_units=draw(st.integers(channels, MAX_UNITS)),
                   channel_fractions=tuple(draw(st.floats(0.2, 1.0)) for _ in range(channels)),
                   emd_s=draw(st.sampled_from([0.0, 0.0123, 0.031])),
                   fatigue=draw(st.sampled_from(['none', 'riener'])))


@st.composite
def train_runs(draw, n_channels):
    """One part of a pulse protocol: a command to some channels (single pulses or
    doublets at 10-60 Hz), then steps of 0.2-1 ms with dl_MT wandering."""
    commands = [ChannelCommand(c, draw(st.sampled_from(['single', 'doublet'])),
                               draw(st.sampled_from([0.0, 100e-6, 250e-6, 500e-6])), None,
                               draw(st.sampled_from([10.0, 33.0, 60.0])))
                for c in range(1, n_channels + 1) if draw(st.booleans())]
    steps = draw(st.integers(1, 200))
    rng = np.random.default_rng(draw(st.integers(0, 2 ** 32 - 1)))
    dl = np.clip(np.cumsum(rng.normal(0.0, 5e-4, steps)), -0.03, 0.03)
    return commands, dl, draw(st.sampled_from([2e-4, 3e-4, 5e-4, 1e-3]))


def _run_trains(muscle, part):
    commands, dl, dt = part
    if commands:
        muscle.stimulate(commands)
    return muscle.run_trains(dl, dt)


@pytest.mark.parametrize('build', BUILDS)
@settings(max_examples=EXAMPLES)
@given(data=st.data())
def test_a_copied_pulsed_muscle_steps_exactly_as_the_original(build, data):
    # Copied mid-train with pulses sent and not yet acting (emd_s > 0): the copy
    # has the trains and the pending pulses too.
    params = data.draw(pulsed_params())
    muscle = Muscle(params, build=build)
    _run_trains(muscle, data.draw(train_runs(params.n_channels)))
    twin = copy.deepcopy(muscle)
    assert twin.build == build
    np.testing.assert_array_equal(twin.activation, muscle.activation)
    after = data.draw(train_runs(params.n_channels))
    for got, want in zip(_run_trains(twin, after), _run_trains(muscle, after)):
        np.testing.assert_array_equal(got, want, strict=True)
    _same_outputs(twin, muscle)


@pytest.mark.parametrize('build', BUILDS)
def test_stimulating_a_pulsed_copy_leaves_the_original_as_it_was(build):
    params = MuscleParams(activation_model='ding2003', f_iso_max_n=333.87, emd_s=0.031,
                          channel_fractions=(1.0, 1.0), fatigue='riener', n_units=100)
    train = [ChannelCommand(1, 'single', 250e-6, None, 33.0)]
    muscle, untouched = Muscle(params, build=build), Muscle(params, build=build)
    for m in (muscle, untouched):
        m.stimulate(train)
        m.run_trains(np.zeros(120), 1e-3)
    twin = copy.deepcopy(muscle)
    twin.stimulate([ChannelCommand(1, 'doublet', 500e-6, None, 60.0),
                    ChannelCommand(2, 'single', 400e-6, None, 20.0)])
    twin.run_trains(np.full(150, 0.005), 1e-3)
    np.testing.assert_array_equal(muscle.activation, untouched.activation)
    for got, want in zip(muscle.run_trains(np.zeros(200), 1e-3),
                         untouched.run_trains(np.zeros(200), 1e-3)):
        np.testing.assert_array_equal(got, want, strict=True)
