"""ASCII maps: Sokoban XSB text as it is, plus platformer characters (`parse_ascii`,
`LEGEND`).
"""

from __future__ import annotations

import types
from collections.abc import Mapping

import numpy as np

from jaxchain.levels.level import (BOX_TILE, FLAG_TILE, GOAL_TILE, HAZARD_TILE,
                                   HEAVY_TILE, PLATFORM_TILE, PLAYER_TILE, WALL, Level, Tile,
                                   _Body, _level, rectangles)


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
  after the map are dropped; `\\r\\n` line ends are accepted, and a leading
  byte-order mark is dropped.

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
  text = text.removeprefix("\ufeff")  # A byte-order mark (a file read as "utf-8").
  numbered = [(k + 1, line.rstrip("\r")) for k, line in enumerate(text.split("\n"))]
  numbered = [(k, line) for k, line in numbered if not (line.startswith(";") and ";" not in table)]
  while numbered and not numbered[-1][1].strip():
    numbered.pop()
  numbered.reverse()
  while numbered and not numbered[-1][1].strip():
    numbered.pop()
  numbered.reverse()
  if not numbered:
    raise ValueError(f"{source}: no map rows (the text is empty, blank or only ';' comments)")
  return _parse_rows(numbered, table, name, gravity, strict, source)


def _parse_rows(numbered: list[tuple[int, str]], table: dict, name: str, gravity, strict: bool,
                source: str) -> Level:
  """The level of a map's rows `(line number, text)`, top to bottom (at least one):
  `parse_ascii` once the comments and blank edges are gone (also the rows of one map
  of a collection, numbered as in the whole text)."""
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
