"""The paper's claims about the four model variants, as assertions.

Variants: ``units`` single | multi and ``length`` initial | instantaneous.
"""
import itertools
import math

import numpy as np
import pytest
from scipy.optimize import brentq

from hill_muscle_ros.model import Muscle, MuscleParams, Protocol, simulate
from hill_muscle_ros.model.equations import force_length

from reference import reference_force

VARIANTS = [MuscleParams(units=u, length=l)
            for u, l in itertools.product(('single', 'multi'), ('initial', 'instantaneous'))]
VARIANT_IDS = [f'{p.units}-{p.length}' for p in VARIANTS]
P = MuscleParams()


@pytest.fixture(scope='module')
def protocols(protocol_paths):
    return {k: Protocol.from_yaml(v) for k, v in protocol_paths.items()}


@pytest.fixture(scope='module')
def runs(protocols):
    """Every protocol in every variant at the default 1 kHz."""
    return {(name, p.units, p.length): simulate(proto, p)
            for name, proto in protocols.items() for p in VARIANTS}


def hold(muscle, r, dl, seconds, dt=1e-3):
    out = None
    for _ in range(int(round(seconds / dt))):
        out = muscle.step(r, dl, dt)
    return out


# -- rest, passive and free states ---------------------------------------------

@pytest.mark.parametrize('params', VARIANTS, ids=VARIANT_IDS)
def test_rest_state_carries_no_force(params):
    out = Muscle(params).outputs()
    assert (out.l_ce_m, out.force_n, out.f_se_n, out.f_pe_n) == (P.l_rest_m, 0.0, 0.0, 0.0)


@pytest.mark.parametrize('params', VARIANTS, ids=VARIANT_IDS)
def test_unrecruited_muscle_is_purely_passive(params):
    m = Muscle(params)
    out = hold(m, 0.0, 0.01, 0.2)
    assert out.f_se_n == 0.0
    assert out.l_ce_m == pytest.approx(P.l_rest_m + 0.01, abs=1e-15)
    assert out.force_n == pytest.approx(P.k_pe_n_per_m * 0.01, rel=1e-12)


@pytest.mark.parametrize('params', VARIANTS, ids=VARIANT_IDS)
def test_de_recruitment_frees_the_ce_at_once(params):
    m = Muscle(params)
    hold(m, 1.0, 0.005, 1.0)
    out = m.step(0.0, 0.005, 1e-3)
    assert out.f_se_n == 0.0 and out.eff_f_iso_n == 0.0
    assert out.l_ce_m == pytest.approx(P.l_rest_m + 0.005)


# -- analytic steady states ------------------------------------------------------

def test_protocol_I_first_second_reaches_model_md_steady_state(runs):
    """doc/model.md section 6: f_se = f_iso_max FL(1.25) = 37.19 N at 1 s (initial length)."""
    f_expected = P.f_iso_max_n * force_length(P.l_rest_m / P.l_opt_m)
    for units in ('single', 'multi'):
        run = runs[('I', units, 'initial')]
        i = run.at(1.0)
        assert run.f_se_n[i] == pytest.approx(f_expected, abs=0.01)
        assert run.l_ce_m[i] == pytest.approx(P.l_rest_m - run.f_se_n[i] / P.k_se_n_per_m,
                                               abs=1e-15)


@pytest.mark.parametrize('r', [0.25, 0.5, 1.0])
@pytest.mark.parametrize('params', VARIANTS[::2], ids=VARIANT_IDS[::2])
def test_isometric_initial_length_converges_to_r_times_fl_at_rest(params, r):
    out = hold(Muscle(params), r, 0.0, 4.0)
    f_exact = r * P.f_iso_max_n * force_length(P.l_rest_m / P.l_opt_m)
    assert out.f_se_n == pytest.approx(f_exact, abs=1e-9)
    assert out.l_ce_m == pytest.approx(P.l_rest_m - f_exact / P.k_se_n_per_m, abs=1e-12)
    assert out.v_ce_m_per_s == pytest.approx(0.0, abs=1e-9)


@pytest.mark.parametrize('r', [0.25, 0.5, 1.0])
@pytest.mark.parametrize('params', VARIANTS[1::2], ids=VARIANT_IDS[1::2])
def test_isometric_instantaneous_length_converges_to_the_fl_fixed_point(params, r):
    """f = R f_iso_max FL((l_rest - f / k_se) / l_opt), solved independently."""
    def residual(f):
        return f - r * P.f_iso_max_n * force_length((P.l_rest_m - f / P.k_se_n_per_m) / P.l_opt_m)
    f_exact = brentq(residual, 0.0, P.f_iso_max_n, xtol=1e-14)
    out = hold(Muscle(params), r, 0.0, 4.0)
    assert out.f_se_n == pytest.approx(f_exact, abs=1e-9)


@pytest.mark.parametrize('params', VARIANTS, ids=VARIANT_IDS)
def test_stretched_passive_plus_active_steady_state(params):
    """Held stretched: force = f_se + k_pe dl with f_se at its isometric value."""
    dl = 0.004
    m = Muscle(params)
    hold(m, 0.0, dl, 0.01)  # stretch the passive muscle first: l_ce = l_rest + dl
    out = hold(m, 1.0, dl, 5.0)
    assert out.f_pe_n == pytest.approx(P.k_pe_n_per_m * dl)
    assert out.force_n == pytest.approx(out.f_se_n + out.f_pe_n, abs=1e-12)
    if params.length == 'initial':
        f_exact = P.f_iso_max_n * force_length((P.l_rest_m + dl) / P.l_opt_m)
        assert out.f_se_n == pytest.approx(f_exact, abs=1e-9)


# -- accuracy against a fine-step reference --------------------------------------

@pytest.mark.parametrize('name', ['I', 'II'])
@pytest.mark.parametrize('params', VARIANTS, ids=VARIANT_IDS)
def test_one_millisecond_step_is_within_10_mN_of_the_reference(protocols, runs, name, params):
    run = runs[(name, params.units, params.length)]
    ref = reference_force(protocols[name], params, run.t_s)
    err = np.max(np.abs(run.force_n - ref))
    assert err <= 0.01, f'max |force - reference| = {err:.2e} N'


# -- the paper's comparisons -----------------------------------------------------

def test_protocol_I_single_equals_multi_for_the_first_five_seconds(runs):
    single, multi = runs[('I', 'single', 'initial')], runs[('I', 'multi', 'initial')]
    first = single.t_s <= 5.0
    np.testing.assert_allclose(multi.force_n[first], single.force_n[first], rtol=0, atol=1e-9)


def test_protocol_I_multi_is_higher_after_re_recruitment_at_five_seconds(runs):
    single, multi = runs[('I', 'single', 'initial')], runs[('I', 'multi', 'initial')]
    late = single.t_s >= 5.2
    assert np.all(multi.force_n[late] > single.force_n[late] + 0.1)


@pytest.mark.parametrize('name', ['I', 'II'])
def test_instantaneous_length_single_and_multi_overlie(runs, name):
    single = runs[(name, 'single', 'instantaneous')]
    multi = runs[(name, 'multi', 'instantaneous')]
    np.testing.assert_allclose(multi.force_n, single.force_n, rtol=0, atol=1e-9)


def test_protocol_II_multi_is_below_single_by_more_than_1N_after_three_seconds(runs):
    single, multi = runs[('II', 'single', 'initial')], runs[('II', 'multi', 'initial')]
    late = single.t_s >= 3.5
    assert np.all(single.force_n[late] - multi.force_n[late] > 1.0)
    early = single.t_s <= 3.0
    np.testing.assert_allclose(multi.force_n[early], single.force_n[early], atol=1e-9)


@pytest.mark.parametrize('units', ['single', 'multi'])
@pytest.mark.parametrize('name', ['I', 'II'])
def test_initial_and_instantaneous_differ_within_the_first_second(runs, name, units):
    initial = runs[(name, units, 'initial')]
    inst = runs[(name, units, 'instantaneous')]
    first = (initial.t_s > 0.0) & (initial.t_s <= 1.0)
    assert np.max(np.abs(initial.force_n[first] - inst.force_n[first])) > 0.5


def test_ce_shortens_while_se_stretches_at_constant_mtu_length(runs):
    run = runs[('I', 'multi', 'initial')]
    first = run.t_s <= 1.0
    assert np.all(run.dl_mt_m[first] == 0.0)
    assert np.all(np.diff(run.l_ce_m[first]) < 0) and np.all(np.diff(run.f_se_n[first]) > 0)


def test_a_fast_ce_stays_inside_the_fl_range_over_one_long_integrator_step():
    """The integrator bounds its RK4 step by the CE's relaxation rate (doc/model.md
    7.6): a fast instantaneous CE that one whole 10 ms RK4 step would carry below
    the FL range instead follows the fine-step solution, here 100 steps of 0.1 ms."""
    p = MuscleParams(f_iso_max_n=31.0, k_se_n_per_m=1000.0, l_rest_m=0.125, l_opt_m=0.125,
                     fv_a_n=2.0, fv_b_m_per_s=1.0, length='instantaneous')
    coarse, fine = Muscle(p), Muscle(p)
    out = coarse.run((1.0,), (0.0,), 1e-2)   # one step of the run (step would cut it)
    ref = fine.run((1.0,) * 100, (0.0,) * 100, 1e-4)
    assert out.eff_f_iso_n > 0.0   # still inside the FL range, still resisting
    assert out.l_ce_m == pytest.approx(ref.l_ce_m, abs=1e-6)
    assert out.force_n == pytest.approx(ref.force_n, abs=1e-3)


def test_re_recruitment_stores_the_new_ce_length():
    """Units recruited at a shorter CE length produce the FL of that length."""
    m = Muscle(MuscleParams(units='multi', length='initial'))
    hold(m, 1.0, 0.0, 2.0)
    l_then = m.l_ce_m
    m.step(0.5, 0.0, 1e-3)
    m.set_recruitment(1.0)
    half = 0.5 * P.f_iso_max_n
    expected = half * force_length(P.l_rest_m / P.l_opt_m) + half * force_length(
        m.l_ce_m / P.l_opt_m)
    assert m.eff_f_iso() == pytest.approx(expected, abs=1e-12)
    assert m.l_ce_m != l_then


# -- bad inputs ------------------------------------------------------------------

@pytest.mark.parametrize('kwargs, name', [
    ({'recruitment': math.nan}, 'recruitment'),
    ({'recruitment': 1.5}, 'recruitment'),
    ({'recruitment': -0.1}, 'recruitment'),
    ({'dl_mt_m': math.inf}, 'dl_mt_m'),
    ({'dl_mt_m': math.nan}, 'dl_mt_m'),
    ({'dl_mt_m': 2.0}, 'dl_mt_m'),
    ({'dt_s': 0.0}, 'dt_s'),
    ({'dt_s': math.nan}, 'dt_s'),
])
def test_bad_step_input_raises_and_leaves_the_state_unchanged(kwargs, name):
    m = Muscle()
    hold(m, 0.7, 0.003, 0.3)
    before = m.outputs()
    args = {'recruitment': 0.7, 'dl_mt_m': 0.003, 'dt_s': 1e-3, **kwargs}
    with pytest.raises(ValueError, match=f'`{name}`'):
        m.step(**args)
    assert m.outputs() == before


@pytest.mark.parametrize('pw', [math.nan, math.inf, -1e-6])
def test_bad_pulse_width_raises(pw):
    with pytest.raises(ValueError, match='`pulse_width_s`'):
        Muscle().set_pulse_width(pw)


def test_pulse_width_maps_linearly_and_saturates_at_pw_max():
    m = Muscle()
    m.set_pulse_width(0.25 * P.pw_max_s)
    assert m.recruitment == pytest.approx(0.25) and m.n_recruited == 250
    m.set_pulse_width(3 * P.pw_max_s)
    assert m.recruitment == 1.0 and m.n_recruited == 1000


def test_reset_returns_to_rest_and_clears_the_memory():
    m = Muscle()
    hold(m, 1.0, 0.01, 0.5)
    m.reset()
    assert m.outputs() == Muscle().outputs()
    assert m.n_runs == 0
