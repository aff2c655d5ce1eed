"""Levels: Sokoban XSB and platformer ASCII maps, Sokoban collections, and Tiled maps
(JSON and TMX), as host arrays.

A `Level` holds one NumPy array per body field (`pos`, `half`, `mass`, `vel`,
`friction`, `one_way`, `sensor`, `category`, `mask`), tags naming bodies ("player",
"box", "goal", Tiled names and classes, ...), the map's bounds and a gravity;
`Level.world()` turns it into a `jaxchain.World`. Everything here runs on the host,
before tracing: level loading never touches `jit`.

Coordinates: one map cell (an ASCII character, or a Tiled tile) is one world unit
(Tiled: unless the map property `unit` says how many pixels make one unit), and y
points up: the bottom row of a map spans y in [0, 1], and the cell in row r (counted
from the top, from 0) and column c of a map H rows high has centre
(c + 0.5, H - 1 - r + 0.5).

Runs of wall cells (or solid Tiled tiles) become few long rectangles: maximal
horizontal runs of a row first, then runs spanning the same columns in consecutive
rows stack into one rectangle. A floor is therefore one body (a box sliding along it
meets no internal seam), and a level of hundreds of wall characters has tens of
bodies. One-way platforms and kinematic platforms merge along rows only.

Body order: by the top-left cell of each body in reading order (rows top to bottom,
columns left to right); a character making several bodies (`+`, `*`) makes them in
the order its legend entry lists them; Tiled layers come in file order (objects in
the order of the layer's object array). Use `Level.tags`, not indices, to find
bodies.
"""

from __future__ import annotations

import base64
import binascii
import dataclasses
import difflib
import gzip
import importlib.resources
import json
import math
import os
import pathlib
import types
import warnings
import xml.etree.ElementTree as ElementTree
import zlib
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
FLIP_BITS = 0xF0000000  # Tiled GID flags: flipped horizontally, vertically, diagonally; hex 120
GID_MASK = 0x0FFFFFFF  # the tile id bits of a Tiled GID
_MERGES = ("none", "row", "rect")
_U32 = 1 << 32
# The mass of a Tiled object tagged "player" or "box" (by its name, class, tile class,
# layer or `tag` property) that has no `mass` property: the mass of the ASCII `@` and
# `$`. Other objects without `mass` are immovable.
DEFAULT_MASS = 1.0
_MOVABLE_TAGS = ("player", "box")
# Half-extents (world units) of the small sensor a Tiled point object becomes (one not
# tagged "player" or "box": those are spawns, bodies of the ASCII `@` and `$` sizes).
POINT_HALF = 0.05
_F32_MAX = float(np.finfo(np.float32).max)


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


def _kinematic(vel):
  return Tile(tags="kinematic", vel=vel, merge="row")


# The default character set. A value is a Tile, a tuple of Tiles (several bodies in one
# cell), or None (floor: no body).
LEGEND = types.MappingProxyType({
    # Sokoban XSB.
    "#": WALL, " ": None, "-": None, "_": None,
    "@": PLAYER_TILE, "+": (PLAYER_TILE, GOAL_TILE),
    "$": BOX_TILE, "*": (BOX_TILE, GOAL_TILE), ".": GOAL_TILE,
    # XSB variants' letters.
    "p": PLAYER_TILE, "P": (PLAYER_TILE, GOAL_TILE), "b": BOX_TILE, "B": (BOX_TILE, GOAL_TILE),
    # Platformer.
    "=": PLATFORM_TILE, "H": HEAVY_TILE,
    ">": _kinematic((1.0, 0.0)), "<": _kinematic((-1.0, 0.0)),
    "^": _kinematic((0.0, 1.0)), "v": _kinematic((0.0, -1.0)),
    "F": FLAG_TILE, "X": HAZARD_TILE,
})


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
  done, open_ = [], {}
  for r, row in enumerate(cells):
    edges = np.diff(np.concatenate([[0], row.astype(np.int8), [0]]))
    runs = zip(np.flatnonzero(edges == 1).tolist(), (np.flatnonzero(edges == -1) - 1).tolist())
    grown = {}
    for c0, c1 in runs:
      rect = open_.pop((c0, c1)) if vertical and (c0, c1) in open_ else [r, c0, r, c1]
      rect[2] = r
      grown[(c0, c1)] = rect
    done.extend(open_.values())
    open_ = grown
  done.extend(open_.values())
  return sorted(tuple(rect) for rect in done)


# ASCII maps.


def _legend(legend) -> dict[str, tuple[Tile, ...]]:
  table = dict(LEGEND)
  if legend is not None:
    if not isinstance(legend, Mapping):
      raise ValueError(f"legend: expected a dict of character -> Tile, got {type(legend).__name__}")
    table.update(legend)
  out = {}
  for ch, spec in table.items():
    if not isinstance(ch, str) or len(ch) != 1 or ch in "\r\n":
      raise ValueError(f"legend: keys must be single characters (not newlines), got {ch!r}")
    spec = () if spec is None else (spec,) if isinstance(spec, Tile) else tuple(spec)
    if not all(isinstance(t, Tile) for t in spec):
      raise ValueError(f"legend: {ch!r} must map to a Tile, a tuple of Tiles or None, got {spec!r}")
    out[ch] = spec
  return out


def parse_ascii(text: str, legend=None, *, name: str = "", gravity=(0.0, -9.81),
                strict: bool = False, source: str | None = None) -> Level:
  """Reads an ASCII map: Sokoban XSB as it is, plus platformer characters.

  Characters (`LEGEND`; `legend` adds or overrides entries):

  | char | body |
  | --- | --- |
  | `#` | wall (immovable, merged into rectangles), tag "wall" |
  | space `-` `_` | floor (no body) |
  | `@` `p` | player, mass 1, half 0.4, category `PLAYER`, tag "player" |
  | `$` `b` | box, mass 1, half 0.45, category `BOX`, tag "box" |
  | `.` | goal: a sensor of half 0.05 whose mask admits only `BOX`, tag "goal" |
  | `*` `B` | box on a goal (two bodies: box, then goal) |
  | `+` `P` | player on a goal (two bodies: player, then goal) |
  | `=` | one-way platform: a slab `SLAB` (0.25) thick at the top of its cell, runs merged |
  | `H` | heavy box, mass 10, tags "box" and "heavy" |
  | `>` `<` `^` `v` | kinematic platform (immovable, 1 unit/s that way), runs merged, tag "kinematic" |
  | `F` | flag: a full-cell sensor whose mask admits only `PLAYER`, tag "flag" |
  | `X` | hazard: a full-cell sensor whose mask admits only `PLAYER`, runs merged, tag "hazard" |

  Lines starting with `;` are comments (XSB titles), and blank lines before and
  after the map are dropped; `\\r\\n` line ends are accepted.

  Ragged maps: XSB files trim trailing spaces, so their lines differ in length. A
  line shorter than the longest is padded with floor when it ends in a wall (a
  character whose tile merges into rectangles, `#` by default): in XSB every row
  ends at the level's outer wall once the spaces after it are trimmed, so padding
  restores exactly what the trimming removed. A short line ending in anything else
  (a truncated row, trailing floor, a blank line inside the map) is an error,
  since the missing cells could lie inside the level. With `strict=True` every
  line must have the length of the longest.

  Args:
    text: the map, rows from top to bottom.
    legend: optional dict character -> `Tile`, tuple of `Tile`s, or `None` (floor),
      added to `LEGEND` (overriding its entries).
    name: the level's name.
    gravity: the level's gravity (`Level.gravity`); `(0, 0)` suits a top-down
      Sokoban level.
    strict: require a rectangular map.
    source: what errors call the text (default `name`, or "<ascii>").

  Returns:
    A `Level` whose bounds are `(0, 0, width, height)`.

  Raises:
    ValueError: naming the line and column of an unknown character or a tab, the
      line of a ragged row, or an empty map.

  Examples:
    >>> from jaxchain import levels
    >>> lv = levels.parse_ascii('''
    ... #####
    ... #@$.#
    ... #####
    ... ''')
    >>> lv
    Level('', 7 bodies, tags {wall: 4, player: 1, box: 1, goal: 1})
    >>> lv.tags["wall"], lv.player, lv.pos[lv.player].tolist(), lv.half[0].tolist()
    ((0, 1, 5, 6), 2, [1.5, 1.5], [2.5, 0.5])
    >>> levels.parse_ascii("#@?#")
    Traceback (most recent call last):
    ...
    ValueError: <ascii>: line 1, column 3: unknown character '?' ...
  """
  source = source or name or "<ascii>"
  table = _legend(legend)
  numbered = [(k + 1, line.rstrip("\r")) for k, line in enumerate(text.split("\n"))]
  numbered = [(k, line) for k, line in numbered if not (line.startswith(";") and ";" not in table)]
  while numbered and not numbered[0][1].strip():
    numbered.pop(0)
  while numbered and not numbered[-1][1].strip():
    numbered.pop()
  if not numbered:
    raise ValueError(f"{source}: no map rows (the text is empty, blank or only ';' comments)")
  grid = []
  for k, line in numbered:
    for c, ch in enumerate(line):
      if ch not in table:
        if ch == "\t":
          raise ValueError(f"{source}: line {k}, column {c + 1}: tab character (a tab has no "
                           f"width on a map: use spaces)")
        raise ValueError(f"{source}: line {k}, column {c + 1}: unknown character {ch!r} (known: "
                         f"{''.join(sorted(table))!r}; add it with legend=)")
    grid.append([table[ch] for ch in line])
  width = max(len(row) for row in grid)
  longest = next(k for (k, _), row in zip(numbered, grid) if len(row) == width)
  for (k, line), row in zip(numbered, grid):
    if len(row) == width:
      continue
    if strict:
      raise ValueError(f"{source}: line {k} is ragged: {len(row)} columns, but line {longest} "
                       f"has {width} (strict=True needs a rectangular map)")
    if not (row and any(t.merge == "rect" for t in row[-1])):
      raise ValueError(
          f"{source}: line {k} is ragged: {len(row)} columns, but line {longest} has {width}, "
          f"and it does not end in a wall, so the missing cells could be inside the level (end "
          f"the row with a wall, or write the floor out with spaces or '-')")
    row.extend([()] * (width - len(row)))
  return _level(name, _ascii_bodies(grid), (0.0, 0.0, float(width), float(len(grid))), gravity)


def _ascii_bodies(grid: list[list[tuple[Tile, ...]]]) -> list[_Body]:
  """Bodies of a rectangular grid of tile tuples (row 0 at the top)."""
  height = len(grid)
  bodies = []

  def body(tile: Tile, r0, c0, r1, c1):
    # The union of the run's cell rectangles (exactly the tile's own for one cell).
    slot = grid[r0][c0].index(tile)
    pos = ((c0 + c1 + 1) / 2 + tile.offset[0], height - (r0 + r1 + 1) / 2 + tile.offset[1])
    half = ((c1 - c0) / 2 + tile.half[0], (r1 - r0) / 2 + tile.half[1])
    bodies.append(_Body((r0, c0, slot), pos, half, tile.mass, tile.vel, tile.friction, tile.one_way,
                        tile.sensor, tile.category, tile.mask, tile.tags))

  merged = {}
  for r, row in enumerate(grid):
    for c, tiles in enumerate(row):
      for tile in tiles:
        if tile.merge == "none":
          body(tile, r, c, r, c)
        else:
          merged.setdefault(tile, []).append((r, c))
  for tile, cells in merged.items():
    mask = np.zeros((height, len(grid[0])), bool)
    mask[tuple(np.array(cells).T)] = True
    for rect in rectangles(mask, vertical=tile.merge == "rect"):
      body(tile, *rect)
  return bodies


# Tiled JSON maps.


class _Where:
  """Where in a Tiled map an error is (for messages)."""

  def __init__(self, source: str, layer: str | None = None, obj: str | None = None):
    self.source, self.layer, self.obj = source, layer, obj

  def __str__(self):
    parts = [self.source] + [p for p in (self.layer, self.obj) if p]
    return ", ".join(parts)

  def error(self, message: str) -> ValueError:
    return ValueError(f"{self}: {message}")


def _number(value, what: str = "") -> float:
  if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
    prefix = f"{what}: " if what else ""
    raise ValueError(f"{prefix}expected a finite number (an int or float property), got {value!r}")
  return float(value)


def _numeric(value):
  """A property's number: an int or float, or a string holding one (TMX, and JSON
  written before Tiled 1.2, store untyped properties as strings: "1.00")."""
  if isinstance(value, str):
    try:
      return float(value.strip())
    except ValueError:
      return value
  return value


def _prop_bool(value):
  if isinstance(value, str) and value.strip().lower() in ("true", "false"):
    return value.strip().lower() == "true"
  if not isinstance(value, bool):
    raise ValueError(f"expected a bool property (true or false), got {value!r}")
  return value


def _prop_mass(value):
  if isinstance(value, str) and value.strip().lower() in ("inf", "infinity"):
    return math.inf
  value = _numeric(value)
  if isinstance(value, bool) or not isinstance(value, (int, float)) or not value > 0:
    raise ValueError(f"expected a number > 0, or 'inf' for immovable, got {value!r}")
  return float(value)


def _prop_friction(value):
  value = _number(_numeric(value))
  if value < 0:
    raise ValueError(f"expected a number >= 0, got {value!r}")
  return value


def _prop_bits(value):
  if isinstance(value, str):
    bits = 0
    for part in value.replace(",", "|").split("|"):
      part = part.strip()
      if part.lower() in CATEGORIES:
        bits |= CATEGORIES[part.lower()]
        continue
      try:
        bits |= _prop_bits(int(part, 0))
      except ValueError:
        raise ValueError(f"expected an int in [0, 2**32) or category names joined by '|' "
                         f"({', '.join(CATEGORIES)}), got {value!r}") from None
    return bits
  if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value < _U32:
    raise ValueError(f"expected an int in [0, 2**32) or category names joined by '|' "
                     f"({', '.join(CATEGORIES)}), got {value!r}")
  return value


def _prop_vector(value):
  parts = value.split(",") if isinstance(value, str) else []
  try:
    vec = tuple(float(p) for p in parts)
  except ValueError:
    vec = ()
  if len(vec) != 2 or not all(math.isfinite(v) for v in vec):
    raise ValueError(f"expected a string 'x,y' of two numbers, got {value!r}")
  return vec


def _prop_component(value):
  return _number(_numeric(value))


def _prop_tags(value):
  if not isinstance(value, str):
    raise ValueError(f"expected a string of comma-separated tags, got {value!r}")
  return tuple(t.strip() for t in value.split(",") if t.strip())


def _prop_unit(value):
  value = _number(_numeric(value))
  if not value > 0:
    raise ValueError(f"expected pixels per world unit > 0, got {value!r}")
  return value


# The properties this module reads (others are kept by Tiled for the game and ignored).
_PROPERTIES = {
    "solid": _prop_bool, "one_way": _prop_bool, "sensor": _prop_bool,
    "mass": _prop_mass, "friction": _prop_friction, "category": _prop_bits, "mask": _prop_bits,
    "velocity": _prop_vector, "vx": _prop_component, "vy": _prop_component, "tag": _prop_tags,
}
_MAP_PROPERTIES = {"unit": _prop_unit, "gravity": _prop_vector}
# What only objects use (tiles of a tile layer are immovable and static).
_MOTION = ("mass", "velocity", "vx", "vy")


def _properties(raw, where: _Where, known=_PROPERTIES) -> dict:
  """The recognised properties of a Tiled element, checked (`raw`: its `properties`)."""
  if raw is None:
    return {}
  if isinstance(raw, Mapping):  # The format before Tiled 1.2: {name: value}.
    items = list(raw.items())
  elif isinstance(raw, list):
    try:
      items = [(p["name"], p.get("value")) for p in raw]
    except (TypeError, KeyError):
      raise where.error("properties must be objects with 'name' and 'value'") from None
  else:
    raise where.error(f"properties must be an array, got {type(raw).__name__}")
  out = {}
  for k, (key, value) in enumerate(items):
    if not isinstance(key, str):
      raise where.error(f"property {k}: a property name must be a string, got {key!r}")
    if key not in known:
      near = difflib.get_close_matches(key, list(known), n=1, cutoff=0.8)
      if near:
        warnings.warn(f"{where}: property {key!r} is not one jaxchain reads (ignored); did you "
                      f"mean {near[0]!r}?", UserWarning, stacklevel=2)
      continue
    try:
      out[key] = known[key](value)
    except ValueError as e:
      raise where.error(f"property {key!r}: {e}") from None
  return out


def _int_field(data: Mapping, key: str, where: _Where, default=None, minimum=1) -> int:
  value = data.get(key, default)
  if isinstance(value, bool) or not isinstance(value, int) or value < minimum:
    raise where.error(f"{key!r} must be an int >= {minimum}, got {value!r}")
  return value


def _name(value, what: str, where: _Where) -> str:
  """A Tiled name, class or type as a string: `""` if absent; an integer (a map
  written by a script) becomes its decimal string; anything else is an error."""
  if value is None:
    return ""
  if isinstance(value, str):
    return value
  if isinstance(value, int) and not isinstance(value, bool):
    return str(value)
  raise where.error(f"{what!r} must be a string, got {value!r}")


def _array(value, what: str, where: _Where, default=()) -> list:
  """A JSON array field (absent or null: `default`)."""
  if value is None:
    return list(default)
  if not isinstance(value, list):
    raise where.error(f"{what!r} must be an array, got {value!r}")
  return value


def _flag(value, what: str, where: _Where) -> bool:
  """A boolean map field: JSON true/false, or the forms TMX and scripts write
  (0/1, "true"/"false", "0"/"1", any case)."""
  if isinstance(value, bool):
    return value
  if isinstance(value, int) and value in (0, 1):
    return bool(value)
  if isinstance(value, str) and value.strip().lower() in ("true", "false", "0", "1"):
    return value.strip().lower() in ("true", "1")
  raise where.error(f"{what!r} must be a bool (true or false), got {value!r}")


def _check_box(pos, half, where: _Where, size: str) -> None:
  """A body's box must survive the conversion to world units: finite, with a size
  that did not round away, and inside float32 (the World's default dtype)."""
  if not all(math.isfinite(v) for v in (*pos, *half)):
    raise where.error(f"position ({pos[0]:.6g}, {pos[1]:.6g}) in world units is not finite "
                      f"(the map's coordinates overflow); move the object nearer the origin")
  if not min(half) > 0:
    raise where.error(f"position ({pos[0]:.6g}, {pos[1]:.6g}) in world units is so far from "
                      f"the origin that its size {size} rounds away (float64); move it nearer "
                      f"the origin")
  if max(abs(p) + h for p, h in zip(pos, half)) > _F32_MAX:
    raise where.error(f"position ({pos[0]:.6g}, {pos[1]:.6g}) in world units overflows float32 "
                      f"(the World's dtype, at most {_F32_MAX:.4g}); move it nearer the origin")


def _gids(layer: Mapping, width: int, height: int, where: _Where) -> np.ndarray:
  """The `[height, width]` tile ids of a tile layer, flip bits masked off."""
  if "chunks" in layer:
    raise where.error("chunked tile data (an infinite map) is not supported; make the map finite")
  lw, lh = layer.get("width", width), layer.get("height", height)
  if (lw, lh) != (width, height):
    raise where.error(f"layer size {lw}x{lh} differs from the map's {width}x{height}")
  data = layer.get("data")
  encoding = layer.get("encoding", "csv")
  compression = layer.get("compression", "") or ""
  if encoding == "csv":
    if compression:
      raise where.error(f"compression {compression!r} needs encoding 'base64', not 'csv'")
    if isinstance(data, str):  # Some exporters write the CSV text itself.
      data = [p for p in data.replace("\n", ",").split(",") if p.strip()]
      try:
        data = [int(p) for p in data]
      except ValueError:
        raise where.error("CSV tile data holds a value that is not an integer") from None
    if not isinstance(data, list) or not all(
        isinstance(g, int) and not isinstance(g, bool) for g in data):
      raise where.error("tile data must be an array of integer GIDs (encoding 'csv')")
    if any(not 0 <= g < _U32 for g in data):
      raise where.error("tile data holds a GID outside [0, 2**32)")
    gids = np.asarray(data, np.uint64).astype(np.uint32)
  elif encoding == "base64":
    if not isinstance(data, str):
      raise where.error("encoding 'base64' needs the tile data as a string")
    try:
      raw = base64.b64decode(data, validate=True)
    except (binascii.Error, ValueError):
      raise where.error("tile data is not valid base64") from None
    if compression == "zstd":
      raise where.error("zstd compression is not supported (the Python standard library has "
                        "no zstd); save the layer with zlib or gzip compression, or as CSV")
    try:
      if compression == "zlib":
        raw = zlib.decompress(raw)
      elif compression == "gzip":
        raw = gzip.decompress(raw)
      elif compression:
        raise where.error(f"unknown compression {compression!r} (expected zlib, gzip or none)")
    except (zlib.error, OSError, EOFError) as e:
      raise where.error(f"tile data does not decompress as {compression} ({e})") from None
    if len(raw) % 4:
      raise where.error(f"decoded tile data has {len(raw)} bytes, not a multiple of 4")
    gids = np.frombuffer(raw, "<u4").astype(np.uint32)
  else:
    raise where.error(f"unknown encoding {encoding!r} (expected csv or base64)")
  if gids.size != width * height:
    raise where.error(f"tile data has {gids.size} tiles, expected {width}x{height} = "
                      f"{width * height}")
  return (gids & np.uint32(GID_MASK)).reshape(height, width)


def _read_tileset(ts: Mapping, base, where: _Where) -> list:
  """A tileset's tiles that have data: `[(local id, properties element, class)]`."""
  source = ts.get("source")
  if source is None:
    tiles = _array(ts.get("tiles"), "tiles", where)
    if not all(isinstance(t, Mapping) for t in tiles):
      raise where.error("'tiles' must be an array of objects")
    return [(t.get("id"), t.get("properties"),
             _name(t.get("class") or t.get("type"), "class", _Where(where.source, where.layer,
                                                                    f"tile {t.get('id')!r}")))
            for t in tiles]
  if not isinstance(source, str):
    raise where.error(f"'source' (an external tileset's file) must be a string, got {source!r}")
  if base is None:
    raise where.error(f"external tileset {source!r} cannot be found without the map's directory")
  path = base.joinpath(source)
  try:
    text = path.read_text(encoding="utf-8")
  except OSError as e:
    raise where.error(f"external tileset {source!r} cannot be read ({e}); embed the tileset "
                      f"in the map or ship the file beside it") from None
  if source.endswith(".tsx"):
    try:
      root = ElementTree.fromstring(text)
    except ElementTree.ParseError as e:
      raise where.error(f"external tileset {source!r} is not valid XML ({e})") from None
    tiles = []
    for t in root.iter("tile"):
      props = [dict(name=p.get("name"), value=_xml_value(p)) for p in t.iter("property")]
      local = t.get("id", "")
      tiles.append((int(local) if local.isdigit() else local, props,
                    t.get("class") or t.get("type") or ""))
    return tiles
  try:
    data = json.loads(text)
  except json.JSONDecodeError as e:
    raise where.error(f"external tileset {source!r} is not valid JSON ({e})") from None
  return _read_tileset(data, None, where)


def _xml_value(prop):
  """A TMX/TSX `<property>` value, typed like the JSON format types it."""
  kind, value = prop.get("type", "string"), prop.get("value", prop.text or "")
  try:
    if kind == "bool":
      return {"true": True, "false": False}[value]
    if kind == "int":
      return int(value)
    if kind == "float":
      return float(value)
  except (KeyError, ValueError):
    pass
  return value


def _tile_properties(tilesets, base, where: _Where) -> dict[int, tuple[dict, tuple[str, ...]]]:
  """GID -> (checked properties, tags from the tile's class) of the tiles that have any."""
  out = {}
  if not isinstance(tilesets, list):
    raise where.error("'tilesets' must be an array")
  for k, ts in enumerate(tilesets):
    if not isinstance(ts, Mapping):
      raise where.error(f"tileset {k} must be a JSON object")
    label = ts.get("name") or ts.get("source") or k
    ts_where = _Where(where.source, f"tileset {label!r}")
    first = _int_field(ts, "firstgid", ts_where)
    tiles = _read_tileset(ts, base, ts_where)
    for local, props, cls in tiles:
      if not isinstance(local, int) or local < 0:
        raise ts_where.error(f"a tile has an invalid id {local!r}")
      tile_where = _Where(where.source, f"tileset {label!r}", f"tile {local}")
      out[first + local] = (_properties(props, tile_where), (cls,) if cls else ())
  return out


@dataclasses.dataclass(frozen=True)
class _Units:
  """Pixels to world units: x / ux, and y flipped to point up."""

  ux: float
  uy: float
  height_px: float

  def box(self, x0, y0, x1, y1):
    """World `(pos, half)` of the pixel box x in [x0, x1], y (down) in [y0, y1]."""
    pos = ((x0 + x1) / 2 / self.ux, (self.height_px - (y0 + y1) / 2) / self.uy)
    return pos, ((x1 - x0) / 2 / self.ux, (y1 - y0) / 2 / self.uy)


def _spec(props: dict, tags: tuple[str, ...]) -> tuple:
  """The hashable body spec of resolved properties (what makes tiles merge). The
  default category: `SENSOR` for a sensor, else `PLAYER` for a body tagged "player"
  (named, classed or typed so), `BOX` for one tagged "box", else `SOLID`."""
  tags = tuple(dict.fromkeys(tags + props.get("tag", ())))
  sensor = props.get("sensor", False)
  default = (SENSOR if sensor else PLAYER if "player" in tags else BOX if "box" in tags
             else SOLID)
  return (props.get("one_way", False), sensor, props.get("friction", 0.0),
          props.get("category", default), props.get("mask", ALL), tags)


@dataclasses.dataclass
class _Context:
  """What the layer walk of one Tiled map shares."""

  where: _Where
  grid: tuple[int, int, int, int]
  units: _Units
  tiles: dict
  base: object
  firstgids: dict  # normalised external tileset path -> firstgid
  bodies: list = dataclasses.field(default_factory=list)
  decorative: list = dataclasses.field(default_factory=list)  # tile layers with no solid tile
  solid_seen: bool = False  # some layer, group or tile has a `solid` property


def load_tiled(data: Mapping, *, name: str = "", base=None, gravity=None,
               source: str | None = None) -> Level:
  """Reads a Tiled map: its JSON object (`json.load`), or a TMX map turned into the
  same structure by `tmx_to_json`; see `load` for the rules.

  Args:
    data: the map's JSON object.
    name: the level's name.
    base: directory (a `pathlib.Path` or `importlib.resources` traversable) that
      external tilesets and object templates are relative to.
    gravity: the level's gravity; default the map property `gravity` ("gx,gy"),
      else `(0, -9.81)`.
    source: what errors call the map (default `name`, or "<tiled>").

  Warns:
    UserWarning: when tile layers hold tiles but no layer, group or tile of the map
      has a `solid` property (a map written for the old rule, under which every
      tile layer was solid: see the migration note in `load`).

  Examples:
    >>> from jaxchain import levels
    >>> m = {"orientation": "orthogonal", "width": 3, "height": 2, "tilewidth": 16,
    ...      "tileheight": 16, "tilesets": [], "layers": [
    ...          {"type": "tilelayer", "name": "ground", "data": [0, 0, 0, 1, 1, 1],
    ...           "properties": [{"name": "solid", "type": "bool", "value": True}]}]}
    >>> lv = levels.load_tiled(m)
    >>> lv.pos.tolist(), lv.half.tolist(), lv.tags["ground"]
    ([[1.5, 0.5]], [[1.5, 0.5]], (0,))
  """
  where = _Where(source or name or "<tiled>")
  if not isinstance(data, Mapping):
    raise where.error(f"a Tiled map is a JSON object, got {type(data).__name__}")
  orientation = data.get("orientation", "orthogonal")
  if orientation != "orthogonal":
    raise where.error(f"orientation {orientation!r} is not supported: jaxchain reads orthogonal "
                      f"maps only (isometric, staggered and hexagonal maps have no axis-aligned "
                      f"square cells)")
  if _flag(data.get("infinite", False), "infinite", where):
    raise where.error("infinite maps are not supported (their tile data is chunked); make the "
                      "map finite (map property Infinite off) and save it again")
  width, height = _int_field(data, "width", where), _int_field(data, "height", where)
  tw, th = _int_field(data, "tilewidth", where), _int_field(data, "tileheight", where)
  map_props = _properties(data.get("properties"), _Where(where.source, "map properties"),
                          known=_MAP_PROPERTIES)
  unit = map_props.get("unit")
  units = _Units(unit or tw, unit or th, height * th)
  if gravity is None:
    gravity = map_props.get("gravity", (0.0, -9.81))
  tilesets = data.get("tilesets", [])
  tiles = _tile_properties(tilesets, base, where)
  firstgids = {}
  if base is not None:
    for ts in tilesets:
      if isinstance(ts.get("source"), str) and isinstance(ts.get("firstgid"), int):
        firstgids[_normpath(base.joinpath(ts["source"]))] = ts["firstgid"]
  ctx = _Context(where, (width, height, tw, th), units, tiles, base, firstgids,
                 solid_seen=any("solid" in props for props, _ in tiles.values()))
  layers = data.get("layers", [])
  if not isinstance(layers, list):
    raise where.error("'layers' must be an array")
  _walk(layers, {}, (0.0, 0.0), "", ctx)
  if ctx.decorative and not ctx.solid_seen:
    names_ = ", ".join(repr(n) for n in ctx.decorative)
    warnings.warn(
        f"{where}: tile layers are decorative unless marked solid, and no layer, group or tile "
        f"of this map has a 'solid' property: tile layer(s) {names_} made no bodies. Give the "
        f"layers (or tileset tiles) that should collide the bool property solid=true, and "
        f"solid=false to the others to silence this warning", UserWarning, stacklevel=2)
  bounds = (0.0, 0.0, width * tw / units.ux, height * th / units.uy)
  return _level(name, ctx.bodies, bounds, gravity)


def _normpath(path) -> str:
  return os.path.normpath(str(path))


def _walk(layers, inherited, offset, prefix, ctx: _Context):
  """Adds the bodies of `layers` (and of groups within them) to `ctx.bodies`."""
  where = ctx.where
  for k, layer in enumerate(layers):
    if not isinstance(layer, Mapping):
      raise where.error("a layer must be a JSON object")
    lname = prefix + _name(layer.get("name"), "name", _Where(where.source, f"layer {prefix}{k}"))
    lwhere = _Where(where.source, f"layer {lname!r}")
    own = _properties(layer.get("properties"), lwhere)
    ctx.solid_seen |= "solid" in own
    props = {**inherited, **own}
    if props.get("solid") is False:
      continue
    try:
      off = (offset[0] + _number(layer.get("offsetx", 0.0), "offsetx"),
             offset[1] + _number(layer.get("offsety", 0.0), "offsety"))
    except ValueError as e:
      raise lwhere.error(str(e)) from None
    kind = layer.get("type")
    if kind == "group":
      _walk(_array(layer.get("layers"), "layers", lwhere), props, off, lname + "/", ctx)
    elif kind == "tilelayer":
      for key in _MOTION:
        if key in own:
          raise lwhere.error(f"property {key!r}: tile layers are immovable and static (give mass "
                             f"and velocity to objects)")
      props = {k: v for k, v in props.items() if k not in _MOTION}
      _tile_layer(layer, props, off, lname, lwhere, ctx)
    elif kind == "objectgroup":
      _object_layer(layer, props, off, lname, lwhere, ctx)
    elif kind != "imagelayer":
      raise lwhere.error(f"unknown layer type {kind!r}")


def _tile_layer(layer, props, offset, lname, where, ctx: _Context):
  """A tile layer's solid tiles, merged into rectangles. A tile is solid when its
  resolved `solid` (the tile's own property over its layer's and groups') is true."""
  width, height, tw, th = ctx.grid
  gids = _gids(layer, width, height, where)
  specs = {}  # spec -> bool grid of its cells
  layer_tags = (lname,) if lname else ()
  for gid in np.unique(gids[gids > 0]).tolist():
    tile_props, tile_tags = ctx.tiles.get(gid, ({}, ()))
    resolved = {**props, **{k: v for k, v in tile_props.items() if k not in _MOTION}}
    if not resolved.get("solid", False):
      continue
    spec = _spec(resolved, layer_tags + tile_tags)
    specs.setdefault(spec, np.zeros((height, width), bool))
    specs[spec] |= gids == gid
  if not specs and np.any(gids > 0):
    ctx.decorative.append(lname)
  order = len(ctx.bodies)
  for spec, cells in specs.items():
    one_way, sensor, friction, category, mask, tags = spec
    for r0, c0, r1, c1 in rectangles(cells, vertical=not one_way):
      x0, x1 = c0 * tw + offset[0], (c1 + 1) * tw + offset[0]
      y0, y1 = r0 * th + offset[1], (r1 + 1) * th + offset[1]
      if one_way:
        y1 = y0 + SLAB * th
      pos, half = ctx.units.box(x0, y0, x1, y1)
      _check_box(pos, half, _Where(where.source, where.layer, f"tiles from row {r0}, column {c0}"),
                 f"{(c1 - c0 + 1) * tw}x{(r1 - r0 + 1) * th} px")
      ctx.bodies.append(_Body((order, r0, c0), pos, half, math.inf, (0.0, 0.0), friction, one_way,
                              sensor, category, mask, tags))


# Tiled's rotation (degrees clockwise on screen, y down) of a multiple of 90 degrees:
# (cos, sin), exact.
_QUARTER_TURNS = ((1, 0), (0, 1), (-1, 0), (0, -1))


def _rotated_bbox(x0, y0, x1, y1, rotation):
  """The bounding box of the box [x0, x1] x [y0, y1] (pixels, y down, relative to an
  object's origin) rotated by `rotation` degrees (a multiple of 90) clockwise on
  screen about the origin: (dx, dy) -> (dx cos - dy sin, dx sin + dy cos)."""
  c, s = _QUARTER_TURNS[round(rotation / 90) % 4]
  xs, ys = [], []
  for dx, dy in ((x0, y0), (x1, y0), (x1, y1), (x0, y1)):
    xs.append(dx * c - dy * s)
    ys.append(dx * s + dy * c)
  return min(xs), min(ys), max(xs), max(ys)


def _object_layer(layer, props, offset, lname, where, ctx: _Context):
  objects = layer.get("objects", [])
  if not isinstance(objects, list):
    raise where.error("'objects' must be an array")
  for k, obj in enumerate(objects):
    if not isinstance(obj, Mapping):
      raise _Where(where.source, where.layer, f"object {k}").error("an object must be a JSON object")
    oname = _name(obj.get("name"), "name", _Where(where.source, where.layer,
                                                  f"object {obj.get('id', k)}"))
    owhere = _Where(where.source, where.layer,
                    f"object {obj.get('id', k)}" + (f" {oname!r}" if oname else ""))
    if "template" in obj:
      obj = _apply_template(obj, owhere, ctx)
      oname = _name(obj.get("name"), "name", owhere)
    for shape in ("polygon", "polyline", "text"):
      if shape in obj and obj[shape] is not False:
        raise owhere.error(f"{shape} objects are not supported (rectangles, ellipses, points and "
                           f"tile objects become bodies); move it to a layer with property "
                           f"solid=false")
    point = bool(obj.get("point", False))
    try:
      x, y = _number(obj.get("x", 0.0), "x"), _number(obj.get("y", 0.0), "y")
      w, h = _number(obj.get("width", 0.0), "width"), _number(obj.get("height", 0.0), "height")
      rotation = _number(obj.get("rotation", 0.0), "rotation")
    except ValueError as e:
      raise owhere.error(str(e)) from None
    if rotation % 90:
      raise owhere.error(f"rotation {rotation:g} is not supported: boxes are axis-aligned, so only "
                         f"multiples of 90 degrees are (rotate it by a right angle, or remove it)")
    if not point and not (w > 0 and h > 0):
      raise owhere.error(f"size {w:g}x{h:g}: a body needs a width and height > 0")
    kind = _name(obj.get("class") or obj.get("type"), "class" if obj.get("class") else "type",
                 owhere)
    tags = tuple(t for t in (lname, oname, kind) if t)
    resolved = dict(props)
    box = (0.0, 0.0, w, h)  # Relative to the origin (x, y), y down.
    if "gid" in obj:  # A tile object: its origin (x, y) is its bottom-left corner.
      gid = _int_field(obj, "gid", owhere, minimum=0) & GID_MASK
      tile_props, tile_tags = ctx.tiles.get(gid, ({}, ()))
      resolved.update(tile_props)
      tags += tile_tags
      box = (0.0, -h, w, 0.0)
    resolved.update(_properties(obj.get("properties"), owhere))
    if resolved.get("solid") is False:
      continue
    ox, oy = x + offset[0], y + offset[1]
    if point:
      spawn = next((t for t in _MOVABLE_TAGS if t in tags + resolved.get("tag", ())), None)
      pos, _ = ctx.units.box(ox, oy, ox, oy)
      if spawn is None:
        resolved.setdefault("sensor", True)
      half = {"player": PLAYER_TILE.half, "box": BOX_TILE.half}.get(spawn, (POINT_HALF, POINT_HALF))
      size = "a point"
    else:
      bx0, by0, bx1, by1 = _rotated_bbox(*box, rotation)
      pos, half = ctx.units.box(ox + bx0, oy + by0, ox + bx1, oy + by1)
      size = f"{w:g}x{h:g} px"
    _check_box(pos, half, owhere, size)
    vx, vy = resolved.get("velocity", (0.0, 0.0))
    vel = (resolved.get("vx", vx), resolved.get("vy", vy))
    one_way, sensor, friction, category, mask, tags = _spec(resolved, tags)
    movable = not sensor and any(t in tags for t in _MOVABLE_TAGS)
    mass = resolved.get("mass", DEFAULT_MASS if movable else math.inf)
    ctx.bodies.append(_Body((len(ctx.bodies),), pos, half, mass, vel, friction, one_way, sensor,
                            category, mask, tags))


def _apply_template(obj, where: _Where, ctx: _Context) -> dict:
  """An object instance of a template (`.tx` XML or `.tj` JSON) merged with it: the
  instance's fields and properties over the template's; a template's tile (gid)
  mapped into the map's tilesets."""
  path = obj["template"]
  if not isinstance(path, str):
    raise where.error(f"'template' must be a file name, got {path!r}")
  if ctx.base is None:
    raise where.error(f"template {path!r} cannot be found without the map's directory")
  file = ctx.base.joinpath(path)
  try:
    text = file.read_text(encoding="utf-8")
  except OSError as e:
    raise where.error(f"template {path!r} cannot be read ({e}); ship it beside the map, or "
                      f"detach the template in Tiled") from None
  try:
    if path.endswith(".tx"):
      root = ElementTree.fromstring(text)
      element = root.find("object")
      if element is None:
        raise ValueError("it has no <object>")
      template = _xml_object(element, where)
      ts = root.find("tileset")
      tileset = None if ts is None else {"firstgid": _xml_int(ts, "firstgid", where, 1),
                                         "source": ts.get("source")}
    else:
      data = json.loads(text)
      template, tileset = data["object"], data.get("tileset")
  except (ElementTree.ParseError, json.JSONDecodeError, ValueError, KeyError, TypeError) as e:
    raise where.error(f"template {path!r} is not a Tiled template ({e})") from None
  merged = {**template, **{k: v for k, v in obj.items() if k not in ("template", "properties")}}
  merged["properties"] = _property_list(template.get("properties")) + _property_list(
      obj.get("properties"))
  if "gid" in template and "gid" not in obj:
    first = ctx.firstgids.get(_normpath(os.path.join(os.path.dirname(str(file)),
                                                     str((tileset or {}).get("source")))))
    if tileset is None or first is None:
      raise where.error(f"template {path!r} uses a tile of a tileset the map does not hold "
                        f"({(tileset or {}).get('source')!r}); add the tileset to the map")
    gid = template["gid"]
    merged["gid"] = (gid & FLIP_BITS) | (first + (gid & GID_MASK) - tileset["firstgid"])
  return merged


def _property_list(raw) -> list:
  """Properties (the array form, or the old {name: value} form) as an array."""
  if raw is None:
    return []
  if isinstance(raw, Mapping):
    return [{"name": k, "value": v} for k, v in raw.items()]
  return list(raw) if isinstance(raw, list) else [raw]


# TMX (Tiled's XML format), read into the structure of its JSON format.


def tmx_to_json(text: str, *, source: str = "<tmx>") -> dict:
  """Parses a TMX map into the structure of Tiled's JSON format, for `load_tiled`.

  Both formats share one code path: this only moves the XML's elements and
  attributes into the JSON's fields (numbers typed, `<property>` values typed by
  their `type`, CSV tile data as text, base64 data as its string with its
  `compression`, `<ellipse/>` and `<point/>` as `"ellipse": true` and `"point":
  true`, `<group>` layers nested). Images are never read.

  Args:
    text: the TMX text.
    source: what errors call the map.

  Raises:
    ValueError: for text that is not XML or not a `<map>`, or a number attribute
      that is not a number (naming the layer or object).

  Examples:
    >>> from jaxchain import levels
    >>> m = levels.tmx_to_json('''<map orientation="orthogonal" width="2" height="1"
    ...   tilewidth="8" tileheight="8"><layer name="g" width="2" height="1">
    ...   <data encoding="csv">1,0</data></layer></map>''')
    >>> m["width"], m["layers"][0]["type"], m["layers"][0]["data"]
    (2, 'tilelayer', '1,0')
  """
  where = _Where(source)
  try:
    root = ElementTree.fromstring(text)
  except ElementTree.ParseError as e:
    raise where.error(f"not valid XML ({e})") from None
  if root.tag != "map":
    raise where.error(f"a TMX map's root element is <map>, got <{root.tag}>")
  out = dict(root.attrib)
  for key in ("width", "height", "tilewidth", "tileheight"):
    if key in out:
      out[key] = _xml_int(root, key, where)
  out["properties"] = _xml_properties(root)
  out["tilesets"] = [_xml_tileset(ts, where) for ts in root.findall("tileset")]
  out["layers"] = _xml_layers(root, where)
  return out


def _xml_int(element, key: str, where: _Where, default=None) -> int:
  value = element.get(key)
  if value is None and default is not None:
    return default
  try:
    return int(value)
  except (TypeError, ValueError):
    raise where.error(f"attribute {key!r} must be an integer, got {value!r}") from None


def _xml_float(element, key: str, where: _Where) -> float:
  value = element.get(key)
  try:
    return float(value)
  except (TypeError, ValueError):
    raise where.error(f"attribute {key!r} must be a number, got {value!r}") from None


def _xml_properties(element):
  props = element.find("properties")
  if props is None:
    return None
  return [dict(name=p.get("name"), type=p.get("type", "string"), value=_xml_value(p))
          for p in props.findall("property")]


def _xml_tileset(ts, where: _Where) -> dict:
  out = {"firstgid": _xml_int(ts, "firstgid", where, 1)}
  if ts.get("source") is not None:
    out["source"] = ts.get("source")
    return out
  out["name"] = ts.get("name", "")
  tiles = []
  for t in ts.findall("tile"):
    tile = {"id": _xml_int(t, "id", _Where(where.source, f"tileset {out['name']!r}"))}
    if t.get("class") or t.get("type"):
      tile["class"] = t.get("class") or t.get("type")
    tile["properties"] = _xml_properties(t)
    tiles.append(tile)
  out["tiles"] = tiles
  return out


_XML_LAYERS = {"layer": "tilelayer", "objectgroup": "objectgroup", "imagelayer": "imagelayer",
               "group": "group"}


def _xml_layers(parent, where: _Where) -> list:
  layers = []
  for child in parent:
    if child.tag not in _XML_LAYERS:
      continue
    lwhere = _Where(where.source, f"layer {child.get('name', '')!r}")
    layer = {"type": _XML_LAYERS[child.tag], "name": child.get("name", "")}
    for key in ("offsetx", "offsety"):
      if key in child.attrib:
        layer[key] = _xml_float(child, key, lwhere)
    layer["properties"] = _xml_properties(child)
    if child.tag == "layer":
      for key in ("width", "height"):
        if key in child.attrib:
          layer[key] = _xml_int(child, key, lwhere)
      data = child.find("data")
      if data is None:
        raise lwhere.error("a tile layer needs a <data> element")
      if data.find("chunk") is not None:
        layer["chunks"] = True
      encoding = data.get("encoding")
      if encoding is None:  # The oldest TMX form: one <tile gid="..."/> per cell.
        layer["data"] = [_xml_int(t, "gid", lwhere, 0) for t in data.findall("tile")]
      else:
        layer["encoding"] = encoding
        layer["data"] = (data.text or "").strip()
        if data.get("compression"):
          layer["compression"] = data.get("compression")
    elif child.tag == "objectgroup":
      layer["objects"] = [_xml_object(o, lwhere) for o in child.findall("object")]
    elif child.tag == "group":
      layer["layers"] = _xml_layers(child, where)
    layers.append(layer)
  return layers


def _xml_object(o, where: _Where) -> dict:
  """One `<object>` as a JSON object (only the attributes it has)."""
  owhere = _Where(where.source, where.layer, f"object {o.get('id', '?')}")
  out = {}
  for key in ("name", "type", "class", "template"):
    if key in o.attrib:
      out[key] = o.get(key)
  for key in ("id", "gid"):
    if key in o.attrib:
      out[key] = _xml_int(o, key, owhere)
  for key in ("x", "y", "width", "height", "rotation"):
    if key in o.attrib:
      out[key] = _xml_float(o, key, owhere)
  for shape in ("ellipse", "point"):
    if o.find(shape) is not None:
      out[shape] = True
  for shape in ("polygon", "polyline"):
    if o.find(shape) is not None:
      out[shape] = o.find(shape).get("points", "")
  if o.find("text") is not None:
    out["text"] = o.find("text").text or ""
  props = _xml_properties(o)
  if props is not None:
    out["properties"] = props
  return out


# Files and shipped levels.

_SUFFIXES = {".txt": "ascii", ".xsb": "xsb", ".tmj": "tiled", ".json": "tiled", ".tmx": "tmx"}


def _shipped():
  return importlib.resources.files("jaxchain").joinpath("data", "levels")


def names() -> list[str]:
  """The names of the levels shipped with jaxchain (for `load`).

  Examples:
    >>> from jaxchain import levels
    >>> "sokoban1" in levels.names()
    True
  """
  return sorted(p.name.rsplit(".", 1)[0] for p in _shipped().iterdir()
                if "." in p.name and "." + p.name.rsplit(".", 1)[1] in _SUFFIXES)


def load(path, legend=None, *, strict: bool = False, gravity=None) -> Level:
  """Loads a level file by extension, or a shipped level by name (`names()`).

  Formats:
    - `.xsb`: Sokoban XSB text (`parse_ascii`), gravity `(0, 0)` by default
      (Sokoban is seen from above).
    - `.txt`: ASCII map (`parse_ascii`), gravity `(0, -9.81)` by default.
    - `.tmj`, `.json`: Tiled JSON map; `.tmx`: Tiled XML map (read by `tmx_to_json`
      into the JSON's structure, then the same code path). Orthogonal and finite
      only (isometric, staggered and hexagonal maps are an error naming the
      orientation). Tile data: CSV, or base64 uncompressed, zlib or gzip (TMX also
      `<tile gid>` elements); flip bits of the GIDs are masked off. External
      tilesets (`.tsx`, `.tsj`) and object templates (`.tx`, `.tj`) are read from
      beside the map; images never are.
      **Tile layers are decorative unless marked solid**: a tile makes a body only
      when the bool property `solid` is true on the tile (in its tileset) or, when
      the tile does not say, on its layer or a group around it; the tiles of one
      layer with the same properties merge into rectangles. (Migration: before this
      rule every tile layer was solid. A map whose tile layers hold tiles while no
      layer, group or tile has a `solid` property loads with a `UserWarning` naming
      the layers; give the colliding layers `solid: true`.)
      Objects are bodies unless `solid` is false: rectangles and tile objects (their
      box), ellipses (their bounding box), rotated by Tiled's `rotation` when it is
      a multiple of 90 degrees (Tiled turns an object clockwise on screen about its
      origin: the top-left corner of a rectangle or ellipse, the bottom-left corner
      of a tile object; the body is the turned box); any other rotation is an
      error. A point object is a spawn when tagged "player" or "box" (a body of the
      ASCII `@` or `$` size, half 0.4 or 0.45 world units, centred on the point),
      else a trigger: a sensor of half `POINT_HALF` (0.05 world units) centred on
      it. Polygons, polylines and text are errors.
      Properties (on layers, group layers, tiles of a tileset, templates and
      objects; later ones override) say what: `solid` (bool; see above; false skips
      a layer, group, tile or object), `one_way`
      (bool; a slab `SLAB` of a tile thick at its top on tile layers), `sensor`
      (bool), `friction` (float >= 0), `category` and `mask` (int in [0, 2**32), or
      names like "player|box" from `CATEGORIES`; default `SENSOR` for sensors,
      `PLAYER` for a body tagged "player" (an object named, classed or typed
      "player"), `BOX` for one tagged "box", else `SOLID`; mask all bits), `mass`
      (objects only: float > 0 or "inf"; absent means
      `DEFAULT_MASS` (1.0) for an object tagged "player" or "box" that is not a
      sensor, like the ASCII `@` and `$`, and immovable for any other), `velocity`
      ("vx,vy" string) or `vx`/`vy` (floats; objects only,
      world units per second, y up), `tag` (comma-separated extra tags). Numbers
      and bools may be strings ("1.00", "true"), as TMX and old JSON write untyped
      properties. An unknown property close to a known name (`oneway`) warns. A
      tile's mass and velocity apply to tile objects; tile layers are immovable and
      static (mass or velocity on a tile layer itself is an error). Tags: the
      layer's name (group layers as "group/layer"), the object's name and
      class (or type), and the tile's class, always strings (an integer name, as
      scripts write, is read as its decimal string; any other non-string is an
      error). Units: one tile is one world unit
      along each axis unless the map property `unit` (float) gives the pixels per
      unit; y points up. Map properties `gravity` ("gx,gy") and `name` are read too.
      The map field `infinite` is a bool: JSON true/false, or 0/1 and the strings
      "true"/"false"/"0"/"1" that TMX and scripts write; anything else is an
      error. Every body must land inside float32 with its size intact (an object
      at x = 1e300 is an error naming it).

  Args:
    path: a file path, or the name of a shipped level.
    legend: extra characters for ASCII maps (see `parse_ascii`).
    strict: ASCII maps must be rectangular (see `parse_ascii`).
    gravity: the level's gravity, overriding the format's default.

  Returns:
    The `Level`, named after the file's stem (or the map property `name`).

  Raises:
    ValueError: for an unsupported extension or malformed input, naming the file
      and the line and column, or the layer and object, and the property.
    FileNotFoundError: for a path that does not exist and is not a shipped level.

  Examples:
    >>> from jaxchain import levels
    >>> lv = levels.load("sokoban1")
    >>> lv.gravity, len(lv.tags["box"]) == len(lv.tags["goal"])
    ((0.0, 0.0), True)
  """
  file = _level_file(path)
  suffix = "." + file.name.rsplit(".", 1)[-1].lower() if "." in file.name else ""
  if suffix not in _SUFFIXES:
    raise ValueError(f"{file.name}: unsupported level file extension {suffix!r}; expected "
                     f"one of {', '.join(_SUFFIXES)}")
  text = file.read_text(encoding="utf-8")
  stem = file.name.rsplit(".", 1)[0]
  kind = _SUFFIXES[suffix]
  if kind == "tmx":
    data = tmx_to_json(text, source=file.name)
    return load_tiled(data, name=stem, base=_parent(file), gravity=gravity, source=file.name)
  if kind == "tiled":
    try:
      data = json.loads(text)
    except json.JSONDecodeError as e:
      raise ValueError(f"{file.name}: not valid JSON ({e})") from None
    return load_tiled(data, name=stem, base=_parent(file), gravity=gravity, source=file.name)
  if gravity is None:
    gravity = (0.0, 0.0) if kind == "xsb" else (0.0, -9.81)
  if kind == "xsb":
    table = _legend(legend)
    rows = [k for k, line in enumerate(text.split("\n")) if _is_map_row(line, table)]
    runs = 1 + sum(1 for a, b in zip(rows, rows[1:]) if b != a + 1)
    if rows and runs > 1:
      raise ValueError(f"{file.name}: holds {runs} maps separated by blank or text lines (a "
                       f"collection): load them with levels.load_collection(path), one Level "
                       f"each")
  return parse_ascii(text, legend, name=stem, gravity=gravity, strict=strict, source=file.name)


def _level_file(path):
  """The file of a path, or of a shipped level's name (`names()`)."""
  file = pathlib.Path(path)
  if not file.exists() and isinstance(path, str) and not file.suffix and "/" not in path:
    shipped = {p.name.rsplit(".", 1)[0]: p for p in _shipped().iterdir()}
    if path not in shipped:
      raise FileNotFoundError(f"no level file {path!r}, and no shipped level of that name "
                              f"(shipped: {', '.join(names())})")
    return shipped[path]
  if not file.is_file():
    raise FileNotFoundError(f"no level file {str(path)!r} (shipped levels: "
                            f"{', '.join(names())})")
  return file


def _parent(file):
  """The directory of a path or of an `importlib.resources` traversable."""
  if isinstance(file, pathlib.Path):
    return file.parent
  return _shipped()


# Sokoban collections (several levels in one XSB file) and solutions.



def _is_map_row(line: str, table) -> bool:
  """A line of a level's map: after leading floor (spaces, `-`, `_`) it starts with a
  wall `#` (every XSB row does: its first solid cell is the outer wall). A line with a
  stray character is still a map row, so `parse_ascii` reports the character."""
  del table
  return line.lstrip(" -_").startswith("#")


def parse_xsb_collection(text: str, legend=None, *, name: str = "", gravity=(0.0, 0.0),
                         strict: bool = False, source: str | None = None) -> list[Level]:
  """Reads a Sokoban collection: several XSB levels in one text, as a list of `Level`s.

  The text is read line by line. A level is a run of consecutive map lines (lines
  whose first character after leading floor, spaces `-` `_`, is a wall `#`: every
  XSB row starts at the outer wall); a blank line or a text line ends it. Every other line is text: `; ...` comments,
  `Title: ...`, `Author: ...`, `Comment:` ... `Comment-End:` blocks (text whatever
  their lines look like), a collection's header. Only titles are kept (as the
  levels' names); authors and comments are not read into the `Level`s. A level's title is, in this order: a `Title:` line in the paragraph
  right after its map (the text lines up to the next blank line) or in the last
  paragraph before it; else the first `;` comment of that paragraph before it
  (`; 12 'Lockdown'` gives "12 'Lockdown'"); else its first plain text line; else
  `"{name} {k}"` (k counted from 1; "level k" without a `name`). Each map is read
  by `parse_ascii` with `legend` and `strict`, and errors name the line in the
  whole text.

  Args:
    text: the collection.
    legend: extra characters (see `parse_ascii`).
    name: the collection's name (for untitled levels and errors).
    gravity: every level's gravity (default `(0, 0)`: Sokoban is seen from above).
    strict: every map must be rectangular.
    source: what errors call the text (default `name`, or "<xsb>").

  Returns:
    The levels in file order, each named by its title.

  Raises:
    ValueError: when the text holds no level, or a map is malformed (naming the
      line in the whole text).

  Examples:
    >>> from jaxchain import levels
    >>> c = levels.parse_xsb_collection('''; A tiny collection
    ...
    ... ; 1
    ... #####
    ... #@$.#
    ... #####
    ...
    ... ######
    ... #@$ .#
    ... ######
    ... Title: Two steps
    ... Author: me
    ... ''')
    >>> [lv.name for lv in c], [len(lv.tags["box"]) for lv in c]
    (['1', 'Two steps'], [1, 1])
  """
  source = source or name or "<xsb>"
  table = _legend(legend)
  lines = [line.rstrip("\r") for line in text.split("\n")]
  kinds, in_comment = [], False
  for line in lines:
    key = line.strip().lower()
    if in_comment or key.startswith("comment:") or key.startswith("comment-end:"):
      # A Comment: ... Comment-End: block is text, whatever its lines look like.
      in_comment = (in_comment or (key.startswith("comment:") and not key[8:].strip())) and \
          not key.startswith("comment-end:")
      kinds.append("text")
    else:
      kinds.append("blank" if not key else "map" if _is_map_row(line, table) else "text")
  maps = []  # (first line, last line), 0-based, inclusive
  k = 0
  while k < len(lines):
    if kinds[k] == "map":
      start = k
      while k + 1 < len(lines) and kinds[k + 1] == "map":
        k += 1
      maps.append((start, k))
    k += 1
  if not maps:
    raise ValueError(f"{source}: no level (no line starting with a wall '#')")

  def paragraph_after(end):
    out, k = [], end + 1
    while k < len(lines) and kinds[k] == "text":
      out.append(lines[k].strip())
      k += 1
    return out, k

  def title_of(before, after):
    for line in after + before:
      if line.lower().startswith("title:") and line[6:].strip():
        return line[6:].strip()
    for line in before:
      if line.startswith(";") and line.strip(" ;\t"):
        return line.strip(" ;\t")
    for line in before:
      if not line.startswith(";") and ":" not in line:
        return line
    return ""

  out, prev_end = [], -1
  for number, (start, end) in enumerate(maps, 1):
    after, _ = paragraph_after(end)
    # The last paragraph of text before the map (after the previous map's own).
    if prev_end >= 0:
      _, prev_end = paragraph_after(prev_end)
    before, k = [], start - 1
    while k > prev_end and kinds[k] == "blank":
      k -= 1
    while k > prev_end and kinds[k] == "text":
      before.insert(0, lines[k].strip())
      k -= 1
    prev_end = end
    title = title_of(before, after) or f"{name or 'level'} {number}"
    body = "\n" * start + "\n".join(lines[start:end + 1])
    out.append(parse_ascii(body, legend, name=title, gravity=gravity, strict=strict,
                           source=source))
  return out


def load_collection(path, legend=None, *, strict: bool = False, gravity=None) -> list[Level]:
  """Loads a Sokoban collection file (several XSB levels; `parse_xsb_collection`).

  Args:
    path: a file path, or the name of a shipped level (a one-level collection).
    legend: extra characters (see `parse_ascii`).
    strict: every map must be rectangular.
    gravity: every level's gravity (default `(0, 0)`).

  Returns:
    The levels in file order, each named by its title.

  Examples:
    >>> from jaxchain import levels
    >>> [lv.name for lv in levels.load_collection("sokoban1")]
    ['sokoban1 (jaxchain): one box, one goal']
  """
  file = _level_file(path)
  text = file.read_text(encoding="utf-8")
  stem = file.name.rsplit(".", 1)[0]
  return parse_xsb_collection(text, legend, name=stem, strict=strict, source=file.name,
                              gravity=(0.0, 0.0) if gravity is None else gravity)


_MOVE_LETTERS = frozenset("lurdLURD")


def parse_moves(text: str) -> str:
  """Expands a Sokoban solution in LURD notation into one letter per move.

  Letters `l u r d` are moves and `L U R D` pushes (kept as written); a count
  before a letter or a parenthesised group repeats it (`3r` is `rrr`, `2(ul)` is
  `ulul`: the run-length encoding of many published solutions); whitespace and
  line breaks are ignored.

  Raises:
    ValueError: for any other character, a count before nothing, or unbalanced
      parentheses, naming the position.

  Examples:
    >>> from jaxchain import levels
    >>> levels.parse_moves("dl3u 2(rD)")
    'dluuurDrD'
  """
  out, stack, count = [], [], ""
  for k, ch in enumerate(text):
    if ch.isspace():
      if count:
        raise ValueError(f"moves: position {k + 1}: a count ({count}) must come right before a "
                         f"move or a group")
      continue
    if ch.isdigit():
      count += ch
    elif ch in _MOVE_LETTERS:
      out.append(ch * (int(count) if count else 1))
      count = ""
    elif ch == "(":
      stack.append((out, int(count) if count else 1))
      out, count = [], ""
    elif ch == ")":
      if not stack or count:
        raise ValueError(f"moves: position {k + 1}: unbalanced ')'" if not stack else
                         f"moves: position {k + 1}: a count before ')'")
      inner = "".join(out)
      out, times = stack.pop()
      out.append(inner * times)
    else:
      raise ValueError(f"moves: position {k + 1}: {ch!r} is not a move (l u r d, L U R D for "
                       f"pushes, counts and parentheses)")
  if stack:
    raise ValueError("moves: unbalanced '(' (a group is never closed)")
  if count:
    raise ValueError(f"moves: the count {count} at the end repeats nothing")
  return "".join(out)
