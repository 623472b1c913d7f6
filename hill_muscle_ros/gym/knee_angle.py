"""``hill_muscle_ros/KneeAngle-v0``: track a knee angle with the stimulated
quadriceps and hamstrings of the knee preset.

The plant is :class:`~hill_muscle_ros.model.limb.Limb` on ``config/knee.yaml``
(or any plant file or :class:`~hill_muscle_ros.model.limb.LimbPlant`); each
muscle's pulse width goes through its own recruitment curve
(:func:`~hill_muscle_ros.model.stimulus.command_from_pulse_width`). Nothing
here writes a model equation.
"""
from __future__ import annotations

import dataclasses
import math
import os
from typing import Any, Mapping

import numpy as np
from gymnasium import spaces

from ..model import engine as engines
from ..model.limb import Limb, LimbPlant
from ..model.stimulus import command_from_pulse_width
from ._common import (MODEL_DT_S, TrackingEnv, check_pulse_widths, hold_lengths,
                      muscle_variant, piecewise_constant)

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


def plant_variant(plant: LimbPlant, *, units: str | None = None, length: str | None = None,
                  fes_features: bool = True, overrides: Mapping[str, Any] | None = None,
                  muscle_overrides: Mapping[str, Mapping[str, Any]] | None = None) -> LimbPlant:
    """The plant with its muscles changed by the environment's options: ``units``,
    ``length``, ``fes_features`` and ``overrides`` apply to every muscle (as
    :func:`~hill_muscle_ros.gym._common.muscle_variant` says), then
    ``muscle_overrides[name]`` to the muscle ``name`` alone.

    :raises ValueError: naming an unknown muscle or field, or the muscle, the
        field and the value that :class:`~hill_muscle_ros.model.params.MuscleParams` refuses
    """
    names = [m.name for m in plant.muscles]
    if muscle_overrides is not None and not isinstance(muscle_overrides, Mapping):
        raise ValueError(f'`muscle_overrides` must map muscle names to fields and values, '
                         f'got {muscle_overrides!r}')
    per_muscle = dict(muscle_overrides or {})
    unknown = sorted(str(n) for n in per_muscle if n not in names)
    if unknown:
        raise ValueError(f'`muscle_overrides`: unknown muscle `{unknown[0]}` '
                         f'(muscles: {", ".join(names)})')
    muscles = []
    for m in plant.muscles:
        p = muscle_variant(m.params, units=units, length=length, fes_features=fes_features,
                           overrides=overrides)
        p = muscle_variant(p, overrides=per_muscle.get(m.name),
                           where=f'muscle_overrides.{m.name}')
        muscles.append(m if p == m.params else dataclasses.replace(m, params=p))
    return dataclasses.replace(plant, muscles=tuple(muscles))


class KneeAngleEnv(TrackingEnv):
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
    :param units: [-] variant override of every muscle: ``multi`` or ``single``
        (``None``: as the plant)
    :param length: [-] variant override of every muscle: ``initial`` or ``instantaneous``
    :param fes_features: ``False`` switches every FES extension of every
        muscle's dynamics off (delay, activation, ``fv_scaling``, fatigue, fibre
        types, recruitment order, unit length spread), the recruitment curves kept
    :param overrides: :class:`~hill_muscle_ros.model.params.MuscleParams`
        fields by name, applied to every muscle (``{'fatigue': 'none'}``)
    :param muscle_overrides: fields per muscle name, applied last
        (``{'quadriceps': {'f_iso_max_n': 1200.0}}``)
    :param control_period_s: [s] control period, 0.010-0.050, whole milliseconds
    :param episode_duration_s: [s] episode length, a whole number of periods
    :param history_length: [-] samples of each signal in the observation, >= 1
    :param stim_cost: [rad^2] weight of the stimulation term, >= 0
    :param angle_min_rad: [rad] smallest target
    :param angle_max_rad: [rad] largest target
    :param hold_min_s: [s] shortest hold of a target
    :param hold_max_s: [s] longest hold of a target
    :param render_mode: only ``None`` (no rendering)
    :param engine: the build of the limb's kernels, ``'compiled'`` (numba's) or
        ``'python'`` (the same functions as plain Python); the same trajectories
        to 1e-9 rad. ``None``: :func:`hill_muscle_ros.model.engine.choice`
        (compiled where numba can be imported, unless ``HILL_MUSCLE_ENGINE=python``).
        The first compiled environment of a process loads the compiled limb:
        about 0.8 s from numba's disk cache, about 30 s when it compiles (a
        clean clone, or after an edit of the model's code)
    """

    TARGET_OPTION = 'target_rad'

    def __init__(self, plant: LimbPlant | str | None = None, *, units: str | None = None,
                 length: str | None = None, fes_features: bool = True,
                 overrides: dict[str, Any] | None = None,
                 muscle_overrides: dict[str, dict[str, Any]] | None = None,
                 control_period_s: float = 0.02, episode_duration_s: float = 6.0,
                 history_length: int = 5, stim_cost: float = 0.01,
                 angle_min_rad: float = DEFAULT_ANGLE_MIN_RAD,
                 angle_max_rad: float = DEFAULT_ANGLE_MAX_RAD, hold_min_s: float = 1.0,
                 hold_max_s: float = 3.0, render_mode: str | None = None,
                 engine: str | None = None) -> None:
        self._init_episode(control_period_s=control_period_s,
                           episode_duration_s=episode_duration_s,
                           history_length=history_length, stim_cost=stim_cost,
                           hold_min_s=hold_min_s, hold_max_s=hold_max_s,
                           render_mode=render_mode, width=len(SAMPLE_FIELDS))
        self.plant = plant_variant(load_knee_plant(plant), units=units, length=length,
                                   fes_features=fes_features, overrides=overrides,
                                   muscle_overrides=muscle_overrides)
        if not self.plant.muscles:
            raise ValueError('`plant` must have at least one muscle, got none')
        lo, hi = float(angle_min_rad), float(angle_max_rad)
        if not (math.isfinite(lo) and math.isfinite(hi) and lo <= hi):
            raise ValueError(f'`angle_min_rad` <= `angle_max_rad` must be finite, got '
                             f'{angle_min_rad!r}, {angle_max_rad!r}')
        self.angle_min_rad, self.angle_max_rad = lo, hi

        if engine not in (None, engines.COMPILED, engines.PYTHON):
            raise ValueError(f'`engine` must be {engines.COMPILED!r}, {engines.PYTHON!r} or '
                             f'None, got {engine!r}')
        self.limb = Limb(self.plant, build=engine)
        #: ``'compiled'`` or ``'python'``: the build of the kernels the limb runs
        self.engine = self.limb.build
        self._muscle_params = [m.params for m in self.plant.muscles]
        #: what each action entry is, for error messages
        self.action_labels = tuple(f'{m.name} pulse width' for m in self.plant.muscles)
        self._pw_max = np.array([p.pw_max_s for p in self._muscle_params])
        self.action_space = spaces.Box(np.zeros(len(self._pw_max), dtype=np.float32),
                                       self._pw_max.astype(np.float32), dtype=np.float32)
        #: [s] the widest accepted widths: the Box's float32 bounds, read back
        self._pw_high = self.action_space.high.astype(np.float64)
        h = self.history_length
        low = np.tile([-np.inf, -np.inf, lo], h).astype(np.float32)
        high = np.tile([np.inf, np.inf, hi], h).astype(np.float32)
        self.observation_space = spaces.Box(low, high, dtype=np.float32)

    def check_target(self, target_rad: Any) -> float:
        """A fixed target from ``reset`` options, validated.

        :param target_rad: [rad] in [angle_min_rad, angle_max_rad]
        """
        x = float(target_rad)
        if not self.angle_min_rad <= x <= self.angle_max_rad:   # also false for NaN
            raise ValueError(f'`target_rad` must be in [{self.angle_min_rad:g}, '
                             f'{self.angle_max_rad:g}] rad, got {target_rad!r}')
        return x

    def draw_episode(self, rng: np.random.Generator, fixed: float | None) -> np.ndarray:
        """[rad] The target of every control period of one episode, from ``rng``.

        :param fixed: [rad] a target for the whole episode, or ``None``
        """
        starts = hold_lengths(rng, self.n_periods, *self._hold)
        values = rng.uniform(self.angle_min_rad, self.angle_max_rad, size=len(starts))
        targets = piecewise_constant(starts, values, self.n_periods)
        if fixed is not None:
            targets[:] = fixed
        return targets

    def commands(self, pw: np.ndarray) -> list[float]:
        """[-] Each muscle's command u for widths ``pw`` [s], through its own curve."""
        return [command_from_pulse_width(w, p) for w, p in zip(pw.tolist(), self._muscle_params)]

    def run_period(self, limb: Limb, us: list[float], target_rad: float) -> tuple[float, Any]:
        """Step ``limb`` through one control period with commands ``us`` held, in
        one call of its kernels (:meth:`~hill_muscle_ros.model.limb.Limb.hold`).

        :param us: [-] each muscle's recruitment command u, in [0, 1]
        :param target_rad: [rad] the period's target theta*
        :return: the tracking term, mean_j (theta_j - theta*)^2 [rad^2], and the
            limb's outputs at the period's end
        """
        sq = limb.hold(us, 0.0, MODEL_DT_S, self.n_steps, target_rad)
        return sq / self.n_steps, limb.outputs()

    def reset(self, *, seed: int | None = None,
              options: dict[str, Any] | None = None) -> tuple[np.ndarray, dict]:
        """Start an episode: the limb at rest, new targets drawn.

        :param seed: seeds ``self.np_random`` (same seed: same episode)
        :param options: ``{'target_rad': x}`` holds the target at x [rad], in
            [angle_min_rad, angle_max_rad]
        """
        super().reset(seed=seed)
        self._targets = self.draw_episode(self.np_random, self.fixed_target(options))
        self.limb.reset()
        self._k = 0
        self._history.fill((self.limb.theta_rad, self.limb.omega_rad_per_s, self._targets[0]))
        return self._observation(), self._info(np.zeros(len(self._pw_max)), 0.0, 0.0)

    def step(self, action) -> tuple[np.ndarray, float, bool, bool, dict]:
        """Hold the pulse widths ``action`` [s] for one control period.

        :raises ValueError: on a NaN or out-of-Box width (the state is unchanged),
            or a step after the episode's end
        """
        self._check_running()
        pw = check_pulse_widths(action, self._pw_high, self.action_labels, 'action')
        k = self._k
        tracking, out = self.run_period(self.limb, self.commands(pw), float(self._targets[k]))
        stimulation = float(self.stimulation_cost(pw))
        self._k = k = k + 1
        self._history.push((out.theta_rad, out.omega_rad_per_s, self._target_after(k)))
        truncated = k >= self.n_periods
        return (self._observation(), -tracking - stimulation, False, truncated,
                self._info(pw, tracking, stimulation))

    def _observation(self) -> np.ndarray:
        return self._history.flat().astype(np.float32)

    def _info(self, pw: np.ndarray, tracking: float, stimulation: float) -> dict:
        """Float64 values the float32 observation rounds, and the reward's two terms."""
        return {'t_s': self._k * self.control_period_s, 'pulse_width_s': pw.copy(),
                'theta_rad': float(self.limb.theta_rad),
                'target_rad': self._target_after(self._k),
                'tracking_cost': tracking, 'stimulation_cost': stimulation}
