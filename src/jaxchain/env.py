"""Environments: gymnax-style reinforcement-learning tasks on jaxchain levels.

    env, params = jc.env.make("push_box")
    obs, state = env.reset(key, params)
    obs, state, reward, done, info = env.step(key, state, action, params)

Everything is pure and jittable, and vmappable over keys, states and actions
(PureJaxRL style: `jax.vmap(env.step, in_axes=(0, 0, 0, None))`). `step` resets
by itself: when an episode ends, the returned `obs` and `state` are those of a
fresh `reset`, and `info["final_obs"]` holds the observation the episode ended on.

Levels are fixed-capacity. At `make` time (on the host) every level of a task is
loaded from `jaxchain.levels` (or this module's `LEVELS`), its bodies rearranged
into fixed slots (the player in slot 0, then each observed group, then the
rest, every group padded with inactive slots to one count) and stacked as arrays
held by the env; `reset` picks a level with `jax.random` and builds its world
with `World.from_arrays` plus start jitter, so it runs inside `jit`. One static
`jaxchain.Config` per env comes from `Config.for_world` on the stacked levels
(`converge=False`, so `jax.grad` works through `step`).

Tasks (`TASKS`):

* `"push_box"`: Sokoban from above (gravity 0) on `sokoban1`-`sokoban3`. A
  continuous player: the action is a 2-D acceleration in `[-1, 1]^2` (clipped),
  times `EnvParams.accel`; the player feels linear drag `EnvParams.drag` and
  boxes `EnvParams.box_drag` (there is no floor to rub on from above, so drag
  stands in for friction: a pushed box slides about `v / box_drag` further). It
  pushes boxes onto goal sensors (a goal's mask admits boxes only). Reward:
  `goal_reward` for each box newly on a goal (minus as much for each box pushed
  off one), `success_reward` once all goals are filled, `shaping` times the
  decrease of the box-goal distance (the sum over boxes of the Manhattan distance
  to the nearest goal), minus `step_cost` every step and `crush_penalty` if the
  player is crushed. Ends (terminated) when every goal is filled or the player
  is crushed; truncated at `max_steps`.
* `"push_box_easy"`: the same rules on four small rooms (`LEVELS`: `push_east`,
  `push_west`, `push_north`, `push_south`), one box in line between the player
  and the goal: the task of the training example.
* `"reach_flag"`: a platformer (gravity from the level) on `platformer1` and
  `platformer2`: one-way platforms, pushable boxes, a flag sensor, hazards.
  Discrete actions (`ACTIONS`): 0 noop, 1 left, 2 right, 3 jump, 4 left+jump,
  5 right+jump. Horizontal control steers the player's velocity toward
  `-run_speed`, 0 or `+run_speed` with gain `run_gain` (per second; on the
  ground and in the air). A jump is an upward acceleration `jump` (420: about
  7 u/s, 2.5 cells high) for one step, applied only when the player was grounded
  (`jc.grounded`) after the previous step. Boxes feel horizontal drag `box_drag`.
  Kinematic platforms patrol: each turns back every `patrol` steps (so it never
  drifts out of the level). Reward: `success_reward` on reaching the flag (the
  flag sensor senses the player), minus `hazard_penalty` on touching a hazard
  and `crush_penalty` on being crushed, plus `shaping` times the decrease of the
  player-flag Manhattan distance (0 by default), minus `step_cost`. Ends on the
  flag, a hazard or crushing (terminated), or at `max_steps` (truncated).

Cost: a step is one `jaxchain.step` on the env's 13-20 body slots (dense pairs)
plus the reset it may need; on 2 CPU cores that is about 1e4-2e4 env-steps/s, with
little gain from batching (CPU-bound per world; `benchmarks/results/env_throughput.md`),
and compiling a vmapped step takes 5-15 s.

Every task also ends (terminated, reward 0) when the world goes non-finite
(`status.NON_FINITE`), so one broken world resets instead of poisoning a batch.

Observations: one flat float32 vector (`observation_space(params).shape`):

| index | content |
| --- | --- |
| 0-1 | player centre relative to the level's bounds, `(p - lo) / (hi - lo)` (0..1 inside) |
| 2-3 | player velocity (units/s) |
| 4-7 | player contact flags `touching` (+x, -x, +y, -y) as 0/1 (7 is grounded) |
| 8 | `t / max_steps`, the fraction of the episode's step budget used |
| 9 + 8k ... 16 + 8k | slot k: present, dx, dy, vx, vy, hx, hy, flag |

A slot describes one body: `present` is 1 for a body and 0 for a padding slot
(whose eight numbers are all 0); `dx, dy` its centre minus the player's; `vx, vy`
its velocity; `hx, hy` its half-extents; `flag` is, for a sensor, whether it
senses something now (a goal holds a box); for a box, whether it lies on a goal;
for a platform, 1 if one-way (0 for a solid kinematic platform). Slots, in order
(`env.slots`): push_box: 4 boxes, 4 goals (obs size 73); reach_flag: 1 flag,
4 boxes, 4 hazards, 6 platforms (obs size 129). Walls are not observed (the
level layout is fixed per level; a policy can tell levels apart by the slots).

`info` (every step): `final_obs` (the observation the step produced, before any
reset), `terminated`, `truncated`, `success` (bools), `episode_return` and
`episode_length` (of the episode so far, final where `done`), `status` (the
world's status bits after the step).
"""

from __future__ import annotations

import dataclasses
import math
import pathlib
import types
from collections.abc import Sequence

import jax
import jax.numpy as jnp
import numpy as np

from jaxchain import drawing, flags, status
from jaxchain import levels as levels_lib
from jaxchain.config import Config
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

# Each task's default levels (names of `jaxchain.levels.names()` or of `LEVELS`).
TASK_LEVELS = types.MappingProxyType({
    "push_box": ("sokoban1", "sokoban2", "sokoban3"),
    "push_box_easy": ("push_east", "push_west", "push_north", "push_south"),
    "reach_flag": ("platformer1", "platformer2"),
})
TASKS = tuple(TASK_LEVELS)

# reach_flag's discrete actions: (horizontal direction, jump).
ACTIONS = ("noop", "left", "right", "jump", "left+jump", "right+jump")
_ACTION_DIR = (0.0, -1.0, 1.0, 0.0, -1.0, 1.0)
_ACTION_JUMP = (False, False, False, True, True, True)

SLOT_FIELDS = ("present", "dx", "dy", "vx", "vy", "hx", "hy", "flag")
PLAYER_FEATURES = 9  # Position (2), velocity (2), touching (4), time fraction (1).


# Spaces.


@dataclasses.dataclass(frozen=True)
class Discrete:
  """The integers `0 .. n - 1`, as int32 scalars.

  Examples:
    >>> import jax
    >>> from jaxchain import env
    >>> space = env.Discrete(6)
    >>> a = space.sample(jax.random.key(0))
    >>> a.shape, a.dtype, bool(space.contains(a)), bool(space.contains(6))
    ((), dtype('int32'), True, False)
  """

  n: int
  shape: tuple[int, ...] = ()
  dtype: np.dtype = np.dtype(np.int32)

  def sample(self, key: jax.Array) -> jax.Array:
    """A uniformly random element (jittable)."""
    return jax.random.randint(key, self.shape, 0, self.n, dtype=self.dtype)

  def contains(self, x) -> jax.Array:
    """Whether `x` is an integer of this shape in `[0, n)` (a bool array; jittable)."""
    x = jnp.asarray(x)
    if x.shape != self.shape or not jnp.issubdtype(x.dtype, jnp.integer):
      return jnp.asarray(False)
    return jnp.all((x >= 0) & (x < self.n))


@dataclasses.dataclass(frozen=True)
class Box:
  """Real vectors of one shape with every entry in `[low, high]` (bounds may be inf).

  Examples:
    >>> import jax
    >>> from jaxchain import env
    >>> space = env.Box(-1.0, 1.0, (2,))
    >>> a = space.sample(jax.random.key(0))
    >>> a.shape, a.dtype, bool(space.contains(a)), bool(space.contains(a * 3.0))
    ((2,), dtype('float32'), True, False)
  """

  low: float
  high: float
  shape: tuple[int, ...]
  dtype: np.dtype = np.dtype(np.float32)

  def sample(self, key: jax.Array) -> jax.Array:
    """A random element (jittable): uniform when both bounds are finite, else a
    standard normal draw clipped to the bounds."""
    if math.isfinite(self.low) and math.isfinite(self.high):
      return jax.random.uniform(key, self.shape, self.dtype, self.low, self.high)
    return jnp.clip(jax.random.normal(key, self.shape, self.dtype), self.low, self.high)

  def contains(self, x) -> jax.Array:
    """Whether `x` is a float array of this shape inside the bounds (no NaN); a
    bool array, jittable."""
    x = jnp.asarray(x)
    if x.shape != self.shape or not jnp.issubdtype(x.dtype, jnp.floating):
      return jnp.asarray(False)
    return jnp.all((x >= self.low) & (x <= self.high))


# Parameters and state.


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class EnvParams:
  """What a task's dynamics and rewards read: traced values (vmap or grad over
  them if you like), a frozen pytree. `make` returns the task's defaults.

  Attributes:
    max_steps: steps before an episode is truncated.
    jitter: start jitter: the player's and the boxes' start positions move by
      uniform offsets in `[-jitter, jitter]` along each axis on reset.
    accel: push_box: the player's acceleration at full action (units/s^2).
    drag: push_box: the player's linear drag (1/s).
    box_drag: drag on boxes (1/s): both axes in push_box, horizontal in reach_flag.
    goal_reward: push_box: reward per box newly on a goal (the negative per box
      pushed off one).
    success_reward: reward when the task is solved (all goals filled; the flag).
    shaping: reward per unit decrease of the task's distance (push_box: sum over
      boxes of the Manhattan distance to the nearest goal; reach_flag: the
      player's Manhattan distance to the flag).
    step_cost: subtracted every step.
    crush_penalty: subtracted when the player is crushed (the episode ends).
    run_speed: reach_flag: target horizontal speed of left/right (units/s).
    run_gain: reach_flag: how fast the player's horizontal velocity follows the
      target (1/s; `run_gain * dt` must stay below 1).
    jump: reach_flag: the upward acceleration of a jump, for one step (units/s^2).
    hazard_penalty: reach_flag: subtracted on touching a hazard (the episode ends).
    patrol: reach_flag: kinematic platforms turn back every `patrol` steps (0:
      never).
  """

  max_steps: int = 500
  jitter: float = 0.05
  accel: float = 20.0
  drag: float = 4.0
  box_drag: float = 8.0
  goal_reward: float = 1.0
  success_reward: float = 1.0
  shaping: float = 0.1
  step_cost: float = 0.0
  crush_penalty: float = 1.0
  run_speed: float = 4.0
  run_gain: float = 10.0
  jump: float = 420.0
  hazard_penalty: float = 1.0
  patrol: int = 180

  def replace(self, **changes) -> EnvParams:
    """A copy with some fields changed."""
    return dataclasses.replace(self, **changes)


_TASK_PARAMS = types.MappingProxyType({
    "push_box": EnvParams(max_steps=500),
    "push_box_easy": EnvParams(max_steps=200),
    "reach_flag": EnvParams(max_steps=600, box_drag=4.0, shaping=0.0),
})


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class EnvState:
  """The state of one episode (add a leading axis for a batch).

  Attributes:
    world: the `World`, its bodies in the env's slot order (player in slot 0).
    t: `[]` int32, steps taken in this episode.
    level: `[]` int32, index into `env.level_names`.
    ret: `[]` float32, the reward summed over this episode so far.
  """

  world: World
  t: jax.Array
  level: jax.Array
  ret: jax.Array


# Level arrays.


def _level(source) -> levels_lib.Level:
  """A `Level` from a `Level`, a name of `LEVELS` or of the shipped levels, or a path."""
  if isinstance(source, levels_lib.Level):
    return source
  if isinstance(source, str) and source in LEVELS:
    return levels_lib.parse_ascii(LEVELS[source], name=source, gravity=(0.0, 0.0))
  if isinstance(source, (str, pathlib.Path)):
    return levels_lib.load(source)
  raise ValueError(f"levels: expected Level objects, level names or paths, got {source!r}")


def _group(level: levels_lib.Level, kind: str) -> list[int]:
  """The bodies of `level` in one slot group, by tag or (platforms) by kind."""
  if kind == "player":
    return [level.player]
  if kind == "platform":  # One-way or kinematic, not sensors.
    kinematic = np.isinf(level.mass) & np.any(level.vel != 0, axis=-1)
    return np.flatnonzero((level.one_way | kinematic) & ~level.sensor).tolist()
  return level.indices(kind).tolist()


_PAD = dict(pos=0.0, half=1.0, mass=np.inf, vel=0.0, friction=0.0, one_way=False,
            sensor=False, category=levels_lib.SOLID, mask=levels_lib.ALL)
_FIELDS = tuple(_PAD)


def _arrange(level: levels_lib.Level, groups: Sequence[tuple[str, int]], rest: int,
             gravity) -> dict[str, np.ndarray]:
  """One level's host arrays in slot order: each group padded to its count, then the
  remaining bodies padded to `rest`; plus `active`, `gravity` and `bounds`."""
  taken, order = set(), []
  for kind, count in groups:
    idx = [i for i in _group(level, kind) if i not in taken]
    if len(idx) > count:
      raise ValueError(f"level {level.name!r}: {len(idx)} {kind} bodies, but the env holds "
                       f"{count} (raise it: make(..., {_count_name(kind)}={len(idx)}))")
    taken.update(idx)
    order += idx + [-1] * (count - len(idx))
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


def _rest_count(level: levels_lib.Level, groups: Sequence[tuple[str, int]]) -> int:
  taken = set()
  for kind, _ in groups:
    taken.update(_group(level, kind))
  return level.num_bodies - len(taken)


def _manhattan(a: jax.Array, b: jax.Array) -> jax.Array:
  """`[..., i, j]` Manhattan distances between `a` `[..., i, 2]` and `b` `[..., j, 2]`
  (no sqrt: gradient-safe everywhere)."""
  return jnp.sum(jnp.abs(a[..., :, None, :] - b[..., None, :, :]), axis=-1)


def senses(world: World) -> jax.Array:
  """`[n, n]` bool: `senses(world)[i, j]` says sensor j senses body i now.

  The rule of `World.sensed`: j is an active sensor, i an active movable body that
  is not a sensor, the two overlap strictly, and j's mask admits i's category. So
  `senses(world).any(0)` is what a step would report as `world.sensed` for these
  positions (the env uses it to fill `sensed` in a freshly reset world, and for
  the "box on a goal" flag of the observations).

  Examples:
    >>> from jaxchain import env, levels
    >>> lv = levels.load("sokoban3")  # Box 4 starts on goal 5.
    >>> s = env.senses(lv.world())
    >>> bool(s[4, 5]), s.any(0)[lv.indices("goal")].tolist()
    (True, [True, False, False])
  """
  over = jnp.all(world.half[:, None] + world.half[None] - jnp.abs(world.pos[:, None] -
                                                                 world.pos[None]) > 0, axis=-1)
  zero = jnp.zeros((), world.category.dtype)
  admit = (world.category[:, None] & world.mask[None]) != zero
  body = world.movable & ~world.sensor
  sensor = world.sensor & world.active
  return over & admit & body[:, None] & sensor[None]


# Environments.


class Environment:
  """A task on a fixed set of levels, with the gymnax interface.

  Built by `make`. `reset`, `step`, `reset_env`, `step_env`, `get_obs` and
  `render` are pure functions of their arguments (the env object holds only
  constants: the stacked level arrays and the static `Config`), so `jax.jit` and
  `jax.vmap` apply to them directly.

  Attributes:
    name: the task's name.
    level_names: the names of the levels, in index order (`EnvState.level`).
    config: the static `jaxchain.Config` every step uses.
    slots: `(group, count)` of the observed bodies after the player, in order.
    num_bodies: body slots of every world.
    default_params: the task's default `EnvParams`.
    frame_size: `(H, W)` of `render`'s frames by default.
  """

  # (group, count) observed after the player; subclasses set them.
  slots: tuple[tuple[str, int], ...] = ()

  def __init__(self, name: str, level_list: Sequence, *, gravity=None,
               default_params: EnvParams | None = None, **counts):
    slots = tuple((kind, counts.get(_count_name(kind), count)) for kind, count in self.slots)
    unknown = set(counts) - {_count_name(kind) for kind, _ in self.slots}
    if unknown:
      raise TypeError(f"make({name!r}): unknown keyword(s) {sorted(unknown)} (EnvParams fields, "
                      f"or slot counts: {', '.join(_count_name(k) for k, _ in self.slots)})")
    loaded = [_level(s) for s in level_list]
    if not loaded:
      raise ValueError(f"make({name!r}): no levels")
    groups = (("player", 1),) + slots
    rest = max(_rest_count(lv, groups) for lv in loaded)
    arrays = [_arrange(lv, groups, rest, gravity) for lv in loaded]
    host = {k: np.stack([a[k] for a in arrays]) for k in arrays[0]}
    worlds = stack([World.create(a["pos"], a["half"], a["mass"], a["vel"], a["active"],
                                 friction=a["friction"], gravity=a["gravity"],
                                 one_way=a["one_way"], sensor=a["sensor"],
                                 category=a["category"], mask=a["mask"]) for a in arrays])
    self.name = name
    self.level_names = tuple(lv.name for lv in loaded)
    self.slots = slots
    self.num_bodies = len(host["pos"][0])
    self.config = Config.for_world(worlds, converge=False)
    self.default_params = default_params or EnvParams()
    dtype = worlds.pos.dtype
    self._levels = {k: jnp.asarray(v, dtype if v.dtype == np.float64 else v.dtype)
                    for k, v in host.items()}
    starts = np.cumsum([1] + [count for _, count in slots])
    self._slot = {kind: np.arange(starts[k], starts[k + 1]) for k, (kind, _) in enumerate(slots)}
    self._observed = np.arange(1, starts[-1])
    extent = np.max(host["bounds"][:, 2:] - host["bounds"][:, :2], axis=0)
    self.frame_size = tuple(int(16 * math.ceil(e)) for e in extent[::-1])  # (H, W).
    # Bodies that jitter on reset (player and boxes) and feel box drag (boxes).
    box = np.zeros(self.num_bodies, bool)
    box[self._slot.get("box", [])] = True
    self._box = box
    self._jitter = box.copy()
    self._jitter[0] = True

  def __repr__(self) -> str:
    return (f"{type(self).__name__}({self.name!r}, levels {list(self.level_names)}, "
            f"{self.num_bodies} bodies, obs {self.obs_size})")

  @property
  def obs_size(self) -> int:
    """The length of an observation vector."""
    return PLAYER_FEATURES + len(SLOT_FIELDS) * len(self._observed)

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
    """The body slots (int array) of one observed group ("box", "goal", "flag",
    "hazard", "platform"); the player is slot 0."""
    if group == "player":
      return np.zeros(1, np.int64)
    if group not in self._slot:
      raise ValueError(f"slots_of: {self.name} has groups player, {', '.join(self._slot)}; "
                       f"got {group!r}")
    return self._slot[group]

  def action_space(self, params: EnvParams | None = None):
    """The space of valid actions."""
    raise NotImplementedError

  def observation_space(self, params: EnvParams | None = None) -> Box:
    """`Box(-inf, inf, (obs_size,), float32)`."""
    del params
    return Box(-math.inf, math.inf, (self.obs_size,))

  # The gymnax interface.

  def reset(self, key: jax.Array, params: EnvParams | None = None):
    """A fresh episode: `(obs, state)` on a random level with start jitter.

    Args:
      key: a PRNG key.
      params: `EnvParams` (default: `default_params`).

    Returns:
      `(obs, state)`: `obs` `[obs_size]` float32, `state` an `EnvState`.

    Examples:
      >>> import jax
      >>> import jaxchain as jc
      >>> env, params = jc.env.make("push_box")
      >>> obs, state = jax.jit(env.reset)(jax.random.key(0), params)
      >>> obs.shape, obs.dtype, int(state.t), env.level_names[int(state.level)]
      ((73,), dtype('float32'), 0, 'sokoban2')
    """
    params = self.default_params if params is None else params
    state = self.reset_env(key, params)
    return self.get_obs(state, params), state

  def step(self, key: jax.Array, state: EnvState, action, params: EnvParams | None = None):
    """One step, resetting where the episode ends.

    Args:
      key: a PRNG key (used by the reset).
      state: the `EnvState`.
      action: an element of `action_space(params)`.
      params: `EnvParams` (default: `default_params`).

    Returns:
      `(obs, state, reward, done, info)`: `reward` float32 and `done` bool
      scalars; where `done`, `obs` and `state` start a new episode and
      `info["final_obs"]` is the observation the episode ended on. `info` also
      holds `terminated`, `truncated`, `success`, `episode_return`,
      `episode_length` and `status` (see the module docstring).

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

  def reset_level(self, key: jax.Array, params: EnvParams, level) -> EnvState:
    """A fresh `EnvState` on a given level (an int, or a traced int32 index into
    `level_names`), with start jitter from `key`: for evaluation on each level.

    Examples:
      >>> import jax
      >>> import jaxchain as jc
      >>> env, params = jc.env.make("push_box")
      >>> state = env.reset_level(jax.random.key(0), params, 2)
      >>> int(state.level), env.level_names[2], state.world.sensed[env.slots_of("goal")].tolist()
      (2, 'sokoban3', [True, False, False, False])
    """
    level = jnp.asarray(level, jnp.int32)
    a = {k: v[level] for k, v in self._levels.items()}
    offset = jax.random.uniform(key, a["pos"].shape, a["pos"].dtype, -1.0, 1.0)
    pos = a["pos"] + jnp.where(self._jitter[:, None], offset * params.jitter, 0.0)
    world = World.from_arrays(pos, a["half"], a["mass"], a["vel"], a["active"],
                              friction=a["friction"], gravity=a["gravity"], one_way=a["one_way"],
                              sensor=a["sensor"], category=a["category"], mask=a["mask"])
    # What a step would report as sensed here (a box may start on a goal).
    world = dataclasses.replace(world, sensed=senses(world).any(0))
    return EnvState(world=world, t=jnp.zeros((), jnp.int32), level=level,
                    ret=jnp.zeros((), world.pos.dtype))

  def step_env(self, key: jax.Array, state: EnvState, action, params: EnvParams):
    """One step without the reset: `(obs, state, reward, done, info)`."""
    del key
    world = self._before(state, params)
    new = physics_step(world, self.config, self._accel(state, action, params))
    reward, terminated, success = self._outcome(state.world, new, params)
    broken = (new.status & status.NON_FINITE) != 0
    reward = jnp.where(broken, 0.0, reward).astype(new.pos.dtype)
    terminated = terminated | broken
    t = state.t + 1
    truncated = (t >= params.max_steps) & ~terminated
    ret = state.ret + reward
    next_state = EnvState(world=new, t=t, level=state.level, ret=ret)
    info = dict(terminated=terminated, truncated=truncated, success=success & ~broken,
                episode_return=ret, episode_length=t, status=new.status)
    return self.get_obs(next_state, params), next_state, reward, terminated | truncated, info

  def get_obs(self, state: EnvState, params: EnvParams) -> jax.Array:
    """The observation vector of `state` (layout in the module docstring)."""
    w = state.world
    dtype = w.pos.dtype
    bounds = self._levels["bounds"][state.level]
    p0, v0 = w.pos[0], w.vel[0]
    rel = (p0 - bounds[:2]) / (bounds[2:] - bounds[:2])
    frac = state.t.astype(dtype) / jnp.asarray(params.max_steps, dtype)
    idx = self._observed
    present = w.active[idx]
    on_sensor = jnp.any(senses(w), axis=1)
    flag = jnp.where(w.sensor, w.sensed, on_sensor | w.one_way)[idx]
    d = w.pos[idx] - p0[None]
    feats = jnp.concatenate([present[:, None].astype(dtype), d, w.vel[idx], w.half[idx],
                             flag[:, None].astype(dtype)], axis=1)
    feats = jnp.where(present[:, None], feats, 0.0)
    return jnp.concatenate([rel, v0, w.touching[0].astype(dtype), frac[None],
                            feats.reshape(-1)]).astype(jnp.float32)

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
    bounds = self._levels["bounds"][state.level]
    return drawing.render(state.world, self.frame_size if size is None else tuple(size),
                          bounds, player=0)

  # Task hooks.

  def _before(self, state: EnvState, params: EnvParams) -> World:
    """The world handed to the physics step (tasks may set velocities here)."""
    del params
    return state.world

  def _accel(self, state: EnvState, action, params: EnvParams) -> jax.Array:
    raise NotImplementedError

  def _outcome(self, old: World, new: World, params: EnvParams):
    """`(reward, terminated, success)` of the step from `old` to `new`."""
    raise NotImplementedError


class PushBox(Environment):
  """Sokoban from above with a continuous player (tasks "push_box", "push_box_easy")."""

  slots = (("box", 4), ("goal", 4))

  def action_space(self, params: EnvParams | None = None) -> Box:
    """`Box(-1, 1, (2,), float32)`: the player's acceleration over `params.accel`."""
    del params
    return Box(-1.0, 1.0, (2,))

  def _accel(self, state, action, params):
    w = state.world
    a = jnp.clip(jnp.asarray(action, w.pos.dtype), -1.0, 1.0) * params.accel
    accel = jnp.where(self._box[:, None], -params.box_drag * w.vel, 0.0)
    return accel.at[0].set(a - params.drag * w.vel[0])

  def _potential(self, w: World) -> jax.Array:
    """Sum over boxes of the Manhattan distance to the nearest goal (0 with no goal)."""
    box, goal = self._slot["box"], self._slot["goal"]
    dist = jnp.where(w.active[goal][None], _manhattan(w.pos[box], w.pos[goal]), jnp.inf)
    nearest = jnp.min(dist, axis=1)
    return jnp.sum(jnp.where(w.active[box] & jnp.isfinite(nearest), nearest, 0.0))

  def _outcome(self, old, new, params):
    goal = self._slot["goal"]
    present = new.active[goal]
    before = jnp.sum(old.sensed[goal] & present)
    filled = new.sensed[goal] & present
    after = jnp.sum(filled)
    success = jnp.any(present) & jnp.all(filled | ~present)
    crushed = new.crushed[0]
    dtype = new.pos.dtype
    reward = (params.goal_reward * (after - before).astype(dtype)
              + params.success_reward * success.astype(dtype)
              + params.shaping * (self._potential(old) - self._potential(new))
              - params.step_cost - params.crush_penalty * crushed.astype(dtype))
    return reward, success | crushed, success


class ReachFlag(Environment):
  """A platformer: run, jump (when grounded) and reach the flag (task "reach_flag")."""

  slots = (("flag", 1), ("box", 4), ("hazard", 4), ("platform", 6))

  def action_space(self, params: EnvParams | None = None) -> Discrete:
    """`Discrete(6)`: `ACTIONS` (noop, left, right, jump, left+jump, right+jump)."""
    del params
    return Discrete(len(ACTIONS))

  def _before(self, state, params):
    # Kinematic platforms patrol: the level's velocity, reversed every `patrol` steps.
    w = state.world
    vel0 = self._levels["vel"][state.level]
    kinematic = w.active & (w.inv_mass == 0) & jnp.any(vel0 != 0, axis=-1)
    patrol = jnp.maximum(jnp.asarray(params.patrol, jnp.int32), 1)
    back = (jnp.asarray(params.patrol, jnp.int32) > 0) & ((state.t // patrol) % 2 == 1)
    vel = jnp.where(kinematic[:, None], jnp.where(back, -vel0, vel0), w.vel)
    return dataclasses.replace(w, vel=vel)

  def _accel(self, state, action, params):
    w = state.world
    dtype = w.pos.dtype
    a = jnp.clip(jnp.asarray(action, jnp.int32), 0, len(ACTIONS) - 1)
    direction = jnp.asarray(_ACTION_DIR, dtype)[a]
    jump = jnp.asarray(_ACTION_JUMP)[a] & flags.grounded(w)[0]
    ax = params.run_gain * (direction * params.run_speed - w.vel[0, 0])
    ay = jnp.where(jump, jnp.asarray(params.jump, dtype), 0.0)
    accel = jnp.where(self._box[:, None], jnp.stack([-params.box_drag * w.vel[:, 0],
                                                     jnp.zeros_like(w.vel[:, 1])], -1), 0.0)
    return accel.at[0].set(jnp.stack([ax, ay]).astype(dtype))

  def _distance(self, w: World) -> jax.Array:
    flag = self._slot["flag"]
    d = _manhattan(w.pos[:1], w.pos[flag])[0]
    return jnp.sum(jnp.where(w.active[flag], d, 0.0))

  def _outcome(self, old, new, params):
    flag, hazard = self._slot["flag"], self._slot["hazard"]
    success = jnp.any(new.sensed[flag] & new.active[flag])
    hurt = jnp.any(new.sensed[hazard] & new.active[hazard])
    crushed = new.crushed[0]
    dtype = new.pos.dtype
    f = lambda x: x.astype(dtype)
    reward = (params.success_reward * f(success) - params.hazard_penalty * f(hurt)
              - params.crush_penalty * f(crushed)
              + params.shaping * (self._distance(old) - self._distance(new)) - params.step_cost)
    return reward, success | hurt | crushed, success


_CLASSES = types.MappingProxyType(
    {"push_box": PushBox, "push_box_easy": PushBox, "reach_flag": ReachFlag})


def make(name: str, *, levels: Sequence | None = None, **overrides) -> tuple[Environment, EnvParams]:
  """An environment and its default parameters (gymnax's `make`).

  Runs on the host: loads the levels, pads and stacks them and builds the env's
  static `Config` (`Config.for_world` on the stacked levels, `converge=False`).

  Args:
    name: a task of `TASKS`: "push_box", "push_box_easy" or "reach_flag".
    levels: optional levels instead of the task's (`TASK_LEVELS`): names of
      shipped levels (`jaxchain.levels.names()`) or of `LEVELS`, paths, or
      `jaxchain.levels.Level` objects.
    **overrides: `EnvParams` fields to change in the returned params (e.g.
      `max_steps=200`), and slot counts (`max_boxes=`, `max_goals=`, ...; see
      `Environment.slots`).

  Returns:
    `(env, params)`.

  Raises:
    ValueError: for an unknown task, or a level with more bodies of a group than
      the env's slots hold.

  Examples:
    >>> import jax
    >>> import jaxchain as jc
    >>> env, params = jc.env.make("reach_flag", max_steps=300)
    >>> env.level_names, params.max_steps, env.action_space(params).n
    (('platformer1', 'platformer2'), 300, 6)
    >>> env.observation_space(params).shape
    (129,)
  """
  if name not in _CLASSES:
    raise ValueError(f"make: unknown task {name!r}; tasks: {', '.join(TASKS)}")
  fields = {f.name for f in dataclasses.fields(EnvParams)}
  params = _TASK_PARAMS[name].replace(**{k: v for k, v in overrides.items() if k in fields})
  counts = {k: v for k, v in overrides.items() if k not in fields}
  gravity = (0.0, 0.0) if _CLASSES[name] is PushBox else None
  env = _CLASSES[name](name, TASK_LEVELS[name] if levels is None else levels, gravity=gravity,
                       default_params=params, **counts)
  return env, params
