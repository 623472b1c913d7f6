"""The figures of ``hill-muscle figures``: the paper's Figures 8-11 and the FES
figures, the files written and, for each FES figure, its claim checked on the
data behind it against closed forms written here."""
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from matplotlib.image import imread
from PIL import Image

from hill_muscle_ros.model import Protocol
from hill_muscle_ros.tools import cli
from hill_muscle_ros.tools.figures import fes, paper, plotting, pulses


#: The module takes about 7 CPU-s: scheduled among the first (conftest).
pytestmark = pytest.mark.slow

HILL_MUSCLE = Path(sys.executable).with_name('hill-muscle')
PNG_SIGNATURE = b'\x89PNG\r\n\x1a\n'
FIGURE_FILES = ('fig08_protocol_I_initial.png', 'fig09_protocol_II_initial.png',
                'fig10_protocol_I_all.png', 'fig11_protocol_II_all.png')
FES_FILES = ('fes_recruitment_curves.png', 'fes_activation.png', 'fes_fatigue.png',
             'fes_fibre_types.png', 'fes_fv_scaling.png')
PULSE_FILES = ('pulse_force_frequency.png', 'pulse_catchlike.png', 'pulse_kesar_fatigue.png',
               'pulse_sdss.png')
#: [s] generous: the machine is shared with other test runs.
SUBPROCESS_TIMEOUT_S = 120
#: [Hz] step rate of the ``figures`` run whose files are checked.
FIGURES_TEST_RATE_HZ = 200
#: A drawn figure has far more colours than a blank canvas.
MIN_DISTINCT_COLOURS = 20


@pytest.fixture(scope='module', autouse=True)
def fatigue_data_once():
    """``fes.fatigue_data`` computed once per rate for the module, on the
    engine the module was started with: the figures command (through
    ``write_fatigue_figure``) and the fatigue tests read the same data, as the
    command draws it. Its per-unit fitness profiles step a Python muscle
    through the 125 s protocol (1.4 s each time)."""
    original = fes.fatigue_data
    engine_before = os.environ.get('HILL_MUSCLE_ENGINE')
    memo = {}

    def once(rate_hz=plotting.RATE_HZ):
        if rate_hz not in memo:
            with pytest.MonkeyPatch.context() as mp:
                if engine_before is None:
                    mp.delenv('HILL_MUSCLE_ENGINE', raising=False)
                else:
                    mp.setenv('HILL_MUSCLE_ENGINE', engine_before)
                memo[rate_hz] = original(rate_hz)
        return memo[rate_hz]

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(fes, 'fatigue_data', once)
        yield


@pytest.fixture(scope='module')
def figure_dir(tmp_path_factory):
    """Run the ``figures`` command once for the module, in this process (its
    entry function ``cli.main``): the console script itself is run as a
    subprocess by :func:`test_figures_into_an_existing_file_exits_2`."""
    out = tmp_path_factory.mktemp('figures') / 'out'
    # At 200 Hz: these tests check the files; each figure's claims are checked
    # on its data at the figures' own 1 kHz below. On the compiled engines:
    # auto ran the knee figure's four 10 s limbs and the 125 s fatigue runs on
    # the Python loops (most of the command's 8 s); the files are the claim
    # here, and the engines agree to 1e-9 (test_limb_compiled,
    # test_simulate_fes_compiled). The data tests below keep the default engine,
    # and the fatigue figure is drawn from their data (fatigue_data_once).
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv('HILL_MUSCLE_ENGINE', 'compiled')
        assert cli.main(['figures', '--out', str(out),
                         '--rate', str(FIGURES_TEST_RATE_HZ)]) == 0
    return out


def test_figures_command_writes_the_papers_four_the_five_fes_the_limb_and_the_pulse_figures(
        figure_dir):
    assert sorted(p.name for p in figure_dir.iterdir()) == \
        sorted(FIGURE_FILES + FES_FILES + ('limb_knee.png',) + PULSE_FILES)


def test_pulse_figure_files_are_the_modules_own():
    assert pulses.PULSE_FIGURE_FILES == PULSE_FILES


def _declared_size_in(name):
    if name == 'fes_fatigue.png':
        return fes.FATIGUE_FIGSIZE_IN
    if name.startswith('pulse_'):
        return pulses.PULSE_FIGSIZE_IN
    return fes.FES_FIGSIZE_IN if name.startswith('fes_') else paper.FIGSIZE_IN


@pytest.mark.parametrize('name', FIGURE_FILES + FES_FILES + PULSE_FILES)
def test_each_figure_is_a_valid_png_of_the_declared_size(figure_dir, name):
    path = figure_dir / name
    assert path.read_bytes()[:len(PNG_SIGNATURE)] == PNG_SIGNATURE
    image = imread(path)
    width_in, height_in = _declared_size_in(name)
    assert image.shape[:2] == (round(height_in * plotting.DPI), round(width_in * plotting.DPI))


@pytest.mark.parametrize('name', FIGURE_FILES + FES_FILES + PULSE_FILES)
def test_each_figure_is_not_blank(figure_dir, name):
    # The PNG's 8-bit RGBA pixels (Agg writes 8 bits a channel) packed into one
    # uint32 each: a one-to-one code of the colour, so the same distinct colours
    # as np.unique(..., axis=0) on the pixels, which took about 1 s per figure,
    # and as the opaque 16-byte items of imread's floats, 0.08-0.15 CPU-s per
    # figure; these integers take 0.02.
    with Image.open(figure_dir / name) as png:
        rgba = np.ascontiguousarray(png.convert('RGBA'), dtype=np.uint8)
    colours = np.unique(rgba.view(np.uint32))
    assert len(colours) > MIN_DISTINCT_COLOURS


def test_figures_8_and_9_compare_single_and_multi_at_initial_length():
    for spec in paper.FIGURES[:2]:
        assert {(v.units, v.length) for v in spec.variants} == {
            ('single', 'initial'), ('multi', 'initial')}


def test_figures_10_and_11_show_all_four_variants():
    for spec in paper.FIGURES[2:]:
        assert {(v.units, v.length) for v in spec.variants} == {
            (u, l) for u in ('single', 'multi') for l in ('initial', 'instantaneous')}


def test_figures_use_protocols_I_and_II_in_the_papers_order():
    assert [(s.number, s.protocol) for s in paper.FIGURES] == [
        (8, 'I'), (9, 'II'), (10, 'I'), (11, 'II')]
    assert tuple(s.filename for s in paper.FIGURES) == FIGURE_FILES


def test_coinciding_single_and_multi_curves_are_drawn_differently():
    """With instantaneous length single and multi overlie exactly; both must show."""
    for length in ('initial', 'instantaneous'):
        single, multi = (next(v for v in plotting.VARIANTS if (v.units, v.length) == (u, length))
                         for u in ('single', 'multi'))
        assert single.linestyle != multi.linestyle
        assert multi.linewidth < single.linewidth


@pytest.fixture(scope='module')
def figure_11(protocol_paths):
    spec = paper.FIGURES[3]
    protocol = Protocol.from_yaml(protocol_paths[spec.protocol])
    results = paper.simulate_variants(protocol, spec.variants, rate_hz=200.0)
    return spec, results, paper.plot_figure(spec, protocol, results)


def test_figure_plots_the_force_of_each_variant(figure_11):
    spec, results, fig = figure_11
    ax_force = fig.axes[0]
    lines = {line.get_label(): line for line in ax_force.get_lines()}
    assert set(lines) == {v.label for v in spec.variants}
    for variant in spec.variants:
        np.testing.assert_array_equal(lines[variant.label].get_ydata(), results[variant].force_n)


def test_figure_axes_name_their_units(figure_11):
    _, _, fig = figure_11
    ax_force, ax_inputs, ax_dl = fig.axes
    assert '[N]' in ax_force.get_ylabel()
    assert '[s]' in ax_inputs.get_xlabel()
    assert '[-]' in ax_inputs.get_ylabel()
    assert '[mm]' in ax_dl.get_ylabel()


def test_figure_input_panel_shows_recruitment_and_length_change(figure_11):
    spec, results, fig = figure_11
    _, ax_inputs, ax_dl = fig.axes
    inputs = results[spec.variants[0]]
    np.testing.assert_array_equal(ax_inputs.get_lines()[0].get_ydata(), inputs.recruitment)
    np.testing.assert_allclose(ax_dl.get_lines()[0].get_ydata(),
                               inputs.dl_mt_m * plotting.MM_PER_M)


def test_figure_title_names_the_figure_and_protocol(figure_11):
    spec, _, fig = figure_11
    title = fig.axes[0].get_title()
    assert 'Figure 11' in title and 'Protocol II' in title


def test_figures_into_an_existing_file_exits_2(tmp_path):
    blocker = tmp_path / 'file'
    blocker.write_text('')
    proc = subprocess.run([str(HILL_MUSCLE), 'figures', '--out', str(blocker)],
                          capture_output=True, text=True, env=os.environ.copy(),
                          timeout=SUBPROCESS_TIMEOUT_S)
    assert proc.returncode == 2
    assert 'Traceback' not in proc.stderr and str(blocker) in proc.stderr


# =============================================================================
# FES figures: each claim on the data behind the figure
# =============================================================================

#: [Hz] step rate of the FES figure data in these tests: a fifth of the figures'
#: 1 kHz keeps them fast; every event of the protocols falls on a 5 ms sample.
TEST_RATE_HZ = 200.0


def fl(x):
    """Eq. 1 written out here: FL(x) = max(0, -2.777 x^2 + 5.554 x - 1.777)."""
    return max(0.0, -2.777 * x * x + 5.554 * x - 1.777)


def test_fes_figure_functions_return_the_paths_they_write(tmp_path):
    path = fes.write_recruitment_curves_figure(tmp_path)
    assert path == tmp_path / 'fes_recruitment_curves.png'
    assert path.stat().st_size > 0


# --------------------------------------------------------------- recruitment curves

@pytest.fixture(scope='module')
def curves():
    return fes.recruitment_curve_data()


def test_exponential_curve_is_one_minus_1_over_e_at_threshold_plus_scale(curves):
    from hill_muscle_ros.model.stimulus import command_from_pulse_width
    p = curves.params['exponential']
    assert (p.pw_threshold_s, p.pw_scale_s) == (131.4e-6, 194.1e-6)   # Ding et al. 2007
    u = command_from_pulse_width(p.pw_threshold_s + p.pw_scale_s, p)
    assert u == pytest.approx(1.0 - 1.0 / math.e, abs=1e-12)


def test_exponential_curve_data_is_zero_below_threshold_then_its_closed_form(curves):
    p = curves.params['exponential']
    pw = curves.pulse_width_s
    expected = np.where(pw > p.pw_threshold_s,
                        1.0 - np.exp(-(pw - p.pw_threshold_s) / p.pw_scale_s), 0.0)
    np.testing.assert_allclose(curves.command['exponential'], expected, rtol=0, atol=1e-12)


def test_linear_curves_saturate_at_pw_max_and_threshold_linear_starts_at_threshold(curves):
    pw = curves.pulse_width_s
    linear, thr = curves.params['linear'], curves.params['threshold_linear']
    np.testing.assert_allclose(curves.command['linear'], np.minimum(pw / linear.pw_max_s, 1.0),
                               rtol=0, atol=1e-12)
    expected = np.clip((pw - thr.pw_threshold_s) / (thr.pw_max_s - thr.pw_threshold_s), 0, 1)
    np.testing.assert_allclose(curves.command['threshold_linear'], expected, rtol=0, atol=1e-12)


def test_recruitment_curve_figure_plots_the_data(curves):
    fig = fes.plot_recruitment_curves(curves)
    lines = [line for line in fig.axes[0].get_lines() if len(line.get_xdata()) > 2]
    assert len(lines) == len(fes.CURVES)
    for line, curve in zip(lines, fes.CURVES):
        np.testing.assert_array_equal(line.get_ydata(), curves.command[curve])


# --------------------------------------------------------------- activation

@pytest.fixture(scope='module')
def activation():
    return fes.activation_data()


def test_activation_equals_its_closed_form_after_the_delay(activation):
    """a = u (1 - exp(-(t - t_on - emd) / tau_act)) while the delayed command is on,
    then a_off exp(-(t - t_off - emd) / tau_deact)."""
    p = activation.params
    r = activation.results['initial']
    u = 1.0 - math.exp(-(fes.ACT_PW_S - p.pw_threshold_s) / p.pw_scale_s)
    t_up, t_down = fes.ACT_T_ON_S + p.emd_s, fes.ACT_T_OFF_S + p.emd_s
    a_off = u * (1.0 - math.exp(-(t_down - t_up) / p.tau_act_s))
    t = r.t_s
    expected = np.where(t < t_up, 0.0,
                        np.where(t < t_down, u * (1.0 - np.exp(-(t - t_up) / p.tau_act_s)),
                                 a_off * np.exp(-(t - t_down) / p.tau_deact_s)))
    np.testing.assert_allclose(r.recruitment, expected, rtol=0, atol=1e-12)
    np.testing.assert_allclose(r.command[(t >= fes.ACT_T_ON_S) & (t < fes.ACT_T_OFF_S)],
                               u, rtol=0, atol=1e-12)


def test_no_force_before_the_delay_has_passed(activation):
    p = activation.params
    for r in activation.results.values():
        before = r.t_s <= fes.ACT_T_ON_S + p.emd_s
        assert np.all(r.force_n[before] == 0.0)
        assert r.force_n[r.at(fes.ACT_T_ON_S + p.emd_s + 0.05)] > 1.0


def test_stretch_during_recruitment_separates_initial_from_instantaneous_length(activation):
    """Rest length is on the descending limb of FL (1.25 l_opt): after the stretch the
    current CE is longer than where most units were recruited, so ``initial`` is higher."""
    end_of_stretch = fes.ACT_STRETCH_KNOTS[-1][0]
    initial, instantaneous = (activation.results[k].force_n for k in fes.ACT_LENGTHS)
    i = activation.results['initial'].at(end_of_stretch)
    assert initial[i] > instantaneous[i] + 0.5


# --------------------------------------------------------------- fatigue

@pytest.fixture(scope='module')
def fatigue():
    return fes.fatigue_data(TEST_RATE_HZ)


def tired_fitness_at_step(params, before_s=0.0):
    """Fitness of the units every train recruits, ``before_s`` before the step:
    Riener's law per unit, recruited 5 s then resting 5 s, eleven times, then
    recruited again until then."""
    mu_min, t_fat, t_rec = params.fatigue_min[0], params.tau_fatigue_s[0], params.tau_recovery_s[0]
    mu = 1.0
    for i in range(fes.FATIGUE_TRAINS):
        on_s = fes.FATIGUE_ON_S - (before_s if i == fes.FATIGUE_TRAINS - 1 else 0.0)
        mu = mu_min + (mu - mu_min) * math.exp(-on_s / t_fat)
        if i < fes.FATIGUE_TRAINS - 1:
            mu = 1.0 - (1.0 - mu) * math.exp(-(fes.FATIGUE_PERIOD_S - fes.FATIGUE_ON_S)
                                             / t_rec)
    return mu


def test_before_the_step_the_trained_units_are_tired_and_the_others_fresh(fatigue):
    params = fes.fatigue_params('multi')
    profile = fatigue.profiles[fatigue.step_s]
    m_low = int(params.n_units * fes.FATIGUE_PW_LOW_S / params.pw_max_s + 0.5)
    np.testing.assert_allclose(profile[:m_low], tired_fitness_at_step(params), rtol=0, atol=1e-9)
    assert np.all(profile[m_low:] == 1.0)


def test_step_up_adds_fresh_units_to_the_per_unit_model(fatigue):
    """F0 just after the step = the tired units (recruited at rest length) + the added
    units at full fitness, recruited at the CE length of the step instant."""
    p = fes.fatigue_params('multi')
    r = fatigue.results['multi']
    i = r.at(fatigue.step_s)
    m_low = int(p.n_units * fes.FATIGUE_PW_LOW_S / p.pw_max_s + 0.5)
    m_high = int(p.n_units * fes.FATIGUE_PW_HIGH_S / p.pw_max_s + 0.5)
    tired = m_low * p.f_iso_max_n / p.n_units * fl(p.l_rest_m / p.l_opt_m)
    fresh = (m_high - m_low) * p.f_iso_max_n / p.n_units * fl(r.l_ce_m[i] / p.l_opt_m)
    dt = r.t_s[i] - r.t_s[i - 1]
    assert r.eff_f_iso_n[i - 1] == pytest.approx(tired * tired_fitness_at_step(p, dt), rel=1e-9)
    assert r.eff_f_iso_n[i] == pytest.approx(tired * tired_fitness_at_step(p) + fresh, rel=1e-9)


def test_step_up_raises_force_per_recruitment_per_unit_but_not_whole_muscle(fatigue):
    """Whole-muscle fitness is one number: the units a step adds are as tired as the
    rest, F0 / R is continuous and the force grows with R. Per unit, they are fresh."""
    r_ratio = fes.FATIGUE_PW_HIGH_S / fes.FATIGUE_PW_LOW_S
    gain = {}
    for units, r in fatigue.results.items():
        i = r.at(fatigue.step_s)
        per_r = fes.f0_per_recruitment(r)
        gain[units] = (per_r[i] / per_r[i - 1],
                       r.force_n[r.at(fatigue.step_s + 1.0)] / r.force_n[i - 1])
    assert gain['single'][0] == pytest.approx(1.0, abs=1e-3)
    assert gain['multi'][0] > 1.3
    assert gain['single'][1] == pytest.approx(r_ratio, rel=0.05)
    assert gain['multi'][1] > 1.25 * r_ratio


def test_fitness_profiles_agree_with_the_simulated_mean_fitness(fatigue):
    r = fatigue.results['multi']
    assert sorted(fatigue.profiles) == sorted(fes.FATIGUE_PROFILE_TIMES_S)
    for t, profile in fatigue.profiles.items():
        assert profile.mean() == pytest.approx(r.mean_fitness[r.at(t)], abs=1e-12)


def test_whole_muscle_fitness_follows_riener_with_a_equal_to_r(fatigue):
    """First train: mu' = (mu_min - mu) a / T_fat + (1 - mu)(1 - a) / T_rec, a = 0.4."""
    p = fes.fatigue_params('single')
    a = fes.FATIGUE_PW_LOW_S / p.pw_max_s
    rate_f, rate_r = a / p.tau_fatigue_s[0], (1.0 - a) / p.tau_recovery_s[0]
    lam = rate_f + rate_r
    mu_inf = (p.fatigue_min[0] * rate_f + rate_r) / lam
    r = fatigue.results['single']
    i = r.at(fes.FATIGUE_ON_S)
    assert r.mean_fitness[i] == pytest.approx(
        mu_inf + (1.0 - mu_inf) * math.exp(-lam * r.t_s[i]), abs=1e-12)


# --------------------------------------------------------------- fibre types

@pytest.fixture(scope='module')
def fibres():
    return fes.fibre_data(TEST_RATE_HZ)


def _riener_recruited(t, mu_min, t_fat):
    return mu_min + (1.0 - mu_min) * np.exp(-t / t_fat)


def test_size_and_reverse_orders_tire_with_their_types_own_time_constant(fibres):
    """R = 0.5 recruits exactly the slow type in size order and the fast one in reverse,
    all at t = 0 and rest length, so F0 / F0(0) is that type's fitness."""
    p = fes.fibre_params('size')
    for order, t_fat in (('size', p.tau_fatigue_s[0]), ('reverse', p.tau_fatigue_s[1])):
        r = fibres.results[order]
        np.testing.assert_allclose(r.eff_f_iso_n / r.eff_f_iso_n[0],
                                   _riener_recruited(r.t_s, p.fatigue_min[0], t_fat),
                                   rtol=1e-9, atol=0)


def test_fast_first_starts_twice_as_strong_as_slow_first(fibres):
    w = fes.fibre_params('size').fibre_force_weights
    ratio = fibres.results['reverse'].eff_f_iso_n[0] / fibres.results['size'].eff_f_iso_n[0]
    assert ratio == pytest.approx(w[1] / w[0], rel=1e-12)


def test_random_order_tires_as_the_mix_of_types_its_permutation_recruits(fibres):
    p = fes.fibre_params('random')
    n = p.n_units
    types = np.repeat([0, 1], [n // 2, n - n // 2])[np.random.default_rng(
        p.recruitment_seed).permutation(n)]
    m = int(n * fes.FIBRE_PW_S / p.pw_max_s + 0.5)
    counts = np.bincount(types[:m], minlength=2)
    r = fibres.results['random']
    weighted = [counts[k] * p.fibre_force_weights[k] for k in (0, 1)]
    expected = sum(wk * _riener_recruited(r.t_s, p.fatigue_min[0], p.tau_fatigue_s[k])
                   for k, wk in enumerate(weighted)) / sum(weighted)
    np.testing.assert_allclose(r.eff_f_iso_n / r.eff_f_iso_n[0], expected, rtol=1e-9, atol=0)


# --------------------------------------------------------------- fv_scaling

@pytest.fixture(scope='module')
def fv():
    return fes.fv_data()


def test_last_unit_leaves_at_the_closed_form_instant(fv):
    for r in fv.results.values():
        k = int(np.flatnonzero(r.n_recruited > 0)[-1])
        assert r.t_s[k] < fv.release_s <= r.t_s[k + 1]


def test_absolute_scaling_holds_the_force_then_drops_it_when_the_last_unit_leaves(fv):
    r = fv.results['absolute']
    plateau = r.f_se_n[r.at(fes.FV_T_OFF_S)]
    drops = -np.diff(r.f_se_n)
    k = int(np.argmax(drops))
    assert r.t_s[k] < fv.release_s <= r.t_s[k + 1]
    assert drops[k] > 0.5 * plateau
    # Just before, the stretch has pushed the force back above its plateau, carried
    # by the last unit's F0 of less than a hundredth of it.
    assert r.f_se_n[k] > plateau > 100.0 * r.eff_f_iso_n[k]


def test_relative_scaling_lets_the_force_decay_with_f0(fv):
    r = fv.results['relative']
    plateau = r.f_se_n[r.at(fes.FV_T_OFF_S)]
    assert r.f_se_n[r.at(fes.FV_T_OFF_S + 0.5)] < 0.05 * plateau
    assert np.max(-np.diff(r.f_se_n)) < 0.05 * plateau
