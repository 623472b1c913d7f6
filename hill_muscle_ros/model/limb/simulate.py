"""Offline runs of a limb: a whole protocol in one call of the kernels.

:func:`simulate_limb` replays a :class:`~.plant.LimbProtocol` from the
plant's initial state and returns every sample (:class:`~.plant.LimbResult`);
:func:`run_rows` is its loop on a limb's arrays, which
:func:`~.batch.simulate_limb_batch` runs for each plant of a sweep. Both run
:func:`.kernels.limb_run` on the build that
:func:`~hill_muscle_ros.model.engine.kernels` chooses: compiled, or the very
same functions as plain Python (``HILL_MUSCLE_ENGINE=python``).
"""
from __future__ import annotations

import numpy as np

from .. import engine
from ..simulate import sample_times
from ..substeps import repeat_rows, substeps_for
from . import kernels
from .arrays import SCRATCH, LimbArrays, pulse_arrays, row_length
from .kernels import DELAY_FULL, MODE_RUN, STATUS_BASE
from .plant import (TORQUE_LIMIT_N_M, LimbPlant, LimbProtocol, LimbResult, check_step_inputs,
                    limb_columns)


def substep_rows(u: np.ndarray, tau: np.ndarray, dt_s: float
                 ) -> tuple[np.ndarray, np.ndarray, float, int]:
    """A run's inputs per substep of at most 1 ms, each sample's held over its
    n = ceil(dt / 1 ms) substeps (:mod:`~hill_muscle_ros.model.substeps`), as
    :meth:`.limb.Limb.step` takes them.

    :param u: [-] commands, one row per sample
    :param tau: [N m] external torque, one entry per sample
    :param dt_s: [s] the samples' step
    :return: (u, tau) one row per substep, [s] the substep h, [-] n: the
        samples are every n-th row of the run
    """
    n = substeps_for(dt_s)
    if n > 1:
        u, tau = repeat_rows(u, n), repeat_rows(tau, n)
    return u, tau, dt_s / n, n


def run_rows(arrays: LimbArrays, u: np.ndarray, tau: np.ndarray, dt_s: float,
             build) -> tuple[np.ndarray, tuple[int, str] | None]:
    """:func:`.kernels.limb_run` on ``arrays`` from their current state: the
    commands of the first sample given, then per sample the step and the next
    sample's commands.

    :param u: [-] (samples, muscles) commands, checked in [0, 1]
    :param tau: [N m] (samples,) external torque, checked
    :param dt_s: [s] the step, at most 1 ms (:func:`substep_rows`)
    :param build: the kernels' build that runs (:func:`~hill_muscle_ros.model.engine.kernels`)
    :return: the outputs (samples, :func:`~.arrays.row_length`) in the columns of
        :func:`~.plant.limb_columns` (the time from the state), and None; or, when
        step k stretched a muscle out of range, rows that are not all written and
        (k, the message :meth:`.limb.Limb.step` raises)
    :raises RuntimeError: if a muscle's delay line overflowed (never for valid parameters)
    """
    arrays.ensure_delay(dt_s)
    u = np.ascontiguousarray(u, dtype=float).reshape(len(tau), arrays.nm)
    tau = np.ascontiguousarray(tau, dtype=float)
    # Every row is written (limb_record's every column) unless the run fails,
    # and the rows of a failed run are not read.
    rows = np.empty((len(tau), row_length(arrays.nm, arrays.n_activations)))
    done = arrays.entry(build, MODE_RUN, u, tau, float(dt_s), 0, 0.0, np.zeros(1), rows)
    if done >= 0:
        return rows, None
    k, status = divmod(-done, STATUS_BASE)
    if status == DELAY_FULL:
        raise RuntimeError(f'a muscle\'s delay line overflowed at step {k}')
    return rows, (k, str(arrays.error(status)))


def run_limb(arrays: LimbArrays, u: np.ndarray, tau: np.ndarray, dt_s: float) -> np.ndarray:
    """:func:`run_rows` on the engine's build of the kernels, raising on a failure.

    :return: the outputs, one row per sample
    :raises ValueError: as :meth:`.limb.Limb.step`, when a muscle is stretched out of range
    """
    rows, failure = run_rows(arrays, u, tau, dt_s, engine.kernels(kernels))
    if failure is not None:
        raise ValueError(failure[1])
    return rows


def simulate_limb(plant: LimbPlant, protocol: LimbProtocol,
                  rate_hz: float = 1000.0) -> LimbResult:
    """Run a limb protocol from the initial state at a fixed step of 1 / ``rate_hz``.

    The sample at t_k shows the state at t_k with the commands of t_k given;
    the step from t_k holds the commands and the external torque of t_k, in
    substeps of at most 1 ms. The whole run is one call of the kernels, on the
    build :func:`~hill_muscle_ros.model.engine.kernels` chooses.

    A ``ding2003`` muscle is driven by its ``channels``' pulse trains: every
    pulse is checked against its ``stimulator`` and acts at its own instant,
    the step cut there (:func:`.kernels.limb_step`); the result gains
    ``a_<muscle>_<c>``, each channel's activation.

    :param plant: the joint and its muscles
    :param protocol: the stimulation of each muscle and the external torque
    :param rate_hz: [Hz] sample rate, 1 / dt
    :return: the time series, ``round(duration * rate) + 1`` samples
    :raises ValueError: on a bad rate, a protocol muscle the plant lacks
        (:class:`~hill_muscle_ros.model.protocol.ProtocolError`), an input out
        of range (naming it, as :meth:`.limb.Limb.step`), or a muscle stretched
        out of range
    """
    t = sample_times(protocol.duration_s, rate_hz)
    u = np.asarray(protocol.commands(t, plant), dtype=float)
    pulses = protocol.pulses(plant)
    tau = np.asarray(protocol.external_torque_n_m(t), dtype=float)
    dt = 1.0 / rate_hz
    # The protocol validated its knots, and interpolation keeps them in range:
    # one look at the arrays replaces the check of every step.
    bad = ~((u >= 0.0) & (u <= 1.0)).all(axis=1) | ~(np.abs(tau) <= TORQUE_LIMIT_N_M)
    if bad.any():
        k = int(np.argmax(bad))
        check_step_inputs(plant, u[k].tolist(), float(tau[k]), dt)   # raises, naming it
    u, tau, h, n = substep_rows(u, tau, dt)
    arrays = LimbArrays(plant, h, SCRATCH)
    arrays.pulses = pulse_arrays(pulses)
    try:
        rows = run_limb(arrays, u, tau, h)[::n]
    finally:
        arrays.give_back()
    rows[:, 0] = t   # the sample times are the inputs themselves
    return LimbResult(t, dict(zip(limb_columns(plant), rows.T)))
