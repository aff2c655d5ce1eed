"""The shared level type: `Level` (host arrays, one entry per body), `Tile` (what one
map cell makes) and its standard tiles, the collision categories, and `rectangles`
(cells merged into few bodies). Every format's reader builds its bodies as `_Body`
records and hands them to `_level`.
"""

from __future__ import annotations

import dataclasses
import math
import types
from collections.abc import Mapping

import numpy as np

from jaxchain.world import World

# Collision categories (bits of `category` and `mask`; World: two bodies interact when
# each one's category shares a bit with the other's mask).
SOLID = 1  # walls, platforms, anything else by default (World's default category)
PLAYER = 2
BOX = 4
SENSOR = 8  # goals, flags, hazards
ALL = 0xFFFFFFFF  # a mask admitting every category (World's default mask)
# Names accepted for category and mask bits in Tiled properties ("player|box").
CATEGORIES = types.MappingProxyType(
    {"solid": SOLID, "player": PLAYER, "box": BOX, "sensor": SENSOR, "all": ALL})

SLAB = 0.25  # thickness of a one-way platform, in cells: a slab at the top of its cell
_MERGES = ("none", "row", "rect")
_U32 = 1 << 32
# The most bodies a loader makes of one level (of one collection, in all), unless its
# `max_bodies` keyword says otherwise: checked before the bodies are built.
MAX_BODIES = 100_000
# The most cells a map may have (width x height, 2048 x 2048; Tiled: tiles of a layer, 4
# bytes each, and compressed tile data is inflated only up to the layer's size).
MAX_TILES = 1 << 22


@dataclasses.dataclass(frozen=True)
class Tile:
  """What one map character makes: a body per cell, or bodies merged over runs of cells.

  Sizes and offsets are in cells. A body sits at its cell's centre plus `offset`;
  merged runs span the union of their cells' rectangles.

  Attributes:
    tags: the tags its bodies get in `Level.tags` (a string is one tag).
    mass: `inf` (default) for immovable; a finite mass makes a movable body.
    half: half-extents `> 0` of the body in one cell.
    offset: offset of the body's centre from the cell's centre.
    vel: initial velocity, world units per second; an immovable body with a
      velocity is a kinematic platform.
    friction: Coulomb coefficient `>= 0`.
    one_way: a jump-through platform (blocks only bodies coming down from above).
    sensor: a trigger: never pushes, never pushed; `World.sensed` reports overlaps.
    category: uint32 category bits.
    mask: uint32 mask bits: the categories it interacts with (or, for a sensor,
      the categories it senses).
    merge: `"rect"` merges runs of cells into maximal rectangles (walls), `"row"`
      merges horizontal runs only (platforms), `"none"` makes one body per cell.
      Only immovable tiles merge.

  Examples:
    >>> from jaxchain import levels
    >>> ice = levels.Tile(tags="ice", friction=0.0, merge="rect")
    >>> ice.tags, ice.mass
    (('ice',), inf)
  """

  tags: tuple[str, ...] = ()
  mass: float = math.inf
  half: tuple[float, float] = (0.5, 0.5)
  offset: tuple[float, float] = (0.0, 0.0)
  vel: tuple[float, float] = (0.0, 0.0)
  friction: float = 0.0
  one_way: bool = False
  sensor: bool = False
  category: int = SOLID
  mask: int = ALL
  merge: str = "none"

  def __post_init__(self):
    tags = (self.tags,) if isinstance(self.tags, str) else tuple(self.tags)
    if not all(isinstance(t, str) and t for t in tags):
      raise ValueError(f"Tile: tags must be non-empty strings, got {self.tags!r}")
    set_ = lambda name, value: object.__setattr__(self, name, value)
    set_("tags", tags)
    set_("mass", float(self.mass))
    set_("friction", float(self.friction))
    for name in ("half", "offset", "vel"):
      value = tuple(float(v) for v in getattr(self, name))
      if len(value) != 2 or not all(math.isfinite(v) for v in value):
        raise ValueError(f"Tile: {name} must be two finite numbers, got {getattr(self, name)!r}")
      set_(name, value)
    if not min(self.half) > 0:
      raise ValueError(f"Tile: half-extents must be > 0, got {self.half}")
    if not self.mass > 0:
      raise ValueError(f"Tile: mass must be > 0 (inf for immovable), got {self.mass}")
    if not (math.isfinite(self.friction) and self.friction >= 0):
      raise ValueError(f"Tile: friction must be finite and >= 0, got {self.friction}")
    for name in ("category", "mask"):
      value = getattr(self, name)
      if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or not 0 <= value < _U32:
        raise ValueError(f"Tile: {name} must be an int in [0, 2**32), got {value!r}")
      set_(name, int(value))
    set_("one_way", bool(self.one_way))
    set_("sensor", bool(self.sensor))
    if self.merge not in _MERGES:
      raise ValueError(f"Tile: merge must be one of {_MERGES}, got {self.merge!r}")
    if self.merge != "none" and math.isfinite(self.mass):
      raise ValueError(f"Tile: only immovable tiles (mass inf) merge; got mass {self.mass} "
                       f"with merge={self.merge!r} (adjacent boxes are separate boxes)")


WALL = Tile(tags="wall", merge="rect")
PLAYER_TILE = Tile(tags="player", mass=1.0, half=(0.4, 0.4), category=PLAYER)
BOX_TILE = Tile(tags="box", mass=1.0, half=(0.45, 0.45), category=BOX)
HEAVY_TILE = Tile(tags=("box", "heavy"), mass=10.0, half=(0.45, 0.45), category=BOX)
# A small goal: a default box (half 0.45) overlaps it exactly when the box's centre lies
# in the goal's cell (0.45 + 0.05 = 0.5).
GOAL_TILE = Tile(tags="goal", half=(0.05, 0.05), sensor=True, category=SENSOR, mask=BOX)
PLATFORM_TILE = Tile(tags="platform", half=(0.5, SLAB / 2), offset=(0.0, 0.5 - SLAB / 2),
                     one_way=True, merge="row")
FLAG_TILE = Tile(tags="flag", sensor=True, category=SENSOR, mask=PLAYER)
HAZARD_TILE = Tile(tags="hazard", sensor=True, category=SENSOR, mask=PLAYER, merge="row")


@dataclasses.dataclass(frozen=True, eq=False, repr=False)
class Level:
  """A level as host arrays, one entry per body (read-only NumPy arrays).

  Attributes:
    name: the level's name (file stem, or the `name` given to `parse_ascii`).
    pos: `[n, 2]` float64 centres.
    half: `[n, 2]` float64 half-extents.
    mass: `[n]` float64 masses, `inf` for immovable bodies.
    vel: `[n, 2]` float64 initial velocities.
    friction: `[n]` float64 Coulomb coefficients.
    one_way: `[n]` bool, jump-through platforms.
    sensor: `[n]` bool, triggers.
    category: `[n]` uint32 category bits.
    mask: `[n]` uint32 mask bits.
    tags: tag name -> sorted tuple of body indices.
    bounds: `(xmin, ymin, xmax, ymax)` of the map (not of the bodies).
    gravity: `(gx, gy)`, the gravity `world()` uses unless overridden.
  """

  name: str
  pos: np.ndarray
  half: np.ndarray
  mass: np.ndarray
  vel: np.ndarray
  friction: np.ndarray
  one_way: np.ndarray
  sensor: np.ndarray
  category: np.ndarray
  mask: np.ndarray
  tags: Mapping[str, tuple[int, ...]]
  bounds: tuple[float, float, float, float]
  gravity: tuple[float, float] = (0.0, -9.81)

  def __post_init__(self):
    n = len(self.pos)
    fields = dict(pos=(np.float64, (n, 2)), half=(np.float64, (n, 2)), mass=(np.float64, (n,)),
                  vel=(np.float64, (n, 2)), friction=(np.float64, (n,)), one_way=(bool, (n,)),
                  sensor=(bool, (n,)), category=(np.uint32, (n,)), mask=(np.uint32, (n,)))
    for name, (dtype, shape) in fields.items():
      x = np.array(getattr(self, name), dtype=dtype).reshape(shape)
      x.setflags(write=False)
      object.__setattr__(self, name, x)
    tags = {}
    for tag, idx in self.tags.items():
      idx = tuple(sorted(int(i) for i in idx))
      if any(not 0 <= i < n for i in idx):
        raise ValueError(f"Level: tag {tag!r} names bodies {idx} outside [0, {n})")
      tags[tag] = idx
    object.__setattr__(self, "tags", types.MappingProxyType(tags))
    object.__setattr__(self, "bounds", tuple(float(b) for b in self.bounds))
    object.__setattr__(self, "gravity", tuple(float(g) for g in self.gravity))

  @property
  def num_bodies(self) -> int:
    """The number of bodies `n`."""
    return len(self.pos)

  def __len__(self) -> int:
    return self.num_bodies

  def __repr__(self) -> str:
    tags = ", ".join(f"{t}: {len(i)}" for t, i in self.tags.items())
    return f"Level({self.name!r}, {self.num_bodies} bodies, tags {{{tags}}})"

  @property
  def player(self) -> int:
    """The index of the one body tagged "player".

    Raises:
      ValueError: if no body or several bodies carry the tag.
    """
    idx = self.tags.get("player", ())
    if len(idx) != 1:
      raise ValueError(f"level {self.name!r}: expected one body tagged 'player', found "
                       f"{len(idx)} {list(idx)}")
    return idx[0]

  def indices(self, *tags: str) -> np.ndarray:
    """The sorted indices (int array) of the bodies carrying any of `tags`.

    Examples:
      >>> from jaxchain import levels
      >>> levels.parse_ascii("#@$*#").indices("box", "goal").tolist()
      [2, 3, 4]
    """
    idx = sorted({i for t in tags for i in self.tags.get(t, ())})
    return np.asarray(idx, dtype=np.int64)

  def world(self, **overrides) -> World:
    """The level as a `World` (`World.create` validates it).

    Args:
      **overrides: values replacing any keyword this passes to `World.create`:
        `pos`, `half`, `mass`, `vel`, `friction`, `gravity`, `one_way`, `sensor`,
        `category`, `mask` (and `active`, not passed by default).

    Returns:
      A `World` with one slot per body, in the level's body order.

    Examples:
      >>> from jaxchain import levels
      >>> w = levels.parse_ascii("#@ $#").world(gravity=(0.0, 0.0))
      >>> w.num_bodies, w.inv_mass.tolist()
      (4, [0.0, 1.0, 1.0, 0.0])
    """
    args = dict(pos=self.pos, half=self.half, mass=self.mass, vel=self.vel,
                friction=self.friction, gravity=self.gravity, one_way=self.one_way,
                sensor=self.sensor, category=self.category, mask=self.mask)
    args.update(overrides)
    return World.create(args.pop("pos"), args.pop("half"), args.pop("mass"), **args)


@dataclasses.dataclass
class _Body:
  """One body while a level is built (sorted by `key` at the end)."""

  key: tuple
  pos: tuple[float, float]
  half: tuple[float, float]
  mass: float
  vel: tuple[float, float]
  friction: float
  one_way: bool
  sensor: bool
  category: int
  mask: int
  tags: tuple[str, ...]


def _max_bodies(value) -> int:
  """A `max_bodies` keyword, checked."""
  if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 0:
    raise ValueError(f"max_bodies must be an int >= 0, got {value!r}")
  return int(value)


def _too_many(where, max_bodies: int, sep: str = ": ") -> ValueError:
  """The error of a level (or collection) past its body limit; `where` names it."""
  return ValueError(f"{where}{sep}more than max_bodies = {max_bodies} bodies "
                    f"(levels.MAX_BODIES; raise it with max_bodies=)")


def _level(name, bodies: list[_Body], bounds, gravity) -> Level:
  bodies = sorted(bodies, key=lambda b: b.key)
  n = len(bodies)
  tags = {}
  for i, b in enumerate(bodies):
    for t in b.tags:
      tags.setdefault(t, []).append(i)
  col = lambda f, dtype: np.array([getattr(b, f) for b in bodies], dtype)
  return Level(
      name=name, pos=np.array([b.pos for b in bodies], np.float64).reshape(n, 2),
      half=np.array([b.half for b in bodies], np.float64).reshape(n, 2),
      mass=col("mass", np.float64), vel=np.array([b.vel for b in bodies], np.float64).reshape(n, 2),
      friction=col("friction", np.float64), one_way=col("one_way", bool),
      sensor=col("sensor", bool), category=col("category", np.uint32),
      mask=col("mask", np.uint32), tags=tags, bounds=bounds, gravity=gravity)


def rectangles(cells, vertical: bool = True) -> list[tuple[int, int, int, int]]:
  """Covers the `True` cells of a grid with few rectangles, greedily.

  Each row's maximal horizontal runs come first; with `vertical`, runs spanning the
  same columns in consecutive rows stack into one rectangle. Every `True` cell lies
  in exactly one rectangle, and every rectangle holds only `True` cells.

  Args:
    cells: `[rows, cols]` bool grid, row 0 first (at the top of a map).
    vertical: stack identical runs of consecutive rows (`False`: runs only).

  Returns:
    Rectangles `(r0, c0, r1, c1)` (inclusive bounds), sorted by `(r0, c0)`.

  Examples:
    >>> from jaxchain import levels
    >>> levels.rectangles([[1, 1, 1], [1, 0, 1], [1, 1, 1]])
    [(0, 0, 0, 2), (1, 0, 1, 0), (1, 2, 1, 2), (2, 0, 2, 2)]
    >>> levels.rectangles([[1, 1], [1, 1]]), levels.rectangles([[1, 1], [1, 1]], vertical=False)
    ([(0, 0, 1, 1)], [(0, 0, 0, 1), (1, 0, 1, 1)])
  """
  cells = np.asarray(cells, bool)
  if cells.ndim != 2:
    raise ValueError(f"rectangles: expected a 2-D grid, got shape {cells.shape}")
  rects = _label_rectangles(np.where(cells, 0, -1), np.asarray([bool(vertical)]))
  return [tuple(r) for r in rects[:, :4].tolist()]


def _label_rectangles(labels: np.ndarray, vertical: np.ndarray, limit: int | None = None
                      ) -> np.ndarray | None:
  """`rectangles` of every label at once, vectorised (no Python loop over rows or runs).

  Args:
    labels: `[rows, cols]` int grid, the cell's label `>= 0`, or -1 for none.
    vertical: `[labels]` bool, whether a label's runs stack over consecutive rows.
    limit: optional; more rectangles than this return None, found before they are
      built (a body limit refuses a hostile map at the cost of a few passes over it).

  Returns:
    `[k, 5]` int64 rows `(r0, c0, r1, c1, label)`, sorted by `(r0, c0)`: for each
    label what `rectangles` gives for its cells (or None, past `limit`).
  """
  labels = np.asarray(labels)
  vertical = np.asarray(vertical, bool)
  rows, cols = labels.shape
  filled = labels >= 0
  starts, ends = filled.copy(), filled.copy()  # A run starts (ends) where its label does.
  starts[:, 1:] &= labels[:, 1:] != labels[:, :-1]
  ends[:, :-1] &= labels[:, :-1] != labels[:, 1:]
  r, c0 = np.nonzero(starts)  # Row-major, like the ends: the k-th start and end pair up.
  c1 = np.nonzero(ends)[1]
  if not len(r):
    return np.zeros((0, 5), np.int64)
  r, c0, c1 = r.astype(np.int64), c0.astype(np.int64), c1.astype(np.int64)
  lab = labels[r, c0].astype(np.int64)
  if limit is not None and len(r) > limit:
    # Count first, without sorting: a run continues the rectangle above it when the
    # row above holds the same run (the same label over its columns, by a running
    # count of the cells that differ from the one above, starting and ending there).
    differs = np.ones((rows, cols), np.int64)
    differs[1:] = labels[1:] != labels[:-1]
    seen = np.cumsum(differs, axis=1)
    inside = seen[r, c1] - np.where(c0 > 0, seen[r, np.maximum(c0 - 1, 0)], 0)
    above = np.maximum(r - 1, 0)
    cont = (r > 0) & (inside == 0) & starts[above, c0] & ends[above, c1] & vertical[lab]
    if len(r) - np.count_nonzero(cont) > limit:
      return None
  # Stack: sorted by columns (stable, so rows stay in order: a row holds one run of
  # them), a rectangle runs from a run that does not continue the one before it (the
  # same columns and label, one row up, where the label stacks) to the last that does.
  order = np.argsort(c0 * np.int64(cols) + c1, kind="stable")
  r, c0, c1, lab = r[order], c0[order], c1[order], lab[order]
  cont = np.zeros(len(r), bool)
  cont[1:] = ((lab[1:] == lab[:-1]) & (c0[1:] == c0[:-1]) & (c1[1:] == c1[:-1])
              & (r[1:] == r[:-1] + 1) & vertical[lab[1:]])
  first = np.flatnonzero(~cont)
  last = np.append(first[1:] - 1, len(r) - 1)
  rects = np.stack([r[first], c0[first], r[last], c1[first], lab[first]], axis=-1)
  return rects[np.argsort(rects[:, 0] * np.int64(cols) + rects[:, 1], kind="stable")]
