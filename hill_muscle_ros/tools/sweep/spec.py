"""A sweep spec: reading and validating it into the parameter sets to simulate.

:func:`load_spec` reads a spec file, :func:`parse_spec` validates its mapping
(the keys are described in :mod:`hill_muscle_ros.tools.sweep`) into a
:class:`SweepSpec`: one validated parameter set (or limb plant) per row of the
grid or the Latin hypercube. Errors are :class:`SweepError`, one line naming
the key and the value.
"""
from __future__ import annotations

import dataclasses
import itertools
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np
import yaml

from ... import resources
from ...model import MuscleParams, Protocol
from ...model.limb import LimbPlant, LimbProtocol
from ...model.plant_fields import PlantNameError, plant_field, plant_value, replaced_plant
from ...model.protocol import safe_load_yaml
from ...params_file import load_muscle_params, load_plant

#: [Hz] step rate when neither the spec nor its parameters file gives one
#: (the same default as ``hill-muscle simulate``).
DEFAULT_RATE_HZ = 1000.0
#: Keys a sweep spec may hold.
SPEC_KEYS = ('protocol', 'params', 'plant', 'rate_hz', 'sample_times_s', 'vary',
             'samples', 'seed')
#: Keys of a range in ``vary``.
RANGE_KEYS = ('low', 'high', 'n', 'log')
#: Default seed of the Latin hypercube, so that a spec without one is reproducible.
DEFAULT_SEED = 0
#: A sample time closer than this many steps to a step instant is that instant
#: (times like 0.3 s are not exact multiples of 1 / 1000 Hz in binary).
STEP_TOLERANCE = 1e-6


class SweepError(ValueError):
    """An error in the sweep spec or its files: one line naming the key and value."""


@dataclass(frozen=True)
class SweepSpec:
    """A validated sweep.

    :param protocol: the protocol every set replays (a limb protocol for a limb)
    :param rate_hz: [Hz] step rate, 1 / dt
    :param sample_times_s: [s] sample instants, on the step grid, ascending
    :param names: the varied parameters, in spec order
    :param sets: one validated :class:`MuscleParams` per parameter set, or one
        :class:`LimbPlant` for a limb sweep
    :param values: per set, the values of ``names``
    :param plant: the base plant of a limb sweep, ``None`` for the muscle
    """

    protocol: Protocol | LimbProtocol
    rate_hz: float
    sample_times_s: tuple[float, ...]
    names: tuple[str, ...]
    sets: tuple[MuscleParams, ...] | tuple[LimbPlant, ...]
    values: tuple[tuple[Any, ...], ...]
    plant: LimbPlant | None = None

    @property
    def muscle_names(self) -> tuple[str, ...]:
        """The limb's muscles, in the plant's order (none for a muscle sweep)."""
        return () if self.plant is None else tuple(m.name for m in self.plant.muscles)

    @property
    def sample_indices(self) -> tuple[int, ...]:
        """Step indices of the sample times."""
        return tuple(int(round(t * self.rate_hz)) for t in self.sample_times_s)


_FIELDS = {f.name: f for f in dataclasses.fields(MuscleParams)}


def _is_number(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def _finite_number(source: str, key: str, value: Any) -> float:
    if not _is_number(value) or not math.isfinite(value):
        raise SweepError(f'{source}: `{key}` must be a finite number, got {value!r}')
    return float(value)


def _resolve(base: Path, text: Any, key: str, source: str) -> Path:
    if not isinstance(text, str) or not text:
        raise SweepError(f'{source}: `{key}` must be a file path, got {text!r}')
    path = Path(text).expanduser()
    return path if path.is_absolute() else base / path


def _range_axis(source: str, name: str, spec: Mapping[str, Any], lhs: bool,
                field: dataclasses.Field) -> dict:
    """Validate a ``{low, high, n, log}`` range of parameter ``field``; returns its fields."""
    key = f'vary.{name}'
    unknown = sorted(str(k) for k in spec if k not in RANGE_KEYS)
    if unknown:
        raise SweepError(f'{source}: unknown key `{key}.{unknown[0]}` '
                         f'(a range has {", ".join(RANGE_KEYS)})')
    if field.type != 'float':
        raise SweepError(f'{source}: `{key}` is not a real-valued parameter, so it '
                         f'takes a list of values, not a range; got {dict(spec)!r}')
    for bound in ('low', 'high'):
        if bound not in spec:
            raise SweepError(f'{source}: `{key}` needs `{bound}`, got {dict(spec)!r}')
    low = _finite_number(source, f'{key}.low', spec['low'])
    high = _finite_number(source, f'{key}.high', spec['high'])
    if not low < high:
        raise SweepError(f'{source}: `{key}.low` must be below `{key}.high`, '
                         f'got low={spec["low"]!r}, high={spec["high"]!r}')
    log = spec.get('log', False)
    if not isinstance(log, bool):
        raise SweepError(f'{source}: `{key}.log` must be true or false, got {log!r}')
    if log and low <= 0.0:
        raise SweepError(f'{source}: `{key}.low` must be positive for a log range, '
                         f'got {spec["low"]!r}')
    n = spec.get('n')
    if lhs:
        if n is not None:
            raise SweepError(f'{source}: `{key}.n` is not used with `samples` '
                             f'(the Latin hypercube draws `samples` sets), got {n!r}')
    elif isinstance(n, bool) or not isinstance(n, int) or n < 2:
        raise SweepError(f'{source}: `{key}.n` must be an integer >= 2 for a grid, '
                         f'got {n!r}')
    return {'low': low, 'high': high, 'n': n, 'log': log}


def _grid_values(axis: dict) -> list[float]:
    if axis['log']:
        return [float(v) for v in np.geomspace(axis['low'], axis['high'], axis['n'])]
    return [float(v) for v in np.linspace(axis['low'], axis['high'], axis['n'])]


def _lhs_values(axes: Sequence[dict], samples: int, seed: int) -> list[tuple[float, ...]]:
    """``samples`` points of a seeded Latin hypercube over the ranges ``axes``."""
    from scipy.stats import qmc   # here: importing the module stays light

    unit = qmc.LatinHypercube(d=len(axes), rng=seed).random(samples)
    columns = []
    for j, axis in enumerate(axes):
        u = unit[:, j]
        if axis['log']:
            lo, hi = math.log(axis['low']), math.log(axis['high'])
            columns.append(np.exp(lo + u * (hi - lo)))
        else:
            columns.append(axis['low'] + u * (axis['high'] - axis['low']))
    return [tuple(float(c[i]) for c in columns) for i in range(samples)]


def _sample_times(source: str, value: Any, duration_s: float, rate_hz: float
                  ) -> tuple[float, ...]:
    key = 'sample_times_s'
    if not isinstance(value, list) or not value:
        raise SweepError(f'{source}: `{key}` must be a non-empty list of times in '
                         f'seconds, got {value!r}')
    times = []
    for i, t in enumerate(value):
        t = _finite_number(source, f'{key}[{i}]', t)
        if not 0.0 <= t <= duration_s:
            raise SweepError(f'{source}: `{key}[{i}]` must be within the protocol, '
                             f'0..{duration_s:g} s, got {value[i]!r}')
        steps = t * rate_hz
        if abs(steps - round(steps)) > STEP_TOLERANCE:
            raise SweepError(f'{source}: `{key}[{i}]` must be a multiple of the step '
                             f'1/{rate_hz:g} s, got {value[i]!r}')
        times.append(round(steps) / rate_hz)
    if len(set(times)) != len(times) or times != sorted(times):
        raise SweepError(f'{source}: `{key}` must be ascending without repeats, '
                         f'got {value!r}')
    return tuple(times)


def parse_spec(doc: Any, source: str = '<spec>', base_dir: Path | None = None) -> SweepSpec:
    """Validate a sweep spec (a parsed YAML mapping) and build every parameter set.

    :param doc: the spec mapping
    :param source: what it came from, for error messages
    :param base_dir: directory relative paths are resolved against (default: cwd)
    :raises SweepError: naming the key and the value of the first problem
    """
    base_dir = Path('.') if base_dir is None else base_dir
    if not isinstance(doc, dict):
        raise SweepError(f'{source}: expected a mapping with `protocol`, `vary` and '
                         f'`sample_times_s`, got {type(doc).__name__}')
    unknown = sorted(str(k) for k in doc if k not in SPEC_KEYS)
    if unknown:
        raise SweepError(f'{source}: unknown key `{unknown[0]}` '
                         f'(known: {", ".join(SPEC_KEYS)})')
    for key in ('protocol', 'vary', 'sample_times_s'):
        if key not in doc:
            raise SweepError(f'{source}: missing key `{key}`')
    limb = doc.get('plant') is not None
    if limb:
        protocol, base, node = _load_limb(doc, source, base_dir)
    else:
        protocol, base, node = _load_muscle(doc, source, base_dir)

    rate = doc.get('rate_hz', node.get('rate_hz', DEFAULT_RATE_HZ))
    if not _is_number(rate) or not math.isfinite(rate) or rate <= 0.0:
        raise SweepError(f'{source}: `rate_hz` must be positive and finite, got {rate!r}')
    rate = float(rate)
    times = _sample_times(source, doc['sample_times_s'], protocol.duration_s, rate)

    vary = doc['vary']
    if not isinstance(vary, dict) or not vary:
        raise SweepError(f'{source}: `vary` must map parameter names to a list of values '
                         f'or a range {{low, high, n, log}}, got {vary!r}')
    fields = {}   # the dataclass field of each varied parameter
    for key in vary:
        if limb:
            try:
                fields[key] = plant_field(str(key), base, label='vary.').spec
            except PlantNameError as err:
                raise SweepError(f'{source}: {err}') from None
        elif key in _FIELDS:
            fields[key] = _FIELDS[key]
        else:
            raise SweepError(f'{source}: {_unknown(str(key))}')
    samples = doc.get('samples')
    lhs = samples is not None
    if lhs and (isinstance(samples, bool) or not isinstance(samples, int) or samples < 1):
        raise SweepError(f'{source}: `samples` must be a positive integer, got {samples!r}')
    seed = doc.get('seed', DEFAULT_SEED)
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise SweepError(f'{source}: `seed` must be a non-negative integer, got {seed!r}')
    if 'seed' in doc and not lhs:
        raise SweepError(f'{source}: `seed` is used only with `samples`, got seed={seed!r}')

    names = tuple(str(k) for k in vary)
    axes = []
    for key, spec in vary.items():
        if isinstance(spec, dict):
            axes.append(_range_axis(source, key, spec, lhs, fields[key]))
        elif isinstance(spec, list) and spec:
            if lhs:
                raise SweepError(f'{source}: with `samples`, `vary.{key}` must be a range '
                                 f'{{low, high, log}}, got {spec!r}')
            axes.append(spec)
        else:
            raise SweepError(f'{source}: `vary.{key}` must be a non-empty list of values '
                             f'or a range {{low, high, n, log}}, got {spec!r}')
    if lhs:
        combos = _lhs_values(axes, samples, seed)
    else:
        combos = list(itertools.product(
            *(_grid_values(a) if isinstance(a, dict) else a for a in axes)))

    sets, values = [], []
    for i, combo in enumerate(combos):
        try:
            if limb:
                p = replaced_plant(base, dict(zip(names, combo)))
            else:
                p = dataclasses.replace(base, **dict(zip(names, combo)))
        except (ValueError, TypeError) as err:
            shown = ', '.join(f'{n}={v!r}' for n, v in zip(names, combo))
            raise SweepError(f'{source}: parameter set {i} ({shown}): {err}') from None
        sets.append(p)
        values.append(tuple(plant_value(p, n) if limb else getattr(p, n) for n in names))
    return SweepSpec(protocol, rate, times, names, tuple(sets), tuple(values),
                     base if limb else None)


def _load_muscle(doc: Mapping[str, Any], source: str, base_dir: Path
                 ) -> tuple[Protocol, MuscleParams, dict]:
    """The protocol and the base parameters of a muscle sweep, and the file's node keys."""
    name = doc['protocol']
    if not isinstance(name, str) or not name:
        raise SweepError(f'{source}: `protocol` must be I, II or a path, got {name!r}')
    path = (resources.protocol_path(name) if name in resources.BUILTIN_PROTOCOLS
            else _resolve(base_dir, name, 'protocol', source))
    params_path = (resources.default_params_file() if doc.get('params') is None
                   else _resolve(base_dir, doc['params'], 'params', source))
    try:
        protocol = Protocol.from_yaml(path)
        base, node = load_muscle_params(params_path)
    except ValueError as err:   # ProtocolError is a ValueError; both name the file
        raise SweepError(str(err)) from None
    return protocol, base, node


def _load_limb(doc: Mapping[str, Any], source: str, base_dir: Path
               ) -> tuple[LimbProtocol, LimbPlant, dict]:
    """The limb protocol and the base plant of a limb sweep, and the file's node keys."""
    if doc.get('params') is not None:
        raise SweepError(f'{source}: `params` (a muscle\'s parameters) and `plant` (a limb) '
                         f'exclude each other; set the muscles\' parameters in the plant '
                         f'file, got params={doc["params"]!r}')
    name = doc['protocol']
    if not isinstance(name, str) or not name or name in resources.BUILTIN_PROTOCOLS:
        raise SweepError(f'{source}: with `plant`, `protocol` must be the path of a limb '
                         f'protocol (inputs per muscle), got {name!r}')
    path = _resolve(base_dir, name, 'protocol', source)
    plant_path = _resolve(base_dir, doc['plant'], 'plant', source)
    try:
        protocol = LimbProtocol.from_yaml(path)
        plant, node = load_plant(plant_path)
    except ValueError as err:   # ProtocolError is a ValueError; both name the file
        raise SweepError(str(err)) from None
    try:
        protocol.commands(np.zeros(1), plant)   # a protocol muscle the plant lacks
    except ValueError as err:
        raise SweepError(f'{path}: {err}') from None
    return protocol, plant, node


def _unknown(key: str) -> str:
    """The message for a ``vary`` name that is not a parameter of the muscle."""
    return f'unknown parameter `vary.{key}` (known: {", ".join(_FIELDS)})'


def load_spec(path: str | Path) -> SweepSpec:
    """Read and validate a sweep spec file (:func:`parse_spec`)."""
    path = Path(path)
    try:
        doc = safe_load_yaml(path.read_text(encoding='utf-8'))
    except (OSError, UnicodeDecodeError) as err:
        raise SweepError(f'{path}: cannot read sweep spec: {err}') from None
    except yaml.YAMLError as err:
        raise SweepError(f'{path}: not valid YAML: {err}') from None
    return parse_spec(doc, str(path), path.parent)
