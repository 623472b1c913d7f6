"""A sweep's result as a tidy Parquet table: one row per parameter set and sample time.

pyarrow is imported only by the functions that need it.
"""
from __future__ import annotations

from pathlib import Path
from typing import Sequence

from .spec import SweepError, SweepSpec


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
