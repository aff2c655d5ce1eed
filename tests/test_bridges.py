"""jaxchain.bridges against the real gymnax and Gymnasium packages.

The adapters must give what the wrapped env gives: the gymnax step is jaxchain's
`env.step` (same key split, same auto-reset), the vector env is the vmapped step
in NumPy, and the single env passes Gymnasium's own checker. Tasks are tiny
(`max_steps` of a few steps) so episodes end inside a test.
"""

import copy
import doctest
import pathlib
import pickle
import subprocess
import sys
import warnings

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxchain as jc
from jaxchain import bridges

gymnax = pytest.importorskip("gymnax", reason="the rl extra (pip install -e '.[rl]')")
gymnasium = pytest.importorskip("gymnasium", reason="the rl extra (pip install -e '.[rl]')")
from gymnasium.utils.env_checker import check_env  # noqa: E402
from gymnax.environments import environment as gymnax_environment  # noqa: E402
from gymnax.environments import spaces as gymnax_spaces  # noqa: E402

MAX_STEPS = 3
# A discrete task with few bodies if the library has one, else the platformer.
DISCRETE = "push_box_discrete" if "push_box_discrete" in jc.env.TASKS else "reach_flag"


def test_import_jaxchain_needs_neither_package():
  code = ("import sys, jaxchain, jaxchain.bridges, jaxchain.env; "
          "print(sorted(m for m in ('gymnax', 'gymnasium', 'flax', 'optax', 'stable_baselines3', "
          "'torch') if m in sys.modules))")
  out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
  assert out.stdout.strip() == "[]"


def test_doctests():
  result = doctest.testmod(bridges, optionflags=doctest.ELLIPSIS)
  assert result.attempted > 0 and result.failed == 0


def test_one_module_per_client():
  """`jaxchain.bridges` is a package (DESIGN.md section 7): one module per client, what
  they share in `common`, the public names re-exported by `__init__` (the classes
  lazily, under `jaxchain.bridges.<name>` for pickle)."""
  import jaxchain.bridges.common
  import jaxchain.bridges.gymnasium
  import jaxchain.bridges.gymnax
  import jaxchain.bridges.sb3
  root = pathlib.Path(bridges.__file__).parent
  assert root.name == "bridges" and bridges.__file__.endswith("__init__.py")
  assert sorted(p.name for p in root.glob("*.py")) == [
      "__init__.py", "common.py", "gymnasium.py", "gymnax.py", "sb3.py"]
  assert jaxchain.bridges.gymnax.register_gymnax is bridges.register_gymnax
  assert jaxchain.bridges.gymnasium.register_gymnasium is bridges.register_gymnasium
  for name in ("GymnaxEnv", "GymnasiumEnv", "GymnasiumVectorEnv"):
    cls = getattr(bridges, name)
    assert (cls.__module__, cls.__qualname__) == ("jaxchain.bridges", name)
  assert set(bridges.__all__) == {
      "GymnaxEnv", "GymnaxState", "GymnasiumEnv", "GymnasiumVectorEnv", "SB3VecEnv",
      "GYMNAX_IDS", "GYMNASIUM_IDS", "register_gymnax", "register_gymnasium"}


def test_unknown_attribute():
  with pytest.raises(AttributeError, match="no attribute"):
    bridges.NotAnAdapter  # noqa: B018


# gymnax.


@pytest.fixture(scope="module")
def gymnax_pair():
  env, params = jc.env.make("push_box_easy", max_steps=MAX_STEPS)
  return env, params, bridges.GymnaxEnv(env, params)


def test_gymnax_interface(gymnax_pair):
  env, params, genv = gymnax_pair
  assert isinstance(genv, gymnax_environment.Environment)
  assert genv.default_params is params
  assert genv.name == "PushBoxEasy-jaxchain"
  assert genv.num_actions == 2
  space = genv.action_space(params)
  assert isinstance(space, gymnax_spaces.Box)
  assert (space.low, space.high, tuple(space.shape)) == (-1.0, 1.0, (2,))
  obs_space = genv.observation_space(params)
  assert isinstance(obs_space, gymnax_spaces.Box)
  assert tuple(obs_space.shape) == env.observation_space(params).shape
  assert "GymnaxEnv" in repr(genv)


def test_gymnax_step_is_jaxchains_step(gymnax_pair):
  """gymnax's inherited `step` (auto-reset by gymnax) equals jaxchain's `env.step`
  on the same keys, through an episode end, batched under vmap."""
  env, params, genv = gymnax_pair
  b = 2
  keys = jax.random.split(jax.random.key(0), b)
  obs_g, state_g = jax.vmap(genv.reset, in_axes=(0, None))(keys, params)
  obs_j, state_j = jax.jit(jax.vmap(env.reset, in_axes=(0, None)))(keys, params)
  np.testing.assert_array_equal(obs_g, obs_j)
  step_g = jax.jit(jax.vmap(genv.step, in_axes=(0, 0, 0, None)))
  step_j = jax.jit(jax.vmap(env.step, in_axes=(0, 0, 0, None)))
  action = jnp.array([[1.0, 0.0], [-0.5, 0.5]], jnp.float32)
  ended = False
  for t in range(MAX_STEPS + 1):
    keys = jax.random.split(jax.random.key(t + 1), b)
    obs_g, state_g, r_g, term, trunc, info_g = step_g(keys, state_g, action, params)
    obs_j, state_j, r_j, done, info_j = step_j(keys, state_j, action, params)
    np.testing.assert_array_equal(obs_g, obs_j)
    np.testing.assert_array_equal(r_g, r_j)
    np.testing.assert_array_equal(term | trunc, done)
    np.testing.assert_array_equal(term, info_j["terminated"])
    np.testing.assert_array_equal(trunc, info_j["truncated"])
    np.testing.assert_array_equal(info_g["final_observation"], info_j["final_obs"])
    np.testing.assert_array_equal(state_g.env_state.t, state_j.t)
    np.testing.assert_array_equal(state_g.time, state_j.t)  # Both 0 after a reset.
    np.testing.assert_array_equal(info_g["success"], info_j["success"])
    ended = ended or bool(np.any(done))
  assert ended, "the episode should have been truncated at max_steps"
  assert bool(genv.is_terminal(state_g, params).shape == (b,))


def test_gymnax_transition_gradients(gymnax_pair):
  """Stopped by default (gymnax's rule); `with_transition_gradients()` lets jaxchain's
  differentiable step through."""
  env, params, genv = gymnax_pair
  _, state = genv.reset(jax.random.key(0), params)
  key = jax.random.key(1)

  def speed(e, a):
    obs, *_ = e.step_env(key, state, a, params)
    return obs[2]  # The player's x velocity.

  a = jnp.array([0.5, 0.0], jnp.float32)
  assert float(jax.jit(jax.grad(lambda a: speed(genv, a)))(a)[0]) == 0.0
  live = genv.with_transition_gradients()
  assert live.transition_gradients_enabled and not genv.transition_gradients_enabled
  assert float(jax.jit(jax.grad(lambda a: speed(live, a)))(a)[0]) > 0.0


def test_gymnax_register_and_make():
  ids = bridges.register_gymnax()
  assert "PushBoxEasy-jaxchain" in ids and "ReachFlag-jaxchain" in ids
  assert set(ids) <= set(gymnax.registered_envs)
  assert bridges.register_gymnax() == ids  # Idempotent.
  genv, params = gymnax.make("PushBoxEasy-jaxchain", max_steps=7)
  assert isinstance(genv, bridges.GymnaxEnv)
  assert params.max_steps == 7


def test_gymnax_discrete_space():
  genv = bridges.GymnaxEnv(DISCRETE, max_steps=MAX_STEPS)
  space = genv.action_space(genv.default_params)
  assert isinstance(space, gymnax_spaces.Discrete)
  assert space.n == genv.num_actions == genv.env.action_space().n


# Gymnasium.


def test_gymnasium_env_passes_check_env():
  bridges.register_gymnasium()
  env = gymnasium.make(bridges.GYMNASIUM_IDS[DISCRETE], max_steps=MAX_STEPS)
  with warnings.catch_warnings(record=True) as caught:
    warnings.simplefilter("always")
    check_env(env.unwrapped)  # Raises on any API violation; render modes included.
  # The only remarks: the observation box is unbounded (it is: velocities, offsets).
  remarks = {str(w.message) for w in caught}
  assert all("infinity" in m for m in remarks), remarks
  env.close()


def test_gymnasium_env_episode():
  env = bridges.GymnasiumEnv("push_box_easy", max_steps=MAX_STEPS, render_mode="rgb_array")
  assert isinstance(env, gymnasium.Env)
  assert env.action_space == gymnasium.spaces.Box(-1.0, 1.0, (2,), np.float32)
  with pytest.raises(RuntimeError, match="reset"):
    env.step(np.zeros(2, np.float32))
  obs, info = env.reset(seed=3)
  assert obs.dtype == np.float32 and obs in env.observation_space and info == {}
  again, _ = env.reset(seed=3)
  np.testing.assert_array_equal(obs, again)
  frame = env.render()
  assert frame.dtype == np.uint8 and frame.ndim == 3 and frame.shape[-1] == 3
  for t in range(MAX_STEPS):
    obs, reward, terminated, truncated, info = env.step(np.array([1.0, 0.0], np.float32))
    assert isinstance(reward, float) and isinstance(terminated, bool)
    assert set(info) >= {"success", "invalid_action", "episode_return", "episode_length"}
  assert truncated and not terminated and int(info["episode_length"]) == MAX_STEPS
  with pytest.raises(ValueError, match="action: expected shape"):
    env.step(np.float32(1.0))  # A scalar is not broadcast.


@pytest.fixture(scope="module")
def vector_pair():
  env, params = jc.env.make("push_box_easy", max_steps=MAX_STEPS)
  return env, params, bridges.GymnasiumVectorEnv(env, num_envs=3, params=params)


def test_vector_env_spaces(vector_pair):
  env, params, venv = vector_pair
  assert isinstance(venv, gymnasium.vector.VectorEnv)
  assert venv.num_envs == 3
  assert venv.metadata["autoreset_mode"] == gymnasium.vector.AutoresetMode.SAME_STEP
  assert venv.single_action_space == gymnasium.spaces.Box(-1.0, 1.0, (2,), np.float32)
  assert venv.action_space.shape == (3, 2)
  assert venv.single_observation_space.shape == env.observation_space(params).shape
  assert venv.observation_space.shape == (3,) + env.observation_space(params).shape


def test_vector_env_is_the_vmapped_step(vector_pair):
  """NumPy in and out, equal to jaxchain's vmapped step; same-step autoreset with
  Gymnasium's `final_obs` / `final_info` masks."""
  env, params, venv = vector_pair
  obs, info = venv.reset(seed=5)
  assert isinstance(obs, np.ndarray) and obs.shape == (3, env.obs_size) and info == {}
  again, _ = venv.reset(seed=5)
  np.testing.assert_array_equal(obs, again)
  actions = np.tile(np.array([[0.8, -0.2]], np.float32), (3, 1))
  # The reference: the same keys through jaxchain directly. Env i is seeded with 5 + i
  # (SyncVectorEnv's rule); its key splits as a GymnasiumEnv's does.
  split = jax.vmap(jax.random.split)
  pair = split(jnp.stack([jax.random.key(5 + i) for i in range(3)]))
  keys = pair[:, 0]
  ref_obs, ref_state = jax.jit(jax.vmap(env.reset, in_axes=(0, None)))(pair[:, 1], params)
  np.testing.assert_array_equal(obs, ref_obs)
  step = jax.jit(jax.vmap(env.step, in_axes=(0, 0, 0, None)))
  for t in range(MAX_STEPS):
    obs, reward, terminated, truncated, info = venv.step(actions)
    pair = split(keys)
    keys = pair[:, 0]
    ref_obs, ref_state, ref_r, ref_done, ref_info = step(pair[:, 1], ref_state,
                                                         jnp.asarray(actions), params)
    assert isinstance(reward, np.ndarray) and reward.shape == (3,)
    assert reward.dtype == np.float64  # As gymnasium's SyncVectorEnv gives rewards.
    np.testing.assert_array_equal(obs, ref_obs)
    np.testing.assert_array_equal(reward, np.asarray(ref_r, np.float64))
    np.testing.assert_array_equal(terminated | truncated, ref_done)
    np.testing.assert_array_equal(info["episode_return"], ref_info["episode_return"])
    assert info["_success"].all()
  assert truncated.all() and not terminated.any()
  assert info["_final_obs"].all() and info["final_obs"].dtype == object
  np.testing.assert_array_equal(np.stack(info["final_obs"]), ref_info["final_obs"])
  assert info["final_info"]["_episode_length"].all()
  np.testing.assert_array_equal(info["final_info"]["episode_length"], MAX_STEPS)
  assert (info["episode_length"] == MAX_STEPS).all()
  with pytest.raises(ValueError, match=r"action: expected shape \(3, 2\)"):
    venv.step(np.zeros((2, 2), np.float32))
  assert "num_envs=3" in repr(venv)


def test_vector_env_make_vec():
  ids = bridges.register_gymnasium()
  assert bridges.GYMNASIUM_IDS["push_box_easy"] in ids
  venv = gymnasium.make_vec(bridges.GYMNASIUM_IDS["push_box_easy"], num_envs=2,
                            vectorization_mode="vector_entry_point", max_steps=MAX_STEPS)
  assert isinstance(venv.unwrapped, bridges.GymnasiumVectorEnv) and venv.num_envs == 2
  assert venv.unwrapped.params.max_steps == MAX_STEPS


def test_bad_arguments():
  env, params = jc.env.make("push_box_easy")
  with pytest.raises(TypeError, match="need a task name"):
    bridges.GymnasiumVectorEnv(env, num_envs=2, max_steps=4)
  with pytest.raises(TypeError, match="only with a built env"):
    bridges.GymnaxEnv("push_box_easy", params)
  with pytest.raises(ValueError, match="num_envs"):
    bridges.GymnasiumVectorEnv("push_box_easy", num_envs=0)
  with pytest.raises(ValueError, match="render_mode"):
    bridges.GymnasiumEnv(env, params, render_mode="human")


def test_vector_env_seeds_each_env_like_a_single_env(vector_pair):
  """`reset(seed=[a, b, c])` gives env i the single env's episode under seed i (its
  reset and every step's key), as SyncVectorEnv over GymnasiumEnvs would; a None keeps
  that env's own key; `reset_mask` resets only the masked envs."""
  env, params, venv = vector_pair
  seeds = [11, 3, 7]
  obs, _ = venv.reset(seed=seeds)
  singles = [bridges.GymnasiumEnv(env, params) for _ in seeds]
  firsts = [s.reset(seed=seed)[0] for s, seed in zip(singles, seeds)]
  np.testing.assert_array_equal(obs, np.stack(firsts))
  assert not np.array_equal(obs[0], obs[1])  # The seeds differ, and so do the starts.
  rng = np.random.default_rng(0)
  for t in range(MAX_STEPS - 1):  # Before the step limit: no auto-reset yet.
    actions = rng.uniform(-1, 1, (3, 2)).astype(np.float32)
    obs, reward, *_ = venv.step(actions)
    for i, single in enumerate(singles):
      o, r, *_ = single.step(actions[i])
      np.testing.assert_array_equal(obs[i], o)
      assert reward[i] == r
  # A None goes on from that env's key: the same as not reseeding it.
  a, _ = venv.reset(seed=[11, None, 7])
  b, _ = venv.reset(seed=[11, 3, 7])
  np.testing.assert_array_equal(a[[0, 2]], b[[0, 2]])
  # reset_mask: env 1 restarts, envs 0 and 2 keep their observation.
  obs, *_ = venv.step(np.zeros((3, 2), np.float32))
  again, _ = venv.reset(seed=[0, 3, 0], options={"reset_mask": np.array([False, True, False])})
  np.testing.assert_array_equal(again[[0, 2]], obs[[0, 2]])
  np.testing.assert_array_equal(again[1], b[1])
  with pytest.raises(ValueError, match="a list of 3 seeds"):
    venv.reset(seed=[1, 2])
  with pytest.raises(ValueError, match="unknown options"):
    venv.reset(options={"level": 2})
  with pytest.raises(ValueError, match="reset_mask"):
    venv.reset(options={"reset_mask": np.zeros(3, bool)})


def test_one_seed_rule_for_every_env(vector_pair):
  """A seed is an int >= 0 of any size (Gymnasium's rule; all its bits count) or None,
  for the single env and the vector env alike; anything else is one ValueError."""
  env, params, venv = vector_pair
  single = bridges.GymnasiumEnv(env, params)
  bad = r"seed: expected an int >= 0 \(any size\) or None, got "
  for seed in (-1, -5, 1.5, "3", True, np.float64(2.0)):
    with pytest.raises(ValueError, match=bad):
      single.reset(seed=seed)
    with pytest.raises(ValueError, match=bad):
      venv.reset(seed=seed)
  for seeds in ([-1, 3, 0], [0, 2.0, 1], [0, None, "1"]):
    with pytest.raises(ValueError, match=bad):
      venv.reset(seed=seeds)
  # Large seeds work, use all their bits, and env i still draws what a single env does.
  big = [2**32, 2**63, 2**64]
  starts = [single.reset(seed=s)[0] for s in [0] + big]
  assert len({o.tobytes() for o in starts}) == 4  # 2**32 is not 0 (nor 2**64).
  obs, _ = venv.reset(seed=2**63)  # Env i: 2**63 + i.
  np.testing.assert_array_equal(obs[0], starts[2])
  np.testing.assert_array_equal(obs[1], single.reset(seed=2**63 + 1)[0])
  obs, _ = venv.reset(seed=big)
  np.testing.assert_array_equal(obs, np.stack(starts[1:]))
  # Below 2**32 a seed is the JAX key it always was (the reference of the test above).
  first = single.reset(seed=7)[0]
  ref, _ = env.reset(jax.random.split(jax.random.key(7))[1], params)
  np.testing.assert_array_equal(first, ref)


def test_discrete_actions_must_be_integers(vector_pair):
  """A float or a string given as a discrete action is refused (no silent cast: 2.7
  was action 2, '1' action 1); an integer out of range is flagged invalid (the env
  truncates), also one that int32 cannot hold. Continuous actions take real numbers."""
  env = bridges.GymnasiumEnv(DISCRETE, max_steps=MAX_STEPS)
  env.reset(seed=0)
  wrong = r"action: Discrete\(\d+\) takes integer actions, got "
  for action in (2.7, "1", np.float32(2.0), True, np.array(1.0), None):
    with pytest.raises(TypeError, match=wrong):
      env.step(action)
  *_, truncated, info = env.step(np.int64(2**40))  # Not 0 (its int32 cast).
  assert bool(info["invalid_action"]) and truncated
  env.reset(seed=0)
  *_, truncated, info = env.step(np.uint8(2))
  assert not info["invalid_action"] and not truncated
  # The vector adapters share the rule (continuous here: numbers, never strings or bools).
  _, _, venv = vector_pair
  venv.reset(seed=0)
  for actions in (np.full((3, 2), "0.5"), np.ones((3, 2), bool), np.ones((3, 2), complex)):
    with pytest.raises(TypeError, match=r"action: Box\(-1.0, 1.0, \(2,\)\) takes real numbers"):
      venv.step(actions)
  assert not venv.step(np.ones((3, 2), np.int64))[-1]["invalid_action"].any()


def test_vector_env_resets_as_sync_vector_env_over_single_envs(vector_pair):
  """Across episode ends (SAME_STEP autoreset), the vector env gives what Gymnasium's
  SyncVectorEnv over GymnasiumEnvs gives: there each env is reset() after its episode
  ends and starts from the key its last step drew, as the vmapped step does."""
  env, params, venv = vector_pair
  sync = gymnasium.vector.SyncVectorEnv([lambda: bridges.GymnasiumEnv(env, params)] * 3,
                                        autoreset_mode=gymnasium.vector.AutoresetMode.SAME_STEP)
  np.testing.assert_array_equal(venv.reset(seed=9)[0], sync.reset(seed=9)[0])
  rng = np.random.default_rng(2)
  ends = 0
  for t in range(4 * MAX_STEPS):
    actions = rng.uniform(-1, 1, (3, 2)).astype(np.float32)
    obs, reward, terminated, truncated, info = venv.step(actions)
    s_obs, s_reward, s_terminated, s_truncated, s_info = sync.step(actions)
    np.testing.assert_allclose(obs, s_obs, rtol=0, atol=1e-6)  # t / max_steps: an ulp.
    np.testing.assert_array_equal(reward, s_reward)
    np.testing.assert_array_equal(terminated | truncated, s_terminated | s_truncated)
    if "final_obs" in info:
      ends += int(info["_final_obs"].sum())
      for i in np.flatnonzero(info["_final_obs"]):
        np.testing.assert_allclose(info["final_obs"][i], s_info["final_obs"][i], atol=1e-6)
  assert ends == 12


def test_vector_env_call_get_attr_set_attr(vector_pair):
  env, params, venv = vector_pair
  assert venv.get_attr("level_names") == (env.level_names,) * 3
  assert venv.get_attr("action_space") == (venv.single_action_space,) * 3
  assert venv.get_attr("render_mode") == (None,) * 3
  assert venv.call("obs_size") == (env.obs_size,) * 3
  assert venv.call("action_space") == (venv.single_action_space,) * 3
  # A method of the jaxchain env, called per env with the arguments.
  spaces = venv.call("observation_space", params)
  assert len(spaces) == 3 and spaces[0].shape == (env.obs_size,)
  assert venv.call("render") == (None,) * 3  # No render mode: no frames.
  with pytest.raises(AttributeError, match="no attribute 'nope'"):
    venv.get_attr("nope")
  # params for all envs alike; a different value per env, or another attribute, refused.
  longer = params.replace(max_steps=MAX_STEPS + 2)
  venv.set_attr("params", longer)
  assert venv.params is longer
  venv.set_attr("params", [params] * 3)
  assert venv.params is params
  with pytest.raises(ValueError, match="one value for all 3 envs"):
    venv.set_attr("params", [params, longer, params])
  with pytest.raises(AttributeError, match="cannot set 'env'"):
    venv.set_attr("env", env)
  with pytest.raises(ValueError, match="render_mode"):
    venv.set_attr("render_mode", "human")


# Copies: pickle and deepcopy (gymnax's Gym wrappers deep-copy the env they wrap).


def _roundtrips(obj):
  return [("deepcopy", copy.deepcopy(obj)), ("pickle", pickle.loads(pickle.dumps(obj)))]


def test_copies_of_the_gymnasium_envs_step_like_the_original():
  single = bridges.GymnasiumEnv("push_box_easy", max_steps=MAX_STEPS)
  single.reset(seed=4)
  vector = bridges.GymnasiumVectorEnv("push_box_easy", num_envs=2, max_steps=MAX_STEPS)
  vector.reset(seed=4)
  a = np.array([0.5, 0.5], np.float32)
  copies = _roundtrips(single)
  want = single.step(a)[0]
  for name, copied in copies:
    assert type(copied) is bridges.GymnasiumEnv, name
    np.testing.assert_array_equal(copied.step(a)[0], want)
  copies = _roundtrips(vector)
  want = vector.step(np.ones((2, 2), np.float32))
  for name, copied in copies:
    assert type(copied) is bridges.GymnasiumVectorEnv, name
    got = copied.step(np.ones((2, 2), np.float32))
    np.testing.assert_array_equal(got[0], want[0])
    np.testing.assert_array_equal(got[1], want[1])


def test_gymnax_env_copies_and_gymnax_gym_wrapper(gymnax_pair):
  """gymnax's own `GymnaxToGymWrapper` deep-copies the env; it then runs episodes."""
  from gymnax.wrappers.gym import GymnaxToGymWrapper
  env, params, genv = gymnax_pair
  for name, copied in _roundtrips(genv):
    assert type(copied) is bridges.GymnaxEnv, name
    o1, _ = copied.reset(jax.random.key(0), params)
    o2, _ = genv.reset(jax.random.key(0), params)
    np.testing.assert_array_equal(o1, o2)
  wrapped = GymnaxToGymWrapper(genv, params, seed=0)
  obs, info = wrapped.reset(seed=1)
  assert obs.shape == (env.obs_size,) and wrapped.action_space.shape == (2,)
  ended = False
  for _ in range(MAX_STEPS):
    obs, reward, terminated, truncated, info = wrapped.step(jnp.array([1.0, 0.0], jnp.float32))
    ended = ended or bool(terminated) or bool(truncated)
  assert ended and np.isfinite(float(reward))
  frame = np.asarray(wrapped.render())
  assert frame.dtype == np.uint8 and frame.ndim == 3 and frame.shape[-1] == 3
