"""The Gymnasium environments (hill_muscle_ros.gym): API, determinism, action
bounds, reward, and that the options reach the model. Offline, no ROS."""
import dataclasses

import numpy as np
import pytest

gym = pytest.importorskip('gymnasium')
from gymnasium.utils.env_checker import check_env  # noqa: E402
from gymnasium.wrappers import ClipAction  # noqa: E402

from hill_muscle_ros.gym import (FORCE_TRACKING_ID, KNEE_ANGLE_ID, ForceTrackingEnv,  # noqa: E402
                                 ForceTrackingVectorEnv, KneeAngleEnv, KneeAngleVectorEnv)
from hill_muscle_ros.model import Muscle, MuscleParams  # noqa: E402
from hill_muscle_ros.model.limb import Limb  # noqa: E402
from hill_muscle_ros.params_file import load_plant  # noqa: E402
from hill_muscle_ros.resources import config_dir  # noqa: E402

#: [s] the model step inside a control period (1 kHz)
DT_S = 1e-3
FES_QUADRICEPS = config_dir() / 'fes_quadriceps.yaml'
#: Control periods of the knee tests: short, the limb is the slow engine.
KNEE_STEPS = 10


def _rollout(env, seed, n_steps, action_seed=0):
    """Observations, rewards and flags of ``n_steps`` seeded random actions."""
    rng = np.random.default_rng(action_seed)
    obs, _ = env.reset(seed=seed)
    out = [obs]
    low, high = env.action_space.low, env.action_space.high
    for _ in range(n_steps):
        action = rng.uniform(low, high).astype(np.float32)
        obs, reward, terminated, truncated, _ = env.step(action)
        out.append((obs, reward, terminated, truncated))
    return out


def _same(a, b):
    """Exactly equal nested rollouts (arrays bit for bit)."""
    assert len(a) == len(b)
    for x, y in zip(a, b):
        if isinstance(x, tuple):
            np.testing.assert_array_equal(x[0], y[0])
            assert x[1:] == y[1:]
        else:
            np.testing.assert_array_equal(x, y)


def test_import_registers_both_ids():
    assert FORCE_TRACKING_ID == 'hill_muscle_ros/ForceTracking-v0'
    assert KNEE_ANGLE_ID == 'hill_muscle_ros/KneeAngle-v0'
    assert isinstance(gym.make(FORCE_TRACKING_ID).unwrapped, ForceTrackingEnv)
    assert isinstance(gym.make(KNEE_ANGLE_ID).unwrapped, KneeAngleEnv)


def test_force_tracking_passes_check_env():
    check_env(gym.make(FORCE_TRACKING_ID, disable_env_checker=True).unwrapped)


def test_force_tracking_with_fatigue_passes_check_env():
    check_env(ForceTrackingEnv(FES_QUADRICEPS))


def test_knee_angle_passes_check_env():
    check_env(gym.make(KNEE_ANGLE_ID, disable_env_checker=True).unwrapped)


def test_force_tracking_same_seed_gives_identical_trajectories():
    a = _rollout(ForceTrackingEnv(), seed=7, n_steps=250)   # a whole 5 s episode
    b = _rollout(ForceTrackingEnv(), seed=7, n_steps=250)
    _same(a, b)
    assert a[-1][3] is True   # truncated at the episode's end


def test_force_tracking_reset_with_the_seed_again_repeats_the_episode():
    env = ForceTrackingEnv(FES_QUADRICEPS)   # fatigue and activation state must reset too
    a = _rollout(env, seed=3, n_steps=60)
    b = _rollout(env, seed=3, n_steps=60)
    _same(a, b)


def test_force_tracking_different_seeds_draw_different_targets():
    env = ForceTrackingEnv()
    env.reset(seed=1)
    t1 = env._targets.copy()
    env.reset(seed=2)
    assert not np.array_equal(t1, env._targets)


def test_knee_angle_same_seed_gives_identical_trajectories():
    _same(_rollout(KneeAngleEnv(), seed=5, n_steps=KNEE_STEPS),
          _rollout(KneeAngleEnv(), seed=5, n_steps=KNEE_STEPS))


@pytest.mark.parametrize('bad', [np.nan, -1e-6, 0.0005 * 1.01, np.inf])
def test_force_tracking_action_outside_the_box_raises_and_changes_nothing(bad):
    env, fresh = ForceTrackingEnv(), ForceTrackingEnv()
    env.reset(seed=0)
    fresh.reset(seed=0)
    with pytest.raises(ValueError, match=r'`action` \(pulse width\) must be in \[0, 0.0005\] s'):
        env.step(np.array([bad], dtype=np.float64))
    good = np.array([0.0002], dtype=np.float32)
    np.testing.assert_array_equal(env.step(good)[0], fresh.step(good)[0])


def test_force_tracking_box_edge_pw_max_is_accepted():
    env = ForceTrackingEnv()
    env.reset(seed=0)
    env.step(env.action_space.high)   # the float32 bound, a hair above 0.0005 s


def test_force_tracking_clip_action_wrapper_clips_to_the_box():
    clipped = ClipAction(ForceTrackingEnv())
    plain = ForceTrackingEnv()
    clipped.reset(seed=0)
    plain.reset(seed=0)
    a = clipped.step(np.array([1.0], dtype=np.float32))      # 1 s: far above PW_max
    b = plain.step(plain.action_space.high)
    np.testing.assert_array_equal(a[0], b[0])
    assert a[1] == b[1]


def test_knee_angle_action_outside_the_box_raises_naming_the_muscle():
    env = KneeAngleEnv()
    env.reset(seed=0)
    with pytest.raises(ValueError, match=r'`action\[1\]` \(hamstrings pulse width\)'):
        env.step(np.array([0.0, np.nan]))
    with pytest.raises(ValueError, match='must hold 2 pulse widths'):
        env.step(np.array([0.0002]))


def test_force_tracking_reward_without_stimulation_is_minus_the_normalised_target_squared():
    # Isometric, nothing recruited: F = 0 at every millisecond, so the
    # tracking term is (F* / f_iso_max)^2 exactly and the stimulation term 0.
    env = ForceTrackingEnv(length_max_m=0.0, stim_cost=0.5)
    env.reset(seed=0, options={'target_n': 9.0})
    _, reward, _, _, info = env.step(np.array([0.0], dtype=np.float32))
    assert reward == -(9.0 / 45.0) ** 2
    assert info['stimulation_cost'] == 0.0


def test_force_tracking_reward_is_mean_squared_error_plus_stimulation_cost():
    # Full stimulation on the paper's muscle, isometric, 20 ms: the tracking
    # term from an independently stepped Muscle, the stimulation term w * 1.
    w, target = 0.25, 20.0
    env = ForceTrackingEnv(length_max_m=0.0, stim_cost=w, control_period_s=0.02)
    env.reset(seed=0, options={'target_n': target})
    _, reward, _, _, info = env.step(np.array([0.0005], dtype=np.float32))
    muscle = Muscle(MuscleParams())   # the float32 width is above PW_max: R = 1
    forces = [muscle.step(1.0, 0.0, DT_S).force_n for _ in range(20)]
    tracking = np.mean([((f - target) / 45.0) ** 2 for f in forces])
    assert info['tracking_cost'] == pytest.approx(tracking, rel=1e-12)
    assert info['stimulation_cost'] == pytest.approx(w * (float(np.float32(0.0005)) / 0.0005) ** 2,
                                                     rel=1e-15)
    assert reward == -info['tracking_cost'] - info['stimulation_cost']
    assert reward < 0.0


def test_knee_angle_reward_is_mean_squared_angle_error_plus_mean_stimulation_cost():
    w, target = 0.1, np.radians(30.0)
    env = KneeAngleEnv(stim_cost=w, control_period_s=0.02)
    env.reset(seed=0, options={'target_rad': target})
    pw = np.array([0.0003, 0.0], dtype=np.float32)
    _, reward, _, _, info = env.step(pw)
    plant, _ = load_plant(config_dir() / 'knee.yaml')
    limb = Limb(plant)
    from hill_muscle_ros.model.stimulus import command_from_pulse_width
    us = [command_from_pulse_width(float(pw[i]), m.params) for i, m in enumerate(plant.muscles)]
    thetas = [limb.step(us, 0.0, DT_S).theta_rad for _ in range(20)]
    assert info['tracking_cost'] == pytest.approx(np.mean((np.array(thetas) - target) ** 2),
                                                  rel=1e-12)
    assert info['stimulation_cost'] == pytest.approx(
        w * ((float(pw[0]) / 0.0006) ** 2 + 0.0) / 2.0, rel=1e-12)
    assert reward == -info['tracking_cost'] - info['stimulation_cost']


def test_force_tracking_zero_stimulation_gives_zero_force_isometric():
    env = ForceTrackingEnv(length_max_m=0.0)
    obs, _ = env.reset(seed=4)
    forces = [obs[0]]
    truncated = False
    while not truncated:
        obs, _, _, truncated, info = env.step(np.zeros(1, dtype=np.float32))
        forces.append(obs[0])
        assert info['force_n'] == 0.0
    assert np.all(np.array(forces) == 0.0)


def test_force_tracking_zero_stimulation_force_is_the_parallel_spring_alone():
    # Nothing recruited: the free CE leaves the SE slack, F = k_PE max(dl_MT, 0).
    env = ForceTrackingEnv(length_max_m=0.01)
    env.reset(seed=4)
    truncated = False
    while not truncated:
        _, _, _, truncated, info = env.step(np.zeros(1, dtype=np.float32))
        assert info['force_n'] == pytest.approx(1000.0 * max(info['dl_mt_m'], 0.0),
                                                rel=1e-12, abs=1e-12)
    assert env._dl.max() > 0.0   # the profile did stretch the muscle


def test_force_tracking_params_and_variant_reach_the_muscle():
    params = MuscleParams(f_iso_max_n=90.0, pw_max_s=0.0004)
    env = ForceTrackingEnv(params, units='single', length='instantaneous', length_max_m=0.0)
    assert env.muscle.params == dataclasses.replace(params, units='single',
                                                    length='instantaneous')
    assert env.action_space.high[0] == np.float32(0.0004)
    env.reset(seed=0)
    _, _, _, _, info = env.step(np.array([0.0002], dtype=np.float32))
    reference = Muscle(env.muscle.params)
    r = float(np.float32(0.0002)) / 0.0004   # the linear curve, at the float32 width
    for _ in range(20):
        out = reference.step(r, 0.0, DT_S)
    assert info['force_n'] == pytest.approx(out.force_n, rel=1e-12)
    default = ForceTrackingEnv(length_max_m=0.0)
    default.reset(seed=0)
    assert default.step(np.array([0.0002], dtype=np.float32))[4]['force_n'] != info['force_n']


def test_force_tracking_yaml_with_fatigue_uses_the_fes_engine_and_observes_fitness():
    env = ForceTrackingEnv(str(FES_QUADRICEPS))
    assert not env.muscle.params.fes_defaults   # the features reach the muscle
    assert env.observation_space.shape == (4 * 5 + 1,)
    obs, _ = env.reset(seed=0)
    assert obs[-1] == 1.0   # a fresh muscle
    for _ in range(25):
        obs, *_ = env.step(env.action_space.high)
    assert 0.2 < obs[-1] < 1.0   # fatigued a little, above fatigue_min


def test_force_tracking_history_length_sets_the_observation_and_shifts_newest_first():
    env = ForceTrackingEnv(history_length=3, length_max_m=0.0)
    assert env.observation_space.shape == (12,)
    obs0, _ = env.reset(seed=0)
    obs1, *_ = env.step(np.array([0.0003], dtype=np.float32))
    obs2, *_ = env.step(np.array([0.0003], dtype=np.float32))
    np.testing.assert_array_equal(obs2[4:8], obs1[0:4])
    np.testing.assert_array_equal(obs2[8:12], obs0[0:4])


@pytest.mark.parametrize('period, message', [
    (0.005, r'`control_period_s` must be in \[0.01, 0.05\] s'),
    (0.0155, '`control_period_s` must be a whole number of model steps'),
    (np.nan, '`control_period_s` must be positive and finite'),
])
def test_bad_control_period_raises_naming_it(period, message):
    with pytest.raises(ValueError, match=message):
        ForceTrackingEnv(control_period_s=period)
    with pytest.raises(ValueError, match=message):
        KneeAngleEnv(control_period_s=period)


def test_control_period_sets_the_model_steps_per_env_step():
    env = ForceTrackingEnv(control_period_s=0.05, episode_duration_s=1.0)
    env.reset(seed=0)
    _, _, _, _, info = env.step(np.zeros(1, dtype=np.float32))
    assert env.muscle.t_s == pytest.approx(0.05, abs=1e-12)
    assert info['t_s'] == pytest.approx(0.05, abs=1e-15)
    assert env.n_periods == 20


def test_step_after_the_episode_end_raises():
    env = ForceTrackingEnv(episode_duration_s=0.04)
    env.reset(seed=0)
    env.step(np.zeros(1, dtype=np.float32))
    assert env.step(np.zeros(1, dtype=np.float32))[3] is True
    with pytest.raises(ValueError, match='the episode is over'):
        env.step(np.zeros(1, dtype=np.float32))


def test_readme_gym_example_prints_the_output_the_readme_shows(capsys):
    # The worked example of doc/gym.md is run as written; its shown output must be
    # what it prints (the episode is seeded, so it is exact).
    from pathlib import Path
    text = (Path(__file__).resolve().parents[1] / 'doc' / 'gym.md').read_text(encoding='utf-8')
    section = text.split('<!-- gym-example -->', 1)[1]
    code = section.split('```python\n', 1)[1].split('```\n', 1)[0]
    shown = section.split('```text\n', 1)[1].split('```\n', 1)[0]
    exec(compile(code, 'doc/gym.md (gym example)', 'exec'), {})
    assert capsys.readouterr().out == shown


def _vector_against_singles(env_id, single_cls, k, n_steps, exact=False, **kwargs):
    """Step make_vec and K single envs (seeds 11 + i) with the same actions,
    through the end of the episode and the autoreset step after it."""
    vec = gym.make_vec(env_id, num_envs=k, **kwargs)
    singles = [single_cls(**kwargs) for _ in range(k)]
    obs_v, _ = vec.reset(seed=11)
    obs_s = np.stack([env.reset(seed=11 + i)[0] for i, env in enumerate(singles)])
    np.testing.assert_array_equal(obs_v, obs_s)
    rng = np.random.default_rng(1)
    high = singles[0].action_space.high
    for _ in range(n_steps):
        actions = rng.uniform(0.0, high, size=(k, len(high))).astype(np.float32)
        obs_v, rew_v, term_v, trunc_v, info_v = vec.step(actions)
        steps = [env.step(a) for env, a in zip(singles, actions)]
        if exact:   # the same scalar engine: bit for bit
            np.testing.assert_array_equal(obs_v, np.stack([s[0] for s in steps]))
            np.testing.assert_array_equal(rew_v, [s[1] for s in steps])
            np.testing.assert_array_equal(info_v['tracking_cost'],
                                          [s[4]['tracking_cost'] for s in steps])
        else:   # the batch engine agrees with the scalar muscle to 1e-9 N, not bit for bit
            np.testing.assert_allclose(obs_v, np.stack([s[0] for s in steps]), rtol=1e-6,
                                       atol=1e-9)
            np.testing.assert_allclose(rew_v, [s[1] for s in steps], rtol=1e-9, atol=1e-12)
        assert list(term_v) == [s[2] for s in steps]
        assert list(trunc_v) == [s[3] for s in steps]
    assert trunc_v.all()
    # NEXT_STEP autoreset: the step after the end ignores the actions and returns
    # the next episode's first observation, drawn from each sub-env's generator.
    obs_v, rew_v, term_v, trunc_v, _ = vec.step(actions)
    np.testing.assert_array_equal(obs_v, np.stack([env.reset()[0] for env in singles]))
    assert not rew_v.any() and not term_v.any() and not trunc_v.any()
    # ... and the new episodes run on as the singles' do.
    actions = rng.uniform(0.0, high, size=(k, len(high))).astype(np.float32)
    obs_v = vec.step(actions)[0]
    np.testing.assert_allclose(obs_v, np.stack([env.step(a)[0] for env, a in
                                                zip(singles, actions)]),
                               rtol=0 if exact else 1e-6, atol=0 if exact else 1e-9)
    return vec


def test_make_vec_uses_the_native_vector_env_and_equals_k_single_envs():
    vec = _vector_against_singles(FORCE_TRACKING_ID, ForceTrackingEnv, 4, 25,
                                  episode_duration_s=0.5)
    assert type(vec.unwrapped) is ForceTrackingVectorEnv


def test_make_vec_with_fatigue_equals_k_single_envs():
    _vector_against_singles(FORCE_TRACKING_ID, ForceTrackingEnv, 3, 10,
                            params=str(FES_QUADRICEPS), episode_duration_s=0.2)


@pytest.mark.parametrize('engine', ['compiled', 'python'])
def test_knee_make_vec_uses_the_native_vector_env_and_equals_k_single_envs_exactly(engine):
    # Holds of 20-30 ms: the target changes inside the 50 ms episodes of five
    # 10 ms control periods (the plain build's limbs take ~3 ms a 1 ms step).
    vec = _vector_against_singles(KNEE_ANGLE_ID, KneeAngleEnv, 3, 5, exact=True,
                                  control_period_s=0.01, episode_duration_s=0.05,
                                  hold_min_s=0.02, hold_max_s=0.03, engine=engine)
    assert type(vec.unwrapped) is KneeAngleVectorEnv
    assert vec.unwrapped.batch.build == engine


@pytest.mark.parametrize('engine', ['compiled', 'python'])
def test_knee_make_vec_with_options_equals_k_single_envs_exactly(engine):
    _vector_against_singles(KNEE_ANGLE_ID, KneeAngleEnv, 2, 3, exact=True,
                            episode_duration_s=0.06, fes_features=False, units='single',
                            muscle_overrides={'hamstrings': {'f_iso_max_n': 800.0}},
                            engine=engine)


def test_knee_engine_default_follows_the_environment_variable(monkeypatch):
    from hill_muscle_ros.model import engine as engines
    monkeypatch.setenv(engines.ENV_VAR, 'python')
    env = KneeAngleEnv()
    assert (env.engine, env.limb.build) == ('python', 'python')
    monkeypatch.setenv(engines.ENV_VAR, 'compiled')
    env = KneeAngleEnv()
    assert (env.engine, env.limb.build) == ('compiled', 'compiled')
    assert type(env.limb) is Limb


def test_knee_engine_option_rejects_an_unknown_engine():
    with pytest.raises(ValueError, match=r"`engine` must be 'compiled', 'python' or None, "
                                         r"got 'fast'"):
        KneeAngleEnv(engine='fast')


def test_knee_compiled_and_python_engines_give_the_same_episode():
    # The limb's kernels compiled and as plain Python: the angle to 1e-9 rad.
    envs = [KneeAngleEnv(engine=e, control_period_s=0.02) for e in ('compiled', 'python')]
    for env in envs:
        env.reset(seed=3)
    rng = np.random.default_rng(4)
    for _ in range(KNEE_STEPS):
        action = rng.uniform(0.0, envs[0].action_space.high).astype(np.float32)
        (_, r_c, *_, info_c), (_, r_p, *_, info_p) = (env.step(action) for env in envs)
        assert info_c['theta_rad'] == pytest.approx(info_p['theta_rad'], abs=1e-9)
        assert r_c == pytest.approx(r_p, abs=1e-9)


def test_knee_vector_env_action_outside_the_box_raises_naming_env_and_muscle():
    vec = gym.make_vec(KNEE_ANGLE_ID, num_envs=2)
    vec.reset(seed=0)
    with pytest.raises(ValueError, match=r'`actions\[1, 1\]` \(hamstrings pulse width\) '
                                         r'must be in \[0, 0.0006\] s, got nan'):
        vec.step(np.array([[0.0001, 0.0], [0.0001, np.nan]]))
    with pytest.raises(ValueError, match=r'`actions` must hold 2 pulse widths \[s\] per '
                                         r'environment \(2\)'):
        vec.step(np.zeros(2))


def test_knee_vector_reset_target_option_holds_every_sub_env_and_bad_one_raises():
    vec = gym.make_vec(KNEE_ANGLE_ID, num_envs=2)
    obs, _ = vec.reset(seed=[3, 4], options={'target_rad': 0.5})
    assert np.all(obs[:, 2::3] == np.float32(0.5))
    assert np.all(vec.unwrapped._targets == 0.5)
    with pytest.raises(ValueError, match=r'`target_rad` must be in'):
        vec.reset(options={'target_rad': 3.0})
    with pytest.raises(ValueError, match=r"unknown reset options \['target_n'\]"):
        vec.reset(options={'target_n': 3.0})


def test_vector_env_action_outside_the_box_raises_naming_the_env():
    vec = gym.make_vec(FORCE_TRACKING_ID, num_envs=2)
    vec.reset(seed=0)
    with pytest.raises(ValueError, match=r'`actions\[1\]` \(pulse width\) must be in'):
        vec.step(np.array([[0.0001], [np.nan]]))


# -- options: muscle parameters, physiology features, variant ----------------------------

def test_force_tracking_fes_features_off_is_the_paper_dynamics_on_the_same_muscle():
    preset = ForceTrackingEnv(FES_QUADRICEPS).params
    env = ForceTrackingEnv(FES_QUADRICEPS, fes_features=False, length_max_m=0.0)
    p = env.params
    assert p.fes_defaults and env.muscle.params.fes_defaults
    # the muscle and its recruitment curve are the preset's
    assert (p.f_iso_max_n, p.k_se_n_per_m, p.recruitment_curve, p.pw_threshold_s) == \
        (preset.f_iso_max_n, preset.k_se_n_per_m, preset.recruitment_curve,
         preset.pw_threshold_s)
    assert env.observation_space.shape == (20,)   # no fatigue: no fitness entry
    env.reset(seed=0)
    pw = np.array([0.0004], dtype=np.float32)
    info = env.step(pw)[4]
    reference = Muscle(p)
    from hill_muscle_ros.model.stimulus import command_from_pulse_width
    u = command_from_pulse_width(float(pw[0]), p)
    for _ in range(20):
        out = reference.step(u, 0.0, DT_S)
    assert info['force_n'] == pytest.approx(out.force_n, rel=1e-12)
    # With the preset's 31 ms delay nothing has happened yet after 20 ms.
    delayed = ForceTrackingEnv(FES_QUADRICEPS, length_max_m=0.0)
    delayed.reset(seed=0)
    assert delayed.step(pw)[4]['force_n'] == pytest.approx(0.0, abs=1e-9)
    assert info['force_n'] > 100.0


def test_force_tracking_overrides_switch_features_on_and_reach_the_engine():
    env = ForceTrackingEnv(overrides={'fatigue': 'riener', 'tau_act_s': 0.02,
                                      'tau_deact_s': 0.03})
    assert (env.params.fatigue, env.params.tau_act_s) == ('riener', 0.02)
    assert (env.muscle.params.fatigue, env.muscle.params.tau_act_s) == ('riener', 0.02)
    assert env.observation_space.shape == (21,)   # fatigue on: the fitness is observed
    env.reset(seed=0)
    # Full width: with activation dynamics the force of the first period is
    # still rising, below the paper's instantaneous recruitment.
    env_plain = ForceTrackingEnv()
    env_plain.reset(seed=0)
    high = env.action_space.high
    assert env.step(high)[4]['force_n'] < env_plain.step(high)[4]['force_n']


@pytest.mark.parametrize('overrides, message', [
    ({'fatigeu': 'riener'}, r'`overrides`: unknown MuscleParams field `fatigeu`'),
    ({'tau_act_s': -1.0}, r'`overrides`: `tau_act_s` must be'),
    (['fatigue'], r'`overrides` must map MuscleParams fields to values'),
])
def test_force_tracking_bad_overrides_raise_naming_the_field(overrides, message):
    with pytest.raises(ValueError, match=message):
        ForceTrackingEnv(overrides=overrides)


def test_fes_features_must_be_a_bool():
    with pytest.raises(ValueError, match=r'`fes_features` must be True or False, got 0'):
        ForceTrackingEnv(fes_features=0)


def test_observe_fitness_gives_a_model_without_fatigue_the_fatigued_observation_space():
    # Train without fatigue, test with it: the same observation layout.
    plain = ForceTrackingEnv(observe_fitness=True)
    tired = ForceTrackingEnv(FES_QUADRICEPS)
    assert plain.observation_space.shape == tired.observation_space.shape == (21,)
    obs, _ = plain.reset(seed=0)
    for _ in range(5):
        obs = plain.step(plain.action_space.high)[0]
        assert obs[-1] == 1.0   # no fatigue: fitness stays 1
    hidden = ForceTrackingEnv(FES_QUADRICEPS, observe_fitness=False)
    assert hidden.observation_space.shape == (20,)
    with pytest.raises(ValueError, match='`observe_fitness` must be True, False or None'):
        ForceTrackingEnv(observe_fitness='yes')


def test_force_vector_env_with_observe_fitness_equals_single_envs():
    _vector_against_singles(FORCE_TRACKING_ID, ForceTrackingEnv, 2, 5, observe_fitness=True,
                            episode_duration_s=0.1, overrides={'tau_act_s': 0.01,
                                                               'tau_deact_s': 0.01})


def test_knee_variant_and_features_options_reach_every_muscle():
    from hill_muscle_ros.model.muscle.state import I_INITIAL, I_MULTI
    env = KneeAngleEnv(units='single', length='instantaneous', fes_features=False)
    for m in env.plant.muscles:
        p = m.params
        assert (p.units, p.length, p.fes_defaults) == ('single', 'instantaneous', True)
        assert p.recruitment_curve == 'exponential'   # the curve stays the preset's
    # The limb's state holds those muscles: their parameters, and the variant
    # its kernels branch on.
    bundle = env.limb.arrays.bundle
    assert env.limb.plant is env.plant
    assert bundle.params == [m.params for m in env.plant.muscles]
    for i in range(len(env.plant.muscles)):
        assert (bundle.view(i, 'ip')[I_MULTI], bundle.view(i, 'ip')[I_INITIAL]) == (0, 0)


def test_knee_overrides_apply_to_all_muscles_and_muscle_overrides_to_one():
    env = KneeAngleEnv(overrides={'fatigue': 'none'},
                       muscle_overrides={'quadriceps': {'f_iso_max_n': 1200.0}})
    quad, ham = (m.params for m in env.plant.muscles)
    assert quad.fatigue == ham.fatigue == 'none'
    assert (quad.f_iso_max_n, ham.f_iso_max_n) == (1200.0, 593.4)


def test_knee_muscle_overrides_change_the_simulated_limb():
    # One period of quadriceps stimulation against an independent Limb on the
    # changed plant: the option reaches the dynamics, not only the parameters.
    plant, _ = load_plant(config_dir() / 'knee.yaml')
    quad = plant.muscles[0]
    changed = dataclasses.replace(plant, muscles=(
        dataclasses.replace(quad, params=dataclasses.replace(quad.params, f_iso_max_n=600.0)),
        plant.muscles[1]))
    env = KneeAngleEnv(muscle_overrides={'quadriceps': {'f_iso_max_n': 600.0}},
                       control_period_s=0.05)
    env.reset(seed=0, options={'target_rad': 0.5})
    pw = np.array([0.0005, 0.0], dtype=np.float32)
    info = env.step(pw)[4]
    limb = Limb(changed)
    from hill_muscle_ros.model.stimulus import command_from_pulse_width
    us = [command_from_pulse_width(float(w), m.params) for w, m in zip(pw, changed.muscles)]
    for _ in range(50):
        out = limb.step(us, 0.0, DT_S)
    assert info['theta_rad'] == pytest.approx(out.theta_rad, abs=1e-9)   # either engine
    default = KneeAngleEnv(control_period_s=0.05)
    default.reset(seed=0, options={'target_rad': 0.5})
    assert default.step(pw)[4]['theta_rad'] > info['theta_rad'] > 0.0


@pytest.mark.parametrize('kwargs, message', [
    ({'muscle_overrides': {'biceps': {'f_iso_max_n': 1.0}}},
     r'`muscle_overrides`: unknown muscle `biceps` \(muscles: quadriceps, hamstrings\)'),
    ({'muscle_overrides': {'hamstrings': {'f_iso_max_n': -1.0}}},
     r'`muscle_overrides.hamstrings`: `f_iso_max_n` must be'),
    ({'overrides': {'nope': 1}}, r'`overrides`: unknown MuscleParams field `nope`'),
    ({'units': 'many'}, r'^`units` must be one of'),
])
def test_knee_bad_muscle_options_raise_naming_them(kwargs, message):
    with pytest.raises(ValueError, match=message):
        KneeAngleEnv(**kwargs)


# -- the RL example (examples/train_force_tracking.py): its evaluation, never its training --

def _example():
    import importlib.util
    from pathlib import Path
    path = Path(__file__).resolve().parents[1] / 'examples' / 'train_force_tracking.py'
    spec = importlib.util.spec_from_file_location('train_force_tracking', path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_example_rms_error_of_no_stimulation_isometric_is_the_rms_target():
    # Isometric and unstimulated, F = 0 at every millisecond: the RMS error over
    # the episode is the RMS of the targets the seed draws.
    example = _example()
    env = ForceTrackingEnv(length_max_m=0.0)
    result = example.evaluate(env, lambda obs: np.zeros(1, dtype=np.float32), seeds=[1000])
    targets, _ = env.draw_episode(np.random.default_rng(1000), None)
    assert result['rms_error_n'] == pytest.approx(np.sqrt(np.mean(targets ** 2)), rel=1e-12)


def test_example_main_without_training_prints_the_pi_evaluation(capsys):
    example = _example()
    assert example.main(['--timesteps', '0', '--eval-seeds', '1000']) == 0
    env = example.make_env()
    act, reset = example.pi_policy(env)
    pi = example.evaluate(env, act, seeds=[1000], reset=reset)
    assert capsys.readouterr().out == (f'PI controller: RMS force error {pi["rms_error_n"]:.3f} '
                                       f'N, mean return {pi["mean_return"]:.3f} (1 episodes)\n')


def test_example_pi_policy_tracks_far_better_than_no_stimulation():
    example = _example()
    env = example.make_env()
    act, reset = example.pi_policy(env)
    pi = example.evaluate(env, act, seeds=[1000, 1001], reset=reset)
    idle = example.evaluate(env, lambda obs: np.zeros(1, dtype=np.float32), seeds=[1000, 1001])
    assert pi['rms_error_n'] < 0.5 * idle['rms_error_n']
    assert pi['mean_return'] > idle['mean_return']


def test_example_without_stable_baselines3_says_how_to_install_it(capsys):
    try:
        import stable_baselines3  # noqa: F401
        pytest.skip('Stable-Baselines3 is installed')
    except ImportError:
        pass
    assert _example().main(['--timesteps', '10', '--eval-seeds', '1000']) == 1
    assert 'pip install "hill_muscle_ros[rl]"' in capsys.readouterr().err


def test_example_trains_and_evaluates_with_a_tiny_budget(capsys):
    pytest.importorskip('stable_baselines3')
    example = _example()
    assert example.main(['--timesteps', '64', '--num-envs', '1', '--eval-seeds', '1000']) == 0
    out = capsys.readouterr().out.splitlines()
    assert out[1].startswith('PPO (64 steps, ')
