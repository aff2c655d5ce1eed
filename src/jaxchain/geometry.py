"""Narrowphase: per candidate pair, the contact axis, direction and depth.

The pairs come in a `Candidates` table, defined here because the narrowphase is
what consumes it; `jaxchain.broadphase` fills it.

Directions are numbered `0: +x, 1: -x, 2: +y, 3: -y`; `d ^ 1` is the opposite.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax

from jaxchain.gather import take

DIRECTIONS = ("+x", "-x", "+y", "-y")
NUM_DIRECTIONS = 4
OPPOSITE = np.array([1, 0, 3, 2])  # d -> d ^ 1, as a static index.
_WORD_BITS = 24  # Bits packed per word in `first_set`.
# `Links.reduce` unrolls its slots up to this many; longer rows reduce along the slot
# axis. 0: every table reduces along the slot axis, one gather for all its slots
# (benchmarks/compile_time.py, same bits: the demo compiles in 0.84x and runs in 0.94x,
# the room of 64 in 0.86x and 0.91x, against unrolling up to 8 slots).
UNROLL_SLOTS = 0


def opposite(x: jax.Array, axis: int = 0) -> jax.Array:
  """`x` with its direction axis (size 4) permuted `d -> d ^ 1`: `x[..., OPPOSITE, ...]`
  as a reshape and a reversal, which XLA runs as a copy (an index gather is slower)."""
  axis = axis % x.ndim
  pairs = x.reshape(x.shape[:axis] + (2, 2) + x.shape[axis + 1:])
  return jnp.flip(pairs, axis + 1).reshape(x.shape)


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class Candidates:
  """Neighbour table.

  Attributes:
    idx: `[n, m]` int32, `idx[i, k]` is the k-th candidate partner of body i.
      Unused slots hold any valid index and are masked out. `None` means dense:
      `m = n` and `idx[i, k] = k`, so gathers become broadcasts.
    mask: `[n, m]` bool, which slots are real candidate pairs. A pair (i, j) is
      listed in both rows i and j, so every pairwise quantity is computed from
      both sides and the resolver stays permutation-equivariant.
  """

  idx: jax.Array | None
  mask: jax.Array

  def gather(self, x: jax.Array) -> jax.Array:
    """Partner values of `x` with bodies on the last axis: `[..., n]` -> `[..., n, m]`."""
    if self.idx is None:
      return jnp.broadcast_to(x[..., None, :], x.shape[:-1] + (x.shape[-1], x.shape[-1]))
    if x.ndim == 1:
      return take(x, self.idx)
    return x[..., self.idx]

  def gather_bodies(self, x: jax.Array) -> jax.Array:
    """Per-partner values of a per-body array `x` of shape `[n, *f]`: `[n, m, *f]`."""
    if self.idx is None:
      n = x.shape[0]
      return jnp.broadcast_to(x[None], (n,) + x.shape)
    return x[self.idx]

  def partner_index(self) -> jax.Array:
    """`[n, m]` int32 partner indices (materialised for dense)."""
    if self.idx is None:
      n = self.mask.shape[0]
      return jnp.broadcast_to(jnp.arange(n, dtype=jnp.int32), (n, n))
    return self.idx


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class Contacts:
  """Contacts over the candidate table, all `[n, m]`.

  Attributes:
    link: the pair touches (gap within `skin`) or overlaps along its contact axis
      and overlaps strictly along the other axis. Links carry pushes and mass.
    direction: int32 in 0..3, direction from body i towards partner j; resolving
      the contact moves j along it and i against it.
    depth: penetration along the contact axis, `max(overlap, 0)`; 0 unless `link`.
    overlap: signed overlap along the contact axis (negative: a gap within `skin`).
  """

  link: jax.Array
  direction: jax.Array
  depth: jax.Array
  overlap: jax.Array


def overlap(pos_a, half_a, pos_b, half_b):
  """Per-axis overlap `h_a + h_b - |p_b - p_a|` (positive means overlapping)."""
  return half_a + half_b - jnp.abs(pos_b - pos_a)


def along_axis(o: jax.Array, use_y: jax.Array) -> tuple[jax.Array, jax.Array]:
  """Splits per-axis values `[..., 2]` into (along the contact axis, along the other)."""
  return jnp.where(use_y, o[..., 1], o[..., 0]), jnp.where(use_y, o[..., 0], o[..., 1])


def contacts(pos: jax.Array, half: jax.Array, cand: Candidates, skin: float,
             start: jax.Array | None = None, one_way: OneWay | None = None,
             surface: jax.Array | None = None) -> Contacts:
  """Contacts of every candidate pair.

  The contact axis of a pair that overlapped at `start` (or of every pair, without
  `start`) is the axis of smaller overlap (ties go to x). A pair that was separated at
  `start` (not overlapping beyond `skin` along both axes; touching, or a rounding
  overlap within `skin`, counts as separated) takes the
  axis along which the motion from `start` to `pos` closed the gap last: its time of
  impact. That is the axis the two boxes met along, so a box falling onto the edge of
  another lands on it instead of being pushed sideways (`impact_axis`).

  Along the contact axis the partner j lies in direction `sign(p_j - p_i)`, measured
  at `start` for a pair separated there (so a fast pair is resolved back to the side
  it came from) and at `pos` otherwise; coincident centres go by index: the body with
  the larger index lies in the positive direction. That tie rule is the only place
  body order matters.

  With `one_way` (see `OneWay`), a pair with a one-way member is a contact only when
  the one-way rule admits it, and then along y.

  With `surface` (and `start`), seams: a pair whose faces were level along both axes at
  `start` (a corner contact: `|o0| <= skin` on both) takes the axis that a surface
  bodies make decides (`seam_axis`): a body sliding along a floor of separate tiles
  rides onto the next tile, and one sliding down a wall of tiles slides past the next,
  whatever the rounding (no ghost collisions).

  Args:
    pos: `[n, 2]` centres.
    half: `[n, 2]` half-extents.
    cand: candidate table with `[n, m]` entries.
    skin: gap below which separated bodies still count as linked.
    start: optional `[n, 2]` centres at the start of the step.
    one_way: optional one-way bodies (`OneWay`).
    surface: optional `[n]` bool, the bodies whose faces make surfaces (immovable,
      not one-way): read with `start` only.
  """
  n = pos.shape[0]
  # One [n, m] array per coordinate: a trailing axis of 2 would leave XLA:CPU's
  # vector units mostly idle.
  col = lambda x, k: x[:, k][:, None]
  partner = lambda x, k: cand.gather(x[:, k])
  dx, dy = partner(pos, 0) - col(pos, 0), partner(pos, 1) - col(pos, 1)
  hx, hy = col(half, 0) + partner(half, 0), col(half, 1) + partner(half, 1)
  ox, oy = hx - jnp.abs(dx), hy - jnp.abs(dy)
  use_y = oy < ox
  if start is not None:
    dx0, dy0 = partner(start, 0) - col(start, 0), partner(start, 1) - col(start, 1)
    ox0, oy0 = hx - jnp.abs(dx0), hy - jnp.abs(dy0)
    # Apart at the start: not overlapping by more than the skin along some axis (a
    # float32 rounding overlap at a resting contact counts as touching).
    separated = (ox0 <= skin) | (oy0 <= skin)
    use_y = jnp.where(separated, _impact_axis(ox0, oy0, ox, oy, use_y, skin), use_y)
    if surface is not None:
      use_y = seam_axis(cand, half, surface, dx0, dy0, ox0, oy0, skin, use_y)
    dx, dy = jnp.where(separated, dx0, dx), jnp.where(separated, dy0, dy)
  admitted, upward = None, None
  if one_way is not None:
    admitted, vertical, upward = _one_way_rule(pos if start is None else start, half, cand,
                                               one_way, hy)
    use_y = use_y | vertical
  o_axis, o_other = jnp.where(use_y, oy, ox), jnp.where(use_y, ox, oy)
  d_axis = jnp.where(use_y, dy, dx)
  self_idx = jnp.arange(n, dtype=jnp.int32)[:, None]
  positive = (d_axis > 0) | ((d_axis == 0) & (cand.partner_index() > self_idx))
  link = cand.mask & (o_other > 0) & (o_axis >= -skin)
  if one_way is not None:
    positive = jnp.where(vertical, upward, positive)
    link = link & admitted
  direction = 2 * use_y.astype(jnp.int32) + (~positive).astype(jnp.int32)
  # Materialised once: every direction of the link table reads them, and fused into
  # its [4, n, m] consumers they would be recomputed four times.
  code = jnp.where(link, direction, NUM_DIRECTIONS)
  code, o_axis = _materialise(code), _materialise(o_axis)
  link, direction = code < NUM_DIRECTIONS, jnp.minimum(code, NUM_DIRECTIONS - 1)
  depth = jnp.where(link, jnp.maximum(o_axis, 0.0), 0.0)
  return Contacts(link=link, direction=direction, depth=depth, overlap=o_axis)


# A body came down onto a one-way body when, at the start of the step, its bottom was
# at or above the one-way body's top, up to this fraction of the pair's summed
# half-heights (resting contacts sit a rounding error inside), and it was not rising
# relative to it.
ONE_WAY_MARGIN = 0.05
# "Rising" relative to a one-way body: moving up relative to it faster than this (units
# per second), so float rounding of a resting body's velocity never lets it through.
ONE_WAY_RISE = 1e-6


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class OneWay:
  """The bodies the one-way rule reads, `[n]` bool each.

  Attributes:
    one_way: jump-through bodies (`World.one_way`, active ones).
    solid: immovable bodies that are not one-way: walls and floors. They block a
      one-way body on every side (a movable one-way crate rests on the floor).
    vel: optional `[n, 2]` velocities at the start of the pass: a body rising
      relative to a one-way body is not coming down onto it (`_one_way_rule`). None
      (`jaxchain.resolve`, no velocities): positions alone decide.
  """

  one_way: jax.Array
  solid: jax.Array
  vel: jax.Array | None = None


def _one_way_rule(ref: jax.Array, half: jax.Array, cand: Candidates, ow: OneWay,
                  hy: jax.Array) -> tuple[jax.Array, jax.Array, jax.Array]:
  """Which pairs with a one-way member are contacts, `[n, m]` each.

  A one-way body blocks only bodies that come down onto it from above, judged at `ref`
  (the start of the step) and from the velocities `ow.vel`. A body i comes down onto
  a one-way body j when

  * its bottom is at or above j's top; or
  * its bottom is below j's top by at most `ONE_WAY_MARGIN` of the summed
    half-heights and i is not rising relative to j (by more than `ONE_WAY_RISE`): a
    resting contact
    a rounding error inside. A body rising through j from below is not lifted onto it
    (issue 18: a box rising at 0.3 with its bottom 0.03 below the top was lifted onto
    it, +20.7 J in one step); or
  * it is *pressed* into j (a crush sinks a body deeper than the margin): its centre
    is above j's top and it sinks below j's top by at most the margin plus its press,
    the deepest overlap along y (the axis of smaller overlap) of a body above it that
    is not one-way. The crush rule splits the overlap of a crushed body equally between
    its two sides, so a body crushed onto a one-way ledge overlaps the ceiling as deep
    as it sinks into the ledge: the ledge keeps holding it, and it stays between the
    two until their faces meet (it never drops through). Velocities do not matter here:
    a box crushed on a rising elevator keeps the crush's mean velocity, upward, when
    the elevator stops, and must still be held.

  It lets the others pass, from below and from the sides; solid immovable bodies block
  it like any body. Two one-way bodies meet when one came down onto the other. Every
  test reads only the pair, its candidates and the start of the step: order-independent
  and stateless.

  Returns:
    `(admitted, vertical, upward)`: the pair may be a contact; its contact axis is y
    by the rule (not by the overlaps); and then the partner lies above (`+y`).
  """
  col = lambda x: x[:, 1][:, None]
  partner = lambda x: cand.gather(x[:, 1])
  margin = ONE_WAY_MARGIN * hy
  bottom_i, top_i = col(ref) - col(half), col(ref) + col(half)
  bottom_j, top_j = partner(ref) - partner(half), partner(ref) + partner(half)
  ow_i, ow_j = ow.one_way[:, None], cand.gather(ow.one_way)
  # Pressed from above: a body that is not one-way overlaps it from above by more than
  # the margin, along y (the axis of smaller overlap).
  dx, dy = cand.gather(ref[:, 0]) - ref[:, 0][:, None], partner(ref) - col(ref)
  ox = half[:, 0][:, None] + cand.gather(half[:, 0]) - jnp.abs(dx)
  oy = hy - jnp.abs(dy)
  from_above = cand.mask & ~ow_j & (dy > 0) & (ox > 0) & (oy > 0) & (oy < ox)
  press = jnp.max(jnp.where(from_above, oy, 0.0), axis=-1, initial=0.0)  # [n]
  press_i, press_j = press[:, None], cand.gather(press)
  if ow.vel is None:
    rising_i = rising_j = jnp.zeros(dy.shape, bool)
  else:
    rel = partner(ow.vel) - col(ow.vel)  # j's velocity along y relative to i's.
    rising_i, rising_j = rel < -ONE_WAY_RISE, rel > ONE_WAY_RISE
  pressed_i = (col(ref) > top_j) & (bottom_i >= top_j - margin - press_i) & (press_i > 0)
  pressed_j = (partner(ref) > top_i) & (bottom_j >= top_i - margin - press_j) & (press_j > 0)
  i_above = (bottom_i >= top_j) | (~rising_i & (bottom_i >= top_j - margin)) | pressed_i
  j_above = (bottom_j >= top_i) | (~rising_j & (bottom_j >= top_i - margin)) | pressed_j
  solid_i, solid_j = ow.solid[:, None], cand.gather(ow.solid)
  admitted = jnp.where(ow_i & ow_j, i_above | j_above,
                       (~ow_j | solid_i | i_above) & (~ow_i | solid_j | j_above))
  vertical = (ow_i | ow_j) & ~(solid_i | solid_j)
  return admitted, vertical, j_above


def _materialise(x: jax.Array) -> jax.Array:
  """`x`, computed into memory once. XLA fuses cheap elementwise producers into each of
  their consumers (recomputing them there), XLA:CPU drops `optimization_barrier`, and
  its simplifier removes trivial reductions. A dynamic-update-slice at an offset it
  cannot prove is 0 it keeps, as a copy into a buffer (the offset is always 0: an
  update of the buffer's full size is clamped there)."""
  if x.size == 0:  # An empty world: nothing to compute.
    return x
  zero = jnp.zeros((), jnp.int32) * jnp.isnan(x.reshape(-1)[0]).astype(jnp.int32)
  return lax.dynamic_update_slice(jnp.zeros_like(x), x, (zero,) * x.ndim)


def surface_cover(cand: Candidates, half: jax.Array, surface: jax.Array, dx0: jax.Array,
                  dy0: jax.Array, skin: float) -> jax.Array:
  """`[4, 2, n]` bool: entry `(f, c, i)`, the space just outside face f of body i (in
  `DIRECTIONS` order), next to the face's corner c (`0`: the corner on the positive
  side of the other axis, `1`: the negative one), lies inside a surface body.

  Read from i's candidates k (`dx0, dy0`: `[n, m]` offsets `p_k - p_i` at the start):
  along the face's axis k starts at or before the face plane (within `skin`) and ends
  beyond it; along the other axis it reaches the corner (within `skin`) and extends
  past it into the face. A surface body that covers a face there makes it an inner
  side of the surface.
  """
  col = lambda k: half[:, k][:, None]
  partner = lambda k: cand.gather(half[:, k])
  ok = cand.mask & cand.gather(surface)

  def axis_tests(d, h_i, h_k):  # Per sign s = +1, -1: (face tests, corner tests).
    face = [(s * d - h_k - h_i <= skin) & (s * d + h_k - h_i > skin) for s in (1.0, -1.0)]
    corner = [(s * d + h_k - h_i >= -skin) & (s * d - h_k - h_i < -skin) for s in (1.0, -1.0)]
    return face, corner

  face_x, corner_x = axis_tests(dx0, col(0), partner(0))
  face_y, corner_y = axis_tests(dy0, col(1), partner(1))
  faces = [(face_x[0], corner_y), (face_x[1], corner_y), (face_y[0], corner_x),
           (face_y[1], corner_x)]
  return jnp.stack([jnp.stack([jnp.any(ok & f & c, axis=-1) for c in corners])
                    for f, corners in faces])


def seam_axis(cand: Candidates, half: jax.Array, surface: jax.Array, dx0: jax.Array,
              dy0: jax.Array, ox0: jax.Array, oy0: jax.Array, skin: float,
              use_y: jax.Array) -> jax.Array:
  """The contact axis of corner contacts next to surfaces (`[n, m]` bool, y or not).

  Two bodies i and j whose faces were level along both axes at the start (`|o0| <=
  skin` on both) meet at a common corner C, diagonally. Of the two other quadrants at
  C, one lies beside i's face along y and j's face along x, the other beside i's face
  along x and j's face along y. Where exactly one of them is inside a surface body
  (`surface_cover`, read from both rows, so the rule is symmetric), the faces beside
  it are inner sides of that surface: the contact is along the other axis. A player
  whose edge is on the seam between two floor tiles rests on the next tile (it does not
  hit its side), and one pressed against a wall of tiles with its bottom on a seam
  slides past the next tile down (it does not stand on its top). Other pairs keep
  `use_y`.
  """
  cover = surface_cover(cand, half, surface, dx0, dy0, skin)
  own, other = cover[..., None], cand.gather(cover)  # [4, 2, n, m] each.
  sx, sy = dx0 > 0, dy0 > 0  # j's side of i along each axis.

  def pick(c, pos_face, neg_face, face_sign, corner_sign):
    at = lambda f: jnp.where(corner_sign, c[f, 0], c[f, 1])
    return jnp.where(face_sign, at(pos_face), at(neg_face))

  # Beside i's y face and j's x face (then the contact is along y), and the other one.
  beside_x = pick(own, 2, 3, sy, sx) | pick(other, 0, 1, ~sx, ~sy)
  beside_y = pick(own, 0, 1, sx, sy) | pick(other, 2, 3, ~sy, ~sx)
  corner = (jnp.abs(ox0) <= skin) & (jnp.abs(oy0) <= skin)
  return jnp.where(corner & (beside_x != beside_y), beside_x, use_y)


def impact_axis(o0: jax.Array, o1: jax.Array, tie: jax.Array, skin: float) -> jax.Array:
  """Whether a pair separated at the start met along y: per-axis overlaps `o0` at the
  start and `o1` now (`[..., 2]`), moving linearly in between.

  A pair whose faces were level along one axis at the start (`|o0| <= skin` there:
  resting on, or sliding along, each other's face) keeps that axis: a box sliding over
  the seam between two floor tiles of one height rides onto the next tile instead of
  hitting its side (a "ghost collision"), and one touching a box's side pushes it.
  Level along both axes (a corner contact, as at a seam the body's edge is exactly on)
  says nothing by itself: rounding decides the times below, so `contacts` lets the
  surface around the corner decide first (`seam_axis`). Otherwise, along each axis the projections start overlapping at the fraction
  `t = -o0 / (o1 - o0)` of the motion (0 if they already overlapped, and later than any
  fraction if they still do not: that axis still separates them). The boxes meet when
  the later of the two does, so that is the contact axis. Ties (level along both axes,
  or equal times) take `tie` (the smaller-overlap rule). Gradient-safe: the division is
  guarded.
  """
  return _impact_axis(o0[..., 0], o0[..., 1], o1[..., 0], o1[..., 1], tie, skin)


def _impact_axis(ox0, oy0, ox1, oy1, tie, skin):
  """`impact_axis` with the two axes as separate arrays."""
  def start_time(o0, o1):  # The fraction of the motion at which the projections meet.
    t = jnp.where(o0 > 0, 0.0, _safe_ratio(-o0, o1 - o0))
    return jnp.where((o0 <= 0) & (o1 <= 0), 2.0, t)  # Still apart along this axis.

  tx, ty = start_time(ox0, ox1), start_time(oy0, oy1)
  by_time = jnp.where(ty == tx, tie, ty > tx)
  level_x, level_y = jnp.abs(ox0) <= skin, jnp.abs(oy0) <= skin
  return jnp.where(level_x == level_y, by_time, level_y)


def _safe_ratio(num: jax.Array, den: jax.Array) -> jax.Array:
  ok = den > 0
  return jnp.where(ok, num / jnp.where(ok, den, 1.0), 2.0)


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class Links:
  """Every body's links, per direction: `[l, 4, n]` tables the chain hops walk.

  Entry `(k, d, i)` is the k-th partner j that lies in direction d from i (i pushes
  it along d). The slot axis `k` comes first: a hop gathers one `[4, n]` slab per slot
  and reduces the slabs elementwise, the layout XLA:CPU runs fastest
  (`jaxchain.gather`). A compact table (`idx` set) keeps at most `l` partners per row,
  the first by candidate slot; without `idx` the table is the candidate table itself
  masked per direction (`l = m`, nothing can be dropped).

  Attributes:
    idx: `[l, 4, n]` int32 partner indices, or None: the candidate slots (`cand`).
    mask: `[l, 4, n]` bool, which entries are links.
    overlap: `[l, 4, n]` signed overlap along the direction's axis (`Contacts.overlap`).
    cand: the candidate table the links were taken from.
  """

  idx: jax.Array | None
  mask: jax.Array
  overlap: jax.Array
  cand: Candidates

  def gather(self, x: jax.Array) -> jax.Array:
    """`[..., 4, n]` per direction and body -> `[..., l, 4, n]`: `x[..., d, partner]`."""
    if self.idx is None:  # Dense: slot k is body k.
      return jnp.broadcast_to(jnp.swapaxes(x, -1, -2)[..., None], x.shape[:-2] + self.mask.shape)
    return take(x.reshape(-1), self._flat_index(x.shape)).reshape(x.shape[:-2] + self.mask.shape)

  def reduce(self, kind: str, x: jax.Array, term) -> jax.Array:
    """`kind` ("sum", "max" or "any") over the slots of `term(k, x_k)`, `[..., 4, n]`.

    `x_k` is `x` (`[..., 4, n]`) gathered at slot k (`x[..., d, partner(k, d, i)]`);
    `term` combines it with the slot's other values (`mask[k]`, say). "max" starts
    from 0 and "any" from False. A compact table runs one gather per slot and folds
    the slots with elementwise operations, so XLA fuses each slot's gather, term and
    fold into one loop and never materialises the `[l, 4, n]` terms; a dense table
    (`l = m`) gathers by broadcasting and reduces along the slot axis (`k` is then
    `slice(None)`), and so does a table of more than `UNROLL_SLOTS` slots (a whole
    grid row, `links=None`), whose unrolled slots would make the compile slow.
    """
    if self.idx is None or self.mask.shape[0] > UNROLL_SLOTS:
      t = term(slice(None), self.gather(x))
      if kind == "sum":
        return jnp.sum(t, axis=-3)
      if kind == "max":
        return jnp.max(t, axis=-3, initial=0.0)
      return jnp.any(t, axis=-3)
    fold = {"sum": jnp.add, "max": jnp.maximum, "any": jnp.logical_or}[kind]
    out = None
    for k, x_k in enumerate(self._slot_values(x)):
      t = term(k, x_k)
      out = t if out is None else fold(out, t)
    if kind == "max":
      out = jnp.maximum(out, 0.0)
    return out

  def _slot_values(self, x: jax.Array) -> list[jax.Array]:
    """Per slot k, `x` (`[..., 4, n]`) gathered at the slot's partners, `[..., 4, n]`."""
    flat, table = self._flat_index(x.shape), x.reshape(-1)
    return [take(table, flat[..., k, :, :]) for k in range(self.mask.shape[0])]

  def _flat_index(self, shape: tuple[int, ...]) -> jax.Array:
    """`[..., l, 4, n]` indices into `x.reshape(-1)` for `x` of `shape` (`[..., 4, n]`)."""
    n = shape[-1]
    flat = self.idx + n * jnp.arange(NUM_DIRECTIONS, dtype=self.idx.dtype)[None, :, None]
    lead = shape[:-2]
    rows = int(np.prod(lead, dtype=int))
    offsets = (NUM_DIRECTIONS * n * jnp.arange(rows, dtype=flat.dtype)).reshape(lead + (1, 1, 1))
    return flat.reshape((1,) * len(lead) + flat.shape) + offsets

  def gather_bodies(self, x: jax.Array) -> jax.Array:
    """`[n]` per body -> partner values `[l, 4, n]`."""
    if self.idx is None:
      return jnp.broadcast_to(x[:, None, None], self.mask.shape)
    return take(x, self.idx)

  def reversed(self) -> Links:
    """The table of partners behind: row `(d, i)` lists the bodies that push i along d."""
    idx = None if self.idx is None else opposite(self.idx, 1)
    return Links(idx, opposite(self.mask, 1), opposite(self.overlap, 1), self.cand)


def links(pos: jax.Array, half: jax.Array, cand: Candidates, *, skin: float,
          limit: int | None, rows: jax.Array, start: jax.Array | None = None,
          one_way: OneWay | None = None,
          surface: jax.Array | None = None) -> tuple[Links, jax.Array]:
  """The contacts-and-links stage of a pass: `contacts`, then `link_table`.

  Args:
    pos, half: `[n, 2]`.
    cand: the pass's candidate table.
    skin: link tolerance (static).
    limit: links kept per body and direction (static, `Config.links`).
    rows: `[n]` bool, the bodies whose rows are kept: the movable ones (an immovable
      body's row is never needed: its flag decides every split it is in, and it never
      moves).
    start: optional `[n, 2]` centres at the start of the step (contact axes).
    one_way: optional one-way bodies (`OneWay`, see `contacts`).
    surface: optional `[n]` bool, bodies whose faces make surfaces (seams, see
      `contacts`).

  Returns:
    `(links, overflow)`: the `[l, 4, n]` table and whether a row lost links.
  """
  return link_table(contacts(pos, half, cand, skin, start, one_way, surface), cand, limit,
                    rows=rows)


def by_direction(c: Contacts, rows: jax.Array | None = None) -> jax.Array:
  """`[4, n, m]` bool: candidate k of body i is a link in direction d (in a kept row)."""
  dirs = jnp.arange(NUM_DIRECTIONS, dtype=c.direction.dtype)[:, None, None]
  sel = c.link[None] & (c.direction[None] == dirs)
  return sel if rows is None else sel & rows[None, :, None]


def link_table(c: Contacts, cand: Candidates, limit: int | None,
               rows: jax.Array | None = None) -> tuple[Links, jax.Array]:
  """Selects the links of `c` by direction, keeping at most `limit` per body and direction.

  Compacting makes every chain hop cost `4 n limit` instead of `4 n m`. The first
  `limit` links by candidate slot are kept; more set the returned overflow flag
  (`status.LINK_OVERFLOW`), never silently. Which links are dropped on overflow
  depends on the candidate order (body order for dense pairs), and a dropped link
  may still be kept in the partner's row: the answer is then not the exact one.

  Args:
    c: contacts over the candidate table.
    cand: the candidate table.
    limit: links kept per body and direction (static); None, or not below `m`, keeps
      the candidate table as it is.
    rows: optional `[n]` bool, the bodies whose rows are kept (the others get none).

  Returns:
    `(links, overflow)`, overflow a bool scalar.
  """
  sel = by_direction(c, rows)
  n, m = sel.shape[-2:]
  if limit is None or limit >= m:
    if cand.idx is not None:  # A candidate table of partner indices, kept whole.
      idx = jnp.broadcast_to(cand.idx.T[:, None, :], (m, NUM_DIRECTIONS, n))
      overlap = jnp.broadcast_to(c.overlap.T[:, None, :], idx.shape)
      return Links(idx, jnp.moveaxis(sel, -1, 0), overlap, cand), jnp.zeros((), bool)
    overlap = jnp.broadcast_to(c.overlap.T[:, None, :], (m, NUM_DIRECTIONS, n))
    return Links(None, jnp.moveaxis(sel, -1, 0), overlap, cand), jnp.zeros((), bool)
  slot, mask, overflow = first_set(sel, limit)  # [limit, 4, n]
  entry = slot + m * jnp.arange(n, dtype=slot.dtype)[None, None]  # Into the flat [n, m] tables.
  partner = slot if cand.idx is None else take(cand.idx.reshape(-1), entry)
  overlap = take(c.overlap.reshape(-1), entry)
  return Links(partner, mask, overlap, cand), overflow


def first_set(sel: jax.Array, limit: int) -> tuple[jax.Array, jax.Array, jax.Array]:
  """Positions of the first `limit` set entries along the last axis of `sel` (`[..., m]`).

  Packs each row into words of 24 bits with one float32 matrix product (sums of
  distinct powers of two below 2^24 are exact; XLA:CPU runs it several times faster
  than the same sum as a reduction), then peels the lowest set bit `limit` times in a
  `lax.scan`, each peel a few elementwise operations per word (no `argmax`, a variadic
  reduction XLA:CPU runs slowly), so the cost is `O(m + limit * m / 24)` per row rather
  than a sort. The scan keeps each peel's words in memory: unrolled, XLA fuses every
  slot's chain of peels into the slot's output and recomputes slot k's k peels there
  (quadratic in `limit`: measured 1.3x at 8 slots, 3.3x at 16; the same at 4). Used by
  the link table and by the neighbour table (`broadphase.build`).

  Returns:
    `(slot, valid, overflow)`: `[limit, ...]` int32 positions (0 where not valid),
    `[limit, ...]` bool (slot-major, as `Links` keeps them), and whether any row had
    more than `limit` set entries.
  """
  m = sel.shape[-1]
  num_words = -(-m // _WORD_BITS)
  k = np.arange(m)
  powers = np.zeros((m, num_words), np.float32)
  powers[k, k // _WORD_BITS] = 2.0 ** (k % _WORD_BITS)
  packed = jnp.dot(sel.astype(jnp.float32), powers, precision=lax.Precision.HIGHEST)
  words = jnp.moveaxis(packed.astype(jnp.uint32), -1, 0)  # [num_words, ...]
  none = jnp.int32(num_words * _WORD_BITS)  # Above every position: "no bit left".
  base = (_WORD_BITS * jnp.arange(num_words, dtype=jnp.int32)).reshape(
      (num_words,) + (1,) * (words.ndim - 1))

  def peel(x, _):
    low = x & (~x + jnp.uint32(1))
    at = jnp.where(x != 0, base + 31 - lax.clz(low).astype(jnp.int32), none)
    first = jnp.min(at, axis=0)
    x = jnp.where(at == first[None], x ^ low, x)
    valid = first < none
    return x, (jnp.where(valid, first, 0), valid)

  words, (slot, valid) = lax.scan(peel, words, None, length=limit)
  return slot, valid, jnp.any(words != 0)