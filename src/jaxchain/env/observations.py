"""The observation modes: `vector`, `grid` and `pixels` (`make(..., obs=...)`).

Each is `fn(env, state, params) -> array`, pure and jittable; `space(env)` gives the
matching `Box`. The layouts are in `jaxchain.env`'s docstring.
"""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np

from jaxchain import drawing
from jaxchain.env.spaces import Box
from jaxchain.world import World

SLOT_FIELDS = ("present", "dx", "dy", "vx", "vy", "hx", "hy", "flag")
PLAYER_FEATURES = 9  # Position (2), velocity (2), touching (4), time fraction (1).
# Pixels: sensors are drawn at least this large (half-extent, world units), so a
# goal is a visible square, not a 1-pixel dot.
SENSOR_MIN_HALF = 0.3


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


def space(env) -> Box:
  """The `Box` of `env`'s observation mode ("vector", "grid" or "pixels")."""
  if env.obs_mode == "vector":
    return Box(-math.inf, math.inf, (PLAYER_FEATURES + len(SLOT_FIELDS) * len(env._observed),))
  if env.obs_mode == "grid":
    return Box(0.0, 1.0, env.grid_shape + (len(env.grid_channels),))
  return Box(0, 255, env.pixel_size + (3,), np.dtype(np.uint8))


def vector(env, state, params) -> jax.Array:
  """The flat float32 vector: the player's features, then one slot of
  `SLOT_FIELDS` per observed body (`env.slots`, walls included)."""
  w = state.world
  dtype = w.pos.dtype
  bounds = env.level_data["bounds"][state.level]
  p0, v0 = w.pos[0], w.vel[0]
  rel = (p0 - bounds[:2]) / (bounds[2:] - bounds[:2])
  frac = state.t.astype(dtype) / jnp.asarray(params.max_steps, dtype)
  idx = env._observed
  present = w.active[idx]
  on_sensor = jnp.any(senses(w), axis=1)
  flag = jnp.where(w.sensor, w.sensed, on_sensor | w.one_way)[idx]
  d = w.pos[idx] - p0[None]
  feats = jnp.concatenate([present[:, None].astype(dtype), d, w.vel[idx], w.half[idx],
                           flag[:, None].astype(dtype)], axis=1)
  feats = jnp.where(present[:, None], feats, 0.0)
  return jnp.concatenate([rel, v0, w.touching[0].astype(dtype), frac[None],
                          feats.reshape(-1)]).astype(jnp.float32)


def grid(env, state, params) -> jax.Array:
  """`[H, W, C]` float32 occupancy, one channel per kind (`env.grid_channels`).

  Cells are one world unit, row 0 at the top of the level (its bounds' `ymax`),
  column 0 at its `xmin`. A channel's value in a cell is the largest, over the
  active bodies of that kind, of the area the body covers in the cell divided by
  the smaller of the cell's and the body's area: 1 for a wall filling the cell or
  a goal inside it, about 0.5 in each of two cells a box straddles.
  """
  del params
  w = state.world
  dtype = w.pos.dtype
  h, wd = env.grid_shape
  bounds = env.level_data["bounds"][state.level]
  lo, hi = w.pos - w.half, w.pos + w.half  # [n, 2]
  x0 = bounds[0] + jnp.arange(wd, dtype=dtype)  # Left edges of the columns.
  y1 = bounds[3] - jnp.arange(h, dtype=dtype)  # Top edges of the rows.
  ox = jnp.clip(jnp.minimum(hi[:, 0:1], x0[None] + 1) - jnp.maximum(lo[:, 0:1], x0[None]), 0.0)
  oy = jnp.clip(jnp.minimum(hi[:, 1:2], y1[None]) - jnp.maximum(lo[:, 1:2], y1[None] - 1), 0.0)
  area = jnp.minimum(4 * w.half[:, 0] * w.half[:, 1], 1.0)  # [n]
  cover = oy[:, :, None] * ox[:, None, :] / area[:, None, None]  # [n, H, W]
  member = jnp.asarray(env._channel_member) & w.active[:, None]  # [n, C]
  occ = jnp.max(jnp.where(member[:, None, None, :], cover[..., None], 0.0), axis=0)
  return jnp.clip(occ, 0.0, 1.0).astype(jnp.float32)


def pixels(env, state, params) -> jax.Array:
  """`uint8[H, W, 3]`: `jaxchain.render` of the level at `env.pixel_size`, the
  player in the player's colour, sensors drawn at least `SENSOR_MIN_HALF` large."""
  del params
  w = state.world
  half = jnp.where(w.sensor[:, None], jnp.maximum(w.half, SENSOR_MIN_HALF), w.half)
  bounds = env.level_data["bounds"][state.level]
  return drawing.render(dataclasses.replace(w, half=half), env.pixel_size, bounds, player=0)
