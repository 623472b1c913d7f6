"""The limb stepped one call at a time: :class:`Limb`, a thin facade over the kernels.

A :class:`Limb` holds a limb's flat state (:class:`~.arrays.LimbArrays`) and
steps it with the kernels of :mod:`.kernels`; which build of them runs, the
numba-compiled one or the very same functions as plain Python, is
:func:`~hill_muscle_ros.model.engine.kernels`' choice (``HILL_MUSCLE_ENGINE``,
unless the limb is asked for a build).
Its outputs are read off the state: nothing of the dynamics is written here.

The external torque and the stimulation are held over each step (zero-order
hold), as the simulator node holds its inputs. A step longer than 1 ms is
integrated in n = ceil(dt / 1 ms) equal substeps (:mod:`~hill_muscle_ros.model.substeps`).
"""
from __future__ import annotations

import copy
from typing import Sequence

import numpy as np

from .. import engine as engines
from ..channels import ChannelTrains, steps_end_s
from ..params import PULSED_MODEL
from ..stimulator import ChannelCommand
from ..substeps import MAX_SUBSTEP_S, substeps_for
from . import kernels
from .arrays import ROW_JOINT, LimbArrays, no_pulses, pulse_arrays, row_length
from .kernels import L_OMEGA, L_T, L_TAU, L_THETA, MODE_GIVE, MODE_HOLD, MODE_RECORD, OK
from .plant import MUSCLE_COLUMNS, LimbOutputs, LimbPlant, check_step_inputs

#: [s] The step the delay lines of a :class:`Limb` are first sized for (the
#: 1 kHz of the presets); a shorter step resizes them, keeping the state.
FIRST_DT_S = 1e-3


def check_hold_step(dt_s: float) -> float:
    """[s] the step of :meth:`Limb.hold`: one substep, so that each squared error
    is taken at a step's end.

    :raises ValueError: unless 0 < ``dt_s`` <=
        :data:`~hill_muscle_ros.model.substeps.MAX_SUBSTEP_S`
    """
    dt = float(dt_s)
    if not 0.0 < dt <= MAX_SUBSTEP_S:   # also false for NaN
        raise ValueError(f'`dt_s` must be in (0, {MAX_SUBSTEP_S:g}] s, got {dt_s!r}')
    return dt


class Limb:
    """The joint and its muscles, integrated together (doc/model.md section 9).

    The state is (theta, omega, l_CE of every muscle) with every muscle's
    recruitment memory, delay line, activation and fatigue, in flat arrays
    that :mod:`.kernels` steps. The first limb built in a process on the
    compiled engine loads the compiled kernels: about 0.8 s from numba's disk
    cache, about 30 s when they compile (a clean clone, or after an edit of
    the model's code).

    :param plant: the joint and its muscles
    :param row: where the outputs are written (:func:`~.arrays.row_length`
        entries: t, theta, omega, then per muscle command, recruitment, dl_MT,
        l_CE, force, then each ``ding2003`` muscle's channels' activations),
        e.g. a row of a batch's array; default an array of its own

    A muscle with ``activation_model: ding2003`` is driven by pulse trains per
    channel (:meth:`stimulate`), each pulse acting at its own instant inside
    the steps; its entry of a step's ``commands`` is not used.
    :param build: :data:`~hill_muscle_ros.model.engine.COMPILED` or
        :data:`~hill_muscle_ros.model.engine.PYTHON`, or None (the default) for
        what ``HILL_MUSCLE_ENGINE`` chooses; :attr:`build` says which runs
    :raises ValueError: if ``row`` is not a float64 array of that length, or
        ``build`` (or ``HILL_MUSCLE_ENGINE``) is unknown
    :raises ImportError: if the compiled build is asked for and numba cannot be imported
    """

    def __init__(self, plant: LimbPlant, row: np.ndarray | None = None,
                 build: str | None = None) -> None:
        self.plant = plant
        self.joint = plant.joint
        self._kernels = engines.kernels(kernels, build)
        self.arrays = LimbArrays(plant, FIRST_DT_S)
        self._dt = FIRST_DT_S
        nm = len(plant.muscles)
        width = row_length(nm, self.arrays.n_activations)
        if row is None:
            row = np.zeros(width)
        elif not (isinstance(row, np.ndarray) and row.shape == (width,)
                  and row.dtype == np.float64 and row.flags.c_contiguous):
            raise ValueError(f'`row` must be a contiguous float64 array of '
                             f'{width} entries, got {row!r}')
        #: The outputs of the last step, reset or command (see ``row`` above).
        self.row = row
        self._us = np.zeros(nm)
        self._tau = np.zeros(1)
        self._acc = np.zeros(1)
        self._s_r = [m.sign * m.moment_arm_m for m in plant.muscles]
        self._pulsed = [m.params.activation_model == PULSED_MODEL for m in plant.muscles]
        # Each pulsed muscle's channels: commands, trains and pending pulses.
        self._channels = [ChannelTrains(m.params) if p else None
                          for m, p in zip(plant.muscles, self._pulsed)]
        # Where each pulsed muscle's activations start in the row.
        self._act_at = []
        at = row_length(nm)
        for m, p in zip(plant.muscles, self._pulsed):
            self._act_at.append(at if p else None)
            at += m.params.n_channels if p else 0
        self._views()
        self.reset()

    def _views(self) -> None:
        """limb_entry's 2-D views of the row and the commands."""
        self._rows = self.row[np.newaxis, :]
        self._u = self._us[np.newaxis, :]

    def __deepcopy__(self, memo: dict) -> 'Limb':
        """A limb in the same state with arrays of its own (outputs in a row of its
        own), stepping on the same build of the kernels."""
        twin = copy.copy(self)
        twin.arrays = copy.deepcopy(self.arrays, memo)
        for name in ('row', '_us', '_tau', '_acc'):
            setattr(twin, name, getattr(self, name).copy())
        twin._channels = copy.deepcopy(self._channels, memo)
        twin._views()
        return twin

    @property
    def build(self) -> str:
        """:data:`~hill_muscle_ros.model.engine.COMPILED` or
        :data:`~hill_muscle_ros.model.engine.PYTHON`: the build this limb runs."""
        return engines.PYTHON if self._kernels is kernels else engines.COMPILED

    def reset(self) -> None:
        """theta = theta_0, omega = 0, each CE at l_rest + dl_MT(theta_0), nothing
        recruited, no command given, t = 0; the pulsed muscles' trains stopped."""
        self.arrays.reset()
        for channels in self._channels:
            if channels is not None:
                channels.reset()
        self.arrays.pulses = no_pulses()
        self._entry(MODE_RECORD, 0.0, 0, 0.0)

    @property
    def t_s(self) -> float:
        """[s] simulated time (t)."""
        return float(self.arrays.L[L_T])

    @property
    def theta_rad(self) -> float:
        """[rad] joint angle (theta)."""
        return float(self.arrays.L[L_THETA])

    @property
    def omega_rad_per_s(self) -> float:
        """[rad/s] joint angular velocity (omega)."""
        return float(self.arrays.L[L_OMEGA])

    @property
    def external_torque_n_m(self) -> float:
        """[N m] the external torque held over the last step (tau_ext)."""
        return float(self.arrays.L[L_TAU])

    def _entry(self, mode: int, dt_s: float, n_steps: int, target_rad: float) -> None:
        """The kernels' entry on this limb: commands :attr:`_us`, torque :attr:`_tau`,
        outputs into :attr:`row`.

        :raises ValueError: on a muscle stretched out of range
        """
        status = self.arrays.entry(self._kernels, mode, self._u, self._tau, dt_s, n_steps,
                                   target_rad, self._acc, self._rows)
        if status != OK:
            raise self.arrays.error(status)

    def _size_for(self, dt_s: float) -> None:
        """Room in the delay lines for steps of ``dt_s`` [s]."""
        if dt_s != self._dt:
            self.arrays.ensure_delay(dt_s)
            self._dt = dt_s

    # -- pulses (activation_model ding2003) -----------------------------------

    def muscle_index(self, muscle: int | str) -> int:
        """The index of ``muscle`` (its index or its name) in the plant.

        :raises ValueError: for a muscle the plant lacks
        """
        names = [m.name for m in self.plant.muscles]
        if isinstance(muscle, str):
            if muscle not in names:
                raise ValueError(f'muscle {muscle!r} is not in the plant (muscles: '
                                 f'{", ".join(names)})')
            return names.index(muscle)
        if isinstance(muscle, bool) or not isinstance(muscle, (int, np.integer)) or not (
                0 <= muscle < len(names)):
            raise ValueError(f'`muscle` must be a name ({", ".join(names)}) or an index in '
                             f'[0, {len(names) - 1}], got {muscle!r}')
        return int(muscle)

    def stimulate(self, muscle: int | str, commands: Sequence[ChannelCommand]) -> None:
        """Command channels of a ``ding2003`` muscle from now, as
        :meth:`~hill_muscle_ros.model.muscle.Muscle.stimulate` does: each
        channel named gets a new train (a running train's schedule carries
        over), the others keep theirs; every command is checked against the
        muscle's ``stimulator`` first, and nothing changes if one fails. The
        pulses act at their own instants in the following steps (sent + ``emd_s``).

        :param muscle: the muscle's index or name
        :param commands: :class:`~hill_muscle_ros.model.stimulator.ChannelCommand` s
        :raises ValueError: naming the muscle, and the field, channel and value
            of a bad command (a channel beyond the muscle's, or out of the
            stimulator's range), or a muscle that is not ``ding2003``
        """
        i = self.muscle_index(muscle)
        m = self.plant.muscles[i]
        if not self._pulsed[i]:
            raise ValueError(f'muscle `{m.name}`: `stimulate` needs `activation_model: '
                             f'{PULSED_MODEL}`, got {m.params.activation_model!r}')
        try:
            self._channels[i].stimulate(commands, self.t_s)
        except ValueError as err:
            raise ValueError(f'muscle `{m.name}`: {err}') from None

    def activation(self, muscle: int | str) -> np.ndarray:
        """[-] each channel's activation a_c now (C,) of a ``ding2003`` muscle (its
        index or name): Ding's force over its limit A (tau1 + tau2).

        :raises ValueError: for a muscle that is not ``ding2003``
        """
        i = self.muscle_index(muscle)
        if not self._pulsed[i]:
            raise ValueError(f'muscle `{self.plant.muscles[i].name}` has no channels\' '
                             f'activation: it is not `activation_model: {PULSED_MODEL}`')
        at = self._act_at[i]
        return self.row[at:at + self.plant.muscles[i].params.n_channels].copy()

    def _pulses_until(self, t1_s: float) -> None:
        """The pulses that act before ``t1_s`` into the kernels' pulse arrays (those
        sent up to then first taken into the pending ones)."""
        if not any(self._pulsed):
            return
        due = [(t, i, c, u) for i, channels in enumerate(self._channels) if channels is not None
               for t, c, u in channels.due(t1_s)]
        due.sort(key=lambda p: p[0])
        self.arrays.pulses = pulse_arrays(due)

    def give_commands(self, us: Sequence[float]) -> None:
        """Give each muscle its command now where it differs from its last one, as a
        sample of :func:`~.simulate.simulate_limb` does (the outputs into :attr:`row`).

        :param us: [-] each muscle's recruitment command u, checked in [0, 1]
        """
        self._us[:] = us
        self._entry(MODE_GIVE, 0.0, 0, 0.0)

    def advance(self, us: Sequence[float], tau: float, dt_s: float) -> None:
        """:meth:`step` of checked inputs, the outputs into :attr:`row` only.

        :param us: [-] each muscle's recruitment command u, checked in [0, 1]
        :param tau: [N m] external torque tau_ext, checked
        :param dt_s: [s] step length, > 0
        :raises ValueError: on a muscle stretched out of range (the step taken)
        """
        n = substeps_for(dt_s)   # one at 1 kHz
        h = dt_s / n
        self._size_for(h)
        self._us[:] = us
        self._tau[0] = tau
        self._pulses_until(steps_end_s(self.t_s, h, n))
        self._entry(MODE_HOLD, h, n, 0.0)

    def hold(self, us: Sequence[float], tau: float, dt_s: float, n_steps: int,
             target_rad: float) -> float:
        """``n_steps`` steps of at most 1 ms with checked inputs held, in one call of
        the kernels; the outputs of the last in :attr:`row`.

        :param us: [-] each muscle's recruitment command u, checked in [0, 1]
        :param tau: [N m] external torque tau_ext, checked
        :param dt_s: [s] each step's length, in (0, 1 ms]
        :param n_steps: [-] steps, >= 1
        :param target_rad: [rad] angle theta* of the squared errors
        :return: [rad^2] sum over the steps of (theta - theta*)^2 at each step's end
        :raises ValueError: on a step longer than 1 ms (:func:`check_hold_step`;
            nothing changes), or a muscle stretched out of range (the limb is
            left after that step)
        """
        dt_s = check_hold_step(dt_s)
        self._size_for(dt_s)
        self._us[:] = us
        self._tau[0] = tau
        self._pulses_until(steps_end_s(self.t_s, dt_s, n_steps))
        self._entry(MODE_HOLD, dt_s, n_steps, target_rad)
        return float(self._acc[0])

    def step(self, commands: Sequence[float], external_torque_n_m: float,
             dt_s: float) -> LimbOutputs:
        """Advance one step: each muscle's command and the external torque held over it.

        A step longer than 1 ms is integrated in n = ceil(dt / 1 ms) equal
        substeps with the inputs held (:mod:`~hill_muscle_ros.model.substeps`):
        ``dt_s`` is how often the caller samples, not the integrator's step.

        :param commands: [-] recruitment command u of each muscle, in [0, 1]
        :param external_torque_n_m: [N m] external torque (tau_ext)
        :param dt_s: [s] step length, > 0
        :return: the outputs at the end of the step
        :raises ValueError: naming the input on a bad value (the state is
            unchanged), or the muscle stretched beyond
            ±:data:`~hill_muscle_ros.model.muscle.DL_MT_LIMIT_M` (the step taken)
        """
        us, tau = check_step_inputs(self.plant, commands, external_torque_n_m, dt_s)
        self.advance(us, tau, float(dt_s))
        return self.outputs()

    def outputs(self) -> LimbOutputs:
        """The outputs at the current instant (read off :attr:`row`)."""
        row = self.row[:row_length(len(self.plant.muscles))].tolist()
        width = len(MUSCLE_COLUMNS)
        per_muscle = [row[ROW_JOINT + j::width] for j in range(width)]
        torque = 0.0
        for s_r, f in zip(self._s_r, per_muscle[-1]):   # in order: sum_i s_i r_i F_i
            torque += s_r * f
        return LimbOutputs(*row[:ROW_JOINT], torque, *(tuple(c) for c in per_muscle))
