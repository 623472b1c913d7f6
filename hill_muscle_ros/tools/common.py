"""What the ``hill-muscle`` subcommands share: the user's error, argument types,
the step rate from a parameters file, and the writers of CSV tables and bags.

It sits below every command module (:mod:`.cli`, :mod:`.limb_cli`, :mod:`.fit`,
:mod:`.sweep`) and imports none of them: :mod:`.cli` dispatches down to the
commands, and the commands take what they share from here.
"""
from __future__ import annotations

import argparse
import math
from pathlib import Path
from typing import Callable, Sequence

import numpy as np

PROG = 'hill-muscle'
#: Exit status for errors in the user's input (as argparse uses).
EXIT_USAGE = 2
#: [Hz] step rate when neither ``--rate`` nor the parameters file gives one.
DEFAULT_RATE_HZ = 1000.0
#: Key of the step rate in the simulator node's parameters file.
RATE_KEY = 'rate_hz'


class UserError(Exception):
    """An error in the user's input: reported in one line, exit status 2."""


def bounded_number(kind: Callable[[str], float] = float, *, low: float | None = None,
                   high: float | None = None, low_inclusive: bool = True, unit: str = '',
                   noun: str | None = None) -> Callable[[str], float]:
    """An argparse ``type``: a finite number of ``kind`` within ``low`` to ``high``.

    Its errors name the rule and the text, e.g. ``must be in [1, 64], got '0'``.

    :param kind: ``int`` or ``float``, which parses the text
    :param low: lower bound (``None``: none); accepted unless ``low_inclusive`` is false
    :param high: upper bound, accepted (``None``: none)
    :param unit: the unit written after the range in the message (``s``)
    :param noun: what a text that does not parse should be (default ``an integer``
        or ``a number``; e.g. ``a number of seconds``)
    """
    noun = noun or ('an integer' if kind is int else 'a number')
    unit = f' {unit}' if unit else ''
    if low is not None and high is not None:
        rule = f'in {"[" if low_inclusive else "("}{low:g}, {high:g}]{unit}'
    elif low is None:
        rule = f'at most {high:g}{unit}' if high is not None else 'finite'
    elif low_inclusive:
        rule = f'at least {low:g}{unit}'
    else:
        rule = 'positive' if low == 0 else f'above {low:g}{unit}'
    if kind is not int and high is None and low is not None:
        rule += ' and finite'

    def parse(text: str) -> float:
        try:
            value = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f'must be {noun}, got {text!r}') from None
        above = low is None or (value >= low if low_inclusive else value > low)
        if not (math.isfinite(value) and above and (high is None or value <= high)):
            raise argparse.ArgumentTypeError(f'must be {rule}, got {text!r}')
        return value
    return parse


#: argparse type for ``--rate``: a positive finite number of hertz.
positive_rate = bounded_number(float, low=0.0, low_inclusive=False, noun='a number of hertz')


def rate_from_file(node_settings: dict, source: Path) -> float | None:
    """The ``rate_hz`` a parameters file gives, validated, or ``None``."""
    if RATE_KEY not in node_settings:
        return None
    value = node_settings[RATE_KEY]
    if (isinstance(value, bool) or not isinstance(value, (int, float))
            or not math.isfinite(value) or value <= 0.0):
        raise UserError(f'{source}: `{RATE_KEY}` must be positive and finite, got {value!r}')
    return float(value)


def write_csv_table(path: Path, header: Sequence[str], columns: Sequence[np.ndarray]) -> int:
    """Write a header line and one row per sample, each number in its shortest
    exact form: Python's ``repr`` of the float, the fewest digits that read back
    as the same float64 (``0.0005``, where a fixed 17 digits writes
    ``0.00050000000000000001``).

    :param path: the CSV file; missing parent directories are created
    :param header: the column names
    :param columns: one array per column, all of the same length
    :return: the number of data rows written
    """
    rows = zip(*(np.asarray(c, dtype=float).tolist() for c in columns))
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        with path.open('w', encoding='utf-8', newline='') as f:
            f.write(','.join(header) + '\n')
            count = 0
            for row in rows:
                f.write(','.join(map(repr, row)) + '\n')
                count += 1
    except OSError as err:
        raise UserError(f'{path}: cannot write CSV: {err.strerror or err}') from None
    return count


def summary_times(duration_s: float) -> list[float]:
    """[s] the end of each whole second, and the end of the protocol if later."""
    times = [float(s) for s in range(1, int(math.floor(duration_s)) + 1)]
    if not times or times[-1] < duration_s:
        times.append(duration_s)
    return times


def write_bag(path: Path, write: Callable[[], None]) -> None:
    """Write a bag to ``path`` with ``write()``: a bag that cannot be written
    is the user's error (``UserError``, its message); then say where it is."""
    from ..recording import BagOutputError   # rclpy and the bag writer only here
    try:
        write()
    except BagOutputError as err:
        raise UserError(str(err)) from None
    print(f'wrote bag {path}')
