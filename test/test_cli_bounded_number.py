"""common.bounded_number: the argparse type of every bounded number option."""
import argparse

import pytest

from hill_muscle_ros.tools.common import bounded_number


def _error(parse, text: str) -> str:
    with pytest.raises(argparse.ArgumentTypeError) as err:
        parse(text)
    return str(err.value)


def test_integer_within_the_range_is_returned_as_an_int():
    value = bounded_number(int, low=1, high=64)('7')
    assert value == 7 and type(value) is int


def test_both_ends_of_a_closed_range_are_accepted():
    parse = bounded_number(float, low=0.0, high=1.0)
    assert (parse('0'), parse('1')) == (0.0, 1.0)


def test_integer_option_refuses_a_fraction_naming_the_text():
    assert _error(bounded_number(int, low=1), '1.5') == "must be an integer, got '1.5'"


def test_unparsable_text_names_the_noun():
    parse = bounded_number(float, low=0.0, high=1.0, noun='a number of seconds')
    assert _error(parse, 'soon') == "must be a number of seconds, got 'soon'"


def test_value_above_the_range_names_the_range_and_unit():
    parse = bounded_number(float, low=0.0, high=1.0, unit='s')
    assert _error(parse, '1.5') == "must be in [0, 1] s, got '1.5'"


def test_excluded_low_end_is_refused_with_an_open_bracket():
    parse = bounded_number(float, low=0.0, high=100.0, low_inclusive=False)
    assert _error(parse, '0') == "must be in (0, 100], got '0'"


def test_lower_bound_alone_reads_at_least():
    assert _error(bounded_number(int, low=0), '-1') == "must be at least 0, got '-1'"


def test_positive_float_refuses_zero_as_not_positive_and_finite():
    parse = bounded_number(float, low=0.0, low_inclusive=False)
    assert _error(parse, '0') == "must be positive and finite, got '0'"


@pytest.mark.parametrize('text', ['nan', 'inf', '-inf'])
def test_float_refuses_non_finite_values(text):
    assert 'must be positive and finite' in _error(
        bounded_number(float, low=0.0, low_inclusive=False), text)


def test_nan_is_refused_even_within_open_bounds():
    assert _error(bounded_number(float), 'nan') == "must be finite, got 'nan'"


def test_argparse_reports_the_option_and_the_rule():
    parser = argparse.ArgumentParser(exit_on_error=False)
    parser.add_argument('--jobs', type=bounded_number(int, low=1, high=64))
    with pytest.raises(argparse.ArgumentError, match=r"--jobs: must be in \[1, 64\], got '0'"):
        parser.parse_args(['--jobs', '0'])
