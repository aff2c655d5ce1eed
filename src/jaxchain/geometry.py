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

DIRECTIONS = ("+x", "-x", "+y", "-y")
NUM_DIRECTIONS = 4
OPPOSITE = np.array([1, 0, 3, 2])  # d -> d ^ 1, as a static index.
ALONG_Y = np.array([False, False, True, True])[:, None, None]  # Per direction: its axis is y.
_WORD_BITS = 24  # Bits packed per float32 word in `_first_set` (exact below 2^24).


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
             start: jax.Array | None = None) -> Contacts:
  """Contacts of every candidate pair.

  The contact axis of a pair that overlapped at `start` (or of every pair, without
  `start`) is the axis of smaller overlap (ties go to x). A pair that was separated at
  `start` (not overlapping along both axes; touching counts as separated) takes the
  axis along which the motion from `start` to `pos` closed the gap last: its time of
  impact. That is the axis the two boxes met along, so a box falling onto the edge of
  another lands on it instead of being pushed sideways (`impact_axis`).

  Along the contact axis the partner j lies in direction `sign(p_j - p_i)`, measured
  at `start` for a pair separated there (so a fast pair is resolved back to the side
  it came from) and at `pos` otherwise; coincident centres go by index: the body with
  the larger index lies in the positive direction. That tie rule is the only place
  body order matters.

  Args:
    pos: `[n, 2]` centres.
    half: `[n, 2]` half-extents.
    cand: candidate table with `[n, m]` entries.
    skin: gap below which separated bodies still count as linked.
    start: optional `[n, 2]` centres at the start of the step.
  """
  n = pos.shape[0]
  pos_j, half_j = cand.gather_bodies(pos), cand.gather_bodies(half)
  delta = pos_j - pos[:, None, :]
  o = overlap(pos[:, None, :], half[:, None, :], pos_j, half_j)
  use_y = o[..., 1] < o[..., 0]
  if start is not None:
    start_j = cand.gather_bodies(start)
    delta0 = start_j - start[:, None, :]
    o0 = overlap(start[:, None, :], half[:, None, :], start_j, half_j)
    separated = jnp.min(o0, axis=-1) <= 0
    use_y = jnp.where(separated, impact_axis(o0, o, use_y, skin), use_y)
    delta = jnp.where(separated[..., None], delta0, delta)
  o_axis, o_other = along_axis(o, use_y)
  d_axis, _ = along_axis(delta, use_y)
  self_idx = jnp.arange(n, dtype=jnp.int32)[:, None]
  positive = (d_axis > 0) | ((d_axis == 0) & (cand.partner_index() > self_idx))
  link = cand.mask & (o_other > 0) & (o_axis >= -skin)
  direction = 2 * use_y.astype(jnp.int32) + (~positive).astype(jnp.int32)
  depth = jnp.where(link, jnp.maximum(o_axis, 0.0), 0.0)
  return Contacts(link=link, direction=direction, depth=depth, overlap=o_axis)


def impact_axis(o0: jax.Array, o1: jax.Array, tie: jax.Array, skin: float) -> jax.Array:
  """Whether a pair separated at the start met along y: per-axis overlaps `o0` at the
  start and `o1` now (`[..., 2]`), moving linearly in between.

  A pair whose faces were level along one axis at the start (`|o0| <= skin` there:
  resting on, or sliding along, each other's face) keeps that axis: a box sliding over
  the seam between two floor tiles of one height rides onto the next tile instead of
  hitting its side (a "ghost collision"), and one touching a box's side pushes it.
  Otherwise, along each axis the projections start overlapping at the fraction
  `t = -o0 / (o1 - o0)` of the motion (0 if they already overlapped, and later than any
  fraction if they still do not: that axis still separates them). The boxes meet when
  the later of the two does, so that is the contact axis. Ties (level along both axes,
  or equal times) take `tie` (the smaller-overlap rule). Gradient-safe: the division is
  guarded.
  """
  closing = o1 - o0
  t = jnp.where(o0 > 0, 0.0, _safe_ratio(-o0, closing))
  t = jnp.where((o0 <= 0) & (o1 <= 0), 2.0, t)  # Still apart along this axis.
  by_time = jnp.where(t[..., 1] == t[..., 0], tie, t[..., 1] > t[..., 0])
  level = jnp.abs(o0) <= skin
  return jnp.where(level[..., 0] == level[..., 1], by_time, level[..., 1])


def _safe_ratio(num: jax.Array, den: jax.Array) -> jax.Array:
  ok = den > 0
  return jnp.where(ok, num / jnp.where(ok, den, 1.0), 2.0)


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class Links:
  """Every body's links, per direction: `[4, n, l]` tables the chain hops walk.

  Row `(d, i)` lists the partners j that lie in direction d from i (i pushes them
  along d). A compact table (`idx` set) keeps at most `l` of them, the first by
  candidate slot; without `idx` the table is the candidate table itself masked per
  direction (`l = m`, nothing can be dropped).

  Attributes:
    idx: `[4, n, l]` int32 partner indices, or None: the candidate slots (`cand`).
    mask: `[4, n, l]` bool, which entries are links.
    overlap: `[4, n, l]` signed overlap along the direction's axis (`Contacts.overlap`).
    cand: the candidate table the links were taken from.
  """

  idx: jax.Array | None
  mask: jax.Array
  overlap: jax.Array
  cand: Candidates

  def gather(self, x: jax.Array) -> jax.Array:
    """`[..., 4, n]` per direction and body -> `[..., 4, n, l]`: `x[..., d, partner]`."""
    if self.idx is None:
      return self.cand.gather(x)
    n = x.shape[-1]
    flat = self.idx + n * jnp.arange(NUM_DIRECTIONS, dtype=self.idx.dtype)[:, None, None]
    return x.reshape(x.shape[:-2] + (-1,))[..., flat]

  def gather_bodies(self, x: jax.Array) -> jax.Array:
    """`[n, f]` per body -> partner values `[4, n, l, f]` (`[1, n, m, f]` uncompacted)."""
    if self.idx is None:
      return self.cand.gather_bodies(x)[None]
    return x[self.idx]

  def reversed(self) -> Links:
    """The table of partners behind: row `(d, i)` lists the bodies that push i along d."""
    idx = None if self.idx is None else self.idx[OPPOSITE]
    return Links(idx, self.mask[OPPOSITE], self.overlap[OPPOSITE], self.cand)


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
  m = sel.shape[-1]
  if limit is None or limit >= m:
    overlap = jnp.broadcast_to(c.overlap[None], sel.shape)
    return Links(None, sel, overlap, cand), jnp.zeros((), bool)
  slot, mask, overflow = _first_set(sel, limit)
  partner = slot if cand.idx is None else jnp.take_along_axis(cand.idx[None], slot, axis=-1)
  overlap = jnp.take_along_axis(c.overlap[None], slot, axis=-1)
  return Links(partner, mask, overlap, cand), overflow


def _first_set(sel: jax.Array, limit: int) -> tuple[jax.Array, jax.Array, jax.Array]:
  """Positions of the first `limit` set entries along the last axis of `sel`.

  Packs each row into words of 24 bits and peels the lowest set bit `limit` times,
  so the cost is `O(m + limit * m / 24)` per row rather than a sort. The packing is
  a float32 matrix product (sums of distinct powers of two below 2^24 are exact):
  unlike a reduction, XLA does not fuse the producer of `sel` into it, which would
  recompute the contacts for every bit.

  Returns:
    `(slot, valid, overflow)`: `[..., limit]` int32 positions (0 where not valid),
    `[..., limit]` bool, and whether any row had more than `limit` set entries.
  """
  m = sel.shape[-1]
  words_per_row = -(-m // _WORD_BITS)
  k = np.arange(m)
  powers = np.zeros((m, words_per_row), np.float32)
  powers[k, k // _WORD_BITS] = 2.0 ** (k % _WORD_BITS)
  words = jnp.dot(sel.astype(jnp.float32), powers, precision=lax.Precision.HIGHEST)
  words = words.astype(jnp.uint32)
  word_ids = jnp.arange(words_per_row, dtype=jnp.int32).reshape((1,) * (sel.ndim - 1) + (-1,))

  def peel(words, _):
    first = jnp.argmax(words != 0, axis=-1).astype(jnp.int32)  # First word with a bit left.
    at = word_ids == first[..., None]
    word = jnp.sum(jnp.where(at, words, jnp.uint32(0)), axis=-1, dtype=jnp.uint32)
    lowest = word & (~word + jnp.uint32(1))
    valid = word != 0
    slot = jnp.where(valid, _WORD_BITS * first + 31 - lax.clz(lowest).astype(jnp.int32), 0)
    return jnp.where(at, words ^ lowest[..., None], words), (slot, valid)

  words, (slot, valid) = lax.scan(peel, words, None, length=limit)
  return jnp.moveaxis(slot, 0, -1), jnp.moveaxis(valid, 0, -1), jnp.any(words != 0)
