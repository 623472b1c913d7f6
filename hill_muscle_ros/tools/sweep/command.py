"""``hill-muscle sweep``: the subcommand's parser and the glue from its options to
the spec, the run and the Parquet file.

User errors raise :class:`~hill_muscle_ros.tools.common.UserError`.
"""
from __future__ import annotations

import os
import sys
from pathlib import Path

from ..common import UserError, bounded_number
from .execution import Progress, run_sweep
from .output import check_out, to_table, write_parquet
from .simulation import MAX_AUTO_CHUNK, MAX_AUTO_LIMB_CHUNK
from .spec import SweepError, SweepSpec, load_spec

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
