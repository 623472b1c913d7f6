"""``simulate --csv``: every number in its shortest exact form, and the header doc/cli.md gives is the real one.

Each CSV field must read back as the very float the simulation gave (exact),
and no representation with fewer significant digits may read back as it
(shortest): ``0.0005``, not ``0.00050000000000000001``. Both are checked
against the run itself and by trying the shorter forms, not by ``repr``.
"""
import re

import numpy as np
import pytest

from hill_muscle_ros import resources
from hill_muscle_ros.model import COLUMNS, MuscleParams, Protocol, simulate
from hill_muscle_ros.model.limb import LimbProtocol, limb_columns, simulate_limb
from hill_muscle_ros.params_file import load_plant
from hill_muscle_ros.tools import cli

#: [Hz] 2 kHz: the second sample is at t = 1 / 2000 = 0.0005 s, a float that
#: 17 significant digits write as 0.00050000000000000001.
RATE_HZ = 2000.0
HALF_MILLISECOND_TEXT = '0.0005'
#: [Hz] the limb's rate here: a fifth of 1 kHz, to keep the Python limb quick.
LIMB_RATE_HZ = 200.0
README = resources.config_dir().parent / 'doc' / 'cli.md'
#: The sentence of doc/cli.md (the README's CLI reference) that gives the single muscle's CSV header.
README_HEADER = re.compile(r'The CSV header is\s+`([^`]+)`')


def _significant_digits(text: str) -> str:
    """The significant digits of a decimal number's text (``0.0005`` -> ``5``)."""
    mantissa = re.split('[eE]', text)[0].lstrip('+-').replace('.', '')
    return mantissa.lstrip('0').rstrip('0') or '0'


def _read(path):
    lines = path.read_text(encoding='utf-8').splitlines()
    return lines[0].split(','), [line.split(',') for line in lines[1:]]


def _assert_exact_and_shortest(fields, values):
    """Each text reads back as its value, and one significant digit fewer cannot."""
    for text, value in zip(fields, values):
        assert float(text) == value, (text, value)
        digits = len(_significant_digits(text))
        if digits > 1:
            shorter = f'{value:.{digits - 2}e}'   # digits - 1 significant digits
            assert float(shorter) != value, (text, shorter)


@pytest.fixture(scope='module')
def muscle_csv(tmp_path_factory):
    path = tmp_path_factory.mktemp('csv') / 'protocol_II.csv'
    assert cli.main(['simulate', '--protocol', 'II', '--rate', str(RATE_HZ),
                     '--csv', str(path)]) == 0
    result = simulate(Protocol.from_yaml(resources.find_protocol('II')), MuscleParams(),
                      RATE_HZ)
    return path, result


def test_every_muscle_csv_number_reads_back_exactly_and_is_shortest(muscle_csv):
    path, result = muscle_csv
    _, rows = _read(path)
    assert len(rows) == len(result.t_s)
    for k, row in enumerate(rows):
        _assert_exact_and_shortest(row, [float(getattr(result, a)[k]) for a, _ in COLUMNS])


def test_half_a_millisecond_is_written_0_0005(muscle_csv):
    path, _ = muscle_csv
    header, rows = _read(path)
    assert rows[1][header.index('t_s')] == HALF_MILLISECOND_TEXT


def test_the_readme_gives_the_real_csv_header(muscle_csv):
    path, _ = muscle_csv
    header, _ = _read(path)
    stated = README_HEADER.search(README.read_text(encoding='utf-8'))
    assert stated is not None, 'doc/cli.md: "The CSV header is `...`" not found'
    assert stated.group(1).split(',') == header


def test_every_limb_csv_number_reads_back_exactly_and_is_shortest(tmp_path):
    plant_path = resources.config_dir() / 'knee.yaml'
    protocol_path = resources.config_dir() / 'protocols' / 'knee_extension.yaml'
    path = tmp_path / 'knee.csv'
    assert cli.main(['simulate', '--plant', str(plant_path), '--protocol', str(protocol_path),
                     '--rate', str(LIMB_RATE_HZ), '--csv', str(path)]) == 0
    plant = load_plant(plant_path)[0]
    result = simulate_limb(plant, LimbProtocol.from_yaml(protocol_path), LIMB_RATE_HZ)
    header, rows = _read(path)
    assert header == limb_columns(plant)
    assert len(rows) == len(result.t_s)
    for k, row in enumerate(rows):
        _assert_exact_and_shortest(row, [float(result[c][k]) for c in header])
    assert np.array_equal([float(r[0]) for r in rows], result.t_s)
