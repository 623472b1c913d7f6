"""The limb in the ``hill-muscle`` command: ``simulate --plant`` and ``animate``.

``hill-muscle simulate --plant PLANT.yaml --protocol P.yaml`` runs a limb
protocol offline (no ROS): with ``--csv`` it writes one row per step with the
columns of :func:`~hill_muscle_ros.model.limb.limb_columns`, without it prints
the joint angle in degrees and each muscle's force at the end of each second;
``--bag`` also writes the run with the limb node's topics
(:func:`~hill_muscle_ros.recording.offline.write_limb_bag`).
``hill-muscle animate`` draws the same run as a stick-figure GIF
(:mod:`hill_muscle_ros.animation`).

Errors in the user's files raise :class:`~hill_muscle_ros.tools.common.UserError`
naming the file and the key (one line, exit status 2).
"""
from __future__ import annotations

import argparse
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .. import resources
from ..model.limb import LimbPlant, LimbProtocol, LimbResult, limb_columns, simulate_limb
from ..model.protocol import safe_load_yaml
from ..params_file import load_plant
from .common import (DEFAULT_RATE_HZ, PROG, UserError, bounded_number, positive_rate,
                     rate_from_file, summary_times, write_bag, write_csv_table)

#: Options of ``simulate`` that configure the single muscle, not a limb.
MUSCLE_ONLY_OPTIONS = (('params', '--params'), ('units', '--units'), ('length', '--length'))
#: [frames/s] default frame rate of ``animate``: smooth, and a GIF of a few seconds
#: stays small.
DEFAULT_FPS = 25.0
#: [frames/s] the GIF format counts frame durations in hundredths of a second.
MAX_FPS = 100.0


@dataclass(frozen=True)
class LimbRun:
    """One offline limb run and what produced it.

    :param plant: the joint and its muscles
    :param protocol: the limb protocol
    :param rate_hz: [Hz] step rate, 1 / dt
    :param result: the time series
    """

    plant: LimbPlant
    protocol: LimbProtocol
    rate_hz: float
    result: LimbResult


def add_plant_option(parser: argparse.ArgumentParser) -> None:
    """``--plant`` of ``simulate``: a limb instead of the single muscle."""
    parser.add_argument('--plant', type=Path, metavar='YAML',
                        help='a limb plant file (a joint and its muscles, '
                             'e.g. config/knee.yaml): simulate the limb; --protocol is '
                             'then a limb protocol (inputs per muscle)')


def add_animate_parser(sub) -> None:
    """The ``animate`` subcommand."""
    anim = sub.add_parser(
        'animate', help='draw a limb run as a stick-figure GIF',
        description='Simulate a limb protocol offline and write it as an animated GIF: '
                    'the proximal segment fixed, the moving segment turning with the '
                    'joint angle, each muscle coloured by its recruitment.',
        epilog='example:\n'
               f'  {PROG} animate --plant config/knee.yaml '
               '--protocol config/protocols/knee_extension.yaml --out leg.gif',
        formatter_class=argparse.RawDescriptionHelpFormatter)
    anim.add_argument('--plant', type=Path, required=True, metavar='YAML',
                      help='the limb plant file (e.g. config/knee.yaml)')
    anim.add_argument('--protocol', type=Path, required=True, metavar='YAML',
                      help='the limb protocol file')
    anim.add_argument('--out', type=Path, required=True, metavar='GIF',
                      help='the GIF file to write')
    anim.add_argument('--fps', type=_fps, default=DEFAULT_FPS, metavar='FPS',
                      help=f'frames per second of simulated time (default {DEFAULT_FPS:g})')
    anim.add_argument('--rate', type=positive_rate, metavar='HZ',
                      help=f'simulation step rate (default: `rate_hz` of the plant file, '
                           f'else {DEFAULT_RATE_HZ:g})')


#: argparse type for ``--fps``: a number of frames per second in (0, MAX_FPS].
_fps = bounded_number(float, low=0.0, high=MAX_FPS, low_inclusive=False)


def load_limb_run(plant_path: Path, protocol_path: Path, rate_hz: float | None) -> LimbRun:
    """Load the plant and the protocol, check they fit, and simulate.

    :param rate_hz: [Hz] the step rate, or ``None`` for the plant file's ``rate_hz``
    :raises UserError: naming the file and the key on any defect
    """
    _check_limb_protocol(protocol_path)
    try:
        plant, node = load_plant(plant_path)
        protocol = LimbProtocol.from_yaml(protocol_path)
    except ValueError as err:   # ProtocolError is a ValueError
        if _is_muscle_protocol(protocol_path):
            raise UserError(f'{protocol_path} is a single-muscle protocol (`recruitment`); '
                            f'{_limb_plays()}') from None
        raise UserError(str(err)) from None
    rate = rate_hz if rate_hz is not None else (
        rate_from_file(node, plant_path) or DEFAULT_RATE_HZ)
    try:
        result = simulate_limb(plant, protocol, rate)
    except ValueError as err:   # a protocol muscle the plant lacks, a limb out of range
        raise UserError(f'{protocol_path}: {err}') from None
    return LimbRun(plant, protocol, rate, result)


def _limb_plays() -> str:
    """What a limb runs, for the messages about a muscle protocol given to it."""
    return ('a limb (--plant) plays a limb protocol file, with inputs per muscle, e.g. '
            f'{resources.config_dir() / "protocols" / "knee_extension.yaml"}')


def _check_limb_protocol(path: Path) -> None:
    """A built-in protocol name (``II``) given for a limb: say what a limb plays.

    :raises UserError: if ``path`` names a built-in protocol and no file
    """
    name = resources.builtin_protocol(str(path))
    if name is not None and not path.exists():
        raise UserError(f'--protocol {path}: the built-in protocols I and II are '
                        f'single-muscle protocols; {_limb_plays()}')


def _is_muscle_protocol(path: Path) -> bool:
    """Whether ``path`` holds a mapping with a single-muscle protocol's ``recruitment``
    and no limb protocol's ``muscles``."""
    try:
        doc = safe_load_yaml(path.read_text(encoding='utf-8'))
    except Exception:   # noqa: BLE001 -- unreadable: LimbProtocol's message says so
        return False
    return isinstance(doc, dict) and 'recruitment' in doc and 'muscles' not in doc


def write_limb_csv(path: Path, run: LimbRun) -> int:
    """Write one row per step, columns of :func:`limb_columns`, each number in its
    shortest exact form (:func:`~hill_muscle_ros.tools.common.write_csv_table`).

    :return: the number of data rows written
    """
    columns = limb_columns(run.plant)
    return write_csv_table(path, columns, [run.result[c] for c in columns])


def format_limb_table(run: LimbRun) -> str:
    """The joint angle in degrees and each muscle's force at the end of each second."""
    r = run.result
    names = [m.name for m in run.plant.muscles]
    headers = ['t_s', 'theta_deg'] + [f'{n}_force_n' for n in names]
    widths = [max(len(h), 9) for h in headers]
    lines = [f'{run.protocol.name}: {run.plant.joint.name} with {", ".join(names)}, '
             f'{run.rate_hz:g} Hz ({len(r.t_s)} samples)',
             '  '.join(f'{h:>{w}}' for h, w in zip(headers, widths))]
    for t in summary_times(run.protocol.duration_s):
        k = int(np.argmin(np.abs(r.t_s - t)))
        values = [r.t_s[k], math.degrees(r['theta_rad'][k])] + [
            r[f'{n}_force_n'][k] for n in names]
        formats = ['{:.3f}', '{:.2f}'] + ['{:.1f}'] * len(names)
        lines.append('  '.join(f'{fmt.format(float(v)):>{w}}'
                               for fmt, v, w in zip(formats, values, widths)))
    return '\n'.join(lines)


def cmd_simulate_limb(args: argparse.Namespace) -> int:
    """``hill-muscle simulate --plant ...``."""
    given = [flag for attr, flag in MUSCLE_ONLY_OPTIONS if getattr(args, attr, None)]
    if given:
        raise UserError(f'{given[0]} applies to the single muscle, not to a limb (--plant): '
                        'set each muscle\'s parameters in the plant file')
    run = load_limb_run(args.plant, Path(args.protocol), args.rate)
    if args.bag is not None:
        from ..recording.offline import write_limb_bag   # rclpy and the bag writer only here
        write_bag(args.bag, lambda: write_limb_bag(args.bag, run.result, run.plant,
                                                   run.protocol))
    if args.csv is not None:
        rows = write_limb_csv(args.csv, run)
        print(f'wrote {rows} rows to {args.csv}')
    else:
        print(format_limb_table(run))
    return 0


def cmd_animate(args: argparse.Namespace) -> int:
    """``hill-muscle animate``: the run as a GIF."""
    from ..animation import write_gif   # matplotlib only for this command
    run = load_limb_run(args.plant, args.protocol, args.rate)
    try:
        frames = write_gif(args.out, run.plant, run.result, args.fps)
    except OSError as err:
        raise UserError(f'{args.out}: cannot write GIF: {err.strerror or err}') from None
    print(f'wrote {frames} frames to {args.out}')
    return 0
