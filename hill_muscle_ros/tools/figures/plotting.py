"""What the figure families share: the size and resolution of a PNG, the
simulations' step rate, the units plotted, the four model variants and how each
is drawn, and saving a figure.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from matplotlib.figure import Figure

#: [dots per inch] keeps each PNG small (about 100 kB) yet readable.
DPI = 100
#: [Hz] step rate of the simulations behind the figures (the paper's 1 ms).
RATE_HZ = 1000.0
#: Plot dl_MT in millimetres, as the paper does; the data stay in metres.
MM_PER_M = 1000.0
#: The axis label of dl_MT (matplotlib mathtext).
DL_LABEL = r'$\Delta L_\mathrm{MT}$'


@dataclass(frozen=True)
class Variant:
    """One of the four model variants and how its curve is drawn.

    Single-unit curves are wide and solid, multi-unit curves narrow and dashed
    on top of them, so curves that coincide (always so with instantaneous
    length) stay visible as a dashed line over a solid one.
    """

    units: str
    length: str
    color: str
    linestyle: str
    linewidth: float

    @property
    def label(self) -> str:
        unit_text = 'single unit' if self.units == 'single' else 'multiple units'
        return f'{unit_text}, {self.length} length'


VARIANTS = (
    Variant('single', 'initial', 'tab:blue', '-', 3.0),
    Variant('multi', 'initial', 'tab:orange', '--', 1.6),
    Variant('single', 'instantaneous', 'tab:green', '-', 3.0),
    Variant('multi', 'instantaneous', 'tab:red', (0, (2, 2)), 1.6),
)


#: Plot pulse widths in microseconds; the data stay in seconds.
US_PER_S = 1.0e6


def save_figure(fig: Figure, out_dir: str | Path, filename: str) -> Path:
    """Write ``fig`` to ``out_dir/filename`` at :data:`DPI` (the directory is created
    if missing); return the path."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    path = out / filename
    fig.savefig(path, dpi=DPI)
    return path
