"""What a step tells the game: contact flags, sensors, and the pairs layers admit.

Everything here reads what a pass already built (its candidate table and its link
table), so the flags cost no extra pass:

* `touching` from the link table of each pass (`World.touching`, `[n, 4]`), and the
  helpers `grounded` and `blocked` on top of it;
* `sensed`, whether a sensor overlaps a body its mask admits at the end of a step;
* `admit`, the candidate filter of collision layers and sensors (a pair that layers
  keep apart, or with a sensor in it, is never a contact, so chains, friction and
  the flags all leave it out).

Directions are those of `jaxchain.geometry.DIRECTIONS`: `0: +x, 1: -x, 2: +y, 3: -y`.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp

from jaxchain import geometry
from jaxchain.geometry import Candidates, Links
from jaxchain.world import World

RIGHT, LEFT, UP, DOWN = range(geometry.NUM_DIRECTIONS)  # Indices into `touching[..., d]`.


def admit(cand: Candidates, world: World, *, layers: bool, sensors: bool) -> Candidates:
  """`cand` without the pairs that collision layers keep apart or that hold a sensor.

  Bodies i and j interact only when `category[i] & mask[j]` and `category[j] &
  mask[i]` are both nonzero (Box2D's filter rule), and a sensor interacts with
  nothing (it only senses: `sensed`). With both switches off it returns `cand`.
  """
  ok = None
  if layers:
    cat_j, mask_j = cand.gather(world.category), cand.gather(world.mask)
    zero = jnp.zeros((), world.category.dtype)
    ok = ((world.category[:, None] & mask_j) != zero) & ((cat_j & world.mask[:, None]) != zero)
  if sensors:
    solid = ~world.sensor[:, None] & ~cand.gather(world.sensor)
    ok = solid if ok is None else ok & solid
  return cand if ok is None else dataclasses.replace(cand, mask=cand.mask & ok)


def touching(links: Links) -> jax.Array:
  """`[4, n]` bool: body i has a link in direction d (rows of the table only)."""
  return jnp.any(links.mask, axis=0)


def sensed(world: World, pos: jax.Array, cand: Candidates) -> jax.Array:
  """`[n]` bool: sensor j overlaps (strictly, at `pos`) a movable body that is not a
  sensor and that j's mask admits (`category[i] & mask[j] != 0`).

  Read from the rows of the movable bodies of `cand` (every broadphase lists each
  movable body's partners in its row), scattered to the sensors they overlap.
  """
  n = pos.shape[0]
  j = cand.partner_index()
  col = lambda x, k: x[:, k][:, None]
  partner = lambda x, k: cand.gather(x[:, k])
  over = [col(world.half, k) + partner(world.half, k) - jnp.abs(partner(pos, k) - col(pos, k)) > 0
          for k in (0, 1)]
  zero = jnp.zeros((), world.category.dtype)
  seen = (world.movable & ~world.sensor)[:, None] & cand.gather(world.sensor & world.active)
  seen = seen & cand.mask & over[0] & over[1]
  seen = seen & ((world.category[:, None] & cand.gather(world.mask)) != zero)
  if cand.idx is None:  # Dense: column j holds body j.
    return jnp.any(seen, axis=0)
  hits = jnp.zeros(n, jnp.int32).at[j.reshape(-1)].max(seen.reshape(-1).astype(jnp.int32))
  return hits > 0


def grounded(world: World) -> jax.Array:
  """Whether each body stands on something: `world.touching[..., 3]` (`[..., n]` bool).

  Examples:
    >>> import jaxchain as jc
    >>> w = jc.World.create([[0.0, 0.5], [0.0, -0.5]], [[0.5, 0.5], [5.0, 0.5]],
    ...                     [1.0, float("inf")])
    >>> jc.grounded(jc.step(w, jc.Config())).tolist()
    [True, False]
  """
  return world.touching[..., DOWN]


def blocked(world: World) -> dict[str, jax.Array]:
  """`touching` by name, like Phaser's `body.blocked`: `{"right", "left", "up",
  "down"}`, each `[..., n]` bool. Only movable bodies get flags."""
  t = world.touching
  return dict(right=t[..., RIGHT], left=t[..., LEFT], up=t[..., UP], down=t[..., DOWN])
