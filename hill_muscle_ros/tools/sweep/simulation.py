"""What a sweep's task computes: a chunk of parameter sets simulated at once.

:func:`run_chunk` runs a chunk of muscles on
:class:`~hill_muscle_ros.model.muscle.batch.MuscleBatch` (:func:`simulate_forces`),
:func:`run_limb_chunk` a chunk of limb plants on the limb batch; both run on a
Dask worker or in this process. :func:`chunk_ranges` cuts the sets into chunks.
"""
from __future__ import annotations

import math
from typing import Sequence

import numpy as np

from ...model import LimbOutOfRange, MuscleBatch, MuscleParams, Protocol, simulate_limb_batch
from ...model.limb import LimbPlant, LimbProtocol
from ...model.simulate import sample_times
from .spec import SweepError

#: Largest automatic chunk (sets per task). A batch step's cost is mostly
#: fixed (measured 70-100 us for 1 to 256 muscles), so the fewer and larger
#: the chunks the faster: on 2 cores, 1024 sets of Protocol II ran at 650
#: sets/s in chunks of 256 and 900 in chunks of 512, but 80-100 sets/s for
#: 256 sets in chunks of 32. Ctrl-C loses at most the chunks running.
MAX_AUTO_CHUNK = 512
#: Largest automatic chunk of a limb sweep. A limb batch steps each limb on
#: its own (:mod:`~hill_muscle_ros.model.limb.batch`), so a chunk costs the
#: same per set at any size, and one knee set of a few seconds already takes
#: seconds: small chunks balance the workers and move the progress bar, for a
#: task overhead of milliseconds.
MAX_AUTO_LIMB_CHUNK = 4
#: Value of the ``worker`` column for rows computed in this process (no Dask).
LOCAL_WORKER = 'local'


def simulate_forces(protocol: Protocol, params: Sequence[MuscleParams], rate_hz: float,
                    sample_indices: Sequence[int]) -> np.ndarray:
    """[N] MTU force of many muscles at some steps of one protocol, all at once.

    Muscle i follows :func:`~hill_muscle_ros.model.simulate.simulate` with
    ``params[i]``: the sample of step k shows the state at t_k with the command
    of t_k applied; the step from t_k to t_(k+1) holds u(t_k) and ramps dl_MT.
    The run stops at the last sample.

    :param protocol: the protocol every muscle replays
    :param params: the muscles' parameters (K >= 1)
    :param rate_hz: [Hz] step rate, 1 / dt
    :param sample_indices: step indices to sample, ascending
    :return: [N] force, shape (K, len(sample_indices))
    """
    last = max(sample_indices)
    t = sample_times(protocol.duration_s, rate_hz)[:last + 1]
    dl = np.asarray(protocol.dl_mt(t), dtype=float)
    # Pulse widths map through each muscle's own recruitment curve.
    r = np.column_stack([np.asarray(protocol.command(t, p), dtype=float) for p in params])
    batch = MuscleBatch(params)
    dt = 1.0 / rate_hz
    wanted = {k: j for j, k in enumerate(sample_indices)}
    force = np.empty((len(params), len(sample_indices)))
    batch.set_recruitment(r[0])
    if 0 in wanted:
        force[:, wanted[0]] = batch.outputs().force_n
    for k in range(last):
        batch.step(r[k], dl[k + 1], dt)
        if k + 1 in wanted:
            batch.set_recruitment(r[k + 1])
            force[:, wanted[k + 1]] = batch.outputs().force_n
    return force


def run_chunk(set_ids: Sequence[int], params: Sequence[MuscleParams], protocol: Protocol,
              rate_hz: float, sample_indices: Sequence[int]) -> dict:
    """One task: simulate a chunk of parameter sets; runs on a Dask worker or here.

    :return: ``set_ids``, ``force_n`` (K, S) and ``worker`` (the address of the
        Dask worker that ran it, or ``local``)
    """
    force = simulate_forces(protocol, params, rate_hz, sample_indices)
    return {'set_ids': list(set_ids), 'force_n': force, 'worker': _worker()}


def run_limb_chunk(set_ids: Sequence[int], plants: Sequence[LimbPlant],
                   protocol: LimbProtocol, rate_hz: float,
                   sample_indices: Sequence[int]) -> dict:
    """One task of a limb sweep: simulate a chunk of plants with a
    :class:`~hill_muscle_ros.model.limb.LimbBatch`; runs on a Dask worker or here.

    :return: ``set_ids``, ``theta_rad`` (K, S), ``force_n`` (K, M, S) and ``worker``
    :raises SweepError: naming the parameter set of a limb driven beyond its
        muscles' length range
    """
    try:
        theta, force = simulate_limb_batch(plants, protocol, rate_hz, sample_indices)
    except LimbOutOfRange as err:
        raise SweepError(f'parameter set {set_ids[err.limb]}: {err.message}') from None
    return {'set_ids': list(set_ids), 'theta_rad': theta, 'force_n': force,
            'worker': _worker()}


def _worker() -> str:
    """The address of the Dask worker running this, or ``local``."""
    try:
        from distributed import get_worker
        return get_worker().address
    except (ImportError, ValueError):   # not inside a Dask worker
        return LOCAL_WORKER


def chunk_ranges(n_sets: int, n_workers: int, chunk: int | None = None,
                 max_chunk: int = MAX_AUTO_CHUNK) -> list[range]:
    """Consecutive ranges of set indices, one per task.

    :param n_workers: workers that share the tasks (0: this process alone)
    :param chunk: sets per task (default: an equal share per worker, at most
        ``max_chunk``)
    :param max_chunk: largest automatic chunk (:data:`MAX_AUTO_CHUNK`, or
        :data:`MAX_AUTO_LIMB_CHUNK` for a limb)
    """
    if chunk is None:
        chunk = max(1, min(max_chunk, math.ceil(n_sets / max(n_workers, 1))))
    return [range(i, min(i + chunk, n_sets)) for i in range(0, n_sets, chunk)]
