"""The figures of the FES extensions (doc/model.md section 7), each making one
point: the recruitment curves, the delay and activation, per-unit versus
whole-muscle fatigue, the recruitment order of fibre types, and the scaling of
the force-velocity constants.

Each has a data function (the simulation behind it, which the tests check), a
plot function and a function that writes the PNG and returns its path.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from ...model import Muscle, MuscleParams, Protocol, SimulationResult, simulate
from ...model.simulate import sample_times
from ...model.stimulus import command_from_pulse_width
from .plotting import DL_LABEL, DPI, MM_PER_M, RATE_HZ, US_PER_S, save_figure

#: [inch] size of the FES figures (width, height); the fatigue figure is taller.
FES_FIGSIZE_IN = (8.0, 7.2)
FATIGUE_FIGSIZE_IN = (8.0, 11.2)
#: File names of the FES figures, in the order they are written.
FES_FIGURE_FILES = ('fes_recruitment_curves.png', 'fes_activation.png', 'fes_fatigue.png',
                    'fes_fibre_types.png', 'fes_fv_scaling.png')


#: [s] Threshold pd0 and scale pdt of Ding et al. (2007)'s exponential
#: recruitment curve (131.405 us and 194.138 us in cocofest's ding2007 model).
DING_PW_THRESHOLD_S = 131.4e-6
DING_PW_SCALE_S = 194.1e-6


def _protocol(name: str, duration_s: float, key: str, stimulation: list,
              dl_mt_m: list) -> Protocol:
    """A protocol from knots ``[time_s, value]``, validated like a protocol file."""
    return Protocol.from_mapping({'name': name, 'duration_s': duration_s, key: stimulation,
                                  'dl_mt_m': dl_mt_m}, source=f'<{name}>')


def _train(t_on_s: float, t_off_s: float, pulse_width_s: float) -> list:
    """Knots of one stimulation train: 0 before ``t_on_s``, PW until ``t_off_s``, 0 after."""
    return [[t_on_s, 0.0], [t_on_s, pulse_width_s], [t_off_s, pulse_width_s], [t_off_s, 0.0]]


#: The recruitment curves, in the order drawn.
CURVES = ('linear', 'threshold_linear', 'exponential')
#: [s] end of the pulse-width axis: past PW_max (500 us) to show the saturation.
CURVE_PW_END_S = 600e-6
#: Points per curve: one per microsecond.
CURVE_SAMPLES = 601


def curve_params(curve: str) -> MuscleParams:
    """The paper's muscle with recruitment curve ``curve``.

    The threshold of ``threshold_linear`` and ``exponential`` and the scale of
    ``exponential`` are Ding et al. (2007)'s, so the two share a threshold.
    """
    if curve == 'linear':
        return MuscleParams()
    return MuscleParams(recruitment_curve=curve, pw_threshold_s=DING_PW_THRESHOLD_S,
                        pw_scale_s=DING_PW_SCALE_S)


@dataclass(frozen=True)
class CurveData:
    """The recruitment command u of each curve against pulse width.

    :param pulse_width_s: [s] pulse widths PW
    :param command: curve name -> [-] u(PW)
    :param params: curve name -> the parameters that gave it
    """

    pulse_width_s: np.ndarray
    command: dict[str, np.ndarray]
    params: dict[str, MuscleParams]


def recruitment_curve_data(n_samples: int = CURVE_SAMPLES) -> CurveData:
    """u(PW) of the three curves, from the model's own recruitment curve."""
    pw = np.linspace(0.0, CURVE_PW_END_S, n_samples)
    params = {c: curve_params(c) for c in CURVES}
    command = {c: np.array([command_from_pulse_width(x, params[c]) for x in pw])
               for c in CURVES}
    return CurveData(pw, command, params)


def plot_recruitment_curves(data: CurveData) -> Figure:
    """u against PW for the three curves, with threshold, scale and PW_max marked."""
    fig = Figure(figsize=FES_FIGSIZE_IN, dpi=DPI, layout='constrained')
    ax = fig.subplots()
    styles = {'linear': ('tab:blue', '-'), 'threshold_linear': ('tab:green', '--'),
              'exponential': ('tab:red', '-')}
    labels = {'linear': 'linear: PW / PW_max (the paper)',
              'threshold_linear': 'threshold_linear: (PW - PW_th) / (PW_max - PW_th)',
              'exponential': 'exponential: 1 - exp(-(PW - PW_th) / PW_scale) (Ding et al. 2007)'}
    pw_us = data.pulse_width_s * US_PER_S
    for c in CURVES:
        color, style = styles[c]
        ax.plot(pw_us, data.command[c], color=color, linestyle=style, linewidth=2.0,
                label=labels[c])
    p = data.params['exponential']
    ax.axvline(p.pw_threshold_s * US_PER_S, color='grey', linestyle=':', linewidth=1.0)
    ax.axvline(p.pw_max_s * US_PER_S, color='grey', linestyle=':', linewidth=1.0)
    ax.text(p.pw_threshold_s * US_PER_S, 1.03, ' PW_th', color='grey', va='bottom')
    ax.text(p.pw_max_s * US_PER_S, 1.03, ' PW_max', color='grey', va='bottom')
    knee_pw = (p.pw_threshold_s + p.pw_scale_s) * US_PER_S
    knee_u = 1.0 - math.exp(-1.0)
    ax.plot([knee_pw], [knee_u], 'o', color='tab:red')
    ax.annotate('PW_th + PW_scale: u = 1 - 1/e', (knee_pw, knee_u),
                xytext=(knee_pw + 40.0, knee_u - 0.18), arrowprops={'arrowstyle': '->'})
    ax.set_xlabel('pulse width PW [us]')
    ax.set_ylabel('recruitment command u [-]')
    ax.set_title('Recruitment curves: pulse width to recruitment command')
    ax.set_xlim(0.0, CURVE_PW_END_S * US_PER_S)
    ax.set_ylim(-0.02, 1.12)
    ax.grid(True, alpha=0.3)
    ax.legend(loc='lower right', fontsize='small')
    return fig


def write_recruitment_curves_figure(out_dir: str | Path) -> Path:
    """Write ``fes_recruitment_curves.png``; return its path."""
    return save_figure(plot_recruitment_curves(recruitment_curve_data()), out_dir,
                 FES_FIGURE_FILES[0])


#: [s] The activation figure's stimulation: pulse width ACT_PW_S from ACT_T_ON_S
#: to ACT_T_OFF_S, then nothing until ACT_DURATION_S.
ACT_T_ON_S = 0.1
ACT_T_OFF_S = 0.8
ACT_DURATION_S = 1.5
#: [s] 300 us: about 60 % of the units on Ding's exponential curve.
ACT_PW_S = 300e-6
#: [s], [m] While the units are being recruited the MTU is stretched by 5 mm at
#: the paper's 10 mm/s, so that units recruited at different instants store
#: clearly different CE lengths (``initial``).
ACT_STRETCH_KNOTS = [[0.0, 0.0], [0.2, 0.0], [0.7, 0.005]]
#: The delay and activation of the figure: Sinclair et al.'s 31 ms delay of the
#: stimulated quadriceps at 90 deg of knee flexion, and an activation (60 ms) and
#: deactivation (110 ms) slow enough for each stage to show at this time scale.
ACT_FES = {'recruitment_curve': 'exponential', 'pw_threshold_s': DING_PW_THRESHOLD_S,
           'pw_scale_s': DING_PW_SCALE_S, 'emd_s': 0.031, 'tau_act_s': 0.060,
           'tau_deact_s': 0.110}
#: The two length variants compared.
ACT_LENGTHS = ('initial', 'instantaneous')


@dataclass(frozen=True)
class ActivationData:
    """A pulse-width step through delay and activation, for each length variant.

    :param protocol: the stimulation and length protocol
    :param params: the FES parameters (``length: initial``)
    :param results: length variant -> simulation
    """

    protocol: Protocol
    params: MuscleParams
    results: dict[str, SimulationResult]


def activation_protocol() -> Protocol:
    """The pulse-width step of the activation figure."""
    return _protocol('pulse-width step', ACT_DURATION_S, 'pulse_width_s',
                     _train(ACT_T_ON_S, ACT_T_OFF_S, ACT_PW_S), ACT_STRETCH_KNOTS)


def activation_data(rate_hz: float = RATE_HZ) -> ActivationData:
    """Simulate the pulse-width step with ``initial`` and ``instantaneous`` length."""
    protocol = activation_protocol()
    params = MuscleParams(**ACT_FES)
    results = {length: simulate(protocol, params.replace(length=length), rate_hz)
               for length in ACT_LENGTHS}
    return ActivationData(protocol, params, results)


def plot_activation(data: ActivationData) -> Figure:
    """Force of both length variants above; command, delayed command, activation below."""
    fig = Figure(figsize=FES_FIGSIZE_IN, dpi=DPI, layout='constrained')
    ax_f, ax_a = fig.subplots(2, 1, sharex=True, gridspec_kw={'height_ratios': (3, 2)})
    styles = {'initial': ('tab:orange', '-', 2.5), 'instantaneous': ('tab:red', '--', 1.6)}
    for length in ACT_LENGTHS:
        r = data.results[length]
        color, style, width = styles[length]
        ax_f.plot(r.t_s, r.force_n, color=color, linestyle=style, linewidth=width,
                  label=f'multiple units, {length} length')
    p = data.params
    ax_f.set_ylabel('muscle force [N]')
    ax_f.set_title(f'Pulse-width step through a {p.emd_s * 1e3:.0f} ms delay and '
                   f'activation ({p.tau_act_s * 1e3:.0f} ms up, '
                   f'{p.tau_deact_s * 1e3:.0f} ms down)')
    ax_f.set_ylim(bottom=0.0)
    ax_f.grid(True, alpha=0.3)
    ax_f.legend(loc='upper right', fontsize='small')

    r = data.results['initial']
    delayed = np.where(r.t_s >= p.emd_s,
                       data.protocol.command(np.maximum(r.t_s - p.emd_s, 0.0), p), 0.0)
    ax_a.plot(r.t_s, r.command, color='grey', linewidth=1.5, label='command u = curve(PW)')
    ax_a.plot(r.t_s, delayed, color='black', linestyle=':', linewidth=1.5,
              label='delayed command u(t - emd)')
    ax_a.plot(r.t_s, r.recruitment, color='tab:blue', linewidth=2.0,
              label='activation a = recruitment R')
    ax_dl = ax_a.twinx()
    ax_dl.plot(r.t_s, r.dl_mt_m * MM_PER_M, color='tab:purple', linestyle='--',
               linewidth=1.2, label=DL_LABEL)
    ax_dl.set_ylabel(f'{DL_LABEL} [mm]', color='tab:purple')
    ax_dl.tick_params(axis='y', colors='tab:purple')
    ax_dl.set_ylim(-1.0, 12.0)
    ax_a.set_ylabel('u, a [-]')
    ax_a.set_ylim(-0.05, 1.0)
    ax_a.set_xlabel('time [s]')
    ax_a.set_xlim(0.0, data.protocol.duration_s)
    ax_a.grid(True, alpha=0.3)
    ax_a.legend(loc='upper right', fontsize='small')
    return fig


def write_activation_figure(out_dir: str | Path, rate_hz: float = RATE_HZ) -> Path:
    """Write ``fes_activation.png``; return its path."""
    return save_figure(plot_activation(activation_data(rate_hz)), out_dir, FES_FIGURE_FILES[1])


#: [s] The intermittent protocol: a train of FATIGUE_ON_S every FATIGUE_PERIOD_S,
#: FATIGUE_TRAINS times (two minutes); the last train does not stop: at its
#: end its pulse width steps up, held FATIGUE_HOLD_S.
FATIGUE_ON_S = 5.0
FATIGUE_PERIOD_S = 10.0
FATIGUE_TRAINS = 12
FATIGUE_HOLD_S = 10.0
#: [s] Pulse widths before and after the step: R = 0.4 and 0.8 on the linear
#: curve (PW_max = 500 us), so the step recruits as many fresh units as the
#: trains have been tiring.
FATIGUE_PW_LOW_S = 200e-6
FATIGUE_PW_HIGH_S = 400e-6
#: [s] Instants at which the fitness profile is drawn: the end of the first
#: train, two later ones, just before the step and the end.
FATIGUE_PROFILE_TIMES_S = (5.0, 45.0, 85.0, 115.0, 125.0)
#: The two fatigue models compared: per-unit (multi) and whole-muscle (single),
#: both with Riener's law and its parameters (the defaults).
FATIGUE_UNITS = ('multi', 'single')


def fatigue_step_s() -> float:
    """[s] instant of the step up: the end of the last train's low pulse width."""
    return (FATIGUE_TRAINS - 1) * FATIGUE_PERIOD_S + FATIGUE_ON_S


def fatigue_protocol() -> Protocol:
    """Five seconds on, five off for two minutes, then a step to a higher pulse width."""
    knots = []
    for i in range(FATIGUE_TRAINS - 1):
        t0 = i * FATIGUE_PERIOD_S
        knots += _train(t0, t0 + FATIGUE_ON_S, FATIGUE_PW_LOW_S)
    t_last, t_step = (FATIGUE_TRAINS - 1) * FATIGUE_PERIOD_S, fatigue_step_s()
    end = t_step + FATIGUE_HOLD_S
    knots += [[t_last, 0.0], [t_last, FATIGUE_PW_LOW_S], [t_step, FATIGUE_PW_LOW_S],
              [t_step, FATIGUE_PW_HIGH_S], [end, FATIGUE_PW_HIGH_S]]
    return _protocol('intermittent trains, then a step up', end, 'pulse_width_s', knots,
                     [[0.0, 0.0]])


def fatigue_params(units: str) -> MuscleParams:
    """The paper's muscle with Riener fatigue (defaults), per unit or whole-muscle."""
    return MuscleParams(fatigue='riener', units=units)


def fitness_profiles(protocol: Protocol, params: MuscleParams, rate_hz: float,
                     times_s: tuple[float, ...]) -> dict[float, np.ndarray]:
    """Fitness of every unit along the recruitment order at the sample instants ``times_s``.

    Steps a muscle through ``protocol`` exactly as :func:`simulate` does (the
    command of t_k given at t_k, then the step to t_(k+1)), reading
    ``fitness_profile()`` at the samples nearest to ``times_s``. O(N) per read.

    :return: instant -> [-] mu of the units at positions 1..N of the order
    """
    muscle = Muscle(params)
    t = sample_times(protocol.duration_s, rate_hz)
    command = np.asarray(protocol.command(t, muscle.params), dtype=float).tolist()
    dl = np.asarray(protocol.dl_mt(t), dtype=float).tolist()
    wanted = {int(round(s * rate_hz)): s for s in times_s}
    dt = 1.0 / rate_hz
    profiles = {}
    last = len(t) - 1
    for k in range(last + 1):
        muscle.set_recruitment(command[k])
        if k in wanted:
            profiles[wanted[k]] = muscle.fitness_profile()
        if k < last:
            muscle.advance(dl[k + 1], dt)
    return profiles


@dataclass(frozen=True)
class FatigueData:
    """The intermittent protocol with per-unit and whole-muscle fatigue.

    :param protocol: the protocol
    :param step_s: [s] instant of the step up
    :param results: ``multi`` / ``single`` -> simulation
    :param profiles: instant -> [-] fitness along the order (multi)
    """

    protocol: Protocol
    step_s: float
    results: dict[str, SimulationResult]
    profiles: dict[float, np.ndarray]


def fatigue_data(rate_hz: float = RATE_HZ) -> FatigueData:
    """Simulate the intermittent protocol with both fatigue models.

    At 1 kHz the 125 s protocol is 125 000 steps per model; the figure uses
    the default 1 kHz (about 5 s for all three passes on one core).
    """
    protocol = fatigue_protocol()
    results = {u: simulate(protocol, fatigue_params(u), rate_hz) for u in FATIGUE_UNITS}
    profiles = fitness_profiles(protocol, fatigue_params('multi'), rate_hz,
                                FATIGUE_PROFILE_TIMES_S)
    return FatigueData(protocol, fatigue_step_s(), results, profiles)


def f0_per_recruitment(result: SimulationResult) -> np.ndarray:
    """[N] F0 / R: the effective isometric force per unit of recruitment.

    NaN where nothing is recruited. Without fatigue, with every unit recruited
    at the same length, it is f_iso_max FL whatever R is; with fatigue it is
    scaled by the mean fitness of the recruited units, so it shows whether the
    units a step up adds are fresh or as tired as the rest.
    """
    with np.errstate(divide='ignore', invalid='ignore'):
        return np.where(result.recruitment > 0.0, result.eff_f_iso_n / result.recruitment,
                        np.nan)


def plot_fatigue(data: FatigueData) -> Figure:
    """Stimulus, force, F0 per recruitment and mean fitness against time; fitness
    along the unit order at a few instants."""
    fig = Figure(figsize=FATIGUE_FIGSIZE_IN, dpi=DPI, layout='constrained')
    grid = fig.add_gridspec(5, 1, height_ratios=(0.7, 2.0, 1.5, 1.2, 2.0))
    ax_pw = fig.add_subplot(grid[0])
    ax_f = fig.add_subplot(grid[1], sharex=ax_pw)
    ax_fr = fig.add_subplot(grid[2], sharex=ax_pw)
    ax_mu = fig.add_subplot(grid[3], sharex=ax_pw)
    ax_prof = fig.add_subplot(grid[4])
    multi, single = data.results['multi'], data.results['single']
    colors = {'multi': 'tab:red', 'single': 'tab:blue'}
    labels = {'multi': 'per-unit fatigue (multi)', 'single': 'whole-muscle fatigue (single)'}

    pw = data.protocol.stimulation(multi.t_s)
    ax_pw.plot(multi.t_s, pw * US_PER_S, color='black', linewidth=1.0)
    ax_pw.set_ylabel('PW [us]')
    ax_pw.set_title('5 s on, 5 s off, then a step up: Riener fatigue per unit vs whole muscle')
    for units in ('single', 'multi'):
        r = data.results[units]
        ax_f.plot(r.t_s, r.force_n, color=colors[units], linewidth=1.0, label=labels[units])
        ax_fr.plot(r.t_s, f0_per_recruitment(r), color=colors[units], linewidth=1.0,
                   label=labels[units])
        ax_mu.plot(r.t_s, r.mean_fitness, color=colors[units], linewidth=1.5,
                   label=labels[units])
    for ax in (ax_pw, ax_f, ax_fr, ax_mu):
        ax.axvline(data.step_s, color='grey', linestyle=':', linewidth=1.0)
        ax.grid(True, alpha=0.3)
    for ax in (ax_pw, ax_f, ax_fr):
        ax.tick_params(labelbottom=False)
    i_after = multi.at(data.step_s + 1.0)
    ax_fr.annotate('step up: the added units are fresh', (data.step_s,
                   f0_per_recruitment(multi)[i_after]), xytext=(50.0, 36.0),
                   arrowprops={'arrowstyle': '->'}, fontsize='small')
    ax_f.set_ylabel('muscle force [N]')
    ax_f.set_ylim(0.0, 30.0)
    ax_f.legend(loc='upper left', fontsize='small', ncols=2)
    ax_fr.set_ylabel('F0 / R [N]')
    ax_fr.set_ylim(0.0, 42.0)
    ax_mu.set_ylabel('mean fitness [-]')
    ax_mu.set_ylim(0.0, 1.05)
    ax_mu.set_xlabel('time [s]')
    ax_mu.set_xlim(0.0, data.protocol.duration_s)
    ax_mu.legend(loc='lower left', fontsize='small', ncols=2)

    shades = ('tab:olive', 'tab:green', 'tab:cyan', 'tab:purple', 'black')
    for (t, profile), color in zip(sorted(data.profiles.items()), shades):
        position = np.arange(1, profile.size + 1)
        ax_prof.plot(position, profile, color=color, linewidth=1.8, label=f't = {t:g} s')
        ax_prof.axhline(single.mean_fitness[single.at(t)], color=color, linestyle=':',
                        linewidth=1.2)
    ax_prof.plot([], [], color='grey', linestyle=':', label='whole muscle (one value)')
    ax_prof.set_xlabel('position in the recruitment order [-] (1 = recruited first)')
    ax_prof.set_ylabel('unit fitness mu [-]')
    ax_prof.set_title('Fitness of each unit (solid) and of the whole-muscle model (dotted)',
                      fontsize='medium')
    ax_prof.set_xlim(1, profile.size)
    ax_prof.set_ylim(0.0, 1.05)
    ax_prof.grid(True, alpha=0.3)
    ax_prof.legend(loc='lower right', fontsize='small', ncols=3)
    return fig


def write_fatigue_figure(out_dir: str | Path, rate_hz: float = RATE_HZ) -> Path:
    """Write ``fes_fatigue.png``; return its path."""
    return save_figure(plot_fatigue(fatigue_data(rate_hz)), out_dir, FES_FIGURE_FILES[2])


#: The recruitment orders compared.
FIBRE_ORDERS = ('size', 'reverse', 'random')
#: Two fibre types in equal shares (the vastus lateralis is about half type I,
#: Lexell et al. 1983: 52 %); a fast unit twice as strong as a slow one (fast
#: motor units are the larger ones) and four times as fatigable (60 s vs 15 s;
#: their harmonic mean, 24 s, is near Riener's whole-muscle 30 s). Illustrative
#: values chosen to make the contrast plain, not a fit.
FIBRE_FES = {'fatigue': 'riener', 'fibre_fractions': (0.5, 0.5),
             'fibre_force_weights': (1.0, 2.0), 'tau_fatigue_s': (60.0, 15.0)}
#: [s] 250 us on the linear curve: R = 0.5, half the units, so that ``size``
#: recruits exactly the slow type and ``reverse`` exactly the fast one.
FIBRE_PW_S = 250e-6
#: [s] one minute of constant stimulation, isometric.
FIBRE_DURATION_S = 60.0


def fibre_protocol() -> Protocol:
    """Constant stimulation at half recruitment for one minute, isometric."""
    return _protocol('constant half recruitment', FIBRE_DURATION_S, 'pulse_width_s',
                     [[0.0, FIBRE_PW_S]], [[0.0, 0.0]])


def fibre_params(order: str) -> MuscleParams:
    """The paper's muscle with a slow and a fatigable fast type, recruited in ``order``."""
    return MuscleParams(recruitment_order=order, **FIBRE_FES)


@dataclass(frozen=True)
class FibreData:
    """The fatiguing protocol for each recruitment order.

    :param protocol: the protocol
    :param results: order -> simulation
    """

    protocol: Protocol
    results: dict[str, SimulationResult]


def fibre_data(rate_hz: float = RATE_HZ) -> FibreData:
    """Simulate the constant stimulation with each recruitment order."""
    protocol = fibre_protocol()
    return FibreData(protocol, {o: simulate(protocol, fibre_params(o), rate_hz)
                                for o in FIBRE_ORDERS})


def plot_fibre_types(data: FibreData) -> Figure:
    """Force against time, and F0 relative to its fresh value, per recruitment order."""
    fig = Figure(figsize=FES_FIGSIZE_IN, dpi=DPI, layout='constrained')
    ax_f, ax_n = fig.subplots(2, 1, sharex=True)
    styles = {'size': ('tab:blue', 'size: slow type first'),
              'reverse': ('tab:red', 'reverse: fast type first'),
              'random': ('tab:green', 'random (seeded permutation)')}
    for order in FIBRE_ORDERS:
        r = data.results[order]
        color, label = styles[order]
        ax_f.plot(r.t_s, r.force_n, color=color, linewidth=1.8, label=label)
        ax_n.plot(r.t_s, r.eff_f_iso_n / r.eff_f_iso_n[0], color=color, linewidth=1.8,
                  label=label)
    ax_f.set_ylabel('muscle force [N]')
    ax_f.set_title('Recruitment order at R = 0.5 with a slow and a fatigable fast type '
                   '(force weights 1 : 2, T_fat 60 s : 15 s)', fontsize='medium')
    ax_f.set_ylim(bottom=0.0)
    ax_f.grid(True, alpha=0.3)
    ax_f.legend(loc='upper right', fontsize='small')
    ax_n.set_ylabel('F0 / F0 fresh [-]')
    ax_n.set_ylim(0.0, 1.05)
    ax_n.set_xlabel('time [s]')
    ax_n.set_xlim(0.0, data.protocol.duration_s)
    ax_n.grid(True, alpha=0.3)
    ax_n.legend(loc='upper right', fontsize='small')
    return fig


def write_fibre_types_figure(out_dir: str | Path, rate_hz: float = RATE_HZ) -> Path:
    """Write ``fes_fibre_types.png``; return its path."""
    return save_figure(plot_fibre_types(fibre_data(rate_hz)), out_dir, FES_FIGURE_FILES[3])


#: The two scalings of the force-velocity constants compared.
FV_SCALINGS = ('absolute', 'relative')
#: [s] A train at full recruitment (500 us on the linear curve) from FV_T_ON_S
#: to FV_T_OFF_S; as it ends, the MTU is stretched by 10 mm at the paper's
#: 10 mm/s (FV_STRETCH_KNOTS, [s] and [m]).
FV_T_ON_S = 0.1
FV_T_OFF_S = 1.0
FV_DURATION_S = 2.5
FV_PW_S = 500e-6
FV_STRETCH_KNOTS = [[0.0, 0.0], [1.0, 0.0], [2.0, 0.010]]
#: [s] Activation and the slow deactivation under which the two scalings differ.
FV_FES = {'tau_act_s': 0.060, 'tau_deact_s': 0.110}


def fv_protocol() -> Protocol:
    """A stimulation train that ends as the MTU is stretched."""
    return _protocol('train that ends during a stretch', FV_DURATION_S, 'pulse_width_s',
                     _train(FV_T_ON_S, FV_T_OFF_S, FV_PW_S), FV_STRETCH_KNOTS)


def fv_release_s(params: MuscleParams) -> float:
    """[s] instant the last unit leaves after the train: closed form of the activation.

    a rises towards u = 1 from FV_T_ON_S, a_off = 1 - exp(-(t_off - t_on) /
    tau_act), then decays as a_off exp(-(t - t_off) / tau_deact); the last unit
    goes when N a + 0.5 falls below 1, i.e. a = 0.5 / N.
    """
    a_off = 1.0 - math.exp(-(FV_T_OFF_S - FV_T_ON_S) / params.tau_act_s)
    return FV_T_OFF_S + params.tau_deact_s * math.log(2.0 * params.n_units * a_off)


@dataclass(frozen=True)
class FvData:
    """The train that ends, with each force-velocity scaling.

    :param protocol: the protocol
    :param release_s: [s] instant the last unit leaves (the same for both)
    :param results: scaling -> simulation
    """

    protocol: Protocol
    release_s: float
    results: dict[str, SimulationResult]


def fv_params(scaling: str) -> MuscleParams:
    """The paper's muscle with activation dynamics and ``fv_scaling`` = ``scaling``."""
    return MuscleParams(fv_scaling=scaling, **FV_FES)


def fv_data(rate_hz: float = RATE_HZ) -> FvData:
    """Simulate the train that ends with ``absolute`` and ``relative`` scaling."""
    protocol = fv_protocol()
    results = {s: simulate(protocol, fv_params(s), rate_hz) for s in FV_SCALINGS}
    return FvData(protocol, fv_release_s(fv_params('absolute')), results)


def plot_fv_scaling(data: FvData) -> Figure:
    """CE force of both scalings, F0 on a log scale, and the inputs."""
    fig = Figure(figsize=FES_FIGSIZE_IN, dpi=DPI, layout='constrained')
    ax_f, ax_0, ax_in = fig.subplots(3, 1, sharex=True,
                                     gridspec_kw={'height_ratios': (3, 2, 1.3)})
    styles = {'absolute': ('tab:red', '-', 2.5), 'relative': ('tab:blue', '--', 1.8)}
    labels = {'absolute': "absolute: a, a' in newtons (the paper)",
              'relative': "relative: a, a' scaled by F0 / f_iso_max"}
    for scaling in FV_SCALINGS:
        r = data.results[scaling]
        color, style, width = styles[scaling]
        ax_f.plot(r.t_s, r.f_se_n, color=color, linestyle=style, linewidth=width,
                  label=labels[scaling])
        ax_0.semilogy(r.t_s, np.where(r.eff_f_iso_n > 0.0, r.eff_f_iso_n, np.nan),
                      color=color, linestyle=style, linewidth=width, label=labels[scaling])
    for ax in (ax_f, ax_0):
        ax.axvline(data.release_s, color='grey', linestyle=':', linewidth=1.0)
        ax.grid(True, alpha=0.3)
    ax_f.text(data.release_s, 1.0, ' last unit leaves', color='grey', fontsize='small')
    ax_f.set_ylabel('CE (tendon) force f_SE [N]')
    ax_f.set_ylim(bottom=0.0)
    ax_f.set_title('A train that ends during a stretch, deactivation '
                   f'{FV_FES["tau_deact_s"] * 1e3:.0f} ms: force-velocity scaling')
    ax_f.legend(loc='upper left', fontsize='small')
    ax_0.set_ylabel('F0 = Eff.f_iso [N]')
    ax_0.legend(loc='lower left', fontsize='small')
    r = data.results['absolute']
    ax_in.plot(r.t_s, r.recruitment, color='black', linewidth=1.5, label='activation a = R')
    ax_dl = ax_in.twinx()
    ax_dl.plot(r.t_s, r.dl_mt_m * MM_PER_M, color='tab:purple', linestyle='--', linewidth=1.5)
    ax_dl.set_ylabel(f'{DL_LABEL} [mm]', color='tab:purple')
    ax_dl.tick_params(axis='y', colors='tab:purple')
    ax_in.set_ylabel('R [-]')
    ax_in.set_xlabel('time [s]')
    ax_in.set_xlim(0.0, data.protocol.duration_s)
    ax_in.grid(True, alpha=0.3)
    return fig


def write_fv_scaling_figure(out_dir: str | Path, rate_hz: float = RATE_HZ) -> Path:
    """Write ``fes_fv_scaling.png``; return its path."""
    return save_figure(plot_fv_scaling(fv_data(rate_hz)), out_dir, FES_FIGURE_FILES[4])


def write_fes_figures(out_dir: str | Path, rate_hz: float = RATE_HZ) -> list[Path]:
    """Write the five FES figures into ``out_dir`` (created if missing).

    :param rate_hz: [Hz] step rate of the simulations
    :return: the paths written, in the order of :data:`FES_FIGURE_FILES`
    """
    return [write_recruitment_curves_figure(out_dir),
            write_activation_figure(out_dir, rate_hz),
            write_fatigue_figure(out_dir, rate_hz),
            write_fibre_types_figure(out_dir, rate_hz),
            write_fv_scaling_figure(out_dir, rate_hz)]
