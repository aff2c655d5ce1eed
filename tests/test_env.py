"""jaxchain.env: gymnax-style tasks under jit and vmap, scripted rewards, auto-reset.

Compiles are the cost here (several seconds each on 2 cores), so every test shares
one jitted, vmapped `step` and `reset_level` per task (module fixtures), and the
scripted scenes of a task run as rows of one batch.
"""

import dataclasses
import doctest
import functools
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

  def __init__(self, name, made=None, compiler_options=None):
    self.env, self.params = jc_env.make(name) if made is None else made
    jit = functools.partial(jax.jit, compiler_options=compiler_options)
    name = self.env.name
    TRACES[name] = 0

    def counted_step(key, state, action, params):
      TRACES[name] += 1
      return self.env.step(key, state, action, params)

    self.step = jit(jax.vmap(counted_step, in_axes=(0, 0, 0, None)))
    self.reset_level = jit(jax.vmap(self.env.reset_level, in_axes=(0, None, 0)))
    self.reset = jit(jax.vmap(self.env.reset, in_axes=(0, None)))
    self.get_obs = jit(jax.vmap(self.env.get_obs, in_axes=(0, None)))

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


@pytest.fixture(scope="module")
def discrete():
  return Task("push_box_discrete")


def _load_example(name):
  spec = importlib.util.spec_from_file_location(name, ROOT / "examples" / f"{name}.py")
  module = importlib.util.module_from_spec(spec)
  spec.loader.exec_module(module)
  return module


@pytest.fixture(scope="module")
def two_box():
  return Task(None, _load_example("two_box_task").make_env())


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
  # Then the walls, in fixed slots: sokoban2 has 7 of the 11 (sokoban3 has 11).
  walls = obs[73:].reshape(11, 8)
  np.testing.assert_array_equal(walls[:, 0], [1] * 7 + [0] * 4)
  np.testing.assert_array_equal(walls[7:], 0.0)
  wall_ids = lv.indices("wall")
  np.testing.assert_allclose(walls[:7, 5:7], lv.half[wall_ids], rtol=1e-6)
  np.testing.assert_allclose(walls[:7, 1:3], lv.pos[wall_ids] - p0, rtol=1e-5, atol=1e-6)
  np.testing.assert_array_equal(walls[:, [3, 4, 7]], 0.0)  # At rest, no flag.


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
  module = _load_example("es_push_box")
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


# Tasks from parts.


def test_two_box_task_from_parts(two_box):
  env, p = two_box.env, two_box.params
  assert env.level_names == ("two_box",) and env.action_space(p) == jc_env.Discrete(5)
  assert [k for k, _ in env.slots] == ["box", "goal", "wall"] and env.actions.repeat == 4
  assert env.obs_shape == (9 + 8 * (2 + 2 + len(env.slots_of("wall"))),)
  assert env.config.gravity is False and p.max_steps == 200
  states, keys = two_box.states([0], seed=20, params=p.replace(jitter=0.0))
  # Row 0: both boxes just short of their goals, sliding in at 3 u/s: home within the
  # first of the 4 physics steps. Row 1: the player runs right from rest.
  box, goal = env.slots_of("box"), env.slots_of("goal")
  w = states.world
  for b, g in zip(box, goal):
    target = np.asarray(w.pos[0, g])
    order = np.argsort(np.abs(np.asarray(w.pos[0, box, 1]) - target[1]))
    b = box[order[0]]
    states = _with(states, 0, pos=((b,), jnp.asarray(target - [0.52, 0.0])),
                   vel=((b,), jnp.array([3.0, 0.0])))
  actions = jnp.array([0, 2, 0, 0, 0, 0, 0, 0], jnp.int32)
  obs, new, reward, done, info = two_box.step(keys, states, actions, p)
  assert bool(done[0]) and bool(info["terminated"][0]) and bool(info["success"][0])
  # One physics step counted (+1 per goal, +2 both home, shaping, one step cost); the
  # world stops at the termination: the boxes' speed after one step of drag, not four.
  assert 4.0 - 0.002 < float(reward[0]) < 4.2
  dt = env.config.dt
  final = np.asarray(info["final_obs"][0, 9:9 + 16]).reshape(2, 8)
  np.testing.assert_allclose(final[:, 3], 3.0 * (1 - p.box_drag * dt), rtol=1e-5)
  # Row 1: four steps of semi-implicit Euler with drag, no contact.
  v, x = 0.0, 0.0
  for _ in range(4):
    v = v + dt * (p.accel - p.drag * v)
    x = x + dt * v
  np.testing.assert_allclose(float(new.world.vel[1, 0, 0]), v, rtol=1e-5)
  np.testing.assert_allclose(float(new.world.pos[1, 0, 0] - states.world.pos[1, 0, 0]), x,
                             rtol=1e-4)
  assert not bool(done[1]) and int(new.t[1]) == 1
  # Auto-reset equals reset with the step's reset key; nothing retraces.
  _, fresh = two_box.reset(jax.vmap(lambda k: jax.random.split(k)[1])(keys), p)
  chex_equal(_row(new, 0), _row(fresh, 0))
  two_box.step(keys, new, actions, p)
  assert TRACES["two_box"] == 1


def test_discrete_push_box_moves(discrete):
  env, p = discrete.env, discrete.params
  assert env.action_space(p) == jc_env.Discrete(5) and env.obs_shape == (161,)
  states, keys = discrete.states([0, 0, 0, 0, 0], params=p.replace(jitter=0.0))
  actions = jnp.array([0, 1, 2, 3, 4, 0, 0, 0], jnp.int32)
  _, new, *_ = discrete.step(keys, states, actions, p)
  dv = np.asarray(new.world.vel[:5, 0])
  step = p.accel * env.config.dt
  np.testing.assert_allclose(dv, [[0, 0], [-step, 0], [step, 0], [0, -step], [0, step]],
                             atol=1e-6)


# Actions.


def test_invalid_actions_act_as_noop_and_truncate(discrete, push):
  p = discrete.params
  states, keys = discrete.states([0, 1, 2, 0, 1, 2, 0, 1], seed=21)
  actions = jnp.array([2, 5, -1, 100, 6, 0, 4, 1], jnp.int32)
  _, new, reward, done, info = discrete.step(keys, states, actions, p)
  noop = jnp.where(jnp.array([False, True, True, True, True, False, False, False]), 0, actions)
  _, new_noop, reward_noop, *_ , info_noop = discrete.step(keys, states, noop, p)
  bad = np.array([0, 1, 1, 1, 1, 0, 0, 0], bool)
  np.testing.assert_array_equal(np.asarray(info["invalid_action"]), bad)
  np.testing.assert_array_equal(np.asarray(info["truncated"]), bad)
  np.testing.assert_array_equal(np.asarray(done), bad)
  assert not np.any(np.asarray(info["terminated"]))
  assert not np.any(np.asarray(info_noop["invalid_action"]))
  np.testing.assert_array_equal(np.asarray(info["final_obs"]), np.asarray(info_noop["final_obs"]))
  np.testing.assert_array_equal(np.asarray(reward), np.asarray(reward_noop))
  # Continuous: a non-finite action is invalid; a finite one outside [-1, 1] is clipped.
  states, keys = push.states([0, 1, 2], seed=22)
  acts = jnp.zeros((B, 2)).at[0, 0].set(jnp.nan).at[1, 1].set(jnp.inf).at[2].set(jnp.array([3.0, 0.0]))
  _, _, reward, done, info = push.step(keys, states, acts, push.params)
  _, _, _, _, info_ref = push.step(keys, states, acts.at[:2].set(0.0).at[2, 0].set(1.0),
                                   push.params)
  np.testing.assert_array_equal(np.asarray(info["invalid_action"])[:3], [True, True, False])
  np.testing.assert_array_equal(np.asarray(info["truncated"])[:3], [True, True, False])
  assert not np.any(np.asarray(info["terminated"])) and np.all(np.isfinite(np.asarray(reward)))
  np.testing.assert_array_equal(np.asarray(info["final_obs"]), np.asarray(info_ref["final_obs"]))


def test_actions_checked_at_trace_time(push, discrete):
  key = jax.random.key(23)
  for task, bad, error, match in (
      (push, jnp.float32(0.5), ValueError, r"action: expected shape \(2,\) and dtype float32"),
      (push, jnp.zeros(3), ValueError, r"action: expected shape \(2,\), got|action: expected shape"),
      (push, jnp.zeros((4, 2)), ValueError, "vmap env.step"),
      (push, jnp.array([1, 0]), TypeError, "action: expected a float array of shape"),
      (discrete, jnp.float32(2.7), TypeError, r"action: expected an integer array of shape \(\)"),
      (discrete, jnp.array([1]), ValueError, r"action: expected shape \(\)"),
      (discrete, jnp.array(True), TypeError, "action"),
  ):
    state = task.env.reset_level(key, task.params, 0)
    with pytest.raises(error, match=match):
      jax.eval_shape(task.env.step, key, state, bad, task.params)
  # check_actions="raise": eager calls with a concrete invalid action raise; traced ones flag.
  env, p = jc_env.make("push_box_discrete", check_actions="raise")
  state = env.reset_level(key, p, 0)
  with pytest.raises(ValueError, match=r"action 7 is not in Discrete\(n=5"):
    env.step_env(key, state, 7, p)
  with pytest.raises(ValueError, match="not in Box"):
    jc_env.make("push_box", check_actions="raise")[0].step_env(key, _row(push.states([0])[0], 0),
                                                                jnp.array([jnp.nan, 0.0]),
                                                                push.params)
  out = jax.eval_shape(env.step, key, state, jnp.int32(7), p)
  assert out[4]["invalid_action"].dtype == jnp.bool_
  with pytest.raises(ValueError, match="check_actions must be one of"):
    jc_env.make("push_box", check_actions="warn")


# Physics through make and params; randomisation.


def test_make_takes_physics_switches_config_and_names_its_keywords():
  key = jax.random.key(24)
  env, p = jc_env.make("reach_flag", gravity=(0, -9.81))  # Was an internal TypeError.
  np.testing.assert_allclose(np.asarray(p.gravity), [0.0, -9.81])
  env, p = jc_env.make("reach_flag", friction=True)
  assert env.config.friction and p.friction is None
  env, p = jc_env.make("push_box", friction=0.5, gravity=(0.0, -1.0), depth=2)
  assert env.config.friction and env.config.gravity and env.config.depth == 2
  w = env.reset_level(key, p, 0).world
  np.testing.assert_allclose(np.asarray(w.friction)[np.asarray(w.active)], 0.5)
  np.testing.assert_allclose(np.asarray(w.gravity), [0.0, -1.0])
  cfg = jc.Config(gravity=False, friction=False, depth=3, one_way=False)
  assert jc_env.make("push_box", config=cfg)[0].config == cfg
  assert jc_env.make("push_box", config=cfg, substeps=2)[0].config == cfg.replace(substeps=2)
  with pytest.raises(TypeError, match=r"unknown keyword 'max_crates'. Accepted: levels, obs, "
                     r"config, randomize.*max_steps.*max_boxes, max_goals, max_walls.*substeps"):
    jc_env.make("push_box", max_crates=2)
  with pytest.raises(TypeError, match="run_speed"):
    jc_env.make("push_box", run_speed=2.0)  # A reach_flag param: push_box's are its own.
  # Physics the Config would leave out raises, never silently drops.
  env, p = jc_env.make("push_box")
  assert not env.config.friction and not env.config.gravity
  with pytest.raises(ValueError, match="params.friction is set, but this env's Config leaves"):
    env.reset_level(key, p.replace(friction=jnp.float32(0.3)), 0)
  with pytest.raises(ValueError, match="params.gravity is set"):
    env.reset(key, p.replace(gravity=jnp.array([0.0, -9.81])))
  with pytest.raises(ValueError, match="the randomize hook sets friction"):
    jc_env.make("push_box", friction=False,
                randomize=jc_env.uniform_physics(friction=(0.1, 0.5)))
  # A friction value switches friction on, in a given config too.
  assert jc_env.make("push_box", friction=0.5, config=cfg)[0].config == cfg.replace(friction=True)


@pytest.fixture(scope="module")
def randomized():
  hook = jc_env.uniform_physics(friction=(0.2, 0.8), mass=(0.5, 2.0),
                                gravity=((0.0, -2.0), (0.0, -1.0)), size=(0.9, 1.0))
  # Compiled with XLA's default fusion emitters, as users run it: the test below compares
  # two programs bit for bit (the reset inside the step, a fresh reset), and with the
  # suite's faster codegen (tests/conftest.py) the two round `jax.random.uniform`'s
  # multiply-add one ulp apart (a size factor 0.41607264 against 0.41607267).
  return Task(None, jc_env.make("push_box_easy", randomize=hook, max_steps=2),
              compiler_options={"xla_cpu_use_fusion_emitters": True})


def test_randomisation_applied_at_reset_and_after_auto_reset(randomized):
  env, p = randomized.env, randomized.params
  assert env.config.friction and env.config.gravity  # Switched on by what the hook sets.
  keys = jax.random.split(jax.random.key(25), B)
  obs, states = randomized.reset(keys, p)

  def check(w, levels):
    active = np.asarray(w.active)
    mu = np.asarray(w.friction)
    for i in range(B):
      assert np.all(mu[i, active[i]] == mu[i, active[i]][0]) and 0.2 <= mu[i, 0] <= 0.8
      box = env.slots_of("box")[0]
      mass = 1 / float(w.inv_mass[i, box])
      assert 0.5 <= mass <= 2.0
      level_half = np.asarray(env.level_data["half"])[levels[i], box]
      assert np.all(np.asarray(w.half[i, box]) <= level_half + 1e-6)
      assert np.all(np.asarray(w.half[i, box]) >= 0.9 * level_half - 1e-6)
      assert -2.0 <= float(w.gravity[i, 1]) <= -1.0 and float(w.gravity[i, 0]) == 0.0
    assert len(set(mu[:, 0].tolist())) == B  # Per episode.

  check(states.world, np.asarray(states.level))
  step_keys = jax.random.split(jax.random.key(26), B)
  _, states1, *_ = randomized.step(step_keys, states, jnp.zeros((B, 2)), p)
  obs2, states2, _, done, info = randomized.step(step_keys, states1, jnp.zeros((B, 2)), p)
  assert np.all(np.asarray(done)) and np.all(np.asarray(info["truncated"]))
  assert np.all(np.asarray(states2.t) == 0)
  check(states2.world, np.asarray(states2.level))
  assert not np.array_equal(np.asarray(states2.world.friction), np.asarray(states.world.friction))
  _, fresh = randomized.reset(jax.vmap(lambda k: jax.random.split(k)[1])(step_keys), p)
  chex_equal(states2, fresh)


# Observations.


def test_grid_and_pixel_observations():
  key = jax.random.key(27)
  lv = levels.load("sokoban1")
  env, p = jc_env.make("push_box", obs="grid", jitter=0.0)
  state = env.reset_level(key, p, 0)  # sokoban1 (6 x 5) in a 9 x 7 grid, at the top left.
  grid = np.asarray(jax.jit(env.get_obs)(state, p))
  assert env.grid_channels == ("player", "box", "goal", "wall")
  assert grid.shape == env.observation_space(p).shape == (7, 9, 4) and grid.dtype == np.float32
  assert bool(env.observation_space(p).contains(grid))
  channel = dict(zip(env.grid_channels, np.moveaxis(grid, -1, 0)))
  onehot = lambda r, c: np.zeros((7, 9)).__setitem__((r, c), 1.0) or None
  for kind, body in (("player", 3), ("box", 4), ("goal", 5)):
    x, y = lv.pos[body]
    want = np.zeros((7, 9))
    want[int(5 - y), int(x)] = 1.0  # Row 0 is the top (y = 5).
    np.testing.assert_allclose(channel[kind], want, atol=1e-6, err_msg=kind)
  want = np.zeros((7, 9))
  want[:5, :6] = 1.0
  want[1:4, 1:5] = 0.0
  np.testing.assert_allclose(channel["wall"], want, atol=1e-6)
  del onehot
  # A box straddling two cells covers each about half.
  w = state.world
  state = state.replace(world=w.replace(pos=w.pos.at[env.slots_of("box")[0]].set(
      jnp.array([3.0, 2.5]))))
  box = np.asarray(env.get_obs(state, p))[..., 1]
  np.testing.assert_allclose(box[2, 2:4], [0.5, 0.5], rtol=1e-5)
  # Pixels: 64 x 64, the goal a visible square, the player in its colour.
  env, p = jc_env.make("push_box", obs="pixels", jitter=0.0)
  state = env.reset_level(key, p, 0)
  img = np.asarray(jax.jit(env.get_obs)(state, p))
  space = env.observation_space(p)
  assert img.shape == space.shape == (64, 64, 3) and img.dtype == space.dtype == np.uint8
  assert bool(space.contains(img))
  scale = 9 / 64  # The view: sokoban1's bounds, widened to square pixels.
  def pixel(x, y):
    return int(32 - (y - 2.5) / scale), int(32 + (x - 3.0) / scale)
  assert tuple(img[pixel(*lv.pos[3])]) == jc.drawing.PALETTE.player
  gx, gy = lv.pos[5]
  r0, c0 = pixel(gx - 0.3, gy + 0.3)
  r1, c1 = pixel(gx + 0.3, gy - 0.3)
  background = np.array(jc.drawing.PALETTE.background)
  changed = np.any(img[r0:r1 + 1, c0:c1 + 1] != background, axis=-1)
  assert changed.sum() >= 16, changed.sum()  # At least 4 x 4 pixels, not a dot.
  with pytest.raises(ValueError, match="obs must be one of"):
    jc_env.make("push_box", obs="rgb")


def test_every_obs_mode_steps_under_vmap():
  """The step's obs and final_obs have the space's shape and dtype in every mode
  (traced only: `jax.eval_shape`, no compile)."""
  keys = jax.random.split(jax.random.key(29), B)
  for mode, shape, dtype in (("grid", (7, 9, 4), jnp.float32), ("pixels", (32, 48, 3), jnp.uint8)):
    env, p = jc_env.make("push_box_discrete", obs=mode, pixel_size=(32, 48))
    assert env.observation_space(p).shape == shape
    states = jax.eval_shape(jax.vmap(env.reset_level, in_axes=(0, None, None)), keys, p, 0)
    out = jax.eval_shape(jax.vmap(env.step, in_axes=(0, 0, 0, None)), keys, states,
                         jnp.zeros(B, jnp.int32), p)
    for obs in (out[0], out[4]["final_obs"]):
      assert obs.shape == (B,) + shape and obs.dtype == dtype, (mode, obs)


def test_custom_observation_function():
  def observe(env, state, params):
    return state.world.pos[env.slots_of("box")]
  env, p = jc_env.make("push_box", obs=observe)
  assert env.obs_mode == "custom" and env.observation_space(p).shape == (4, 2)


# Consistency.


def test_reset_level_checks_the_index(push):
  key = jax.random.key(28)
  for bad in (3, 7, -1):
    with pytest.raises(ValueError, match=rf"level {bad} is out of range: this env has 3 levels"):
      push.env.reset_level(key, push.params, bad)
  with pytest.raises(TypeError, match="integer"):
    push.env.reset_level(key, push.params, 1.0)
  states, _ = push.states([7, -1, 1, 2])  # Traced: clamped and flagged.
  np.testing.assert_array_equal(np.asarray(states.level)[:4], [2, 0, 1, 2])
  np.testing.assert_array_equal(np.asarray(states.level_clamped)[:4], [True, True, False, False])
  state = push.env.reset_level(key, push.params, 1)
  assert state.replace(t=jnp.int32(5)).t == 5 and state.replace(t=jnp.int32(5)).level == 1


X64_SCRIPT = """
import jax, jax.numpy as jnp
import jaxchain as jc
assert jax.config.jax_enable_x64
env, params = jc.env.make("push_box_discrete")
key = jax.random.key(0)
obs, state = env.reset(key, params)
obs, state, reward, done, info = jax.jit(env.step)(key, state, jnp.int32(2), params)
assert state.world.pos.dtype == jnp.float64, state.world.pos.dtype
got = (obs.dtype, reward.dtype, state.ret.dtype, info["episode_return"].dtype,
       env.action_space(params).sample(key).dtype)
assert all(d == want for d, want in zip(got, ["float32", "float32", "float32", "float32", "int32"])), got
print("x64 env ok")
"""


def test_dtypes_under_x64():
  import os
  import subprocess
  import sys
  environ = {**os.environ, "JAX_ENABLE_X64": "1", "JAX_PLATFORMS": "cpu"}
  done = subprocess.run([sys.executable, "-c", X64_SCRIPT], capture_output=True, text=True,
                        env=environ, timeout=600)
  assert done.returncode == 0, done.stderr[-3000:]
  assert "x64 env ok" in done.stdout


def test_docs_two_box_task_is_short_and_matches_the_example():
  """docs/rl.md's two-box task (run by tests/test_readme.py) stays under 30 lines and
  is the task of examples/two_box_task.py."""
  import re
  page = (ROOT / "docs" / "rl.md").read_text()
  block, = [b for b in re.findall(r"^```python\n(.*?)^```", page, flags=re.S | re.M)
            if 'name="two_box"' in b]
  assert len(block.strip().splitlines()) < 30
  example = (ROOT / "examples" / "two_box_task.py").read_text()
  for part in ("ROOM = ", "def reward(", "jc.env.Moves(repeat=4)", "jc.env.push_terminate"):
    assert part in block and part in example, part
  room = lambda text: text.split('ROOM = """')[1].split('"""')[0]
  body = lambda text: text.split("def reward(")[1].split("\n\n")[0].split("\n", 1)[1]
  assert room(block) == room(example) and body(block) == body(example)


# Physics ranges that no step can use are refused, naming the parameter.


@pytest.mark.parametrize("kwargs, message", [
    (dict(friction=(-0.1, 0.5)), "friction coefficients must be >= 0"),
    (dict(friction=(float("nan"), 0.5)), "friction must be finite"),
    (dict(friction=(0.2, float("inf"))), "friction must be finite"),
    (dict(friction=(0.8, 0.2)), "friction needs lo <= hi"),
    (dict(mass=(0.0, 2.0)), "mass factors must be > 0"),
    (dict(mass=(-1.0, 2.0)), "mass factors must be > 0"),
    (dict(mass=(float("nan"), 2.0)), "mass must be finite"),
    (dict(size=(0.0, 1.0)), "size factors must be > 0"),
    (dict(gravity=((0.0, float("nan")), (0.0, -1.0))), "gravity must be finite"),
    (dict(gravity=((0.0, -1.0), (0.0, -2.0))), "gravity needs lo <= hi"),
    (dict(mass=0.5), "mass must be a pair"),
])
def test_uniform_physics_refuses_bad_ranges(kwargs, message):
  with pytest.raises(ValueError, match=f"uniform_physics: {message}"):
    jc_env.make("push_box_easy", randomize=jc_env.uniform_physics(**kwargs))


def test_uniform_physics_is_a_picklable_value():
  import pickle
  hook = jc_env.uniform_physics(friction=(0, 1), mass=(0.5, 2), gravity=((0, -2), (0, -1)))
  assert hook.friction == (0.0, 1.0) and hook.gravity == ((0.0, -2.0), (0.0, -1.0))
  assert pickle.loads(pickle.dumps(hook)) == hook and hash(hook) == hash(pickle.loads(
      pickle.dumps(hook)))
  # Edge values that are valid: friction 0, equal bounds.
  assert jc_env.uniform_physics(friction=(0.0, 0.0), mass=(1.0, 1.0)).mass == (1.0, 1.0)


@pytest.mark.parametrize("kwargs, message", [
    (dict(friction=-0.5), "friction must be one finite coefficient >= 0"),
    (dict(friction=float("nan")), "friction must be one finite coefficient >= 0"),
    (dict(gravity=(0.0, float("nan"))), r"gravity must be a finite \(gx, gy\)"),
    (dict(gravity=(0.0, -9.81, 0.0)), r"gravity must be a finite \(gx, gy\)"),
])
def test_make_refuses_bad_physics_values(kwargs, message):
  with pytest.raises(ValueError, match=message):
    jc_env.make("push_box_easy", **kwargs)


def test_make_refuses_a_hook_that_gives_unusable_physics():
  """A hook of the user's own (not `uniform_physics`) is checked on make's probe resets."""
  def negative_friction(key, world, params):
    del key, params
    return world.replace(friction=jnp.where(world.active, -0.25, 0.0).astype(world.pos.dtype))

  def zero_mass(key, world, params):
    del key, params
    return world.replace(inv_mass=jnp.where(world.movable, jnp.inf, world.inv_mass))

  with pytest.raises(ValueError, match="randomize hook gave a friction"):
    jc_env.make("push_box_easy", randomize=negative_friction)
  with pytest.raises(ValueError, match="randomize hook gave a mass"):
    jc_env.make("push_box_easy", randomize=zero_mass)
