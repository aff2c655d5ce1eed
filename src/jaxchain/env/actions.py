"""Action maps: how an agent's action drives the player.

An action map is a small frozen object with
- `space`: the `Box` or `Discrete` of valid actions;
- `repeat`: physics steps per env step (action repeat, frame skip);
- `noop`: the action that does nothing (what an invalid action becomes);
- `invalid(action)`: a bool scalar, True for an action outside the space that the
  env cannot use (a discrete action out of range, a non-finite continuous one);
- `__call__(env, world, action, params)`: the player's `[2]` acceleration, or the
  `[n, 2]` accelerations of every body (a controller: `jaxchain.env.SokobanMoves`).

`check(action)` runs at trace time: it raises for a wrong shape or dtype with a
message naming `action`, and casts to the space's dtype. Ship your own map by
subclassing `ActionMap` (set `space` and `noop`, write `__call__`).
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp

from jaxchain import flags
from jaxchain.env.spaces import Box, Discrete

# `Moves`: (dx, dy) per discrete action.
MOVES = ("noop", "left", "right", "down", "up")
_MOVE_DIR = ((0.0, 0.0), (-1.0, 0.0), (1.0, 0.0), (0.0, -1.0), (0.0, 1.0))

# `RunJump` (reach_flag): (horizontal direction, jump) per discrete action.
ACTIONS = ("noop", "left", "right", "jump", "left+jump", "right+jump")
_ACTION_DIR = (0.0, -1.0, 1.0, 0.0, -1.0, 1.0)
_ACTION_JUMP = (False, False, False, True, True, True)


@dataclasses.dataclass(frozen=True)
class ActionMap:
  """The base of the action maps (see the module docstring).

  Attributes:
    repeat: physics steps per env step, each with the same action (>= 1).
  """

  repeat: int = 1

  def __post_init__(self):
    if isinstance(self.repeat, bool) or not isinstance(self.repeat, int) or self.repeat < 1:
      raise ValueError(f"{type(self).__name__}: repeat must be an integer >= 1, got {self.repeat!r}")

  @property
  def space(self) -> Box | Discrete:
    raise NotImplementedError

  @property
  def noop(self) -> jax.Array:
    """The action that does nothing."""
    space = self.space
    return jnp.zeros(space.shape, space.dtype)

  def check(self, action) -> jax.Array:
    """`action` as an array of the space's dtype; raises (at trace time) for a wrong
    shape or kind of dtype. A scalar is never broadcast to a vector.

    Raises:
      ValueError: for a wrong shape. TypeError: for a wrong kind of dtype (an
        integer or bool continuous action, a float or bool discrete one).
    """
    space = self.space
    try:
      x = jnp.asarray(action)
    except TypeError as e:
      raise TypeError(f"action: expected an array of shape {space.shape} and dtype "
                      f"{space.dtype} ({space}), got {type(action).__name__}") from e
    if x.shape != tuple(space.shape):
      hint = " (one env's action: vmap env.step over a batch)" if x.ndim > len(space.shape) else ""
      raise ValueError(f"action: expected shape {tuple(space.shape)} and dtype {space.dtype} for "
                       f"{space}, got shape {x.shape}{hint}")
    kind = jnp.integer if isinstance(space, Discrete) else jnp.floating
    if not jnp.issubdtype(x.dtype, kind):
      what = "an integer" if kind is jnp.integer else "a float"
      raise TypeError(f"action: expected {what} array of shape {tuple(space.shape)} (dtype "
                      f"{space.dtype}) for {space}, got dtype {x.dtype}")
    return x.astype(space.dtype)

  def invalid(self, action: jax.Array) -> jax.Array:
    """`[]` bool: the action is one the env cannot use (becomes `noop`, truncates)."""
    space = self.space
    if isinstance(space, Discrete):
      return (action < 0) | (action >= space.n)
    return ~jnp.all(jnp.isfinite(action))

  def __call__(self, env, world, action, params) -> jax.Array:
    """The player's `[2]` acceleration (world dtype) for a checked, valid action."""
    raise NotImplementedError


@dataclasses.dataclass(frozen=True)
class Accelerate(ActionMap):
  """Continuous: `Box(-1, 1, (2,))`, clipped, times `params.accel` (units/s^2).

  Finite values outside `[-1, 1]` are clipped; a non-finite one is invalid.
  """

  @property
  def space(self) -> Box:
    return Box(-1.0, 1.0, (2,))

  def __call__(self, env, world, action, params):
    del env
    return jnp.clip(jnp.asarray(action, world.pos.dtype), -1.0, 1.0) * params.accel


@dataclasses.dataclass(frozen=True)
class Moves(ActionMap):
  """Discrete moves, `Discrete(5)` (`MOVES`): 0 noop, 1 left, 2 right, 3 down, 4 up,
  each an acceleration of `params.accel` along that direction."""

  @property
  def space(self) -> Discrete:
    return Discrete(len(MOVES))

  def __call__(self, env, world, action, params):
    del env
    direction = jnp.asarray(_MOVE_DIR, world.pos.dtype)[action]
    return direction * params.accel


@dataclasses.dataclass(frozen=True)
class RunJump(ActionMap):
  """A platformer's actions, `Discrete(6)` (`ACTIONS`): noop, left, right, jump,
  left+jump, right+jump.

  Horizontal control steers the player's velocity toward `-params.run_speed`, 0 or
  `+params.run_speed` with gain `params.run_gain` (1/s); a jump is an upward
  acceleration `params.jump` for one step, applied only when the player is
  grounded (`jc.grounded`, from the previous step).
  """

  @property
  def space(self) -> Discrete:
    return Discrete(len(ACTIONS))

  def __call__(self, env, world, action, params):
    del env
    dtype = world.pos.dtype
    direction = jnp.asarray(_ACTION_DIR, dtype)[action]
    jump = jnp.asarray(_ACTION_JUMP)[action] & flags.grounded(world)[0]
    ax = params.run_gain * (direction * params.run_speed - world.vel[0, 0])
    ay = jnp.where(jump, jnp.asarray(params.jump, dtype), 0.0)
    return jnp.stack([ax, ay]).astype(dtype)
