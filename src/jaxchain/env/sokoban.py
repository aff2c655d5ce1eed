"""Sokoban by the cell: `SokobanMoves`, an action map that moves the player exactly one
cell per action with Sokoban's push rule, and `sokoban_terminate`.

Why a controller. jaxchain's physics alone does not give Sokoban's rule: collision
chaining pushes a row of boxes as one body (a box pushed into a box moves both), and
contacts carry momentum. A player driven one cell (four steps of 1/64 s) into a box
with a second box behind it ends 0.30 cells short, and both boxes move (0.75 and 0.65
cells) and keep sliding at 12.4 units/s. So `SokobanMoves` decides the move on the
grid and drives the physics to carry it out: every physics step of an env step it returns the acceleration of every
body (`[n, 2]`), which the physics integrates like any other.

One env step is `repeat` physics steps (default 5):

1. From rest, the move is planned on the world's own positions: the player's cell
   `p`, the next cell `p + d` and the one after `p + 2d` (cell centres at
   `(i + 0.5) * cell`). A body "is in" a cell when the cell's centre lies strictly
   inside its box. The move is refused (nobody moves) when `p + d` is inside a wall
   (an immovable, non-sensor body), or holds a box (a movable, non-sensor body other
   than the player) while `p + 2d` holds a wall or a box. Otherwise the player moves,
   and the box in `p + d` (if any) with it. The noop moves nobody.
2. The movers get the velocity `d * cell / ((repeat - 1) * dt)` (a quarter of a cell
   per physics step by default: below the tunnelling limit of `status.FAST_BODY`), and
   keep it; the physics step that would carry a body past the next cell centre gets
   the velocity that lands it exactly on that centre.
3. A moving body on a cell centre is stopped (velocity 0).

So after each env step the world is at rest and every player and box centre is a
cell centre: exactly, when `dt` and `cell` are powers of two (`make(task, dt=1/64)`:
every product and sum is then exact in float32); otherwise to within a float32
rounding or two. While it moves, nothing else does: the cells it moves into are
free, so the physics finds no contact (gaps of at least 0.1 cells with the default
sizes) and its positions are the integrated velocities.

Use it with start jitter 0 (`params.jitter = 0`: the bodies must start on cells), no
drag or other task forces on the player and boxes, gravity 0 (XSB levels have it),
`Config.substeps = 1` (checked at trace time) and `sokoban_terminate`, which ends an
episode only once every goal holds a box and the world is at rest: the env stops an
action repeat at termination, and a box sensed by its goal mid-move would stop
there.

    task = jc.env.Task(name="microban", levels=jc.levels.load_collection(path),
                       actions=jc.env.SokobanMoves(), reward=jc.env.push_reward,
                       terminate=jc.env.sokoban_terminate,
                       params=jc.env.PushBoxParams(jitter=0.0, max_steps=1000))
    env, params = jc.env.make(task, dt=1 / 64)

Published solutions replay with `sokoban_actions` (LURD letters to actions, padded)
and `make_replay` (one vmapped, jittable scan of the env over every level's actions):

    replay = jax.jit(jc.env.make_replay(env, params))
    state, path, info = replay(jnp.arange(len(moves)), jc.env.sokoban_actions(moves))
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence

import jax
import jax.numpy as jnp
import numpy as np

from jaxchain.env.actions import _MOVE_DIR, MOVES, ActionMap
from jaxchain.env.spaces import Discrete

# `MOVES` index of each LURD letter (either case: a push is a move that pushes). XSB's
# rows run down the screen, so its "d" is the world's -y.
LURD = {"l": 1, "r": 2, "d": 3, "u": 4, "L": 1, "R": 2, "D": 3, "U": 4}

# How far from a cell centre (in cells) a body still counts as on it, and how slow
# (in cells per step) a body counts as at rest: both far above float32 rounding, far
# below a step's motion.
_ON_CENTRE = 1e-4
_AT_REST = 1e-4


@dataclasses.dataclass(frozen=True)
class SokobanMoves(ActionMap):
  """Sokoban moves by the cell, `Discrete(5)` (`MOVES`: noop, left, right, down, up).

  Each env step moves the player exactly one cell, pushing a box ahead of it one
  cell, unless the push rule refuses the move: a wall ahead, or a box ahead with a
  wall or a box behind it, and then nothing moves. A controller: see
  `jaxchain.env.sokoban` for how it drives the physics and what it needs (start
  jitter 0, no task forces, `Config.substeps == 1`, `sokoban_terminate`).

  Attributes:
    repeat: physics steps per env step (>= 2): `repeat - 1` to move, one to stop.
    cell: the grid's cell size in world units (1 for `jaxchain.levels` maps).

  Examples:
    >>> import jax, jax.numpy as jnp
    >>> import jaxchain as jc
    >>> task = jc.env.Task(name="s", levels=["#######\\n#@$ .#\\n#######"],
    ...                    actions=jc.env.SokobanMoves(), reward=jc.env.push_reward,
    ...                    terminate=jc.env.sokoban_terminate,
    ...                    params=jc.env.PushBoxParams(jitter=0.0))
    >>> env, params = jc.env.make(task, dt=1 / 64)
    >>> state = env.reset_level(jax.random.key(0), params, 0)
    >>> step = jax.jit(env.step_env)
    >>> for a in (2, 2, 2):  # Right, right, right: the box reaches the wall side.
    ...   _, state, _, done, info = step(jax.random.key(0), state, jnp.int32(a), params)
    >>> state.world.pos[0].tolist(), bool(info["success"])
    ([3.5, 1.5], True)
  """

  repeat: int = 5
  cell: float = 1.0

  def __post_init__(self):
    super().__post_init__()
    if self.repeat < 2:
      raise ValueError(f"SokobanMoves: repeat must be >= 2 (repeat - 1 physics steps move, one "
                       f"stops), got {self.repeat}")
    if isinstance(self.cell, bool) or not isinstance(self.cell, (int, float)) or not self.cell > 0:
      raise ValueError(f"SokobanMoves: cell must be a number > 0, got {self.cell!r}")

  @property
  def space(self) -> Discrete:
    return Discrete(len(MOVES))

  def __call__(self, env, world, action, params) -> jax.Array:
    """`[n, 2]` accelerations of every body for one physics step (see the module)."""
    del params
    config = env.config
    if config.substeps != 1:
      raise ValueError(f"SokobanMoves: needs Config.substeps == 1 (an acceleration is held over "
                       f"a whole step), got {config.substeps}")
    dtype = world.pos.dtype
    dt, cell = config.dt, self.cell
    n = world.num_bodies
    pos, vel, half = world.pos, world.vel, world.half
    solid = world.active & ~world.sensor
    wall = solid & (world.inv_mass == 0)
    box = solid & (world.inv_mass > 0) & (jnp.arange(n) != 0)
    movable = world.active & (world.inv_mass > 0)

    def inside(point, mask):  # [n] bool: the bodies of `mask` whose box holds `point`.
      return mask & jnp.all(jnp.abs(point[None] - pos) < half, axis=-1)

    # Plan, from rest: whom to move (the player, and the box ahead on a push).
    d = jnp.asarray(_MOVE_DIR, dtype)[action]
    here = (jnp.floor(pos[0] / cell) + 0.5) * cell
    ahead, beyond = here + d * cell, here + 2 * d * cell
    box_ahead = inside(ahead, box)
    blocked = (jnp.any(inside(ahead, wall)) |
               (jnp.any(box_ahead) & jnp.any(inside(beyond, wall | box))))
    go = (action != 0) & ~blocked
    movers = go & (box_ahead | (jnp.arange(n) == 0))
    speed = cell / ((self.repeat - 1) * dt)
    planned = jnp.where(movers[:, None], d * speed, 0.0)

    # Carry on: keep the velocity, land exactly on the next centre, stop on one.
    g = pos / cell - 0.5  # Grid coordinates: cell centres are the integers.
    on_centre = jnp.abs(g - jnp.round(g)) < _ON_CENTRE
    next_centre = jnp.where(vel > 0, jnp.floor(g) + 1, jnp.ceil(g) - 1)
    to_next = (next_centre - g) * cell
    lands = jnp.abs(to_next) <= jnp.abs(vel) * dt * (1 + 1e-4)
    carry = jnp.where(vel == 0, 0.0,
                      jnp.where(on_centre, (jnp.round(g) - g) * cell / dt,
                                jnp.where(lands, to_next / dt, vel)))

    resting = ~jnp.any(movable[:, None] & (jnp.abs(vel) * dt > _AT_REST * cell))
    target = jnp.where(resting, planned, carry)
    return jnp.where(movable[:, None], (target - vel) / dt, 0.0).astype(dtype)


def at_rest(world, cell: float = 1.0, dt: float = 1 / 60) -> jax.Array:
  """`[]` bool: no movable body moves more than `_AT_REST` cells a step."""
  movable = world.active & (world.inv_mass > 0)
  return ~jnp.any(movable[:, None] & (jnp.abs(world.vel) * dt > _AT_REST * cell))


def sokoban_terminate(env, old, action, new, params):
  """`(terminated, success)`: every goal holds a box and the world is at rest (so a
  `SokobanMoves` step is never cut short mid-move), or the player is crushed."""
  del old, action, params
  goal = env.slots_of("goal")
  present = new.world.active[goal]
  filled = jnp.any(present) & jnp.all(new.world.sensed[goal] | ~present)
  success = filled & at_rest(new.world, dt=env.config.dt)
  return success | new.world.crushed[0], success


def sokoban_actions(moves: Sequence[str]) -> np.ndarray:
  """`SokobanMoves` actions of Sokoban solutions, one row per solution.

  Args:
    moves: solutions, one letter per move (`jaxchain.levels.parse_moves` expands
      the run-length form): `l r d u` moves and `L R D U` pushes (`LURD`).

  Returns:
    `[len(moves), T]` int32 (`MOVES` indices), padded with noops (0) to the longest
    solution `T`.

  Raises:
    ValueError: for a letter that is not a move, naming the solution and position.

  Examples:
    >>> from jaxchain import env
    >>> env.sokoban_actions(["rRd", "u"]).tolist()
    [[2, 2, 3], [4, 0, 0]]
  """
  moves = list(moves)
  out = np.zeros((len(moves), max(map(len, moves), default=0)), np.int32)
  for k, m in enumerate(moves):
    for j, ch in enumerate(m):
      if ch not in LURD:
        raise ValueError(f"sokoban_actions: solution {k}, position {j + 1}: {ch!r} is not a move "
                         f"(l r d u, L R D U for pushes; expand counts with "
                         f"jaxchain.levels.parse_moves)")
      out[k, j] = LURD[ch]
  return out


def make_replay(env, params) -> Callable[[jax.Array, jax.Array], tuple]:
  """A replay of action sequences, one per level: `replay(levels, actions)`.

  Each level starts from `env.reset_level(jax.random.key(0), params, level)` and
  steps through its row of `actions` with `env.step_env` (no auto-reset: an episode
  that ends goes on stepping, so give `params` a `max_steps` above the row's
  length); the levels run side by side in one `jax.vmap` of a `lax.scan`. Pure and
  jittable: `jax.jit(make_replay(env, params))`, or lower and compile it apart.

  Args:
    env: an env of `jaxchain.env.make` (a `SokobanMoves` task, for solutions).
    params: its params.

  Returns:
    `replay(levels, actions) -> (state, path, info)`: `levels` `[L]` int level
    indices, `actions` `[L, T]` (`sokoban_actions`); `state` the final `EnvState` of
    each level (leading axis `L`), `path` `[L, T, 2]` the player's centre after every
    env step, `info` the steps' info dicts (`success`, `terminated`, ...: `[L, T]`).
  """
  def one(level, actions):
    key = jax.random.key(0)

    def body(state, action):
      _, state, _, _, info = env.step_env(key, state, action, params)
      return state, (state.world.pos[0], info)
    state, (path, info) = jax.lax.scan(body, env.reset_level(key, params, level), actions)
    return state, path, info

  def replay(levels, actions):
    return jax.vmap(one)(jnp.asarray(levels, jnp.int32), jnp.asarray(actions))

  return replay
