"""The shipped tasks, written as `Task`s from parts, their reusable hooks, the
`uniform_physics` randomiser, and `make`."""

from __future__ import annotations

import dataclasses
import math
import types

import jax
import jax.numpy as jnp
import numpy as np

from jaxchain.config import Config
from jaxchain.env import core
from jaxchain.env.actions import Accelerate, Moves, RunJump
from jaxchain.env.core import (Environment, EnvParams, PushBoxParams, ReachFlagParams, Task,
                                   _manhattan)

# Hooks of the Sokoban tasks (any task with "box" and "goal" slots can use them).


def goals_filled(env, world) -> jax.Array:
  """`[goals]` bool: each goal slot holds a box now (padding slots: False)."""
  goal = env.slots_of("goal")
  return world.sensed[goal] & world.active[goal]


def all_goals_filled(env, world) -> jax.Array:
  """`[]` bool: the level has a goal and every one holds a box."""
  goal = env.slots_of("goal")
  present = world.active[goal]
  return jnp.any(present) & jnp.all(world.sensed[goal] | ~present)


def box_goal_distance(env, world) -> jax.Array:
  """`[]`: the sum over boxes of the Manhattan distance to the nearest goal (0
  without goals): the push tasks' shaping potential."""
  box, goal = env.slots_of("box"), env.slots_of("goal")
  dist = jnp.where(world.active[goal][None], _manhattan(world.pos[box], world.pos[goal]), jnp.inf)
  nearest = jnp.min(dist, axis=1)
  return jnp.sum(jnp.where(world.active[box] & jnp.isfinite(nearest), nearest, 0.0))


def push_reward(env, old, action, new, params) -> jax.Array:
  """push_box's reward: `goal_reward` per box newly on a goal (minus as much per box
  pushed off), `success_reward` once all goals are filled, `shaping` times the
  decrease of `box_goal_distance`, minus `step_cost`, minus `crush_penalty` if the
  player is crushed."""
  del action
  before = jnp.sum(goals_filled(env, old.world))
  after = jnp.sum(goals_filled(env, new.world))
  success = all_goals_filled(env, new.world)
  dtype = new.world.pos.dtype
  return (params.goal_reward * (after - before).astype(dtype)
          + params.success_reward * success.astype(dtype)
          + params.shaping * (box_goal_distance(env, old.world) - box_goal_distance(env, new.world))
          - params.step_cost - params.crush_penalty * new.world.crushed[0].astype(dtype))


def push_terminate(env, old, action, new, params):
  """push_box's ending: `(all goals filled | player crushed, all goals filled)`."""
  del old, action, params
  success = all_goals_filled(env, new.world)
  return success | new.world.crushed[0], success


def drag(env, world, params) -> jax.Array:
  """push_box's forces: linear drag `-drag * v` on the player, `-box_drag * v` on
  the boxes."""
  box = jnp.zeros(env.num_bodies, bool).at[env.slots_of("box")].set(True)
  accel = jnp.where(box[:, None], -params.box_drag * world.vel, 0.0)
  return accel.at[0].set(-params.drag * world.vel[0])


# Hooks of the platformer task.


def _flag_distance(env, world) -> jax.Array:
  flag = env.slots_of("flag")
  d = _manhattan(world.pos[:1], world.pos[flag])[0]
  return jnp.sum(jnp.where(world.active[flag], d, 0.0))


def _reach_events(env, world):
  flag, hazard = env.slots_of("flag"), env.slots_of("hazard")
  success = jnp.any(world.sensed[flag] & world.active[flag])
  hurt = jnp.any(world.sensed[hazard] & world.active[hazard])
  return success, hurt, world.crushed[0]


def reach_reward(env, old, action, new, params) -> jax.Array:
  """reach_flag's reward: `success_reward` on the flag, minus `hazard_penalty` on a
  hazard and `crush_penalty` on being crushed, plus `shaping` times the decrease of
  the player-flag Manhattan distance, minus `step_cost`."""
  del action
  success, hurt, crushed = _reach_events(env, new.world)
  f = lambda x: x.astype(new.world.pos.dtype)
  return (params.success_reward * f(success) - params.hazard_penalty * f(hurt)
          - params.crush_penalty * f(crushed)
          + params.shaping * (_flag_distance(env, old.world) - _flag_distance(env, new.world))
          - params.step_cost)


def reach_terminate(env, old, action, new, params):
  """reach_flag's ending: the flag, a hazard or crushing; success on the flag."""
  del old, action, params
  success, hurt, crushed = _reach_events(env, new.world)
  return success | hurt | crushed, success


def box_drag_x(env, world, params) -> jax.Array:
  """reach_flag's forces: horizontal drag `-box_drag * vx` on the boxes."""
  box = jnp.zeros(env.num_bodies, bool).at[env.slots_of("box")].set(True)
  return jnp.where(box[:, None], jnp.stack([-params.box_drag * world.vel[:, 0],
                                            jnp.zeros_like(world.vel[:, 1])], -1), 0.0)


def patrol(env, state, params):
  """reach_flag's `before`: kinematic platforms move with their level velocity,
  reversed every `params.patrol` env steps (so they never drift out of the level)."""
  w = state.world
  vel0 = env.level_data["vel"][state.level]
  kinematic = w.active & (w.inv_mass == 0) & jnp.any(vel0 != 0, axis=-1)
  period = jnp.maximum(jnp.asarray(params.patrol, jnp.int32), 1)
  back = (jnp.asarray(params.patrol, jnp.int32) > 0) & ((state.t // period) % 2 == 1)
  vel = jnp.where(kinematic[:, None], jnp.where(back, -vel0, vel0), w.vel)
  return dataclasses.replace(w, vel=vel)


# Randomisation.


def _float_pair(name: str, value, *, positive: bool) -> tuple[float, float]:
  """`value` as a `(lo, hi)` pair of finite floats with `lo <= hi`, `lo >= 0` (or `> 0`
  when `positive`); else a ValueError that names the parameter."""
  bound = "> 0" if positive else ">= 0"
  try:
    lo, hi = (float(v) for v in value)
  except (TypeError, ValueError):
    raise ValueError(f"uniform_physics: {name} must be a pair (lo, hi) of numbers, got "
                     f"{value!r}") from None
  if not (math.isfinite(lo) and math.isfinite(hi)):
    raise ValueError(f"uniform_physics: {name} must be finite, got ({lo}, {hi})")
  if (lo <= 0) if positive else (lo < 0):
    what = "factors" if name in ("mass", "size") else "coefficients"
    raise ValueError(f"uniform_physics: {name} {what} must be {bound}, got ({lo}, {hi})")
  if lo > hi:
    raise ValueError(f"uniform_physics: {name} needs lo <= hi, got ({lo}, {hi})")
  return lo, hi


def _gravity_range(value) -> tuple[tuple[float, float], tuple[float, float]]:
  try:
    lo, hi = (tuple(float(x) for x in g) for g in value)
    if len(lo) != 2 or len(hi) != 2:
      raise ValueError
  except (TypeError, ValueError):
    raise ValueError(f"uniform_physics: gravity must be ((gx_lo, gy_lo), (gx_hi, gy_hi)), got "
                     f"{value!r}") from None
  if not all(math.isfinite(x) for x in lo + hi):
    raise ValueError(f"uniform_physics: gravity must be finite, got ({lo}, {hi})")
  if any(a > b for a, b in zip(lo, hi)):
    raise ValueError(f"uniform_physics: gravity needs lo <= hi per component, got ({lo}, {hi})")
  return lo, hi


@dataclasses.dataclass(frozen=True)
class UniformPhysics:
  """The `randomize(key, world, params) -> world` hook of `uniform_physics`: a frozen
  value (hashable, picklable) holding the validated ranges; see `uniform_physics`."""

  gravity: tuple | None = None
  friction: tuple[float, float] | None = None
  mass: tuple[float, float] | None = None
  size: tuple[float, float] | None = None

  def __post_init__(self):
    if self.gravity is not None:
      object.__setattr__(self, "gravity", _gravity_range(self.gravity))
    for name, positive in (("friction", False), ("mass", True), ("size", True)):
      if getattr(self, name) is not None:
        object.__setattr__(self, name, _float_pair(name, getattr(self, name), positive=positive))

  def __call__(self, key, world, params):
    del params
    dtype = world.pos.dtype
    k_g, k_f, k_m, k_s = jax.random.split(key, 4)
    n = world.num_bodies
    if self.gravity is not None:
      lo, hi = (jnp.asarray(g, dtype) for g in self.gravity)
      world = dataclasses.replace(world, gravity=jax.random.uniform(k_g, (2,), dtype, lo, hi))
    if self.friction is not None:
      mu = jax.random.uniform(k_f, (), dtype, *self.friction)
      world = dataclasses.replace(world, friction=jnp.where(world.active, mu, 0.0).astype(dtype))
    movable = world.movable
    if self.mass is not None:
      scale = jax.random.uniform(k_m, (n,), dtype, *self.mass)
      world = dataclasses.replace(world, inv_mass=jnp.where(movable, world.inv_mass / scale,
                                                            world.inv_mass))
    if self.size is not None:
      scale = jax.random.uniform(k_s, (n,), dtype, *self.size)
      world = dataclasses.replace(world, half=jnp.where(movable[:, None],
                                                        world.half * scale[:, None], world.half))
    return world


def uniform_physics(*, gravity=None, friction=None, mass=None, size=None) -> UniformPhysics:
  """A `randomize(key, world, params) -> world` hook drawing per-episode physics.

  Args:
    gravity: optional `((gx_lo, gy_lo), (gx_hi, gy_hi))`: the world's gravity,
      uniform per component.
    friction: optional `(lo, hi)` with `0 <= lo <= hi`: one Coulomb coefficient for
      every body.
    mass: optional `(lo, hi)` with `0 < lo <= hi`: each movable body's mass times a
      uniform factor.
    size: optional `(lo, hi)` with `0 < lo <= hi`: each movable body's half-extents
      times a uniform factor (both axes alike).

  Returns:
    The hook (a frozen, picklable `UniformPhysics`), for `make(..., randomize=...)`
    or `Task(randomize=...)`. `make` switches friction and gravity on in the Config
    when the hook sets them.

  Raises:
    ValueError: naming the parameter, for a range that is not finite, has
      `lo > hi`, or holds a negative friction or a mass or size factor <= 0.

  Examples:
    >>> import jax
    >>> import jaxchain as jc
    >>> env, params = jc.env.make("push_box", randomize=jc.env.uniform_physics(
    ...     friction=(0.2, 0.8), mass=(0.5, 2.0)))
    >>> state = env.reset_level(jax.random.key(0), params, 0)
    >>> env.config.friction, 0.2 <= float(state.world.friction[0]) <= 0.8
    (True, True)
    >>> jc.env.uniform_physics(mass=(0.0, 2.0))
    Traceback (most recent call last):
    ...
    ValueError: uniform_physics: mass factors must be > 0, got (0.0, 2.0)
  """
  return UniformPhysics(gravity=gravity, friction=friction, mass=mass, size=size)


# The shipped tasks.

_PUSH = dict(reward=push_reward, terminate=push_terminate, forces=drag, gravity=(0.0, 0.0),
             slots=(("box", 4), ("goal", 4)))

TASK_DEFS = types.MappingProxyType({
    "push_box": Task(name="push_box", levels=("sokoban1", "sokoban2", "sokoban3"),
                     actions=Accelerate(), params=PushBoxParams(max_steps=500), **_PUSH),
    "push_box_easy": Task(name="push_box_easy",
                          levels=("push_east", "push_west", "push_north", "push_south"),
                          actions=Accelerate(), params=PushBoxParams(max_steps=200), **_PUSH),
    "push_box_discrete": Task(name="push_box_discrete", levels=("sokoban1", "sokoban2", "sokoban3"),
                              actions=Moves(), params=PushBoxParams(max_steps=500), **_PUSH),
    "reach_flag": Task(name="reach_flag", levels=("platformer1", "platformer2"), actions=RunJump(),
                       reward=reach_reward, terminate=reach_terminate, forces=box_drag_x,
                       before=patrol, params=ReachFlagParams(),
                       slots=(("flag", 1), ("box", 4), ("hazard", 4), ("platform", 6))),
})
TASKS = tuple(TASK_DEFS)
# Each task's default levels (names of `jaxchain.levels.names()` or of `LEVELS`).
TASK_LEVELS = types.MappingProxyType({k: t.levels for k, t in TASK_DEFS.items()})

_MAKE_KEYWORDS = ("levels", "obs", "config", "randomize", "check_actions", "pixel_size")


def _check_physics_value(name: str, key: str, value) -> None:
  """`make`'s `friction=` (a finite coefficient >= 0) or `gravity=` (a finite `(gx, gy)`)."""
  try:
    v = np.asarray(value, np.float64)
  except (TypeError, ValueError):
    raise ValueError(f"make({name!r}): {key} must be a number, got {value!r}") from None
  if key == "friction" and (v.shape != () or not np.isfinite(v) or v < 0):
    raise ValueError(f"make({name!r}): friction must be one finite coefficient >= 0, got "
                     f"{value!r}")
  if key == "gravity" and (v.shape != (2,) or not np.all(np.isfinite(v))):
    raise ValueError(f"make({name!r}): gravity must be a finite (gx, gy), got {value!r}")


def make(task, *, levels=None, obs=None, config: Config | None = None, randomize=None,
         check_actions: str = "flag", pixel_size=(64, 64), **overrides):
  """An environment and its default parameters (gymnax's `make`).

  Runs on the host: loads the levels, pads and stacks them into fixed slots and
  builds the env's static `Config` (`Config.for_world` on the levels,
  `converge=False` so `jax.grad` works through `step`).

  Args:
    task: a name of `TASKS` ("push_box", "push_box_easy", "push_box_discrete",
      "reach_flag") or a `Task`.
    levels: optional levels instead of the task's: names of shipped levels
      (`jaxchain.levels.names()`) or of `LEVELS`, paths, ASCII maps, or
      `jaxchain.levels.Level` objects.
    obs: "vector" (default), "grid", "pixels", or `fn(env, state, params)`.
    config: optional `jaxchain.Config` to use instead of the derived one.
    randomize: optional `randomize(key, world, params) -> world` hook applied by
      every reset (`uniform_physics` makes one); replaces the task's.
    check_actions: "flag" (default: an invalid action sets
      `info["invalid_action"]`, acts as the noop and truncates) or "raise" (also
      raise on a concrete invalid action, for debugging).
    pixel_size: `(H, W)` of `obs="pixels"`.
    **overrides: params fields (`max_steps=200`, ...); slot counts (`max_boxes=`,
      `max_walls=`, ...); `Config` fields (`depth=`, `substeps=`, ...). Two are
      physics: `friction` and `gravity` given a bool switch the Config's feature
      on or off; given a value (`friction=0.5`, `gravity=(0, -9.81)`) they set
      `params.friction` / `params.gravity`, which every reset puts into the
      world, and switch the feature on.

  Returns:
    `(env, params)`.

  Raises:
    ValueError: for an unknown task, a level with more bodies of a group than
      the env's slots hold, or physics the Config leaves out.
    TypeError: for an unknown keyword (the message lists the accepted ones).

  Examples:
    >>> import jax
    >>> import jaxchain as jc
    >>> env, params = jc.env.make("reach_flag", max_steps=300, gravity=(0.0, -12.0))
    >>> env.level_names, params.max_steps, env.action_space(params).n
    (('platformer1', 'platformer2'), 300, 6)
    >>> env.observation_space(params).shape
    (161,)
    >>> env.reset_level(jax.random.key(0), params, 0).world.gravity.tolist()
    [0.0, -12.0]
  """
  if isinstance(task, str):
    if task not in TASK_DEFS:
      raise ValueError(f"make: unknown task {task!r}; tasks: {', '.join(TASKS)}")
    task = TASK_DEFS[task]
  elif not isinstance(task, Task):
    raise TypeError(f"make: expected a task name ({', '.join(TASKS)}) or a Task, got "
                    f"{type(task).__name__}")
  if levels is not None:
    task = task.replace(levels=tuple(levels))
  if randomize is not None:
    task = task.replace(randomize=randomize)
  param_fields = [f.name for f in dataclasses.fields(task.params)]
  config_fields = [f.name for f in dataclasses.fields(Config)]
  slot_kinds = [k for k, _ in task.slots] + ["wall"]
  counts_names = list(dict.fromkeys(core._count_name(k) for k in slot_kinds))
  params_kw, config_kw, counts = {}, {}, {}
  for key, value in overrides.items():
    if key in ("friction", "gravity"):
      if isinstance(value, bool):
        config_kw[key] = value
      else:
        _check_physics_value(task.name, key, value)
        params_kw[key] = jnp.asarray(value, jnp.float32)
        config_kw[key] = True
    elif key in param_fields:
      params_kw[key] = value
    elif key in counts_names:
      counts[key] = value
    elif key in config_fields:
      config_kw[key] = value
    else:
      raise TypeError(
          f"make({task.name!r}): unknown keyword {key!r}. Accepted: "
          f"{', '.join(_MAKE_KEYWORDS)}; params fields ({type(task.params).__name__}): "
          f"{', '.join(param_fields)}; slot counts: {', '.join(counts_names)}; Config fields: "
          f"{', '.join(f for f in config_fields if f not in param_fields)}")
  params = task.params.replace(**params_kw)
  env = Environment(task, obs=obs, config=config, config_overrides=config_kw,
                    check_actions=check_actions, pixel_size=pixel_size, default_params=params,
                    **counts)
  return env, params

