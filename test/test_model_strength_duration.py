"""The strength-duration law of a pulse (doc/model.md section 10).

A unit of rheobase r is excited by a pulse (I, PW) if I PW / (PW + c) >= r;
:func:`equivalent_pulse_width` is the width that excites the same units at the
reference current. Each test is one property of that law.
"""
import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from hill_muscle_ros.model.equations import (DEFAULT_CHRONAXIE_S, DEFAULT_CURRENT_REF_A,
                                             equivalent_pulse_width, threshold_current)

C = DEFAULT_CHRONAXIE_S
I_REF = DEFAULT_CURRENT_REF_A

widths = st.floats(1e-6, 5e-3)
chronaxies = st.floats(20e-6, 2e-3)
currents = st.floats(1e-3, 0.2)


@given(widths, currents, chronaxies)
def test_at_the_reference_current_the_width_is_its_own_equivalent(pw, i_ref, c):
    assert equivalent_pulse_width(pw, i_ref, i_ref, c) == pw


@pytest.mark.parametrize('pw, i', [(0.0, 0.05), (300e-6, 0.0), (0.0, 0.0)])
def test_no_width_or_no_current_recruits_nothing(pw, i):
    assert equivalent_pulse_width(pw, i, I_REF, C) == 0.0


@given(widths, st.floats(0.01, 0.99), st.floats(0.01, 0.99))
def test_more_current_recruits_more(pw, a, b):
    # Currents below the one that reaches I_ref (k < I_ref): both finite.
    top = threshold_current(pw, I_REF, C)
    low, high = sorted((a * top, b * top))
    if high > low * (1 + 1e-9):
        assert equivalent_pulse_width(pw, low, I_REF, C) < equivalent_pulse_width(
            pw, high, I_REF, C)


@given(st.floats(1e-6, 4e-3), st.floats(1.001, 3.0), st.floats(0.001, I_REF))
def test_a_wider_pulse_recruits_more(pw, factor, i):
    # Below I_ref, k < I_ref at every width: both finite.
    assert equivalent_pulse_width(pw, i, I_REF, C) < equivalent_pulse_width(
        pw * factor, i, I_REF, C)


def test_a_pulse_that_reaches_the_reference_currents_limit_recruits_every_unit():
    # k = I PW / (PW + c) >= I_ref: no width at I_ref does as much.
    pw = 300e-6
    assert equivalent_pulse_width(pw, 2 * threshold_current(pw, I_REF, C), I_REF, C) == math.inf
    assert equivalent_pulse_width(pw, 1.0, I_REF, C) == math.inf


def test_the_threshold_is_twice_the_rheobase_at_the_chronaxie():
    assert threshold_current(C, 0.012, C) == pytest.approx(0.024, rel=1e-15)


@pytest.mark.parametrize('factor', [1e3, 1e6, 1e9])
def test_the_threshold_tends_to_the_rheobase_for_long_pulses(factor):
    # I_th = r (1 + c / PW): within c / PW of r.
    r = 0.012
    assert threshold_current(C * factor, r, C) == pytest.approx(r, rel=1.01 / factor)


def test_no_current_excites_with_a_zero_width():
    assert threshold_current(0.0, 0.012, C) == math.inf


@given(widths, st.floats(0.05, 0.95), chronaxies)
def test_the_unit_at_threshold_is_at_threshold_at_the_equivalent_width(pw, share, c):
    # The unit just excited by (I, PW): r = I PW / (PW + c). At (I_ref, PW_eq)
    # its threshold current is I_ref.
    i = share * threshold_current(pw, I_REF, c)
    r = i * pw / (pw + c)
    pw_eq = equivalent_pulse_width(pw, i, I_REF, c)
    assert threshold_current(pw_eq, r, c) == pytest.approx(I_REF, rel=1e-12)


@given(widths, st.floats(0.05, 0.95), chronaxies)
def test_going_to_the_reference_current_and_back_gives_the_width_again(pw, share, c):
    i = share * threshold_current(pw, I_REF, c)
    pw_eq = equivalent_pulse_width(pw, i, I_REF, c)
    assert equivalent_pulse_width(pw_eq, I_REF, i, c) == pytest.approx(pw, rel=1e-12)



def test_the_documented_defaults_are_the_codes():
    """doc/model.md section 10 gives the chronaxie and reference current the code uses."""
    from pathlib import Path
    doc = (Path(__file__).resolve().parents[1] / 'doc' / 'model.md').read_text(encoding='utf-8')
    section = doc.split('## 10. ')[1].split('\n## ')[0]
    assert C == 459e-6 and '459 µs' in section
    assert I_REF == 0.040 and '40 mA' in section
