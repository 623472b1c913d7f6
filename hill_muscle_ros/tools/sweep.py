"""``hill-muscle sweep``: simulate one protocol over many muscle or limb parameter sets.

A sweep spec (YAML) names a protocol, optional base parameters (or a limb
plant), the parameters to vary and the instants to sample. The parameter sets
are cut into chunks; each chunk is simulated at once by a batch engine
(:class:`~hill_muscle_ros.model.batch.MuscleBatch` for the muscle,
:class:`~hill_muscle_ros.model.limb_batch.LimbBatch` for a limb) on a Dask
worker, either of a local cluster started for the sweep or of an existing one
given by its scheduler address. The result is a tidy Parquet table: one row
per parameter set and sample time.

Spec keys::

    protocol: II                 # I, II or a protocol YAML (relative to the spec)
    params: muscle.yaml          # optional base parameters file (same rules)
    rate_hz: 1000                # optional step rate [Hz] (else the file's, else 1000)
    sample_times_s: [1.0, 6.0]   # [s] instants to sample, multiples of 1 / rate_hz
    vary:                        # a grid of every combination ...
      f_iso_max_n: [30, 45, 60]                      # listed values
      k_se_n_per_m: {low: 5e3, high: 2e4, n: 4, log: true}   # or a range of n
    samples: 64                  # ... or, with ranges only (no n), a Latin
    seed: 0                      # hypercube of this many sets (seed default 0)

A limb sweep gives ``plant`` (a limb plant file, as ``hill-muscle simulate
--plant`` reads) instead of ``params``, a limb protocol, and names the plant's
parameters in ``vary`` with the plant file's dotted names: ``joint.<field>``
(a :class:`~hill_muscle_ros.model.limb.JointParams` field) and
``<muscle>.<field>`` (a muscle's ``moment_arm_m``, ``reference_angle_rad`` or
any :class:`~hill_muscle_ros.model.params.MuscleParams` field)::

    plant: knee.yaml
    protocol: protocols/knee_extension.yaml
    sample_times_s: [1.0, 2.0]
    vary:
      quadriceps.f_iso_max_n: [1000.0, 1500.0]
      joint.stiffness_n_m_per_rad: {low: 10.0, high: 20.0, n: 3}

Its rows hold ``theta_rad`` and one ``<muscle>_force_n`` column per muscle
(the names of ``hill-muscle simulate --plant``'s CSV) instead of ``force_n``.

Dask, SciPy and pyarrow are imported only by the functions that need them:
the rest of the package runs without them. This module has no rclpy.
"""
from __future__ import annotations

import contextlib
import dataclasses
import itertools
import logging
import math
import os
import signal
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence

import numpy as np
import yaml

from .. import resources
from ..model import LimbOutOfRange, MuscleBatch, MuscleParams, Protocol, simulate_limb_batch
from ..model.limb import LimbPlant, LimbProtocol
from ..model.plant_fields import PlantNameError, plant_field, plant_value, replaced_plant
from ..model.protocol import safe_load_yaml
from ..model.simulate import sample_times
from ..params_file import load_muscle_params, load_plant
from .common import UserError, bounded_number

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
#: Largest automatic chunk (sets per task). A batch step's cost is mostly
#: fixed (measured 70-100 us for 1 to 256 muscles), so the fewer and larger
#: the chunks the faster: on 2 cores, 1024 sets of Protocol II ran at 650
#: sets/s in chunks of 256 and 900 in chunks of 512, but 80-100 sets/s for
#: 256 sets in chunks of 32. Ctrl-C loses at most the chunks running.
MAX_AUTO_CHUNK = 512
#: Largest automatic chunk of a limb sweep. A limb batch steps each limb on
#: its own (:mod:`~hill_muscle_ros.model.limb_batch`), so a chunk costs the
#: same per set at any size, and one knee set of a few seconds already takes
#: seconds: small chunks balance the workers and move the progress bar, for a
#: task overhead of milliseconds.
MAX_AUTO_LIMB_CHUNK = 4
#: Value of the ``worker`` column for rows computed in this process (no Dask).
LOCAL_WORKER = 'local'
#: [s] how long to wait for an existing scheduler to answer.
CONNECT_TIMEOUT_S = 10.0
#: Width of the text progress bar, in characters.
PROGRESS_WIDTH = 30


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


# --------------------------------------------------------------------------- spec

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


# --------------------------------------------------------------------------- simulation

def simulate_forces(protocol: Protocol, params: Sequence[MuscleParams], rate_hz: float,
                    sample_indices: Sequence[int]) -> np.ndarray:
    """[N] MTU force of many muscles at some steps of one protocol, all at once.

    Muscle i follows :func:`~hill_muscle_ros.model.simulate.simulate` with
    ``params[i]``: the sample of step k shows the state at t_k with the command
    of t_k applied; the step from t_k to t_(k+1) holds u(t_k) and ramps dl_MT.
    The run stops at the last sample.

    :param protocol: the protocol every muscle replays
    :param params: the muscles' parameters (K >= 1)
    :param rate_hz: [Hz] step rate, 1 / dt
    :param sample_indices: step indices to sample, ascending
    :return: [N] force, shape (K, len(sample_indices))
    """
    last = max(sample_indices)
    t = sample_times(protocol.duration_s, rate_hz)[:last + 1]
    dl = np.asarray(protocol.dl_mt(t), dtype=float)
    # Pulse widths map through each muscle's own recruitment curve.
    r = np.column_stack([np.asarray(protocol.command(t, p), dtype=float) for p in params])
    batch = MuscleBatch(params)
    dt = 1.0 / rate_hz
    wanted = {k: j for j, k in enumerate(sample_indices)}
    force = np.empty((len(params), len(sample_indices)))
    batch.set_recruitment(r[0])
    if 0 in wanted:
        force[:, wanted[0]] = batch.outputs().force_n
    for k in range(last):
        batch.step(r[k], dl[k + 1], dt)
        if k + 1 in wanted:
            batch.set_recruitment(r[k + 1])
            force[:, wanted[k + 1]] = batch.outputs().force_n
    return force


def run_chunk(set_ids: Sequence[int], params: Sequence[MuscleParams], protocol: Protocol,
              rate_hz: float, sample_indices: Sequence[int]) -> dict:
    """One task: simulate a chunk of parameter sets; runs on a Dask worker or here.

    :return: ``set_ids``, ``force_n`` (K, S) and ``worker`` (the address of the
        Dask worker that ran it, or ``local``)
    """
    force = simulate_forces(protocol, params, rate_hz, sample_indices)
    return {'set_ids': list(set_ids), 'force_n': force, 'worker': _worker()}


def run_limb_chunk(set_ids: Sequence[int], plants: Sequence[LimbPlant],
                   protocol: LimbProtocol, rate_hz: float,
                   sample_indices: Sequence[int]) -> dict:
    """One task of a limb sweep: simulate a chunk of plants with a
    :class:`~hill_muscle_ros.model.limb_batch.LimbBatch`; runs on a Dask worker or here.

    :return: ``set_ids``, ``theta_rad`` (K, S), ``force_n`` (K, M, S) and ``worker``
    :raises SweepError: naming the parameter set of a limb driven beyond its
        muscles' length range
    """
    try:
        theta, force = simulate_limb_batch(plants, protocol, rate_hz, sample_indices)
    except LimbOutOfRange as err:
        raise SweepError(f'parameter set {set_ids[err.limb]}: {err.message}') from None
    return {'set_ids': list(set_ids), 'theta_rad': theta, 'force_n': force,
            'worker': _worker()}


def _worker() -> str:
    """The address of the Dask worker running this, or ``local``."""
    try:
        from distributed import get_worker
        return get_worker().address
    except (ImportError, ValueError):   # not inside a Dask worker
        return LOCAL_WORKER


def _chunk_task(spec: SweepSpec) -> Callable[..., dict]:
    """The task that simulates a chunk of the spec's sets."""
    return run_chunk if spec.plant is None else run_limb_chunk


def chunk_ranges(n_sets: int, n_workers: int, chunk: int | None = None,
                 max_chunk: int = MAX_AUTO_CHUNK) -> list[range]:
    """Consecutive ranges of set indices, one per task.

    :param n_workers: workers that share the tasks (0: this process alone)
    :param chunk: sets per task (default: an equal share per worker, at most
        ``max_chunk``)
    :param max_chunk: largest automatic chunk (:data:`MAX_AUTO_CHUNK`, or
        :data:`MAX_AUTO_LIMB_CHUNK` for a limb)
    """
    if chunk is None:
        chunk = max(1, min(max_chunk, math.ceil(n_sets / max(n_workers, 1))))
    return [range(i, min(i + chunk, n_sets)) for i in range(0, n_sets, chunk)]


# --------------------------------------------------------------------------- output

def force_columns(spec: SweepSpec) -> list[str]:
    """The output columns between ``t_s`` and ``worker``: ``force_n`` for the
    muscle; ``theta_rad`` and ``<muscle>_force_n`` per muscle for a limb."""
    if spec.plant is None:
        return ['force_n']
    return ['theta_rad'] + [f'{name}_force_n' for name in spec.muscle_names]


def to_table(spec: SweepSpec, results: Sequence[dict], complete: bool):
    """The tidy pyarrow table: one row per set and sample time, ordered by set.

    Columns: ``set_id``, the varied parameters, ``t_s``, those of
    :func:`force_columns`, ``worker``.
    """
    import pyarrow as pa

    results = sorted(results, key=lambda r: r['set_ids'][0])
    outputs = force_columns(spec)
    columns: dict[str, list] = {'set_id': []}
    columns.update({n: [] for n in spec.names})
    columns.update({'t_s': [], **{c: [] for c in outputs}, 'worker': []})
    for res in results:
        if spec.plant is None:
            series = [res['force_n']]
        else:
            series = [res['theta_rad']] + [res['force_n'][:, i]
                                           for i in range(len(spec.muscle_names))]
        for row, set_id in enumerate(res['set_ids']):
            values = spec.values[set_id]
            for j, t in enumerate(spec.sample_times_s):
                columns['set_id'].append(set_id)
                for n, v in zip(spec.names, values):
                    columns[n].append(list(v) if isinstance(v, tuple) else v)
                columns['t_s'].append(t)
                for c, x in zip(outputs, series):
                    columns[c].append(float(x[row, j]))
                columns['worker'].append(res['worker'])
    metadata = {'hill_muscle_ros.protocol': spec.protocol.name,
                'hill_muscle_ros.rate_hz': repr(spec.rate_hz),
                'hill_muscle_ros.n_sets': str(len(spec.sets)),
                'hill_muscle_ros.complete': 'true' if complete else 'false'}
    if spec.plant is not None:
        metadata['hill_muscle_ros.plant'] = (f'{spec.plant.joint.name}: '
                                             f'{", ".join(spec.muscle_names)}')
    return pa.table(columns).replace_schema_metadata(metadata)


def _max_chunk(spec: SweepSpec) -> int:
    return MAX_AUTO_CHUNK if spec.plant is None else MAX_AUTO_LIMB_CHUNK


def check_out(path: Path, overwrite: bool) -> None:
    """Refuse an output that exists, before any simulation, unless ``overwrite``.

    :raises SweepError: naming the file (and ``--overwrite``), or a directory
    """
    if path.is_dir():
        raise SweepError(f'{path}: --out is a directory; give the Parquet file to write')
    if path.exists() and not overwrite:
        raise SweepError(f'{path} exists: pass --overwrite to replace it, or choose '
                         'another --out')


def write_parquet(path: Path, table) -> None:
    """Write the table; a failure to write names the file."""
    import pyarrow.parquet as pq

    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        pq.write_table(table, path)
    except OSError as err:
        raise SweepError(f'{path}: cannot write Parquet: {err.strerror or err}') from None


# --------------------------------------------------------------------------- execution

class Progress:
    """A one-line text progress bar on a stream (no tqdm)."""

    def __init__(self, total_sets: int, stream=None) -> None:
        self.total = total_sets
        self.done = 0
        self.stream = sys.stderr if stream is None else stream
        self.start = time.perf_counter()

    def advance(self, n_sets: int) -> None:
        self.done += n_sets
        filled = PROGRESS_WIDTH * self.done // max(self.total, 1)
        elapsed = time.perf_counter() - self.start
        end = '\n' if self.done >= self.total else ''
        self.stream.write(f'\r[{"#" * filled}{"." * (PROGRESS_WIDTH - filled)}] '
                          f'{self.done}/{self.total} sets, {elapsed:.1f} s{end}')
        self.stream.flush()


@dataclass
class SweepResult:
    """What :func:`run_sweep` computed.

    :param results: the finished chunks (see :func:`run_chunk`)
    :param complete: False if the sweep was interrupted
    :param elapsed_s: [s] wall time of the simulation, cluster start-up excluded
    """

    results: list
    complete: bool
    elapsed_s: float

    @property
    def n_sets(self) -> int:
        return sum(len(r['set_ids']) for r in self.results)


def run_local(spec: SweepSpec, chunk: int | None = None,
              on_chunk: Callable[[int], None] | None = None) -> SweepResult:
    """Run every chunk in this process, without Dask (a reference and a fallback)."""
    results = []
    task = _chunk_task(spec)
    start = time.perf_counter()
    try:
        for ids in chunk_ranges(len(spec.sets), 0, chunk, _max_chunk(spec)):
            results.append(task(list(ids), [spec.sets[i] for i in ids], spec.protocol,
                                spec.rate_hz, spec.sample_indices))
            if on_chunk:
                on_chunk(len(ids))
    except KeyboardInterrupt:
        return SweepResult(results, False, time.perf_counter() - start)
    return SweepResult(results, True, time.perf_counter() - start)


def run_on_client(spec: SweepSpec, client, chunk: int | None = None,
                  on_chunk: Callable[[int], None] | None = None) -> SweepResult:
    """Run the chunks as tasks on a Dask client's cluster.

    On Ctrl-C the unfinished tasks are cancelled and the finished ones kept.
    """
    from distributed import as_completed

    n_workers = max(len(client.scheduler_info(n_workers=-1)['workers']), 1)
    start = time.perf_counter()
    # The protocol goes to every worker once rather than with each task. A key
    # of its own (hash=False): a content-hashed key is shared with an earlier
    # sweep's copy, which the scheduler may be releasing just then, and the
    # tasks that need it would be cancelled.
    [protocol] = client.scatter([spec.protocol], broadcast=True, hash=False)
    task = _chunk_task(spec)
    futures = [client.submit(task, list(ids), [spec.sets[i] for i in ids], protocol,
                             spec.rate_hz, spec.sample_indices, pure=False)
               for ids in chunk_ranges(len(spec.sets), n_workers, chunk, _max_chunk(spec))]
    results = []
    completed = None

    def keep(res) -> None:
        results.append(res)
        if on_chunk:
            on_chunk(len(res['set_ids']))

    try:
        # The results come with the futures, fetched by the client's own
        # thread: this thread calls nothing that waits on it until a task
        # fails. A Ctrl-C inside such a wait (``Future.result``) that came
        # before the wait's coroutine had started made distributed's
        # ``sync`` cancel a future it did not have yet: a NameError that
        # tornado printed with its traceback (distributed 2026.8.0; 1 of 45
        # interrupted sweeps at idle priority beside two busy cores).
        completed = as_completed(futures, with_results=True, raise_errors=False)
        for future, res in completed:
            if future.status != 'finished':
                error = SweepError(f'a sweep task {future.status} on the cluster: '
                                   f'{_task_error(future)}')
                _cancel_and_settle(client, futures, completed, keep)
                raise error
            keep(res)
    except KeyboardInterrupt:
        _cancel_and_settle(client, futures, completed, keep)
        return SweepResult(results, False, time.perf_counter() - start)
    return SweepResult(results, True, time.perf_counter() - start)


#: [s] bound on the wait for the futures' last results after a Ctrl-C or a
#: failed task (:func:`_cancel_and_settle`).
SETTLE_TIMEOUT_S = CONNECT_TIMEOUT_S
#: [s] how often that wait looks for them.
SETTLE_POLL_S = 0.02


def _cancel_and_settle(client, futures, completed, keep: Callable) -> None:
    """Cancel the unfinished ``futures``, then take what ``completed`` (their
    ``as_completed(with_results=True)``, None before it exists) still hands out, at most
    :data:`SETTLE_TIMEOUT_S`: a finished task's result goes to ``keep``.

    The client's thread fetches each finished task's result; the cluster
    closed while one was still on its way left that fetch a
    ``CommClosedError``, which tornado printed with its traceback (1 of 75
    interrupted sweeps at idle priority beside two busy cores). A second
    Ctrl-C stops the wait.
    """
    try:
        client.cancel([f for f in futures if not f.done()])
        deadline = time.monotonic() + SETTLE_TIMEOUT_S
        while completed is not None and not completed.is_empty() and time.monotonic() < deadline:
            if not completed.has_ready():
                time.sleep(SETTLE_POLL_S)
                continue
            future, res = next(completed)
            if future.status == 'finished':
                keep(res)
    except KeyboardInterrupt:
        pass


def _task_error(future) -> str:
    """What went wrong with a task that did not finish, in one line."""
    try:
        err = future.exception(timeout=CONNECT_TIMEOUT_S)
    except Exception as cancelled:   # a cancelled future raises instead
        err = cancelled
    return f'{type(err).__name__}: {err}'


def run_sweep(spec: SweepSpec, scheduler: str | None = None, workers: int | None = None,
              chunk: int | None = None, progress: Progress | None = None) -> SweepResult:
    """Run a sweep: here (``workers == 0``), on a new LocalCluster of ``workers``
    processes (default: the core count), or on the cluster at ``scheduler``.

    :raises SweepError: if Dask is missing or the scheduler does not answer
    """
    on_chunk = progress.advance if progress else None
    if workers == 0 and scheduler is None:
        return run_local(spec, chunk, on_chunk)
    try:
        from distributed import Client, LocalCluster
    except ImportError as err:
        raise SweepError(f'sweeps on Dask need the `sweep` extra (pip install '
                         f'dask distributed pyarrow): {err}') from None
    if scheduler is not None:
        try:
            client = Client(scheduler, timeout=f'{CONNECT_TIMEOUT_S}s')
        except (OSError, TimeoutError, ValueError) as err:
            raise SweepError(f'--scheduler {scheduler}: cannot connect: {err}') from None
        with client:
            return run_on_client(spec, client, chunk, on_chunk)
    n = workers if workers is not None else (os.cpu_count() or 1)
    # One thread per worker process: the batch engine holds the GIL.
    with _sigint_ignored():
        # The worker processes inherit the ignored Ctrl-C (and Python leaves an
        # ignored SIGINT ignored): a terminal's Ctrl-C reaches the whole process
        # group, and only this process should act on it, cancelling the tasks
        # and closing the cluster in order, not the workers dying mid-task.
        cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True,
                               dashboard_address=None, silence_logs=logging.ERROR)
    # The scheduler runs in this process: the filter stays until it is closed.
    scheduler_log = logging.getLogger('distributed.scheduler')
    quiet = ClientGoneFilter()
    scheduler_log.addFilter(quiet)
    try:
        with cluster, Client(cluster) as client:
            quiet.client = client
            client.register_plugin(quiet_heartbeat_on_close(), name=QUIET_HEARTBEAT_PLUGIN)
            return run_on_client(spec, client, chunk, on_chunk)
    finally:
        scheduler_log.removeFilter(quiet)


#: What a Dask worker logs when a heartbeat to the scheduler fails
#: (``distributed.worker.Worker.heartbeat``, distributed 2026.8.0).
HEARTBEAT_FAILED = 'Failed to communicate with scheduler during heartbeat'
#: The name the plugin of :func:`quiet_heartbeat_on_close` is registered under.
QUIET_HEARTBEAT_PLUGIN = 'hill_muscle_ros-quiet-heartbeat-on-close'


def quiet_heartbeat_on_close():
    """A Dask worker plugin that drops one log record: the heartbeat failure a
    worker logs, with a traceback, when its own close cut the heartbeat that
    was on the wire.

    ``Worker.close`` marks the worker closing, then closes its connection pool;
    a heartbeat still waiting for the scheduler's answer then fails with
    ``CommClosedError`` and is logged at ERROR (dask/distributed#7105). On our
    own cluster, which this process closes on purpose (at the end, or after
    Ctrl-C), that record says nothing; it came in 2 of 54 Ctrl-C'd sweeps on
    a loaded machine, the worker closing both times. The same failure in a worker that is
    not closing is kept. (A class built here: ``WorkerPlugin`` comes with the
    optional ``sweep`` extra, and Dask pickles it by value.)
    """
    from distributed.diagnostics.plugin import WorkerPlugin

    class QuietHeartbeatOnClose(WorkerPlugin):
        def setup(self, worker) -> None:
            logging.getLogger('distributed.worker').addFilter(
                HeartbeatOnCloseFilter(worker))

    return QuietHeartbeatOnClose()


class HeartbeatOnCloseFilter(logging.Filter):
    """Drop :data:`HEARTBEAT_FAILED` while ``worker`` is closing or closed."""

    def __init__(self, worker) -> None:
        super().__init__()
        self.worker = worker

    def filter(self, record: logging.LogRecord) -> bool:
        if not record.getMessage().startswith(HEARTBEAT_FAILED):
            return True
        from distributed.core import Status
        return self.worker.status not in (Status.closing, Status.closed,
                                          Status.closing_gracefully)


#: What the scheduler logs, at CRITICAL with a traceback, when it tells a
#: client that has closed its connection that a result is in memory
#: (``distributed.scheduler.Scheduler.report``, distributed 2026.8.0).
CLIENT_GONE = 'Closed comm <BatchedSend: closed> while trying to write'


class ClientGoneFilter(logging.Filter):
    """Drop :data:`CLIENT_GONE` once our own client is closing or closed.

    After Ctrl-C this process closes its client, then its cluster, on
    purpose; a task that finished meanwhile makes the scheduler report its
    result to the closed client, and that record (seen once, in the Ctrl-C
    test of a loaded fresh-clone run) says nothing. The same record while
    the client is open is kept.
    """

    def __init__(self) -> None:
        super().__init__()
        self.client = None

    def filter(self, record: logging.LogRecord) -> bool:
        if not record.getMessage().startswith(CLIENT_GONE) or self.client is None:
            return True
        return self.client.status not in ('closing', 'closed')


@contextlib.contextmanager
def _sigint_ignored():
    """Ignore SIGINT in this block (only the main thread can set handlers)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


# --------------------------------------------------------------------------- command line

#: Exit status of a sweep stopped by Ctrl-C (128 + SIGINT, as shells report it).
EXIT_INTERRUPTED = 130


#: argparse type for ``--workers``: 0 (no Dask) or more worker processes.
_workers = bounded_number(int, low=0)
#: argparse type for ``--chunk``: parameter sets per task, at least 1.
_chunk = bounded_number(int, low=1)


def add_parser(sub) -> None:
    """The ``sweep`` subcommand's parser, on ``hill-muscle``'s subparsers."""
    import argparse
    p = sub.add_parser(
        'sweep', help='simulate a protocol over many parameter sets on Dask (Parquet out)',
        description='Simulate one protocol for every parameter set of a sweep spec (a grid '
                    'or a Latin hypercube) on a Dask cluster, and write the force (a limb: '
                    'the joint angle and each muscle\'s force) at the sample times as a '
                    'Parquet table: one row per set and time.',
        epilog='examples:\n'
               '  hill-muscle sweep config/sweep_example.yaml --out sweep.parquet\n'
               '  hill-muscle sweep config/sweep_knee_example.yaml --out knee.parquet\n'
               '  hill-muscle sweep spec.yaml --out sweep.parquet --workers 2\n'
               '  hill-muscle sweep spec.yaml --out sweep.parquet '
               '--scheduler tcp://10.0.0.5:8786',
        formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument('spec', type=Path, metavar='SPEC.yaml', help='the sweep spec')
    p.add_argument('--out', required=True, type=Path, metavar='PARQUET',
                   help='the Parquet file to write (also written on Ctrl-C, with the '
                        'sets finished so far); an existing file is an error unless '
                        '--overwrite is given')
    p.add_argument('--overwrite', action='store_true',
                   help='replace the --out file if it exists')
    where = p.add_mutually_exclusive_group()
    where.add_argument('--scheduler', metavar='ADDRESS',
                       help='use the running Dask cluster at this scheduler address '
                            '(tcp://host:port); its workers need hill_muscle_ros installed')
    where.add_argument('--workers', type=_workers, metavar='N',
                       help='start a local Dask cluster of N worker processes (default: '
                            'the number of cores); 0 runs here without Dask')
    p.add_argument('--chunk', type=_chunk, metavar='SETS',
                   help=f'parameter sets per task (default: an equal share per worker, '
                        f'at most {MAX_AUTO_CHUNK}, {MAX_AUTO_LIMB_CHUNK} for a limb); smaller '
                        f'chunks move the progress bar more often (a muscle\'s also run '
                        f'slower)')


def _plant_text(spec: SweepSpec) -> str:
    """`` on the knee (quadriceps, hamstrings)`` for a limb sweep, else nothing."""
    if spec.plant is None:
        return ''
    return f' on the {spec.plant.joint.name} ({", ".join(spec.muscle_names)})'


def cmd_sweep(args) -> int:
    """Run ``hill-muscle sweep``; user errors become the CLI's one-line errors."""
    try:
        check_out(args.out, args.overwrite)
        spec = load_spec(args.spec)
        try:
            import pyarrow  # noqa: F401 - fail before simulating, not after
        except ImportError as err:
            raise SweepError(f'sweeps need the `sweep` extra (pip install dask '
                             f'distributed pyarrow): {err}') from None
        where = ('this process (no Dask)' if args.workers == 0 and not args.scheduler
                 else args.scheduler or
                 f'a local Dask cluster of {args.workers or os.cpu_count() or 1} workers')
        print(f'{len(spec.sets)} parameter sets x {len(spec.sample_times_s)} sample times, '
              f'{spec.protocol.name}{_plant_text(spec)} at {spec.rate_hz:g} Hz, on {where}',
              flush=True)
        result = run_sweep(spec, args.scheduler, args.workers, args.chunk,
                           Progress(len(spec.sets)))
        write_parquet(args.out, to_table(spec, result.results, result.complete))
    except SweepError as err:
        raise UserError(str(err)) from None
    rate = result.n_sets / result.elapsed_s if result.elapsed_s > 0 else float('inf')
    rows = result.n_sets * len(spec.sample_times_s)
    if not result.complete:
        print(f'\ninterrupted: wrote {rows} rows ({result.n_sets} of {len(spec.sets)} '
              f'sets) to {args.out}', file=sys.stderr)
        return EXIT_INTERRUPTED
    print(f'wrote {rows} rows to {args.out} ({result.n_sets} sets in '
          f'{result.elapsed_s:.2f} s, {rate:.1f} sets/s)')
    return 0
