"""The paper's Figures 8-11, reproduced from the offline model, and the figures
of the FES extensions (doc/model.md section 7).

Each of the paper's figures shows the muscle force against time for the model
variants its caption names, with the inputs (recruitment R and MTU length
change dl_MT) in a panel below. The FES figures each make one point of the
extensions: the recruitment curves, the delay and activation, per-unit versus
whole-muscle fatigue, the recruitment order of fibre types, and the scaling of
the force-velocity constants. Each FES figure has a data function (the
simulation behind it, which the tests check), a plot function and a function
that writes the PNG and returns its path.

One module per family: :mod:`.paper` (Figures 8-11), :mod:`.fes` (the five
FES figures), :mod:`.limb` (the knee in the four variants) and :mod:`.pulses`
(the pulse model against published results: force-frequency, catch-like
trains, Kesar 2006's fatigue protocols, four channels in turn), with what they
share (sizes, units, the variants' styles, saving) in :mod:`.plotting`;
:func:`write_figures` writes them all.

Figures are drawn with matplotlib's object API on the Agg canvas, so no
display and no global pyplot state are needed.
"""
from __future__ import annotations

from pathlib import Path

from ... import resources
from ...model import MuscleParams, Protocol
from .fes import write_fes_figures
from .limb import write_limb_figure
from .paper import FIGURES, plot_figure, simulate_variants
from .pulses import write_pulse_figures
from .plotting import DPI, RATE_HZ, VARIANTS


def write_figures(out_dir: str | Path, params: MuscleParams | None = None,
                  rate_hz: float = RATE_HZ) -> list[Path]:
    """Write the PNGs of Figures 8-11, of the FES extensions, the limb and the
    pulse model into ``out_dir``.

    The directory is created if missing.

    :param params: muscle parameters of Figures 8-11 other than the variant
        (the paper's if omitted); the FES figures bring their own
    :param rate_hz: [Hz] step rate of the simulations
    :return: the paths written: Figures 8-11 in order, then the FES figures, the
        limb figure and the pulse figures
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    protocols = {name: Protocol.from_yaml(resources.protocol_path(name))
                 for name in sorted({spec.protocol for spec in FIGURES})}
    results = {name: simulate_variants(p, VARIANTS, params, rate_hz)
               for name, p in protocols.items()}
    paths = []
    for spec in FIGURES:
        fig = plot_figure(spec, protocols[spec.protocol], results[spec.protocol])
        path = out / spec.filename
        fig.savefig(path, dpi=DPI)
        paths.append(path)
    paths.extend(write_fes_figures(out, rate_hz))
    paths.append(write_limb_figure(out, rate_hz))
    paths.extend(write_pulse_figures(out, rate_hz))
    return paths
