"""jaxchain.env: gymnax-style tasks under jit and vmap, scripted rewards, auto-reset.

Compiles are the cost here (several seconds each on 2 cores), so every test shares
one jitted, vmapped `step` and `reset_level` per task (module fixtures), and the
scripted scenes of a task run as rows of one batch.
"""

import dataclasses
import doctest
import importlib.util
import pathlib

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxchain as jc
from jaxchain import env as jc_env
from jaxchain import levels

ROOT = pathlib.Path(__file__).resolve().parents[1]
B = 8  # Every batch in this module: one shape, one compile per function.
TRACES = {}  # Task name -> how many times its shared step was traced.


class Task:
  """An env, its params and its shared compiled functions."""

  def __init__(self, name):
    self.env, self.params = jc_env.make(name)
    TRACES[name] = 0

    def counted_step(key, state, action, params):
      TRACES[name] += 1
      return self.env.step(key, state, action, params)

    self.step = jax.jit(jax.vmap(counted_step, in_axes=(0, 0, 0, None)))
    self.reset_level = jax.jit(jax.vmap(self.env.reset_level, in_axes=(0, None, 0)))
    self.reset = jax.jit(jax.vmap(self.env.reset, in_axes=(0, None)))
    self.get_obs = jax.jit(jax.vmap(self.env.get_obs, in_axes=(0, None)))

  def states(self, level_idx, seed=0, params=None):
    """`B` fresh states, on the given levels (one row each, the rest cycling through
    the levels), and their keys."""
    level_idx = list(level_idx) + [k % self.env.num_levels for k in range(B - len(level_idx))]
    keys = jax.random.split(jax.random.key(seed), B)
    return self.reset_level(keys, params or self.params, jnp.asarray(level_idx, jnp.int32)), keys


@pytest.fixture(scope="module")
def push():
  return Task("push_box")


@pytest.fixture(scope="module")
def reach():
  return Task("reach_flag")


def _with(states, row, **world_changes):
  """`states` with some world fields of one row changed (`field=(index, value)`)."""
  w = states.world
  for field, (index, value) in world_changes.items():
    arr = getattr(w, field)
    w = dataclasses.replace(w, **{field: arr.at[(row,) + index].set(value)})
  return dataclasses.replace(states, world=w)


def _row(tree, i):
  return jax.tree.map(lambda x: x[i], tree)


def test_make_lists_tasks_and_rejects_bad_arguments():
  assert set(jc_env.TASKS) == {"push_box", "push_box_easy", "push_box_discrete", "reach_flag"}
  with pytest.raises(ValueError, match="unknown task 'sokoban'"):
    jc_env.make("sokoban")
  with pytest.raises(ValueError, match=r"3 box bodies, but the env holds 2 .*max_boxes=3"):
    jc_env.make("push_box", levels=["sokoban3"], max_boxes=2)
  with pytest.raises(TypeError, match="unknown keyword"):
    jc_env.make("push_box", max_crates=2)
  with pytest.raises(ValueError, match="no levels"):
    jc_env.make("push_box", levels=[])


def test_spaces_sample_valid_actions(push, reach):
  keys = jax.random.split(jax.random.key(1), 256)
  box, discrete = push.env.action_space(push.params), reach.env.action_space(reach.params)
  assert (box.shape, box.dtype, discrete.shape, discrete.dtype, discrete.n) == (
      (2,), np.float32, (), np.int32, 6)
  for space in (box, discrete):
    actions = jax.vmap(space.sample)(keys)
    assert actions.shape == (256,) + space.shape and actions.dtype == space.dtype
    assert bool(jnp.all(jax.vmap(space.contains)(actions)))
  assert set(np.asarray(jax.vmap(discrete.sample)(keys)).tolist()) == set(range(6))
  assert bool(jax.jit(box.contains)(jnp.array([1.0, -1.0])))
  for bad in (jnp.array([1.5, 0.0]), jnp.array([jnp.nan, 0.0]), jnp.zeros(3), jnp.zeros(2, jnp.int32)):
    assert not bool(box.contains(bad))
  for bad in (6, -1, jnp.array(2.0), jnp.array([1, 2])):
    assert not bool(discrete.contains(bad))
  obs_space = push.env.observation_space(push.params)
  sample = obs_space.sample(keys[0])
  assert sample.shape == (161,) and bool(obs_space.contains(sample))
  assert not bool(obs_space.contains(jnp.full(161, jnp.nan)))


def test_reset_under_jit_and_vmap(push, reach):
  for task, size in ((push, 161), (reach, 161)):
    keys = jax.random.split(jax.random.key(2), B)
    obs, state = task.reset(keys, task.params)
    assert obs.shape == (B, size) and obs.dtype == jnp.float32
    assert task.env.observation_space(task.params).shape == (size,)
    assert bool(jnp.all(jax.vmap(task.env.observation_space(task.params).contains)(obs)))
    assert np.all(np.asarray(state.t) == 0) and np.all(np.asarray(state.ret) == 0)
    level = np.asarray(state.level)
    assert level.min() >= 0 and level.max() < task.env.num_levels
    assert len(set(level.tolist())) > 1  # Random levels.
    # The player is slot 0, jittered by at most `jitter` from its level's start.
    start = np.asarray(task.env.level_data["pos"])[level, 0]
    offset = np.asarray(state.world.pos[:, 0]) - start
    assert np.all(np.abs(offset) <= task.params.jitter + 1e-6) and np.abs(offset).max() > 0
    assert np.all(np.asarray(state.world.category[:, 0]) == levels.PLAYER)
    np.testing.assert_array_equal(np.asarray(obs), np.asarray(task.get_obs(state, task.params)))


def test_observation_layout(push):
  state, _ = push.states([1])  # sokoban2: 2 boxes, 2 goals.
  obs = np.asarray(push.get_obs(state, push.params))[0]
  w = _row(state.world, 0)
  lv = levels.load("sokoban2")
  lo, hi = np.array(lv.bounds[:2]), np.array(lv.bounds[2:])
  p0 = np.asarray(w.pos[0])
  np.testing.assert_allclose(obs[:2], (p0 - lo) / (hi - lo), rtol=1e-6)
  np.testing.assert_array_equal(obs[2:9], 0.0)  # At rest, no contacts yet, t = 0.
  slots = obs[9:73].reshape(8, 8)  # 4 box slots, then 4 goal slots (then walls).
  np.testing.assert_array_equal(slots[:, 0], [1, 1, 0, 0, 1, 1, 0, 0])
  np.testing.assert_array_equal(slots[[2, 3, 6, 7]], 0.0)
  box = push.env.slots_of("box")[0]
  np.testing.assert_allclose(slots[0, 1:3], np.asarray(w.pos[box]) - p0, rtol=1e-6)
  np.testing.assert_allclose(slots[0, 5:7], [0.45, 0.45], rtol=1e-6)
  np.testing.assert_allclose(slots[4, 5:7], [0.05, 0.05], rtol=1e-6)
  assert slots[0, 7] == 0 and slots[4, 7] == 0  # No box on a goal in sokoban2.


def test_step_under_jit_and_vmap(push, reach):
  for task in (push, reach):
    b = B
    obs, state = task.reset(jax.random.split(jax.random.key(3), b), task.params)
    space = task.env.action_space(task.params)
    for k in range(3):
      keys = jax.random.split(jax.random.key(10 + k), b)
      actions = jax.vmap(space.sample)(keys)
      obs, state, reward, done, info = task.step(keys, state, actions, task.params)
    assert obs.shape == (b, task.env.obs_size) and obs.dtype == jnp.float32
    assert reward.shape == (b,) and reward.dtype == jnp.float32
    assert done.shape == (b,) and done.dtype == jnp.bool_
    assert set(info) == {"final_obs", "terminated", "truncated", "success", "invalid_action",
                         "episode_return", "episode_length", "status"}
    assert info["final_obs"].shape == obs.shape
    assert np.all(np.asarray(state.t) == 3) and not np.any(np.asarray(done))
    assert np.all(np.asarray(info["status"]) & jc.status.NON_FINITE == 0)
    assert np.all(np.isfinite(np.asarray(obs)))


def test_push_box_success_reward_done_and_auto_reset(push):
  # Rows: 0 sokoban1, a box sliding onto its goal; 1 sokoban1 at the step limit;
  # 2 sokoban3 (a box starts on a goal) standing still; 3 sokoban2 standing still.
  p = push.params
  states, _ = push.states([0, 0, 2, 1], seed=4, params=p.replace(jitter=0.0))
  box, goal = push.env.slots_of("box")[0], push.env.slots_of("goal")[0]
  goal_pos = np.asarray(states.world.pos[0, goal])
  states = _with(states, 0, pos=((box,), jnp.asarray(goal_pos - [0.52, 0.0])),
                 vel=((box,), jnp.array([3.0, 0.0])))
  states = dataclasses.replace(states, t=states.t.at[1].set(p.max_steps - 1))
  keys = jax.random.split(jax.random.key(5), B)
  obs, new, reward, done, info = push.step(keys, states, jnp.zeros((B, 2)), p)
  reward, done = np.asarray(reward), np.asarray(done)
  # Row 0: +1 for the box on the goal, +1 for success, shaping for 0.04 closer.
  assert 2.0 < reward[0] < 2.0 + p.shaping * 0.1
  assert done[0] and bool(info["terminated"][0]) and bool(info["success"][0])
  assert not bool(info["truncated"][0])
  final = np.asarray(info["final_obs"][0, 9:73]).reshape(8, 8)
  assert final[0, 7] == 1 and final[4, 7] == 1  # The box is on the goal, the goal filled.
  assert float(info["episode_return"][0]) == reward[0] and int(info["episode_length"][0]) == 1
  # Row 1: truncated, not terminated, at the step limit.
  assert done[1] and bool(info["truncated"][1]) and not bool(info["terminated"][1])
  assert int(info["episode_length"][1]) == p.max_steps and not bool(info["success"][1])
  # Rows 2, 3: nothing happens; sokoban3's box that started home earns nothing more.
  assert reward[2] == 0 and reward[3] == 0 and not done[2] and not done[3]
  assert np.asarray(obs[2, 9:73]).reshape(8, 8)[0, 7] == 1
  # Where done, obs and state are a fresh reset with the step's reset key.
  obs_reset, fresh = push.reset(jax.vmap(lambda k: jax.random.split(k)[1])(keys), p)
  for i in (0, 1):
    chex_equal(_row(new, i), _row(fresh, i))
    np.testing.assert_array_equal(np.asarray(obs[i]), np.asarray(obs_reset[i]))
    assert not np.array_equal(np.asarray(obs[i]), np.asarray(info["final_obs"][i]))
  assert np.all(np.asarray(new.t)[:4] == [0, 0, 1, 1])


def chex_equal(a, b):
  for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b)):
    np.testing.assert_array_equal(np.asarray(x), np.asarray(y))


def test_sensed_at_reset_matches_what_a_step_reports(push):
  states, keys = push.states([2, 2, 1, 0], seed=6)
  goals = push.env.slots_of("goal")
  assert np.asarray(states.world.sensed[:2, goals[0]]).all()  # sokoban3's box on a goal.
  _, new, *_ = push.step(keys, states, jnp.zeros((B, 2)), push.params)
  np.testing.assert_array_equal(np.asarray(new.world.sensed), np.asarray(states.world.sensed))
  np.testing.assert_array_equal(np.asarray(jax.vmap(jc_env.senses)(new.world).any(1)),
                                np.asarray(new.world.sensed))


def test_reach_flag_rewards_jump_and_patrol(reach):
  # Rows: 0 platformer1, running into the flag; 1 platformer1, into the hazard;
  # 2 platformer2, jump from the floor; 3 platformer2, "jump" in mid-air;
  # 4, 5 platformer1 at the patrol turn and just before it.
  p = reach.params
  states, _ = reach.states([0, 0, 1, 1, 0, 0], seed=7, params=p.replace(jitter=0.0))
  w = states.world
  flag, hazard = reach.env.slots_of("flag")[0], reach.env.slots_of("hazard")[0]
  for row, target in ((0, flag), (1, hazard)):
    x = float(w.pos[row, target, 0] - w.half[row, target, 0]) - 0.45
    states = _with(states, row, pos=((0,), jnp.array([x, float(w.pos[row, target, 1])])),
                   vel=((0,), jnp.array([8.0, 0.0])))
  states = _with(states, 3, pos=((0,), jnp.array([2.0, 6.0])))
  states = dataclasses.replace(states, t=states.t.at[4].set(p.patrol).at[5].set(p.patrol - 1))
  keys = jax.random.split(jax.random.key(8), B)
  actions = jnp.array([2, 2, 3, 3, 0, 0, 0, 0], jnp.int32)
  obs, new, reward, done, info = reach.step(keys, states, actions, p)
  reward, done = np.asarray(reward), np.asarray(done)
  assert reward[0] == p.success_reward and done[0] and bool(info["success"][0])
  assert reward[1] == -p.hazard_penalty and done[1] and bool(info["terminated"][1])
  assert not bool(info["success"][1])
  np.testing.assert_array_equal(reward[2:], 0.0)
  assert not done[2:].any()
  # Kinematic platform (platformer1): level velocity -1 along x, reversed from t = patrol.
  kin = reach.env.slots_of("platform")[np.asarray(reach.env.level_data["vel"])[0][
      reach.env.slots_of("platform"), 0] != 0][0]
  np.testing.assert_allclose(np.asarray(new.world.vel[4:6, kin]), [[1.0, 0.0], [-1.0, 0.0]])
  # Jumps: at reset nobody is grounded yet, so row 2 only lands; now it is grounded.
  assert bool(new.world.touching[2, 0, 3]) and not bool(new.world.touching[3, 0, 3])
  vy_before = np.asarray(new.world.vel[:, 0, 1])
  obs, new2, *_ = reach.step(keys, new, actions, p)
  vy = np.asarray(new2.world.vel[:, 0, 1])
  g = 9.81 / 60
  np.testing.assert_allclose(vy[2], p.jump / 60 - g, rtol=1e-4)  # About 7 u/s up.
  np.testing.assert_allclose(vy[3], vy_before[3] - g, rtol=1e-4)  # No jump in the air.


def test_determinism_for_a_given_key(push):
  keys = jax.random.split(jax.random.key(9), B)
  a = push.reset(keys, push.params)
  b = push.reset(keys, push.params)
  chex_equal(a, b)
  c = push.reset(jax.random.split(jax.random.key(10), B), push.params)
  assert not np.array_equal(np.asarray(a[0]), np.asarray(c[0]))
  actions = jnp.ones((B, 2)) * 0.5
  chex_equal(push.step(keys, a[1], actions, push.params), push.step(keys, b[1], actions, push.params))


def test_nothing_recompiles(push, reach):
  for task in (push, reach):
    obs, state = task.reset(jax.random.split(jax.random.key(11), B), task.params)
    actions = jax.vmap(task.env.action_space(task.params).sample)(
        jax.random.split(jax.random.key(12), B))
    for _ in range(2):
      obs, state, *_ = task.step(jax.random.split(jax.random.key(13), B), state, actions,
                                 task.params.replace(jitter=0.01))
    assert TRACES[task.env.name] == 1


def test_render_frames(push):
  states, _ = push.states([0, 1, 2])
  frames = jax.jit(push.env.render)(states)  # A batch of states: a batch of frames.
  h, w = push.env.frame_size
  assert frames.shape == (B, h, w, 3) and frames.dtype == jnp.uint8
  # The player has the player's colour (the view is the level's bounds, widened
  # about its centre to square pixels); a point off its centre, away from the goal
  # sokoban3's player stands on.
  for i in range(3):
    lo, hi = np.asarray(push.env.level_data["bounds"])[int(states.level[i])].reshape(2, 2)
    scale = max((hi - lo) / [w, h])
    centre = (lo + hi) / 2
    x, y = np.asarray(states.world.pos[i, 0]) + [-0.2, 0.2]
    col = int((x - centre[0]) / scale + w / 2)
    row = int(h / 2 - (y - centre[1]) / scale)
    assert tuple(np.asarray(frames[i, row, col])) == jc.drawing.PALETTE.player


def test_training_raises_the_return():
  spec = importlib.util.spec_from_file_location("es_push_box", ROOT / "examples" / "es_push_box.py")
  module = importlib.util.module_from_spec(spec)
  spec.loader.exec_module(module)
  before, after = module.train(iterations=6, population=8, seed=0, steps=100, learning_rate=0.1)
  assert before == 0.0  # The zero policy stands still.
  assert after > before + 0.5, (before, after)


def test_doctests():
  attempted = 0
  for module in (jc_env, jc_env.core, jc_env.spaces, jc_env.actions, jc_env.observations,
                 jc_env.tasks):
    result = doctest.testmod(module, optionflags=doctest.ELLIPSIS)
    assert result.failed == 0, module.__name__
    attempted += result.attempted
  assert attempted >= 10
