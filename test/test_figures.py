"""The paper's Figures 8-11: files written by ``hill-muscle figures`` and their content."""
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from matplotlib.image import imread

from hill_muscle_ros import figures
from hill_muscle_ros.model import Protocol

HILL_MUSCLE = Path(sys.executable).with_name('hill-muscle')
PNG_SIGNATURE = b'\x89PNG\r\n\x1a\n'
FIGURE_FILES = ('fig08_protocol_I_initial.png', 'fig09_protocol_II_initial.png',
                'fig10_protocol_I_all.png', 'fig11_protocol_II_all.png')
#: [s] generous: the machine is shared with other test runs.
SUBPROCESS_TIMEOUT_S = 120
#: A drawn figure has far more colours than a blank canvas.
MIN_DISTINCT_COLOURS = 20


@pytest.fixture(scope='module')
def figure_dir(tmp_path_factory):
    """Run ``hill-muscle figures`` once for the module."""
    out = tmp_path_factory.mktemp('figures') / 'out'
    proc = subprocess.run([str(HILL_MUSCLE), 'figures', '--out', str(out)], capture_output=True,
                          text=True, env=os.environ.copy(), timeout=SUBPROCESS_TIMEOUT_S)
    assert proc.returncode == 0, proc.stderr
    return out


def test_figures_command_writes_the_four_files(figure_dir):
    assert sorted(p.name for p in figure_dir.iterdir()) == list(FIGURE_FILES)


@pytest.mark.parametrize('name', FIGURE_FILES)
def test_each_figure_is_a_valid_png_of_the_declared_size(figure_dir, name):
    path = figure_dir / name
    assert path.read_bytes()[:len(PNG_SIGNATURE)] == PNG_SIGNATURE
    image = imread(path)
    width_in, height_in = figures.FIGSIZE_IN
    assert image.shape[:2] == (round(height_in * figures.DPI), round(width_in * figures.DPI))


@pytest.mark.parametrize('name', FIGURE_FILES)
def test_each_figure_is_not_blank(figure_dir, name):
    image = imread(figure_dir / name)
    colours = np.unique(image.reshape(-1, image.shape[-1]), axis=0)
    assert len(colours) > MIN_DISTINCT_COLOURS


def test_figures_8_and_9_compare_single_and_multi_at_initial_length():
    for spec in figures.FIGURES[:2]:
        assert {(v.units, v.length) for v in spec.variants} == {
            ('single', 'initial'), ('multi', 'initial')}


def test_figures_10_and_11_show_all_four_variants():
    for spec in figures.FIGURES[2:]:
        assert {(v.units, v.length) for v in spec.variants} == {
            (u, l) for u in ('single', 'multi') for l in ('initial', 'instantaneous')}


def test_figures_use_protocols_I_and_II_in_the_papers_order():
    assert [(s.number, s.protocol) for s in figures.FIGURES] == [
        (8, 'I'), (9, 'II'), (10, 'I'), (11, 'II')]
    assert tuple(s.filename for s in figures.FIGURES) == FIGURE_FILES


def test_coinciding_single_and_multi_curves_are_drawn_differently():
    """With instantaneous length single and multi overlie exactly; both must show."""
    for length in ('initial', 'instantaneous'):
        single, multi = (next(v for v in figures.VARIANTS if (v.units, v.length) == (u, length))
                         for u in ('single', 'multi'))
        assert single.linestyle != multi.linestyle
        assert multi.linewidth < single.linewidth


@pytest.fixture(scope='module')
def figure_11(protocol_paths):
    spec = figures.FIGURES[3]
    protocol = Protocol.from_yaml(protocol_paths[spec.protocol])
    results = figures.simulate_variants(protocol, spec.variants, rate_hz=200.0)
    return spec, results, figures.plot_figure(spec, protocol, results)


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
                               inputs.dl_mt_m * figures.MM_PER_M)


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
