"""``hill-muscle fit``: the subcommand's parser and the glue from its options to
the recording, the fit and the files written.

User errors raise :class:`~hill_muscle_ros.tools.common.UserError`.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any, Callable

import yaml

from ...model.limb import LimbPlant
from ...model.plant_fields import JOINT_PART
from ..common import PROG, UserError, bounded_number
from .edges import edge_search_runs, fit_with_aligned_edges
from .estimate import fit_parameters
from .parameters import parse_fit_names, parse_plant_fit_names
from .recording import (EXTERNAL_TORQUE_TOPIC, FORCE_TOPICS, JOINT_STATES_TOPIC, LENGTH_TOPICS,
                        LIMB_PULSE_WIDTH_TOPIC, LIMB_RECRUITMENT_TOPIC, MUSCLE_PLACEHOLDER,
                        PULSE_WIDTH_TOPIC, RECRUITMENT_TOPIC, load_limb_recording,
                        load_muscle_recording)
from .replay import LimbReplay, MuscleReplay, replay_runs
from .report import (REPORT_ANGLE_PNG, REPORT_MARKDOWN, REPORT_PNG, REPORT_YAML,
                     format_limb_report, format_report, limb_report_data, params_file_text,
                     plant_file_text, plot_fit, plot_limb_fit, report_data)


def add_fit_parser(sub: argparse._SubParsersAction) -> None:
    """The ``fit`` subcommand's parser."""
    fit = sub.add_parser(
        'fit', help='estimate muscle or limb parameters from a recorded bag (least squares)',
        description='Replay the stimulation and length recorded in a rosbag2 MCAP bag '
                    'through the model and fit the named parameters to the recorded '
                    'force by least squares. Writes a parameters file that simulate and '
                    'the simulator node load, and reports each estimate with its standard '
                    'error and the correlations. With --plant, replay each muscle\'s '
                    'stimulation through the limb and fit to the recorded joint angle '
                    '(joint_states); names are then the plant file\'s parameter names, '
                    'joint.<field> or <muscle>.<field> (e.g. joint.damping_n_m_s_per_rad, '
                    'quadriceps.f_iso_max_n, quadriceps.moment_arm_m), and the output is '
                    'the plant file with the fitted values in place.',
        epilog='examples:\n'
               f'  {PROG} simulate --protocol II --params truth.yaml --bag run_bag\n'
               f'  {PROG} fit --bag run_bag --fit f_iso_max_n,k_se_n_per_m,fv_a_n '
               '--out fitted.yaml --report fit_report\n'
               f'  {PROG} fit --bag knee_bag --plant config/knee.yaml '
               '--fit quadriceps.f_iso_max_n,joint.damping_n_m_s_per_rad '
               '--out knee_fitted.yaml --report knee_fit',
        formatter_class=argparse.RawDescriptionHelpFormatter)
    fit.add_argument('--bag', required=True, type=Path, metavar='DIR',
                     help='the rosbag2 MCAP bag (a directory)')
    fit.add_argument('--fit', required=True, metavar='NAME[,NAME...]', dest='fit_names',
                     help='parameters to estimate, e.g. f_iso_max_n,k_se_n_per_m '
                          '(a list entry as tau_fatigue_s[0]); with --plant '
                          f'{JOINT_PART}.<field> or <muscle>.<field>, e.g. '
                          f'{JOINT_PART}.damping_n_m_s_per_rad,quadriceps.f_iso_max_n')
    fit.add_argument('--params', type=Path, metavar='YAML',
                     help='start values and every parameter not fitted (default: the '
                          "package's config/muscle.yaml)")
    fit.add_argument('--plant', type=Path, metavar='YAML',
                     help='fit a limb instead: the plant file (e.g. config/knee.yaml) gives '
                          'the start values and every parameter not fitted; --out is then '
                          'that file with the fitted values in place')
    fit.add_argument('--out', required=True, type=Path, metavar='YAML',
                     help='write the fitted parameters (or plant) file here')
    fit.add_argument('--report', type=Path, metavar='DIR',
                     help=f'also write {REPORT_MARKDOWN}, {REPORT_YAML} and {REPORT_PNG} '
                          f'({REPORT_ANGLE_PNG} with --plant) here')
    stim = fit.add_mutually_exclusive_group()
    stim.add_argument('--pulse-width-topic', metavar='TOPIC',
                      help=f'stimulation as pulse widths [s] (default: `{PULSE_WIDTH_TOPIC}`, '
                           f'else `{RECRUITMENT_TOPIC}`; with --plant `{LIMB_PULSE_WIDTH_TOPIC}`, '
                           f'else `{LIMB_RECRUITMENT_TOPIC}`, {MUSCLE_PLACEHOLDER} standing for '
                           "each muscle's name)")
    stim.add_argument('--recruitment-topic', metavar='TOPIC',
                      help='stimulation as recruitment [-] (with --plant, a topic with '
                           f'{MUSCLE_PLACEHOLDER})')
    fit.add_argument('--joint-states-topic', metavar='TOPIC',
                     help='with --plant: the joint angle, sensor_msgs/JointState position of '
                          f"the plant's joint.name (default: `{JOINT_STATES_TOPIC}`)")
    fit.add_argument('--external-torque-topic', metavar='TOPIC',
                     help='with --plant: the external torque [N m], Float64 (default: '
                          f'`{EXTERNAL_TORQUE_TOPIC}`, 0 if the bag has none)')
    fit.add_argument('--jobs', type=_jobs, metavar='N',
                     help='with --plant: run the n + 1 limb simulations of each evaluation '
                          'in N processes (default 1; more than the free CPUs does not help)')
    fit.add_argument('--edge-search', type=_edge_search, metavar='S',
                     help='single muscle, for live bags: move each change of the stimulation '
                          'by whole steps within +-S seconds of its stamp to where it best '
                          'explains the force, fitting again until the moves settle (a plain '
                          'stimulation topic reaches the simulator some ms off the '
                          "recorder's stamp; e.g. 0.03). Default: the stamps as they are")
    fit.add_argument('--length-topic', metavar='TOPIC',
                     help='MTU length change [m], Float64 or PointStamped knots (default: '
                          f'`{LENGTH_TOPICS[0]}`, else `{LENGTH_TOPICS[1]}`)')
    fit.add_argument('--force-topic', metavar='TOPIC',
                     help='measured force [N], Float64 or WrenchStamped force.x (default: '
                          f'`{FORCE_TOPICS[0]}`, else `{FORCE_TOPICS[1]}`)')


#: [s] Largest --edge-search: a second is far beyond any delivery delay, and the
#: search costs one replay per step of the window and change.
MAX_EDGE_SEARCH_S = 1.0


#: argparse type for ``--edge-search``: seconds in [0, MAX_EDGE_SEARCH_S].
_edge_search = bounded_number(float, low=0.0, high=MAX_EDGE_SEARCH_S, unit='s',
                              noun='a number of seconds')


#: Most --jobs: an evaluation runs n + 1 simulations, and a fit of more than a
#: few dozen parameters is not what this is for.
MAX_JOBS = 64


#: argparse type for ``--jobs``: an integer in [1, MAX_JOBS].
_jobs = bounded_number(int, low=1, high=MAX_JOBS)


#: Options of ``fit`` for one kind of plant only: (attribute, flag).
MUSCLE_FIT_OPTIONS = (('params', '--params'), ('length_topic', '--length-topic'),
                      ('force_topic', '--force-topic'), ('edge_search', '--edge-search'))
LIMB_FIT_OPTIONS = (('joint_states_topic', '--joint-states-topic'),
                    ('external_torque_topic', '--external-torque-topic'), ('jobs', '--jobs'))


def cmd_fit(args: argparse.Namespace) -> int:
    """Run ``hill-muscle fit``; user errors raise
    :class:`~hill_muscle_ros.tools.common.UserError`."""
    from ... import resources
    from ...params_file import load_muscle_params
    if args.plant is not None:
        given = [flag for attr, flag in MUSCLE_FIT_OPTIONS if getattr(args, attr) is not None]
        if given:
            raise UserError(f'{given[0]} applies to the single muscle, not to a limb '
                            '(--plant): the plant file gives every start value')
        return _cmd_fit_limb(args)
    given = [flag for attr, flag in LIMB_FIT_OPTIONS if getattr(args, attr) is not None]
    if given:
        raise UserError(f'{given[0]} applies to a limb: give --plant PLANT.yaml')
    params_path = args.params if args.params is not None else resources.default_params_file()
    try:
        start, node_settings = load_muscle_params(params_path)
        parameters = parse_fit_names(args.fit_names, start)
        edge_search_s = args.edge_search or 0.0
        recording = load_muscle_recording(
            args.bag, pulse_width_topic=args.pulse_width_topic,
            recruitment_topic=args.recruitment_topic, length_topic=args.length_topic,
            force_topic=args.force_topic, lead_s=edge_search_s)
        runs = (edge_search_runs(recording, len(parameters),
                                 round(edge_search_s * recording.rate_hz))
                if edge_search_s > 0.0 else replay_runs(len(parameters)))
        compiled = MuscleReplay(recording, runs).compiled(not start.fes_defaults)
        print(f'fitting {", ".join(p.name for p in parameters)} to '
              f'{recording.topics["force"]} ({len(recording.force_n)} samples at '
              f'{recording.rate_hz:g} Hz); each evaluation runs {len(parameters) + 1} '
              f'simulations, {"compiled" if compiled else "in Python"}', file=sys.stderr)
        progress = lambda line: print(line, file=sys.stderr, flush=True)  # noqa: E731
        shifts = None
        if edge_search_s > 0.0:
            result, recording, shifts = fit_with_aligned_edges(
                recording, start, parameters, round(edge_search_s * recording.rate_hz),
                progress)
        else:
            result = fit_parameters(MuscleReplay(recording, runs), recording.force_n, start,
                                    parameters, progress=progress)
    except ValueError as err:   # FitError, and the params file's own errors
        raise UserError(str(err)) from None
    report = format_report(result, recording, str(params_path), shifts, edge_search_s)
    return _write_outputs(args, params_file_text(result, node_settings, str(args.bag)), report,
                          lambda: report_data(result, recording), REPORT_PNG,
                          lambda path: plot_fit(path, result, recording))


def _cmd_fit_limb(args: argparse.Namespace) -> int:
    """``hill-muscle fit --plant``: the limb's parameters from its joint angle."""
    from ...params_file import load_plant
    try:
        start, _ = load_plant(args.plant)
        start_text = args.plant.read_text(encoding='utf-8')
        parameters = parse_plant_fit_names(args.fit_names, start)
        recording = load_limb_recording(
            args.bag, start, joint_states_topic=args.joint_states_topic,
            pulse_width_topic=args.pulse_width_topic,
            recruitment_topic=args.recruitment_topic,
            external_torque_topic=args.external_torque_topic)
        print(f'fitting {", ".join(p.name for p in parameters)} to the angle of '
              f'`{recording.joint}` on {recording.topics["joint_states"]} '
              f'({len(recording.angle_rad)} samples at {recording.rate_hz:g} Hz); each '
              f'evaluation runs {len(parameters) + 1} limb simulations', file=sys.stderr)
        with LimbReplay(recording, jobs=args.jobs or 1) as replay:
            result = fit_parameters(
                replay, recording.angle_rad, start, parameters,
                progress=lambda line: print(line, file=sys.stderr, flush=True),
                quantity='joint angle', unit='rad')
    except (OSError, UnicodeDecodeError) as err:
        raise UserError(f'{args.plant}: cannot read the plant file: {err}') from None
    except ValueError as err:   # FitError, and the plant file's own errors
        raise UserError(str(err)) from None
    report = format_limb_report(result, recording, str(args.plant))
    text = plant_file_text(start_text, result, str(args.bag))
    if text is None or _plant_of(text) != result.params:
        raise UserError(f'{args.plant}: cannot write the fitted values into this file\'s '
                        'layout (block-style `ros__parameters` with the muscles\' and the '
                        'joint\'s sections needed)')
    return _write_outputs(args, text, report, lambda: limb_report_data(result, recording),
                          REPORT_ANGLE_PNG, lambda path: plot_limb_fit(path, result, recording))


def _write_outputs(args: argparse.Namespace, out_text: str, report: str,
                   data: Callable[[], dict[str, Any]], png: str,
                   plot: Callable[[Path], None]) -> int:
    """Write ``--out`` and, with ``--report``, the report's Markdown, YAML and plot
    (file name ``png``); print the report and what was written.

    :param data: the report's YAML data (made only with ``--report``)
    :param plot: draws the plot into the path it is given
    """
    try:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(out_text, encoding='utf-8')
        if args.report is not None:
            args.report.mkdir(parents=True, exist_ok=True)
            (args.report / REPORT_MARKDOWN).write_text(report + '\n', encoding='utf-8')
            (args.report / REPORT_YAML).write_text(
                yaml.safe_dump(data(), sort_keys=False), encoding='utf-8')
            plot(args.report / png)
    except OSError as err:
        raise UserError(f'{err.filename}: cannot write: {err.strerror or err}') from None
    print(report)
    print(f'wrote {args.out}')
    if args.report is not None:
        print(f'wrote {args.report / REPORT_MARKDOWN}, {args.report / REPORT_YAML}, '
              f'{args.report / png}')
    return 0


def _plant_of(text: str) -> LimbPlant | None:
    """The plant a plant file's text gives, as the limb CLI loads it (``None`` if it
    does not load): the written file is checked against the fitted plant."""
    import tempfile
    from ...params_file import load_plant
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / 'plant.yaml'
        path.write_text(text, encoding='utf-8')
        try:
            return load_plant(path)[0]
        except ValueError:
            return None
