"""The native vector form of ``hill_muscle_ros/ForceTracking-v0``: K episodes
stepped together on :class:`~hill_muscle_ros.model.batch.MuscleBatch`.

``gymnasium.make_vec('hill_muscle_ros/ForceTracking-v0', num_envs=K)`` makes
it. Sub-environment i behaves as a :class:`~.force_tracking.ForceTrackingEnv`
seeded with ``seed + i`` (gymnasium's convention for an integer seed): the
same profiles bit for bit, the same muscle to the batch engine's agreement
with the scalar one (1e-9 N, ``test/test_model_batch.py``).
"""
from __future__ import annotations

from typing import Any

import numpy as np
from gymnasium.utils import seeding
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from ..model.batch import MuscleBatch
from ..model.stimulus import command_from_pulse_width
from ._common import MODEL_DT_S
from .force_tracking import SAMPLE_FIELDS, ForceTrackingEnv, draw_profiles


class ForceTrackingVectorEnv(VectorEnv):
    """K force-tracking episodes with the same settings, one muscle each.

    Every keyword argument is :class:`~.force_tracking.ForceTrackingEnv`'s;
    spaces, reward, bad-action errors and episodes are the same, per
    sub-environment. Episodes all last ``episode_duration_s`` and never
    terminate, so the K sub-environments end together; the step after the end
    resets them all (gymnasium's ``NEXT_STEP`` autoreset: that step ignores
    the actions and returns the first observations with reward 0).

    :param num_envs: [-] K, >= 1
    """

    metadata = {'render_modes': [], 'autoreset_mode': AutoresetMode.NEXT_STEP}

    def __init__(self, num_envs: int = 1, **kwargs: Any) -> None:
        if isinstance(num_envs, bool) or not isinstance(num_envs, (int, np.integer)) \
                or num_envs < 1:
            raise ValueError(f'`num_envs` must be an integer >= 1, got {num_envs!r}')
        #: the settings of every sub-environment, validated by the single env
        self.template = t = ForceTrackingEnv(**kwargs)
        self.num_envs = k = int(num_envs)
        self.render_mode = None
        self.params = t.params
        self.single_action_space = t.action_space
        self.single_observation_space = t.observation_space
        self.action_space = batch_space(t.action_space, k)
        self.observation_space = batch_space(t.observation_space, k)
        self.batch = MuscleBatch([t.params] * k)
        self._rngs: list[np.random.Generator | None] = [None] * k
        self._history = np.zeros((k, t.history_length, len(SAMPLE_FIELDS)))
        self._targets = np.zeros((k, t.n_periods))
        self._dl = np.zeros((k, t.n_periods * t.n_steps + 1))
        self._k = 0
        self._needs_reset = False
        self._pw_high_s = float(t.action_space.high[0])

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

    def reset(self, *, seed: int | list | None = None,
              options: dict[str, Any] | None = None) -> tuple[np.ndarray, dict]:
        """Start K episodes; ``seed`` an int (sub-env i gets ``seed + i``) or K seeds.

        :param options: ``{'target_n': F}``: every sub-environment holds F [N]
        """
        options = dict(options or {})
        target_n = options.pop('target_n', None)
        if options:
            raise ValueError(f'unknown reset options {sorted(options)}; known: target_n')
        if target_n is not None:
            target_n = self.template.check_target(target_n)
        self._seed_rngs(seed)
        for i, rng in enumerate(self._rngs):
            self._targets[i], self._dl[i] = draw_profiles(rng, self.template, target_n)
        return self._restart(), {}

    def _restart(self) -> np.ndarray:
        self.batch.reset()
        self._k = 0
        self._needs_reset = False
        out = self.batch.outputs()
        sample = np.stack([out.force_n, self._targets[:, 0], out.l_ce_m, out.dl_mt_m], axis=1)
        self._history[:] = sample[:, None, :]
        return self._observation(out.mean_fitness)

    def _check_actions(self, actions) -> np.ndarray:
        a = np.asarray(actions, dtype=np.float64)
        if a.size != self.num_envs:
            raise ValueError(f'`actions` must hold one pulse width [s] per environment '
                             f'({self.num_envs}), got shape {a.shape}')
        pw = a.reshape(-1)
        bad = ~((pw >= 0.0) & (pw <= self._pw_high_s))   # also true for NaN
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            raise ValueError(f'`actions[{i}]` (pulse width) must be in '
                             f'[0, {self._pw_high_s:g}] s, got {pw[i]!r}')
        return pw

    def step(self, actions) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict]:
        """One control period of every sub-environment (see the class docstring)."""
        t, k_envs = self.template, self.num_envs
        pw = self._check_actions(actions)
        if self._needs_reset:   # NEXT_STEP autoreset: new episodes from the same generators
            for i, rng in enumerate(self._rngs):
                self._targets[i], self._dl[i] = draw_profiles(rng, t, None)
            obs = self._restart()
            zeros = np.zeros(k_envs, dtype=bool)
            return obs, np.zeros(k_envs), zeros, zeros.copy(), {}
        u = np.array([command_from_pulse_width(w, self.params) for w in pw.tolist()])
        n, k = t.n_steps, self._k
        target = self._targets[:, k]
        f_ref = self.params.f_iso_max_n
        squared = np.zeros(k_envs)
        for j in range(k * n + 1, (k + 1) * n + 1):
            out = self.batch.step(u, self._dl[:, j], MODEL_DT_S)
            squared += ((out.force_n - target) / f_ref) ** 2
        tracking = squared / n
        stimulation = t.stim_cost * (pw / self.params.pw_max_s) ** 2
        self._k = k = k + 1
        next_target = self._targets[:, min(k, t.n_periods - 1)]
        self._history[:, 1:] = self._history[:, :-1]
        self._history[:, 0] = np.stack([out.force_n, next_target, out.l_ce_m,
                                        self._dl[:, k * n]], axis=1)
        truncated = np.full(k_envs, k >= t.n_periods)
        self._needs_reset = bool(truncated[0])
        info = {'tracking_cost': tracking, 'stimulation_cost': stimulation}
        return (self._observation(out.mean_fitness), -tracking - stimulation,
                np.zeros(k_envs, dtype=bool), truncated, info)

    def _observation(self, fitness: np.ndarray) -> np.ndarray:
        obs = self._history.reshape(self.num_envs, -1)
        if self.template.fatigue:
            obs = np.concatenate([obs, np.asarray(fitness)[:, None]], axis=1)
        return obs.astype(np.float32)
