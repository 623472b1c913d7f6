"""Train a small PPO policy on ``hill_muscle_ros/ForceTracking-v0`` and compare
it with the package's PI force controller on the same seeded targets.

Needs Stable-Baselines3 and PyTorch for the training (``pip install
"hill_muscle_ros[gym,rl]"``; a CPU-only PyTorch build is enough); the PI
comparison alone (``--timesteps 0``) needs only gymnasium::

    python examples/train_force_tracking.py --timesteps 200000
    python examples/train_force_tracking.py --timesteps 0          # the PI alone

The policy acts in [-1, 1] (``gymnasium.wrappers.RescaleAction`` maps that
onto the pulse-width Box) and sees the observation normalised by SB3's
``VecNormalize``, whose statistics are frozen for the evaluation. The PI is
:class:`~hill_muscle_ros.control.ForceController` with its default gains and
the model feedforward of the simulated muscle, fed from the same observation:
force, target, and the imposed length with its rate from the last two samples.

Both are scored on the same episodes (``--eval-seeds``, seeded targets and
length profiles): the RMS force error [N] over every model step, from the
environment's ``tracking_cost`` (the mean squared error of a period over
f_iso_max^2), and the return.
"""
from __future__ import annotations

import argparse
import math
import sys
import time
from typing import Callable

import gymnasium as gym
import numpy as np

from hill_muscle_ros.control import ControllerParams, ForceController
from hill_muscle_ros.gym import ForceTrackingEnv

#: Observation indices of the newest sample (ForceTrackingEnv.SAMPLE_FIELDS
#: order: force, target, l_CE, dl_MT) and of the dl_MT of the one before.
FORCE, TARGET, DL_MT, DL_MT_PREVIOUS = 0, 1, 3, 7
#: Seeds of the evaluation episodes: never used in training (it seeds from 0).
EVAL_SEEDS = (1000, 1001, 1002, 1003, 1004)
#: PPO settings (our choice for this task): a small MLP; gamma 0.95, since a
#: pulse width acts on the force within a few periods (the episode is 250);
#: an initial action noise of std e^-1 = 0.37 of the half range, not SB3's 1,
#: which saturates half the actions at the Box's edges.
POLICY_LAYERS = [64, 64]
GAMMA = 0.95
N_STEPS = 512
LOG_STD_INIT = -1.0

#: A controller: observation -> pulse width [s] (an array of one).
Policy = Callable[[np.ndarray], np.ndarray]


def make_env(**kwargs) -> ForceTrackingEnv:
    """The environment of the training and of the evaluation (default settings)."""
    return ForceTrackingEnv(**kwargs)


def rescaled(env: ForceTrackingEnv) -> gym.Env:
    """``env`` with actions in [-1, 1] mapped onto its pulse-width Box (float32
    bounds, as the Box's: float64 ones make gymnasium warn)."""
    one = np.ones(env.action_space.shape, dtype=np.float32)
    return gym.wrappers.RescaleAction(env, -one, one)


def pi_policy(env: ForceTrackingEnv) -> tuple[Policy, Callable[[], None]]:
    """The package's PI force controller as a policy, and its reset.

    Default gains, the model feedforward of the environment's own muscle.
    """
    period = env.control_period_s
    pw_max = float(env.action_space.high[0])
    controller = ForceController(ControllerParams(rate_hz=1.0 / period, pw_max_s=pw_max),
                                 model=env.params)

    def act(obs: np.ndarray) -> np.ndarray:
        v_mt = (float(obs[DL_MT]) - float(obs[DL_MT_PREVIOUS])) / period
        pw = controller.update(float(obs[TARGET]), float(obs[FORCE]), period,
                               dl_mt_m=float(obs[DL_MT]), v_mt_m_per_s=v_mt)
        return np.array([pw], dtype=np.float32)
    return act, controller.reset


def evaluate(env: gym.Env, act: Policy, seeds=EVAL_SEEDS,
             reset: Callable[[], None] = lambda: None) -> dict:
    """Run one episode per seed; the RMS force error [N] and the mean return.

    :param env: a ForceTrackingEnv, possibly wrapped (the policy acts on its action space)
    :param act: observation -> action
    :param reset: called before each episode (a controller's state)
    """
    f_ref = env.unwrapped.params.f_iso_max_n
    squared, returns = [], []
    for seed in seeds:
        reset()
        obs, _ = env.reset(seed=seed)
        total, done = 0.0, False
        while not done:
            obs, reward, terminated, truncated, info = env.step(act(obs))
            squared.append(info['tracking_cost'])
            total += reward
            done = terminated or truncated
        returns.append(total)
    return {'rms_error_n': f_ref * math.sqrt(float(np.mean(squared))),
            'mean_return': float(np.mean(returns))}


def train(timesteps: int, num_envs: int, seed: int):
    """PPO on ``num_envs`` copies; returns the model and the frozen normaliser."""
    import torch   # optional: only the training needs it and SB3
    from stable_baselines3 import PPO
    from stable_baselines3.common.env_util import make_vec_env
    from stable_baselines3.common.vec_env import VecNormalize

    # One thread: the network is tiny, and more threads than free cores make
    # every small matrix product wait for the others (measured 50 steps/s
    # with the default threads on a busy 2-core machine).
    torch.set_num_threads(1)

    venv = make_vec_env(lambda: rescaled(make_env()),
                        n_envs=num_envs, seed=seed)
    venv = VecNormalize(venv, gamma=GAMMA)
    model = PPO('MlpPolicy', venv, gamma=GAMMA, n_steps=N_STEPS, seed=seed, verbose=0,
                policy_kwargs={'net_arch': POLICY_LAYERS, 'log_std_init': LOG_STD_INIT},
                device='cpu')
    model.learn(total_timesteps=timesteps)
    venv.training = False   # freeze the observation statistics for the evaluation
    return model, venv


def ppo_policy(model, normaliser) -> Policy:
    """The trained policy, deterministic, on raw observations."""
    def act(obs: np.ndarray) -> np.ndarray:
        action, _ = model.predict(normaliser.normalize_obs(obs[None, :]), deterministic=True)
        return action[0]
    return act


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--timesteps', type=int, default=200_000,
                        help='PPO environment steps (0: evaluate the PI alone)')
    parser.add_argument('--num-envs', type=int, default=4, help='training environments')
    parser.add_argument('--seed', type=int, default=0, help='training seed')
    parser.add_argument('--eval-seeds', type=int, nargs='+', default=list(EVAL_SEEDS),
                        help='seeds of the evaluation episodes')
    args = parser.parse_args(argv)
    if args.timesteps < 0 or args.num_envs < 1:
        parser.error('--timesteps must be >= 0 and --num-envs >= 1')

    env = make_env()
    act, reset = pi_policy(env)
    pi = evaluate(env, act, args.eval_seeds, reset)
    print(f'PI controller: RMS force error {pi["rms_error_n"]:.3f} N, '
          f'mean return {pi["mean_return"]:.3f} ({len(args.eval_seeds)} episodes)')
    if args.timesteps == 0:
        return 0
    try:
        import stable_baselines3  # noqa: F401
    except ImportError:
        print('Stable-Baselines3 is not installed: pip install "hill_muscle_ros[rl]"',
              file=sys.stderr)
        return 1
    t0 = time.perf_counter()
    model, normaliser = train(args.timesteps, args.num_envs, args.seed)
    wall = time.perf_counter() - t0
    ppo = evaluate(rescaled(make_env()),
                   ppo_policy(model, normaliser), args.eval_seeds)
    print(f'PPO ({args.timesteps} steps, {wall:.0f} s): RMS force error '
          f'{ppo["rms_error_n"]:.3f} N, mean return {ppo["mean_return"]:.3f}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
