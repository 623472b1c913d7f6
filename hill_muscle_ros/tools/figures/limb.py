"""The limb figure (doc/model.md section 9): the knee under one stimulation, in the
four model variants of its quadriceps.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from ... import resources
from ...model.limb import LimbPlant, LimbProtocol, LimbResult, simulate_limb
from ...params_file import load_plant
from .plotting import DPI, RATE_HZ, US_PER_S, VARIANTS, Variant, save_figure

#: File name of the limb figure.
LIMB_FIGURE_FILE = 'limb_knee.png'
#: [inch] size of the limb figure (width, height).
LIMB_FIGSIZE_IN = (8.0, 8.0)
#: The knee plant and the stimulation of the limb figure (config/).
LIMB_PLANT_FILE = 'knee.yaml'
LIMB_PROTOCOL_FILE = 'knee_ramp.yaml'
#: The stimulated muscle whose model variant changes.
LIMB_MUSCLE = 'quadriceps'
#: [s] The instant at which the angles are compared: the end of the last hold,
#: just before the stimulation stops (config/protocols/knee_ramp.yaml).
LIMB_COMPARE_S = 5.99


@dataclass(frozen=True)
class LimbData:
    """The knee under one stimulation, in the four model variants of its quadriceps.

    :param protocol: the limb protocol
    :param results: variant -> limb simulation
    :param compare_s: [s] instant at which the end angles are compared
    """

    protocol: LimbProtocol
    results: dict[Variant, LimbResult]
    compare_s: float

    def angle_deg(self, variant: Variant) -> float:
        """[deg] the variant's knee angle at :attr:`compare_s`."""
        r = self.results[variant]
        k = int(np.argmin(np.abs(r.t_s - self.compare_s)))
        return math.degrees(float(r['theta_rad'][k]))

    def spread_deg(self, a: Variant, b: Variant) -> float:
        """[deg] how far apart two variants' angles end up (a - b)."""
        return self.angle_deg(a) - self.angle_deg(b)


def limb_variant_plant(plant: LimbPlant, units: str, length: str) -> LimbPlant:
    """The plant with its quadriceps in one model variant.

    The single unit has one fibre type, so every variant gets one, with
    Riener's whole-muscle fatigue constant (30 s): the four differ only in
    ``units`` and ``length``.
    """
    muscles = []
    for m in plant.muscles:
        if m.name == LIMB_MUSCLE:
            p = m.params.replace(units=units, length=length, fibre_fractions=(1.0,),
                                 fibre_force_weights=(1.0,), tau_fatigue_s=(30.0,))
            m = dataclasses.replace(m, params=p)
        muscles.append(m)
    return LimbPlant(plant.joint, tuple(muscles))


def limb_data(rate_hz: float = RATE_HZ) -> LimbData:
    """Simulate the knee figure's stimulation in the four variants (about 10 s)."""
    plant, _ = load_plant(resources.config_dir() / LIMB_PLANT_FILE)
    protocol = LimbProtocol.from_yaml(resources.config_dir() / 'protocols' / LIMB_PROTOCOL_FILE)
    results = {v: simulate_limb(limb_variant_plant(plant, v.units, v.length), protocol, rate_hz)
               for v in VARIANTS}
    return LimbData(protocol, results, LIMB_COMPARE_S)


def plot_limb(data: LimbData) -> Figure:
    """Knee angle of the four variants, the quadriceps' force, and the stimulation below."""
    fig = Figure(figsize=LIMB_FIGSIZE_IN, dpi=DPI, layout='constrained')
    ax_th, ax_f, ax_pw = fig.subplots(3, 1, sharex=True,
                                      gridspec_kw={'height_ratios': (3, 2, 1.5)})
    for v in VARIANTS:
        r = data.results[v]
        style = {'color': v.color, 'linestyle': v.linestyle, 'linewidth': v.linewidth}
        ax_th.plot(r.t_s, np.degrees(r['theta_rad']), label=v.label, **style)
        ax_f.plot(r.t_s, r[f'{LIMB_MUSCLE}_force_n'], **style)
    single_initial, multi_initial, single_inst, multi_inst = VARIANTS
    ax_th.set_title(f'Knee under FES, the same stimulation: at {data.compare_s:g} s the angle '
                    f'with initial length\nis {data.spread_deg(multi_initial, multi_inst):.1f}'
                    f' deg above instantaneous with multiple units, '
                    f'{data.spread_deg(single_initial, single_inst):.1f} deg with a single '
                    f'unit', fontsize='medium')
    ax_th.axhline(90.0, color='grey', linestyle=':', linewidth=1.0)
    ax_th.text(0.05, 91.0, 'horizontal', color='grey', fontsize='small', va='bottom')
    ax_th.axvline(data.compare_s, color='grey', linestyle=':', linewidth=1.0)
    ax_th.set_ylabel('knee angle from hanging [deg]')
    ax_th.grid(True, alpha=0.3)
    ax_th.legend(loc='lower left', fontsize='small')
    ax_f.set_ylabel(f'{LIMB_MUSCLE} force [N]')
    ax_f.set_ylim(bottom=0.0)
    ax_f.grid(True, alpha=0.3)

    r = data.results[multi_initial]
    key, knots = data.protocol.stimulation[LIMB_MUSCLE]
    ax_pw.plot(r.t_s, np.asarray(knots(r.t_s)) * US_PER_S, color='black', linewidth=1.2,
               label='pulse width')
    ax_pw.set_ylabel('PW [us]')
    ax_r = ax_pw.twinx()
    ax_r.plot(r.t_s, r[f'{LIMB_MUSCLE}_recruitment'], color='tab:blue', linewidth=1.2,
              label='recruitment R (activation)')
    ax_r.set_ylabel('R [-]', color='tab:blue')
    ax_r.tick_params(axis='y', colors='tab:blue')
    ax_r.set_ylim(0.0, 1.0)
    ax_pw.set_xlabel('time [s]')
    ax_pw.set_xlim(0.0, data.protocol.duration_s)
    ax_pw.grid(True, alpha=0.3)
    return fig


def write_limb_figure(out_dir: str | Path, rate_hz: float = RATE_HZ,
                      data: LimbData | None = None) -> Path:
    """Write ``limb_knee.png``; return its path.

    :param data: the simulations to draw (:func:`limb_data` at ``rate_hz`` if omitted)
    """
    return save_figure(plot_limb(data if data is not None else limb_data(rate_hz)), out_dir,
                 LIMB_FIGURE_FILE)
