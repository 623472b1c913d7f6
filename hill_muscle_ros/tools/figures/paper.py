"""The paper's Figures 8-11: the muscle force against time for the model variants
each caption names, with the inputs (recruitment R and MTU length change dl_MT)
in a panel below.
"""
from __future__ import annotations

from dataclasses import dataclass

from matplotlib.figure import Figure

from ...model import MuscleParams, Protocol, SimulationResult, simulate
from .plotting import DL_LABEL, DPI, MM_PER_M, RATE_HZ, VARIANTS, Variant

#: [inch] figure size (width, height).
FIGSIZE_IN = (8.0, 6.4)
#: Relative heights of the force panel and the input panel.
HEIGHT_RATIOS = (3, 1.5)
#: Axis ranges of the input panel: offset from each other so that R = 1 and
#: dl_MT = 10 mm (or both at zero) do not draw on top of each other, with
#: headroom above the curves for the legend.
R_AXIS_LIMITS = (-0.05, 1.6)
R_TICKS = (0.0, 0.5, 1.0)
DL_AXIS_LIMITS_MM = (-1.5, 19.0)
DL_TICKS_MM = (0.0, 5.0, 10.0)


_INITIAL = tuple(v for v in VARIANTS if v.length == 'initial')


@dataclass(frozen=True)
class FigureSpec:
    """One of the paper's figures: its file, the protocol and the curves.

    :param filename: PNG file name
    :param number: the paper's figure number
    :param protocol: ``I`` or ``II``
    :param variants: the curves the caption names
    :param subtitle: what the figure compares
    """

    filename: str
    number: int
    protocol: str
    variants: tuple[Variant, ...]
    subtitle: str

    @property
    def title(self) -> str:
        return f'Figure {self.number}: Protocol {self.protocol}, {self.subtitle}'


FIGURES = (
    FigureSpec('fig08_protocol_I_initial.png', 8, 'I', _INITIAL,
               'single vs multiple motor units (initial length)'),
    FigureSpec('fig09_protocol_II_initial.png', 9, 'II', _INITIAL,
               'single vs multiple motor units (initial length)'),
    FigureSpec('fig10_protocol_I_all.png', 10, 'I', VARIANTS, 'all four model variants'),
    FigureSpec('fig11_protocol_II_all.png', 11, 'II', VARIANTS, 'all four model variants'),
)


def simulate_variants(protocol: Protocol, variants: tuple[Variant, ...],
                      params: MuscleParams | None = None,
                      rate_hz: float = RATE_HZ) -> dict[Variant, SimulationResult]:
    """Run ``protocol`` once per variant.

    :param params: the other muscle parameters (the paper's if omitted)
    :param rate_hz: [Hz] step rate
    """
    base = params if params is not None else MuscleParams()
    return {v: simulate(protocol, base.replace(units=v.units, length=v.length), rate_hz)
            for v in variants}


def plot_figure(spec: FigureSpec, protocol: Protocol,
                results: dict[Variant, SimulationResult]) -> Figure:
    """Draw one figure: force against time above, the inputs below."""
    fig = Figure(figsize=FIGSIZE_IN, dpi=DPI, layout='constrained')
    ax_force, ax_r = fig.subplots(2, 1, sharex=True,
                                  gridspec_kw={'height_ratios': HEIGHT_RATIOS})
    for variant in spec.variants:
        r = results[variant]
        ax_force.plot(r.t_s, r.force_n, label=variant.label, color=variant.color,
                      linestyle=variant.linestyle, linewidth=variant.linewidth)
    ax_force.set_ylabel('muscle force [N]')
    ax_force.set_title(spec.title)
    ax_force.set_ylim(bottom=0.0)
    ax_force.grid(True, alpha=0.3)
    ax_force.legend(loc='lower center', fontsize='small')

    # The inputs are the same for every variant.
    inputs = results[spec.variants[0]]
    ax_dl = ax_r.twinx()
    line_r = ax_r.plot(inputs.t_s, inputs.recruitment, color='black', linewidth=1.5,
                       label='recruitment R')
    line_dl = ax_dl.plot(inputs.t_s, inputs.dl_mt_m * MM_PER_M, color='tab:purple',
                         linestyle='--', linewidth=1.5, label=f'MTU length change {DL_LABEL}')
    ax_r.set_ylabel('recruitment R [-]')
    ax_r.set_ylim(*R_AXIS_LIMITS)
    ax_r.set_yticks(R_TICKS)
    ax_dl.set_ylim(*DL_AXIS_LIMITS_MM)
    ax_dl.set_yticks(DL_TICKS_MM)
    ax_dl.set_ylabel(f'{DL_LABEL} [mm]', color='tab:purple')
    ax_dl.tick_params(axis='y', colors='tab:purple')
    ax_r.set_xlabel('time [s]')
    ax_r.set_xlim(0.0, protocol.duration_s)
    ax_r.grid(True, alpha=0.3)
    ax_r.legend(handles=line_r + line_dl, loc='upper center', ncols=2, fontsize='small')
    return fig
