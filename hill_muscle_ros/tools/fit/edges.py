"""Live bags: each stimulation change moved to the step that best explains the force.

A live recording stamps the stimulation with the recorder's receive time, some
steps off the step the simulator acted on: :func:`fit_with_aligned_edges` fits,
moves each change (:func:`align_stimulation_edges`) and fits again until the
moves settle.
"""
from __future__ import annotations

import dataclasses
from typing import Callable, Sequence

import numpy as np

from ...model import MuscleParams
from .estimate import FitResult, fit_parameters
from .parameters import FitParameter
from .recording import MuscleRecording
from .replay import MuscleReplay, replay_runs


def candidate_moves(recording: 'MuscleRecording', max_shift_steps: int) -> int:
    """[-] moves :func:`align_stimulation_edges` tries at most: each stimulation
    change by every whole step within ±``max_shift_steps``."""
    return len(stimulation_edges(recording.stimulation)) * (2 * max_shift_steps + 1)


def edge_search_runs(recording: 'MuscleRecording', n_parameters: int,
                     max_shift_steps: int) -> int:
    """[-] runs of :func:`fit_with_aligned_edges` at most: per round a fit and one
    run per candidate move."""
    return MAX_ALIGN_ROUNDS * (replay_runs(n_parameters)
                               + candidate_moves(recording, max_shift_steps))


def stimulation_edges(stimulation: np.ndarray) -> np.ndarray:
    """Grid indices where the held stimulation changes (the first step it acts on)."""
    return np.flatnonzero(stimulation[1:] != stimulation[:-1]) + 1


def _moved_edge(stimulation: np.ndarray, edge: int, shift: int) -> np.ndarray:
    """The stimulation with the change at ``edge`` moved by ``shift`` steps."""
    out = stimulation.copy()
    if shift > 0:
        out[edge:edge + shift] = stimulation[edge - 1]
    elif shift < 0:
        out[edge + shift:edge] = stimulation[edge]
    return out


def align_stimulation_edges(recording: MuscleRecording, params: MuscleParams,
                            max_shift_steps: int, runs: int | None = None,
                            ) -> tuple[MuscleRecording, list[int]]:
    """Each stimulation change moved to the step that best explains the force.

    A live recording stamps the stimulation with the recorder's receive time,
    while the simulator applied each message from the first step of its next
    tick: a change can act some steps before or after its stamp (measured: up
    to 13 ms on a loaded machine). With the force of the paper's model jumping
    at each change, one step off leaves a residual of the size of the jump and
    biases the fit. Each change, in order, is moved by the whole number of steps
    within ±``max_shift_steps`` (never past its neighbours) that gives the least
    sum of squared residuals with ``params``; a tie keeps the smallest move.
    The moves of one change are replayed from the muscle saved before the
    earliest of them (:meth:`MuscleReplay.checkpoint`), with the same forces
    as replays from rest.

    :param runs: [-] runs the caller expects in all, for :class:`MuscleReplay`'s
        choice of engine (default: this search's own, one per candidate move)
    :return: the recording with the changes moved, and each change's move [steps]
    """
    stim = recording.stimulation
    edges = [int(c) for c in stimulation_edges(stim)]
    if runs is None:
        runs = candidate_moves(recording, max_shift_steps)
    shifts = []
    for j, edge in enumerate(edges):
        low = (edges[j - 1] + shifts[j - 1] + 1) if j else 1
        high = edges[j + 1] - 1 if j + 1 < len(edges) else len(stim) - 1
        moves = [shift for shift in sorted(range(-max_shift_steps, max_shift_steps + 1), key=abs)
                 if low <= edge + shift <= high]   # never empty: 0 always is
        # Every move leaves the commands before its earliest step as they are:
        # those steps are replayed once, each move goes on from there.
        replay = MuscleReplay(dataclasses.replace(recording, stimulation=stim), runs)
        checkpoint = replay.checkpoint(params, edge + min(moves))
        best = None
        for shift in moves:
            residual = checkpoint.predict(_moved_edge(stim, edge, shift)) - recording.force_n
            sse = float(residual @ residual)
            if best is None or sse < best[0]:
                best = (sse, shift)
        shift = best[1] if best is not None else 0
        stim = _moved_edge(stim, edge, shift)
        shifts.append(shift)
    return dataclasses.replace(recording, stimulation=stim), shifts


#: Most rounds of fitting and aligning the stimulation changes: the moves settle
#: in one or two (a move found with the first estimates is rarely revised).
MAX_ALIGN_ROUNDS = 4


def fit_with_aligned_edges(recording: MuscleRecording, start: MuscleParams,
                           parameters: Sequence[FitParameter], max_shift_steps: int,
                           progress: Callable[[str], None] | None = None,
                           ) -> tuple['FitResult', MuscleRecording, list[int]]:
    """Fit, move the stimulation changes to the fitted model, and fit again from
    ``start``, until the moves stay the same (:func:`align_stimulation_edges`).

    :return: the last fit, the recording it used, and the moves [steps]
    """
    used = recording
    shifts = [0] * len(stimulation_edges(recording.stimulation))
    # Every run of the search judged together: one engine from the first run on.
    runs = edge_search_runs(recording, len(parameters), max_shift_steps)
    for _ in range(MAX_ALIGN_ROUNDS):
        result = fit_parameters(MuscleReplay(used, runs), recording.force_n, start,
                                parameters, progress=progress)
        fitted_with = (used, shifts)
        aligned, new_shifts = align_stimulation_edges(recording, result.params,
                                                      max_shift_steps, runs)
        if progress is not None:
            progress('stimulation changes moved by ' + (', '.join(
                f'{s * 1e3 / recording.rate_hz:+g} ms' for s in new_shifts) or 'nothing'))
        if new_shifts == shifts:
            break
        used, shifts = aligned, new_shifts
    return (result, *fitted_with)   # if the moves never settled: the last fit's
