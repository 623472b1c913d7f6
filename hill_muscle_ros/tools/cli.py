"""The ``hill-muscle`` command: offline simulation, the paper's figures, and the ROS nodes.

``simulate``, ``figures`` and ``compile`` (the numba kernels into their disk
cache) run the model core offline and never import rclpy. The node
subcommands (``simulator``, ``player``, ``record``, ``controller``) import
their node module only when called and hand it the rest of the command line
untouched, so ``--ros-args -p name:=value`` works as with ``ros2 run``.

User errors (a malformed protocol or parameters file, a bad option value)
print one line naming the file and the key and exit with status 2; there is
no traceback.
"""
from __future__ import annotations

import argparse
import importlib
import os
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

from .. import resources
from ..model import COLUMNS, LENGTH_CHOICES, UNITS_CHOICES, MuscleParams, Protocol
from ..model import SimulationResult, simulate
from ..model.protocol import PulseProtocol, read_protocol
from ..params_file import load_muscle_params
from . import limb_cli
from .common import (DEFAULT_RATE_HZ, EXIT_USAGE, PROG, RATE_KEY, UserError, positive_rate,
                     rate_from_file, summary_times, write_bag, write_csv_table)

#: The key that makes a protocol file a limb protocol (inputs per muscle).
LIMB_PROTOCOL_KEY = 'muscles'
#: [s] spacing of the rows of the summary table printed without ``--csv``.
TABLE_INTERVAL_S = 1.0
#: Columns of the summary table: result attribute, header, printf format.
TABLE_COLUMNS = (
    ('t_s', 't_s', '{:7.3f}'),
    ('recruitment', 'recruitment', '{:11.3f}'),
    ('dl_mt_m', 'dl_mt_m', '{:9.5f}'),
    ('l_ce_m', 'l_ce_m', '{:9.6f}'),
    ('f_se_n', 'f_se_n', '{:9.3f}'),
    ('force_n', 'force_n', '{:9.3f}'),
)


@dataclass(frozen=True)
class NodeCommand:
    """A subcommand that runs one of the package's ROS 2 nodes.

    :param module: module whose ``main(args)`` runs the node
    :param executable: the node's name for ``ros2 run hill_muscle_ros ...``
    :param summary: one line for ``hill-muscle --help``
    """

    module: str
    executable: str
    summary: str


NODE_COMMANDS = {
    'simulator': NodeCommand('hill_muscle_ros.nodes.simulator', 'simulator',
                             'run the muscle simulator node (ROS 2)'),
    'player': NodeCommand('hill_muscle_ros.nodes.protocol_player', 'protocol_player',
                          'run the protocol player node (ROS 2)'),
    'record': NodeCommand('hill_muscle_ros.nodes.recorder', 'recorder',
                          'run the recorder node (ROS 2)'),
    'controller': NodeCommand('hill_muscle_ros.nodes.force_controller', 'force_controller',
                              'run the force controller node (ROS 2)'),
    'limb': NodeCommand('hill_muscle_ros.nodes.limb', 'limb_simulator',
                        'run the limb simulator node (ROS 2)'),
    'joint-controller': NodeCommand('hill_muscle_ros.nodes.joint_controller',
                                    'joint_controller',
                                    'run the joint-angle controller node (ROS 2)'),
}
_HELP_FLAGS = ('-h', '--help')
_ROS_ARGS = '--ros-args'


@dataclass(frozen=True)
class SimulationRun:
    """One offline run and what produced it, handed to the output writers.

    :param protocol: the protocol that was replayed
    :param params: the muscle parameters, with ``--units``/``--length`` applied
    :param rate_hz: [Hz] step rate, 1 / dt
    :param result: the time series
    """

    protocol: Protocol
    params: MuscleParams
    rate_hz: float
    result: SimulationResult


# --------------------------------------------------------------------------- parsing

def _add_output_options(parser: argparse.ArgumentParser) -> None:
    """Options that choose where ``simulate`` writes its result.

    Each output has its option here and its writer in :func:`write_outputs`.
    """
    parser.add_argument('--csv', metavar='PATH', type=Path,
                        help='write one row per step to this CSV file (SI units, '
                             'column names with unit suffixes such as force_n); '
                             'without it a summary table is printed')
    parser.add_argument('--bag', metavar='DIR', type=Path,
                        help='also write the run as a rosbag2 MCAP bag in simulated time, '
                             'with the topics of a live run (DIR must not exist or be empty)')


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of ``hill-muscle`` with all subcommands."""
    parser = argparse.ArgumentParser(
        prog=PROG,
        description='Hill-type muscle with time-varying recruitment and length memory '
                    '(hill_muscle_ros): offline simulation, figures and ROS 2 nodes.')
    sub = parser.add_subparsers(dest='command', metavar='COMMAND', required=True)

    sim = sub.add_parser(
        'simulate', help='run a protocol offline (no ROS) and print or save the result',
        description='Run a stimulation protocol offline from the resting state and print\n'
                    'the force at the end of each second, or write every step to a CSV.',
        epilog='examples:\n'
               f'  {PROG} simulate --protocol II\n'
               f'  {PROG} simulate --protocol I --units single --csv protocol_I.csv\n'
               f'  {PROG} simulate --protocol my_protocol.yaml --params my_muscle.yaml '
               '--rate 2000\n'
               f'  {PROG} simulate --plant config/knee.yaml '
               '--protocol config/protocols/knee_extension.yaml',
        formatter_class=argparse.RawDescriptionHelpFormatter)
    sim.add_argument('--protocol', required=True, metavar='{I,II,PATH}',
                     help='the paper\'s Protocol I or II (in any case), or a protocol YAML '
                          'file (copy config/protocols/protocol_II.yaml to write one); with '
                          '--plant, a limb protocol file')
    sim.add_argument('--units', choices=UNITS_CHOICES,
                     help='motor units: multi (N virtual units, Eq. 2) or single '
                          '(overrides the parameters file)')
    sim.add_argument('--length', choices=LENGTH_CHOICES,
                     help='length used in the force-length relation: initial (at '
                          'recruitment) or instantaneous (overrides the parameters file)')
    sim.add_argument('--rate', type=positive_rate, metavar='HZ',
                     help=f'output rate in Hz: a sample every 1/HZ s, inputs sampled and '
                          f'held there; the model integrates substeps of at most 1 ms '
                          f'whatever the rate (default: `{RATE_KEY}` of the '
                          f'parameters file, else {DEFAULT_RATE_HZ:g})')
    sim.add_argument('--params', type=Path, metavar='YAML',
                     help='ROS 2 parameters file (`/**:` or `simulator:`, then '
                          '`ros__parameters:`), the one the simulator node loads '
                          f'(default: {resources.default_params_file()})')
    _add_output_options(sim)
    limb_cli.add_plant_option(sim)

    fig = sub.add_parser(
        'figures', help="write PNGs of the paper's Figures 8-11, of the FES extensions "
                        'and of the limb',
        description="Simulate Protocols I and II in the model variants of the paper's "
                    'Figures 8-11, and the protocols of the FES figures (recruitment '
                    'curves, activation, fatigue, fibre types, force-velocity scaling) '
                    'and of the limb (the knee in the four variants); write one PNG per '
                    'figure.')
    fig.add_argument('--out', required=True, type=Path, metavar='DIR',
                     help='directory for the PNG files (created if missing)')
    fig.add_argument('--rate', type=positive_rate, default=None, metavar='HZ',
                     help='step rate of the simulations behind the figures '
                          '(default: 1000 Hz, the figures of this README)')
    sub.add_parser(
        'compile', help='compile every numba kernel into its disk cache ahead of use',
        description='Compile the model\'s numba kernels (the FES muscle, the limb, the '
                    'batches, the paper\'s muscle) into numba\'s disk cache, or load those '
                    'already there, so that no node and no run compiles later: the limb '
                    'node\'s first start in a clean install otherwise takes about 30 s. '
                    'Run it after installing or editing the model; `make test` runs it '
                    'before the tests.')
    limb_cli.add_animate_parser(sub)
    from . import sweep
    sweep.add_parser(sub)
    from . import fit   # the fit itself (scipy, the bag reader) loads on use
    fit.add_fit_parser(sub)

    for name, node in NODE_COMMANDS.items():
        # Listed for the help text only: main() dispatches node commands before
        # argparse, which would otherwise reject ``--ros-args -p x:=1``.
        sub.add_parser(name, help=f'{node.summary}; arguments go to the node',
                       add_help=False)
    return parser


# --------------------------------------------------------------------------- simulate

def _read_muscle_protocol(path: Path) -> Protocol | PulseProtocol:
    """A single-muscle protocol; a limb protocol (one with ``muscles``) gets a
    hint to add ``--plant`` in place of the muscle protocol's complaint.

    :raises ProtocolError: naming the file and the key
    :raises UserError: for a limb protocol
    """
    try:
        return read_protocol(path)
    except ValueError:
        from ..model.protocol import safe_load_yaml
        try:
            doc = safe_load_yaml(path.read_text(encoding='utf-8'))
        except Exception:   # noqa: BLE001 -- unreadable: the muscle protocol's message
            doc = None
        if not (isinstance(doc, dict) and LIMB_PROTOCOL_KEY in doc):
            raise
    raise UserError(f'{path} is a limb protocol (`{LIMB_PROTOCOL_KEY}`: inputs per muscle): '
                    f'add --plant with the limb\'s plant file, e.g. '
                    f'--plant {resources.knee_plant_file()}')


def load_inputs(args: argparse.Namespace) -> tuple[Protocol, MuscleParams, float]:
    """The protocol, parameters and step rate that the options ask for.

    :raises UserError: naming the file and key if a file is malformed
    """
    try:
        protocol_path = resources.find_protocol(args.protocol)
        protocol = _read_muscle_protocol(protocol_path)
        params_path = args.params if args.params is not None else resources.default_params_file()
        params, node_settings = load_muscle_params(params_path)
    except ValueError as err:  # ProtocolError is a ValueError
        raise UserError(str(err)) from None
    overrides = {k: v for k, v in (('units', args.units), ('length', args.length)) if v}
    if overrides:
        params = params.replace(**overrides)
    rate = args.rate
    if rate is None:
        rate = rate_from_file(node_settings, params_path) or DEFAULT_RATE_HZ
    return protocol, params, rate


def write_csv(path: Path, result: SimulationResult) -> int:
    """Write one row per sample, the columns of :data:`~.model.COLUMNS`, each
    number in its shortest exact form (:func:`~.common.write_csv_table`).

    :param path: the CSV file; missing parent directories are created
    :return: the number of data rows written
    """
    headers = [name for _, name in COLUMNS]
    columns = [getattr(result, attr) for attr, _ in COLUMNS]
    if result.activation is not None:   # a pulse protocol: a_<c> per channel
        headers += [f'a_{c + 1}' for c in range(result.activation.shape[1])]
        columns += list(result.activation.T)
    return write_csv_table(path, headers, columns)


def format_table(run: SimulationRun) -> str:
    """The summary table: the state at the end of each second."""
    p, result = run.params, run.result
    lines = [f'{run.protocol.name}: units={p.units}, length={p.length}, '
             f'{run.rate_hz:g} Hz ({len(result.t_s)} samples)',
             '  '.join(f'{header:>{len(fmt.format(0.0))}}' for _, header, fmt in TABLE_COLUMNS)]
    for t in summary_times(run.protocol.duration_s):
        k = result.at(t)
        lines.append('  '.join(fmt.format(float(getattr(result, attr)[k]))
                               for attr, _, fmt in TABLE_COLUMNS))
    return '\n'.join(lines)


def write_outputs(args: argparse.Namespace, run: SimulationRun) -> None:
    """Write the run where the output options say (:func:`_add_output_options`)."""
    if args.bag is not None:
        from ..recording.offline import write_simulation_bag
        write_bag(args.bag, lambda: write_simulation_bag(args.bag, run.result, run.params,
                                                         run.protocol))
    if args.csv is not None:
        rows = write_csv(args.csv, run.result)
        print(f'wrote {rows} rows to {args.csv}')
    else:
        print(format_table(run))


def cmd_simulate(args: argparse.Namespace) -> int:
    if args.plant is not None:
        return limb_cli.cmd_simulate_limb(args)
    protocol, params, rate = load_inputs(args)
    run = SimulationRun(protocol, params, rate, simulate(protocol, params, rate))
    write_outputs(args, run)
    return 0


# --------------------------------------------------------------------------- figures

def cmd_figures(args: argparse.Namespace) -> int:
    # matplotlib is imported only for this command.
    from .figures import write_figures
    try:
        rate = {} if args.rate is None else {'rate_hz': args.rate}
        paths = write_figures(args.out, **rate)
    except OSError as err:
        raise UserError(f'{args.out}: cannot write figures: {err.strerror or err}') from None
    for path in paths:
        print(f'wrote {path}')
    return 0


# --------------------------------------------------------------------------- nodes

def node_usage(name: str) -> str:
    """Help for a node subcommand, printed without importing rclpy."""
    node = NODE_COMMANDS[name]
    return (f'usage: {PROG} {name} [--ros-args [-p NAME:=VALUE ...] '
            f'[--params-file FILE] [-r FROM:=TO ...]]\n\n'
            f'{node.summary[0].upper()}{node.summary[1:]}: the same as '
            f'`ros2 run hill_muscle_ros {node.executable}`.\n'
            'It is a ROS 2 node: everything after the subcommand goes to ROS untouched.\n'
            'Set parameters with `--ros-args -p NAME:=VALUE` or '
            '`--ros-args --params-file config/muscle.yaml`;\n'
            'list them while it runs with `ros2 param list`.')


def run_node(name: str, node_args: Sequence[str]) -> int:
    """Import a node module and run its ``main`` with ``node_args``.

    The node gets ``[program, *node_args]``, the shape of ``sys.argv`` that
    ``rclpy.init(args=...)`` expects.
    """
    node = NODE_COMMANDS[name]
    if any(a in _HELP_FLAGS for a in _args_before_ros(node_args)):
        print(node_usage(name))
        return 0
    try:
        module = importlib.import_module(node.module)
    except ModuleNotFoundError as err:
        if err.name == node.module or node.module.startswith(f'{err.name}.'):
            raise UserError(f'the `{name}` node is not available: module '
                            f'{node.module} is not installed') from None
        raise UserError(f'the `{name}` node cannot start: {err} '
                        '(is ROS 2 / rclpy installed in this environment?)') from None
    status = module.main([f'{PROG} {name}', *node_args])
    return 0 if status is None else int(status)


def _args_before_ros(args: Sequence[str]) -> Sequence[str]:
    """The arguments before ``--ros-args`` (those are not ROS's to parse)."""
    args = list(args)
    return args[:args.index(_ROS_ARGS)] if _ROS_ARGS in args else args


# --------------------------------------------------------------------------- main

def cmd_animate(args: argparse.Namespace) -> int:
    return limb_cli.cmd_animate(args)


def cmd_fit(args: argparse.Namespace) -> int:
    from .fit import cmd_fit as fit
    return fit(args)


def cmd_compile(_args: argparse.Namespace) -> int:
    """``hill-muscle compile``: each group of kernel sets in a process of its own
    (:data:`.model.precompile.KERNEL_GROUPS`), one line per set."""
    from concurrent.futures import ProcessPoolExecutor, as_completed

    from ..model import engine, precompile
    if not engine.numba_available():
        raise UserError('numba is not installed, so nothing is compiled: the model runs '
                        'its Python loops (pip install numba for the compiled engine)')
    groups = precompile.KERNEL_GROUPS
    start = time.perf_counter()
    with ProcessPoolExecutor(max_workers=min(len(groups), os.cpu_count() or 1)) as pool:
        for done in as_completed([pool.submit(precompile.compile_kernel_group, group)
                                  for group in groups]):
            for name, wall_s, compiling_s in done.result():
                how = (f'compiled in {compiling_s:.1f} s' if compiling_s > 0.0
                       else 'loaded from the cache')
                print(f'{name}: {how} ({wall_s:.1f} s)', flush=True)
    print(f'every kernel in numba\'s cache ({time.perf_counter() - start:.1f} s)')
    return 0


def cmd_sweep(args: argparse.Namespace) -> int:
    from .sweep import cmd_sweep as sweep   # Dask and pyarrow load only here
    return sweep(args)


_COMMANDS = {'simulate': cmd_simulate, 'figures': cmd_figures, 'animate': cmd_animate,
             'sweep': cmd_sweep, 'fit': cmd_fit, 'compile': cmd_compile}


def _error(message: str) -> int:
    print(f'{PROG}: error: {message}', file=sys.stderr)
    return EXIT_USAGE


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``hill-muscle`` console script.

    :param argv: the arguments after the program name (default: ``sys.argv[1:]``)
    :return: exit status: 0 on success, 2 on a user error
    """
    argv = list(sys.argv[1:] if argv is None else argv)
    try:
        if argv and argv[0] in NODE_COMMANDS:
            return run_node(argv[0], argv[1:])
        try:
            args = build_parser().parse_args(argv)
        except SystemExit as exit_:  # --help, or argparse's own usage error
            if exit_.code is None:
                return 0
            return exit_.code if isinstance(exit_.code, int) else EXIT_USAGE
        _check_engine_setting()
        return _COMMANDS[args.command](args)
    except UserError as err:
        return _error(str(err))


def _check_engine_setting() -> None:
    """A user error for an unusable ``HILL_MUSCLE_ENGINE`` (an unknown value, or
    ``compiled`` without numba), before a command runs: the engine choice is
    made deep in the model, which would raise it as a traceback.

    :raises UserError: naming the variable and its value
    """
    from ..model import engine   # cheap: numba is looked for, not imported
    try:
        engine.choice()
    except (ValueError, ImportError) as err:
        raise UserError(str(err)) from None


if __name__ == '__main__':
    sys.exit(main())
