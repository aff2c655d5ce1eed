"""Queries a game asks each frame, and kinematic character helpers.

All pure functions of one `World` (use `jax.vmap` for a batch), jitted with their
static arguments, with fixed output shapes and no Python loop over bodies:

* `touching_bodies`: which bodies each body touches now, per direction (the contact
  rule of `jc.step`, read as indices instead of flags);
* `query_aabb`, `query_point`: which bodies a box or a point overlaps;
* `raycast`: the nearest body a ray enters (`RayHit`);
* `move_and_slide`: move one body as a kinematic character (Godot's
  `CharacterBody2D.move_and_slide` for boxes), stopping flush at walls, floors and
  ceilings (`SlideInfo`);
* `drive_platforms`: set the velocity of kinematic platforms and carry what stands on
  them (its riders, and what stands on those) by the change, with no friction needed;
* `drop_through`: let a body standing on one-way platforms fall through them.

Directions are those of `jaxchain.flags.DIRECTIONS`: `0: +x, 1: -x, 2: +y, 3: -y`.
The pair queries (`touching_bodies`, `drive_platforms`, `drop_through`) build dense
pairs, O(n^2) per world, like the dense broadphase; `raycast` sorts, O(n log n); the
others are O(n).

Host input is checked where it is concrete (a `ValueError` names the argument);
traced input (inside `jit` or `vmap`) is not checked, and a bad value there gives a
documented neutral answer instead (a zero ray direction hits nothing, a body index out
of range moves nothing: it never wraps around to the last body).
"""

from __future__ import annotations

import dataclasses
import functools

import jax
import jax.numpy as jnp
import numpy as np

from jaxchain import core
from jaxchain.config import Config
from jaxchain.core.contacts import ONE_WAY_MARGIN
from jaxchain.core.layout import NUM_DIRECTIONS
from jaxchain.world import World

SKIN = Config().skin  # The step's default link tolerance: faces this close touch.
# `drop_through` moves a body this fraction of the summed half-heights past the one-way
# margin (`core.contacts.ONE_WAY_MARGIN`), so rounding cannot leave it inside the margin.
DROP_EXTRA = 0.01


def _check_single(world: World, fn: str) -> None:
  if world.pos.ndim != 2:
    raise ValueError(f"{fn}: expected a single world with pos of shape (n, 2), got "
                     f"{world.pos.shape}; for a batch use jax.vmap({fn}, ...)")


def _concrete(x) -> np.ndarray | None:
  """`x` as a NumPy array if it is a concrete value, None if it is traced."""
  if isinstance(x, jax.core.Tracer):
    return None
  try:
    return np.asarray(x)
  except (TypeError, ValueError):
    return None


def _vector(name: str, fn: str, x, dtype, finite: bool = True) -> jax.Array:
  """A `[2]` float array; concrete input is checked for shape and finiteness."""
  host = _concrete(x)
  if host is not None:
    if host.shape != (2,):
      raise ValueError(f"{fn}: {name} must have shape (2,), got {host.shape}")
    if host.dtype.kind not in "fiu" or host.dtype == bool:
      raise ValueError(f"{fn}: {name} must be numbers, got {host.dtype}")
    if finite and not np.all(np.isfinite(host)):
      raise ValueError(f"{fn}: {name} must be finite, got {host.tolist()}")
  return jnp.asarray(x, dtype)


def _body_index(fn: str, world: World, body) -> jax.Array:
  """A body index as an int32 scalar; a concrete one must name an active body."""
  host = _concrete(body)
  n = world.num_bodies
  if host is not None:
    if host.shape != () or host.dtype.kind not in "iu":
      raise ValueError(f"{fn}: body must be one integer index, got {host.dtype} {host.shape}")
    if not 0 <= int(host) < n:
      raise ValueError(f"{fn}: body {int(host)} is not in [0, {n})")
    active = _concrete(world.active)
    if active is not None and not active[int(host)]:
      raise ValueError(f"{fn}: body {int(host)} is inactive")
  return jnp.asarray(body, jnp.int32)


def _category_filter(fn: str, world: World, mask) -> jax.Array:
  """`[n]` bool: `category & mask != 0` (all True without a mask)."""
  if mask is None:
    return jnp.ones(world.num_bodies, bool)
  host = _concrete(mask)
  if host is not None:
    if host.shape != () or host.dtype.kind not in "iu" or not 0 <= int(host) <= 0xFFFFFFFF:
      raise ValueError(f"{fn}: mask must be one integer in [0, 2**32) (layer bits), got {host!r}")
    mask = np.uint32(int(host))
  bits = jnp.asarray(mask, jnp.uint32)
  return (world.category & bits) != jnp.zeros((), jnp.uint32)


def _pair_directions(world: World, skin: float) -> jax.Array:
  """`[4, n, n]` bool: entry `(d, i, j)`, body j lies in direction d from body i and
  touches it, by the step's contact rule (`core.contacts.contacts`) for every pair of
  active, solid, layer-admitted bodies at the current positions and velocities, as a
  pass that starts and ends here sees them: the one-way rule reads `world.vel`, and
  corner contacts at the seams of immovable surfaces take the surface's axis
  (`core.contacts.seam_axis`), so a body whose edge is on the seam between two floor
  tiles touches no tile's side, whatever the rounding. The core at one world (`B = 1`)."""
  state, bodies = core.from_world(world)
  cand = core.contacts.admit(core.pairs.dense(bodies.active), bodies, layers=True, sensors=True)
  solid = bodies.fixed & ~bodies.one_way
  ow = core.contacts.OneWay(one_way=bodies.active & bodies.one_way, solid=solid, vel=state.vel)
  c = core.contacts.contacts(state.pos, bodies.half, cand, skin, start=state.pos, one_way=ow,
                             surface=solid, walk=bodies.fixed & bodies.one_way)
  code = c.code[..., 0].T  # [n, n]: row i, partner j.
  return code[None] == jnp.arange(NUM_DIRECTIONS, dtype=code.dtype)[:, None, None]


# --- touching_bodies --------------------------------------------------------------------


def touching_bodies(world: World, *, k: int = 4, skin: float = SKIN
                    ) -> tuple[jax.Array, jax.Array]:
  """Which bodies each body touches now, per direction: `[n, 4, k]` indices.

  Entry `(i, d, s)` is the s-th body (by index) that lies in direction d from body i
  (`jc.flags.DIRECTIONS`: +x, -x, +y, -y) and touches it, or -1. "Touches" is the
  contact rule of a pass of `jc.step` (`core.contacts.contacts`) at the current positions:
  the pair's contact axis is the one of smaller overlap (ties x); along it the faces
  are within `skin` or overlap, and along the other axis the boxes overlap strictly
  (a corner contact is none). Only active, non-sensor pairs that collision layers admit
  count (`category[i] & mask[j]` and `category[j] & mask[i]` both nonzero), and a pair
  with a one-way body follows the one-way rule of the step (`core.contacts.one_way_rule`,
  reading `world.vel`): a body resting on a one-way platform touches it downward (and
  the platform touches the body upward), a body rising through it touches nothing.

  So `touching_bodies(world)[0][:, 3, 0]` answers "what am I standing on". Unlike
  `World.touching` (written by a step, movable bodies only), every body has rows,
  immovable ones included (a platform's `+y` row lists its riders). Corner contacts at
  the seams of immovable surfaces take the surface's axis as in the step
  (`core.contacts.seam_axis`): a box whose edge is on the seam between two floor tiles stands
  on them and touches no tile's side, whatever the rounding. A step's contact axes also
  read the step's motion (time of impact); here there is none, so at rest the two agree.

  O(n^2): dense pairs; the first `k` per row by a running count.

  Args:
    world: a single world (`jax.vmap` it for a batch).
    k: slots per body and direction (static).
    skin: faces this close touch (static; the step's `Config.skin` by default).

  Returns:
    `(index, overflow)`: `[n, 4, k]` int32 body indices in increasing order, -1 for
    none; `[n]` bool, body i touches more than `k` bodies in some direction (the first
    `k` by index are listed).

  Examples:
    >>> import jaxchain as jc
    >>> w = jc.World.create([[0.0, -0.5], [0.0, 0.5], [0.0, 1.5]],
    ...                     [[5.0, 0.5], [0.5, 0.5], [0.5, 0.5]], [float("inf"), 1.0, 1.0])
    >>> index, overflow = jc.touching_bodies(w, k=2)
    >>> index[:, 3, 0].tolist(), index[0, 2].tolist(), bool(overflow.any())
    ([-1, 0, 1], [1, -1], False)
  """
  _check_single(world, "touching_bodies")
  if isinstance(k, bool) or not isinstance(k, (int, np.integer)) or k < 1:
    raise ValueError(f"touching_bodies: k must be an integer >= 1, got {k!r}")
  if not (isinstance(skin, (int, float, np.floating)) and np.isfinite(skin) and skin >= 0):
    raise ValueError(f"touching_bodies: skin must be a finite number >= 0, got {skin!r}")
  return _touching_bodies(world, int(k), float(skin))


@functools.partial(jax.jit, static_argnames=("k", "skin"))
def _touching_bodies(world: World, k: int, skin: float) -> tuple[jax.Array, jax.Array]:
  n = world.num_bodies
  if n == 0:
    return jnp.zeros((0, 4, k), jnp.int32), jnp.zeros((0,), bool)
  sel = _pair_directions(world, skin)  # [4, n, n]
  rank = jnp.cumsum(sel, axis=-1, dtype=jnp.int32)  # Touching partners up to j.
  index = jnp.stack([jnp.where(jnp.any(hit, axis=-1), jnp.argmax(hit, axis=-1), -1)
                     for hit in (sel & (rank == s + 1) for s in range(k))]).astype(jnp.int32)
  overflow = jnp.any(jnp.sum(sel, axis=-1) > k, axis=0)
  return jnp.transpose(index, (2, 1, 0)), overflow


# --- query_aabb, query_point -------------------------------------------------------------


def query_aabb(world: World, lo, hi, *, mask=None) -> jax.Array:
  """Which active bodies overlap or touch the box `[lo, hi]`: `[n]` bool.

  Closed boxes (Box2D's `b2AABB_Overlaps`): a body whose face lies on the query box's
  face counts. For strict overlap, shrink the query box by a small amount. Sensors
  count like any body (`& ~world.sensor` leaves them out).

  Args:
    world: a single world.
    lo, hi: `[2]` lower-left and upper-right corners, `lo <= hi`.
    mask: optional uint32 layer bits: only bodies with `category & mask != 0` (Box2D's
      query filter).

  Returns:
    `[n]` bool. Under `jit`, a box with `lo > hi` along an axis finds nothing.

  Raises:
    ValueError: for concrete corners that are not `[2]` finite numbers, `lo > hi`, or a
      mask that is not an integer in `[0, 2**32)`.

  Examples:
    >>> import jaxchain as jc
    >>> w = jc.World.create([[0.0, 0.0], [2.0, 0.0]], [0.5, 0.5], 1.0)
    >>> jc.query_aabb(w, [0.5, -0.1], [1.0, 0.1]).tolist()  # touches body 0's face
    [True, False]
  """
  _check_single(world, "query_aabb")
  dtype = world.pos.dtype
  lo, hi = _vector("lo", "query_aabb", lo, dtype), _vector("hi", "query_aabb", hi, dtype)
  host_lo, host_hi = _concrete(lo), _concrete(hi)
  if host_lo is not None and host_hi is not None and np.any(host_lo > host_hi):
    raise ValueError(f"query_aabb: lo must be <= hi on both axes, got lo {host_lo.tolist()}, "
                     f"hi {host_hi.tolist()}")
  return _query_aabb(world, lo, hi, _category_filter("query_aabb", world, mask))


@jax.jit
def _query_aabb(world: World, lo: jax.Array, hi: jax.Array, admitted: jax.Array) -> jax.Array:
  low, high = world.pos - world.half, world.pos + world.half
  inside = jnp.all((low <= hi[None]) & (lo[None] <= high), axis=-1)
  return world.active & admitted & inside & jnp.all(lo <= hi)


def query_point(world: World, point, *, mask=None) -> jax.Array:
  """Which active bodies contain `point` (boundary included): `[n]` bool.

  Args:
    world: a single world.
    point: `[2]`.
    mask: optional uint32 layer bits (see `query_aabb`).

  Examples:
    >>> import jaxchain as jc
    >>> w = jc.World.create([[0.0, 0.0], [1.0, 0.0]], [0.5, 0.5], 1.0)
    >>> jc.query_point(w, [0.5, 0.0]).tolist(), jc.query_point(w, [0.2, 0.6]).tolist()
    ([True, True], [False, False])
  """
  _check_single(world, "query_point")
  p = _vector("point", "query_point", point, world.pos.dtype)
  return _query_aabb(world, p, p, _category_filter("query_point", world, mask))


# --- raycast -----------------------------------------------------------------------------


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class RayHit:
  """The nearest body a ray enters (`raycast`); with a batch, each field gains its axes.

  Attributes:
    hit: `[]` bool, whether the ray entered a body within `max_distance`.
    body: `[]` int32, the body, or -1.
    distance: `[]` float, distance from the origin to the entry point in world units
      (along the unit direction); `max_distance` when nothing was hit.
    point: `[2]` float, the entry point (the face coordinate exactly along the normal's
      axis); the origin when nothing was hit.
    normal: `[2]` float, the outward normal of the face entered (`(-1, 0)` for the left
      face, ...); zero when nothing was hit.
  """

  hit: jax.Array
  body: jax.Array
  distance: jax.Array
  point: jax.Array
  normal: jax.Array


def raycast(world: World, origin, direction, max_distance=float("inf"), *, mask=None,
            ignore=None) -> RayHit:
  """The nearest active, non-sensor body the ray `origin + t * direction` enters.

  The slab method on every body: the ray enters a box at the latest of its per-axis
  entry times and leaves it at the earliest exit; it hits when it enters before it
  leaves (strictly: a ray that only grazes a corner, or runs along the face of one
  body, hits nothing) at a distance in `[0, max_distance]`. A body that contains the
  origin is ignored (Box2D's rule: a ray starting inside a box does not hit it, so a
  character can cast from its own centre); a ray starting on a face and pointing into
  the box hits it at distance 0. The nearest hit wins, ties to the lower index.

  Seams: an axis-aligned ray that runs exactly along the faces between bodies (the seam
  of a floor of tiles, the base of a wall standing on a floor) sees them as their
  union, as the step and `move_and_slide` see one surface there: it enters a body on
  one side of the seam where a body on the other side holds it too (and both hold
  points past the entry), and hits that body there. A ground check straight down at an
  integer x over a tiled floor hits it, as over one merged body; along the outer face
  of a floor with nothing on the other side it still grazes and hits nothing.

  Distances are in world units: `direction` is normalised first (divided by its
  largest component, then by its length, so any direction of normal floats works,
  `(1e-30, -1e-30)` too). Gradient-safe: the distance and point of a hit are
  differentiable in `origin`, `direction` and the bodies' positions and sizes, also
  for axis-aligned rays (a direction component of 0 takes no division; the
  normalisation is guarded by a double `where`), and finite for tiny directions: the
  derivatives of the normalisation and of `1 / u` are written without `|d| ** -2` and
  `u ** -2` (which overflow at 1e-30 in float32), so `(1e-30, -1e-30)` has the
  gradient of `(1, -1)` times 1e30, and `(1, -1e-30)` that of `(1, 0)`. O(n log n): the
  seams sort the bodies along the ray.

  Args:
    world: a single world.
    origin: `[2]`.
    direction: `[2]`, nonzero (any length).
    max_distance: how far the ray reaches, `>= 0` (default inf).
    mask: optional uint32 layer bits: only bodies with `category & mask != 0`.
    ignore: optional body index, or `[n]` bool mask, of bodies to skip (the caster).

  Returns:
    A `RayHit`. Under `jit` a zero direction (or one below the dtype's smallest normal
    float, which XLA flushes to zero) hits nothing.

  Raises:
    ValueError: for concrete input that is not `[2]` finite numbers, a zero direction
      (no component of magnitude at least the dtype's smallest normal float), a
      negative or NaN `max_distance`, or a bad mask or ignore.

  Examples:
    >>> import jaxchain as jc
    >>> w = jc.World.create([[0.0, 0.0], [3.0, 0.0], [5.0, 0.0]], [0.5, 0.5], 1.0)
    >>> r = jc.raycast(w, [0.0, 0.25], [2.0, 0.0])  # from inside body 0: it is ignored
    >>> bool(r.hit), int(r.body), float(r.distance), r.point.tolist(), r.normal.tolist()
    (True, 1, 2.5, [2.5, 0.25], [-1.0, 0.0])
  """
  _check_single(world, "raycast")
  dtype = world.pos.dtype
  origin = _vector("origin", "raycast", origin, dtype)
  direction = _vector("direction", "raycast", direction, dtype)
  host = _concrete(direction)
  tiny = np.finfo(np.dtype(dtype)).tiny
  if host is not None and not np.max(np.abs(host.astype(np.float64))) >= tiny:
    raise ValueError(f"raycast: direction must be nonzero, with a component of magnitude at "
                     f"least {tiny:.3g} (the smallest normal {np.dtype(dtype).name}: smaller ones "
                     f"flush to zero), got {host.tolist()}")
  host = _concrete(max_distance)
  if host is not None and (host.shape != () or np.isnan(host) or host < 0):
    raise ValueError(f"raycast: max_distance must be a number >= 0 (inf for no limit), got "
                     f"{max_distance!r}")
  admitted = _category_filter("raycast", world, mask)
  if ignore is not None:
    host = _concrete(ignore)
    n = world.num_bodies
    if host is not None:
      ok = (host.shape == () and host.dtype.kind in "iu" and 0 <= int(host) < n) or (
          host.shape == (n,) and host.dtype == bool)
      if not ok:
        raise ValueError(f"raycast: ignore must be a body index in [0, {n}) or a bool mask of "
                         f"shape ({n},), got {host.dtype} {host.shape}")
    ignore = jnp.asarray(ignore)
    skip = (jnp.arange(n) == ignore) if ignore.ndim == 0 else ignore
    admitted = admitted & ~skip
  return _raycast(world, origin, direction, jnp.asarray(max_distance, dtype), admitted)


@jax.jit
def _raycast(world: World, origin: jax.Array, direction: jax.Array, max_distance: jax.Array,
             admitted: jax.Array) -> RayHit:
  if world.num_bodies == 0:  # Nothing to hit.
    zero = jnp.zeros(2, origin.dtype)
    return RayHit(hit=jnp.zeros((), bool), body=jnp.full((), -1, jnp.int32),
                  distance=max_distance, point=origin, normal=zero)
  u = _unit(direction)
  ok = jnp.any(u != 0)
  moving = u != 0  # [2]
  inv = _reciprocal(u)
  low, high = world.pos - world.half, world.pos + world.half  # [n, 2]
  t1, t2 = (low - origin[None]) * inv[None], (high - origin[None]) * inv[None]
  enter_k = jnp.where(moving[None], jnp.minimum(t1, t2), -jnp.inf)
  leave_k = jnp.where(moving[None], jnp.maximum(t1, t2), jnp.inf)
  # Along an axis the ray does not move, it must lie strictly inside the slab...
  in_slab = jnp.where(moving[None], True, (origin[None] > low) & (origin[None] < high))
  enter, leave = jnp.max(enter_k, axis=-1), jnp.min(leave_k, axis=-1)
  hittable = ok & world.active & ~world.sensor & admitted
  # ...or on a seam: on a face of bodies on one side of it and of bodies on the other,
  # the ray enters a body once a body of the other side holds it too (the union).
  line = jnp.sum(moving) == 1
  above = hittable & line & jnp.any(~moving[None] & (origin[None] == low), axis=-1)
  below = hittable & line & jnp.any(~moving[None] & (origin[None] == high), axis=-1)
  seam = (above & _covered(enter, enter, leave, below)) | (below & _covered(enter, enter, leave,
                                                                           above))
  hits = (hittable & (jnp.all(in_slab, axis=-1) | seam)
          & (enter >= 0) & (enter < leave) & (enter <= max_distance))
  best = jnp.argmin(jnp.where(hits, enter, jnp.inf)).astype(jnp.int32)
  hit = jnp.any(hits)
  distance = jnp.where(hit, enter[best], max_distance)
  axis = jnp.argmax(enter_k[best])  # The axis entered last (ties: x).
  onehot = jnp.arange(2) == axis
  face = jnp.where(u > 0, low[best], high[best])  # The face plane along each axis.
  point = jnp.where(onehot, face, origin + jnp.where(hit, enter[best], 0.0) * u)
  normal = jnp.where(onehot, -jnp.sign(u), 0.0)
  return RayHit(hit=hit, body=jnp.where(hit, best, -1), distance=distance,
                point=jnp.where(hit, point, origin), normal=jnp.where(hit, normal, 0.0))


def _normalise(x: jax.Array) -> tuple[jax.Array, jax.Array, jax.Array]:
  """`(u, scale, length)`: `x` (`[2]`) over its largest component (`scale`, so that a
  tiny direction such as (1e-30, -1e-30) does not square to zero), then over that
  vector's length (in `[1, sqrt 2]`); zeros for a zero `x`."""
  scale = jnp.max(jnp.abs(x))
  ok = scale > 0
  d = x / jnp.where(ok, scale, 1.0)
  length = jnp.sqrt(jnp.where(ok, jnp.sum(d * d), 1.0))
  return jnp.where(ok, d / length, 0.0), jnp.where(ok, scale, 1.0), length


@jax.custom_jvp
def _unit(x: jax.Array) -> jax.Array:
  """The unit vector along `x` (`[2]`), zero for a zero `x` (`_normalise`).

  Its derivative, `(dx - u (u . dx)) / |x|`, is written as one division by `scale` (and
  by `length`): JAX's own rules go through `scale ** -2`, which overflows for a tiny
  direction (1e-30 in float32: 1e60) and turned every gradient of a ray cast along
  such a direction into NaN (issue 44 item 9)."""
  return _normalise(x)[0]


@_unit.defjvp
def _unit_jvp(primals, tangents):
  (x,), (dx,) = primals, tangents
  u, scale, length = _normalise(x)
  t = dx / scale
  return u, (t - u * jnp.sum(u * t)) / length


@jax.custom_jvp
def _reciprocal(u: jax.Array) -> jax.Array:
  """`1 / u` where `u != 0`, else 0. Its derivative `-(du / u) / u` is written so that a
  zero cotangent stays zero for a tiny `u` (JAX's rule multiplies by `u ** -2`, inf for
  u = 1e-30 in float32, and `0 * inf` is NaN: the axis a ray nearly runs along)."""
  moving = u != 0
  return jnp.where(moving, 1.0 / jnp.where(moving, u, 1.0), 0.0)


@_reciprocal.defjvp
def _reciprocal_jvp(primals, tangents):
  (u,), (du,) = primals, tangents
  inv = _reciprocal(u)
  return inv, -(du * inv) * inv


def _covered(t: jax.Array, enter: jax.Array, leave: jax.Array, member: jax.Array
             ) -> jax.Array:
  """`[n]` bool: whether `t[i]` lies in `[enter[j], leave[j])` of some member j (`[n]`
  each). O(n log n): the members sorted by entry, with the running latest exit."""
  e = jnp.where(member, enter, jnp.inf)
  order = jnp.argsort(e)
  reach = jax.lax.cummax(jnp.where(member, leave, -jnp.inf)[order])
  k = jnp.searchsorted(e[order], t, side="right")  # Members entering at or before t.
  return (k > 0) & (reach[jnp.maximum(k - 1, 0)] > t)


# --- move_and_slide ----------------------------------------------------------------------


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class SlideInfo:
  """What `move_and_slide` ran into (scalars; a batch adds its axes).

  Attributes:
    on_floor: `[]` bool, the move along y went down and was stopped by a floor.
    on_wall: `[]` bool, the move along x was stopped by a wall.
    on_ceiling: `[]` bool, the move along y went up and was stopped by a ceiling.
    hit_x: `[]` int32, the body that stopped the move along x, or -1.
    hit_y: `[]` int32, the body that stopped the move along y, or -1.
    floor_velocity: `[2]` float, the velocity of the floor it landed on (a moving
      platform's, say: add it to the next move to ride along, Godot's
      `get_platform_velocity`); zero when not `on_floor`.
  """

  on_floor: jax.Array
  on_wall: jax.Array
  on_ceiling: jax.Array
  hit_x: jax.Array
  hit_y: jax.Array
  floor_velocity: jax.Array


def move_and_slide(world: World, body, velocity, dt, *, skin: float = SKIN
                   ) -> tuple[World, SlideInfo]:
  """Moves one body as a kinematic character: Godot's `move_and_slide`, for boxes.

  The body moves by `velocity * dt`, one axis at a time, x first, then y from where the
  x move ended. Along each axis it stops flush at the first face in its way (its
  position is then the obstacle's face plus its half-extent, exactly up to float
  rounding: it never enters), and that velocity component becomes 0; the other axis
  keeps its speed, so a body slides along floors and walls. An obstacle is every other
  active, non-sensor body that collision layers admit with it, movable ones included,
  that overlaps it along the other axis by more than `skin` (faces within `skin` of
  each other, as a floor under a body sliding along a wall, are no obstacle: no ghost
  collisions at seams) and lies ahead with a gap of at least `-skin`. A body it
  already overlaps more deeply never lets it go deeper: when that axis is the pair's
  contact axis (the one of smaller overlap, ties x, as in the step) and the move heads
  toward the obstacle's centre, the body stays where it is along that axis (a hit, its
  velocity component zeroed); moves that leave the overlap, or slide along it (a body
  sunk into a floor running sideways), are free, and nothing pushes it out. A
  one-way body blocks only a downward move whose bottom starts at or above its top, up
  to the step's one-way margin (`core.contacts.ONE_WAY_MARGIN` of the summed half-heights),
  and is then landed on flush; other moves pass it (from below, from the sides, and
  after `drop_through`).

  It pushes nothing: movable bodies are obstacles like walls (pushing is what `jc.step`
  and its chains are for), and the body's mass and one-way flag are not read. It sets
  the body's position and velocity in the world; a `jc.step` afterwards moves the body
  again by that velocity (and, if it is movable, by gravity and contacts), so a
  character that only `move_and_slide` moves should be stepped with its velocity set
  to 0 (or not stepped: a level of static bodies needs no step). `on_floor` needs a
  downward move: add gravity to the velocity every frame, as in Godot. To ride a moving
  platform, add `info.floor_velocity` to the next frame's move.

  Args:
    world: a single world.
    body: the index of the body to move (an active body; traced values allowed: one
      out of range or inactive moves nothing, and the info reports no hit).
    velocity: `[2]` velocity to move with.
    dt: the time step, `> 0`.
    skin: contact tolerance (static; the step's `Config.skin` by default).

  Returns:
    `(world, info)`: the world with the body's `pos` and `vel` (the velocity with the
    stopped components zeroed) updated, and a `SlideInfo`.

  Raises:
    ValueError: for a concrete body index that is out of range or inactive, a velocity
      that is not `[2]` finite numbers, or a `dt` that is not finite and `> 0`.

  Examples:
    >>> import jaxchain as jc
    >>> INF = float("inf")  # A floor and a wall at x = 2; the player runs right and falls.
    >>> w = jc.World.create([[0.0, -0.5], [2.5, 1.0], [0.0, 0.5]],
    ...                     [[5.0, 0.5], [0.5, 1.0], [0.5, 0.5]], [INF, INF, 1.0])
    >>> w, info = jc.move_and_slide(w, 2, [120.0, -30.0], 1 / 60)
    >>> w.pos[2].tolist(), w.vel[2].tolist(), bool(info.on_floor), int(info.hit_x)
    ([1.5, 0.5], [0.0, 0.0], True, 1)
  """
  _check_single(world, "move_and_slide")
  i = _body_index("move_and_slide", world, body)
  v = _vector("velocity", "move_and_slide", velocity, world.pos.dtype)
  host = _concrete(dt)
  if host is not None and (host.shape != () or not np.isfinite(host) or host <= 0):
    raise ValueError(f"move_and_slide: dt must be a finite number > 0, got {dt!r}")
  if not (isinstance(skin, (int, float, np.floating)) and np.isfinite(skin) and skin >= 0):
    raise ValueError(f"move_and_slide: skin must be a finite number >= 0, got {skin!r}")
  return _move_and_slide(world, i, v, jnp.asarray(dt, world.pos.dtype), float(skin))


def _obstacles(world: World, i: jax.Array) -> jax.Array:
  """`[n]` bool: the bodies that can stop body i (active, solid, admitted by layers)."""
  n = world.num_bodies
  zero = jnp.zeros((), jnp.uint32)
  admitted = (((world.category[i] & world.mask) != zero)
              & ((world.category & world.mask[i]) != zero))
  return world.active & ~world.sensor & admitted & (jnp.arange(n) != i)


def _sweep(world: World, obstacle: jax.Array, p: jax.Array, h: jax.Array, axis: int,
           move: jax.Array, skin: float) -> tuple[jax.Array, jax.Array, jax.Array]:
  """Moves the box (`p`, `h`) by `move` along `axis`: `(coordinate, hit, index)`."""
  other = 1 - axis
  d = world.pos - p[None]  # [n, 2]
  reach = world.half + h[None]
  side = reach[:, other] - jnp.abs(d[:, other])  # Overlap along the other axis.
  gap = jnp.abs(d[:, axis]) - reach[:, axis]  # >= 0: apart along the axis.
  ahead = jnp.where(move > 0, d[:, axis] > 0, d[:, axis] < 0)
  solid = ~world.one_way & (gap >= -skin)
  # Already inside it, this axis the pair's contact axis (the smaller overlap; ties x, as
  # in the step): moving toward its centre would go deeper, so the body stays put.
  deeper = ~world.one_way & (gap < -skin) & ((-gap <= side) if axis == 0 else (-gap < side))
  if axis == 1:  # A one-way body stops only a fall that starts above it (its margin).
    margin = ONE_WAY_MARGIN * reach[:, 1]
    solid = solid | (world.one_way & (move < 0) & (gap >= -margin))
  else:
    solid = solid & ~world.one_way
  stop = obstacle & ahead & (side > skin) & (solid | deeper) & (move != 0)
  clear = jnp.maximum(gap, 0.0)
  stop = stop & (clear <= jnp.abs(move))
  j = jnp.argmin(jnp.where(stop, clear, jnp.inf)).astype(jnp.int32)
  hit = jnp.any(stop)
  face = world.pos[j, axis] - jnp.sign(move) * reach[j, axis]
  face = jnp.where(deeper[j], p[axis], face)
  return jnp.where(hit, face, p[axis] + move), hit, jnp.where(hit, j, -1)


def _live(world: World, i: jax.Array) -> tuple[jax.Array, jax.Array]:
  """`(index, live)`: a traced body index clamped into range, and whether it names an
  active body (an index out of range names none: it must not wrap to the last body)."""
  n = world.num_bodies
  ok = (i >= 0) & (i < n)
  i = jnp.where(ok, i, 0)
  return i, ok & world.active[i]


@functools.partial(jax.jit, static_argnames="skin")
def _move_and_slide(world: World, i: jax.Array, v: jax.Array, dt: jax.Array,
                    skin: float) -> tuple[World, SlideInfo]:
  i, live = _live(world, i)
  obstacle = _obstacles(world, i)
  p, h = world.pos[i], world.half[i]
  move = jnp.where(live, v * dt, 0.0)
  x, hit_x, j_x = _sweep(world, obstacle, p, h, 0, move[0], skin)
  p = p.at[0].set(x)
  y, hit_y, j_y = _sweep(world, obstacle, p, h, 1, move[1], skin)
  p = p.at[1].set(y)
  vel = jnp.where(jnp.stack([hit_x, hit_y]), 0.0, v)
  vel = jnp.where(live, vel, world.vel[i])
  p = jnp.where(live, p, world.pos[i])
  on_floor = hit_y & (move[1] < 0)
  info = SlideInfo(on_floor=on_floor, on_wall=hit_x, on_ceiling=hit_y & (move[1] > 0),
                   hit_x=j_x, hit_y=j_y,
                   floor_velocity=jnp.where(on_floor, world.vel[jnp.maximum(j_y, 0)], 0.0))
  world = dataclasses.replace(world, pos=world.pos.at[i].set(p), vel=world.vel.at[i].set(vel))
  return world, info


# --- drive_platforms ---------------------------------------------------------------------


def drive_platforms(world: World, platforms, velocity, *, depth: int | None = None,
                    skin: float = SKIN, left_behind: bool = False):
  """Sets the velocity of kinematic platforms and carries their riders by the change.

  A kinematic platform is an immovable body (mass inf) that moves by its velocity in
  `jc.step`. Left alone, the step carries what stands on it only by friction (a
  frictionless box stays behind when the platform starts moving sideways). This sets
  each platform's velocity to `velocity` and adds the platform's velocity *change* to
  every body carried by it, so relative velocities are kept and the following steps
  move riders with the platform, friction or not.

  Carried: an active movable body whose support (what it stands on:
  `touching_bodies`' `-y` row, the one-way rule included; of several, the one under
  the widest part of its bottom face, ties to the lower index) is a driven platform,
  or is itself carried: a stack of any height by default, or up to `depth` bodies high
  (each level one hop, so `depth` bounds the work). With a `depth`, the bodies of a
  higher stack keep their velocity: `left_behind=True` returns which. Both velocity components change
  (a platform that starts down takes its riders down with it). A body touching a
  platform only from the side or from below is not carried, nor is an immovable one (a
  character moved by `move_and_slide` rides with `SlideInfo.floor_velocity`).

  This is external work, like the platform's own motion: momentum and energy are not
  conserved by this call (the step's conservation statements, physics page, are about
  the step and are untouched). Call it whenever you change a platform's velocity;
  changing it with `world.replace` or through `jc.step`'s `accel` carries nothing.
  O(n^2) (dense pairs).

  Args:
    world: a single world.
    platforms: the bodies to drive: one index, or an `[n]` bool mask. Movable bodies
      in it are ignored (a concrete one is an error).
    velocity: `[2]` for all of them, or `[n, 2]` (row i for body i).
    depth: how many bodies high a stack is carried (static); None (default): any
      height (`n - 1` hops).
    skin: contact tolerance (static).
    left_behind: also return which bodies a `depth` left behind (static).

  Returns:
    The world with the platforms' and their riders' velocities updated; with
    `left_behind`, `(world, left)`: `left` `[n]` bool, the bodies standing on a driven
    stack higher than `depth` (carried by the whole stack, not by this call; all
    False without a `depth`).

  Raises:
    ValueError: for a concrete platform index out of range, a mask of the wrong shape,
      a movable platform, a velocity that is not finite `[2]` or `[n, 2]`, or a
      `depth` that is not None or an integer >= 0.

  Examples:
    >>> import jaxchain as jc
    >>> INF = float("inf")  # A platform, a frictionless box on it, a box on that one.
    >>> w = jc.World.create([[0.0, 0.0], [0.0, 1.0], [0.0, 2.0]],
    ...                     [[2.0, 0.5], [0.5, 0.5], [0.5, 0.5]], [INF, 1.0, 1.0])
    >>> jc.drive_platforms(w, 0, [2.0, 0.0]).vel[:, 0].tolist()
    [2.0, 2.0, 2.0]
  """
  _check_single(world, "drive_platforms")
  n = world.num_bodies
  host = _concrete(platforms)
  if host is not None:
    if host.shape == () and host.dtype.kind in "iu":
      if not 0 <= int(host) < n:
        raise ValueError(f"drive_platforms: platform {int(host)} is not in [0, {n})")
      host = np.arange(n) == int(host)
    elif host.shape != (n,) or host.dtype != bool:
      raise ValueError(f"drive_platforms: platforms must be a body index or a bool mask of shape "
                       f"({n},), got {host.dtype} {host.shape}")
    inv_mass = _concrete(world.inv_mass)
    if inv_mass is not None and np.any(host & (inv_mass > 0)):
      raise ValueError(f"drive_platforms: platforms must be immovable (mass inf); bodies "
                       f"{np.flatnonzero(host & (inv_mass > 0)).tolist()} are movable")
  platforms = jnp.asarray(platforms)
  if platforms.ndim == 0:
    platforms = jnp.arange(n) == platforms
  vel = _concrete(velocity)
  if vel is not None and (vel.shape not in ((2,), (n, 2)) or not np.all(np.isfinite(vel))):
    raise ValueError(f"drive_platforms: velocity must be finite, of shape (2,) or ({n}, 2), got "
                     f"{vel.shape}")
  velocity = jnp.broadcast_to(jnp.asarray(velocity, world.vel.dtype), (n, 2))
  if depth is not None and (isinstance(depth, bool) or not isinstance(depth, (int, np.integer))
                            or depth < 0):
    raise ValueError(f"drive_platforms: depth must be None or an integer >= 0, got {depth!r}")
  hops = max(n - 1, 0) if depth is None else min(int(depth), max(n - 1, 0))
  world, left = _drive_platforms(world, platforms, velocity, hops, float(skin), bool(left_behind))
  return (world, left) if left_behind else world


def _supports(world: World, skin: float) -> tuple[jax.Array, jax.Array, jax.Array]:
  """Per body: whether it stands on something, the support under the widest part of
  its bottom face (ties: lower index), and whether every support is one-way; also the
  `[n, n]` support matrix. (`touching_bodies`' `-y` rows, uncompacted.)"""
  below = _pair_directions(world, skin)[3]  # [n, n]: j touches i from below.
  d = world.pos[None, :, 0] - world.pos[:, None, 0]
  width = world.half[:, None, 0] + world.half[None, :, 0] - jnp.abs(d)
  best = jnp.argmax(jnp.where(below, width, -jnp.inf), axis=-1).astype(jnp.int32)
  return jnp.any(below, axis=-1), best, below


@functools.partial(jax.jit, static_argnames=("hops", "skin", "report"))
def _drive_platforms(world: World, platforms: jax.Array, velocity: jax.Array, hops: int,
                     skin: float, report: bool) -> tuple[World, jax.Array]:
  n = world.num_bodies
  if n == 0:
    return world, jnp.zeros((0,), bool)
  driven = platforms & world.active & (world.inv_mass == 0)
  change = jnp.where(driven[:, None], velocity - world.vel, 0.0)
  stands, best, _ = _supports(world, skin)
  carried = stands & world.movable

  def hop(_, dv):  # One more body high: each carried body takes its support's change.
    return jnp.where(carried[:, None], dv[best], change)

  dv = jax.lax.fori_loop(0, hops, hop, change)
  left = jnp.zeros((n,), bool)
  if report and hops < n - 1:  # The whole stack (a support chain has at most n bodies).
    full = jax.lax.fori_loop(0, n - 1 - hops, hop, dv)
    left = jnp.any(full != dv, axis=-1)
  return dataclasses.replace(world, vel=world.vel + dv), left


# --- drop_through ------------------------------------------------------------------------


def drop_through(world: World, body, *, skin: float = SKIN) -> tuple[World, jax.Array]:
  """Lets a body standing only on one-way platforms fall through them.

  When body i stands on something (`touching_bodies`' `-y` row: the one-way rule of the
  step, at the current positions and velocities) and everything it stands on is
  one-way, it moves down until its bottom is below each support's top by the one-way
  margin plus a little: `top_j - (ONE_WAY_MARGIN + DROP_EXTRA) * (h_i + h_j)` along y
  (half-heights; `DROP_EXTRA = 0.01`). From there the one-way rule no longer holds it
  (its bottom is below the margin; only a crush would), so the next `jc.step` lets it
  fall, and `move_and_slide` passes the platforms too. Its velocity is unchanged. A body
  on solid ground (any support that is not one-way), or standing on nothing, is left
  as it is. O(n^2) (dense pairs).

  Args:
    world: a single world.
    body: the index of the body (an active body; traced values allowed: one out of
      range or inactive drops nothing).
    skin: contact tolerance (static).

  Returns:
    `(world, dropped)`: the world, and a bool scalar saying whether the body moved.

  Examples:
    >>> import jaxchain as jc
    >>> w = jc.World.create([[0.0, 0.0], [0.0, 0.6]], [[2.0, 0.1], [0.5, 0.5]],
    ...                     [float("inf"), 1.0], one_way=[True, False])
    >>> w, dropped = jc.drop_through(w, 1)
    >>> bool(dropped), round(float(w.pos[1, 1]), 4)  # 0.6 - 0.06 * (0.5 + 0.1)
    (True, 0.564)
  """
  _check_single(world, "drop_through")
  i = _body_index("drop_through", world, body)
  return _drop_through(world, i, float(skin))


@functools.partial(jax.jit, static_argnames="skin")
def _drop_through(world: World, i: jax.Array, skin: float) -> tuple[World, jax.Array]:
  i, live = _live(world, i)
  _, _, below = _supports(world, skin)
  row = below[i]  # [n]
  dropped = jnp.any(row) & ~jnp.any(row & ~world.one_way) & live
  h = world.half[i, 1]
  top = world.pos[:, 1] + world.half[:, 1]
  bottom = top - (ONE_WAY_MARGIN + DROP_EXTRA) * (world.half[:, 1] + h)
  y = jnp.min(jnp.where(row, bottom + h, jnp.inf))
  y = jnp.minimum(y, world.pos[i, 1])  # Only ever down.
  new = jnp.where(dropped, y, world.pos[i, 1])
  return dataclasses.replace(world, pos=world.pos.at[i, 1].set(new)), dropped
