"""The muscle: one class over the one engine's state.

:class:`Muscle` is a thin facade. Its state is a one-muscle
:class:`~.state.FesBundle` (flat arrays), and every step, recruitment
and output is a function of :mod:`.kernels` over those arrays, built from
the equations of :mod:`.equations`. Which build runs (numba-compiled, or the
very same functions as plain Python) is chosen once, by
:func:`.engine.kernels`. The paper's model is this muscle with every FES
feature off (``params.fes_defaults``): no second implementation.

The single continuous state is the CE length ``l_ce``; its derivative is the
inverse force-velocity relation evaluated at the tendon force (doc/model.md
section 4). The integrator is the classical fourth-order Runge-Kutta method
(RK4) with the recruitment held and the MTU length following a linear ramp
within the step. At the default 1 ms step it stays within 0.01 N of a
``solve_ivp`` reference at rtol 1e-10 on both of the paper's protocols; forward
Euler would be off by about 0.3 N.
"""
from __future__ import annotations

import copy
import math
from typing import NamedTuple, Sequence

import numpy as np

from .. import engine
from ..params import PULSED_MODEL, MuscleParams
from ..channels import ChannelTrains, steps_end_s
from ..stimulator import ChannelCommand
from ..stimulus import command_from_pulse_width
from ..substeps import length_ramp, substeps_for
from . import kernels
from .state import (I_MULTI, J_NREC, J_RTOP, N_OUT, S_CMD, S_DL, S_L, S_R, S_T, TIME_TOL_S,
                    FesBundle, delay_capacity, fitness_profile)

#: Largest |dl_mt| accepted as an input: far beyond the range where FL is
#: non-zero (l_ce / l_opt outside about 0.4..1.6), so anything larger is
#: a unit error (mm for m) rather than an experiment.
DL_MT_LIMIT_M = 1.0

_INF = math.inf
#: Index of ``n_recruited`` in :class:`MuscleOutputs` (an int there, a float in the kernels').
_N_RECRUITED = 2


class MuscleOutputs(NamedTuple):
    """The muscle's outputs at one instant (all SI).

    :param t_s: [s] simulated time
    :param recruitment: [-] recruitment R in force at this instant
    :param n_recruited: [-] recruited units M (``single``: 1 if R > 0 else 0)
    :param dl_mt_m: [m] MTU length change from rest (dl_MT)
    :param l_ce_m: [m] CE length (l_CE)
    :param v_ce_m_per_s: [m/s] CE velocity (v_CE), negative when shortening
    :param f_se_n: [N] series elastic force (f_SE), equal to the CE force
    :param f_pe_n: [N] parallel elastic force (f_PE)
    :param force_n: [N] muscle force f_SE + f_PE
    :param eff_f_iso_n: [N] effective isometric force (Eff.f_iso, F0)
    :param command: [-] recruitment command u given last (before the delay and
        the activation; equal to R in the paper's model)
    :param mean_fitness: [-] mean fitness of all units (1 without fatigue)
    """

    t_s: float
    recruitment: float
    n_recruited: int
    dl_mt_m: float
    l_ce_m: float
    v_ce_m_per_s: float
    f_se_n: float
    f_pe_n: float
    force_n: float
    eff_f_iso_n: float
    command: float
    mean_fitness: float


def check_recruitment(recruitment: float, name: str = 'recruitment') -> float:
    """Validate a recruitment value; raise ``ValueError`` naming it otherwise.

    :param recruitment: [-] recruitment R
    :param name: what to call the value in the error message
    :return: [-] R as a float, in [0, 1]
    """
    r = float(recruitment)
    if not 0.0 <= r <= 1.0:  # also false for NaN
        raise ValueError(f'`{name}` must be in [0, 1], got {recruitment!r}')
    return r


def recruitment_from_pulse_width(pulse_width_s: float, pw_max_s: float,
                                 name: str = 'pulse_width_s') -> float:
    """Recruitment of an FES pulse: R = clip(PW / PW_max, 0, 1).

    Saturation above PW_max is the stimulator's physics, not a correction:
    every unit is already recruited. Negative or non-finite widths raise.

    :param pulse_width_s: [s] stimulation pulse width (PW)
    :param pw_max_s: [s] pulse width that recruits every unit (PW_max)
    :param name: what to call the value in the error message (e.g. the topic)
    :return: [-] recruitment R in [0, 1]
    """
    pw = float(pulse_width_s)
    if not (math.isfinite(pw) and pw >= 0.0):
        raise ValueError(f'`{name}` must be finite and non-negative, '
                         f'got {pulse_width_s!r}')
    return min(pw / pw_max_s, 1.0)


def check_dl_mt(dl_mt_m: float, name: str = 'dl_mt_m') -> float:
    """Validate an MTU length change; raise ``ValueError`` naming it otherwise.

    :param dl_mt_m: [m] MTU length change from rest (dl_MT)
    :param name: what to call the value in the error message
    :return: [m] dl_MT as a float
    """
    dl = float(dl_mt_m)
    if not -DL_MT_LIMIT_M <= dl <= DL_MT_LIMIT_M:  # also false for NaN
        raise ValueError(f'`{name}` must be finite and within ±{DL_MT_LIMIT_M} m '
                         f'of rest, got {dl_mt_m!r}')
    return dl


class Muscle:
    """One Hill-type muscle-tendon unit with the motor-unit memory, and any FES
    feature its parameters switch on (delay, activation, fatigue, fibre types).

    Use :meth:`step` to advance by ``dt`` and read the returned
    :class:`MuscleOutputs`; :meth:`reset` returns to the resting state. The
    stimulation input of :meth:`step` and :meth:`run` is the recruitment
    *command* u (after the recruitment curve, before the delay and the
    activation); ``recruitment`` is the activation a = R in force. With the
    paper's model (no delay, instantaneous activation) the two are equal.

    The first muscle built in a process on the compiled engine loads the
    compiled kernels: about 1 s from numba's disk cache, about 25 s when they
    compile (a clean clone, or after an edit of the model's code).

    :param params: the muscle's parameters (paper defaults if omitted)
    :param build: :data:`.engine.COMPILED` or :data:`.engine.PYTHON`, or None
        (the default) for what ``HILL_MUSCLE_ENGINE`` chooses (:func:`.engine.kernels`)
    :raises ImportError: if the compiled build is asked for and numba is missing
    """

    def __init__(self, params: MuscleParams | None = None, build: str | None = None) -> None:
        self.params = params if params is not None else MuscleParams()
        self._kernels = engine.kernels(kernels, build)
        self._bundle = FesBundle([self.params])
        self._r = np.zeros(1)
        self._dl = np.zeros(1)
        self._out = np.zeros((1, N_OUT))
        self._row = np.zeros(N_OUT)
        self._views()
        self._pulsed = self.params.activation_model == PULSED_MODEL
        # The channels' commands, trains and pending pulses (ding2003 only).
        self._channels = ChannelTrains(self.params) if self._pulsed else None
        self._no_pulse = (np.empty(0), np.empty(0, dtype=np.int64), np.empty(0))

    def _views(self) -> None:
        """Views of the state (taken anew whenever the bundle's arrays move)."""
        self._fs = self._bundle.view(0, 'fs')
        self._js = self._bundle.view(0, 'js')
        self._multi = bool(self._bundle.view(0, 'ip')[I_MULTI])

    def __deepcopy__(self, memo: dict) -> 'Muscle':
        """A muscle in the same state with state of its own, stepping on the same
        build of the kernels: it goes on exactly as this one would, and neither
        moves the other (the fit's edge search replays each move of a
        stimulation change from a copy saved before it).

        Copied: the bundle's ``F`` and ``I`` (time, CE and MTU lengths, command,
        delay line, activation, unit memory and fatigue, channel slots), a
        ``ding2003`` muscle's trains and pending pulses, and the step's scratch.
        Shared: the parameters (frozen) and the kernels (functions, or numba's
        dispatchers: a module cannot be copied, which is why this method exists).
        """
        # Seeded in the memo so that the bundle and the channels keep the very
        # same parameters object rather than copies of it.
        memo[id(self.params)] = self.params
        twin = copy.copy(self)
        twin._bundle = copy.deepcopy(self._bundle, memo)
        for name in ('_r', '_dl', '_out', '_row'):
            setattr(twin, name, getattr(self, name).copy())
        twin._channels = copy.deepcopy(self._channels, memo)
        twin._views()
        return twin

    # -- state -----------------------------------------------------------------

    def reset(self) -> None:
        """Return to rest: no command, a = 0, every unit fresh and unrecruited,
        the motor-unit memory erased; a ding2003 muscle's trains stopped."""
        self._bundle.reset(0)
        if self._channels is not None:
            self._channels.reset()

    @property
    def build(self) -> str:
        """:data:`.engine.COMPILED` or :data:`.engine.PYTHON`: the build this muscle runs."""
        return engine.PYTHON if self._kernels is kernels else engine.COMPILED

    @property
    def t_s(self) -> float:
        """[s] simulated time."""
        return float(self._fs[S_T])

    @property
    def l_ce_m(self) -> float:
        """[m] CE length (l_CE)."""
        return float(self._fs[S_L])

    @property
    def dl_mt_m(self) -> float:
        """[m] MTU length change from rest (dl_MT)."""
        return float(self._fs[S_DL])

    @property
    def recruitment(self) -> float:
        """[-] recruitment R = a in force now."""
        return float(self._fs[S_R])

    @property
    def command(self) -> float:
        """[-] the recruitment command u given last."""
        return float(self._fs[S_CMD])

    @property
    def n_recruited(self) -> int:
        """[-] recruited units M (``single``: 1 if R > 0 else 0)."""
        return int(self._js[J_NREC])

    @property
    def n_runs(self) -> int:
        """Groups of units recruited at one instant that the memory holds (multi;
        0 for single): one per distinct recruitment instant still in force."""
        return int(self._js[J_RTOP]) if self._multi else 0

    @property
    def mean_fitness(self) -> float:
        """[-] mean fitness of all units now (1 without fatigue)."""
        return self.outputs().mean_fitness

    def fitness_profile(self) -> np.ndarray:
        """[-] fitness of every unit along the recruitment order now (multi), O(N).

        :raises ValueError: for a ``single`` muscle
        """
        return fitness_profile(self._bundle, 0)

    def set_recruitment(self, recruitment: float) -> None:
        """Give the recruitment command u now (R directly, bypassing the curve).

        It takes effect after ``emd_s``, through the activation; with no delay
        and instantaneous activation (the paper's model), now: new units store
        the CE length of this instant, and a release to zero frees the CE.
        Idempotent: giving the same command again changes nothing.

        :param recruitment: [-] command u in [0, 1]
        :raises ValueError: if u is outside [0, 1] or not finite
        """
        self.give_command(check_recruitment(recruitment))

    def set_pulse_width(self, pulse_width_s: float) -> None:
        """Give an FES pulse width now, through the recruitment curve
        (:func:`~hill_muscle_ros.model.stimulus.command_from_pulse_width`).

        With ``activation_model: ding2003`` the pulse width is channel 1's, sent
        in single pulses at ``frequency_hz`` (:meth:`stimulate`).

        :param pulse_width_s: [s] stimulation pulse width (PW), >= 0
        """
        if self._pulsed:
            self.stimulate([ChannelCommand(1, 'single', float(pulse_width_s), None,
                                           self.params.frequency_hz)])
            return
        self.give_command(command_from_pulse_width(pulse_width_s, self.params))

    # -- pulses (activation_model ding2003) -----------------------------------

    @property
    def n_channels(self) -> int:
        """[-] stimulation channels C."""
        return self.params.n_channels

    @property
    def activation(self) -> np.ndarray:
        """[-] each channel's activation a_c now (C,): Ding's force over its limit
        A (tau1 + tau2) for ding2003; the recruitment R for first_order."""
        if not self._pulsed:
            return np.array([self.recruitment])
        out = np.zeros(self.n_channels)
        self._kernels.ding_activation(self._bundle.F, self._bundle.I, 0, out)
        return out

    def _need_pulses(self, what: str) -> None:
        if not self._pulsed:
            raise ValueError(f'`{what}` needs `activation_model: ding2003`, got '
                             f'{self.params.activation_model!r}')

    def stimulate(self, commands) -> None:
        """Command channels from now: each channel named gets a new train (its
        schedule carries over: a running train's next burst stays 1/f after the
        last), the others keep theirs. Every command is checked against the
        ``stimulator`` first; nothing changes if one fails.

        :param commands: :class:`~hill_muscle_ros.model.stimulator.ChannelCommand` s
        :raises ValueError: naming the field, channel and value, for a channel
            beyond the muscle's or a command out of the stimulator's range
        """
        self._need_pulses('stimulate')
        self._channels.stimulate(commands, self.t_s)

    def run_pulses(self, times_s, channels, commands, dl_mt_end_m, dt_s: float) -> tuple:
        """Advance ``len(dl_mt_end_m)`` steps of ``dt_s`` with the pulses given
        (acting at their instants; those at or after the last step's end are
        not used): the core of :meth:`step_trains` and of :func:`.simulate`.

        :param times_s: [s] when each pulse acts, not decreasing
        :param channels: 0-based channel of each pulse
        :param commands: [-] the fraction u of its channel's territory each recruits
        :param dl_mt_end_m: [m] MTU length change at the end of each step
        :param dt_s: [s] step length, > 0, at most 1 ms
        :return: ``(outputs, activation, used)``: (steps, 12) outputs as
            :meth:`run_array`'s, (steps, C) each channel's a, the pulses used
        """
        self._need_pulses('run_pulses')
        t = np.require(times_s, dtype=float, requirements=('C', 'W'))
        c = np.require(channels, dtype=np.int64, requirements=('C', 'W'))
        u = np.require(commands, dtype=float, requirements=('C', 'W'))
        dl = np.require(dl_mt_end_m, dtype=float, requirements=('C', 'W'))
        out = np.empty((len(dl), N_OUT))
        act = np.empty((len(dl), self.n_channels))
        bundle = self._bundle
        used = self._kernels.ding_run(bundle.F, bundle.I, 0, t, c, u, dl, float(dt_s), out, act)
        return out, act, int(used)

    def pulses_now(self, times_s, channels, commands) -> int:
        """Apply the leading pulses that act now (within TIME_TOL_S of :attr:`t_s`),
        so that the outputs of this instant show them, as a sample shows the
        command of its instant.

        :return: how many of the pulses (in time order) were applied
        """
        self._need_pulses('pulses_now')
        bundle, k = self._bundle, self._kernels
        used = 0
        while used < len(times_s) and times_s[used] <= self.t_s + TIME_TOL_S:
            k.ding_pulse(bundle.F, bundle.I, 0, int(channels[used]), float(commands[used]),
                         self.t_s)
            used += 1
        if used:
            k.free_if_idle(bundle.F, bundle.I, 0, self.t_s, self.dl_mt_m)
        return used

    def run_trains(self, dl_mt_end_m, dt_s: float) -> tuple:
        """Advance ``len(dl_mt_end_m)`` steps driven by the channels' trains
        (:meth:`stimulate`), each pulse at its own instant.

        :return: ``(outputs, activation)`` as :meth:`run_pulses`'
        """
        self._need_pulses('run_trains')
        dl = np.asarray(dl_mt_end_m, dtype=float)
        due = self._channels.due(steps_end_s(self.t_s, float(dt_s), len(dl)))
        if due:
            out, act, _ = self.run_pulses([p[0] for p in due], [p[1] for p in due],
                                          [p[2] for p in due], dl, dt_s)
        else:
            out, act, _ = self.run_pulses(*self._no_pulse, dl, dt_s)
        return out, act

    def step_trains(self, dl_mt_m: float, dt_s: float) -> MuscleOutputs:
        """One step of ``dt_s`` driven by the channels' trains, dl_MT ramping to
        ``dl_mt_m``; a step longer than 1 ms in substeps.

        :raises ValueError: on a NaN, infinite or out-of-range input
        """
        dl = check_dl_mt(dl_mt_m)
        if not (math.isfinite(dt_s) and dt_s > 0.0):
            raise ValueError(f'`dt_s` must be positive and finite, got {dt_s!r}')
        n = substeps_for(dt_s)
        out, _ = self.run_trains(length_ramp(self.dl_mt_m, dl, n) if n > 1 else [dl],
                                 dt_s / n)
        return _as_outputs(out[-1])

    def give_command(self, u: float) -> None:
        """Queue command ``u`` at the current instant and apply what is due now.

        :param u: [-] recruitment command in [0, 1], already validated
        """
        if self._pulsed:
            raise ValueError('a ding2003 muscle is driven by pulses: `stimulate` its channels, '
                             'it takes no recruitment command')
        bundle = self._bundle
        if not self._kernels.give_command(bundle.F, bundle.I, 0, float(u)):
            raise RuntimeError(f'the delay line of the muscle is full '
                               f'(emd_s {self.params.emd_s!r})')

    def eff_f_iso(self, l_ce_m: float | None = None, t_s: float | None = None) -> float:
        """[N] Eff.f_iso at CE length ``l_ce_m`` and instant ``t_s`` (default: now).

        Implements Eq. (2) of the paper (multi/initial) and its siblings of
        doc/model.md section 2, with each unit's fitness and length scale.

        :param l_ce_m: [m] CE length (l_CE), the current one if omitted
        :param t_s: [s] instant within the current piece, now if omitted
        """
        bundle = self._bundle
        l = self.l_ce_m if l_ce_m is None else float(l_ce_m)
        t = self.t_s if t_s is None else float(t_s)
        return float(self._kernels.eff_f_iso(bundle.F, bundle.I, 0, l, t))

    def outputs(self) -> MuscleOutputs:
        """The outputs at the current instant, derived from the state."""
        bundle = self._bundle
        self._kernels.muscle_outputs(bundle.F, bundle.I, 0, self._row)
        return _as_outputs(self._row)

    # -- dynamics ------------------------------------------------------------

    def _ready(self, dt_s: float) -> None:
        """Size the delay line for steps of ``dt_s`` (keeps the state)."""
        if delay_capacity(self.params.emd_s, dt_s) > self._bundle.cap:
            self._bundle.ensure_delay(dt_s)
            self._views()

    def _call_run(self, r_start: np.ndarray, dl_end: np.ndarray, dt_s: float,
                  r_end: np.ndarray, have_r_end: bool, out: np.ndarray) -> None:
        if self._pulsed:
            raise ValueError('a ding2003 muscle is driven by pulses: `stimulate` its channels '
                             'and call `run_trains`, not a run of recruitment commands')
        self._ready(dt_s)
        bundle = self._bundle
        done = self._kernels.muscle_run(bundle.F, bundle.I, 0, r_start, dl_end, dt_s, r_end,
                                        have_r_end, out)
        if done != len(dl_end):   # delay_capacity bounds the commands pending
            raise RuntimeError(f'the delay line of the muscle overflowed at step {done} '
                               f'(emd_s {self.params.emd_s!r}, dt_s {dt_s!r})')

    def run_array(self, r_start, dl_mt_end_m, dt_s: float, r_end=None) -> np.ndarray:
        """Advance ``len(dl_mt_end_m)`` steps, each integrated whole; return the
        outputs after each step as rows of an array (:class:`MuscleOutputs`' order).

        Step k gives the command ``r_start[k]`` at its start, integrates with
        the MTU length ramping linearly to ``dl_mt_end_m[k]``, then gives
        ``r_end[k]`` (default: none) before its outputs: :func:`.simulate`
        passes ``r_end[k] = r_start[k + 1]`` so each sample shows the
        recruitment of its instant. Inputs are not validated (:meth:`step`
        validates, :func:`.simulate` checks whole arrays).

        :param r_start: [-] command u in [0, 1] given at the start of each step
        :param dl_mt_end_m: [m] MTU length change at the end of each step
        :param dt_s: [s] step length, > 0: the integrator's own step (at most
            :data:`~.substeps.MAX_SUBSTEP_S` for RK4's accuracy)
        :param r_end: [-] command given after each step, before the outputs
        :return: (steps, 12) outputs
        """
        r_start, dl_end, r_end, have_end = kernels.run_inputs(r_start, dl_mt_end_m, r_end)
        out = np.empty((len(dl_end), N_OUT))
        self._call_run(r_start, dl_end, float(dt_s), r_end, have_end, out)
        return out

    def run(self, r_start: Sequence[float], dl_mt_end_m: Sequence[float], dt_s: float,
            r_end: Sequence[float] | None = None,
            columns: Sequence[list] | None = None) -> MuscleOutputs:
        """:meth:`run_array`, returning the outputs after the last step.

        :param columns: if given, twelve preallocated lists in the order of
            :class:`MuscleOutputs`; step k writes index k of each
        :return: the outputs after the last step (now, for no step)
        """
        if len(dl_mt_end_m) == 0:
            return self.outputs()
        out = self.run_array(r_start, dl_mt_end_m, dt_s, r_end)
        if columns is not None:
            for j, column in enumerate(columns):
                column[:len(out)] = out[:, j].tolist()
        return _as_outputs(out[-1])

    def advance(self, dl_mt_end_m: float, dt_s: float) -> None:
        """Integrate over one step with the command held, the MTU length ramping
        linearly to ``dl_mt_end_m``; a step longer than 1 ms in substeps, as
        :meth:`step`'s.

        :param dl_mt_end_m: [m] MTU length change at the end of the step
        :param dt_s: [s] step length, > 0
        """
        self._substeps(self.command, float(dl_mt_end_m), float(dt_s))

    def step(self, recruitment: float, dl_mt_m: float, dt_s: float) -> MuscleOutputs:
        """Advance one step: give the command now, then integrate with it held.

        The memory changes only at the instants the recruitment changes, from
        the CE length of that instant (doc/model.md sections 4 and 7). A step
        longer than :data:`~.substeps.MAX_SUBSTEP_S` (1 ms) is integrated in
        n = ceil(dt / 1 ms) equal substeps, the command held and dl_MT ramping
        linearly across them (:mod:`.substeps`): ``dt_s`` is how often the
        caller samples, not the integrator's step.

        :param recruitment: [-] recruitment command u in [0, 1], held over the step
        :param dl_mt_m: [m] MTU length change at the end of the step (dl_MT)
        :param dt_s: [s] step length, > 0
        :return: the outputs at the end of the step
        :raises ValueError: on a NaN, infinite or out-of-range input; the state
            is unchanged
        """
        if self._pulsed:
            raise ValueError('a ding2003 muscle is driven by pulses: `stimulate` its channels '
                             'and call `step_trains`, not `step` with a recruitment')
        r, dl = float(recruitment), float(dl_mt_m)
        # One combined check (false for NaN too) keeps the node's tick cheap;
        # the helpers run only to raise the error that names the culprit.
        if not (0.0 <= r <= 1.0 and -DL_MT_LIMIT_M <= dl <= DL_MT_LIMIT_M
                and 0.0 < dt_s < _INF):
            check_dl_mt(dl_mt_m)
            if not (math.isfinite(dt_s) and dt_s > 0.0):
                raise ValueError(f'`dt_s` must be positive and finite, got {dt_s!r}')
            check_recruitment(recruitment)
        return self._substeps(r, dl, float(dt_s))

    def _substeps(self, u: float, dl_mt_end_m: float, dt_s: float) -> MuscleOutputs:
        """One output step of ``dt_s`` as n = ceil(dt / 1 ms) substeps
        (:mod:`.substeps`), the command held and dl_MT ramping linearly."""
        n = substeps_for(dt_s)
        if n == 1:   # the node's 1 kHz tick: no arrays to build
            r, dls, out = self._r, self._dl, self._out
            r[0] = u
            dls[0] = dl_mt_end_m
        else:
            r = np.full(n, u)
            dls = np.array(length_ramp(self.dl_mt_m, dl_mt_end_m, n))
            out = np.empty((n, N_OUT))
        self._call_run(r, dls, dt_s / n, r, False, out)
        return _as_outputs(out[-1])


def _as_outputs(row: np.ndarray) -> MuscleOutputs:
    """A kernel output row as :class:`MuscleOutputs` (Python floats, the count an int)."""
    values = row.tolist()
    values[_N_RECRUITED] = int(values[_N_RECRUITED])
    return MuscleOutputs(*values)
