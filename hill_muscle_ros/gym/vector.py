"""The native vector forms of both environments: K episodes stepped together.

``gymnasium.make_vec(id, num_envs=K)`` makes them. Sub-environment i behaves
as the single environment seeded with ``seed + i`` (gymnasium's convention for
an integer seed): the same episodes bit for bit, since both draw them with the
single environment's :meth:`~._common.TrackingEnv.draw_episode` from a
generator seeded alike.

- :class:`ForceTrackingVectorEnv` steps the K muscles on
  :class:`~hill_muscle_ros.model.muscle.batch.MuscleBatch`: the same muscle to the
  batch engine's agreement with the scalar one (1e-9 N,
  ``test/test_model_batch.py``).
- :class:`KneeAngleVectorEnv` steps the K limbs on
  :class:`~hill_muscle_ros.model.limb.LimbBatch`, each a
  :class:`~hill_muscle_ros.model.limb.Limb` on the single environment's build
  of the kernels, by its own call of the same kernels: identical
  trajectories, bit for bit. The limb batch has no
  vectorised path, so this brings the vector API, the shared autoreset and
  one call per limb and model step instead of SyncVectorEnv's Python around
  each environment.
"""
from __future__ import annotations

from typing import Any

import numpy as np
from gymnasium.utils import seeding
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from ..model.muscle.batch import MuscleBatch
from ..model.limb import LimbBatch
from ..model.protocol import commands_from_pulse_widths
from ._common import MODEL_DT_S, History, TrackingEnv, check_pulse_widths
from .force_tracking import SAMPLE_FIELDS as FORCE_FIELDS
from .force_tracking import ForceTrackingEnv
from .knee_angle import SAMPLE_FIELDS as KNEE_FIELDS
from .knee_angle import KneeAngleEnv


class TrackingVectorEnv(VectorEnv):
    """K episodes of one tracking environment with the same settings.

    Every keyword argument is the single environment's; spaces, reward,
    bad-action errors and episodes are the same, per sub-environment. Episodes
    all last ``episode_duration_s`` and never terminate, so the K
    sub-environments end together; the step after the end resets them all
    (gymnasium's ``NEXT_STEP`` autoreset: that step ignores the actions and
    returns the first observations with reward 0), each drawing its next
    episode from its own generator, as a single environment's ``reset()``
    without a seed does. ``info`` holds the reward's two terms per
    sub-environment, ``tracking_cost`` and ``stimulation_cost``.

    Subclasses set :attr:`single_env` and write the engine's part:
    :meth:`_set_episode`, :meth:`_restart_engines` and :meth:`_advance`.

    :param num_envs: [-] K, >= 1
    """

    metadata = {'render_modes': [], 'autoreset_mode': AutoresetMode.NEXT_STEP}
    #: The single environment's class.
    single_env: type[TrackingEnv] = TrackingEnv
    #: The signals of one history sample (the single environment's).
    sample_fields: tuple[str, ...] = ()

    def __init__(self, num_envs: int = 1, **kwargs: Any) -> None:
        if isinstance(num_envs, bool) or not isinstance(num_envs, (int, np.integer)) \
                or num_envs < 1:
            raise ValueError(f'`num_envs` must be an integer >= 1, got {num_envs!r}')
        #: the settings of every sub-environment, validated by the single env
        self.template = t = self.single_env(**kwargs)
        self.num_envs = k = int(num_envs)
        self.render_mode = None
        self.single_action_space = t.action_space
        self.single_observation_space = t.observation_space
        self.action_space = batch_space(t.action_space, k)
        self.observation_space = batch_space(t.observation_space, k)
        self._rngs: list[np.random.Generator | None] = [None] * k
        self._history = History(t.history_length, len(self.sample_fields), batch=k)
        self._targets = np.zeros((k, t.n_periods))
        self._k = 0
        self._needs_reset = False

    # -- episodes --------------------------------------------------------------------

    def _seed_rngs(self, seed: int | list | None) -> None:
        k = self.num_envs
        if seed is None:
            seeds = [None] * k
        elif isinstance(seed, (int, np.integer)):
            seeds = [int(seed) + i for i in range(k)]
        else:
            seeds = list(seed)
            if len(seeds) != k:
                raise ValueError(f'`seed` must be an int or {k} seeds, got {len(seeds)}')
        for i, s in enumerate(seeds):
            if s is not None or self._rngs[i] is None:
                self._rngs[i], _ = seeding.np_random(s)

    def _draw(self, fixed: float | None) -> None:
        for i, rng in enumerate(self._rngs):
            self._set_episode(i, self.template.draw_episode(rng, fixed))

    def reset(self, *, seed: int | list | None = None,
              options: dict[str, Any] | None = None) -> tuple[np.ndarray, dict]:
        """Start K episodes; ``seed`` an int (sub-env i gets ``seed + i``) or K seeds.

        :param options: the single environment's (``{'target_n': F}``,
            ``{'target_rad': x}``): every sub-environment holds that target
        """
        fixed = self.template.fixed_target(options)
        self._seed_rngs(seed)
        self._draw(fixed)
        return self._restart(), {}

    def _restart(self) -> np.ndarray:
        self._k = 0
        self._needs_reset = False
        self._history.fill(self._restart_engines())
        return self._observation()

    # -- stepping --------------------------------------------------------------------

    def step(self, actions) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict]:
        """One control period of every sub-environment (see the class docstring).

        :raises ValueError: on a NaN or out-of-Box width, naming the
            sub-environment (and the muscle); the state is unchanged
        """
        t, k_envs = self.template, self.num_envs
        pw = check_pulse_widths(actions, t._pw_high, t.action_labels, 'actions', rows=k_envs)
        no = np.zeros(k_envs, dtype=bool)
        if self._needs_reset:   # NEXT_STEP autoreset: new episodes from the same generators
            self._draw(None)
            return self._restart(), np.zeros(k_envs), no, no.copy(), {}
        k = self._k
        next_target = self._targets[:, min(k + 1, t.n_periods - 1)]
        tracking, sample = self._advance(pw, k, next_target)
        stimulation = t.stimulation_cost(pw)
        self._k = k = k + 1
        self._history.push(sample)
        truncated = np.full(k_envs, k >= t.n_periods)
        self._needs_reset = bool(truncated[0])
        info = {'tracking_cost': tracking, 'stimulation_cost': stimulation}
        return self._observation(), -tracking - stimulation, no, truncated, info

    def _observation(self) -> np.ndarray:
        return self._history.flat().astype(np.float32)

    # -- the engine: in the subclasses -------------------------------------------------

    def _set_episode(self, i: int, episode: Any) -> None:
        """Keep sub-environment ``i``'s episode, as ``draw_episode`` gives it."""
        raise NotImplementedError

    def _restart_engines(self) -> np.ndarray:
        """Every plant at rest; the first history sample, shape (K, width)."""
        raise NotImplementedError

    def _advance(self, pw: np.ndarray, k: int,
                 next_target: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Step every plant through control period ``k`` with widths ``pw`` (K, M).

        :param next_target: the target of period k + 1, per sub-environment
        :return: the tracking term per sub-environment and the newest history
            sample, shape (K, width)
        """
        raise NotImplementedError


class ForceTrackingVectorEnv(TrackingVectorEnv):
    """K force-tracking episodes (:class:`~.force_tracking.ForceTrackingEnv`'s
    keyword arguments), the K muscles on one :class:`MuscleBatch`."""

    single_env = ForceTrackingEnv
    sample_fields = FORCE_FIELDS

    def __init__(self, num_envs: int = 1, **kwargs: Any) -> None:
        super().__init__(num_envs, **kwargs)
        t = self.template
        self.params = t.params
        self.batch = MuscleBatch([t.params] * self.num_envs)
        # [m] dl_MT at every model step boundary (rows) of every sub-environment
        # (columns): a step reads one contiguous row.
        self._dl = np.zeros((t.n_periods * t.n_steps + 1, self.num_envs))
        self._fitness = np.ones(self.num_envs)
        #: [N] every sub-environment's force at each model step of a period
        self._forces = np.zeros((t.n_steps, self.num_envs))

    def _set_episode(self, i: int, episode: tuple[np.ndarray, np.ndarray]) -> None:
        self._targets[i], self._dl[:, i] = episode

    def _restart_engines(self) -> np.ndarray:
        self.batch.reset()
        out = self.batch.outputs()
        self._fitness = out.mean_fitness
        return np.stack([out.force_n, self._targets[:, 0], out.l_ce_m, out.dl_mt_m], axis=1)

    def _advance(self, pw: np.ndarray, k: int,
                 next_target: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        p, n = self.params, self.template.n_steps
        u = commands_from_pulse_widths(pw[:, 0], p)
        forces = self._forces
        for i, j in enumerate(range(k * n + 1, (k + 1) * n + 1)):
            out = self.batch.step(u, self._dl[j], MODEL_DT_S)
            forces[i] = out.force_n
        # One whole-array pass for the period, not one per model step.
        errors = (forces - self._targets[:, k]) / p.f_iso_max_n
        self._fitness = out.mean_fitness
        sample = np.stack([out.force_n, next_target, out.l_ce_m, self._dl[(k + 1) * n]],
                          axis=1)
        return np.mean(errors * errors, axis=0), sample

    def _observation(self) -> np.ndarray:
        obs = super()._observation()
        if self.template.observe_fitness:
            obs = np.concatenate([obs, self._fitness[:, None].astype(np.float32)], axis=1)
        return obs


class KneeAngleVectorEnv(TrackingVectorEnv):
    """K knee-angle episodes (:class:`~.knee_angle.KneeAngleEnv`'s keyword
    arguments), the K limbs on one :class:`LimbBatch`."""

    single_env = KneeAngleEnv
    sample_fields = KNEE_FIELDS

    def __init__(self, num_envs: int = 1, **kwargs: Any) -> None:
        super().__init__(num_envs, **kwargs)
        self.batch = LimbBatch([self.template.plant] * self.num_envs,
                               build=self.template.engine)

    def _set_episode(self, i: int, episode: np.ndarray) -> None:
        self._targets[i] = episode

    def _restart_engines(self) -> np.ndarray:
        self.batch.reset()
        out = self.batch.outputs()
        return np.stack([out.theta_rad, out.omega_rad_per_s, self._targets[:, 0]], axis=1)

    def _advance(self, pw: np.ndarray, k: int,
                 next_target: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        n = self.template.n_steps
        u = self.batch.commands_from_pulse_widths(pw)
        # No external torque, as the single environment.
        out, squared = self.batch.hold_commands(u, 0.0, MODEL_DT_S, n, self._targets[:, k])
        sample = np.stack([out.theta_rad, out.omega_rad_per_s, next_target], axis=1)
        return squared / n, sample
