"""What a fit writes: the parameters or plant file, the report and its plot.

:func:`params_file_text` writes the fitted muscle parameters as a ROS 2
parameters file, :func:`plant_file_text` the fitted values into the start
plant file (every other byte kept); :func:`format_report` and
:func:`format_limb_report` give the report in Markdown,
:func:`report_data` and :func:`limb_report_data` as plain data for YAML,
:func:`plot_fit` and :func:`plot_limb_fit` the measured and the fitted signal.
"""
from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any, Sequence

import numpy as np
import yaml

from ...model import MuscleParams
from ...model.plant_fields import plant_value
from .estimate import FitResult
from .parameters import PlantParameter
from .recording import LimbRecording, MuscleRecording

#: Output file names in --report DIR.
REPORT_MARKDOWN = 'fit_report.md'
REPORT_YAML = 'fit_report.yaml'
REPORT_PNG = 'fit_force.png'
#: The plot's file name with --plant, in place of REPORT_PNG.
REPORT_ANGLE_PNG = 'fit_angle.png'


def _yaml_value(value: Any) -> str:
    """A parameter value as one line of YAML, floats with a point (ROS types them)."""
    if isinstance(value, tuple):
        return '[' + ', '.join(_yaml_value(v) for v in value) + ']'
    if isinstance(value, float):
        return repr(value)   # shortest round-trip form, always with '.' or 'e'
    return yaml.safe_dump(value, default_flow_style=True).strip().removesuffix('...').strip()


def params_file_text(result: FitResult, node_settings: dict[str, Any], source: str) -> str:
    """The fitted parameters as a ROS 2 parameters file (``/**: ros__parameters:``)."""
    fitted = {p.field for p in result.parameters}
    errors = {p.name: (v, se) for p, v, se in zip(result.parameters, result.estimates,
                                                   result.std_errors)}
    lines = [f'# Muscle parameters fitted by `hill-muscle fit` to {source}.',
             '# Load with:  hill-muscle simulate --params THIS_FILE ...',
             '# or:         ros2 run hill_muscle_ros simulator --ros-args --params-file THIS_FILE',
             '/**:', '  ros__parameters:']
    for f in dataclasses.fields(MuscleParams):
        value = getattr(result.params, f.name)
        line = f'    {f.name}: {_yaml_value(value)}'
        if f.name in fitted:
            notes = [f'{name} fitted, std error {se:.3g} {f.metadata["unit"]}'
                     for name, (_, se) in errors.items()
                     if name == f.name or name.startswith(f.name + '[')]
            line += '  # ' + '; '.join(notes)
        lines.append(line)
    for key, value in node_settings.items():
        lines.append(f'    {key}: {_yaml_value(value)}')
    return '\n'.join(lines) + '\n'


def format_report(result: FitResult, recording: MuscleRecording, start_source: str,
                  shifts: Sequence[int] | None = None, edge_search_s: float = 0.0) -> str:
    """The fit in words and tables (Markdown; also what stdout shows).

    :param shifts: [steps] the moves of the stimulation changes, if they were searched
    :param edge_search_s: [s] the search window, ±
    """
    r = recording
    names = [p.name for p in result.parameters]
    lines = [f'# Fit of {", ".join(names)}', '',
             f'- bag: {r.bag}',
             f'- force: `{r.topics["force"]}`, {result.n_samples} samples at '
             f'{r.rate_hz:g} Hz over {r.sample_t_s[-1] - r.sample_t_s[0]:.3f} s',
             f'- inputs: `{r.topics["stimulation"]}` ({r.stimulation_kind}), '
             f'`{r.topics["length"]}`'] + ([
                 f'- stimulation changes moved by '
                 f'{", ".join(f"{s * 1e3 / r.rate_hz:+g}" for s in shifts) or "nothing"} ms '
                 f'(searched within ±{edge_search_s:g} s of their stamps)']
                 if shifts is not None else []) + [
             f'- start: {start_source}',
             f'- least squares: {result.n_evaluations} evaluations; {result.message}',
             f'- residual RMS: {result.rms_n:.6g} N (at the start: {result.start_rms_n:.6g} N)',
             ''] + _estimate_lines(result) + [
        '', 'Standard errors: sigma^2 (J^T J)^-1 at the estimate, sigma^2 = the sum of '
            'squared residuals / (samples - parameters); they assume independent '
            'force errors of equal variance.']
    return '\n'.join(lines)


def _estimate_lines(result: FitResult) -> list[str]:
    """The estimates with their standard errors, and their correlations (Markdown)."""
    names = [p.name for p in result.parameters]
    width = max(len(n) for n in names + ['parameter'])
    lines = [f'| {"parameter":<{width}} | {"start":>12} | {"estimate":>14} | '
             f'{"std error":>10} | unit |',
             f'|{"-" * (width + 2)}|{"-" * 14}|{"-" * 16}|{"-" * 12}|------|']
    for p, x0, x, se in zip(result.parameters, result.start_values, result.estimates,
                            result.std_errors):
        lines.append(f'| {p.name:<{width}} | {x0:12.6g} | {x:14.8g} | {se:10.3g} | '
                     f'{p.unit} |')
    col = max([12] + [len(n) for n in names])   # 12: the muscle's names fit
    lines += ['', 'Correlation of the estimates:', '',
              '| ' + ' | '.join([' ' * width] + [f'{n:>{col}}' for n in names]) + ' |',
              '|' + '|'.join(['-' * (width + 2)] + ['-' * (col + 2)] * len(names)) + '|']
    for name, row in zip(names, result.correlation):
        lines.append('| ' + ' | '.join([f'{name:<{width}}'] + [f'{c:{col}.4f}' for c in row])
                     + ' |')
    return lines


def _estimates_data(result: FitResult) -> dict[str, Any]:
    """The estimates, their standard errors and correlations as plain data,
    the part of ``fit_report.yaml`` that a muscle's and a limb's fit share."""
    return {
        'parameters': {p.name: {'unit': p.unit, 'start': float(x0), 'estimate': float(x),
                                'std_error': float(se)}
                       for p, x0, x, se in zip(result.parameters, result.start_values,
                                               result.estimates, result.std_errors)},
        'correlation': {'names': [p.name for p in result.parameters],
                        'matrix': [[float(c) for c in row] for row in result.correlation]},
    }


def report_data(result: FitResult, recording: MuscleRecording) -> dict[str, Any]:
    """The report as plain data (for ``fit_report.yaml``)."""
    return {
        'bag': str(recording.bag), 'topics': dict(recording.topics),
        'rate_hz': float(recording.rate_hz), 'n_samples': result.n_samples,
        'n_evaluations': result.n_evaluations, 'message': result.message,
        'residual_rms_n': result.rms_n, 'start_residual_rms_n': result.start_rms_n,
        **_estimates_data(result),
    }


def _plot_measured_and_fitted(path: Path, result: FitResult, t_s: np.ndarray,
                              measured: np.ndarray, measured_label: str,
                              quantity: str, unit: str) -> None:
    """PNG of a measured signal and the fitted model's, and their difference.

    :param measured_label: what was measured, for the legend (the topic)
    :param quantity: its name on the axis (``force``, ``joint angle``)
    :param unit: its unit (``N``, ``rad``)
    """
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    fig, (ax_m, ax_r) = plt.subplots(2, 1, sharex=True, figsize=(8, 6),
                                     gridspec_kw={'height_ratios': [3, 1]})
    ax_m.plot(t_s, measured, color='0.6', lw=2, label=f'measured ({measured_label})')
    ax_m.plot(t_s, result.fitted, color='C0', lw=1, label='fitted model')
    ax_m.set_ylabel(f'{quantity} [{unit}]')
    ax_m.set_title(f'hill-muscle fit: {", ".join(p.name for p in result.parameters)}')
    ax_m.legend(loc='best')
    ax_r.plot(t_s, measured - result.fitted, color='C3', lw=0.8)
    ax_r.set_ylabel(f'measured - fitted [{unit}]')
    ax_r.set_xlabel('time [s]')
    for ax in (ax_m, ax_r):
        ax.grid(True, alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def plot_fit(path: Path, result: FitResult, recording: MuscleRecording) -> None:
    """PNG of the measured and the fitted force, and their difference."""
    _plot_measured_and_fitted(path, result, recording.sample_t_s, recording.force_n,
                              recording.topics['force'], 'force', 'N')


def _plant_sections(root: Any) -> list[Any]:
    """The ``ros__parameters`` mapping nodes of the sections the limb node reads."""
    sections = []
    if not isinstance(root, yaml.MappingNode):
        return sections
    for key, value in root.value:
        name = str(key.value)
        if name != '/**' and name.rstrip('/').split('/')[-1] != 'limb':
            continue
        if isinstance(value, yaml.MappingNode):
            sections += [v for k, v in value.value
                         if k.value == 'ros__parameters' and isinstance(v, yaml.MappingNode)]
    return sections


def _lookup(mapping: Any, key: str) -> Any:
    return next((v for k, v in mapping.value if k.value == key), None)


def _value_nodes(section: Any, p: PlantParameter) -> list[Any]:
    """The YAML scalar nodes of ``section`` that hold ``p`` (nested or dotted)."""
    nodes = []
    part = _lookup(section, p.part)
    candidates = [_lookup(section, f'{p.part}.{p.field}')]
    if isinstance(part, yaml.MappingNode):
        candidates.append(_lookup(part, p.field))
    for node in candidates:
        if p.inner.index is not None and isinstance(node, yaml.SequenceNode):
            node = node.value[p.inner.index] if p.inner.index < len(node.value) else None
        if isinstance(node, yaml.ScalarNode):
            nodes.append(node)
    return nodes


def plant_file_text(text: str, result: FitResult, source: str) -> str | None:
    """The plant file ``text`` with the fitted values written in place.

    Every other byte stays as it was (comments included); a fitted value's own
    line comment becomes its standard error and start value. A value the file
    does not give (a default) is added as a line of its own in the muscle's or
    the joint's section, or as a dotted name. A header comment names the fit.

    :return: the new text, or ``None`` if the file's layout (flow style) has no
        place for a missing value
    """
    root = yaml.compose(text, Loader=yaml.SafeLoader)
    sections = _plant_sections(root)
    if not sections:
        return None
    edits: list[tuple[int, int, str]] = []   # (start, end, replacement) character spans
    lines_at = text.splitlines(keepends=True)
    for p, x0, x, se in zip(result.parameters, result.start_values, result.estimates,
                            result.std_errors):
        note = (f'# fitted by hill-muscle fit: std error {se:.3g} {p.unit} '
                f'(was {_yaml_value(float(x0))})')
        nodes = [n for s in sections for n in _value_nodes(s, p)]
        for node in nodes:
            start, end = node.start_mark.index, node.end_mark.index
            line = lines_at[node.end_mark.line]
            rest = line[node.end_mark.column:]
            if not rest.strip() or (node.style is None and rest.strip().startswith('#')):
                # A block value: its line comment becomes the fit's note.
                end += len(rest.rstrip('\r\n'))
                edits.append((start, end, f'{_yaml_value(float(x))}  {note}'))
            else:
                edits.append((start, end, _yaml_value(float(x))))
        if nodes:
            continue
        # Not in the file: a new line in the last section the node reads.
        section = sections[-1]
        part = _lookup(section, p.part)
        # A list entry brings the whole list (the rest of it as the start gave it).
        fitted = (p.get(result.params) if p.inner.index is None
                  else plant_value(result.params, p.path))
        if isinstance(part, yaml.MappingNode) and part.value and not part.flow_style:
            target, key = part, p.field
        elif section.value and not section.flow_style:
            target, key = section, f'{p.part}.{p.field}'
        else:
            return None
        first = target.value[0][0].start_mark
        line_start = first.index - first.column
        edits.append((line_start, line_start,
                      f'{" " * first.column}{key}: {_yaml_value(fitted)}  {note}\n'))
    for start, end, new in sorted(edits, reverse=True):
        text = text[:start] + new + text[end:]
    names = ', '.join(p.name for p in result.parameters)
    return (f'# {names} fitted by `hill-muscle fit` to {source}; every other value is the '
            'start file\'s.\n' + text)


def format_limb_report(result: FitResult, recording: LimbRecording, start_source: str) -> str:
    """The limb fit in words and tables (Markdown; also what stdout shows)."""
    r = recording
    inputs = ', '.join(f'`{r.topics[name]}` ({r.stimulation_kind[name]})'
                       for name in r.stimulation)
    torque = (f'`{r.topics["external_torque"]}`' if r.topics['external_torque']
              else 'none in the bag (0 N m)')
    lines = [f'# Fit of {", ".join(p.name for p in result.parameters)}', '',
             f'- bag: {r.bag}',
             f'- joint angle: `{r.topics["joint_states"]}` (`{r.joint}`), {result.n_samples} '
             f'samples at {r.rate_hz:g} Hz over {r.sample_t_s[-1] - r.sample_t_s[0]:.3f} s',
             f'- stimulation: {inputs}; external torque: {torque}',
             f'- start: {start_source}',
             f'- least squares: {result.n_evaluations} evaluations; {result.message}',
             f'- residual RMS: {result.rms_n:.6g} rad (at the start: {result.start_rms_n:.6g} '
             'rad)', ''] + _estimate_lines(result) + [
        '', 'Standard errors: sigma^2 (J^T J)^-1 at the estimate, sigma^2 = the sum of '
            'squared residuals / (samples - parameters); they assume independent '
            'angle errors of equal variance.']
    return '\n'.join(lines)


def limb_report_data(result: FitResult, recording: LimbRecording) -> dict[str, Any]:
    """The limb fit's report as plain data (for ``fit_report.yaml``)."""
    return {
        'bag': str(recording.bag), 'topics': dict(recording.topics),
        'joint': recording.joint, 'rate_hz': float(recording.rate_hz),
        'n_samples': result.n_samples, 'n_evaluations': result.n_evaluations,
        'message': result.message, 'residual_rms_rad': result.rms_n,
        'start_residual_rms_rad': result.start_rms_n,
        **_estimates_data(result),
    }


def plot_limb_fit(path: Path, result: FitResult, recording: LimbRecording) -> None:
    """PNG of the measured and the fitted joint angle, and their difference."""
    _plot_measured_and_fitted(path, result, recording.sample_t_s, recording.angle_rad,
                              f'{recording.topics["joint_states"]}, {recording.joint}',
                              'joint angle', 'rad')
