"""Helpers shared by the environments: argument checks, the control period,
per-episode profiles and the observation history.

No model equations here: the environments step the engines of
:mod:`hill_muscle_ros.model`.
"""
from __future__ import annotations

import dataclasses
import math
import os
from typing import Any, Mapping, Sequence

import gymnasium as gym
import numpy as np

# The FES extensions' fields and their defaults, as the parameters define them.
from ..model.params import _FES_FIELDS, CURVE_FIELDS, MuscleParams

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


def muscle_variant(p: MuscleParams, *, units: str | None = None, length: str | None = None,
                   fes_features: bool = True, overrides: Mapping[str, Any] | None = None,
                   where: str = 'overrides') -> MuscleParams:
    """A muscle changed by an environment's options, in this order: the variant
    fields ``units`` and ``length`` if given; with ``fes_features=False`` every
    FES extension of the dynamics back at the paper's value (delay, activation,
    ``fv_scaling``, fatigue, fibre types, recruitment order, unit length spread;
    the recruitment curve stays, it maps the action to the command); last,
    ``overrides``, any :class:`MuscleParams` fields by name.

    :param where: what to call ``overrides`` in error messages
    :raises ValueError: naming an unknown field, or the field and value that
        :class:`MuscleParams` refuses
    """
    if not isinstance(fes_features, bool):
        raise ValueError(f'`fes_features` must be True or False, got {fes_features!r}')
    changes = {k: v for k, v in (('units', units), ('length', length)) if v is not None}
    if not fes_features:
        changes.update((name, f.default) for name, f in _FES_FIELDS.items()
                       if name not in CURVE_FIELDS)
    if changes:   # MuscleParams names the field and the value it refuses
        p = dataclasses.replace(p, **changes)
    if overrides is None:
        return p
    if not isinstance(overrides, Mapping):
        raise ValueError(f'`{where}` must map MuscleParams fields to values, '
                         f'got {overrides!r}')
    known = MuscleParams.field_names()
    unknown = sorted(str(k) for k in overrides if k not in known)
    if unknown:
        raise ValueError(f'`{where}`: unknown MuscleParams field `{unknown[0]}` '
                         f'(known: {", ".join(known)})')
    try:
        return dataclasses.replace(p, **overrides)
    except (TypeError, ValueError) as err:
        raise ValueError(f'`{where}`: {err}') from None


def muscle_params(params: Any, units: str | None = None, length: str | None = None,
                  fes_features: bool = True,
                  overrides: Mapping[str, Any] | None = None) -> MuscleParams:
    """The muscle of an environment: a :class:`MuscleParams`, a parameters
    YAML file (``config/muscle.yaml`` format) or ``None`` (the paper's muscle),
    changed by the options as :func:`muscle_variant` says.

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
    return muscle_variant(p, units=units, length=length, fes_features=fes_features,
                          overrides=overrides)


def check_pulse_widths(values: Any, high: np.ndarray, labels: Sequence[str], name: str,
                       rows: int | None = None) -> np.ndarray:
    """Pulse widths [s] of one action (``rows=None``) or of K actions, validated.

    :param values: the action(s): M widths, or K rows of M
    :param high: [s] the widest accepted width of each of the M muscles
    :param labels: what each width is, for messages (``'hamstrings pulse width'``)
    :param name: the argument's name, ``action`` or ``actions``
    :return: [s] float64 widths, shape (M,) or (K, M)
    :raises ValueError: on a wrong size, or a NaN or out-of-range width, naming
        its index (``action[1]``, ``actions[3]``, ``actions[3, 1]``), muscle and value
    """
    m = len(high)
    shape = (m,) if rows is None else (rows, m)
    a = np.asarray(values, dtype=np.float64)
    if a.size != int(np.prod(shape)):
        what = 'one pulse width [s]' if m == 1 else f'{m} pulse widths [s]'
        per = '' if rows is None else f' per environment ({rows})'
        raise ValueError(f'`{name}` must hold {what}{per}, got shape {np.shape(values)}')
    a = a.reshape(shape)
    bad = ~((a >= 0.0) & (a <= high))   # also true for NaN
    if bad.any():
        index = np.unravel_index(int(np.flatnonzero(bad)[0]), shape)
        j = int(index[-1])
        shown = [int(i) for i in index] if m > 1 else [int(i) for i in index[:-1]]
        where = f'[{", ".join(map(str, shown))}]' if shown else ''
        raise ValueError(f'`{name}{where}` ({labels[j]}) must be in [0, {high[j]:g}] s, '
                         f'got {float(a[index])!r}')
    return a


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
    """The last ``length`` samples of a few signals, newest first, as one vector;
    with ``batch`` K, one such history per sub-environment.

    :param length: samples kept (>= 1)
    :param width: signals per sample
    :param batch: sub-environments (``None``: a single environment)
    """

    def __init__(self, length: int, width: int, batch: int | None = None) -> None:
        self._buf = np.zeros((length, width) if batch is None else (batch, length, width))

    def fill(self, sample) -> None:
        """Start an episode: every slot holds ``sample`` (no earlier samples exist);
        ``sample`` has shape (width,), or (K, width) with a batch."""
        self._buf[:] = np.asarray(sample)[..., None, :]

    def push(self, sample) -> None:
        """Add the newest sample, dropping the oldest."""
        self._buf[..., 1:, :] = self._buf[..., :-1, :]
        self._buf[..., 0, :] = sample

    @property
    def newest(self) -> np.ndarray:
        """The newest sample (a view)."""
        return self._buf[..., 0, :]

    def flat(self) -> np.ndarray:
        """``[newest sample, previous, ...]`` flattened, per sub-environment (a copy)."""
        return self._buf.reshape(*self._buf.shape[:-2], -1).copy()


class TrackingEnv(gym.Env):
    """What both tracking environments share: the episode's clock of control
    periods, the reset option that holds one target, the observation history.

    Subclasses set :attr:`TARGET_OPTION` and write :meth:`check_target` and
    :meth:`draw_episode`; the native vector environments call the same two, so
    a sub-environment draws exactly what a single environment draws.
    """

    metadata = {'render_modes': []}
    #: The name of the reset option that holds one target for the whole episode.
    TARGET_OPTION = ''

    def _init_episode(self, *, control_period_s: Any, episode_duration_s: Any,
                      history_length: Any, stim_cost: Any, hold_min_s: Any, hold_max_s: Any,
                      render_mode: Any, width: int) -> None:
        """Validate and keep the settings of the episode's clock and history.

        :param width: signals per history sample
        :raises ValueError: naming the argument and the value
        """
        if render_mode is not None:
            raise ValueError(f'`render_mode` must be None (no rendering), got {render_mode!r}')
        self.render_mode = None
        self.n_steps = steps_per_period(control_period_s)
        self.control_period_s = self.n_steps * MODEL_DT_S
        self.n_periods = whole_multiple(
            'episode_duration_s', check_positive('episode_duration_s', episode_duration_s),
            self.control_period_s, 'control periods')
        self.history_length = check_count('history_length', history_length)
        self.stim_cost = check_positive('stim_cost', stim_cost, allow_zero=True)
        self._hold = check_hold_range(hold_min_s, hold_max_s, self.control_period_s)
        self._history = History(self.history_length, width)
        self._targets = np.zeros(self.n_periods)
        self._k = 0

    def check_target(self, value: Any) -> float:
        """The fixed target of the reset option, validated (in the subclass)."""
        raise NotImplementedError

    def draw_episode(self, rng: np.random.Generator, fixed: float | None) -> Any:
        """One episode's profiles from ``rng`` (in the subclass)."""
        raise NotImplementedError

    def fixed_target(self, options: Mapping[str, Any] | None) -> float | None:
        """The reset options: the fixed target if given (validated), else ``None``.

        :raises ValueError: on an unknown option or a bad target
        """
        options = dict(options or {})
        value = options.pop(self.TARGET_OPTION, None)
        if options:
            raise ValueError(f'unknown reset options {sorted(options)}; '
                             f'known: {self.TARGET_OPTION}')
        return None if value is None else self.check_target(value)

    def stimulation_cost(self, pw: np.ndarray) -> np.ndarray:
        """The reward's stimulation term, ``stim_cost`` mean_i (PW_i / PW_max,i)^2.

        :param pw: [s] widths, shape (..., M) for M muscles
        :return: [-] shape (...)
        """
        return self.stim_cost * np.mean((pw / self._pw_max) ** 2, axis=-1)

    def _check_running(self) -> None:
        if self._k >= self.n_periods:
            raise ValueError('the episode is over (truncated): call reset() first')

    def _target_after(self, k: int) -> float:
        """The target of the period that starts at control instant ``k`` (the
        last period's after the end)."""
        return float(self._targets[min(k, self.n_periods - 1)])
