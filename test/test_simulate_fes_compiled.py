"""simulate() of a muscle with FES features on: the compiled build against the plain one.

``simulate`` runs the muscle on the build :func:`hill_muscle_ros.model.engine.kernels`
chooses; here ``HILL_MUSCLE_ENGINE`` forces each in turn, and every column of
the result must agree to 1e-9 (N, m, m/s), n_recruited exactly.
"""
import numpy as np
import pytest
from hypothesis import HealthCheck, assume, example, given, settings, strategies as st

from hill_muscle_ros import resources
from hill_muscle_ros.model import MuscleParams, Protocol, engine
from hill_muscle_ros.model.muscle import kernels as muscle_kernels
from hill_muscle_ros.model.simulate import COLUMNS, simulate
from hill_muscle_ros.params_file import load_muscle_params
from test_fes_compiled import _params

#: [N], [m], [m/s] agreement asked of every column (the forces' is the goal's 1e-9 N).
TOL = 1e-9
#: [s] longest random protocol: the Python reference stays quick. It holds
#: two of the shorter drawn fatigue time constant (0.1 s) and six of the
#: longest delay (31 ms); whole 6 s paper protocols are the preset's
#: comparison (test_quadriceps_preset_matches_the_python_run).
MAX_DURATION_S = 0.2
PRESET = resources.config_dir() / 'fes_quadriceps.yaml'
PROTOCOLS = resources.config_dir() / 'protocols'


@pytest.fixture(scope='module')
def kernels():
    return muscle_kernels.compiled()


def _run(monkeypatch, value, protocol, params, rate_hz):
    monkeypatch.setenv(engine.ENV_VAR, value)
    try:
        return simulate(protocol, params, rate_hz)
    finally:
        monkeypatch.delenv(engine.ENV_VAR)


def _assert_same(got, ref):
    for name, _ in COLUMNS + (('n_recruited', None),):
        a, b = getattr(got, name), getattr(ref, name)
        assert a.shape == b.shape and a.dtype == b.dtype, name
        assert np.abs(a - b).max(initial=0.0) <= TOL, (name, np.abs(a - b).max())


def _compare(monkeypatch, protocol, params, rate_hz=1000.0):
    ref = _run(monkeypatch, engine.PYTHON, protocol, params, rate_hz)
    got = _run(monkeypatch, engine.COMPILED, protocol, params, rate_hz)
    _assert_same(got, ref)


@st.composite
def fes_params(draw):
    """Any mix of the FES features: delay, activation, fatigue, fibre types,
    unit lengths, relative FV scaling, over both unit models and length modes."""
    units = draw(st.sampled_from(['multi', 'single']))
    k = draw(st.integers(1, 3)) if units == 'multi' else 1
    fields = dict(units=units, length=draw(st.sampled_from(['initial', 'instantaneous'])),
                  n_units=draw(st.integers(1, 150)),
                  emd_s=draw(st.sampled_from([0.0, 0.0123, 0.031])),
                  tau_act_s=draw(st.sampled_from([0.0, 0.025])),
                  tau_deact_s=draw(st.sampled_from([0.0, 0.028])),
                  fatigue=draw(st.sampled_from(['none', 'riener'])),
                  fv_scaling=draw(st.sampled_from(['absolute', 'relative'])),
                  tau_fatigue_s=tuple(draw(st.sampled_from([0.1, 2.0])) for _ in range(k)))
    if units == 'multi':
        fields.update(fibre_fractions=tuple(draw(st.floats(0.1, 1.0)) for _ in range(k)),
                      unit_length_spread=draw(st.sampled_from([0.0, 0.3])),
                      recruitment_order=draw(st.sampled_from(['size', 'random'])))
    params = _params(**fields)
    assume(not params.fes_defaults)   # some FES feature on
    return params


@st.composite
def protocols(draw):
    """Random recruitment and dl_MT knots (steps and ramps) over up to MAX_DURATION_S."""
    duration = draw(st.sampled_from([0.05, 0.1, MAX_DURATION_S]))
    times = sorted(draw(st.lists(st.floats(0.0, duration), min_size=1, max_size=6)))
    r = [[t, draw(st.sampled_from([0.0, 1.0, 0.3, 0.77]))] for t in times]
    dl = [[t, draw(st.floats(-0.01, 0.01))] for t in times]
    return Protocol.from_mapping({'name': 'random', 'duration_s': duration,
                                  'recruitment': r, 'dl_mt_m': dl})


#: A pinned protocol: recruitment steps up, down to 0 and up to 1, dl_MT ramps
#: out and back, over 0.2 s.
PINNED_PROTOCOL = Protocol.from_mapping({
    'name': 'pinned', 'duration_s': 0.2,
    'recruitment': [[0.0, 0.3], [0.05, 0.3], [0.05, 1.0], [0.1, 0.0], [0.15, 0.77]],
    'dl_mt_m': [[0.0, 0.0], [0.05, 0.01], [0.1, -0.01], [0.2, 0.005]]})


@settings(max_examples=15, deadline=None,
          suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])
@given(params=fes_params(), protocol=protocols(),
       rate_hz=st.sampled_from([500.0, 1000.0, 5000.0]))
@example(params=MuscleParams(units='multi', length='instantaneous', n_units=40, emd_s=0.031,
                             tau_act_s=0.025, tau_deact_s=0.028, fatigue='riener',
                             fv_scaling='relative', tau_fatigue_s=(0.1, 2.0, 0.1),
                             fibre_fractions=(0.1, 1.0, 0.5), unit_length_spread=0.3,
                             recruitment_order='random'),
         protocol=PINNED_PROTOCOL, rate_hz=5000.0)
@example(params=MuscleParams(units='single', length='initial', n_units=1, emd_s=0.0123,
                             fatigue='riener', fv_scaling='relative', tau_fatigue_s=(0.1,)),
         protocol=PINNED_PROTOCOL, rate_hz=500.0)
def test_fes_features_match_the_python_run(kernels, monkeypatch, params, protocol, rate_hz):
    _compare(monkeypatch, protocol, params, rate_hz)


@pytest.fixture(scope='module')
def preset_python_runs():
    """The FES preset simulated on the Python engine, once per paper protocol,
    and how often each run asked for the compiled build (the kernels'
    ``compiled()`` spied on): the reference of the preset's comparison and
    the object of test_python_engine_never_loads_the_compiled_build, which
    ran Protocol I on the Python engine a second time."""
    params, _ = load_muscle_params(PRESET)
    runs = {}

    def run(name):
        if name not in runs:
            asked = []

            def spy():
                asked.append(name)
                return original()
            with pytest.MonkeyPatch.context() as mp:
                original = muscle_kernels.compiled
                mp.setattr(muscle_kernels, 'compiled', spy)
                mp.setenv(engine.ENV_VAR, engine.PYTHON)
                result = simulate(Protocol.from_yaml(PROTOCOLS / name), params)
            runs[name] = (params, result, asked)
        return runs[name]
    return run


@pytest.mark.parametrize('name', ['protocol_I.yaml', 'protocol_II.yaml'])
def test_quadriceps_preset_matches_the_python_run(kernels, monkeypatch, preset_python_runs,
                                                   name):
    """config/fes_quadriceps.yaml (every feature, 1000 units) on a whole paper protocol."""
    params, ref, _ = preset_python_runs(name)
    got = _run(monkeypatch, engine.COMPILED, Protocol.from_yaml(PROTOCOLS / name), params,
               1000.0)
    _assert_same(got, ref)


def test_auto_takes_the_compiled_build_where_numba_is(kernels, monkeypatch):
    monkeypatch.setenv(engine.ENV_VAR, 'auto')
    assert engine.kernels(muscle_kernels) is kernels


def test_python_engine_never_loads_the_compiled_build(preset_python_runs):
    _, result, asked = preset_python_runs('protocol_I.yaml')
    assert not asked, 'the compiled build was asked for'
    assert result.force_n.max() > 0.0
