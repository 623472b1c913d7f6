"""``hill_muscle_ros/ForceTracking-v0``: track a force target with one stimulated
muscle whose length is imposed.

The muscle is :class:`~hill_muscle_ros.model.muscle.Muscle` (the FES engine
when the parameters switch on an FES feature); the pulse width goes through
:func:`~hill_muscle_ros.model.stimulus.command_from_pulse_width`. Nothing here
writes a model equation.
"""
from __future__ import annotations

import math
from typing import Any

import numpy as np
from gymnasium import spaces

from ..model.muscle import DL_MT_LIMIT_M, Muscle
from ..model.params import MuscleParams
from ..model.stimulus import command_from_pulse_width
from ._common import (MODEL_DT_S, TrackingEnv, check_positive, check_pulse_widths,
                      hold_lengths, muscle_params, piecewise_constant)

#: Signals of one history sample, in order: [N] force, [N] target, [m] CE
#: length, [m] MTU length change (the length command).
SAMPLE_FIELDS = ('force_n', 'target_n', 'l_ce_m', 'dl_mt_m')
#: Index of the muscle force f_SE + f_PE among the twelve output columns of
#: :meth:`Muscle.run <hill_muscle_ros.model.muscle.Muscle.run>` (MuscleOutputs order).
_FORCE_COLUMN = 8
_L_CE_COLUMN = 4
_FITNESS_COLUMN = 11
_N_COLUMNS = 12


class ForceTrackingEnv(TrackingEnv):
    """Track a piecewise-constant force target by choosing the pulse width.

    **Time.** Every :meth:`step` holds one pulse width for one control period
    (``control_period_s``, 10-50 ms); inside it the muscle steps at 1 kHz
    (:data:`~hill_muscle_ros.gym._common.MODEL_DT_S`) while its MTU length
    follows the episode's length profile.

    **Action.** ``[PW]``: the pulse width [s], a ``Box(0, pw_max_s, (1,))``
    (float32). A NaN or a width outside the Box raises ``ValueError``; nothing
    is clipped (a silently clipped command would hide a policy's bug). Wrap the
    environment in ``gymnasium.wrappers.ClipAction`` if clipping is wanted;
    most RL libraries clip to the Box themselves.

    **Observation** (float32, SI). The ``history_length`` most recent samples,
    newest first, each ``(force [N], target [N], l_CE [m], dl_MT [m])``: the
    sample taken at the current control instant and those of the
    ``history_length - 1`` instants before it (the default 5 covers the last
    4 control periods, 80 ms at 20 ms). At reset every slot holds the resting
    sample. The target is the one that holds over the coming period. With
    fatigue on (``fatigue: riener``), or ``observe_fitness=True``, one more
    entry follows: the mean fitness of the units [-], 1 for a fresh muscle
    (and always 1 without fatigue).

    **Reward** (dimensionless), for the period just simulated with pulse width
    PW and target F*::

        r = -(1/N) sum_j ((F_j - F*) / f_iso_max)^2  -  stim_cost (PW / PW_max)^2

    with F_j [N] the muscle force at the end of each of the N model steps of
    the period, f_iso_max [N] and PW_max [s] the muscle's parameters. So r <= 0,
    and r = 0 only with the target met at every millisecond and no stimulation.

    **Episode.** Drawn at :meth:`reset` from ``self.np_random`` (seed it with
    ``reset(seed=...)``): holds of ``hold_min_s`` to ``hold_max_s`` (whole
    control periods); on each hold a target uniform in ``[0, target_max_fraction
    f_iso_max]`` and an MTU length knot uniform in ``[0, length_max_m]`` at the
    hold's start, dl_MT ramping linearly from knot to knot (from 0 at t = 0,
    the resting state, to the last knot at the end). ``length_max_m = 0`` is an
    isometric episode. ``reset(options={'target_n': F})`` holds the target at F
    [N] for the whole episode instead. The episode is truncated after
    ``episode_duration_s``; it never terminates.

    :param params: the muscle: a :class:`~hill_muscle_ros.model.params.MuscleParams`,
        a parameters YAML file (``config/muscle.yaml``,
        ``config/fes_quadriceps.yaml``) or ``None`` for the paper's muscle
    :param units: [-] variant override: ``multi`` or ``single`` (``None``: as ``params``)
    :param length: [-] variant override: ``initial`` or ``instantaneous``
    :param fes_features: ``False`` switches every FES extension of the muscle's
        dynamics off (delay, activation, ``fv_scaling``, fatigue, fibre types,
        recruitment order, unit length spread), the recruitment curve kept:
        the paper's dynamics on the same muscle
    :param overrides: any :class:`MuscleParams` fields by name, applied last
        (``{'fatigue': 'riener', 'tau_act_s': 0.025}``)
    :param observe_fitness: append the mean fitness to the observation;
        ``None``: when fatigue is on. Set it ``True`` to train without fatigue
        and test with it on the same observation space.
    :param control_period_s: [s] control period, 0.010-0.050, whole milliseconds
    :param episode_duration_s: [s] episode length, a whole number of periods
    :param history_length: [-] samples of each signal in the observation, >= 1
    :param stim_cost: [-] weight of the stimulation term, >= 0
    :param target_max_fraction: [-] largest target as a fraction of f_iso_max, in (0, 1]
    :param length_max_m: [m] largest MTU stretch of the length profile, >= 0
    :param hold_min_s: [s] shortest hold of a target
    :param hold_max_s: [s] longest hold of a target
    :param render_mode: only ``None`` (no rendering)
    """

    TARGET_OPTION = 'target_n'

    def __init__(self, params: MuscleParams | str | None = None, *, units: str | None = None,
                 length: str | None = None, fes_features: bool = True,
                 overrides: dict[str, Any] | None = None, observe_fitness: bool | None = None,
                 control_period_s: float = 0.02, episode_duration_s: float = 5.0,
                 history_length: int = 5, stim_cost: float = 0.01,
                 target_max_fraction: float = 0.5, length_max_m: float = 0.01,
                 hold_min_s: float = 0.5, hold_max_s: float = 1.5,
                 render_mode: str | None = None) -> None:
        self._init_episode(control_period_s=control_period_s,
                           episode_duration_s=episode_duration_s,
                           history_length=history_length, stim_cost=stim_cost,
                           hold_min_s=hold_min_s, hold_max_s=hold_max_s,
                           render_mode=render_mode, width=len(SAMPLE_FIELDS))
        self.params = p = muscle_params(params, units, length, fes_features, overrides)
        frac = check_positive('target_max_fraction', target_max_fraction)
        if frac > 1.0:
            raise ValueError(f'`target_max_fraction` must be in (0, 1], '
                             f'got {target_max_fraction!r}')
        self.target_max_n = frac * p.f_iso_max_n
        self.length_max_m = check_positive('length_max_m', length_max_m, allow_zero=True)
        if self.length_max_m > DL_MT_LIMIT_M:
            raise ValueError(f'`length_max_m` must be at most {DL_MT_LIMIT_M} m, '
                             f'got {length_max_m!r}')
        if observe_fitness is not None and not isinstance(observe_fitness, bool):
            raise ValueError(f'`observe_fitness` must be True, False or None, '
                             f'got {observe_fitness!r}')
        #: whether the observation ends with the mean fitness
        self.observe_fitness = (p.fatigue != 'none' if observe_fitness is None
                                else observe_fitness)

        self.muscle = Muscle(p)
        self.action_space = spaces.Box(0.0, p.pw_max_s, shape=(1,), dtype=np.float32)
        #: what the action entry is, for error messages
        self.action_labels = ('pulse width',)
        self._pw_max = np.array([p.pw_max_s])
        #: [s] the widest accepted width: the Box's float32 bound, read back
        self._pw_high = self.action_space.high.astype(np.float64)
        low = np.tile([0.0, 0.0, -np.inf, -DL_MT_LIMIT_M], self.history_length)
        high = np.tile([np.inf, self.target_max_n, np.inf, DL_MT_LIMIT_M], self.history_length)
        if self.observe_fitness:
            low, high = np.append(low, 0.0), np.append(high, 1.0)
        self.observation_space = spaces.Box(low.astype(np.float32), high.astype(np.float32),
                                            dtype=np.float32)
        self._columns = [[0.0] * self.n_steps for _ in range(_N_COLUMNS)]
        self._dl = np.zeros(self.n_periods * self.n_steps + 1)
        self._fitness = 1.0

    # -- episode ---------------------------------------------------------------------

    def draw_episode(self, rng: np.random.Generator,
                     fixed: float | None) -> tuple[np.ndarray, np.ndarray]:
        """One episode's profiles (see the class docstring, *Episode*).

        :param rng: the episode's generator (``self.np_random``, or a vector
            environment's generator of this sub-environment)
        :param fixed: [N] a target for the whole episode, or ``None``
        :return: [N] the target of every control period and [m] dl_MT at every
            model step boundary (``n_periods * n_steps + 1`` values, 0 first)
        """
        n_periods, n_steps = self.n_periods, self.n_steps
        starts = hold_lengths(rng, n_periods, *self._hold)
        targets = rng.uniform(0.0, self.target_max_n, size=len(starts))
        knots = rng.uniform(0.0, self.length_max_m, size=len(starts))
        per_period = piecewise_constant(starts, targets, n_periods)
        if fixed is not None:
            per_period[:] = fixed
        # dl_MT: 0 at t = 0, then knot i at the start of hold i + 1, the last
        # knot at the episode's end; linear in between, sampled every model step.
        knot_steps = np.append(starts[1:], n_periods) * n_steps
        dl = np.interp(np.arange(n_periods * n_steps + 1), np.append(0, knot_steps),
                       np.append(0.0, knots))
        return per_period, dl

    def check_target(self, target_n: Any) -> float:
        """A fixed target from ``reset`` options, validated.

        :param target_n: [N] in [0, target_max_fraction f_iso_max]
        """
        t = check_positive('target_n', target_n, allow_zero=True)
        if t > self.target_max_n:
            raise ValueError(f'`target_n` must be at most {self.target_max_n:g} N '
                             f'(target_max_fraction f_iso_max), got {target_n!r}')
        return t

    def reset(self, *, seed: int | None = None,
              options: dict[str, Any] | None = None) -> tuple[np.ndarray, dict]:
        """Start an episode: the muscle at rest, new profiles drawn.

        :param seed: seeds ``self.np_random`` (same seed: same episode)
        :param options: ``{'target_n': F}`` holds the target at F [N], in
            [0, target_max_fraction f_iso_max]
        """
        super().reset(seed=seed)
        self._targets, self._dl = self.draw_episode(self.np_random, self.fixed_target(options))
        self.muscle.reset()
        self._k = 0
        out = self.muscle.outputs()
        self._fitness = out.mean_fitness
        self._history.fill((out.force_n, self._targets[0], out.l_ce_m, out.dl_mt_m))
        return self._observation(), self._info(0.0, 0.0, 0.0)

    def step(self, action) -> tuple[np.ndarray, float, bool, bool, dict]:
        """Hold pulse width ``action[0]`` [s] for one control period.

        :raises ValueError: on a NaN or out-of-Box width (the state is unchanged),
            or a step after the episode's end
        """
        self._check_running()
        widths = check_pulse_widths(action, self._pw_high, self.action_labels, 'action')
        pw = float(widths[0])
        u = command_from_pulse_width(pw, self.params)
        n, k = self.n_steps, self._k
        target = float(self._targets[k])
        dl = self._dl[k * n + 1:(k + 1) * n + 1].tolist()
        cols = self._columns
        self.muscle.run([u] * n, dl, MODEL_DT_S, None, cols)
        f_ref = self.params.f_iso_max_n
        tracking = math.fsum(((f - target) / f_ref) ** 2 for f in cols[_FORCE_COLUMN]) / n
        stimulation = float(self.stimulation_cost(widths))
        self._k = k = k + 1
        self._fitness = cols[_FITNESS_COLUMN][-1]
        self._history.push((cols[_FORCE_COLUMN][-1], self._target_after(k),
                            cols[_L_CE_COLUMN][-1], dl[-1]))
        reward = -tracking - stimulation
        truncated = k >= self.n_periods
        return self._observation(), reward, False, truncated, self._info(pw, tracking,
                                                                         stimulation)

    def _observation(self) -> np.ndarray:
        obs = self._history.flat()
        if self.observe_fitness:
            obs = np.append(obs, self._fitness)
        return obs.astype(np.float32)

    def _info(self, pw: float, tracking: float, stimulation: float) -> dict:
        """Float64 values the float32 observation rounds, and the reward's two terms."""
        return {'t_s': self._k * self.control_period_s, 'pulse_width_s': pw,
                'target_n': self._target_after(self._k),
                'force_n': float(self._history.newest[0]),
                'dl_mt_m': float(self._history.newest[3]),
                'tracking_cost': tracking, 'stimulation_cost': stimulation}
