"""``hill_muscle_ros/KneeAngle-v0``: track a knee angle with the stimulated
quadriceps and hamstrings of the knee preset.

The plant is :class:`~hill_muscle_ros.model.limb.Limb` on ``config/knee.yaml``
(or any plant file or :class:`~hill_muscle_ros.model.limb.LimbPlant`); each
muscle's pulse width goes through its own recruitment curve
(:func:`~hill_muscle_ros.model.stimulus.command_from_pulse_width`). Nothing
here writes a model equation.
"""
from __future__ import annotations

import math
import os
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from ..model.limb import Limb, LimbPlant
from ..model.stimulus import command_from_pulse_width
from ._common import (MODEL_DT_S, History, check_count, check_hold_range, check_positive,
                      hold_lengths, piecewise_constant, steps_per_period, whole_multiple)

#: Signals of one history sample, in order: [rad] angle, [rad/s] angular
#: velocity, [rad] target angle.
SAMPLE_FIELDS = ('theta_rad', 'omega_rad_per_s', 'target_rad')
#: [rad] Default target range, 10 to 55 deg from hanging: around the 20-45 deg
#: targets that the joint-angle controller's tests and demo hold on this preset.
DEFAULT_ANGLE_MIN_RAD = math.radians(10.0)
DEFAULT_ANGLE_MAX_RAD = math.radians(55.0)


def load_knee_plant(plant: LimbPlant | str | os.PathLike | None) -> LimbPlant:
    """A plant from a :class:`LimbPlant`, a plant YAML file or ``None`` (``config/knee.yaml``).

    :raises ValueError: naming the file and the key on any defect
    """
    if isinstance(plant, LimbPlant):
        return plant
    from ..params_file import load_plant
    if plant is None:
        from ..resources import config_dir
        plant = config_dir() / 'knee.yaml'
    elif not isinstance(plant, (str, os.PathLike)):
        raise ValueError(f'`plant` must be a LimbPlant, a YAML path or None, got {plant!r}')
    return load_plant(plant)[0]


class KneeAngleEnv(gym.Env):
    """Track a piecewise-constant joint angle by choosing each muscle's pulse width.

    **Time.** Every :meth:`step` holds the pulse widths for one control period
    (``control_period_s``, 10-50 ms); inside it the limb steps at 1 kHz with
    no external torque.

    **Action.** One pulse width [s] per muscle, in the plant's order (knee:
    quadriceps, hamstrings), a float32 ``Box(0, pw_max_s of each muscle)``. A
    NaN or a width outside the Box raises ``ValueError``; nothing is clipped
    (use ``gymnasium.wrappers.ClipAction`` for that).

    **Observation** (float32, SI). The ``history_length`` most recent samples,
    newest first, each ``(theta [rad], omega [rad/s], target [rad])``: the
    current control instant and the ``history_length - 1`` before it (default
    5: the last 4 periods). theta is the shank's angle from hanging, positive
    in extension. At reset every slot holds the resting sample; the target is
    the one for the coming period.

    **Reward**, for the period just simulated with widths PW_i and target
    theta*::

        r = -(1/N) sum_j (theta_j - theta*)^2  -  stim_cost (1/M) sum_i (PW_i / PW_max,i)^2

    with theta_j [rad] at the end of each of the N model steps and M muscles:
    the first term in rad^2, the second dimensionless. r <= 0.

    **Episode.** From ``self.np_random`` at :meth:`reset`: holds of
    ``hold_min_s`` to ``hold_max_s`` (whole periods), each with a target uniform
    in ``[angle_min_rad, angle_max_rad]``; ``reset(options={'target_rad': x})``
    holds x instead. The knee starts at rest (the plant's initial angle,
    nothing recruited). Truncated after ``episode_duration_s``; never
    terminated.

    :param plant: a :class:`LimbPlant`, a plant YAML file, or ``None`` for ``config/knee.yaml``
    :param control_period_s: [s] control period, 0.010-0.050, whole milliseconds
    :param episode_duration_s: [s] episode length, a whole number of periods
    :param history_length: [-] samples of each signal in the observation, >= 1
    :param stim_cost: [rad^2] weight of the stimulation term, >= 0
    :param angle_min_rad: [rad] smallest target
    :param angle_max_rad: [rad] largest target
    :param hold_min_s: [s] shortest hold of a target
    :param hold_max_s: [s] longest hold of a target
    :param render_mode: only ``None`` (no rendering)
    """

    metadata = {'render_modes': []}

    def __init__(self, plant: LimbPlant | str | None = None, *, control_period_s: float = 0.02,
                 episode_duration_s: float = 6.0, history_length: int = 5,
                 stim_cost: float = 0.01, angle_min_rad: float = DEFAULT_ANGLE_MIN_RAD,
                 angle_max_rad: float = DEFAULT_ANGLE_MAX_RAD, hold_min_s: float = 1.0,
                 hold_max_s: float = 3.0, render_mode: str | None = None) -> None:
        if render_mode is not None:
            raise ValueError(f'`render_mode` must be None (no rendering), got {render_mode!r}')
        self.render_mode = None
        self.plant = load_knee_plant(plant)
        if not self.plant.muscles:
            raise ValueError('`plant` must have at least one muscle, got none')
        self.n_steps = steps_per_period(control_period_s)
        self.control_period_s = self.n_steps * MODEL_DT_S
        self.n_periods = whole_multiple(
            'episode_duration_s', check_positive('episode_duration_s', episode_duration_s),
            self.control_period_s, 'control periods')
        self.history_length = check_count('history_length', history_length)
        self.stim_cost = check_positive('stim_cost', stim_cost, allow_zero=True)
        lo, hi = float(angle_min_rad), float(angle_max_rad)
        if not (math.isfinite(lo) and math.isfinite(hi) and lo <= hi):
            raise ValueError(f'`angle_min_rad` <= `angle_max_rad` must be finite, got '
                             f'{angle_min_rad!r}, {angle_max_rad!r}')
        self.angle_min_rad, self.angle_max_rad = lo, hi
        self._hold = check_hold_range(hold_min_s, hold_max_s, self.control_period_s)

        self.limb = Limb(self.plant)
        self._muscle_params = [m.params for m in self.plant.muscles]
        self._pw_max = np.array([p.pw_max_s for p in self._muscle_params])
        self.action_space = spaces.Box(np.zeros(len(self._pw_max), dtype=np.float32),
                                       self._pw_max.astype(np.float32), dtype=np.float32)
        #: [s] the widest accepted widths: the Box's float32 bounds, read back
        self._pw_high = self.action_space.high.astype(np.float64)
        h = self.history_length
        low = np.tile([-np.inf, -np.inf, lo], h).astype(np.float32)
        high = np.tile([np.inf, np.inf, hi], h).astype(np.float32)
        self.observation_space = spaces.Box(low, high, dtype=np.float32)
        self._history = History(h, len(SAMPLE_FIELDS))
        self._targets = np.zeros(self.n_periods)
        self._k = 0

    def reset(self, *, seed: int | None = None,
              options: dict[str, Any] | None = None) -> tuple[np.ndarray, dict]:
        """Start an episode: the limb at rest, new targets drawn.

        :param seed: seeds ``self.np_random`` (same seed: same episode)
        :param options: ``{'target_rad': x}`` holds the target at x [rad], in
            [angle_min_rad, angle_max_rad]
        """
        super().reset(seed=seed)
        options = dict(options or {})
        target = options.pop('target_rad', None)
        if options:
            raise ValueError(f'unknown reset options {sorted(options)}; known: target_rad')
        if target is not None:
            x = float(target)
            if not self.angle_min_rad <= x <= self.angle_max_rad:   # also false for NaN
                raise ValueError(f'`target_rad` must be in [{self.angle_min_rad:g}, '
                                 f'{self.angle_max_rad:g}] rad, got {target!r}')
        rng = self.np_random
        starts = hold_lengths(rng, self.n_periods, *self._hold)
        values = rng.uniform(self.angle_min_rad, self.angle_max_rad, size=len(starts))
        self._targets = piecewise_constant(starts, values, self.n_periods)
        if target is not None:
            self._targets[:] = x
        self.limb.reset()
        self._k = 0
        self._history.fill((self.limb.theta_rad, self.limb.omega_rad_per_s, self._targets[0]))
        return self._observation(), self._info(np.zeros(len(self._pw_max)), 0.0, 0.0)

    def _check_action(self, action) -> np.ndarray:
        a = np.asarray(action, dtype=np.float64).reshape(-1)
        if a.shape != self._pw_high.shape:
            raise ValueError(f'`action` must hold {len(self._pw_high)} pulse widths [s], '
                             f'got shape {np.shape(action)}')
        bad = ~((a >= 0.0) & (a <= self._pw_high))   # also true for NaN
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            raise ValueError(f'`action[{i}]` ({self.plant.muscles[i].name} pulse width) must '
                             f'be in [0, {self._pw_high[i]:g}] s, got {a[i]!r}')
        return a

    def step(self, action) -> tuple[np.ndarray, float, bool, bool, dict]:
        """Hold the pulse widths ``action`` [s] for one control period.

        :raises ValueError: on a NaN or out-of-Box width (the state is unchanged),
            or a step after the episode's end
        """
        if self._k >= self.n_periods:
            raise ValueError('the episode is over (truncated): call reset() first')
        pw = self._check_action(action)
        us = [command_from_pulse_width(w, p) for w, p in zip(pw.tolist(), self._muscle_params)]
        k, limb = self._k, self.limb
        target = float(self._targets[k])
        sq = 0.0
        for _ in range(self.n_steps):
            out = limb.step(us, 0.0, MODEL_DT_S)
            sq += (out.theta_rad - target) ** 2
        tracking = sq / self.n_steps
        stimulation = self.stim_cost * float(np.mean((pw / self._pw_max) ** 2))
        self._k = k = k + 1
        self._history.push((out.theta_rad, out.omega_rad_per_s,
                            self._targets[min(k, self.n_periods - 1)]))
        truncated = k >= self.n_periods
        return (self._observation(), -tracking - stimulation, False, truncated,
                self._info(pw, tracking, stimulation))

    def _observation(self) -> np.ndarray:
        return self._history.flat().astype(np.float32)

    def _info(self, pw: np.ndarray, tracking: float, stimulation: float) -> dict:
        """Float64 values the float32 observation rounds, and the reward's two terms."""
        return {'t_s': self._k * self.control_period_s, 'pulse_width_s': pw.copy(),
                'theta_rad': float(self.limb.theta_rad),
                'target_rad': float(self._targets[min(self._k, self.n_periods - 1)]),
                'tracking_cost': tracking, 'stimulation_cost': stimulation}
