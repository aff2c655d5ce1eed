"""jaxchain.bridges.SB3VecEnv against the real Stable-Baselines3 (the sb3 extra, in dev).

The adapter must give what SB3's own `DummyVecEnv` over the single Gymnasium envs
gives (same observations to 1e-6, float32 rewards, dones, `terminal_observation`,
`TimeLimit.truncated`, across hundreds of episode ends), work with SB3's wrappers and
helpers, survive pickle and deepcopy, and let SB3's PPO learn.
"""

import copy
import pickle
import warnings

import numpy as np
import pytest

from jaxchain import bridges

pytest.importorskip("stable_baselines3", reason="the sb3 extra (pip install -e '.[sb3]')")
import torch  # noqa: E402
from stable_baselines3 import PPO  # noqa: E402
from stable_baselines3.common.evaluation import evaluate_policy  # noqa: E402
from stable_baselines3.common.vec_env import DummyVecEnv, VecEnv, VecMonitor  # noqa: E402

import jaxchain as jc  # noqa: E402

MAX_STEPS = 3
N = 3


@pytest.fixture(scope="module")
def made():
  return jc.env.make("push_box_easy", max_steps=MAX_STEPS)


@pytest.fixture(scope="module")
def venv(made):
  env, params = made
  return bridges.SB3VecEnv(env, num_envs=N, params=params)


def test_is_an_sb3_vec_env(made, venv):
  env, params = made
  assert isinstance(venv, VecEnv) and venv.num_envs == N
  assert venv.observation_space.shape == (env.obs_size,)
  assert venv.action_space.shape == (2,) and venv.action_space.dtype == np.float32
  assert venv.seed(7) == [7, 8, 9]  # SB3's rule: env i gets seed + i at the next reset.
  assert "num_envs=3" in repr(venv)


def test_steps_as_dummy_vec_env_does(made, venv):
  """Seeded alike, the jitted batch and SB3's DummyVecEnv over `GymnasiumEnv`s give the
  same observations, float32 rewards, dones and infos through an episode end (the
  observations before it bit for bit; after resets, see the 510-step test below)."""
  env, params = made
  dummy = DummyVecEnv([lambda: bridges.GymnasiumEnv(env, params) for _ in range(N)])
  assert venv.seed(20) == dummy.seed(20)
  np.testing.assert_array_equal(venv.reset(), dummy.reset())
  rng = np.random.default_rng(1)
  for t in range(MAX_STEPS):
    actions = rng.uniform(-1, 1, (N, 2)).astype(np.float32)
    obs, reward, done, infos = venv.step(actions)
    d_obs, d_reward, d_done, d_infos = dummy.step(actions)
    assert reward.dtype == d_reward.dtype == np.float32
    assert done.dtype == d_done.dtype == np.bool_
    np.testing.assert_array_equal(reward, d_reward)
    np.testing.assert_array_equal(done, d_done)
    assert obs.flags.writeable and obs.dtype == d_obs.dtype
    for i in range(N):
      assert infos[i]["TimeLimit.truncated"] == d_infos[i]["TimeLimit.truncated"]
      assert infos[i]["is_success"] == bool(d_infos[i]["success"])
      assert infos[i]["episode_length"] == int(d_infos[i]["episode_length"])
      assert ("terminal_observation" in infos[i]) == ("terminal_observation" in d_infos[i])
      if done[i]:
        np.testing.assert_array_equal(infos[i]["terminal_observation"],
                                      d_infos[i]["terminal_observation"])
    if not done.any():
      np.testing.assert_array_equal(obs, d_obs)
  assert done.all() and all(info["TimeLimit.truncated"] for info in infos)
  assert all(info["episode_length"] == MAX_STEPS for info in infos)  # The episode that ended.


def test_510_steps_with_resets_as_dummy_vec_env_does(made, venv):
  """510 steps, 170 episode ends per env, in one rollout: the jitted batch gives what
  DummyVecEnv over GymnasiumEnvs gives, the starts after every reset included (each
  GymnasiumEnv, reset() by DummyVecEnv after its episode ends, starts from the key its
  last step drew, as the batch's auto-reset does). Observations agree to 1e-6, not bit
  for bit: the vmapped step rounds `t / max_steps` one ulp apart on some steps."""
  env, params = made
  dummy = DummyVecEnv([lambda: bridges.GymnasiumEnv(env, params) for _ in range(N)])
  venv.seed(31)
  dummy.seed(31)
  np.testing.assert_array_equal(venv.reset(), dummy.reset())
  rng = np.random.default_rng(3)
  ends, worst = 0, 0.0
  for t in range(510):
    actions = rng.uniform(-1, 1, (N, 2)).astype(np.float32)
    obs, reward, done, infos = venv.step(actions)
    d_obs, d_reward, d_done, d_infos = dummy.step(actions)
    worst = max(worst, float(np.abs(obs - d_obs).max()))
    np.testing.assert_allclose(obs, d_obs, rtol=0, atol=1e-6, err_msg=f"step {t}")
    np.testing.assert_array_equal(reward, d_reward)
    np.testing.assert_array_equal(done, d_done)
    for i in np.flatnonzero(done):
      np.testing.assert_allclose(infos[i]["terminal_observation"],
                                 d_infos[i]["terminal_observation"], rtol=0, atol=1e-6)
      assert infos[i]["TimeLimit.truncated"] == d_infos[i]["TimeLimit.truncated"]
    ends += int(done.sum())
  assert ends == 510 and worst < 1e-6


def test_seeds_follow_one_rule(made, venv):
  env, params = made
  with pytest.raises(ValueError, match=r"seed: expected an int >= 0 \(any size\) or None"):
    venv.seed(-5)
  assert venv.seed(2**64) == [2**64, 2**64 + 1, 2**64 + 2]
  obs = venv.reset()  # No OverflowError: every bit of the seed counts.
  single = bridges.GymnasiumEnv(env, params)
  np.testing.assert_array_equal(obs[2], single.reset(seed=2**64 + 2)[0])
  assert len(venv.seed()) == N  # SB3 draws a seed below 2**32 and adds i: fine too.
  venv.reset()


def test_attributes_methods_and_wrappers(made, venv):
  env, params = made
  assert venv.get_attr("level_names") == [env.level_names] * N
  assert venv.get_attr("render_mode", indices=[1]) == [None]
  assert venv.get_attr("metadata")[0]["render_fps"] > 0
  assert venv.has_attr("num_bodies") and not venv.has_attr("nope")
  assert venv.env_method("observation_space", params, indices=0)[0].shape == (env.obs_size,)
  assert venv.env_is_wrapped(VecMonitor) == [False] * N
  longer = params.replace(max_steps=MAX_STEPS + 1)
  venv.set_attr("params", longer)
  assert venv.params is longer
  venv.set_attr("params", params)
  with pytest.raises(ValueError, match="one value for all 3 envs"):
    venv.set_attr("params", longer, indices=[0])
  with pytest.raises(AttributeError, match="cannot set"):
    venv.set_attr("num_bodies", 4)
  with warnings.catch_warnings(record=True):
    warnings.simplefilter("always")
    assert venv.get_images() == [None] * N  # No rgb_array render mode.
  # SB3's VecMonitor and evaluate_policy run on it.
  monitored = VecMonitor(venv)
  monitored.seed(0)
  monitored.reset()
  for _ in range(MAX_STEPS):
    *_, infos = monitored.step(np.zeros((N, 2), np.float32))
  assert all("episode" in info for info in infos)
  with pytest.raises(ValueError, match="action: expected shape"):
    venv.step(np.zeros((N + 1, 2), np.float32))


def test_pickle_and_deepcopy_then_step(venv):
  venv.seed(3)
  venv.reset()
  copies = (copy.deepcopy(venv), pickle.loads(pickle.dumps(venv)))
  want = venv.step(np.ones((N, 2), np.float32))
  for copied in copies:
    assert type(copied) is bridges.SB3VecEnv
    got = copied.step(np.ones((N, 2), np.float32))
    np.testing.assert_array_equal(got[0], want[0])
    np.testing.assert_array_equal(got[1], want[1])


def test_ppo_learns():
  """SB3's PPO on platformer1 (episodes of 64 steps, distance shaping), 8 envs, 8k
  steps: the mean return of 8 seeded evaluation episodes rises (seeds 0-2: about
  0.21 -> 0.58)."""
  torch.set_num_threads(1)
  kwargs = dict(levels=["platformer1"], max_steps=64, shaping=0.1)
  train = VecMonitor(bridges.SB3VecEnv("reach_flag", num_envs=8, **kwargs))
  evaluation = VecMonitor(bridges.SB3VecEnv("reach_flag", num_envs=8, **kwargs))
  model = PPO("MlpPolicy", train, n_steps=64, batch_size=128, n_epochs=4, learning_rate=3e-3,
              gamma=0.9, seed=0, device="cpu", policy_kwargs=dict(net_arch=[32, 32]))
  evaluation.seed(100)
  before, _ = evaluate_policy(model, evaluation, n_eval_episodes=8, deterministic=False)
  model.learn(8192)
  evaluation.seed(100)
  after, _ = evaluate_policy(model, evaluation, n_eval_episodes=8, deterministic=False)
  assert after > before + 0.2, (before, after)
  losses = model.logger.name_to_value
  assert all(np.isfinite(v) for k, v in losses.items() if k.startswith("train/")), losses


def test_docstring_examples():
  """The class is built lazily, so `doctest.testmod(bridges)` does not see it."""
  import doctest
  tests = doctest.DocTestFinder().find(bridges.SB3VecEnv, "SB3VecEnv", globs={})
  runner = doctest.DocTestRunner(optionflags=doctest.ELLIPSIS)
  for test in tests:
    runner.run(test)
  assert runner.tries > 0 and runner.failures == 0, (runner.tries, runner.failures)
