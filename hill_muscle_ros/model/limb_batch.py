"""Many limbs stepped at once: K plants of the same joint and muscles, each with
its own parameters and its own stimulation.

For parameter sweeps and controller tuning on a limb: K
:class:`~hill_muscle_ros.model.limb.LimbPlant` s with the same muscles (the
same names, in the same order; e.g. one preset with a muscle's or the joint's
parameters changed) advance together by one step of the same length, each with
its own pulse width per muscle (or recruitment command) and its own external
torque. State and outputs are arrays: (K,) per limb, (K, M) per limb and
muscle, M muscles in the plants' order.

Each limb is stepped by its own :class:`~hill_muscle_ros.model.limb.Limb`:
the joint's equation of motion, the moment arms, the recruitment events of
each muscle and the RK4 of the joint and all CE lengths together are the
limb's code, called, not copied, so limb k of the batch does exactly what a
``Limb(plants[k])`` does (the tests check it against separate runs and against
:func:`~hill_muscle_ros.model.limb.simulate_limb` to 1e-9 rad and 1e-9 N).

On the compiled engine (``engine``) each limb is a
:class:`~hill_muscle_ros.model.limb_kernels.CompiledLimb` instead: the same
step compiled, the same outputs to 1e-9 rad and 1e-9 N.

Cost: one scalar limb step per limb, plus the arrays' bookkeeping. Unlike
:class:`~hill_muscle_ros.model.batch.MuscleBatch`, there is no vectorised
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

from .limb import TORQUE_LIMIT_N_M, Limb, LimbPlant, LimbProtocol
from .params import check_instances
from .simulate import sample_times
from .stimulus import command_from_pulse_width


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


class LimbBatch:
    """K limbs with the same muscles and their own parameters, stepped together.

    :param plants: one :class:`LimbPlant` per limb (K >= 1), all with the same
        muscle names in the same order
    :param engine: ``'compiled'``: each limb a
        :class:`~hill_muscle_ros.model.limb_kernels.CompiledLimb` (the same
        outputs to 1e-9 rad and 1e-9 N; the first in a process loads the
        compiled limb, about 0.8 s, about 30 s if it compiles); ``'python'``:
        each a :class:`~hill_muscle_ros.model.limb.Limb`; ``None``:
        :func:`~hill_muscle_ros.model.limb_kernels.step_engine`'s rule (compiled
        once loaded in the process, or with ``HILL_MUSCLE_ENGINE=compiled``)
    :raises ValueError: if ``plants`` is empty, holds something else, or the
        plants' muscles differ
    """

    def __init__(self, plants: Sequence[LimbPlant], engine: str | None = None) -> None:
        plants = check_instances(LimbPlant, plants, 'plants')
        names = tuple(m.name for m in plants[0].muscles)
        for k, plant in enumerate(plants[1:], start=1):
            other = tuple(m.name for m in plant.muscles)
            if other != names:
                raise ValueError(f'`plants[{k}]` must have the muscles of `plants[0]`, '
                                 f'{list(names)}, in that order; got {list(other)}')
        self.plants = plants
        self.size = len(plants)
        #: The muscles' names, the columns of every (K, M) array.
        self.muscle_names = names
        from . import limb_kernels
        #: ``'compiled'`` or ``'python'``: the engine of every limb
        self.engine = limb_kernels.step_engine(engine)
        self._compiled = self.engine == 'compiled'
        if self._compiled:
            kernels = limb_kernels.compiled()
            # Each limb writes its outputs into its row: one array for the batch.
            self._rows = np.zeros((self.size, 3 + 5 * len(names)))
            self._s_r = np.array([[m.sign * m.moment_arm_m for m in plant.muscles]
                                  for plant in plants]).reshape(self.size, len(names))
            self._limbs = [limb_kernels.CompiledLimb(plant, kernels, row)
                           for plant, row in zip(plants, self._rows)]
        else:
            self._limbs = [Limb(plant) for plant in plants]

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
        """Commands as one list per limb, each u in [0, 1]. Checked in Python:
        for a few limbs a step's NumPy calls would cost more than the loop."""
        u = self._matrix(commands, 'commands').tolist()
        for k, row in enumerate(u):
            for i, value in enumerate(row):
                if not 0.0 <= value <= 1.0:   # also true for NaN
                    raise ValueError(f'`commands[{k}, {i}]` ({self.muscle_names[i]}) must '
                                     f'be in [0, 1], got {value!r}')
        return u

    def give_commands(self, commands) -> None:
        """Give each muscle its recruitment command now, as a limb sample does
        (:func:`~hill_muscle_ros.model.limb.simulate_limb`): a command that
        differs from the muscle's last one is queued at this instant (and acts
        now if it has no delay and no activation dynamics).

        :param commands: [-] u in [0, 1] per limb and muscle, (K, M), (M,) or scalar
        :raises ValueError: naming the limb and the muscle on a bad value; nothing changes
        """
        self._give(self._checked_commands(commands))

    def _give(self, u: list[list[float]]) -> None:
        """:meth:`give_commands` of validated commands, one list per limb."""
        if self._compiled:
            for limb, row in zip(self._limbs, u):
                limb.give_commands(row)
            return
        for limb, row in zip(self._limbs, u):
            for muscle, value in zip(limb.muscles, row):
                if value != muscle.command:
                    muscle.give_command(value)

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
        return self._gather(self._advance(*self._checked_step(commands, external_torque_n_m,
                                                              dt_s)))

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
        taus = tau.tolist()
        for k, value in enumerate(taus):
            if not abs(value) <= TORQUE_LIMIT_N_M:   # also true for NaN
                raise ValueError(f'`external_torque_n_m[{k}]` must be finite and within '
                                 f'±{TORQUE_LIMIT_N_M:g} N m, got {value!r}')
        dt = float(dt_s)
        if not (math.isfinite(dt) and dt > 0.0):
            raise ValueError(f'`dt_s` must be positive and finite, got {dt_s!r}')
        return u, taus, dt

    def _advance(self, u: list[list[float]], tau: list[float], dt: float) -> list:
        """Step every limb with validated inputs (Python lists: no NumPy scalars
        in the scalar limbs' arithmetic); returns each limb's outputs (compiled:
        None, the outputs are in the batch's rows)."""
        if self._compiled:
            for k, limb in enumerate(self._limbs):
                try:
                    limb.advance(u[k], tau[k], dt)
                except ValueError as err:
                    raise LimbOutOfRange(k, str(err)) from None
            return None
        outs = []
        for k, limb in enumerate(self._limbs):
            try:
                outs.append(limb.step(u[k], tau[k], dt))
            except ValueError as err:
                raise LimbOutOfRange(k, str(err)) from None
        return outs

    def hold_commands(self, commands, external_torque_n_m, dt_s: float, n_steps: int,
                      target_rad) -> tuple[LimbBatchOutputs, np.ndarray]:
        """:meth:`step_commands` ``n_steps`` times with the same inputs, and each
        limb's squared distance to an angle summed over the steps (a tracking
        environment's control period); on the compiled engine one call per limb.

        :param n_steps: [-] steps, >= 1
        :param target_rad: [rad] theta* per limb, (K,) or a scalar
        :return: the outputs after the last step, and [rad^2] per limb the sum
            over the steps of (theta - theta*)^2 at each step's end, (K,)
        :raises ValueError: as :meth:`step_commands`; on a limb out of range
            the limbs before it have taken every step, it and the rest fewer
        """
        n = int(n_steps)
        if n < 1:
            raise ValueError(f'`n_steps` must be at least 1, got {n_steps!r}')
        target = np.broadcast_to(np.asarray(target_rad, dtype=float), (self.size,))
        if not self._compiled:
            squared = np.zeros(self.size)
            for _ in range(n):
                out = self.step_commands(commands, external_torque_n_m, dt_s)
                squared += (out.theta_rad - target) ** 2
            return out, squared
        u, taus, dt = self._checked_step(commands, external_torque_n_m, dt_s)
        targets = target.tolist()
        squared = np.empty(self.size)
        for k, limb in enumerate(self._limbs):
            try:
                squared[k] = limb.hold(u[k], taus[k], dt, n, targets[k])
            except ValueError as err:
                raise LimbOutOfRange(k, str(err)) from None
        return self._gather(None), squared

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
        """The outputs of every limb at the current instant."""
        if self._compiled:
            return self._gather(None)
        return self._gather([limb.outputs() for limb in self._limbs])

    def _gather(self, outs: list) -> LimbBatchOutputs:
        """The limbs' :class:`~hill_muscle_ros.model.limb.LimbOutputs` as arrays
        (compiled: from the batch's rows, ``outs`` None)."""
        if outs is None:
            rows = self._rows
            per_muscle = [rows[:, 3 + j::5].copy() for j in range(5)]
            torque = np.zeros(self.size)
            for i in range(len(self.muscle_names)):   # in order, as Limb.outputs sums
                torque += self._s_r[:, i] * per_muscle[4][:, i]
            return LimbBatchOutputs(float(rows[0, 0]), rows[:, 1].copy(), rows[:, 2].copy(),
                                    torque, *per_muscle)
        per_limb = np.array([(o.theta_rad, o.omega_rad_per_s, o.muscle_torque_n_m)
                             for o in outs], dtype=float).reshape(self.size, 3)
        per_muscle = np.array([(o.command, o.recruitment, o.dl_mt_m, o.l_ce_m, o.force_n)
                               for o in outs], dtype=float)
        per_muscle = per_muscle.reshape(self.size, 5, len(self.muscle_names))
        return LimbBatchOutputs(self.t_s, per_limb[:, 0], per_limb[:, 1], per_limb[:, 2],
                                *(per_muscle[:, j] for j in range(5)))


def simulate_limb_batch(plants: Sequence[LimbPlant], protocol: LimbProtocol,
                        rate_hz: float, sample_indices: Sequence[int]
                        ) -> tuple[np.ndarray, np.ndarray]:
    """Joint angle and muscle forces of many plants at some steps of one limb protocol.

    Plant k follows :func:`~hill_muscle_ros.model.limb.simulate_limb` with
    ``plants[k]``: the sample of step j shows the state at t_j with the commands
    of t_j given; the step from t_j holds the commands and the external torque
    of t_j. Pulse widths map through each plant's own recruitment curves. The
    run stops at the last sample. Where the compiled limb pays (as for
    :func:`~hill_muscle_ros.model.limb.simulate_limb`, counting every plant's
    muscle-steps) each plant runs alone on it (:mod:`.limb_kernels`).

    :param plants: the plants (K >= 1), with the same muscles
    :param protocol: the limb protocol every plant replays
    :param rate_hz: [Hz] step rate, 1 / dt
    :param sample_indices: step indices to sample, ascending
    :return: ([rad] theta, shape (K, S); [N] force, shape (K, M, S))
    :raises ValueError: on a protocol muscle the plants lack;
        :class:`LimbOutOfRange` on a limb driven beyond its muscles' length range
    """
    # Python limbs: the compiled path below builds its own arrays per plant.
    batch = LimbBatch(plants, engine='python')
    last = max(sample_indices)
    t = sample_times(protocol.duration_s, rate_hz)[:last + 1]
    # (steps, K, M): each plant's commands through its own muscles' curves.
    u = np.stack([protocol.commands(t, plant) for plant in batch.plants], axis=1)
    tau = np.asarray(protocol.external_torque_n_m(t), dtype=float)
    dt = 1.0 / rate_hz
    wanted = {k: j for j, k in enumerate(sample_indices)}
    theta = np.empty((batch.size, len(sample_indices)))
    force = np.empty((batch.size, len(batch.muscle_names), len(sample_indices)))

    def record(j: int) -> None:
        out = batch.outputs()
        theta[:, j] = out.theta_rad
        force[:, :, j] = out.force_n

    # Validated once, as the steps would (commands in [0, 1], the torque in range).
    for row, torque in zip(u, tau):
        batch._checked_commands(row)
        if not abs(torque) <= TORQUE_LIMIT_N_M:
            raise ValueError(f'`external_torque_n_m` must be finite and within '
                             f'±{TORQUE_LIMIT_N_M:g} N m, got {float(torque)!r}')
    from . import engine, limb_kernels
    if engine.use_compiled(last * batch.size * len(batch.muscle_names),
                           limb_kernels.RUN_MIN_MUSCLE_STEPS, limb_kernels.loaded()):
        # The same numbers (limb_kernels), each plant alone.
        return limb_kernels.run_limb_batch(batch.plants, u, tau, dt, sample_indices)
    u_rows = u.tolist()
    tau_rows = [[value] * batch.size for value in tau.tolist()]
    batch._give(u_rows[0])
    if 0 in wanted:
        record(wanted[0])
    for k in range(last):
        batch._advance(u_rows[k], tau_rows[k], dt)
        batch._give(u_rows[k + 1])
        if k + 1 in wanted:
            record(wanted[k + 1])
    return theta, force
