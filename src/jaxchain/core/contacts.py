"""Contacts and links, batch minor: per candidate pair the contact axis, direction and
depth, then the link table the chain hops walk.

Directions are numbered `0: +x, 1: -x, 2: +y, 3: -y`; `d ^ 1` is the opposite. The
rules are those of DESIGN.md section 3b: the contact axis from the motion (time of
impact) for pairs separated at the start of the step, seams of immovable surfaces act
as one surface, one-way bodies block only what comes down onto them, collision layers
and sensors keep pairs apart (`admit`).
"""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp
from jax import lax

from jaxchain.core.layout import (NUM_DIRECTIONS, Bodies, any_world, batch_any, fold, lane_index,
                                  materialise, opposite, shift, take)
from jaxchain.core.pairs import Candidates, pack, peel

# A body came down onto a one-way body when, at the start of the step, its bottom was
# at or above the one-way body's top, up to this fraction of the pair's summed
# half-heights (resting contacts sit a rounding error inside), and it was not rising
# relative to it.
ONE_WAY_MARGIN = 0.05
# "Rising" relative to a one-way body: moving up relative to it faster than this (units
# per second), so float rounding of a resting body's velocity never lets it through.
ONE_WAY_RISE = 1e-6


def admits(category_i, mask_i, sensor_i, category_j, mask_j, sensor_j, *, layers: bool = True,
           sensors: bool = True):
  """Whether bodies i and j may interact (elementwise, any shapes that broadcast):
  `category[i] & mask[j]` and `category[j] & mask[i]` both nonzero (Box2D's filter rule,
  with `layers`), and neither a sensor (with `sensors`: a sensor only senses). None
  when both switches are off (everything interacts)."""
  ok = None
  if layers:
    zero = jnp.zeros((), category_i.dtype)
    ok = ((category_i & mask_j) != zero) & ((category_j & mask_i) != zero)
  if sensors:
    solid = ~sensor_i & ~sensor_j
    ok = solid if ok is None else ok & solid
  return ok


def admit(cand: Candidates, bodies: Bodies, *, layers: bool, sensors: bool) -> Candidates:
  """`cand` without the pairs that collision layers keep apart or that hold a sensor
  (`admits`); with both switches off, `cand` itself."""
  if not (layers or sensors):
    return cand
  g = cand.gather
  ok = admits(bodies.category[None], bodies.mask[None], bodies.sensor[None],
              g(bodies.category), g(bodies.mask), g(bodies.sensor), layers=layers,
              sensors=sensors)
  return dataclasses.replace(cand, mask=cand.mask & ok)


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class OneWay:
  """The bodies the one-way rule reads, `[n, B]` bool each.

  Attributes:
    one_way: jump-through bodies (active ones).
    solid: immovable bodies that are not one-way: they block a one-way body on every
      side (a movable one-way crate rests on the floor).
    vel: optional `[2, n, B]` velocities at the start of the pass: a body rising
      relative to a one-way body is not coming down onto it. None (`resolve`):
      positions alone decide.
  """

  one_way: jax.Array
  solid: jax.Array
  vel: jax.Array | None = None


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class Contacts:
  """The contacts of a candidate table, `[W, n, B]` each.

  Attributes:
    code: int32 direction 0..3 from body i towards partner j where the pair is a link
      (touching within the skin, or overlapping, along its contact axis and overlapping
      strictly along the other), 4 where it is not.
    overlap: signed overlap along the contact axis (negative: a gap within the skin).
  """

  code: jax.Array
  overlap: jax.Array


def contacts(pos: jax.Array, half: jax.Array, cand: Candidates, skin: float,
             start: jax.Array | None = None, one_way: OneWay | None = None,
             surface: jax.Array | None = None, walk: jax.Array | None = None) -> Contacts:
  """Contacts of every candidate pair.

  The contact axis of a pair that overlapped at `start` (or of every pair, without
  `start`) is the axis of smaller overlap (ties go to x). A pair separated at `start`
  (not overlapping beyond `skin` along both axes) takes the axis along which the
  motion from `start` to `pos` closed the gap last, its time of impact
  (`impact_axis`), so a box falling onto an edge lands on it instead of being pushed
  sideways. Along the contact axis j lies in direction `sign(p_j - p_i)`, measured at
  `start` for a pair separated there and at `pos` otherwise; coincident centres go by
  index (the larger index lies in the positive direction): the only place body order
  matters. With `one_way` a pair with a one-way member is a contact only when the
  one-way rule admits it, and then along y (`one_way_rule`). With `surface` (and
  `start`), corner contacts next to immovable surfaces take the axis the surface
  decides (`seam_axis`): no ghost collisions on seams. With `walk`, the tops of those
  bodies (immovable one-way ones) are surfaces too for a body standing on them.

  Args:
    pos, half: `[2, n, B]`.
    cand: the pass's candidate table, `[W, n, B]`.
    skin: gap below which separated bodies still count as linked.
    start: optional `[2, n, B]` positions at the start of the step.
    one_way: optional `OneWay`.
    surface: optional `[n, B]` bool, bodies whose faces make surfaces (with `start`).
    walk: optional `[n, B]` bool, bodies whose tops make surfaces for a body whose
      bottom is on them (with `surface`).
  """
  n = pos.shape[-2]
  g = cand.gather
  dx, dy = g(pos[0]) - pos[0][None], g(pos[1]) - pos[1][None]
  hx, hy = half[0][None] + g(half[0]), half[1][None] + g(half[1])
  ox, oy = hx - jnp.abs(dx), hy - jnp.abs(dy)
  use_y = oy < ox
  if start is not None:
    dx0, dy0 = g(start[0]) - start[0][None], g(start[1]) - start[1][None]
    ox0, oy0 = hx - jnp.abs(dx0), hy - jnp.abs(dy0)
    # Apart at the start: not overlapping by more than the skin along some axis (a
    # float32 rounding overlap at a resting contact counts as touching).
    separated = (ox0 <= skin) | (oy0 <= skin)
    level = jnp.abs(ox0) <= skin, jnp.abs(oy0) <= skin
    use_y = jnp.where(separated, impact_axis(ox0, oy0, ox, oy, use_y, skin, level), use_y)
    if surface is not None:
      near = (ox >= -skin) & (oy >= -skin)  # Could be a link at `pos`.
      use_y = seam_axis(cand, half, surface, dx0, dy0, ox0, oy0, skin, use_y, walk, near,
                        level)
    dx, dy = jnp.where(separated, dx0, dx), jnp.where(separated, dy0, dy)
  admitted = vertical = upward = None
  if one_way is not None:
    admitted, vertical, upward = one_way_rule(pos if start is None else start, half, cand,
                                              one_way, hy)
    use_y = use_y | vertical
  o_axis, o_other = jnp.where(use_y, oy, ox), jnp.where(use_y, ox, oy)
  d_axis = jnp.where(use_y, dy, dx)
  body = jnp.arange(n, dtype=jnp.int32)[None, :, None]
  positive = (d_axis > 0) | ((d_axis == 0) & (cand.index() > body))
  link = cand.mask & (o_other > 0) & (o_axis >= -skin)
  if one_way is not None:
    positive = jnp.where(vertical, upward, positive)
    link = link & admitted
  code = jnp.where(link, 2 * use_y.astype(jnp.int32) + (~positive).astype(jnp.int32),
                   NUM_DIRECTIONS)
  # Materialised once: every direction of the link table reads them (fused into its
  # consumers they would be recomputed in each).
  return Contacts(code=materialise(code), overlap=materialise(o_axis))


def impact_axis(ox0, oy0, ox1, oy1, tie, skin: float, level=None):
  """Whether a pair separated at the start met along y: overlaps per axis at the start
  (`ox0`, `oy0`) and now (`ox1`, `oy1`), moving linearly in between.

  A pair whose faces were level along one axis at the start (`|o0| <= skin`) while
  overlapping by more than the skin along the other (resting on, or sliding along,
  each other's face) keeps that axis: a box sliding over the seam between two floor
  tiles rides onto the next tile instead of hitting its side, and one touching a box's
  side pushes it. Level along one axis and apart along the other (a body landing with
  its edge on a seam, or hitting a wall with its bottom on one) goes by the time of
  impact; level along both axes (a corner) says nothing by itself (`seam_axis` decides
  next to surfaces). Otherwise, along each
  axis the projections start overlapping at `t = -o0 / (o1 - o0)` of the motion (0 if
  they already overlapped, later than any fraction if they still do not); the boxes
  meet when the later of the two does. Ties take `tie` (the smaller-overlap rule).
  Gradient-safe: the division is guarded. `level`: optional `(|ox0| <= skin,
  |oy0| <= skin)`, computed once by the caller.
  """
  def start_time(o0, o1):
    ok = (o1 - o0) > 0
    t = jnp.where(o0 > 0, 0.0, jnp.where(ok, -o0 / jnp.where(ok, o1 - o0, 1.0), 2.0))
    return jnp.where((o0 <= 0) & (o1 <= 0), 2.0, t)  # Still apart along this axis.

  tx, ty = start_time(ox0, ox1), start_time(oy0, oy1)
  by_time = jnp.where(ty == tx, tie, ty > tx)
  # Level along x and overlapping along y (sliding along each other's side), or the
  # other way round; a pair level along one axis and apart along the other meets at a
  # corner approach, which the time of impact decides.
  level_x, level_y = (jnp.abs(ox0) <= skin, jnp.abs(oy0) <= skin) if level is None else level
  keep_x, keep_y = level_x & (oy0 > skin), level_y & (ox0 > skin)
  return jnp.where(keep_x | keep_y, keep_y, by_time)


def one_way_rule(ref: jax.Array, half: jax.Array, cand: Candidates, ow: OneWay,
                 hy: jax.Array) -> tuple[jax.Array, jax.Array, jax.Array]:
  """Which pairs with a one-way member are contacts, `[W, n, B]` each.

  A one-way body blocks only bodies that come down onto it from above, judged at `ref`
  (the start of the step) and from the velocities `ow.vel`. A body i comes down onto a
  one-way body j when
  * its bottom is at or above j's top; or
  * its bottom is below j's top by at most `ONE_WAY_MARGIN` of the summed half-heights
    and i is not rising relative to j (by more than `ONE_WAY_RISE`): a resting contact
    a rounding error inside (a body rising through j from below is not lifted onto it);
    or
  * it is pressed into j: its centre is above j's top and it sinks below j's top by at
    most the margin plus its press, the deepest overlap along y of a body above it that
    is not one-way (the crush rule splits a crushed body's overlap between its two
    sides, so a body crushed onto a ledge keeps being held). Velocities do not matter
    there.
  It lets the others pass, from below and from the sides; solid immovable bodies block
  it like any body. Two one-way bodies meet when one came down onto the other.

  Returns:
    `(admitted, vertical, upward)`: the pair may be a contact; its axis is y by the
    rule; and then the partner lies above.
  """
  g = cand.gather
  col = lambda x: x[None]
  margin = ONE_WAY_MARGIN * hy
  bottom_i, top_i = col(ref[1]) - col(half[1]), col(ref[1]) + col(half[1])
  bottom_j, top_j = g(ref[1]) - g(half[1]), g(ref[1]) + g(half[1])
  ow_i, ow_j = col(ow.one_way), g(ow.one_way)
  dx, dy = g(ref[0]) - col(ref[0]), g(ref[1]) - col(ref[1])
  ox = col(half[0]) + g(half[0]) - jnp.abs(dx)
  oy = hy - jnp.abs(dy)
  from_above = cand.mask & ~ow_j & (dy > 0) & (ox > 0) & (oy > 0) & (oy < ox)
  press = jnp.max(jnp.where(from_above, oy, 0.0), axis=0, initial=0.0)  # [n, B]
  press_i, press_j = col(press), g(press)
  if ow.vel is None:
    rising_i = rising_j = jnp.zeros(dy.shape, bool)
  else:
    rel = g(ow.vel[1]) - col(ow.vel[1])  # j's velocity along y relative to i's.
    rising_i, rising_j = rel < -ONE_WAY_RISE, rel > ONE_WAY_RISE
  pressed_i = (col(ref[1]) > top_j) & (bottom_i >= top_j - margin - press_i) & (press_i > 0)
  pressed_j = (g(ref[1]) > top_i) & (bottom_j >= top_i - margin - press_j) & (press_j > 0)
  i_above = (bottom_i >= top_j) | (~rising_i & (bottom_i >= top_j - margin)) | pressed_i
  j_above = (bottom_j >= top_i) | (~rising_j & (bottom_j >= top_i - margin)) | pressed_j
  solid_i, solid_j = col(ow.solid), g(ow.solid)
  admitted = jnp.where(ow_i & ow_j, i_above | j_above,
                       (~ow_j | solid_i | i_above) & (~ow_i | solid_j | j_above))
  vertical = (ow_i | ow_j) & ~(solid_i | solid_j)
  return admitted, vertical, j_above


def surface_cover(cand: Candidates, half: jax.Array, surface: jax.Array, dx0: jax.Array,
                  dy0: jax.Array, skin: float, walk: jax.Array | None = None) -> jax.Array:
  """`[4, 2, n, B]` bool: entry `(f, c, i)`, the space just outside face f of body i,
  next to the face's corner c (0: on the positive side of the other axis, 1: the
  negative one), lies inside a surface body (read from i's candidates: along the face's
  axis the candidate starts at or before the face plane, within `skin`, and ends beyond
  it; along the other axis it reaches the corner and extends past it into the face).
  A `walk` body (a one-way platform) covers only the space under i's bottom face, and
  only when its top is level with that face (within `skin`): a one-way top and a solid
  top at the same height are one surface when walked on."""
  col = lambda k: half[k][None]
  partner = lambda k: cand.gather(half[k])
  ok = cand.mask & cand.gather(surface)

  def axis_tests(d, h_i, h_k):
    # Per side s of i (+, -): k's near and far ends past i's face plane.
    ds = (d, -d)
    near = [e - h_k - h_i for e in ds]
    far = [e + h_k - h_i for e in ds]
    face = [(lo <= skin) & (hi > skin) for lo, hi in zip(near, far)]
    corner = [(hi >= -skin) & (lo < -skin) for lo, hi in zip(near, far)]
    return face, corner, near

  face_x, corner_x, _ = axis_tests(dx0, col(0), partner(0))
  face_y, corner_y, near_y = axis_tests(dy0, col(1), partner(1))
  faces = [(face_x[0], corner_y), (face_x[1], corner_y), (face_y[0], corner_x),
           (face_y[1], corner_x)]
  if walk is not None:  # Under i's bottom: a one-way top level with it.
    on_top = cand.mask & cand.gather(walk) & (near_y[1] >= -skin)
    under = face_y[1] & (ok | on_top)
    faces[3] = (under, corner_x)
    faces = [(ok & f, c) for f, c in faces[:3]] + [faces[3]]
  else:
    faces = [(ok & f, c) for f, c in faces]
  return jnp.stack([jnp.stack([fold("any", f & c) for c in corners])
                    for f, corners in faces])


def seam_axis(cand: Candidates, half: jax.Array, surface: jax.Array, dx0: jax.Array,
              dy0: jax.Array, ox0: jax.Array, oy0: jax.Array, skin: float,
              use_y: jax.Array, walk: jax.Array | None = None,
              near: jax.Array | None = None, level=None) -> jax.Array:
  """The contact axis of corner contacts next to surfaces (`[W, n, B]` bool: y or not).

  Two bodies whose faces were level along both axes at the start meet at a common corner
  C. Of the two other quadrants at C, one lies beside i's face along y and j's face
  along x, the other beside i's face along x and j's face along y. Where exactly one of
  them is inside a surface body (`surface_cover`, read from both rows, so the rule is
  symmetric), the faces beside it are inner sides of that surface: the contact is along
  the other axis. A player whose edge is on the seam between two floor tiles rests on
  the next tile, and one pressed against a wall of tiles with its bottom on a seam
  slides past the next tile down; with `walk` (one-way platforms) a player on a
  one-way ledge whose edge is on the seam to a flush solid tile runs onto the tile.

  A pair level along one axis and apart (beyond the skin) along the other, i's face
  level with j's: where the space just outside that face of i, at its end towards j,
  lies inside a surface body (a one-way one only walked on), i slides along a surface
  flush with j's face and keeps the level axis (a player sliding over the seam to the
  next floor tile rides onto it); otherwise the time of impact decides (a body landing
  with its edge on a floor seam lands, one hitting a wall of tiles with its bottom on a
  seam hits the wall). Only pairs `near` (overlapping within the skin at the pass's
  positions) are judged. Other pairs keep `use_y`. Corner and approaching contacts are
  rare: a batch without one skips the rule (`lax.cond` on `layout.batch_any`).
  """
  level_x, level_y = (jnp.abs(ox0) <= skin, jnp.abs(oy0) <= skin) if level is None else level
  corner = level_x & level_y
  approach = (level_x & (oy0 < -skin)) | (level_y & (ox0 < -skin))
  if near is not None:
    approach = approach & near

  def rule(use_y):
    cover = surface_cover(cand, half, surface, dx0, dy0, skin, walk)
    own, other = cover[:, :, None], cand.gather(cover)  # [4, 2, (1 or W), n, B]
    sx, sy = dx0 > 0, dy0 > 0  # j's side of i along each axis.

    def pick(c, pos_face, neg_face, face_sign, corner_sign):
      at = lambda f: jnp.where(corner_sign, c[f, 0], c[f, 1])
      return jnp.where(face_sign, at(pos_face), at(neg_face))

    own_y, own_x = pick(own, 2, 3, sy, sx), pick(own, 0, 1, sx, sy)
    beside_x = own_y | pick(other, 0, 1, ~sx, ~sy)
    beside_y = own_x | pick(other, 2, 3, ~sy, ~sx)
    # Approaching j's corner: i's level face at its end towards j lies on a surface.
    flush = jnp.where(level_y, own_y, own_x)
    use_y = jnp.where(approach & flush, level_y, use_y)
    return jnp.where(corner & (beside_x != beside_y), beside_x, use_y)

  return lax.cond(batch_any((corner | approach) & cand.mask), rule, lambda u: u, use_y)


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class Links:
  """Every body's links per direction: `[L, 4, n, B]` tables the chain hops walk.

  Entry `(k, d, i, b)` is the k-th partner j lying in direction d from body i in world
  b (i pushes it along d). The flat indices of the three gathers a hop can make are
  built once (`of`): into an `[n, B]` table (`bodies`), into a `[4, n, B]` table at the
  same direction (`front`), and the same through the reversed table (`back`: the bodies
  behind i along d, that push i along d). Without `idx` (dense pairs kept whole) slot
  k is body k and every gather is a broadcast.

  Attributes:
    idx: `[L, 4, n, B]` int32 partners, or None.
    mask: `[L, 4, n, B]` bool, which entries are links.
    overlap: `[L, 4, n, B]` signed overlap along the direction's axis.
    back_mask: `mask` of the reversed table (`opposite(mask, 1)`).
  """

  idx: jax.Array | None
  mask: jax.Array
  overlap: jax.Array
  back_mask: jax.Array
  body_flat: jax.Array | None
  front_flat: jax.Array | None
  back_flat: jax.Array | None

  @classmethod
  def of(cls, idx: jax.Array | None, mask: jax.Array, overlap: jax.Array) -> Links:
    if idx is None:
      return cls(None, mask, overlap, opposite(mask, 1), None, None, None)
    n = idx.shape[-2]
    d = jnp.arange(NUM_DIRECTIONS, dtype=jnp.int32)[None, :, None, None]
    return cls(idx, mask, overlap, opposite(mask, 1), lane_index(idx), lane_index(d * n + idx),
               lane_index(d * n + opposite(idx, 1)))

  @property
  def slots(self) -> int:
    return self.mask.shape[0]

  def first(self, k: int) -> Links:
    """The table of the first `k` slots (a compact table whose other slots are empty
    is this table, with cheaper hops)."""
    cut = lambda x: None if x is None else x[:k]
    return Links(cut(self.idx), self.mask[:k], self.overlap[:k], self.back_mask[:k],
                 cut(self.body_flat), cut(self.front_flat), cut(self.back_flat))

  def bodies(self, x: jax.Array) -> jax.Array:
    """`[n, B]` -> `[L, 4, n, B]`: `x[j]`."""
    if self.idx is None:
      return jnp.broadcast_to(x[:, None, None, :], self.mask.shape)
    return take(x, self.body_flat)

  def front(self, x: jax.Array) -> jax.Array:
    """`[..., 4, n, B]` -> `[..., L, 4, n, B]`: `x[..., d, j]`."""
    return self._gather(x, self.front_flat)

  def back(self, x: jax.Array) -> jax.Array:
    """`[..., 4, n, B]` -> `[..., L, 4, n, B]`: `x[..., d, j]` for the bodies j behind
    i along d (the reversed table)."""
    return self._gather(x, self.back_flat)

  def _gather(self, x: jax.Array, flat: jax.Array | None) -> jax.Array:
    lead = x.shape[:-3]
    if flat is None:  # Dense: slot k is body k (in both tables).
      moved = jnp.swapaxes(x, -3, -2)[..., :, :, None, :]  # [..., n(k), 4, 1, B]
      return jnp.broadcast_to(moved, lead + self.mask.shape)
    if not lead:
      return take(x, flat)
    rows = math.prod(lead)
    size = x.shape[-3] * x.shape[-2]
    offsets = (size * jnp.arange(rows, dtype=jnp.int32)).reshape(lead + (1, 1, 1, 1))
    return take(x, shift(flat, offsets))


def link_table(c: Contacts, cand: Candidates, limit: int | None,
               rows: jax.Array) -> tuple[Links, jax.Array]:
  """The links of `c` by direction, at most `limit` per body and direction.

  Compacting makes every chain hop cost `4 n limit` instead of `4 n W`. The first
  `limit` links by candidate slot are kept; more set the returned overflow flag
  (`LINK_OVERFLOW`, `[B]`), never silently. With `limit` None (or not below `W`) the
  candidate table is kept whole.

  The compaction packs one bit per (direction, slot) into uint32 words per direction
  (`pairs.pack`), peels the lowest set bits (`pairs.peel`: its scan keeps the words in
  memory; fused into the slots' consumers XLA would recompute the packing walk in each),
  and gathers the kept slots from the candidate table once.

  Args:
    c: contacts of the candidate table.
    cand: the candidate table.
    limit: links kept per body and direction (static).
    rows: `[n, B]` bool, the bodies whose rows are kept (the movable ones: an immovable
      body's flag decides every split it is in, and it never moves).
  """
  W, n, B = c.code.shape
  code = jnp.where(rows[None], c.code, NUM_DIRECTIONS)
  if limit is None or limit >= W:
    shape = (W, NUM_DIRECTIONS, n, B)
    dirs = jnp.arange(NUM_DIRECTIONS, dtype=code.dtype)[None, :, None, None]
    idx = None if cand.idx is None else jnp.broadcast_to(cand.idx[:, None], shape)
    overlap = jnp.broadcast_to(c.overlap[:, None], shape)
    return Links.of(idx, code[:, None] == dirs, overlap), jnp.zeros((B,), bool)
  words = jnp.stack([pack(lambda k, d=d: code[k] == d, W) for d in range(NUM_DIRECTIONS)], 1)
  slot, valid, rest = peel(words, limit)  # [limit, 4, n, B]
  body = jnp.arange(n, dtype=jnp.int32)[None, None, :, None]
  flat = lane_index(slot * n + body)
  partner = take(cand.index(), flat)
  return Links.of(partner, valid, take(c.overlap, flat)), any_world(rest)


def touching(links: Links) -> jax.Array:
  """`[4, n, B]` bool: body i has a link in direction d."""
  return fold("any", links.mask)
