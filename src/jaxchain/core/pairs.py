"""Candidate pairs, batch minor: the tables every later stage reads.

A `Candidates` table is `[W, n, B]`: entry `(k, i, b)` is the k-th candidate partner
of body i in world b. Two sources list every pair that could touch (the coarse
tables): dense all pairs (`W = n`, slot k is body k, gathers are broadcasts) and the
uniform grid (`jaxchain.broadphase.grid`, built per world and handed on transposed
once). With `Config.neighbors` a (sub)step filters the coarse table once into a narrow
`Neighbors` table (`build`): each movable body's partners within the margin, which
every pass of the substep and the sensors read, each use checking the margin
(`NEIGHBOR_MARGIN`); a full row sets `NEIGHBOR_OVERFLOW`. Nothing is dropped silently.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable

import jax
import jax.numpy as jnp
from jax import lax

from jaxchain import broadphase as host_broadphase
from jaxchain import status
from jaxchain.core.layout import Bodies, any_world, batch_any, fold, lane_index, shift, take


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class Candidates:
  """Candidate partners, `[W, n, B]`.

  Attributes:
    idx: int32 partner indices, or None for dense pairs (`W = n`, slot k is body k).
    mask: bool, which slots are real candidate pairs. A pair is listed in the rows of
      both its bodies (movable ones), so every pairwise quantity is computed from both
      sides and the step stays permutation-equivariant.
    flat: the index `take` reads for the partners in an `[n, B]` table
      (`layout.lane_index`; None for dense).
  """

  idx: jax.Array | None
  mask: jax.Array
  flat: jax.Array | None

  @classmethod
  def of(cls, idx: jax.Array | None, mask: jax.Array) -> Candidates:
    flat = None if idx is None else lane_index(idx)
    return cls(idx, mask, flat)

  def gather(self, x: jax.Array) -> jax.Array:
    """Partner values: `[..., n, B]` -> `[..., W, n, B]`."""
    n, B = x.shape[-2:]
    if self.idx is None:
      return jnp.broadcast_to(x[..., :, None, :], x.shape[:-1] + (n, B))
    lead = x.shape[:-2]
    if not lead:
      return take(x, self.flat)
    rows = math.prod(lead)
    offsets = (n * jnp.arange(rows, dtype=jnp.int32)).reshape(lead + (1, 1, 1))
    return take(x, shift(self.flat, offsets))

  def index(self) -> jax.Array:
    """`[W, n, B]` int32 partner indices (materialised for dense)."""
    if self.idx is None:
      n, B = self.mask.shape[-2:]
      return jnp.broadcast_to(jnp.arange(n, dtype=jnp.int32)[:, None, None], (n, n, B))
    return self.idx


def dense(active: jax.Array) -> Candidates:
  """All pairs of active bodies (`[n, n, B]`, the diagonal masked out). O(n^2)."""
  n = active.shape[0]
  eye = jnp.eye(n, dtype=bool)[:, :, None]
  return Candidates.of(None, active[:, None, :] & active[None, :, :] & ~eye)


def grid(pos: jax.Array, half: jax.Array, active: jax.Array, movable: jax.Array,
         spec: host_broadphase.GridSpec, skin: float) -> tuple[Candidates, jax.Array]:
  """The grid's candidate rows at `pos` (`[2, n, B]`; `half` too, `active` and
  `movable` `[n, B]`): built per world by `jaxchain.broadphase.grid` (a sort and a
  scatter per world, which the batch-minor layout cannot speed up) and handed on
  transposed once, `[m, n, B]`, with the grid's status bits `[B]`."""
  major = lambda x: jnp.moveaxis(x, -1, 0)  # [..., n, B] -> [B, ..., n]
  xy = lambda x: jnp.moveaxis(x, (0, 2), (2, 0))  # [2, n, B] -> [B, n, 2]
  idx, mask, code = jax.vmap(lambda p, h, a, m: host_broadphase.grid(p, h, a, m, spec, skin))(
      xy(pos), xy(half), major(active), major(movable))
  to_minor = lambda x: jnp.transpose(x, (2, 1, 0))  # [B, n, m] -> [m, n, B]
  return Candidates.of(to_minor(idx), to_minor(mask)), code


def coarse(pos: jax.Array, bodies: Bodies, config, skin: float | None = None
           ) -> tuple[Candidates, jax.Array]:
  """The coarse table the config asks for at `pos`: grid rows or dense pairs, with the
  grid's status bits (`[B]`, 0 for dense)."""
  skin = config.skin if skin is None else skin
  n, B = bodies.shape
  if config.uses_grid(n) and n > 0:
    return grid(pos, bodies.half, bodies.active, bodies.movable, config.grid, skin)
  return dense(bodies.active), jnp.zeros((B,), jnp.int32)


WORD = 32  # Bits per packed word (uint32).


def pack(bit: Callable[[int], jax.Array], count: int,
         shift: Callable[[int], jax.Array] | None = None) -> jax.Array:
  """`[ceil(count / 32), ...]` uint32 words whose bit k is `bit(k)` (bool, `[...]`).

  An unrolled walk over k, each an elementwise select ORed into its word: XLA fuses the
  walk into one loop over the `[...]` slabs (measured 4x faster in this layout than a
  reduction over a slot axis, and than the bit-packing matrix product). With `shift`,
  item k goes to bit `shift(k)` (a traced int32 below 32) of a single word instead.
  """
  if shift is not None:
    word = None
    for k in range(count):
      one = jnp.left_shift(jnp.uint32(1), shift(k).astype(jnp.uint32))
      term = jnp.where(bit(k), one, jnp.uint32(0))
      word = term if word is None else word | term
    return word[None]
  words = [None] * (-(-count // WORD))
  for k in range(count):
    term = jnp.where(bit(k), jnp.uint32(1 << (k % WORD)), jnp.uint32(0))
    w = k // WORD
    words[w] = term if words[w] is None else words[w] | term
  return jnp.stack(words)


def peel(words: jax.Array, limit: int) -> tuple[jax.Array, jax.Array, jax.Array]:
  """Positions of the first `limit` set bits of `words` (`[num_words, ...]` uint32,
  `pack`), lowest first: the lowest set bit peeled `limit` times in a `lax.scan` (each
  peel a few elementwise operations per word; no sort, no `argmax`). The scan keeps
  each peel's words in memory: unrolled, XLA fuses every slot's chain of peels into the
  slot's output and recomputes them there.

  Returns:
    `(slot, valid, rest)`: `[limit, ...]` int32 positions (0 where not valid),
    `[limit, ...]` bool, and `[...]` bool: more than `limit` bits were set.
  """
  num_words = words.shape[0]
  none = jnp.int32(num_words * WORD)
  base = (WORD * jnp.arange(num_words, dtype=jnp.int32)).reshape(
      (num_words,) + (1,) * (words.ndim - 1))

  def step(x, _):
    low = x & (~x + jnp.uint32(1))
    at = jnp.where(x != 0, base + (WORD - 1) - lax.clz(low).astype(jnp.int32), none)
    first = jnp.min(at, axis=0)
    x = jnp.where(at == first[None], x ^ low, x)
    valid = first < none
    return x, (jnp.where(valid, first, 0), valid)

  words, (slot, valid) = lax.scan(step, words, None, length=limit)
  return slot, valid, fold("any", words != 0)


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class Neighbors:
  """A candidate table built once per (sub)step and read by every pass (`build`).

  Attributes:
    cand: `[w, n, B]` candidates, `w = Config.neighbors`, in the coarse source's order.
    ref: `[2, n, B]` the positions it was built at.
    code: `[B]` int32 status bits of the build (`NEIGHBOR_OVERFLOW`, the grid's bits,
      and `NEIGHBOR_MARGIN` for a sweep past the margin on the grid).
  """

  cand: Candidates
  ref: jax.Array
  code: jax.Array


def neighbors(centre: jax.Array, half: jax.Array, rows: jax.Array, coarse: Candidates, *,
              width: int, reach: float) -> tuple[Candidates, jax.Array]:
  """Compacts `coarse` to the partners within `reach` of each body of `rows` (an
  AABB gap test along both axes on boxes `centre`, `half`, `[2, n, B]`), the first
  `width` by slot; returns the table and `NEIGHBOR_OVERFLOW` per world."""
  n, B = rows.shape
  if coarse.idx is None:  # Dense: a walk over the partners j, [n, B] slabs.
    m = n

    def near(j):
      ok = rows & coarse.mask[j]
      for k in (0, 1):
        gap = jnp.abs(centre[k][j][None] - centre[k]) - (half[k] + half[k][j][None])
        ok = ok & (gap <= reach)
      return ok
  else:
    table = coarse.mask & rows[None]
    for k in (0, 1):
      gap = jnp.abs(coarse.gather(centre[k]) - centre[k][None]) - (
          half[k][None] + coarse.gather(half[k]))
      table = table & (gap <= reach)
    m = table.shape[0]
    near = lambda j: table[j]
  if width >= m:  # Nothing to compact: the coarse table, filtered.
    table = jnp.stack([near(j) for j in range(m)]) if coarse.idx is None else table
    return Candidates.of(coarse.index(), table), jnp.zeros((B,), jnp.int32)
  slot, valid, rest = peel(pack(near, m), width)
  if coarse.idx is None:
    idx = slot
  else:
    body = jnp.arange(n, dtype=jnp.int32)[None, :, None]
    idx = take(coarse.idx, lane_index(slot * n + body))
  overflow = any_world(rest)
  return Candidates.of(idx, valid), jnp.where(overflow, status.NEIGHBOR_OVERFLOW, 0).astype(jnp.int32)


def build(pos: jax.Array, bodies: Bodies, config, start: jax.Array | None = None
          ) -> Neighbors | None:
  """The neighbour table of a (sub)step at `pos`, or None without `config.neighbors`.

  With `start` (the substep's start positions; `pos` is where the bodies are predicted
  to be) each body is taken as the box it sweeps from `start` to `pos`: the table then
  also holds every pair that meets during that motion (the swept sensor test reads
  it), and the margin need not cover the motion itself. With the grid as the source a
  body that sweeps more than the margin sets `NEIGHBOR_MARGIN`.
  """
  if config.neighbors is None:
    return None
  n, B = bodies.shape
  reach = host_broadphase.neighbor_reach(config.skin, config.margin)
  use_grid = config.uses_grid(n) and n > 0
  grid_skin = reach + config.margin  # One margin more: the swept extension.
  spec = config.grid
  if use_grid and spec.cell < 2 * spec.reach + grid_skin:
    raise ValueError(
        f"Config.grid: a neighbour table with margin {config.margin} needs cells of at least "
        f"2 * reach + skin + 2 * margin (+ {host_broadphase.MARGIN_SLACK:g} margin of slack) = "
        f"{2 * spec.reach + grid_skin:.6g}, got {spec.cell:.6g}; allocate the grid with "
        f"jaxchain.broadphase.allocate(world, skin=jaxchain.broadphase.grid_skin(skin, "
        f"margin)) or use Config.for_world")
  centre, half = pos, bodies.half
  code = jnp.zeros((B,), jnp.int32)
  if start is not None:
    sweep = jnp.where(bodies.active[None], jnp.abs(pos - start), 0.0)
    centre, half = 0.5 * (start + pos), half + 0.5 * sweep
    if use_grid:
      code = jnp.where(any_world(sweep > config.margin), status.NEIGHBOR_MARGIN, 0)
  source, found = coarse(centre, bodies, config, skin=grid_skin)
  compact = lambda src: neighbors(centre, half, bodies.movable, src, width=config.neighbors,
                                  reach=reach)
  if not use_grid:
    cand, overflow = compact(source)
  else:
    # A full cell (rare: the grid is sized with headroom) is built again with `RETRY`
    # times the cell capacity, in a `lax.cond` that only a batch with a full cell takes:
    # the table is then exact, and the same as a rollout's table kept from before the
    # cell filled (issue 44 item 6: `jc.step` set CELL_OVERFLOW and lost pairs where
    # `jc.rollout` kept an exact table and set nothing). Beyond that, CELL_OVERFLOW.
    wide = dataclasses.replace(spec, cell_capacity=RETRY * spec.cell_capacity)

    def retry():
      src, bits = grid(centre, bodies.half, bodies.active, bodies.movable, wide, grid_skin)
      return compact(src) + (bits,)

    full = (found & status.CELL_OVERFLOW) != 0
    cand, overflow, found = lax.cond(batch_any(full), retry,
                                     lambda: compact(source) + (found,))
  return Neighbors(cand=cand, ref=pos, code=(overflow | found | code).astype(jnp.int32))


RETRY = 2  # The cell capacity of a neighbour table's second build when a cell is full.


def empty(bodies: Bodies, config) -> Neighbors | None:
  """A neighbour table no step can use (`ref` at infinity): the first `refresh` of a
  rollout rebuilds it. None without `config.neighbors`."""
  if config.neighbors is None:
    return None
  n, B = bodies.shape
  pos = jnp.zeros((2, n, B), bodies.half.dtype)
  shapes = jax.eval_shape(lambda p: build(p, bodies, config, p), pos)  # The width it has.
  table = jax.tree.map(lambda x: jnp.zeros(x.shape, x.dtype), shapes)
  return Neighbors(cand=Candidates.of(table.cand.idx, table.cand.mask),
                   ref=jnp.full((2, n, B), jnp.inf, bodies.half.dtype), code=table.code)


def refresh(table: Neighbors | None, pos: jax.Array, bodies: Bodies, config,
            start: jax.Array) -> Neighbors | None:
  """The neighbour table of a substep that starts at `start` and is predicted to reach
  `pos` (`[2, n, B]`): `table` itself where every active body of every world is, at
  both, within `margin / 2` of where it was built along each axis (a Verlet list, as
  jax-md's `neighbor_list`), else a new one (`build`); without `table`, a new one.

  Reuse changes no answer: `table` holds every pair within `skin + margin` at its
  build, so every pair within the skin of each other anywhere on the substep's
  straight motions (what the passes, their margin checks and the swept sensor test
  read), and its rows list partners in the coarse source's order as a new build
  would. A batch rebuilds for every world once one world needs it (`lax.cond`).
  """
  if config.neighbors is None:
    return None
  if table is None:
    return build(pos, bodies, config, start)
  ref = lax.stop_gradient(table.ref)
  far = lambda x: jnp.abs(lax.stop_gradient(x) - ref) > 0.5 * config.margin
  stale = any_world(bodies.active[None] & (far(start) | far(pos)))
  return lax.cond(batch_any(stale), lambda: build(pos, bodies, config, start), lambda: table)


def moved(table: Neighbors, pos: jax.Array, active: jax.Array, margin: float) -> jax.Array:
  """`[B]` `NEIGHBOR_MARGIN` where an active body is more than `margin / 2` from where
  `table` was built along an axis (pairs could be missing), else 0."""
  far = active[None] & (jnp.abs(pos - table.ref) > 0.5 * margin)
  return jnp.where(any_world(far), status.NEIGHBOR_MARGIN, 0).astype(jnp.int32)


def candidates(pos: jax.Array, bodies: Bodies, config, table: Neighbors | None = None
               ) -> tuple[Candidates, jax.Array]:
  """The table a pass reads at `pos`: the substep's neighbour table (checked against
  its margin), or without `config.neighbors` the coarse table built at `pos`.
  Returns `(candidates, status [B])`."""
  if config.neighbors is not None:
    if table is None:
      table = build(pos, bodies, config)
    return table.cand, table.code | moved(table, pos, bodies.active, config.margin)
  return coarse(pos, bodies, config)
