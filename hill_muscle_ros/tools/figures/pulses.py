"""The figures of the pulse model (``activation_model: ding2003``, doc/model.md
section 10), each next to the published result it should match: the
force-frequency curve, the doublet-opened (catch-like) train against the
constant train, Kesar & Binder-Macleod 2006's three fatigue protocols, and four
channels fired in turn against one.

Each has a data function (the simulations behind it, which
test/test_pulse_physiology.py checks), a plot function and a function that
writes the PNG and returns its path. Every figure runs an isometric muscle
whose force is Ding et al. 2003's F: the CE at l_opt, f_iso_max = A (tau1 +
tau2) = 333.87 N and a tendon stiff enough that the CE barely moves.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from ... import resources
from ...model import MuscleParams, SimulationResult, simulate
from ...model.protocol import PulseProtocol, read_protocol
from .plotting import DPI, RATE_HZ, US_PER_S, save_figure

#: [inch] size of the pulse figures (width, height).
PULSE_FIGSIZE_IN = (8.0, 7.2)
#: File names of the pulse figures, in the order they are written.
PULSE_FIGURE_FILES = ('pulse_force_frequency.png', 'pulse_catchlike.png',
                      'pulse_kesar_fatigue.png', 'pulse_sdss.png')

#: [N] Ding et al. 2003's force at infinite frequency, A (tau1 + tau2) with
#: A = 3009 N/s (cocofest's ding2003) and the parameters' default tau1, tau2.
DING_F_MAX_N = 3009.0 * (0.050957 + 0.060)
#: The isometric muscle of every pulse figure: Ding's force, the CE at l_opt,
#: a stiff tendon (0.33 um of stretch at 333.87 N: so stiff that the engine
#: takes the CE quasi-static, 40 times faster than 1e7 N/m's RK4 substeps,
#: the forces the same within 1e-8 N) and force-velocity constants
#: in proportion to the force (a = 0.25 f_iso_max, b = 2.5 l_opt / s, as in
#: config/fes_quadriceps.yaml), so that the CE's slow creep under a changing
#: force changes it by well under 1 %.
PULSE_MUSCLE = {'activation_model': 'ding2003', 'f_iso_max_n': DING_F_MAX_N,
                'l_rest_m': 0.1, 'l_opt_m': 0.1, 'k_se_n_per_m': 1.0e9,
                'fv_a_n': 0.25 * DING_F_MAX_N, 'fv_b_m_per_s': 0.25,
                'fv_a_ecc_n': 0.25 * DING_F_MAX_N, 'fv_b_ecc_m_per_s': 0.1875}
#: The caption's words for :data:`PULSE_MUSCLE`.
PULSE_MUSCLE_TEXT = ('ding2003, f_iso_max 333.87 N = A(tau1 + tau2), CE at l_opt, '
                     'k_SE 1e9 N/m, isometric')


def pulse_params(**fields) -> MuscleParams:
    """:data:`PULSE_MUSCLE` with ``fields`` on top."""
    return MuscleParams(**{**PULSE_MUSCLE, **fields})


def shipped_protocol(name: str, duration_s: float | None = None) -> PulseProtocol:
    """A pulse protocol of ``config/protocols`` (``name`` without ``.yaml``),
    cut to ``duration_s`` if given."""
    protocol = read_protocol(resources.config_dir() / 'protocols' / f'{name}.yaml')
    if duration_s is not None:
        protocol = dataclasses.replace(protocol, duration_s=float(duration_s))
    return protocol


def per_cycle(result: SimulationResult, period_s: float, reduce=np.maximum) -> np.ndarray:
    """``reduce`` (np.maximum: the peak; np.add: the sum) of the force over each
    cycle [k period, (k + 1) period) of a run, for every whole cycle."""
    n = int(round(result.t_s[-1] / period_s + 1e-9))
    starts = np.searchsorted(result.t_s, np.arange(n + 1) * period_s - 1e-9)
    return reduce.reduceat(result.force_n[:starts[-1]], starts[:-1])


def cycle_fti(result: SimulationResult, period_s: float) -> np.ndarray:
    """[N s] the force-time integral of each cycle (the samples' sum times dt)."""
    dt = result.t_s[1] - result.t_s[0]
    return per_cycle(result, period_s, np.add) * dt


# --------------------------------------------------------------- force-frequency

#: [Hz] The frequencies of the force-frequency curve.
FF_FREQUENCIES_HZ = (1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0, 10.0, 12.0, 14.0, 16.0, 18.0,
                     20.0, 25.0, 30.0, 35.0, 40.0, 50.0, 60.0, 70.0, 80.0, 90.0, 100.0)
#: [s] Two pulse widths (60 % and 30 % of the units on the linear curve,
#: PW_max 500 us): Binder-Macleod et al. 1995 found the same normalised curve
#: at 20 % and 50 % of MVC.
FF_PULSE_WIDTHS_S = (300e-6, 150e-6)
#: [s] A train lasts at least this long (Ding's a settles within ~0.5 s) and
#: at least two periods; the last whole period is measured.
FF_MIN_TRAIN_S = 1.0


def ff_protocol(frequency_hz: float, pulse_width_s: float) -> PulseProtocol:
    """A constant train from 0 with a whole number of periods, >= 1 s and >= 2 periods."""
    n = max(2, int(np.ceil(FF_MIN_TRAIN_S * frequency_hz)))
    duration = n / frequency_hz
    return PulseProtocol.from_mapping({
        'name': f'{frequency_hz:g} Hz', 'duration_s': duration,
        'channels': [{'frequency_hz': [[0.0, frequency_hz]],
                      'pulse_width_s': [[0.0, pulse_width_s]]}],
        'dl_mt_m': [[0.0, 0.0]]}, source=f'<{frequency_hz:g} Hz train>')


@dataclass(frozen=True)
class ForceFrequencyData:
    """Steady force of the last period against frequency, per pulse width.

    :param frequency_hz: [Hz] the frequencies
    :param peak_n: pulse width -> [N] peak force of the last period
    :param mean_n: pulse width -> [N] mean force of the last period
    """

    frequency_hz: np.ndarray
    peak_n: dict[float, np.ndarray]
    mean_n: dict[float, np.ndarray]

    def normalised(self, pulse_width_s: float, kind: str = 'peak') -> np.ndarray:
        """[-] the peak (or mean) force over its value at the highest frequency."""
        values = (self.peak_n if kind == 'peak' else self.mean_n)[pulse_width_s]
        return values / values[-1]

    def frequency_at(self, fraction: float, pulse_width_s: float = FF_PULSE_WIDTHS_S[0],
                     kind: str = 'peak') -> float:
        """[Hz] where the normalised curve crosses ``fraction`` (linear between points)."""
        return float(np.interp(fraction, self.normalised(pulse_width_s, kind),
                               self.frequency_hz))


def force_frequency_data(rate_hz: float = RATE_HZ) -> ForceFrequencyData:
    """Every frequency at every pulse width, each from rest."""
    params = pulse_params()
    freqs = np.array(FF_FREQUENCIES_HZ)
    peak, mean = {}, {}
    for pw in FF_PULSE_WIDTHS_S:
        peaks, means = [], []
        for f in freqs:
            protocol = ff_protocol(float(f), pw)
            r = simulate(protocol, params, rate_hz)
            last = r.t_s >= protocol.duration_s - 1.0 / f - 1e-9
            last[-1] = False   # the sample at the end is the next period's first
            peaks.append(r.force_n[last].max())
            means.append(r.force_n[last].mean())
        peak[pw], mean[pw] = np.array(peaks), np.array(means)
    return ForceFrequencyData(freqs, peak, mean)


def plot_force_frequency(data: ForceFrequencyData) -> Figure:
    """Normalised peak and mean force of the last period against frequency."""
    fig = Figure(figsize=PULSE_FIGSIZE_IN, dpi=DPI, layout='constrained')
    ax = fig.subplots()
    colours = {FF_PULSE_WIDTHS_S[0]: 'tab:blue', FF_PULSE_WIDTHS_S[1]: 'tab:orange'}
    for pw in FF_PULSE_WIDTHS_S:
        ax.plot(data.frequency_hz, data.normalised(pw, 'peak'), 'o-', color=colours[pw],
                linewidth=2.0 if pw == FF_PULSE_WIDTHS_S[0] else 1.2,
                label=f'peak force, {pw * US_PER_S:.0f} us')
        ax.plot(data.frequency_hz, data.normalised(pw, 'mean'), 's--', color=colours[pw],
                markersize=4, linewidth=1.2, label=f'mean force, {pw * US_PER_S:.0f} us')
    f50 = data.frequency_at(0.5)
    ax.axhline(0.5, color='grey', linestyle=':', linewidth=1.0)
    ax.axvline(f50, color='grey', linestyle=':', linewidth=1.0)
    ax.text(f50 + 1.0, 0.05, f'peak 50 % at {f50:.1f} Hz', color='grey')
    ax.set_xlabel('stimulation frequency [Hz]')
    ax.set_ylabel('force of the last period / force at 100 Hz [-]')
    ax.set_title('Force-frequency curve of the pulse model\n'
                 f'{PULSE_MUSCLE_TEXT}\n(1 s trains, linear curve, PW_max 500 us)',
                 fontsize='medium')
    ax.set_xlim(0.0, 102.0)
    ax.set_ylim(0.0, 1.05)
    ax.grid(True, alpha=0.3)
    ax.legend(loc='lower right', fontsize='small')
    return fig


def write_force_frequency_figure(out_dir: str | Path, rate_hz: float = RATE_HZ) -> Path:
    """Write ``pulse_force_frequency.png``; return its path."""
    return save_figure(plot_force_frequency(force_frequency_data(rate_hz)), out_dir,
                       PULSE_FIGURE_FILES[0])


# --------------------------------------------------------------- catch-like trains

#: The two trains (config/protocols): six 200 us pulses 70 ms apart, and the
#: same opened by a 5 ms doublet; a contraction every CATCH_PERIOD_S.
CATCH_PROTOCOLS = ('catchlike_cft', 'catchlike_vft')
CATCH_PERIOD_S = 0.8
#: [s] The force panel shows the first contractions, until this instant.
CATCH_SHOW_S = 1.6


@dataclass(frozen=True)
class CatchData:
    """The CFT and the VFT over the whole protocol, with Riener fatigue.

    :param results: protocol name -> simulation
    :param fti: protocol name -> [N s] force-time integral of each contraction
    """

    results: dict[str, SimulationResult]
    fti: dict[str, np.ndarray]

    @property
    def ratio(self) -> np.ndarray:
        """[-] VFT / CFT force-time integral, contraction by contraction."""
        return self.fti['catchlike_vft'] / self.fti['catchlike_cft']


def catch_params() -> MuscleParams:
    """The pulse muscle with Riener fatigue (linear curve, PW_max 500 us: 200 us
    recruits 40 % of the units)."""
    return pulse_params(fatigue='riener')


def catch_data(rate_hz: float = RATE_HZ) -> CatchData:
    """Both protocols, the force-time integral of every contraction."""
    params = catch_params()
    results = {name: simulate(shipped_protocol(name), params, rate_hz)
               for name in CATCH_PROTOCOLS}
    return CatchData(results, {n: cycle_fti(r, CATCH_PERIOD_S) for n, r in results.items()})


def plot_catch(data: CatchData) -> Figure:
    """Force of the first contractions above; the FTI ratio per contraction below."""
    fig = Figure(figsize=PULSE_FIGSIZE_IN, dpi=DPI, layout='constrained')
    ax_f, ax_r = fig.subplots(2, 1, gridspec_kw={'height_ratios': (3, 2)})
    styles = {'catchlike_cft': ('tab:blue', '-', 'CFT: six pulses 70 ms apart'),
              'catchlike_vft': ('tab:red', '--', 'VFT: the same opened by a 5 ms doublet')}
    for name in CATCH_PROTOCOLS:
        r = data.results[name]
        color, style, label = styles[name]
        show = r.t_s <= CATCH_SHOW_S
        ax_f.plot(r.t_s[show], r.force_n[show], color=color, linestyle=style, linewidth=2.0,
                  label=f'{label} (FTI {data.fti[name][0]:.1f} N s)')
    ax_f.set_xlabel('time [s]')
    ax_f.set_ylabel('force [N]')
    ax_f.set_title('Catch-like trains (Bickel et al. 2004): the first two contractions\n'
                   f'{PULSE_MUSCLE_TEXT}\n(200 us of PW_max 500 us, fatigue riener)',
                   fontsize='medium')
    ax_f.set_ylim(bottom=0.0)
    ax_f.grid(True, alpha=0.3)
    ax_f.legend(loc='upper right', fontsize='small')
    k = np.arange(1, len(data.ratio) + 1)
    ax_r.plot(k, data.ratio, color='black', linewidth=1.5, label='model, VFT / CFT')
    ax_r.axhline(1.0, color='grey', linestyle=':', linewidth=1.0)
    ax_r.axhline(1.18, color='tab:green', linestyle='--', linewidth=1.2,
                 label='Bickel et al. 2004: +18 % in fatigued able-bodied quadriceps')
    ax_r.set_xlabel('contraction')
    ax_r.set_ylabel('force-time integral VFT / CFT [-]')
    ax_r.set_xlim(1, len(data.ratio))
    ax_r.grid(True, alpha=0.3)
    ax_r.legend(loc='lower right', fontsize='small')
    return fig


def write_catch_figure(out_dir: str | Path, rate_hz: float = RATE_HZ) -> Path:
    """Write ``pulse_catchlike.png``; return its path."""
    return save_figure(plot_catch(catch_data(rate_hz)), out_dir, PULSE_FIGURE_FILES[1])


# --------------------------------------------------------------- Kesar 2006

#: Kesar & Binder-Macleod 2006's protocols (config/protocols), low to high frequency.
KESAR_PROTOCOLS = ('kesar2006_11hz_600us', 'kesar2006_30hz_150us', 'kesar2006_60hz_131us')
#: [s] A train every second.
KESAR_PERIOD_S = 1.0
#: [s] PW_max of the linear curve, chosen so that the three protocols start at
#: the same peak force as in the study (where each subject's pulse widths were
#: set for it): the first 60 Hz train at 131 us of 206 us (64 % of the units)
#: peaks at a = 0.833, the first 11.5 Hz train at 600 us (every unit) at 0.530,
#: and 0.636 x 0.833 = 0.530; 30 Hz at 150 us recruits 73 % at a = 0.743 (2 %
#: above). The p24 stimulator accepts 600 us; its width saturates the curve.
KESAR_PW_MAX_S = 206e-6


@dataclass(frozen=True)
class KesarData:
    """The three protocols with Riener fatigue.

    :param results: protocol name -> simulation
    :param peaks: protocol name -> [N] peak force of each train
    """

    results: dict[str, SimulationResult]
    peaks: dict[str, np.ndarray]

    def normalised(self, name: str) -> np.ndarray:
        """[-] peak force of each train over that of the first."""
        return self.peaks[name] / self.peaks[name][0]


def kesar_params() -> MuscleParams:
    """The pulse muscle with Riener fatigue, the p24 stimulator and :data:`KESAR_PW_MAX_S`."""
    return pulse_params(fatigue='riener', stimulator='p24', pw_max_s=KESAR_PW_MAX_S)


def kesar_data(rate_hz: float = RATE_HZ) -> KesarData:
    """The three 180 s protocols, the peak force of every train."""
    params = kesar_params()
    results = {name: simulate(shipped_protocol(name), params, rate_hz)
               for name in KESAR_PROTOCOLS}
    return KesarData(results, {n: per_cycle(r, KESAR_PERIOD_S) for n, r in results.items()})


def plot_kesar(data: KesarData) -> Figure:
    """Normalised peak force per train above; the mean fitness below."""
    fig = Figure(figsize=PULSE_FIGSIZE_IN, dpi=DPI, layout='constrained')
    ax_p, ax_m = fig.subplots(2, 1, sharex=True, gridspec_kw={'height_ratios': (3, 2)})
    styles = {'kesar2006_11hz_600us': ('tab:green', '11.5 Hz, 600 us'),
              'kesar2006_30hz_150us': ('tab:orange', '30 Hz, 150 us'),
              'kesar2006_60hz_131us': ('tab:red', '60 Hz, 131 us')}
    for name in KESAR_PROTOCOLS:
        color, label = styles[name]
        norm = data.normalised(name)
        t = np.arange(len(norm)) * KESAR_PERIOD_S
        ax_p.plot(t, norm, color=color, linewidth=2.0,
                  label=f'{label}: first train {data.peaks[name][0]:.0f} N, '
                        f'last {norm[-1] * 100:.0f} %')
        r = data.results[name]
        ax_m.plot(r.t_s, r.mean_fitness, color=color, linewidth=1.5, label=label)
    ax_p.set_ylabel('peak force / first train [-]')
    ax_p.set_title("Kesar & Binder-Macleod 2006's protocols: 300 ms trains every second\n"
                   f'{PULSE_MUSCLE_TEXT}\n(linear curve, PW_max '
                   f'{KESAR_PW_MAX_S * US_PER_S:.0f} us, fatigue riener)', fontsize='medium')
    ax_p.grid(True, alpha=0.3)
    ax_p.legend(loc='upper right', fontsize='small')
    ax_m.set_ylabel('mean fitness of all units [-]')
    ax_m.set_xlabel('time [s]')
    ax_m.set_xlim(0.0, 180.0)
    ax_m.grid(True, alpha=0.3)
    ax_m.legend(loc='upper right', fontsize='small')
    return fig


def write_kesar_figure(out_dir: str | Path, rate_hz: float = RATE_HZ) -> Path:
    """Write ``pulse_kesar_fatigue.png``; return its path."""
    return save_figure(plot_kesar(kesar_data(rate_hz)), out_dir, PULSE_FIGURE_FILES[2])


# --------------------------------------------------------------- SDSS

#: One channel at 40 Hz against four at 10 Hz in turn (config/protocols).
SDSS_PROTOCOLS = ('sdss_one_channel', 'sdss_four_channels')
#: Each protocol's channel territories: one, and four equal ones.
SDSS_CHANNELS = {'sdss_one_channel': (1.0,), 'sdss_four_channels': (0.25, 0.25, 0.25, 0.25)}
#: [s] The first two minutes of the protocols; a contraction every 2 s.
SDSS_DURATION_S = 120.0
SDSS_PERIOD_S = 2.0


@dataclass(frozen=True)
class SdssData:
    """One channel against four, with Riener fatigue.

    :param results: protocol name -> simulation
    :param peaks: protocol name -> [N] peak force of each contraction
    """

    results: dict[str, SimulationResult]
    peaks: dict[str, np.ndarray]


def sdss_params(name: str) -> MuscleParams:
    """The pulse muscle with Riener fatigue and the channels of ``name`` (linear
    curve, PW_max 500 us: 300 us recruits 60 % of each territory)."""
    return pulse_params(fatigue='riener', channel_fractions=SDSS_CHANNELS[name])


def sdss_data(rate_hz: float = RATE_HZ) -> SdssData:
    """Both protocols over :data:`SDSS_DURATION_S`."""
    results = {name: simulate(shipped_protocol(name, SDSS_DURATION_S), sdss_params(name),
                              rate_hz) for name in SDSS_PROTOCOLS}
    return SdssData(results, {n: per_cycle(r, SDSS_PERIOD_S) for n, r in results.items()})


def plot_sdss(data: SdssData) -> Figure:
    """Peak force per contraction above; mean fitness below."""
    fig = Figure(figsize=PULSE_FIGSIZE_IN, dpi=DPI, layout='constrained')
    ax_f, ax_m = fig.subplots(2, 1, sharex=True)
    styles = {'sdss_one_channel': ('tab:red', 'one channel at 40 Hz'),
              'sdss_four_channels': ('tab:blue', 'four channels at 10 Hz, 25 ms apart')}
    for name in SDSS_PROTOCOLS:
        color, label = styles[name]
        peaks = data.peaks[name]
        t = np.arange(len(peaks)) * SDSS_PERIOD_S
        ax_f.plot(t, peaks, 'o-', markersize=3, color=color, linewidth=1.8,
                  label=f'{label}: {peaks[-1] / peaks[0] * 100:.0f} % of the first at the end')
        r = data.results[name]
        ax_m.plot(r.t_s, r.mean_fitness, color=color, linewidth=1.8,
                  label=f'{label}: {r.mean_fitness[-1]:.3f} at the end')
    ax_f.set_ylabel('peak force of each contraction [N]')
    ax_f.set_ylim(bottom=0.0)
    ax_f.set_title('Four channels fired in turn (SDSS) against one, 40 pulses/s in all\n'
                   f'{PULSE_MUSCLE_TEXT}\n(300 us of PW_max 500 us, 0.99 s on every 2 s, '
                   'fatigue riener)', fontsize='medium')
    ax_f.grid(True, alpha=0.3)
    ax_f.legend(loc='lower left', fontsize='small')
    ax_m.set_ylabel('mean fitness of all units [-]')
    ax_m.set_xlabel('time [s]')
    ax_m.set_xlim(0.0, SDSS_DURATION_S)
    ax_m.grid(True, alpha=0.3)
    ax_m.legend(loc='lower left', fontsize='small')
    return fig


def write_sdss_figure(out_dir: str | Path, rate_hz: float = RATE_HZ) -> Path:
    """Write ``pulse_sdss.png``; return its path."""
    return save_figure(plot_sdss(sdss_data(rate_hz)), out_dir, PULSE_FIGURE_FILES[3])


def write_pulse_figures(out_dir: str | Path, rate_hz: float = RATE_HZ) -> list[Path]:
    """Write the four pulse figures into ``out_dir`` (created if missing).

    :param rate_hz: [Hz] sample rate of the simulations
    :return: the paths written, in the order of :data:`PULSE_FIGURE_FILES`
    """
    return [write_force_frequency_figure(out_dir, rate_hz),
            write_catch_figure(out_dir, rate_hz),
            write_kesar_figure(out_dir, rate_hz),
            write_sdss_figure(out_dir, rate_hz)]
