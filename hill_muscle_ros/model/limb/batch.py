"""Many limbs stepped at once: K plants of the same joint and muscles, each with
its own parameters and its own stimulation.

For parameter sweeps and controller tuning on a limb: K
:class:`~.plant.LimbPlant` s with the same muscles (the same names, in the
same order; e.g. one preset with a muscle's or the joint's parameters
changed) advance together by one step of the same length, each with its own
pulse width per muscle (or recruitment command) and its own external torque.
State and outputs are arrays: (K,) per limb, (K, M) per limb and muscle, M
muscles in the plants' order.

Each limb is a :class:`~.limb.Limb` writing its outputs into its row of the
batch's array: the kernels of :mod:`.kernels`, called, not copied, so limb k
of the batch does exactly what a ``Limb(plants[k])`` does (the tests check it
against separate runs and against :func:`~.simulate.simulate_limb` to 1e-9
rad and 1e-9 N), on the build :func:`~hill_muscle_ros.model.engine.kernels`
chooses.

Cost: one limb step per limb, plus the arrays' bookkeeping. Unlike
:class:`~hill_muscle_ros.model.muscle.batch.MuscleBatch`, there is no vectorised
path: every limb has its own instants within a step (each muscle's delayed
command switches and units recruited at their own instants, the number of RK4
sub-steps its tendon's stiffness asks for), and integrating all limbs over
the union of those instants would change each limb's result. The muscles of
the shipped presets have delay, activation and fatigue on, which even the
muscle batch steps one by one with the scalar engine.
"""
from __future__ import annotations

import math
from typing import NamedTuple, Sequence

import numpy as np

from .. import engine
from ..params import check_instances
from ..simulate import sample_times
from ..stimulus import command_from_pulse_width
from . import kernels
from .arrays import ROW_JOINT, SCRATCH, LimbArrays
from .limb import Limb, check_hold_step
from .plant import MUSCLE_COLUMNS, TORQUE_LIMIT_N_M, LimbPlant, LimbProtocol
from .simulate import run_rows, substep_rows

#: [-] entries of a muscle's outputs in a row, and the force's among them.
_PER_MUSCLE = len(MUSCLE_COLUMNS)
_FORCE = MUSCLE_COLUMNS.index('force_n')


class LimbOutOfRange(ValueError):
    """A limb of a batch driven beyond its muscles' length range.

    :param limb: the limb's index in the batch
    :param message: what the limb reported (the muscle, its stretch and the angle)
    """

    def __init__(self, limb: int, message: str) -> None:
        super().__init__(f'limb {limb}: {message}')
        self.limb = limb
        self.message = message

    def __reduce__(self):   # picklable with its two arguments (Dask sends it back)
        return (type(self), (self.limb, self.message))


class LimbBatchOutputs(NamedTuple):
    """K limbs at one instant, all SI; (K,) per limb, (K, M) per limb and muscle.

    Same fields and units as :class:`~hill_muscle_ros.model.limb.LimbOutputs`.

    :param t_s: [s] time (the same for every limb)
    :param theta_rad: [rad] joint angle (theta), (K,)
    :param omega_rad_per_s: [rad/s] joint angular velocity (omega), (K,)
    :param muscle_torque_n_m: [N m] net muscle torque sum s_i r_i F_i, (K,)
    :param command: [-] recruitment command u, (K, M)
    :param recruitment: [-] recruitment R (activation), (K, M)
    :param dl_mt_m: [m] MTU length change, (K, M)
    :param l_ce_m: [m] CE length, (K, M)
    :param force_n: [N] muscle force f_SE + f_PE, (K, M)
    """

    t_s: float
    theta_rad: np.ndarray
    omega_rad_per_s: np.ndarray
    muscle_torque_n_m: np.ndarray
    command: np.ndarray
    recruitment: np.ndarray
    dl_mt_m: np.ndarray
    l_ce_m: np.ndarray
    force_n: np.ndarray



def check_plants(plants: Sequence[LimbPlant]) -> tuple[list[LimbPlant], tuple[str, ...]]:
    """Plants of one batch: at least one, each a :class:`~.plant.LimbPlant`, all with
    the muscles of the first (the same names in the same order).

    :return: the plants as a list, and the muscles' names
    :raises ValueError: naming the plant that breaks a rule
    """
    plants = check_instances(LimbPlant, plants, 'plants')
    names = tuple(m.name for m in plants[0].muscles)
    for k, plant in enumerate(plants[1:], start=1):
        other = tuple(m.name for m in plant.muscles)
        if other != names:
            raise ValueError(f'`plants[{k}]` must have the muscles of `plants[0]`, '
                             f'{list(names)}, in that order; got {list(other)}')
    return plants, names


def check_commands(u: list[list[float]], names: Sequence[str]) -> list[list[float]]:
    """Commands per limb (one list of floats each), every u in [0, 1]. Checked in
    Python: for a few limbs a step's NumPy calls would cost more than the loop.

    :param names: the muscles' names, for the message
    :raises ValueError: naming the limb and the muscle of the first bad value
    """
    for k, row in enumerate(u):
        for i, value in enumerate(row):
            if not 0.0 <= value <= 1.0:   # also true for NaN
                raise ValueError(f'`commands[{k}, {i}]` ({names[i]}) must be in [0, 1], '
                                 f'got {value!r}')
    return u


def check_torque(value: float, name: str = 'external_torque_n_m') -> float:
    """[N m] an external torque within ±:data:`~.plant.TORQUE_LIMIT_N_M`.

    :raises ValueError: naming it on a value out of range or NaN
    """
    if not abs(value) <= TORQUE_LIMIT_N_M:   # also true for NaN
        raise ValueError(f'`{name}` must be finite and within ±{TORQUE_LIMIT_N_M:g} N m, '
                         f'got {value!r}')
    return value


class LimbBatch:
    """K limbs with the same muscles and their own parameters, stepped together.

    The first batch built in a process on the compiled engine loads the
    compiled kernels (about 0.8 s, about 30 s if they compile).

    :param plants: one :class:`~.plant.LimbPlant` per limb (K >= 1), all with the
        same muscle names in the same order
    :param build: :data:`~hill_muscle_ros.model.engine.COMPILED` or
        :data:`~hill_muscle_ros.model.engine.PYTHON`, or None (the default) for
        what ``HILL_MUSCLE_ENGINE`` chooses; :attr:`build` says which runs
    :raises ValueError: if ``plants`` is empty, holds something else, or the
        plants' muscles differ; if ``build`` (or ``HILL_MUSCLE_ENGINE``) is unknown
    :raises ImportError: if the compiled build is asked for and numba cannot be imported
    """

    def __init__(self, plants: Sequence[LimbPlant], build: str | None = None) -> None:
        self.plants, names = check_plants(plants)
        for k, plant in enumerate(self.plants):
            for mu in plant.muscles:
                if mu.params.activation_model != 'first_order':
                    raise ValueError(f'`plants[{k}]`: muscle {mu.name!r} must have '
                                     '`activation_model: first_order` in a batch of limbs (its '
                                     'rows carry level commands; a ding2003 muscle takes pulses: '
                                     f'run it with Limb), got {mu.params.activation_model!r}')
        self.size = len(self.plants)
        #: The muscles' names, the columns of every (K, M) array.
        self.muscle_names = names
        m = len(names)
        # Each limb writes its outputs into its row: one array for the batch.
        self._rows = np.zeros((self.size, ROW_JOINT + _PER_MUSCLE * m))
        self._s_r = np.array([[mu.sign * mu.moment_arm_m for mu in plant.muscles]
                              for plant in self.plants]).reshape(self.size, m)
        self._limbs = [Limb(plant, row, build) for plant, row in zip(self.plants, self._rows)]
        #: :data:`~hill_muscle_ros.model.engine.COMPILED` or ``PYTHON``: the
        #: build of the kernels every limb runs
        self.build = self._limbs[0].build

    # -- state ----------------------------------------------------------------------

    def reset(self) -> None:
        """Every limb at its initial state (theta_0, at rest, nothing recruited)."""
        for limb in self._limbs:
            limb.reset()

    @property
    def t_s(self) -> float:
        """[s] the batch's time (every limb's)."""
        return self._limbs[0].t_s

    def _matrix(self, values, name: str) -> np.ndarray:
        """``values`` as a (K, M) float array; a scalar or a (M,) row is shared."""
        v = np.asarray(values, dtype=float)
        shape = (self.size, len(self.muscle_names))
        if v.shape in ((), shape[1:]):
            v = np.broadcast_to(v, shape)
        if v.shape != shape:
            raise ValueError(f'`{name}` must have shape {shape} (limbs, muscles), '
                             f'got {v.shape}')
        return v

    def commands_from_pulse_widths(self, pulse_width_s) -> np.ndarray:
        """[-] recruitment commands u of pulse widths, each through its own
        muscle's recruitment curve
        (:func:`~hill_muscle_ros.model.stimulus.command_from_pulse_width`).

        :param pulse_width_s: [s] pulse width (PW) per limb and muscle, (K, M),
            a (M,) row for every limb, or a scalar
        :return: [-] u, shape (K, M)
        :raises ValueError: naming the limb and the muscle on a negative or
            non-finite width
        """
        pw = self._matrix(pulse_width_s, 'pulse_width_s')
        out = np.empty(pw.shape)
        for k, plant in enumerate(self.plants):
            for i, muscle in enumerate(plant.muscles):
                out[k, i] = command_from_pulse_width(
                    float(pw[k, i]), muscle.params, f'pulse_width_s[{k}, {i}] ({muscle.name})')
        return out

    def _checked_commands(self, commands) -> list[list[float]]:
        """Commands as one list per limb, each u in [0, 1] (:func:`check_commands`)."""
        return check_commands(self._matrix(commands, 'commands').tolist(), self.muscle_names)

    def give_commands(self, commands) -> None:
        """Give each muscle its recruitment command now, as a limb sample does
        (:func:`~.simulate.simulate_limb`): a command that differs from the
        muscle's last one is queued at this instant (and acts now if it has no
        delay and no activation dynamics).

        :param commands: [-] u in [0, 1] per limb and muscle, (K, M), (M,) or scalar
        :raises ValueError: naming the limb and the muscle on a bad value; nothing changes
        """
        for limb, row in zip(self._limbs, self._checked_commands(commands)):
            limb.give_commands(row)

    def set_pulse_widths(self, pulse_width_s) -> None:
        """:meth:`give_commands` of pulse widths through each muscle's curve."""
        self.give_commands(self.commands_from_pulse_widths(pulse_width_s))

    def step_commands(self, commands, external_torque_n_m, dt_s: float) -> LimbBatchOutputs:
        """Advance every limb one step, its commands and external torque held over it.

        Limb k does exactly ``Limb(plants[k]).step(commands[k],
        external_torque_n_m[k], dt_s)``.

        :param commands: [-] u in [0, 1] per limb and muscle, (K, M), (M,) or scalar
        :param external_torque_n_m: [N m] tau_ext per limb, (K,) or a scalar
        :param dt_s: [s] step length, > 0, the same for every limb
        :return: the outputs at the end of the step
        :raises ValueError: on a bad input, naming it, before any limb moves;
            :class:`LimbOutOfRange` (a ValueError) on a limb driven beyond its
            muscles' length range, naming the limb (the limbs before it have
            then stepped: reset the batch)
        """
        u, tau, dt = self._checked_step(commands, external_torque_n_m, dt_s)
        for k, limb in enumerate(self._limbs):
            try:
                limb.advance(u[k], tau[k], dt)
            except ValueError as err:
                raise LimbOutOfRange(k, str(err)) from None
        return self.outputs()

    def _checked_step(self, commands, external_torque_n_m,
                      dt_s: float) -> tuple[list[list[float]], list[float], float]:
        """A step's inputs checked: commands and torques as lists per limb, dt as a float.

        :raises ValueError: naming the bad input
        """
        u = self._checked_commands(commands)
        tau = np.asarray(external_torque_n_m, dtype=float)
        if tau.shape == ():
            tau = np.full(self.size, float(tau))
        if tau.shape != (self.size,):
            raise ValueError(f'`external_torque_n_m` must have shape ({self.size},), '
                             f'got {tau.shape}')
        taus = [check_torque(value, f'external_torque_n_m[{k}]')
                for k, value in enumerate(tau.tolist())]
        dt = float(dt_s)
        if not (math.isfinite(dt) and dt > 0.0):
            raise ValueError(f'`dt_s` must be positive and finite, got {dt_s!r}')
        return u, taus, dt

    def hold_commands(self, commands, external_torque_n_m, dt_s: float, n_steps: int,
                      target_rad) -> tuple[LimbBatchOutputs, np.ndarray]:
        """:meth:`step_commands` ``n_steps`` times with the same inputs, and each
        limb's squared distance to an angle summed over the steps (a tracking
        environment's control period), in one call of the kernels per limb.

        :param dt_s: [s] each step's length, in (0, 1 ms]
        :param n_steps: [-] steps, >= 1
        :param target_rad: [rad] theta* per limb, (K,) or a scalar
        :return: the outputs after the last step, and [rad^2] per limb the sum
            over the steps of (theta - theta*)^2 at each step's end, (K,)
        :raises ValueError: as :meth:`step_commands`, or on a step longer than
            1 ms, before any limb moves; on a limb out of range the limbs before
            it have taken every step, it and the rest fewer
        """
        n = int(n_steps)
        if n < 1:
            raise ValueError(f'`n_steps` must be at least 1, got {n_steps!r}')
        target = np.broadcast_to(np.asarray(target_rad, dtype=float), (self.size,))
        u, taus, dt = self._checked_step(commands, external_torque_n_m, dt_s)
        check_hold_step(dt)
        targets = target.tolist()
        squared = np.empty(self.size)
        for k, limb in enumerate(self._limbs):
            try:
                squared[k] = limb.hold(u[k], taus[k], dt, n, targets[k])
            except ValueError as err:
                raise LimbOutOfRange(k, str(err)) from None
        return self.outputs(), squared

    def step(self, pulse_width_s, external_torque_n_m, dt_s: float) -> LimbBatchOutputs:
        """Advance every limb one step with pulse widths held over it
        (:meth:`step_commands` of :meth:`commands_from_pulse_widths`).

        :param pulse_width_s: [s] PW per limb and muscle, (K, M), (M,) or scalar
        :param external_torque_n_m: [N m] tau_ext per limb, (K,) or a scalar
        :param dt_s: [s] step length, > 0
        """
        return self.step_commands(self.commands_from_pulse_widths(pulse_width_s),
                                  external_torque_n_m, dt_s)

    def outputs(self) -> LimbBatchOutputs:
        """The outputs of every limb at the current instant, read off the batch's rows."""
        rows = self._rows
        per_muscle = [rows[:, ROW_JOINT + j::_PER_MUSCLE].copy() for j in range(_PER_MUSCLE)]
        torque = np.zeros(self.size)
        for i in range(len(self.muscle_names)):   # in order, as Limb.outputs sums
            torque += self._s_r[:, i] * per_muscle[_FORCE][:, i]
        return LimbBatchOutputs(float(rows[0, 0]), rows[:, 1].copy(), rows[:, 2].copy(),
                                torque, *per_muscle)


def simulate_limb_batch(plants: Sequence[LimbPlant], protocol: LimbProtocol,
                        rate_hz: float, sample_indices: Sequence[int]
                        ) -> tuple[np.ndarray, np.ndarray]:
    """Joint angle and muscle forces of many plants at some steps of one limb protocol.

    Plant k follows :func:`~.simulate.simulate_limb` with ``plants[k]``: the
    sample of step j shows the state at t_j with the commands of t_j given;
    the step from t_j holds the commands and the external torque of t_j.
    Pulse widths map through each plant's own recruitment curves. The run
    stops at the last sample. Each plant runs alone (a limb's result does not
    depend on the others'), in one call of the kernels on the build
    :func:`~hill_muscle_ros.model.engine.kernels` chooses.

    :param plants: the plants (K >= 1), with the same muscles
    :param protocol: the limb protocol every plant replays
    :param rate_hz: [Hz] step rate, 1 / dt
    :param sample_indices: step indices to sample, ascending
    :return: ([rad] theta, shape (K, S); [N] force, shape (K, M, S))
    :raises ValueError: on a protocol muscle the plants lack or an input out of
        range; :class:`LimbOutOfRange` on a limb driven beyond its muscles'
        length range: the first such limb at the earliest step, as a
        :class:`LimbBatch` stepping every limb before the next step would say
    """
    plants, names = check_plants(plants)
    last = max(sample_indices)
    t = sample_times(protocol.duration_s, rate_hz)[:last + 1]
    # (steps, K, M): each plant's commands through its own muscles' curves.
    u = np.stack([protocol.commands(t, plant) for plant in plants], axis=1)
    tau = np.asarray(protocol.external_torque_n_m(t), dtype=float)
    # Validated once, as the steps would (commands in [0, 1], the torque in range).
    for row, torque in zip(u.tolist(), tau.tolist()):
        check_commands(row, names)
        check_torque(torque)
    u, tau, h, n = substep_rows(u, tau, 1.0 / rate_hz)
    rows_of = np.asarray(sample_indices, dtype=np.int64) * n
    build = engine.kernels(kernels)
    theta = np.empty((len(plants), len(rows_of)))
    force = np.empty((len(plants), len(names), len(rows_of)))
    failures = []
    for k, plant in enumerate(plants):
        arrays = LimbArrays(plant, h, SCRATCH)
        try:
            rows, failure = run_rows(arrays, u[:, k, :], tau, h, build)
        finally:
            arrays.give_back()
        if failure is not None:
            failures.append((failure[0], k, failure[1]))
            continue
        theta[k] = rows[rows_of, 1]
        for i in range(len(names)):
            force[k, i] = rows[rows_of, ROW_JOINT + _PER_MUSCLE * i + _FORCE]
    if failures:
        _, k, message = min(failures)
        raise LimbOutOfRange(k, message)
    return theta, force
