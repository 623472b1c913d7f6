"""The recorded inputs replayed through the model: the predictions a fit's
residuals are made of.

:class:`MuscleReplay` predicts the force of a single muscle, :class:`LimbReplay`
the joint angle of a limb, for several parameter sets at once; their
``predict`` is all :func:`~.estimate.fit_parameters` asks of a model
(:class:`~.estimate.ForceModel`).
"""
from __future__ import annotations

import copy
from typing import Any, Sequence

import numpy as np

from ...model import Muscle, MuscleParams
from ...model.limb import LimbPlant, LimbProtocol, simulate_limb
from ...model.muscle import MuscleOutputs
from ...model.protocol import Knots, commands_from_pulse_widths
from ...model.simulate import sample_times
from .parameters import FitError
from .recording import LimbRecording, MuscleRecording

#: Evaluations a fit is expected to take, to judge its runs before it starts:
#: the three-parameter fit of Protocol II takes 6 (BENCHMARKS.md, section 8).
#: Only the choice of engine depends on it, never the result.
EXPECTED_EVALUATIONS = 6


def replay_runs(n_parameters: int) -> int:
    """[-] runs a fit of ``n_parameters`` is expected to ask a replay for: K = n + 1
    per evaluation, :data:`EXPECTED_EVALUATIONS` evaluations."""
    return (n_parameters + 1) * EXPECTED_EVALUATIONS


#: Column of the force in a muscle's output rows.
_FORCE = MuscleOutputs._fields.index('force_n')


class MuscleReplay:
    """The recorded inputs replayed through the muscle, for any parameters.

    Every run takes the build of the one engine that
    :func:`~hill_muscle_ros.model.engine.kernels` chooses (compiled where numba
    is), one build for every run of a fit.

    :param recording: the inputs and the force samples to predict
    :param runs: [-] runs the caller expects to ask for in all (:func:`replay_runs`),
        for its reports
    """

    def __init__(self, recording: MuscleRecording, runs: int = 1) -> None:
        self.recording = recording
        self.runs = runs
        self.dt_s = 1.0 / recording.rate_hz
        self._dl_end = recording.dl_mt_m[1:]

    def compiled(self, fes: bool = False) -> bool:
        """Whether the runs take the compiled build (loading it here if so).

        :param fes: kept for callers; every muscle runs the same engine
        """
        from ...model import engine
        from ...model.muscle import kernels as muscle_kernels
        if engine.choice() != engine.COMPILED:
            return False
        muscle_kernels.compiled()
        return True

    def commands(self, params: MuscleParams, stimulation: np.ndarray | None = None
                 ) -> np.ndarray:
        """[-] the command u at each grid instant: the recruitment itself, or the
        pulse width through the muscle's recruitment curve.

        :param stimulation: in place of the recorded one (its kind), if given
        """
        if stimulation is None:
            stimulation = self.recording.stimulation
        if self.recording.stimulation_kind == 'recruitment':
            return stimulation
        return commands_from_pulse_widths(stimulation, params)

    def _start(self, params: MuscleParams, u: np.ndarray, force: np.ndarray) -> Muscle:
        """The muscle at rest given ``u[0]``, its force written to ``force[0]``."""
        muscle = Muscle(params)
        muscle.set_recruitment(float(u[0]))
        force[0] = muscle.outputs().force_n
        return muscle

    def _run(self, muscle: Muscle, u: np.ndarray, first: int, stop: int,
             force: np.ndarray) -> None:
        """Steps ``first`` to ``stop`` - 1, the force after step k written to
        ``force[k + 1]``."""
        # As the simulator node: a command acts from the step after it, so a
        # release to zero shows one sample later than in `simulate`'s own table.
        rows = muscle.run_array(u[first:stop], self._dl_end[first:stop], self.dt_s)
        force[first + 1:stop + 1] = rows[:, _FORCE]

    def force(self, params: MuscleParams, fes: bool = False) -> np.ndarray:
        """[N] the force at every grid instant, from rest.

        :param fes: kept for callers; every muscle runs the same engine
        """
        u = np.asarray(self.commands(params), dtype=float)
        force = np.empty(len(u))
        self._run(self._start(params, u, force), u, 0, len(u) - 1, force)
        return force

    def predict(self, params: Sequence[MuscleParams]) -> np.ndarray:
        """[N] the force at the recorded samples, one row per parameter set."""
        index = self.recording.sample_index
        return np.array([self.force(p)[index] for p in params])

    def checkpoint(self, params: MuscleParams, steps: int) -> 'ReplayCheckpoint':
        """The first ``steps`` steps replayed once with ``params``, for replays of
        stimulations that change only later commands (:class:`ReplayCheckpoint`).

        :param steps: [-] steps to run now, in [1, samples - 1]
        :raises ValueError: for ``steps`` outside that range
        """
        return ReplayCheckpoint(self, params, steps)


class ReplayCheckpoint:
    """A replay's first steps run once and the muscle saved after them, for
    replays of stimulations that give the same commands over those steps.

    The edge search (:func:`~.edges.align_stimulation_edges`) tries every move
    of one stimulation change, and the moves differ only from a few steps
    before it: replayed from rest, each would run the steps before the change
    again (measured: moves within ±0.1 s on Protocol II's bag with its change
    stamped 5 ms late, the fit took 2.5 CPU-s instead of 4.2). Each
    :meth:`predict` goes on from a copy of the saved muscle
    (``copy.deepcopy``), which steps on exactly as the muscle would have, so
    its forces are those of a replay from rest to the last bit.

    :param replay: the recording's replay, its stimulation the one the saved
        steps take
    :param params: the muscle's parameters
    :param steps: [-] steps to run now, in [1, samples - 1]
    :raises ValueError: for ``steps`` outside that range
    """

    def __init__(self, replay: MuscleReplay, params: MuscleParams, steps: int) -> None:
        n = len(replay.recording.stimulation)
        if isinstance(steps, bool) or not isinstance(steps, (int, np.integer)) \
                or not 1 <= steps <= n - 1:
            raise ValueError(f'`steps` must be an integer in [1, {n - 1}], got {steps!r}')
        self.replay = replay
        self.params = params
        self.steps = int(steps)
        self._u = np.asarray(replay.commands(params), dtype=float)
        self._force = np.empty(n)
        self._muscle = replay._start(params, self._u, self._force)
        replay._run(self._muscle, self._u, 0, self.steps, self._force)

    def predict(self, stimulation: np.ndarray) -> np.ndarray:
        """[N] the force at the recorded samples with ``stimulation`` in place of
        the recorded one: :meth:`MuscleReplay.predict`'s row for it.

        :param stimulation: as the recording's (kind, length), giving the same
            commands over the saved steps (step k gives command k)
        :raises ValueError: if its length differs, or it changes a saved step's command
        """
        n = len(self._force)
        if len(stimulation) != n:
            raise ValueError(f"`stimulation` must have the recording's {n} entries, "
                             f'got {len(stimulation)}')
        u = np.asarray(self.replay.commands(self.params, stimulation), dtype=float)
        changed = np.flatnonzero(u[:self.steps] != self._u[:self.steps])
        if len(changed):
            raise ValueError(f'`stimulation` must give the recorded commands over the first '
                             f'{self.steps} steps, it changes step {changed[0]}')
        force = self._force.copy()
        self.replay._run(copy.deepcopy(self._muscle), u, self.steps, n - 1, force)
        return force[self.replay.recording.sample_index]


def _held_knots(values: np.ndarray, t_s: np.ndarray) -> Knots:
    """Knots that give ``values[k]`` at ``t_s[k]`` and hold it to the next instant:
    a repeated time at each change is a step (the later knot wins there)."""
    change = np.flatnonzero(values[1:] != values[:-1]) + 1
    times = np.concatenate(([t_s[0]], np.repeat(t_s[change], 2), [t_s[-1]]))
    held = np.empty(2 * len(change))
    held[0::2], held[1::2] = values[change - 1], values[change]
    return Knots(times, np.concatenate(([values[0]], held, [values[-1]])))


#: A worker process's replay: (protocol, rate [Hz], sample indices), set once by
#: :func:`_limb_worker_init` so that each task sends only its plant.
_LIMB_WORKER: tuple | None = None


def _limb_worker_init(protocol: LimbProtocol, rate_hz: float, index: np.ndarray) -> None:
    global _LIMB_WORKER
    _LIMB_WORKER = (protocol, rate_hz, index)


def _limb_worker_angle(plant: LimbPlant) -> np.ndarray:
    protocol, rate_hz, index = _LIMB_WORKER
    return simulate_limb(plant, protocol, rate_hz)['theta_rad'][index]


class LimbReplay:
    """The recorded stimulation replayed through the limb
    (:func:`~hill_muscle_ros.model.limb.simulate_limb`), for any plant.

    The recording becomes a limb protocol on the grid's instants: each step holds
    the stimulation and torque of its start, as the limb node does, and the angle
    of step k is the state after it, as ``joint_states`` shows it.

    With ``jobs`` > 1 the plants of one :meth:`predict` (an evaluation's n + 1)
    run in that many worker processes (forked once, kept until :meth:`close`);
    each run is the same computation, so the angles are identical to one process's.

    :param recording: the inputs and the joint angles to predict
    :param jobs: worker processes, >= 1
    """

    def __init__(self, recording: LimbRecording, jobs: int = 1) -> None:
        if isinstance(jobs, bool) or not isinstance(jobs, int) or jobs < 1:
            raise ValueError(f'`jobs` must be a positive integer, got {jobs!r}')
        self.jobs = jobs
        self._pool = None
        self.recording = recording
        n = len(recording.external_torque_n_m)
        t = sample_times((n - 1) / recording.rate_hz, recording.rate_hz)
        stimulation = {
            name: ('recruitment' if recording.stimulation_kind[name] == 'recruitment'
                   else 'pulse_width_s', _held_knots(values, t))
            for name, values in recording.stimulation.items()}
        self.protocol = LimbProtocol(f'recording {recording.bag}', float(t[-1]), stimulation,
                                     _held_knots(recording.external_torque_n_m, t))

    def angle(self, plant: LimbPlant) -> np.ndarray:
        """[rad] the joint angle at every grid instant, from the plant's initial state."""
        return simulate_limb(plant, self.protocol, self.recording.rate_hz)['theta_rad']

    def predict(self, plants: Sequence[LimbPlant]) -> np.ndarray:
        """[rad] the joint angle at the recorded samples, one row per plant."""
        from ...model import engine
        from ...model.limb import kernels as limb_kernels
        index = self.recording.sample_index
        # The compiled limb is loaded here, before any worker forks, so that
        # forked workers have it (simulate_limb would load it in each).
        if engine.choice() == engine.COMPILED:
            limb_kernels.compiled()
        try:
            if self.jobs > 1 and len(plants) > 1:
                return np.array(list(self._workers().map(_limb_worker_angle, plants)))
            return np.array([self.angle(p)[index] for p in plants])
        except ValueError as err:   # a muscle driven beyond its length range
            raise FitError(f'the fit reached a plant the recording drives out of range: '
                           f'{err}') from None

    def _workers(self):
        if self._pool is None:
            import multiprocessing
            from concurrent.futures import ProcessPoolExecutor
            # fork: the workers start with the recording in memory, nothing to import.
            self._pool = ProcessPoolExecutor(
                self.jobs, mp_context=multiprocessing.get_context('fork'),
                initializer=_limb_worker_init,
                initargs=(self.protocol, self.recording.rate_hz, self.recording.sample_index))
        return self._pool

    def close(self) -> None:
        """Stop the worker processes, if any."""
        if self._pool is not None:
            self._pool.shutdown()
            self._pool = None

    def __enter__(self) -> 'LimbReplay':
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()
