"""ASCII maps: Sokoban XSB text as it is, plus platformer characters (`parse_ascii`,
`LEGEND`).
"""

from __future__ import annotations

import types
from collections.abc import Mapping

import numpy as np

from jaxchain.levels.level import (BOX_TILE, FLAG_TILE, GOAL_TILE, HAZARD_TILE, HEAVY_TILE,
                                   MAX_BODIES, MAX_TILES, PLATFORM_TILE, PLAYER_TILE, WALL, Level,
                                   Tile, _Body, _label_rectangles, _level, _max_bodies,
                                   _too_many)


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
                strict: bool = False, source: str | None = None,
                max_bodies: int = MAX_BODIES) -> Level:
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
    max_bodies: the most bodies the level may have (`MAX_BODIES`; counted before
      they are built).

  Returns:
    A `Level` whose bounds are `(0, 0, width, height)`.

  Raises:
    ValueError: naming the line and column of an unknown character or a tab, the
      line of a ragged row, or an empty map; for a map of more than `MAX_TILES`
      cells (width x height), or more than `max_bodies` bodies.

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
  max_bodies = _max_bodies(max_bodies)
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
  return _parse_rows(numbered, table, name, gravity, strict, source, max_bodies)


def _parse_rows(numbered: list[tuple[int, str]], table: dict, name: str, gravity, strict: bool,
                source: str, max_bodies: int, too_many=None) -> Level:
  """The level of a map's rows `(line number, text)`, top to bottom (at least one):
  `parse_ascii` once the comments and blank edges are gone (also the rows of one map
  of a collection, numbered as in the whole text). Its bodies are counted before they
  are built: more than `max_bodies` raise `too_many()` (default: naming `source`)."""
  lines = [line for _, line in numbered]
  present = set().union(*map(set, lines))
  unknown = present - table.keys()
  if unknown:  # The first one, by line and column.
    k, c, ch = min((k, line.index(ch), ch) for (k, line) in numbered for ch in unknown
                   if ch in line)
    if ch == "\t":
      raise ValueError(f"{source}: line {k}, column {c + 1}: tab character (a tab has no "
                       f"width on a map: use spaces)")
    raise ValueError(f"{source}: line {k}, column {c + 1}: unknown character {ch!r} (known: "
                     f"{''.join(sorted(table))!r}; add it with legend=)")
  lengths = np.array([len(line) for line in lines])
  width, height = int(lengths.max()), len(lines)
  longest = numbered[int(np.argmax(lengths))][0]
  for (k, line) in numbered:
    if len(line) == width:
      continue
    if strict:
      raise ValueError(f"{source}: line {k} is ragged: {len(line)} columns, but line {longest} "
                       f"has {width} (strict=True needs a rectangular map)")
    if not (line and any(t.merge == "rect" for t in table[line[-1]])):
      raise ValueError(
          f"{source}: line {k} is ragged: {len(line)} columns, but line {longest} has {width}, "
          f"and it does not end in a wall, so the missing cells could be inside the level (end "
          f"the row with a wall, or write the floor out with spaces or '-')")
  if width * height > MAX_TILES:
    raise ValueError(f"{source}: the map is {width}x{height} = {width * height} cells, more than "
                     f"the limit levels.MAX_TILES = {MAX_TILES} (2048x2048)")
  # Each cell's character code (-1: padding of a short row, floor).
  codes = np.full((height, width), -1, np.int64)
  flat = np.frombuffer("".join(lines).encode("utf-32-le"), "<u4")
  codes[np.arange(width)[None, :] < lengths[:, None]] = flat
  too_many = too_many or (lambda: _too_many(source, max_bodies))
  return _level(name, _ascii_bodies(codes, present, table, max_bodies, too_many),
                (0.0, 0.0, float(width), float(height)), gravity)


def _ascii_bodies(codes: np.ndarray, present: set[str], table: dict, max_bodies: int,
                  too_many) -> list[_Body]:
  """The bodies of a `[rows, cols]` grid of character codes (row 0 at the top; the
  characters `present`), counted (cells of unmerged tiles, rectangles of merged ones)
  before any is built."""
  height = codes.shape[0]
  cells = {}  # Tile -> [rows, cols] bool, its cells (a tile may serve several characters).
  for ch in sorted(present):
    at = None
    for tile in table[ch]:
      at = codes == ord(ch) if at is None else at
      cells[tile] = cells[tile] | at if tile in cells else at
  placed, count = [], 0  # (tile, [k, 4] rectangles (r0, c0, r1, c1)), and their number.
  for tile, at in cells.items():
    if tile.merge == "none":
      r, c = np.nonzero(at)
      rects = np.stack([r, c, r, c], axis=-1)
    else:
      rects = _label_rectangles(np.where(at, 0, -1), np.array([tile.merge == "rect"]),
                                max_bodies - count)
      if rects is None:
        raise too_many()
      rects = rects[:, :4]
    count += len(rects)
    if count > max_bodies:
      raise too_many()
    placed.append((tile, rects))
  bodies = []
  for tile, rects in placed:
    for r0, c0, r1, c1 in rects.tolist():
      # The union of the run's cell rectangles (exactly the tile's own for one cell); the
      # slot orders the bodies of one cell as its legend entry lists them.
      slot = table[chr(codes[r0, c0])].index(tile)
      pos = ((c0 + c1 + 1) / 2 + tile.offset[0], height - (r0 + r1 + 1) / 2 + tile.offset[1])
      half = ((c1 - c0) / 2 + tile.half[0], (r1 - r0) / 2 + tile.half[1])
      bodies.append(_Body((r0, c0, slot), pos, half, tile.mass, tile.vel, tile.friction,
                          tile.one_way, tile.sensor, tile.category, tile.mask, tile.tags))
  return bodies
