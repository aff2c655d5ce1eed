"""The grid broadphase's static layout and its per-world table; host-side sizing.

`GridSpec` is the uniform grid's static layout (`Config.grid` holds one) and `allocate`
sizes one from a world on the host. `grid` builds one world's candidate rows (a sort
and a scatter per world); the core (`jaxchain.core.pairs`) builds it per world and
hands it on batch minor. `neighbor_reach` and `grid_skin` are the neighbour table's
gap thresholds, which `Config.for_world` and the core share.

Every candidate table is exact: a full cell, a full static table or a body larger than
the grid was built for sets a status bit, never a silent miss (jax-md's
`partition.cell_list`, with its `did_buffer_overflow`, is the model).
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np

from jaxchain import status


@dataclasses.dataclass(frozen=True)
class GridSpec:
  """Static layout of the uniform grid broadphase (see `jaxchain.broadphase`).

  Attributes:
    origin: `(x0, y0)` lower-left corner of cell `(0, 0)`.
    cell: cell side; at least `2 * reach + skin`, so movable bodies that touch sit
      in neighbouring cells.
    shape: `(nx, ny)` cells. Bodies outside are clamped into the border cells:
      still correct, only more crowded.
    reach: the largest half-extent of a movable body the grid is built for; a larger
      one sets `status.BODY_TOO_LARGE`.
    cell_capacity: movable bodies per cell; more sets `status.CELL_OVERFLOW`.
    static_capacity: immovable bodies per cell (each is entered in every cell it
      can touch a movable body from).
    static_entries: total (immovable body, cell) entries per world; more, or more
      than `static_capacity` in a cell, sets `status.STATIC_OVERFLOW`.
  """

  origin: tuple[float, float]
  cell: float
  shape: tuple[int, int]
  reach: float
  cell_capacity: int = 4
  static_capacity: int = 8
  static_entries: int = 64

  def __post_init__(self):
    object.__setattr__(self, "origin", tuple(float(x) for x in self.origin))
    object.__setattr__(self, "shape", tuple(int(x) for x in self.shape))
    for name in ("cell", "reach"):
      object.__setattr__(self, name, float(getattr(self, name)))
    if len(self.origin) != 2 or len(self.shape) != 2 or min(self.shape) < 1:
      raise ValueError(f"GridSpec: origin and shape need two entries, shape >= 1; got {self}")
    if not self.cell > 0 or not self.reach >= 0:
      raise ValueError(f"GridSpec: cell must be > 0 and reach >= 0; got {self}")
    if self.cell < 2 * self.reach:
      raise ValueError(f"GridSpec: cell {self.cell} is smaller than 2 * reach {self.reach}")
    for name in ("cell_capacity", "static_capacity", "static_entries"):
      v = getattr(self, name)
      if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 1:
        raise ValueError(f"GridSpec.{name}: expected an integer >= 1, got {v!r}")
      object.__setattr__(self, name, int(v))

  @property
  def num_cells(self) -> int:
    return self.shape[0] * self.shape[1]

  @property
  def row_size(self) -> int:
    """Candidate slots per body: the 3x3 movable neighbourhood plus own-cell statics."""
    return 9 * self.cell_capacity + self.static_capacity


def grid(pos: jax.Array, half: jax.Array, active: jax.Array, movable: jax.Array,
         spec: GridSpec, skin: float) -> tuple[jax.Array, jax.Array, jax.Array]:
  """Uniform-grid candidates: O(n) pairs with fixed capacity, overflow reported.

  Movable bodies are entered in the cell of their centre; each gets as candidates
  the movable bodies of its 3x3 cell neighbourhood. Immovable bodies (walls,
  floors, kinematic platforms) of any size are entered in every cell from which a
  movable body could touch them (their box grown by `reach + skin`), in a table of
  their own, and each movable body also gets the immovable bodies of its own cell.
  A 100-unit floor beside unit boxes therefore costs about 100 table entries, not a
  100-unit cell. Immovable bodies get empty rows: the resolver never needs them
  (an immovable body's flag decides every contact it is in, and it never moves).

  Nothing is dropped silently: a full cell, a full static table or a movable body
  larger than `spec.reach` sets a bit of the returned status.

  Args:
    pos, half: `[n, 2]`.
    active, movable: `[n]` bool.
    spec: static grid layout.
    skin: link tolerance (contacts up to this gap must be found).

  Returns:
    `(idx, mask, status)`: `[n, spec.row_size]` int32 partners (any valid index where
    the mask is False) and bool mask, and int32 status bits.
  """
  n = pos.shape[0]
  nx, ny = spec.shape
  n_cells = spec.num_cells
  origin = jnp.asarray(spec.origin, pos.dtype)[None]
  insert = active & movable

  def cell_of(p):  # Clamped integer cell coordinates.
    c = jnp.floor((p - origin) / spec.cell)
    c = jnp.clip(c, 0, jnp.asarray([nx - 1, ny - 1], pos.dtype)[None])
    return c.astype(jnp.int32)

  own = cell_of(pos)
  own_id = own[:, 0] + nx * own[:, 1]
  movable_table, cell_full = _fill(jnp.where(insert, own_id, n_cells), jnp.arange(n, dtype=jnp.int32),
                                   n_cells, spec.cell_capacity, n)

  off = jnp.asarray(_NEIGHBOURS)  # [9, 2]
  near = own[:, None, :] + off[None]  # [n, 9, 2]
  inside = jnp.all((near >= 0) & (near < jnp.asarray([nx, ny])[None, None]), axis=-1)
  near_id = jnp.where(inside, near[..., 0] + nx * near[..., 1], n_cells)
  movable_idx = movable_table[near_id].reshape(n, 9 * spec.cell_capacity)

  # Immovable bodies: one entry per covered cell, laid out by a prefix sum.
  grow = spec.reach + skin
  lo, hi = cell_of(pos - half - grow), cell_of(pos + half + grow)
  width = hi - lo + 1  # [n, 2]
  count = jnp.where(active & ~movable, width[:, 0] * width[:, 1], 0)
  end = jnp.cumsum(count)
  start = end - count
  e = jnp.arange(spec.static_entries, dtype=end.dtype)
  body = jnp.minimum(jnp.searchsorted(end, e, side="right"), n - 1).astype(jnp.int32)
  local = e - start[body]
  ex = lo[body, 0] + local % width[body, 0]
  ey = lo[body, 1] + local // width[body, 0]
  entry_id = jnp.where(e < end[-1], ex + nx * ey, n_cells)
  static_table, static_full = _fill(entry_id, body, n_cells, spec.static_capacity, n)
  static_idx = static_table[own_id]  # [n, static_capacity]

  idx = jnp.concatenate([movable_idx, static_idx], axis=1)
  real = idx < n
  mask = real & (idx != jnp.arange(n, dtype=jnp.int32)[:, None]) & insert[:, None]
  too_large = jnp.any(insert & (jnp.max(half, axis=-1) > spec.reach))
  code = (jnp.where(cell_full, status.CELL_OVERFLOW, 0)
          | jnp.where(static_full | (end[-1] > spec.static_entries), status.STATIC_OVERFLOW, 0)
          | jnp.where(too_large, status.BODY_TOO_LARGE, 0)).astype(jnp.int32)
  return jnp.where(real, idx, 0), mask, code


# The 3x3 neighbourhood of a cell, as (dx, dy) offsets.
_NEIGHBOURS = np.array([(dx, dy) for dy in (-1, 0, 1) for dx in (-1, 0, 1)], np.int32)


def _fill(cell_id: jax.Array, value: jax.Array, n_cells: int, capacity: int,
          sentinel: int) -> tuple[jax.Array, jax.Array]:
  """Scatters `value[k]` into row `cell_id[k]` of a `[n_cells + 1, capacity]` table.

  Entries are sorted by cell (stably, so the layout is deterministic) and each
  takes the next free slot of its row. `cell_id == n_cells` means "not entered";
  the last row stays all `sentinel` and serves out-of-grid lookups.

  Returns:
    `(table, overflow)`, overflow true when some cell had more than `capacity`.
  """
  order = jnp.argsort(cell_id, stable=True)
  sorted_id = cell_id[order]
  rank = jnp.arange(cell_id.shape[0], dtype=jnp.int32) - jnp.searchsorted(
      sorted_id, sorted_id, side="left").astype(jnp.int32)
  entered = sorted_id < n_cells
  keep = entered & (rank < capacity)
  table = jnp.full((n_cells + 1, capacity), sentinel, jnp.int32)
  table = table.at[jnp.where(keep, sorted_id, n_cells + 1), jnp.minimum(rank, capacity - 1)].set(
      value[order], mode="drop")
  return table, jnp.any(entered & (rank >= capacity))


# The build admits pairs up to `skin + margin * (1 + MARGIN_SLACK)` apart, and the check
# allows `margin / 2` of motion: the slack absorbs the rounding of the two gap tests.
MARGIN_SLACK = 2.0**-5


def neighbor_reach(skin: float, margin: float) -> float:
  """The gap up to which a pair enters the neighbour table: `skin + margin (1 + slack)`."""
  return skin + margin * (1 + MARGIN_SLACK)


def grid_skin(skin: float, margin: float) -> float:
  """The `skin` to `allocate` a grid with when it is the source of a neighbour table."""
  return neighbor_reach(skin, margin) + margin


def allocate(world, skin: float = 1e-4, *, headroom: float = 2.0, max_cells: int | None = None
             ) -> GridSpec:
  """Measures a world (or a padded batch) on the host and sizes a grid for it.

  The cell is `2 * reach + skin` with `reach` the largest movable half-extent,
  enlarged when needed so the grid has at most `max_cells` cells (default `8 n`,
  at least 64) over the bodies' bounding box plus a two-cell margin. Capacities are
  the measured maxima times `headroom` (bodies move; the grid does not).

  Typical use, with the re-allocation a long run needs when status bits appear:

      cfg = jc.Config.for_world(world)            # calls allocate for large worlds
      world = jc.step(world, cfg)
      if jc.check(world):                          # e.g. a cell overflowed
        cfg = jc.Config.for_world(world)           # re-measure the current state
        world = world.replace(status=jnp.zeros_like(world.status))

  Args:
    world: a `World`, single or batched.
    skin: the config's skin.
    headroom: factor on every measured capacity.
    max_cells: cap on `nx * ny`.

  Returns:
    A `GridSpec`.
  """
  pos = np.asarray(world.pos, np.float64).reshape(-1, world.num_bodies, 2)
  half = np.asarray(world.half, np.float64).reshape(pos.shape)
  active = np.asarray(world.active).reshape(pos.shape[:2])
  movable = active & (np.asarray(world.inv_mass).reshape(pos.shape[:2]) > 0)
  n = pos.shape[1]
  reach = float(np.max(np.where(movable[..., None], half, 0.0), initial=0.0)) or 0.5
  cell = 2 * reach + skin
  if active.any():
    lo = np.min(np.where(active[..., None], pos - half, np.inf), axis=(0, 1))
    hi = np.max(np.where(active[..., None], pos + half, -np.inf), axis=(0, 1))
  else:
    lo, hi = np.zeros(2), np.ones(2)
  max_cells = max(64, 8 * n) if max_cells is None else max_cells

  def shape_for(c):
    return np.maximum(np.ceil((hi - lo) / c).astype(int) + 4, 1)

  shape = shape_for(cell)
  if shape.prod() > max_cells:
    cell *= float(np.sqrt(shape.prod() / max_cells)) * 1.01
    shape = shape_for(cell)
    while shape.prod() > max_cells:
      cell *= 1.05
      shape = shape_for(cell)
  origin = lo - 2 * cell
  # Measured occupancy per world: movable per cell, immovable entries per cell and in all.
  cells = np.clip(np.floor((pos - origin) / cell), 0, shape - 1).astype(int)
  cell_max, static_max, entries_max = 1, 1, 1
  grow = reach + skin
  for b in range(pos.shape[0]):  # Host-side loop over worlds, eager sizing only.
    ids = cells[b, movable[b], 0] + shape[0] * cells[b, movable[b], 1]
    cell_max = max(cell_max, int(np.bincount(ids, minlength=1).max(initial=0)))
    fixed = active[b] & ~movable[b]
    c_lo = np.clip(np.floor((pos[b, fixed] - half[b, fixed] - grow - origin) / cell), 0, shape - 1)
    c_hi = np.clip(np.floor((pos[b, fixed] + half[b, fixed] + grow - origin) / cell), 0, shape - 1)
    per_cell = np.zeros(shape[::-1], int)
    for (x0, y0), (x1, y1) in zip(c_lo.astype(int), c_hi.astype(int)):
      per_cell[y0 : y1 + 1, x0 : x1 + 1] += 1
    static_max = max(static_max, int(per_cell.max(initial=0)))
    entries_max = max(entries_max, int(per_cell.sum()))
  return GridSpec(origin=tuple(origin), cell=cell, shape=tuple(int(s) for s in shape), reach=reach,
                  cell_capacity=max(2, int(np.ceil(cell_max * headroom))),
                  static_capacity=max(2, int(np.ceil(static_max * headroom))),
                  static_entries=max(16, int(np.ceil(entries_max * headroom))))
