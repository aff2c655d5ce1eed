"""The environment machinery: params, state, levels in fixed slots, `Task` and
`Environment` (reset, step with auto-reset, the info dict)."""

from __future__ import annotations

import dataclasses
import math
import pathlib
import types
from collections.abc import Callable, Sequence
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from jaxchain import drawing, status
from jaxchain import levels as levels_lib
from jaxchain.config import Config
from jaxchain.env import observations
from jaxchain.env.observations import senses
from jaxchain.env.actions import ActionMap
from jaxchain.env.spaces import Box, Discrete
from jaxchain.stepping import step as physics_step
from jaxchain.world import World, stack

# Small push_box rooms: one box in line between the player and a goal by the wall.
LEVELS = types.MappingProxyType({
    "push_east": """
#######
#     #
#@ $ .#
#     #
#######
""",
    "push_west": """
#######
#     #
#. $ @#
#     #
#######
""",
    "push_north": """
#####
# . #
#   #
# $ #
#   #
# @ #
#####
""",
    "push_south": """
#####
# @ #
#   #
# $ #
#   #
# . #
#####
""",
})

OBS_MODES = ("vector", "grid", "pixels")
CHECK_ACTIONS = ("flag", "raise")


# Parameters and state.


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class EnvParams:
  """What every task reads: traced values (vmap or grad over them), a frozen
  pytree. Each shipped task has its own subclass (`PushBoxParams`,
  `ReachFlagParams`) with its dynamics and reward scales; `make` returns the
  task's defaults.

  Attributes:
    max_steps: env steps before an episode is truncated.
    jitter: start jitter: the bodies of the task's jitter groups (the player and
      the boxes) start at uniform offsets in `[-jitter, jitter]` per axis.
    gravity: `None` (each level's own gravity), or a `[2]` gravity every reset
      puts into the world (the env's `Config` must trace gravity).
    friction: `None` (the levels' per-body coefficients), or a scalar Coulomb
      coefficient every reset gives every body (the `Config` must trace friction:
      `make(..., friction=0.5)` or `make(..., friction=True)` switch it on).
  """

  max_steps: int = 500
  jitter: float = 0.05
  gravity: Any = None
  friction: Any = None

  def replace(self, **changes) -> EnvParams:
    """A copy with some fields changed."""
    return dataclasses.replace(self, **changes)


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class PushBoxParams(EnvParams):
  """`EnvParams` of the Sokoban tasks (push_box, push_box_easy, push_box_discrete).

  Attributes:
    accel: the player's acceleration at full action (units/s^2).
    drag: the player's linear drag (1/s).
    box_drag: drag on boxes (1/s), both axes (from above there is no floor to rub
      on, so drag stands in for friction: a pushed box slides about
      `v / box_drag` further).
    goal_reward: reward per box newly on a goal (the negative per box pushed off).
    success_reward: reward when every goal holds a box.
    shaping: reward per unit decrease of the sum over boxes of the Manhattan
      distance to the nearest goal.
    step_cost: subtracted every physics step.
    crush_penalty: subtracted when the player is crushed (the episode ends).
  """

  accel: float = 20.0
  drag: float = 4.0
  box_drag: float = 8.0
  goal_reward: float = 1.0
  success_reward: float = 1.0
  shaping: float = 0.1
  step_cost: float = 0.0
  crush_penalty: float = 1.0


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class ReachFlagParams(EnvParams):
  """`EnvParams` of the platformer task reach_flag.

  Attributes:
    run_speed: target horizontal speed of left/right (units/s).
    run_gain: how fast the player's horizontal velocity follows the target (1/s;
      `run_gain * dt` must stay below 1).
    jump: the upward acceleration of a jump, for one step (units/s^2).
    box_drag: horizontal drag on boxes (1/s).
    success_reward: reward on reaching the flag.
    hazard_penalty: subtracted on touching a hazard (the episode ends).
    crush_penalty: subtracted when the player is crushed (the episode ends).
    shaping: reward per unit decrease of the player-flag Manhattan distance.
    step_cost: subtracted every physics step.
    patrol: kinematic platforms turn back every `patrol` env steps (0: never).
  """

  max_steps: int = 600
  run_speed: float = 4.0
  run_gain: float = 10.0
  jump: float = 420.0
  box_drag: float = 4.0
  success_reward: float = 1.0
  hazard_penalty: float = 1.0
  crush_penalty: float = 1.0
  shaping: float = 0.0
  step_cost: float = 0.0
  patrol: int = 180


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class EnvState:
  """The state of one episode (add a leading axis for a batch).

  Attributes:
    world: the `World`, its bodies in the env's slot order (player in slot 0).
    t: `[]` int32, env steps taken in this episode.
    level: `[]` int32, index into `env.level_names`.
    ret: `[]` float32, the reward summed over this episode so far.
    level_clamped: `[]` bool, True when `reset_level` got a traced level index
      outside `[0, num_levels)` and clamped it (a concrete one raises).
  """

  world: World
  t: jax.Array
  level: jax.Array
  ret: jax.Array
  level_clamped: jax.Array

  def replace(self, **changes) -> EnvState:
    """A copy with some fields changed."""
    return dataclasses.replace(self, **changes)


# Level arrays.


def load_level(source, *, name: str = "", gravity=None) -> levels_lib.Level:
  """A `Level` from a `Level`, a name of `LEVELS` or of the shipped levels
  (`jaxchain.levels.names()`), a path, or an ASCII map (a string with a newline:
  `jaxchain.levels.parse_ascii`, named `name`, gravity 0 unless `gravity` is given).

  Examples:
    >>> from jaxchain import env
    >>> env.load_level("#####\\n#@$.#\\n#####").tags["box"]
    (3,)
  """
  if isinstance(source, levels_lib.Level):
    return source
  if isinstance(source, str) and source in LEVELS:
    return levels_lib.parse_ascii(LEVELS[source], name=source, gravity=(0.0, 0.0))
  if isinstance(source, str) and "\n" in source:
    return levels_lib.parse_ascii(source, name=name,
                                  gravity=(0.0, 0.0) if gravity is None else gravity)
  if isinstance(source, (str, pathlib.Path)):
    return levels_lib.load(source)
  raise ValueError(f"levels: expected Level objects, level names, paths or ASCII maps, got "
                   f"{source!r}")


def _group(level: levels_lib.Level, kind: str) -> list[int]:
  """The bodies of `level` in one slot group: by tag, or by kind for "platform"
  (one-way or kinematic, not sensors) and "wall" (static solids: immovable, at
  rest, neither one-way nor sensors)."""
  if kind == "player":
    return [level.player]
  kinematic = np.isinf(level.mass) & np.any(level.vel != 0, axis=-1)
  if kind == "platform":
    return np.flatnonzero((level.one_way | kinematic) & ~level.sensor).tolist()
  if kind == "wall":
    static = np.isinf(level.mass) & ~kinematic & ~level.one_way & ~level.sensor
    return [i for i in np.flatnonzero(static).tolist() if i != level.player]
  return level.indices(kind).tolist()


def _members(level: levels_lib.Level, groups) -> list[list[int]]:
  """Each group's bodies in `level`, a body in the first group that takes it."""
  taken, out = set(), []
  for kind in groups:
    idx = [i for i in _group(level, kind) if i not in taken]
    taken.update(idx)
    out.append(idx)
  return out


_PAD = dict(pos=0.0, half=1.0, mass=np.inf, vel=0.0, friction=0.0, one_way=False,
            sensor=False, category=levels_lib.SOLID, mask=levels_lib.ALL)
_FIELDS = tuple(_PAD)


def _arrange(level: levels_lib.Level, groups: Sequence[tuple[str, int]], rest: int,
             gravity) -> dict[str, np.ndarray]:
  """One level's host arrays in slot order: each group padded to its count, then the
  remaining bodies padded to `rest`; plus `active`, `gravity` and `bounds`."""
  order = []
  members = _members(level, [kind for kind, _ in groups])
  for (kind, count), idx in zip(groups, members):
    if len(idx) > count:
      raise ValueError(f"level {level.name!r}: {len(idx)} {kind} bodies, but the env holds "
                       f"{count} (raise it: make(..., {_count_name(kind)}={len(idx)}))")
    order += idx + [-1] * (count - len(idx))
  taken = {i for idx in members for i in idx}
  others = [i for i in range(level.num_bodies) if i not in taken]
  order += others + [-1] * (rest - len(others))
  order = np.asarray(order)
  out = {}
  for name in _FIELDS:
    x = getattr(level, name)
    pad = np.full((len(order),) + x.shape[1:], _PAD[name], x.dtype)
    out[name] = np.where((order >= 0).reshape((-1,) + (1,) * (x.ndim - 1)),
                         x[np.maximum(order, 0)], pad)
  out["active"] = order >= 0
  out["gravity"] = np.asarray(level.gravity if gravity is None else gravity, np.float64)
  out["bounds"] = np.asarray(level.bounds, np.float64)
  return out


def _count_name(kind: str) -> str:
  """The `make` keyword of a slot group's count: "box" -> "max_boxes"."""
  return f"max_{kind}es" if kind.endswith("x") else f"max_{kind}s"


def _manhattan(a: jax.Array, b: jax.Array) -> jax.Array:
  """`[..., i, j]` Manhattan distances between `a` `[..., i, 2]` and `b` `[..., j, 2]`
  (no sqrt: gradient-safe everywhere)."""
  return jnp.sum(jnp.abs(a[..., :, None, :] - b[..., None, :, :]), axis=-1)


# Tasks.


@dataclasses.dataclass(frozen=True)
class Task:
  """A task, composed of parts; `make(task)` turns it into an `Environment`.

  The env keeps the loop: reset (level choice, start jitter, physics from params,
  `randomize`), the physics step (`repeat` times per action), auto-reset,
  truncation at `params.max_steps`, `final_obs` and the info dict. The hooks are
  pure, jittable functions of arrays; `env` (the `Environment`) gives them its
  constants (`env.slots_of("box")`, `env.level_data`, `env.config`).

  Attributes:
    name: the task's name.
    levels: the levels: `Level` objects, names of shipped levels or of `LEVELS`,
      paths, or ASCII maps (`load_level`).
    actions: an action map (`Accelerate`, `Moves`, `RunJump` or your own
      `ActionMap`): the action space, action repeat and the player's acceleration.
    reward: `reward(env, old, action, new, params) -> []` float, per physics step
      from `EnvState` `old` to `new` (summed over an action repeat).
    terminate: `terminate(env, old, action, new, params) -> (terminated, success)`,
      two `[]` bools per physics step.
    slots: `(group, count)` of the bodies observed after the player, in order;
      groups are tags ("box", "goal", "flag", "hazard", ...) or the kinds
      "platform" and "wall"; a count of `None` is sized from the levels. Walls
      are always observed: "wall" is appended when missing.
    params: the default params (an `EnvParams` subclass with what the hooks
      read; `PushBoxParams` by default).
    observe: "vector", "grid", "pixels", or `observe(env, state, params) -> array`.
    forces: optional `forces(env, world, params) -> [n, 2]` accelerations besides
      the player's (drag); the action map's acceleration is added to slot 0.
    before: optional `before(env, state, params) -> World`, the world handed to
      each physics step (drive kinematic platforms here).
    randomize: optional `randomize(key, world, params) -> World`, applied by every
      reset (so by auto-reset too): per-episode gravity, friction, masses, sizes
      (`uniform_physics` makes one).
    gravity: optional `(gx, gy)` replacing every level's own gravity.
    jitter: the groups whose start positions jitter on reset.
  """

  name: str
  levels: tuple
  actions: ActionMap
  reward: Callable
  terminate: Callable
  slots: tuple = (("box", None), ("goal", None))
  params: EnvParams = PushBoxParams()
  observe: Any = "vector"
  forces: Callable | None = None
  before: Callable | None = None
  randomize: Callable | None = None
  gravity: tuple | None = None
  jitter: tuple[str, ...] = ("player", "box")

  def __post_init__(self):
    levels = (self.levels,) if isinstance(self.levels, (str, levels_lib.Level)) else self.levels
    object.__setattr__(self, "levels", tuple(levels))
    object.__setattr__(self, "slots", tuple((str(k), c) for k, c in self.slots))
    if not isinstance(self.actions, ActionMap):
      raise TypeError(f"Task {self.name!r}: actions must be an ActionMap (Accelerate(), Moves(), "
                      f"RunJump(), ...), got {self.actions!r}")
    if not isinstance(self.params, EnvParams):
      raise TypeError(f"Task {self.name!r}: params must be an EnvParams (subclass), got "
                      f"{type(self.params).__name__}")

  def replace(self, **changes) -> Task:
    """A copy with some parts changed."""
    return dataclasses.replace(self, **changes)


def _check_randomized(name: str, worlds: World) -> None:
  """Raises when a randomize hook gave physics no step can use (on `make`'s probe resets):
  a friction that is negative or not finite, a mass <= 0 or not finite (an inverse mass
  < 0 or not finite), a half-extent <= 0 or not finite, a gravity not finite."""
  active = np.asarray(worlds.active)
  checks = (
      ("friction", np.asarray(worlds.friction), lambda f: np.isfinite(f) & (f >= 0),
       "finite and >= 0 (uniform_physics: friction=(lo, hi) with 0 <= lo <= hi)"),
      ("mass", np.asarray(worlds.inv_mass), lambda m: np.isfinite(m) & (m >= 0),
       "> 0 (uniform_physics: mass factors > 0)"),
      ("size", np.asarray(worlds.half), lambda h: np.all(np.isfinite(h) & (h > 0), axis=-1),
       "finite half-extents > 0 (uniform_physics: size factors > 0)"),
  )
  for field, values, ok, want in checks:
    bad = active & ~ok(values)
    if np.any(bad):
      raise ValueError(f"make({name!r}): the randomize hook gave a {field} that is not "
                       f"{want}: {values[bad][:3].tolist()}")
  if not np.all(np.isfinite(np.asarray(worlds.gravity))):
    raise ValueError(f"make({name!r}): the randomize hook gave a gravity that is not finite")


def _is_traced(x) -> bool:
  return any(isinstance(leaf, jax.core.Tracer) for leaf in jax.tree.leaves(x))


# Environments.


class Environment:
  """A task on a fixed set of levels, with the gymnax interface.

  Built by `make` (or `Environment(task, ...)`). `reset`, `step`, `reset_env`,
  `reset_level`, `step_env`, `get_obs` and `render` are pure functions of their
  arguments (the env object holds only constants: the stacked level arrays and the
  static `Config`), so `jax.jit` and `jax.vmap` apply to them directly.

  Attributes:
    name: the task's name.
    task: the `Task`.
    level_names: the names of the levels, in index order (`EnvState.level`).
    config: the static `jaxchain.Config` every physics step uses.
    slots: `(group, count)` of the observed bodies after the player, in order.
    num_bodies: body slots of every world.
    default_params: the task's default params.
    obs_mode: "vector", "grid", "pixels" or "custom".
    frame_size: `(H, W)` of `render`'s frames by default.
    level_data: the stacked level arrays (`pos`, `half`, `mass`, `vel`, `active`,
      `friction`, `one_way`, `sensor`, `category`, `mask`: `[levels, n, ...]`;
      `gravity` `[levels, 2]`, `bounds` `[levels, 4]`).
    grid_channels: the channel names of `obs="grid"`.
  """

  def __init__(self, task: Task, *, obs=None, config: Config | None = None,
               config_overrides: dict | None = None, check_actions: str = "flag",
               pixel_size: tuple[int, int] = (64, 64), default_params: EnvParams | None = None,
               **counts):
    name = task.name
    slots = list(task.slots)
    if "wall" not in [k for k, _ in slots]:
      slots.append(("wall", None))
    names = {_count_name(k) for k, _ in slots}
    unknown = set(counts) - names
    if unknown:
      raise TypeError(f"Environment({name!r}): unknown slot count(s) {sorted(unknown)}; "
                      f"slot counts: {', '.join(sorted(names))}")
    loaded = [load_level(s) for s in task.levels]
    if not loaded:
      raise ValueError(f"make({name!r}): no levels")
    kinds = ["player"] + [k for k, _ in slots]
    found = np.array([[len(m) for m in _members(lv, kinds)] for lv in loaded])  # [levels, groups]
    slots = tuple((kind, int(counts.get(_count_name(kind), count if count is not None
                                         else max(found[:, g + 1].max(), 1))))
                  for g, (kind, count) in enumerate(slots))
    groups = (("player", 1),) + slots
    rest = int(max(lv.num_bodies - found[k].sum() for k, lv in enumerate(loaded)))
    arrays = [_arrange(lv, groups, rest, task.gravity) for lv in loaded]
    host = {k: np.stack([a[k] for a in arrays]) for k in arrays[0]}
    params = task.params if default_params is None else default_params
    if check_actions not in CHECK_ACTIONS:
      raise ValueError(f"make({name!r}): check_actions must be one of {CHECK_ACTIONS}, got "
                       f"{check_actions!r}")
    self.name = name
    self.task = task
    self.actions = task.actions
    self.check_actions = check_actions
    self.level_names = tuple(lv.name or f"{name}_{k}" for k, lv in enumerate(loaded))
    self.slots = slots
    self.num_bodies = len(host["pos"][0])
    self.default_params = params
    starts = np.cumsum([1] + [count for _, count in slots])
    self._slot = {kind: np.arange(starts[k], starts[k + 1]) for k, (kind, _) in enumerate(slots)}
    self._observed = np.arange(1, starts[-1])
    self._rest = np.arange(starts[-1], self.num_bodies)
    jitter = np.zeros(self.num_bodies, bool)
    for kind in task.jitter:
      jitter[self.slots_of(kind) if kind in self._slot or kind == "player" else []] = True
    self._jitter = jitter
    extent = np.max(host["bounds"][:, 2:] - host["bounds"][:, :2], axis=0)
    self.frame_size = tuple(int(16 * math.ceil(e)) for e in extent[::-1])  # (H, W).
    self.grid_shape = tuple(int(math.ceil(e - 1e-9)) for e in extent[::-1])  # (H, W) cells.
    self.grid_channels = ("player",) + tuple(k for k, _ in slots) + (
        ("other",) if len(self._rest) else ())
    member = np.zeros((self.num_bodies, len(self.grid_channels)), bool)
    member[0, 0] = True
    for c, kind in enumerate(self.grid_channels[1:], start=1):
      member[self._slot[kind] if kind != "other" else self._rest, c] = True
    self._channel_member = member
    self.pixel_size = drawing._check_size(pixel_size)
    # The level arrays, in JAX's default float dtype.
    worlds = stack([World.create(a["pos"], a["half"], a["mass"], a["vel"], a["active"],
                                 friction=a["friction"], gravity=a["gravity"],
                                 one_way=a["one_way"], sensor=a["sensor"],
                                 category=a["category"], mask=a["mask"]) for a in arrays])
    dtype = worlds.pos.dtype
    self.level_data = types.MappingProxyType(
        {k: jnp.asarray(v, dtype if v.dtype == np.float64 else v.dtype) for k, v in host.items()})
    # The config: sized on the levels with the default params' physics and, with a
    # randomize hook, on a few randomised resets of every level (so a hook that sets
    # friction or gravity switches them on).
    self.config = Config(friction=True, gravity=True)  # Lets the probe below apply any physics.
    sized = self._with_physics(worlds, params)
    if task.randomize is not None:
      keys = jax.random.split(jax.random.key(0), 2 * self.num_levels)
      levels = jnp.tile(jnp.arange(self.num_levels, dtype=jnp.int32), 2)
      probe = jax.jit(jax.vmap(lambda k, lv: self.reset_level(k, params, lv).world))(keys, levels)
      sized = jax.tree.map(lambda a, b: jnp.concatenate([jnp.asarray(a), b]), sized, probe)
      _check_randomized(name, probe)
    overrides = dict(config_overrides or {})
    if config is None:
      config = Config.for_world(sized, **{"converge": False, **overrides})
    elif overrides:
      config = config.replace(**overrides)
    self.config = config
    for field, what in (("friction", "friction"), ("gravity", "gravity")):
      if not getattr(config, field):
        if getattr(params, field) is not None:
          raise ValueError(f"make({name!r}): params.{field} is set but the Config leaves "
                           f"{what} out (Config.{field}=False); drop {field}=False")
        if task.randomize is not None and self._uses(sized, field):
          raise ValueError(f"make({name!r}): the randomize hook sets {what}, but the Config "
                           f"leaves it out (Config.{field}=False); drop {field}=False or use "
                           f"{field}=True")
    # Observations.
    observe = task.observe if obs is None else obs
    if callable(observe):
      self.obs_mode, self._observe_fn = "custom", observe
    elif observe in OBS_MODES:
      self.obs_mode, self._observe_fn = observe, getattr(observations, observe)
    else:
      raise ValueError(f"make({name!r}): obs must be one of {OBS_MODES} or a function "
                       f"(env, state, params) -> array, got {observe!r}")
    if self.obs_mode == "custom":
      spec = jax.eval_shape(lambda k: self.get_obs(self.reset_level(k, params, 0), params),
                            jax.random.key(0))
      self._obs_space = Box(-math.inf, math.inf, tuple(spec.shape), np.dtype(spec.dtype))
    else:
      self._obs_space = observations.space(self)

  def __getstate__(self) -> dict:
    """For pickle and `copy.deepcopy` (gymnax's Gym wrappers deep-copy their env): the
    read-only `level_data` view travels as a plain dict."""
    state = dict(self.__dict__)
    state["level_data"] = dict(self.level_data)
    return state

  def __setstate__(self, state: dict) -> None:
    state = dict(state)
    state["level_data"] = types.MappingProxyType(dict(state["level_data"]))
    self.__dict__.update(state)

  @staticmethod
  def _uses(worlds: World, field: str) -> bool:
    if field == "friction":
      return bool(np.any(np.asarray(worlds.active) & (np.asarray(worlds.friction) > 0)))
    movable = np.asarray(worlds.active) & (np.asarray(worlds.inv_mass) > 0)
    return bool(np.any(np.any(movable, -1) & np.any(np.asarray(worlds.gravity) != 0, -1)))

  def __repr__(self) -> str:
    return (f"Environment({self.name!r}, levels {list(self.level_names)}, {self.num_bodies} "
            f"bodies, actions {self.action_space()}, obs {self.obs_mode} {self.obs_shape})")

  @property
  def obs_shape(self) -> tuple[int, ...]:
    """The shape of an observation."""
    return tuple(self._obs_space.shape)

  @property
  def obs_size(self) -> int:
    """The number of numbers in an observation (the vector's length for "vector")."""
    return int(np.prod(self.obs_shape))

  @property
  def num_actions(self) -> int:
    """gymnax's `num_actions`: the number of discrete actions, or the action's
    dimension for a continuous task."""
    space = self.action_space()
    return space.n if isinstance(space, Discrete) else int(np.prod(space.shape))

  @property
  def num_levels(self) -> int:
    """The number of levels."""
    return len(self.level_names)

  def slots_of(self, group: str) -> np.ndarray:
    """The body slots (int array) of one observed group ("box", "goal", "wall",
    "flag", "hazard", "platform", ...); the player is slot 0."""
    if group == "player":
      return np.zeros(1, np.int64)
    if group not in self._slot:
      raise ValueError(f"slots_of: {self.name} has groups player, {', '.join(self._slot)}; "
                       f"got {group!r}")
    return self._slot[group]

  def action_space(self, params: EnvParams | None = None) -> Box | Discrete:
    """The space of valid actions (the action map's)."""
    del params
    return self.actions.space

  def observation_space(self, params: EnvParams | None = None) -> Box:
    """The space of observations: `Box(-inf, inf, (obs_size,), float32)` for
    "vector", `Box(0, 1, (H, W, C), float32)` for "grid", `Box(0, 255, (H, W, 3),
    uint8)` for "pixels"."""
    del params
    return self._obs_space

  # The gymnax interface.

  def reset(self, key: jax.Array, params: EnvParams | None = None):
    """A fresh episode: `(obs, state)` on a random level with start jitter.

    Args:
      key: a PRNG key.
      params: the env's params (default: `default_params`).

    Returns:
      `(obs, state)`: `obs` of `observation_space(params)`, `state` an `EnvState`.

    Examples:
      >>> import jax
      >>> import jaxchain as jc
      >>> env, params = jc.env.make("push_box")
      >>> obs, state = jax.jit(env.reset)(jax.random.key(0), params)
      >>> obs.shape, obs.dtype, int(state.t), env.level_names[int(state.level)]
      ((161,), dtype('float32'), 0, 'sokoban2')
    """
    params = self.default_params if params is None else params
    state = self.reset_env(key, params)
    return self.get_obs(state, params), state

  def step(self, key: jax.Array, state: EnvState, action, params: EnvParams | None = None):
    """One step, resetting where the episode ends.

    Args:
      key: a PRNG key (used by the reset).
      state: the `EnvState`.
      action: an element of `action_space(params)`: its exact shape and kind of
        dtype (a wrong one raises at trace time, naming `action`).
      params: the env's params (default: `default_params`).

    Returns:
      `(obs, state, reward, done, info)`: `reward` float32 and `done` bool
      scalars; where `done`, `obs` and `state` start a new episode and
      `info["final_obs"]` is the observation the episode ended on. `info` also
      holds `terminated`, `truncated`, `success`, `invalid_action`,
      `episode_return`, `episode_length` and `status` (see `jaxchain.env`).

    Examples:
      >>> import jax
      >>> import jaxchain as jc
      >>> env, params = jc.env.make("push_box")
      >>> key = jax.random.key(0)
      >>> obs, state = env.reset(key, params)
      >>> step = jax.jit(env.step)
      >>> obs, state, reward, done, info = step(key, state, env.action_space(params).sample(key),
      ...                                       params)
      >>> int(state.t), bool(done), sorted(info)[:3]
      (1, False, ['episode_length', 'episode_return', 'final_obs'])
    """
    params = self.default_params if params is None else params
    key_step, key_reset = jax.random.split(key)
    obs, next_state, reward, done, info = self.step_env(key_step, state, action, params)
    obs_reset, state_reset = self.reset(key_reset, params)
    next_state = jax.tree.map(lambda a, b: jnp.where(done, a, b), state_reset, next_state)
    info = dict(info, final_obs=obs)
    return jnp.where(done, obs_reset, obs), next_state, reward, done, info

  def reset_env(self, key: jax.Array, params: EnvParams) -> EnvState:
    """A fresh `EnvState` (no observation): a level drawn uniformly, jittered starts."""
    key_level, key_jitter = jax.random.split(key)
    level = jax.random.randint(key_level, (), 0, self.num_levels, dtype=jnp.int32)
    return self.reset_level(key_jitter, params, level)

  def _level_index(self, level) -> tuple[jax.Array, jax.Array]:
    """`(index, clamped)`: a concrete level is checked (raises), a traced one clamped."""
    if _is_traced(level):
      level = jnp.asarray(level)
      if level.shape != () or not jnp.issubdtype(level.dtype, jnp.integer):
        raise TypeError(f"reset_level: level must be an integer scalar, got {level.dtype} "
                        f"{level.shape}")
      level = level.astype(jnp.int32)
      bad = (level < 0) | (level >= self.num_levels)
      return jnp.clip(level, 0, self.num_levels - 1), bad
    arr = np.asarray(level)
    if arr.shape != () or not np.issubdtype(arr.dtype, np.integer):
      raise TypeError(f"reset_level: level must be an integer scalar (an index into "
                      f"level_names), got {level!r}")
    if not 0 <= int(arr) < self.num_levels:
      raise ValueError(f"reset_level: level {int(arr)} is out of range: this env has "
                       f"{self.num_levels} levels {list(self.level_names)} (0 to "
                       f"{self.num_levels - 1})")
    return jnp.asarray(int(arr), jnp.int32), jnp.asarray(False)

  def reset_level(self, key: jax.Array, params: EnvParams, level) -> EnvState:
    """A fresh `EnvState` on a given level, with start jitter from `key`: for
    evaluation on each level. The params' physics and the task's `randomize` hook
    apply, as in every reset.

    Args:
      key: a PRNG key.
      params: the env's params.
      level: an index into `level_names`: a concrete int out of range raises; a
        traced one is clamped, and `state.level_clamped` says so.

    Raises:
      ValueError: for a concrete level index out of range.

    Examples:
      >>> import jax
      >>> import jaxchain as jc
      >>> env, params = jc.env.make("push_box")
      >>> state = env.reset_level(jax.random.key(0), params, 2)
      >>> int(state.level), env.level_names[2], state.world.sensed[env.slots_of("goal")].tolist()
      (2, 'sokoban3', [True, False, False, False])
    """
    level, clamped = self._level_index(level)
    a = {k: v[level] for k, v in self.level_data.items()}
    offset = jax.random.uniform(key, a["pos"].shape, a["pos"].dtype, -1.0, 1.0)
    pos = a["pos"] + jnp.where(self._jitter[:, None], offset * params.jitter, 0.0)
    world = World.from_arrays(pos, a["half"], a["mass"], a["vel"], a["active"],
                              friction=a["friction"], gravity=a["gravity"], one_way=a["one_way"],
                              sensor=a["sensor"], category=a["category"], mask=a["mask"])
    world = self._with_physics(world, params)
    if self.task.randomize is not None:
      world = self.task.randomize(jax.random.fold_in(key, 1), world, params)
    # What a step would report as sensed here (a box may start on a goal).
    world = dataclasses.replace(world, sensed=senses(world).any(0))
    return EnvState(world=world, t=jnp.zeros((), jnp.int32), level=level,
                    ret=jnp.zeros((), jnp.float32), level_clamped=clamped)

  def _with_physics(self, world: World, params: EnvParams) -> World:
    """`world` with the params' gravity and friction, where set."""
    dtype = world.pos.dtype
    if params.gravity is not None:
      if not self.config.gravity:
        raise ValueError(f"{self.name}: params.gravity is set, but this env's Config leaves "
                         f"gravity out; make it with make(..., gravity=...) or gravity=True")
      world = dataclasses.replace(world, gravity=jnp.broadcast_to(
          jnp.asarray(params.gravity, dtype), world.gravity.shape))
    if params.friction is not None:
      if not self.config.friction:
        raise ValueError(f"{self.name}: params.friction is set, but this env's Config leaves "
                         f"friction out; make it with make(..., friction=...) or friction=True")
      world = dataclasses.replace(world, friction=jnp.where(
          world.active, jnp.asarray(params.friction, dtype), jnp.zeros((), dtype)))
    return world

  def step_env(self, key: jax.Array, state: EnvState, action, params: EnvParams):
    """One step without the reset: `(obs, state, reward, done, info)`.

    An invalid action (`info["invalid_action"]`: a discrete action out of range, a
    non-finite continuous one) acts as the noop and truncates the episode (with
    `check_actions="raise"`, a concrete one raises instead).
    """
    del key
    action = self.actions.check(action)
    invalid = self.actions.invalid(action)
    if self.check_actions == "raise" and not _is_traced(invalid) and bool(invalid):
      raise ValueError(f"{self.name}: action {np.asarray(action).tolist()} is not in "
                       f"{self.action_space()} (check_actions='raise')")
    action = jnp.where(invalid, self.actions.noop, action)
    new, reward, terminated, success = self._advance(state, action, params)
    broken = (new.status & status.NON_FINITE) != 0
    reward = jnp.where(broken, 0.0, reward).astype(jnp.float32)
    terminated = terminated | broken
    t = state.t + 1
    truncated = ((t >= params.max_steps) | invalid) & ~terminated
    ret = state.ret + reward
    next_state = state.replace(world=new, t=t, ret=ret)
    info = dict(terminated=terminated, truncated=truncated, success=success & ~broken,
                invalid_action=invalid, episode_return=ret, episode_length=t, status=new.status)
    return self.get_obs(next_state, params), next_state, reward, terminated | truncated, info

  def _physics_step(self, state: EnvState, action, params):
    """One physics step: `(state, reward, terminated, success)`."""
    task = self.task
    world = state.world if task.before is None else task.before(self, state, params)
    accel = self.actions(self, world, action, params)
    if task.forces is None:
      forces = jnp.zeros_like(world.pos)
    else:
      forces = jnp.asarray(task.forces(self, world, params), world.pos.dtype)
    # An action map gives the player's [2] acceleration, or (a controller such as
    # SokobanMoves) every body's [n, 2].
    accel = jnp.asarray(accel, world.pos.dtype)
    forces = forces + accel if accel.ndim == 2 else forces.at[0].add(accel)
    new = state.replace(world=physics_step(world, self.config, forces))
    reward = jnp.asarray(task.reward(self, state, action, new, params)).astype(jnp.float32)
    terminated, success = task.terminate(self, state, action, new, params)
    terminated = jnp.asarray(terminated, bool)
    success = jnp.asarray(success, bool)
    return new, reward, terminated, success

  def _advance(self, state: EnvState, action, params):
    """`repeat` physics steps (stopping at termination): `(world, reward, terminated,
    success)`, the reward summed."""
    repeat = self.actions.repeat
    if repeat == 1:
      new, reward, terminated, success = self._physics_step(state, action, params)
      return new.world, reward, terminated, success

    def body(carry, _):
      st, reward, terminated, success = carry
      new, r, te, su = self._physics_step(st, action, params)
      te = te | ((new.world.status & status.NON_FINITE) != 0)
      st = jax.tree.map(lambda a, b: jnp.where(terminated, a, b), st, new)
      reward = reward + jnp.where(terminated, 0.0, r)
      success = jnp.where(terminated, success, su)
      return (st, reward, terminated | te, success), None

    init = (state, jnp.zeros((), jnp.float32), jnp.asarray(False), jnp.asarray(False))
    (st, reward, terminated, success), _ = jax.lax.scan(body, init, None, length=repeat)
    return st.world, reward, terminated, success

  def get_obs(self, state: EnvState, params: EnvParams) -> jax.Array:
    """The observation of `state` (the layouts are in `jaxchain.env`)."""
    return self._observe_fn(self, state, params)

  def render(self, state: EnvState, size: tuple[int, int] | None = None) -> jax.Array:
    """A frame of `state`: `jaxchain.render` of its world over its level's bounds,
    the player coloured as the player. Jittable; a batch of states (leading axes)
    gives a batch of frames.

    Args:
      state: an `EnvState` (or a batch of them).
      size: `(H, W)` in pixels (static); default `frame_size`, 16 pixels per cell
        of the env's largest level (the view keeps square pixels, so a smaller
        level is centred with a margin).

    Returns:
      `uint8[H, W, 3]` (`uint8[..., H, W, 3]` for a batch).

    Examples:
      >>> import jax
      >>> import jaxchain as jc
      >>> env, params = jc.env.make("push_box")
      >>> obs, state = env.reset(jax.random.key(0), params)
      >>> frame = env.render(state)
      >>> env.frame_size, frame.shape, frame.dtype
      ((112, 144), (112, 144, 3), dtype('uint8'))
    """
    bounds = self.level_data["bounds"][state.level]
    return drawing.render(state.world, self.frame_size if size is None else tuple(size),
                          bounds, player=0)
