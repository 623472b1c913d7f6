"""A compiled Muscle against the same Muscle on the plain Python functions.

Step by step as the simulator node steps it: random FES features (each
strategy of test_fes_compiled), random commands and MTU lengths, a reset
part-way; every output of every step, and the outputs read between steps,
agree to 1e-9 (N, m, m/s). Bad inputs raise the same errors on both builds
and leave the state as it was.
"""
import math

import numpy as np
import pytest
from hypothesis import example, given, strategies as st

from engines import compiled, plain
from hill_muscle_ros.model.muscle import DL_MT_LIMIT_M
from hill_muscle_ros.model.params import MuscleParams
from test_fes_compiled import (PINNED, SETTINGS, TOL, delay_activation_params, fatigue_params,
                               fibre_type_params, pinned_protocol, protocols, relative_params,
                               spread_params)

any_fes_params = st.one_of(delay_activation_params(), fatigue_params(), fibre_type_params(),
                           spread_params(), relative_params())

#: A muscle with most FES features on, for the error tests.
FES_PARAMS = MuscleParams(n_units=40, emd_s=0.0123, tau_act_s=0.025, tau_deact_s=0.028,
                          fatigue='riener', fv_scaling='relative')


def _gap(a, b) -> float:
    """Largest difference between two MuscleOutputs."""
    return max(abs(x - y) for x, y in zip(a, b))


@SETTINGS
@given(params=any_fes_params, protocol=protocols(), reset_at=st.floats(0.0, 1.0))
@example(params=PINNED['fatigue'], protocol=pinned_protocol(1e-3), reset_at=0.5)
def test_each_compiled_step_matches_the_plain_build_across_a_reset(params, protocol, reset_at):
    r_start, _, dl, dt = protocol
    reset_step = int(reset_at * len(dl))
    ref, got = plain(params), compiled(params)
    for k, (r, d) in enumerate(zip(r_start.tolist(), dl.tolist())):
        if k == reset_step:
            ref.reset()
            got.reset()
            assert _gap(got.outputs(), ref.outputs()) <= TOL
        a, b = ref.step(r, d, dt), got.step(r, d, dt)
        assert type(b.n_recruited) is int
        assert _gap(b, a) <= TOL, (k, a, b)
        assert abs(got.dl_mt_m - ref.dl_mt_m) <= TOL
    assert _gap(got.outputs(), ref.outputs()) <= TOL


BAD_STEPS = [(math.nan, 0.0, 1e-3), (1.5, 0.0, 1e-3), (-0.1, 0.0, 1e-3),
             (0.5, math.inf, 1e-3), (0.5, 2.0 * DL_MT_LIMIT_M, 1e-3), (0.5, 0.0, 0.0),
             (0.5, 0.0, -1e-3), (0.5, 0.0, math.nan), (math.nan, math.nan, math.nan)]


@pytest.mark.parametrize('args', BAD_STEPS)
def test_a_bad_step_raises_the_same_error_on_both_builds_and_changes_nothing(args):
    ref, got = plain(FES_PARAMS), compiled(FES_PARAMS)
    for _ in range(30):
        ref.step(0.7, 0.001, 1e-3)
        got.step(0.7, 0.001, 1e-3)
    before = got.outputs()
    with pytest.raises(ValueError) as expected:
        ref.step(*args)
    with pytest.raises(ValueError) as raised:
        got.step(*args)
    assert str(raised.value) == str(expected.value)
    assert got.outputs() == before
    assert _gap(got.step(0.2, 0.0, 1e-3), ref.step(0.2, 0.0, 1e-3)) <= TOL


def test_the_knee_quadriceps_preset_releases_alike_on_both_builds():
    """1000 units, every feature: pulse widths up through the curve, then 0."""
    from hill_muscle_ros.params_file import load_muscle_params
    from hill_muscle_ros.resources import config_dir
    from hill_muscle_ros.model.stimulus import command_from_pulse_width
    params = load_muscle_params(config_dir() / 'fes_quadriceps.yaml')[0]
    ref, got = plain(params), compiled(params)
    u = [command_from_pulse_width(f * params.pw_max_s, params)
         for f in np.repeat([0.25, 0.5, 1.0], 100)] + [0.0] * 300
    for k, r in enumerate(u):
        assert _gap(got.step(r, 0.0, 1e-3), ref.step(r, 0.0, 1e-3)) <= TOL, k
    assert ref.n_recruited == 0 and got.outputs().n_recruited == 0   # released
