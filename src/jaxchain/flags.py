"""What a step tells the game: contact flags, sensors, and the pairs layers admit.

Everything here reads what a pass already built (its candidate table and its link
table), so the flags cost no extra pass:

* `touching` from the link table of each pass (`World.touching`, `[n, 4]`), and the
  helpers `grounded` and `blocked` on top of it;
* `sensed`, whether a sensor overlaps a body its mask admits at any moment of a step
  (every substep, swept);
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


def sensed(world: World, pos: jax.Array, cand: Candidates,
           start: jax.Array | None = None) -> jax.Array:
  """`[n]` bool: sensor j overlaps (strictly) a movable body that is not a sensor and
  that j's mask admits (`category[i] & mask[j] != 0`).

  Without `start`, the overlap at `pos`. With `start` (`[n, 2]`, the positions a
  substep started from) the overlap at any moment of the substep, both bodies moving
  in a straight line from `start` to `pos`: a swept test, so a bullet that crosses a
  thin trip wire within one substep is seen (`_swept_overlap`).

  Read from the rows of the movable bodies of `cand` (every broadphase lists each
  movable body's partners in its row), scattered to the sensors they overlap.
  """
  n = pos.shape[0]
  j = cand.partner_index()
  col = lambda x, k: x[:, k][:, None]
  partner = lambda x, k: cand.gather(x[:, k])
  reach = [col(world.half, k) + partner(world.half, k) for k in (0, 1)]
  end = [partner(pos, k) - col(pos, k) for k in (0, 1)]
  if start is None:
    hit = (jnp.abs(end[0]) < reach[0]) & (jnp.abs(end[1]) < reach[1])
  else:
    begin = [partner(start, k) - col(start, k) for k in (0, 1)]
    hit = _swept_overlap(begin, end, reach)
  zero = jnp.zeros((), world.category.dtype)
  seen = (world.movable & ~world.sensor)[:, None] & cand.gather(world.sensor & world.active)
  seen = seen & cand.mask & hit
  seen = seen & ((world.category[:, None] & cand.gather(world.mask)) != zero)
  if cand.idx is None:  # Dense: column j holds body j.
    return jnp.any(seen, axis=0)
  hits = jnp.zeros(n, jnp.int32).at[j.reshape(-1)].max(seen.reshape(-1).astype(jnp.int32))
  return hits > 0


def _swept_overlap(begin: list[jax.Array], end: list[jax.Array],
                   reach: list[jax.Array]) -> jax.Array:
  """Whether two boxes overlap strictly at some fraction `t` in `[0, 1]` of a straight
  relative motion: per axis k the offset `d_k(t) = begin_k + t (end_k - begin_k)` must
  satisfy `|d_k(t)| < reach_k` (the summed half-extents), an open interval of `t` per
  axis; the boxes overlap when those intervals and `[0, 1]` meet. A motion of 0 along
  an axis keeps that axis's overlap for the whole substep. Division-free where the
  motion is 0 (double `where`), so no inf or NaN is formed.
  """
  lo, hi = jnp.zeros_like(begin[0]), jnp.ones_like(begin[0])
  open_lo, open_hi = jnp.zeros(begin[0].shape, bool), jnp.zeros(begin[0].shape, bool)
  ok = jnp.ones(begin[0].shape, bool)
  for b, e, r in zip(begin, end, reach):
    d = e - b
    still = d == 0
    safe = jnp.where(still, 1.0, d)
    t0, t1 = (-r - b) / safe, (r - b) / safe
    enter, leave = jnp.minimum(t0, t1), jnp.maximum(t0, t1)  # Open interval (enter, leave).
    ok = ok & jnp.where(still, jnp.abs(b) < r, True)
    # The latest entry and the earliest exit, each remembering whether it is open.
    later = ~still & (enter >= lo)
    lo, open_lo = jnp.where(later, enter, lo), jnp.where(later, True, open_lo)
    sooner = ~still & (leave <= hi)
    hi, open_hi = jnp.where(sooner, leave, hi), jnp.where(sooner, True, open_hi)
  return ok & jnp.where(open_lo | open_hi, lo < hi, lo <= hi)


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
