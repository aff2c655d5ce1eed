"""examples/ppo.py: a tiny PPO run learns (the return rises), and its parts are right.

The full runs (push_box_easy >= 95%, platformer1 >= 80%) are in
benchmarks/results/ppo.md; here the budget is a few thousand env steps.
"""

import importlib.util
import math
import pathlib
import sys

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxchain as jc

pytest.importorskip("optax", reason="the rl extra (pip install -e '.[rl]')")

ROOT = pathlib.Path(__file__).resolve().parents[1]


def _load():
  spec = importlib.util.spec_from_file_location("ppo_example", ROOT / "examples" / "ppo.py")
  module = importlib.util.module_from_spec(spec)
  sys.modules[spec.name] = module  # Dataclasses look their module up while being built.
  spec.loader.exec_module(module)
  return module


ppo = _load()


def test_tiny_run_return_rises(tmp_path):
  """A tiny run on platformer1 with distance shaping: episodes of 64 steps, 8 envs,
  24 updates (12k env steps). The mean return of the episodes that ended rises from
  the first updates to the last ones (the policy learns to head for the flag), and
  the curve files are written."""
  env, params = jc.env.make("reach_flag", levels=["platformer1"], max_steps=64, shaping=0.1)
  config = ppo.PPOConfig(num_envs=8, num_steps=64, total_timesteps=8 * 64 * 24, update_epochs=4,
                         num_minibatches=4, lr=3e-3, hidden=32, gamma=0.9, normalize_obs=True,
                         obs_features=None)
  policy, curve = jax.jit(ppo.make_train(env, params, config))(jax.random.key(0))
  ret = np.asarray(curve["return"])
  assert ret.shape == (config.num_updates,) == (24,)
  assert np.all(np.asarray(curve["episodes"]) == 8)  # Every env ends one episode per update.
  assert np.all(np.isfinite(ret))
  first, last = ret[:4].mean(), ret[-4:].mean()
  assert last > first + 0.15, (first, last, ret)  # Seeds 0-2: about 0.22 -> 0.55.
  assert np.all(np.isfinite(np.asarray(policy["norm"]["var"])))
  csv_path, png_path = ppo.write_curve(tmp_path / "curve", curve, "tiny")
  back = ppo.read_curve(csv_path)
  np.testing.assert_allclose(back["return"], ret, rtol=1e-5, atol=1e-6)
  assert png_path.stat().st_size > 1000


def test_heads():
  """The categorical and Gaussian heads: log-probabilities normalise, entropies match
  their closed forms, sampling stays in the space after `to_env`."""
  key = jax.random.key(0)
  cat = ppo.head_of(jc.env.Discrete(5))
  assert cat.discrete and cat.n == 5
  out = jax.random.normal(key, (3, 5))
  theta = {"log_std": jnp.zeros(5)}
  logp_all = jnp.stack([ppo.log_prob(theta, cat, out, jnp.full((3,), a, jnp.int32))
                        for a in range(5)], -1)
  np.testing.assert_allclose(jnp.exp(logp_all).sum(-1), 1.0, rtol=1e-5)
  np.testing.assert_allclose(ppo.entropy(theta, cat, out),
                             -(jnp.exp(logp_all) * logp_all).sum(-1), rtol=1e-5)
  a = ppo.to_env(cat, ppo.sample(theta, cat, out, key))
  assert a.shape == (3,) and a.dtype == jnp.int32 and bool(jnp.all((a >= 0) & (a < 5)))

  box = ppo.head_of(jc.env.Box(-1.0, 1.0, (2,)))
  assert not box.discrete and box.n == 2
  theta = {"log_std": jnp.log(jnp.array([0.5, 2.0]))}
  mean = jnp.array([[0.0, 1.0]])
  x = jnp.array([[0.5, -1.0]])
  want = sum(-0.5 * ((xi - mi) / s) ** 2 - math.log(s) - 0.5 * math.log(2 * math.pi)
             for xi, mi, s in [(0.5, 0.0, 0.5), (-1.0, 1.0, 2.0)])
  np.testing.assert_allclose(ppo.log_prob(theta, box, mean, x), [want], rtol=1e-5)
  want_h = sum(math.log(s) + 0.5 * (1 + math.log(2 * math.pi)) for s in (0.5, 2.0))
  np.testing.assert_allclose(ppo.entropy(theta, box, mean), [want_h], rtol=1e-5)
  a = ppo.to_env(box, jnp.array([[3.0, -0.25]]))
  np.testing.assert_array_equal(a, [[1.0, -0.25]])  # Clipped to the box.


def test_running_observation_statistics():
  """Merging batches gives the mean and variance of everything seen."""
  rng = np.random.default_rng(0)
  a, b = rng.normal(2.0, 3.0, (50, 4)), rng.normal(-1.0, 0.5, (30, 4))
  norm = ppo.update_norm(ppo.update_norm(ppo.init_norm(4), jnp.asarray(a, jnp.float32)),
                         jnp.asarray(b, jnp.float32))
  both = np.concatenate([a, b])
  np.testing.assert_allclose(norm["mean"], both.mean(0), rtol=1e-4, atol=1e-4)
  np.testing.assert_allclose(norm["var"], both.var(0), rtol=1e-3)
  z = ppo.normalize(norm, jnp.asarray(both, jnp.float32))
  np.testing.assert_allclose(z.mean(0), 0.0, atol=1e-3)


def test_gae_bootstraps_truncation_not_termination():
  """GAE: a terminated step has no value after it; a truncated one carries the
  bootstrap in its reward; neither lets the next episode's advantage run back."""
  env, params = jc.env.make("push_box_easy", max_steps=4)
  config = ppo.PPOConfig(num_envs=1, num_steps=3, total_timesteps=3, gamma=0.5, gae_lambda=1.0)
  del env, params
  # One env, three steps; the episode ends (done) at step 1.
  f = jnp.float32
  traj = ppo.Transition(
      obs=jnp.zeros((3, 1, 1)), action=jnp.zeros((3, 1), jnp.int32), logp=jnp.zeros((3, 1)),
      value=jnp.array([[1.0], [2.0], [4.0]], f), reward=jnp.array([[1.0], [10.0], [0.0]], f),
      terminated=jnp.array([[False], [True], [False]]), done=jnp.array([[False], [True], [False]]),
      ep_return=jnp.zeros((3, 1)), ep_length=jnp.zeros((3, 1)), success=jnp.zeros((3, 1), bool))
  adv, target = ppo.gae_fn(config)(traj, jnp.array([8.0], f))
  # Step 2: 0 + 0.5 * 8 - 4 = 0. Step 1 (done): 10 - 2 = 8, nothing after it.
  # Step 0: delta 1 + 0.5 * 2 - 1 = 1, plus 0.5 * 8 = 5.
  np.testing.assert_allclose(adv[:, 0], [5.0, 8.0, 0.0])
  np.testing.assert_allclose(target[:, 0], [6.0, 10.0, 4.0])


def test_load_env():
  env, params = ppo.load_env("reach_flag", "platformer1", shaping=0.1)
  assert env.level_names == ("platformer1",) and float(params.shaping) == pytest.approx(0.1)
  assert ppo.episode_limit(env, params) == params.max_steps
  with pytest.raises(SystemExit, match="--env"):
    ppo.load_env("no_such_task")
  with pytest.raises(SystemExit, match="--level"):
    ppo.load_env(str(ROOT / "examples" / "ppo.py"), "platformer1")


def test_auto_features_leave_out_the_wall_slots():
  """The default `obs_features="auto"`: the player and the non-wall slots of the vector
  observation (push_box_easy: player + 4 box + 4 goal slots = 73 of 105), all of any
  other observation."""
  easy, _ = jc.env.make("push_box_easy")
  assert ppo.auto_features(easy) == 9 + 8 * 8 == 73 < easy.obs_size
  flag, _ = jc.env.make("reach_flag")
  assert ppo.auto_features(flag) == 9 + 8 * (1 + 4 + 4 + 6) == flag.obs_size - 8 * 4
  grid, _ = jc.env.make("push_box_easy", obs="grid")
  assert ppo.auto_features(grid) is None
  config = ppo.resolve_features(ppo.PPOConfig(), easy)
  assert config.obs_features == 73
  assert ppo.resolve_features(ppo.PPOConfig(obs_features=None), easy).obs_features is None
  with pytest.raises(ValueError, match="obs_features"):
    ppo.resolve_features(ppo.PPOConfig(obs_features="walls"), easy)
