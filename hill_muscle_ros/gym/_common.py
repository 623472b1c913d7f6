"""Helpers shared by the environments: argument checks, the control period,
per-episode profiles and the observation history.

No model equations here: the environments step the engines of
:mod:`hill_muscle_ros.model`.
"""
from __future__ import annotations

import dataclasses
import math
import os
from typing import Any

import numpy as np

from ..model.params import MuscleParams

#: [s] The model's integration step inside every control period: 1 kHz, the
#: step the shipped presets are validated at (the FES quadriceps' stiff tendon
#: needs about 3 ms or less with RK4 at a fixed step).
MODEL_DT_S = 1.0e-3
#: [s] Accepted control periods: 10 to 50 ms (20 to 100 Hz), the rates of a
#: stimulator's pulse-width updates.
CONTROL_PERIOD_MIN_S = 0.010
CONTROL_PERIOD_MAX_S = 0.050
#: Relative tolerance when a period must be a whole number of model steps: the
#: decimal 0.02 is not exactly 20 * 0.001 in binary.
_WHOLE_TOLERANCE = 1e-9


def check_positive(name: str, value: Any, *, allow_zero: bool = False) -> float:
    """A finite number > 0 (or >= 0 with ``allow_zero``), as a float.

    :raises ValueError: naming ``name`` and the value
    """
    ok = not isinstance(value, bool) and isinstance(value, (int, float, np.floating, np.integer))
    x = float(value) if ok else math.nan
    if not (math.isfinite(x) and (x >= 0.0 if allow_zero else x > 0.0)):
        word = 'non-negative' if allow_zero else 'positive'
        raise ValueError(f'`{name}` must be {word} and finite, got {value!r}')
    return x


def whole_multiple(name: str, value_s: float, unit_s: float, unit_name: str) -> int:
    """The number of ``unit_s`` in ``value_s``, which must be a whole number >= 1.

    :raises ValueError: naming ``name`` if it is not
    """
    n = round(value_s / unit_s)
    if n < 1 or abs(n * unit_s - value_s) > _WHOLE_TOLERANCE * max(value_s, unit_s):
        raise ValueError(f'`{name}` must be a whole number of {unit_name} '
                         f'({unit_s:g} s), got {value_s!r}')
    return n


def steps_per_period(control_period_s: Any) -> int:
    """Model steps of :data:`MODEL_DT_S` in one control period.

    :param control_period_s: [s] control period, in [10, 50] ms and a whole
        number of model steps
    :raises ValueError: naming the value otherwise
    """
    period = check_positive('control_period_s', control_period_s)
    if not CONTROL_PERIOD_MIN_S <= period <= CONTROL_PERIOD_MAX_S:
        raise ValueError(f'`control_period_s` must be in [{CONTROL_PERIOD_MIN_S:g}, '
                         f'{CONTROL_PERIOD_MAX_S:g}] s, got {control_period_s!r}')
    return whole_multiple('control_period_s', period, MODEL_DT_S, 'model steps')


def check_count(name: str, value: Any) -> int:
    """An integer >= 1.

    :raises ValueError: naming ``name`` and the value
    """
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
        raise ValueError(f'`{name}` must be an integer >= 1, got {value!r}')
    return int(value)


def check_hold_range(hold_min_s: Any, hold_max_s: Any, period_s: float) -> tuple[int, int]:
    """Shortest and longest hold, in control periods.

    :raises ValueError: if a bound is not positive, or the range holds no
        whole number of periods
    """
    lo_s = check_positive('hold_min_s', hold_min_s)
    hi_s = check_positive('hold_max_s', hold_max_s)
    lo = max(1, math.ceil(lo_s / period_s - _WHOLE_TOLERANCE))
    hi = math.floor(hi_s / period_s + _WHOLE_TOLERANCE)
    if hi < lo:
        raise ValueError(f'`hold_min_s` .. `hold_max_s` must contain a whole number of '
                         f'control periods ({period_s:g} s), got {hold_min_s!r} .. '
                         f'{hold_max_s!r}')
    return lo, hi


def muscle_params(params: Any, units: str | None, length: str | None) -> MuscleParams:
    """The muscle of an environment: a :class:`MuscleParams`, a parameters
    YAML file (``config/muscle.yaml`` format) or ``None`` (the paper's muscle),
    with the variant fields ``units`` and ``length`` replaced if given.

    :raises ValueError: naming the file, the field and the value on any defect
    """
    if params is None:
        p = MuscleParams()
    elif isinstance(params, MuscleParams):
        p = params
    elif isinstance(params, (str, os.PathLike)):
        from ..params_file import load_muscle_params   # needs PyYAML: only for files
        p, _node = load_muscle_params(params)
    else:
        raise ValueError(f'`params` must be a MuscleParams, a YAML path or None, '
                         f'got {params!r}')
    changes = {k: v for k, v in (('units', units), ('length', length)) if v is not None}
    return dataclasses.replace(p, **changes) if changes else p


def hold_lengths(rng: np.random.Generator, n_periods: int, lo: int, hi: int) -> np.ndarray:
    """Random hold lengths in control periods, in [lo, hi], covering ``n_periods``.

    :return: the start period of every hold (the first is 0), increasing
    """
    starts = [0]
    while True:
        nxt = starts[-1] + int(rng.integers(lo, hi + 1))
        if nxt >= n_periods:
            return np.asarray(starts, dtype=np.int64)
        starts.append(nxt)


def piecewise_constant(starts: np.ndarray, values: np.ndarray, n_periods: int) -> np.ndarray:
    """Per-period values: ``values[i]`` from period ``starts[i]`` to the next start."""
    out = np.empty(n_periods)
    ends = list(starts[1:]) + [n_periods]
    for s, e, v in zip(starts, ends, values):
        out[s:e] = v
    return out


class History:
    """The last ``length`` samples of a few signals, newest first, as one vector.

    :param length: samples kept (>= 1)
    :param width: signals per sample
    """

    def __init__(self, length: int, width: int) -> None:
        self._buf = np.zeros((length, width))

    def fill(self, sample) -> None:
        """Start an episode: every slot holds ``sample`` (no earlier samples exist)."""
        self._buf[:] = sample

    def push(self, sample) -> None:
        """Add the newest sample, dropping the oldest."""
        self._buf[1:] = self._buf[:-1]
        self._buf[0] = sample

    @property
    def newest(self) -> np.ndarray:
        """The newest sample (a view)."""
        return self._buf[0]

    def flat(self) -> np.ndarray:
        """``[newest sample, previous, ...]`` flattened (a copy)."""
        return self._buf.reshape(-1).copy()
