"""Host-side sizing: the static shapes and switches a `Config` gets from a scene.

Everything here looks at concrete (host) worlds, eagerly, to choose what the
compiled step is built for: the grid layout (`allocate`, defined with the grid in
`jaxchain.broadphase` and re-exported here), the longest chain and the most links
per body (`measure`), the substeps that keep bodies from tunnelling
(`_substep_need`), and all of it together (`for_world`, the body of
`Config.for_world`). Nothing here runs inside a step.

Layout: this module comes after `broadphase` and before `config`; `config` imports
it, so it takes the config class as an argument instead of importing it.
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax

from jaxchain import broadphase, status
from jaxchain.broadphase import allocate
from jaxchain.core import contacts as core_contacts
from jaxchain.core import pairs as core_pairs
from jaxchain.core.layout import NUM_DIRECTIONS

__all__ = ["DENSE_MAX_BODIES", "MAX_SUBSTEPS", "MIN_LINKS", "MIN_NEIGHBORS", "allocate",
           "for_world", "link_bound", "measure", "measure_neighbors", "measure_table", "neighbor_sizing",
           "stack_bound"]

# Worlds with at most this many body slots use dense all-pairs candidates in
# `for_world` and "auto". Measured with compact link tables
# (benchmarks/results/scaling.md): dense is faster at N=128 and the grid at N=256,
# for one world and for batches of 16; between the two it is not measured.
DENSE_MAX_BODIES = 192

# `for_world` keeps at least this many links per body and direction. Above it the
# width comes from the scene's sizes (`link_bound`): bodies that do not overlap each
# other can touch one face of a body at most `ceil(face / thinnest partner) + 1` at a
# time (two unit boxes side by side under a third is 2), so a table that wide never
# overflows without overlap; an overlapping crowd may need more, and raises
# `LINK_OVERFLOW` (never a silent miss).
MIN_LINKS = 1

# `for_world` refuses a scene that would need more substeps than this to keep every
# body under the tunnelling limit (a box of half-extent 1e-9 falling under gravity
# would get 1.7 million): a tiny or very fast body is nearly always a units mistake.
# Pass `substeps=` to `for_world` explicitly to run such a scene anyway.
MAX_SUBSTEPS = 64

# The neighbour table (`Config.neighbors`) `for_world` sizes: at least `MIN_NEIGHBORS`
# wide (a unit box in a packed room of unit boxes has 8 box partners and up to 2-3
# walls; a brick bond 10), or `NEIGHBOR_HEADROOM` times the most partners any movable
# body has now within the margin; used only when that is at most
# `NEIGHBOR_MAX_FRACTION` of the coarse row (else the build costs more than it saves):
# of dense pairs' row (`n`) at most half; of the grid's row, less than all of it (a
# rollout keeps the table from step to step, and even rebuilt every step a table of
# 12 beats grid rows of 22 in the passes: 0.69 against 0.44 M body-steps/s, settled
# room of 256, B = 256, single steps).
MIN_NEIGHBORS = 12
NEIGHBOR_HEADROOM = 1.5
NEIGHBOR_MAX_FRACTION = 0.5
NEIGHBOR_MAX_FRACTION_GRID = 1.0
# The margin: at least `MARGIN_FRACTION` of the thinnest movable half-extent, and at
# least `MARGIN_HEADROOM` times the largest motion a resolution pass is expected to
# cause (twice the fastest speed over a substep, a head-on pair, plus the deepest
# overlap now): a body may move `margin / 2` before `NEIGHBOR_MARGIN` is raised.
MARGIN_FRACTION = 0.5
MARGIN_HEADROOM = 4.0


# The switches `for_world(..., keep=...)` leaves on whatever the world holds now.
KEEPABLE = ("friction", "gravity", "immovable", "one_way", "sensors", "layers")


def for_world(cls, world, /, **overrides):
  """The body of `Config.for_world` (the public entry point, documented there).

  Takes the config class instead of importing it: `jaxchain.config` imports this
  module (so `Config.for_world` is a one-line delegation with no import inside a
  function), and this module therefore comes before it in the layout. `cls` only
  needs what `Config` offers: construction from keywords, `depth` (the default),
  `dt`, `skin`, `gravity`, `grid`, `replace` and `uses_grid`.

  Args:
    cls: the config class (`jaxchain.Config`).
    world: a (host) `World`, or a padded batch of worlds.
    **overrides: `Config` fields; explicit ones always win. And `keep`: names of
      `KEEPABLE` switches to leave on even where the world does not use them now.

  Returns:
    A `cls` instance sized for `world`.

  Raises:
    ValueError: when a body would need more than `MAX_SUBSTEPS` substeps, or for
      invalid overrides.
  """
  keep = overrides.pop("keep", ())
  keep = (keep,) if isinstance(keep, str) else tuple(keep)
  unknown = [k for k in keep if k not in KEEPABLE]
  if unknown:
    raise ValueError(f"Config.for_world: keep= takes names from {KEEPABLE}, got {unknown}")
  active = np.asarray(world.active)
  inv_mass = np.asarray(world.inv_mass)
  n = int(world.pos.shape[-2])
  movable = active & (inv_mass > 0)
  n_movable = int(np.max(np.sum(movable, axis=-1), initial=0))
  gravity = np.asarray(world.gravity, np.float64)  # [2] or [b, 2].
  switches = dict(
      gravity=bool(np.any(np.any(movable, axis=-1) & np.any(gravity != 0, axis=-1))),
      friction=bool(np.any(active & (np.asarray(world.friction) > 0))),
      one_way=bool(np.any(active & np.asarray(world.one_way))),
      sensors=bool(np.any(active & np.asarray(world.sensor))),
      layers=uses_layers(world))
  switches.update({k: True for k in keep if k in switches})
  switches.update({k: v for k, v in overrides.items() if k in switches})
  derived_keys = ("depth", "immovable", "broadphase", "grid", "substeps", "links", "neighbors",
                  "margin")
  base = cls(**{**{k: v for k, v in overrides.items() if k not in derived_keys}, **switches})
  derived = dict(immovable=bool(np.any(active & (inv_mass == 0))) or "immovable" in keep)
  if "substeps" not in overrides:
    need = _substep_need(world, base.dt, gravity if base.gravity else 0.0)
    if need.substeps > MAX_SUBSTEPS:
      raise ValueError(need.message(base.dt))
    derived["substeps"] = need.substeps
  if "skin" in overrides:  # The default skin on tinier bodies: the step's SKIN_TOO_WIDE.
    _check_skin(world, base)
  kind = overrides.get("broadphase", "auto")  # Not `broadphase`: that is the module.
  if kind in ("auto", "grid") and "grid" not in overrides:
    if kind == "grid" or n > DENSE_MAX_BODIES:
      spec = allocate(world, base.skin)
      crowded = spec.row_size > n / 4
      derived.update(grid=spec, broadphase="dense" if crowded and kind == "auto" else "grid")
    else:
      derived.update(broadphase="dense")
  chosen = base.replace(**{**derived, **{k: v for k, v in overrides.items() if k in derived_keys}})
  if "neighbors" not in overrides or overrides["neighbors"] is not None:
    table = neighbor_sizing(world, chosen.replace(substeps=derived.get("substeps",
                                                                        chosen.substeps)),
                            gravity if base.gravity else 0.0, overrides)
    derived.update(table)
    chosen = chosen.replace(**{**table, **{k: v for k, v in overrides.items()
                                           if k in ("grid", "neighbors", "margin")}})
  uses_grid = chosen.uses_grid(n)
  cap = max(n_movable, 1)
  if not ("depth" in overrides and "links" in overrides):  # Else nothing to measure.
    movable = world.active & (world.inv_mass > 0)
    chain_found, links_found = measure(world.pos, world.half, world.active, movable,
                                       np.int32(cap), spec=chosen.grid if uses_grid else None,
                                       skin=base.skin)
    stacks = stack_bound(world, gravity) if base.gravity else 0
    derived["depth"] = min(cap, max(cls.depth, 2 * int(np.max(chain_found, initial=0)), stacks))
    row = chosen.grid.row_size if uses_grid else n
    links = max(MIN_LINKS, link_bound(world), int(np.max(links_found, initial=0)))
    derived["links"] = links if links < row else None
  derived.update({k: v for k, v in overrides.items() if k in derived_keys})
  return base.replace(**derived)


def _check_skin(world, config) -> None:
  """Raises when `config.skin` is wider than the thinnest active body (not a sensor)
  allows: its half-extent over `status.SKIN_HALF_RATIO`, the limit the step reports as
  `status.SKIN_TOO_WIDE`."""
  solid = np.asarray(world.active) & ~np.asarray(world.sensor)
  half = np.asarray(world.half, np.float64)
  thinnest = float(np.min(np.where(solid[..., None], half, np.inf), initial=np.inf))
  if config.skin > thinnest / status.SKIN_HALF_RATIO:
    raise ValueError(
        f"Config.skin: {config.skin:g} is wider than the thinnest body allows (half-extent "
        f"{thinnest:g} / {status.SKIN_HALF_RATIO} = {thinnest / status.SKIN_HALF_RATIO:g}): "
        f"gaps within the skin count as contact, so bodies would rest and stop up to "
        f"{config.skin:g} apart; pass a smaller skin (the default is 1e-4)")


def stack_bound(world, gravity) -> int:
  """The tallest stack gravity can build (host): the most movable bodies whose extents
  across gravity's axis overlap one body's (itself included), over the bodies of each
  world. Under gravity a body comes to rest on what lies below it in its column, so a
  chain along gravity is never longer; a room of boxes falling into columns of 16 needs
  a depth of 16 once settled, though nothing touches at the start. Gravity's axis is
  the larger component of each world's `gravity` (`[2]` or `[B, 2]`); 0 without gravity.
  O(n log n) per world (sorted extents)."""
  pos, half = np.asarray(world.pos, np.float64), np.asarray(world.half, np.float64)
  movable = np.asarray(world.active) & (np.asarray(world.inv_mass) > 0)
  grav = np.broadcast_to(np.asarray(gravity, np.float64), pos.shape[:-2] + (2,))
  if pos.ndim == 2:
    pos, half, movable, grav = pos[None], half[None], movable[None], grav[None]
  best = 0
  for p, h, m, g in zip(pos, half, movable, grav):
    if not m.any() or not np.any(g != 0):
      continue
    across = 0 if abs(g[1]) >= abs(g[0]) else 1  # Columns along gravity, by this axis.
    lo, hi = (p[m, across] - h[m, across]), (p[m, across] + h[m, across])
    # Body i's column: the j with lo_j < hi_i and hi_j > lo_i (strict: touching sides
    # never stack).
    count = (np.searchsorted(np.sort(lo), hi, side="left")
             - np.searchsorted(np.sort(hi), lo, side="right"))
    best = max(best, int(count.max()))
  return best


def link_bound(world) -> int:
  """The most links one body can have in one direction without overlap (host).

  A movable body's face along x is `2 h_y` long; partners that touch it without
  overlapping each other are disjoint intervals along y, each at least `2 min h_y`
  long (the thinnest active body that is not a sensor), and at most
  `ceil(h_y / min h_y) + 1` of them can meet the face (one may stick out at each end).
  Likewise along y. One-way bodies meet others along y only (a thin jump-through
  ledge never sits beside a face along x), so they are left out of the partners along
  x. The largest over movable bodies and both axes; 0 when nothing is movable. Only
  immovable rows would need more (a wall with many boxes against it), and the link
  table keeps no immovable rows.
  """
  active = np.asarray(world.active) & ~np.asarray(world.sensor)
  movable = active & (np.asarray(world.inv_mass) > 0)
  if not movable.any():
    return 0
  half = np.asarray(world.half, np.float64)
  beside = active & ~np.asarray(world.one_way)  # Partners along x.
  thin_y = np.min(half[beside][:, 1], initial=np.inf)
  thinnest = np.array([np.min(half[active][:, 0]), thin_y])  # Per axis, over every world.
  widest = np.max(half[movable], axis=0)
  # Along x the face runs along y, and the other way round; a rounding margin keeps an
  # exact multiple (unit boxes on unit boxes) at its own count.
  ratio = widest[::-1] / thinnest[::-1]
  return int(np.max(np.ceil(ratio * (1 - 1e-6)))) + 1


def uses_layers(world) -> bool:
  """Whether collision layers keep some pair of active bodies of a world apart (host).

  True when an active body has category 0 (it collides with nothing) or a mask that
  misses a layer some active body of its world is in. Otherwise every mask covers
  every category present and every pair interacts, so layers can be left out.
  """
  active = np.asarray(world.active)
  category = np.where(active, np.asarray(world.category), 0).astype(np.uint64)
  present = np.bitwise_or.reduce(category, axis=-1, keepdims=True)  # Per world.
  mask = np.asarray(world.mask).astype(np.uint64)
  misses = (mask & present) != present
  return bool(np.any(active & ((category == 0) | misses)))


class _SubstepNeed(NamedTuple):
  """How many substeps a world needs, and the body that needs the most."""

  substeps: int
  body: tuple[int, ...]  # (body,) or (world, body).
  axis: int
  speed: float  # Along `axis`, with one step of gravity.
  half: float
  thinnest: float  # The thinnest active body's half-extent along `axis`.
  safety: float

  def message(self, dt: float) -> str:
    where = (f"body {self.body[0]}" if len(self.body) == 1
             else f"body {self.body[-1]} of world {self.body[0]}")
    return (
        f"Config.for_world: {where} would need {self.substeps} substeps, more than "
        f"MAX_SUBSTEPS = {MAX_SUBSTEPS}: it moves at {self.speed:.3g} along {'xy'[self.axis]} "
        f"(its velocity plus one step of gravity) and has half-extent {self.half:.3g} there "
        f"(the thinnest body {self.thinnest:.3g}), so one step of dt = {dt:.3g} carries it "
        f"{self.speed * dt:.3g}, and without tunnelling it may move only "
        f"{(self.half + self.thinnest) / self.safety:.3g} per substep ((its half-extent + the "
        f"thinnest) / {self.safety:g}). Use larger bodies (or other length units) or a smaller "
        f"dt; or pass substeps= explicitly to run it anyway (status.FAST_BODY then reports "
        f"what moves too far)")


def _substep_need(world, dt: float, gravity=0.0, safety: float = 1.25) -> _SubstepNeed:
  """Fewest substeps with `|v| dt / substeps < (half + thinnest half) / safety` for
  every active body and axis, at the world's current velocities plus one step of
  gravity, and the body that sets it.

  Args:
    world: a world or a padded batch.
    dt: the step.
    gravity: `[2]` (one world) or `[b, 2]` (a batch, one per world), or a scalar;
      normally `world.gravity`, or 0 when gravity is switched off.
    safety: margin on the tunnelling limit.
  """
  active = np.asarray(world.active)
  if not active.any():
    return _SubstepNeed(1, (0,) * active.ndim, 0, 0.0, 0.0, 0.0, safety)
  half = np.asarray(world.half, np.float64)
  gravity = np.asarray(gravity, np.float64)
  if gravity.ndim >= 1:
    gravity = gravity[..., None, :]  # Per world, broadcast over its bodies.
  speed = np.broadcast_to(np.abs(np.asarray(world.vel, np.float64)) + np.abs(gravity) * dt,
                          half.shape)
  thinnest = np.min(half[active], axis=0)
  ratio = np.where(active[..., None], speed * dt * safety / (half + thinnest), 0.0)
  worst = np.unravel_index(int(np.argmax(ratio)), ratio.shape)
  return _SubstepNeed(max(1, int(np.ceil(ratio[worst]))), tuple(int(i) for i in worst[:-1]),
                      int(worst[-1]), float(speed[worst]), float(half[worst]),
                      float(thinnest[worst[-1]]), safety)


def _minor(pos, half, active, movable):
  """Host arrays of a world (`[n, ...]`) or a batch (`[B, n, ...]`) -> the core's
  batch-minor layout: `pos`, `half` `[2, n, B]`, `active`, `movable` `[n, B]`."""
  pos, half, active, movable = (jnp.asarray(x) for x in (pos, half, active, movable))
  if pos.ndim == 2:
    pos, half, active, movable = (x[None] for x in (pos, half, active, movable))
  xy = lambda x: jnp.moveaxis(x, (0, 2), (2, 0))
  return xy(pos), xy(half), active.T, movable.T


def _candidates(pos, half, active, movable, spec, skin) -> core_pairs.Candidates:
  if spec is None:
    return core_pairs.dense(active)
  return core_pairs.grid(pos, half, active, movable, spec, skin)[0]


def _per_world(single: bool, *xs):
  return tuple(x[0] for x in xs) if single else xs


@functools.partial(jax.jit, static_argnames=("spec", "skin"))
def measure(pos, half, active, movable, max_hops, *, spec: broadphase.GridSpec | None,
            skin: float) -> tuple[jax.Array, jax.Array]:
  """Longest chain of touching bodies (up to the traced `max_hops`) and most links
  per body and direction, per world (`measure_table`), for a single world or a batch
  (leading axis); dense pairs, or the grid with `spec`. Jitted once per shape and
  static arguments."""
  single = pos.ndim == 2
  pos, half, active, movable = _minor(pos, half, active, movable)
  cand = _candidates(pos, half, active, movable, spec, skin)
  return _per_world(single, *measure_table(pos, half, movable, cand, skin=skin, max_hops=max_hops))


def measure_table(pos: jax.Array, half: jax.Array, movable: jax.Array,
                  cand: core_pairs.Candidates, *, skin: float,
                  max_hops: int | jax.Array) -> tuple[jax.Array, jax.Array]:
  """What a scene needs now: the links in its longest chain of touching or
  overlapping bodies (a wall at the end counts as a link, along any direction, up
  to `max_hops`) and the most links any movable body has in one direction. Used on
  the host to pick a chain depth and a link table size; not differentiable (a
  `while_loop` that stops when nothing changes).

  Args:
    pos, half: `[2, n, B]` (the core's batch-minor layout).
    movable: `[n, B]` bool; immovable bodies end chains.
    cand: candidate table, `[W, n, B]`.
    skin: static.
    max_hops: int, may be traced (only the loop condition reads it).

  Returns:
    `(longest_chain, most_links)`, int32 `[B]` each.
  """
  code = core_contacts.contacts(pos, half, cand, skin).code
  code = jnp.where(movable[None], code, NUM_DIRECTIONS)
  front = code[None] == jnp.arange(NUM_DIRECTIONS, dtype=code.dtype)[:, None, None, None]
  carries = cand.gather(movable)[None]  # [1, W, n, B]: j passes pushes on.

  def hop(state):
    length, _, k = state
    ahead = jnp.where(carries, cand.gather(length), 0)  # [4, W, n, B]
    new = jnp.max(jnp.where(front, 1 + ahead, 0), axis=1, initial=0)
    return new, jnp.any(new != length), k + 1

  length = jnp.zeros((NUM_DIRECTIONS,) + movable.shape, jnp.int32)
  length, _, _ = lax.while_loop(lambda s: s[1] & (s[2] < jnp.int32(max_hops)), hop,
                                (length, jnp.array(True), jnp.array(0, jnp.int32)))
  most = jnp.max(jnp.sum(front, axis=1, dtype=jnp.int32), axis=(0, 1), initial=0)
  return jnp.max(length, axis=(0, 1), initial=0), most


def neighbor_sizing(world, config, gravity=0.0, overrides=None) -> dict:
  """The neighbour-table fields `for_world` gives `config` (host): `neighbors`, `margin`,
  and with the grid a `grid` whose cells hold the margin too.

  The margin is `max(MARGIN_FRACTION * thinnest movable half-extent, MARGIN_HEADROOM *
  (2 * fastest speed * dt / substeps + deepest overlap))`, the speeds with one step of
  gravity. The width is `max(MIN_NEIGHBORS, NEIGHBOR_HEADROOM * most partners within
  the margin now)`, and `neighbors` is None (no table: the coarse rows in every pass)
  when that is more than `NEIGHBOR_MAX_FRACTION` of dense pairs' row (`n`) or not
  narrower than the grid's row without the margin (`NEIGHBOR_MAX_FRACTION_GRID`), or
  nothing moves.
  Explicit `overrides` (`neighbors`, `margin`, `grid`) are kept.

  Args:
    world: a (host) world or padded batch.
    config: the config chosen so far (broadphase, grid, skin, dt, substeps).
    gravity: `[2]`, `[b, 2]` or 0 (switched off).
    overrides: the caller's explicit `Config` fields.

  Returns:
    A dict of `Config` fields.
  """
  overrides = overrides or {}
  active = np.asarray(world.active)
  movable = active & (np.asarray(world.inv_mass) > 0)
  n = int(world.pos.shape[-2])
  if not movable.any() or n < 2:
    return dict(neighbors=overrides.get("neighbors"), margin=overrides.get("margin", 0.0))
  uses_grid = config.uses_grid(n)
  spec = config.grid if uses_grid else None
  pos, half = np.asarray(world.pos), np.asarray(world.half)
  mov = np.asarray(movable)
  if "margin" in overrides:
    margin = float(overrides["margin"])
  else:
    _, deepest = measure_neighbors(pos, half, active, mov, np.asarray(config.skin, pos.dtype),
                                   spec=spec, skin=config.skin)
    half64 = np.asarray(world.half, np.float64)
    thinnest = float(np.min(np.where(movable[..., None], half64, np.inf)))
    grav = np.asarray(gravity, np.float64)
    if grav.ndim >= 1:
      grav = grav[..., None, :]
    speed = np.abs(np.asarray(world.vel, np.float64)) + np.abs(grav) * config.dt
    fastest = float(np.max(np.where(active[..., None], speed, 0.0), initial=0.0))
    motion = 2 * fastest * config.dt / config.substeps + float(np.max(deepest, initial=0.0))
    margin = max(MARGIN_FRACTION * thinnest, MARGIN_HEADROOM * motion)
  reach = broadphase.neighbor_reach(config.skin, margin)
  out = dict(margin=margin)
  if uses_grid:
    spec = overrides.get("grid") or allocate(world, broadphase.grid_skin(config.skin, margin))
    out["grid"] = spec
  count, _ = measure_neighbors(pos, half, active, mov, np.asarray(reach, pos.dtype), spec=spec,
                               skin=broadphase.grid_skin(config.skin, margin))
  # Against the rows the passes would read without a table (the grid without the margin).
  row = config.grid.row_size if uses_grid else n
  if "neighbors" in overrides:
    out["neighbors"] = overrides["neighbors"]
    return out
  width = max(MIN_NEIGHBORS, int(np.ceil(NEIGHBOR_HEADROOM * int(np.max(count, initial=0)))))
  if width > (NEIGHBOR_MAX_FRACTION_GRID * row - 1 if uses_grid else NEIGHBOR_MAX_FRACTION * row):
    return dict(neighbors=None, margin=0.0)
  out["neighbors"] = width
  return out


@functools.partial(jax.jit, static_argnames=("spec", "skin"))
def measure_neighbors(pos, half, active, movable, reach, *, spec: broadphase.GridSpec | None,
                      skin: float) -> tuple[jax.Array, jax.Array]:
  """Per world: the most partners any movable body has within the gap `reach` (traced;
  both axes, as the neighbour table counts them) and the deepest overlap (the smaller
  axis) between a movable body and any other. Dense pairs, or the grid with `spec`
  (built with `skin`); a single world or a batch."""
  single = pos.ndim == 2
  pos, half, active, movable = _minor(pos, half, active, movable)
  cand = _candidates(pos, half, active, movable, spec, skin)
  rows = cand.mask & (active & movable)[None]
  gaps = [jnp.abs(cand.gather(pos[k]) - pos[k][None]) - (half[k][None] + cand.gather(half[k]))
          for k in (0, 1)]
  near = rows & (gaps[0] <= reach) & (gaps[1] <= reach)
  depth = jnp.where(rows, jnp.maximum(-jnp.maximum(gaps[0], gaps[1]), 0.0), 0.0)
  count = jnp.max(jnp.sum(near, axis=0), axis=0, initial=0)
  return _per_world(single, count, jnp.max(depth, axis=(0, 1), initial=0.0))
