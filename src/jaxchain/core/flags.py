"""What a step reports, batch minor: sensors, and the status bits of the state.

Everything here reads what a pass or substep already built. Status bits are `[B]`
int32, one word per world, so one bad world never takes down the batch.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jax import lax

from jaxchain import status
from jaxchain.core.friction import STICK
from jaxchain.core.layout import Bodies, any_world, fold, scatter_max
from jaxchain.core.pairs import Candidates


def bit(on: jax.Array, code: int) -> jax.Array:
  """`[B]` int32: `code` where `on`, else 0."""
  return jnp.where(on, int(code), 0).astype(jnp.int32)


def sensed(bodies: Bodies, pos: jax.Array, cand: Candidates,
           start: jax.Array | None = None) -> jax.Array:
  """`[n, B]` bool: sensor j overlaps (strictly) a movable body that is not a sensor and
  that j's mask admits (`category[i] & mask[j] != 0`).

  Without `start`, the overlap at `pos`. With `start` (`[2, n, B]`, where a substep
  started) the overlap at any moment of the substep, both bodies moving in a straight
  line from `start` to `pos` (`swept_overlap`): a bullet crossing a thin trip wire within
  one substep is seen. Read from the rows of the movable bodies of `cand` and scattered
  to the sensors they overlap.
  """
  n, B = bodies.shape
  g, col = cand.gather, (lambda x: x[None])
  reach = [col(bodies.half[k]) + g(bodies.half[k]) for k in (0, 1)]
  end = [g(pos[k]) - col(pos[k]) for k in (0, 1)]
  if start is None:
    hit = (jnp.abs(end[0]) < reach[0]) & (jnp.abs(end[1]) < reach[1])
  else:
    begin = [g(start[k]) - col(start[k]) for k in (0, 1)]
    hit = swept_overlap(begin, end, reach)
  zero = jnp.zeros((), bodies.category.dtype)
  seen = col(bodies.movable & ~bodies.sensor) & g(bodies.sensor & bodies.active)
  seen = seen & cand.mask & hit & ((col(bodies.category) & g(bodies.mask)) != zero)
  if cand.idx is None:  # Dense: slot k holds body k.
    return fold("any", jnp.swapaxes(seen, 0, 1))
  return scatter_max(n, cand.flat, seen.astype(jnp.int32)) > 0


def swept_overlap(begin: list[jax.Array], end: list[jax.Array],
                  reach: list[jax.Array]) -> jax.Array:
  """Whether two boxes overlap strictly at some fraction `t` in `[0, 1]` of a straight
  relative motion: per axis the offset `d(t) = begin + t (end - begin)` must satisfy
  `|d(t)| < reach` (an open interval of t per axis); the boxes overlap when those
  intervals and `[0, 1]` meet. A motion of 0 along an axis keeps that axis's overlap
  for the whole substep. Division-free where the motion is 0 (double `where`).
  """
  lo, hi = jnp.zeros_like(begin[0]), jnp.ones_like(begin[0])
  open_lo, open_hi = jnp.zeros(begin[0].shape, bool), jnp.zeros(begin[0].shape, bool)
  ok = jnp.ones(begin[0].shape, bool)
  for b, e, r in zip(begin, end, reach):
    d = e - b
    still = d == 0
    safe = jnp.where(still, 1.0, d)
    t0, t1 = (-r - b) / safe, (r - b) / safe
    enter, leave = jnp.minimum(t0, t1), jnp.maximum(t0, t1)
    ok = ok & jnp.where(still, jnp.abs(b) < r, True)
    later = ~still & (enter >= lo)
    lo, open_lo = jnp.where(later, enter, lo), jnp.where(later, True, open_lo)
    sooner = ~still & (leave <= hi)
    hi, open_hi = jnp.where(sooner, leave, hi), jnp.where(sooner, True, open_hi)
  return ok & jnp.where(open_lo | open_hi, lo < hi, lo <= hi)


def finite(bodies: Bodies, *arrays: jax.Array) -> jax.Array:
  """`[B]` `NON_FINITE` where a state array (`[2, n, B]`) of an active body is NaN or inf,
  or a parameter is out of its domain (half-extents not finite and `> 0`, inverse masses
  or friction not finite and `>= 0`, gravity not finite): values traced code can put in
  a World without `World.replace`'s checks."""
  active = bodies.active
  bad = jnp.any(~jnp.isfinite(bodies.gravity), axis=0)
  bad = bad | any_world(active[None] & ~(jnp.isfinite(bodies.half) & (bodies.half > 0)))
  for p in (bodies.inv_mass, bodies.friction):
    bad = bad | any_world(active & ~(jnp.isfinite(p) & (p >= 0)))
  for x in arrays:
    bad = bad | any_world(active[None] & ~jnp.isfinite(x))
  return bit(bad, status.NON_FINITE)


def switched_off(bodies: Bodies, config, physics: bool = True) -> jax.Array:
  """`[B]`: `SWITCHED_OFF` and the bit naming each feature a world uses that the config
  leaves out of the step (`resolve`, with `physics=False`, uses neither friction nor
  gravity), and `SKIN_TOO_WIDE` where `config.skin` is wider than the world's bodies
  allow (`skin_too_wide`). Its equations run under the name `switched_off` (tests count
  the step's work apart from these O(n) checks, once per step)."""
  with jax.named_scope("switched_off"):
    return _switched_off(bodies, config, physics) | skin_too_wide(bodies, config)


def skin_too_wide(bodies: Bodies, config) -> jax.Array:
  """`[B]` `SKIN_TOO_WIDE`: `config.skin` exceeds an active body's half-extent (either
  axis) over `status.SKIN_HALF_RATIO`. Sensors take no contacts (with `config.sensors`):
  they do not count."""
  if config.skin == 0:
    return jnp.zeros(bodies.shape[-1:], jnp.int32)
  solid = bodies.active & ~bodies.sensor if config.sensors else bodies.active
  thin = bodies.half < config.skin * status.SKIN_HALF_RATIO
  return bit(any_world(solid[None] & thin), status.SKIN_TOO_WIDE)


def _switched_off(bodies: Bodies, config, physics: bool) -> jax.Array:
  active = bodies.active
  used = []
  if physics and not config.has_friction:
    used.append((status.FRICTION_OFF, any_world(active & (bodies.friction > 0))))
  if physics and not config.has_gravity:
    used.append((status.GRAVITY_OFF, jnp.any(bodies.gravity != 0, axis=0)
                 & any_world(bodies.movable)))
  if not config.immovable:
    used.append((status.IMMOVABLE_OFF, any_world(bodies.fixed)))
  if not config.one_way:
    used.append((status.ONE_WAY_OFF, any_world(active & bodies.one_way)))
  if not config.sensors:
    used.append((status.SENSORS_OFF, any_world(active & bodies.sensor)))
  if not config.layers:  # As `sizing.uses_layers`: some mask misses a present layer.
    category = jnp.where(active, bodies.category, jnp.zeros_like(bodies.category))
    present = jnp.bitwise_or.reduce(category, axis=0)
    used.append((status.LAYERS_OFF, any_world(
        active & ((category == 0) | ((bodies.mask & present[None]) != present[None])))))
  code = jnp.zeros(bodies.shape[-1:], jnp.int32)
  for b, on in used:
    code = code | bit(on, b | status.SWITCHED_OFF)
  return code


def too_fast(bodies: Bodies, vel: jax.Array, sub_dt: float) -> jax.Array:
  """`[B]` `FAST_BODY`: some body moves, in one substep, at least its own half-extent
  plus the thinnest body's along an axis (its centre could cross a thin body's)."""
  active = bodies.active[None]
  thinnest = jnp.min(jnp.where(active, bodies.half, jnp.inf), axis=1, initial=jnp.inf)
  reach = bodies.half + thinnest[:, None, :]
  return bit(any_world(active & (jnp.abs(vel) * sub_dt >= reach)), status.FAST_BODY)


# A substep's motion shorter than this many float spacings of the body's coordinate sets
# `PRECISION_LOST`. Rounding `x + v dt` errs by at most half a spacing of the result, so
# an unflagged substep's motion is off by at most `1 / (2 PRECISION_SPACINGS)` of itself
# (1/16 = 6.25%), over any number of substeps.
PRECISION_SPACINGS = 8


def motion_lost(bodies: Bodies, start: jax.Array, pos: jax.Array, vel: jax.Array,
                sub_dt: float) -> jax.Array:
  """`[B]` `PRECISION_LOST`: an active body whose velocity at the end of the substep is
  faster than `STICK` along an axis, and whose motion at that velocity over the substep
  is shorter than `PRECISION_SPACINGS` float spacings of its coordinate (at the start
  or the end, the larger): its motion rounds away, in part or whole. Read after the
  contacts, so a body at rest on a floor (whose gravity a contact cancels) and an
  inactive body (which never moves) set nothing. A report only."""
  start, pos, vel = (lax.stop_gradient(x) for x in (start, pos, vel))
  spacing = jnp.spacing(jnp.maximum(jnp.abs(start), jnp.abs(pos)))
  lost = (bodies.active[None] & (jnp.abs(vel) > STICK)
          & (jnp.abs(vel) * sub_dt < PRECISION_SPACINGS * spacing))
  return bit(any_world(lost), status.PRECISION_LOST)
