"""`load`: a level file by its extension, or a shipped level by name.
"""

from __future__ import annotations

from jaxchain.levels.ascii import _legend, parse_ascii
from jaxchain.levels.files import _SUFFIXES, _level_file, _parent, _parse_json, _read_text
from jaxchain.levels.level import MAX_BODIES, Level
from jaxchain.levels.tiled import load_tiled
from jaxchain.levels.tmx import tmx_to_json
from jaxchain.levels.xsb import _is_map_row


def load(path, legend=None, *, strict: bool = False, gravity=None,
         max_bodies: int = MAX_BODIES) -> Level:
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
      the paths the map names, relative to its directory (or absolute), each a
      regular file; images never are. Collision shapes drawn on tiles in Tiled's
      collision editor are ignored, with a `UserWarning` naming the tiles.
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
    max_bodies: the most bodies the level may have (`MAX_BODIES`; counted before
      they are built, so a small file that would make millions is refused fast).

  Returns:
    The `Level`, named after the file's stem (or the map property `name`).

  Limits (docs/levels.md, "Limits"): every file read is a regular file of at most
  `MAX_FILE_BYTES`, read as UTF-8 (a byte-order mark dropped); a map has at most
  `MAX_TILES` cells, group layers nest at most `MAX_GROUP_DEPTH` deep, compressed
  tile data inflates only up to its layer's size, and a level has at most
  `max_bodies` bodies. Past any of them, a ValueError names the file and the limit.

  Raises:
    ValueError: for an unsupported extension or malformed input, naming the file
      and the line and column, or the layer and object, and the property; for a
      file past a limit.
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
  try:
    text = _read_text(file)
  except ValueError as e:
    raise ValueError(f"{file.name}: {e}") from None
  stem = file.name.rsplit(".", 1)[0]
  kind = _SUFFIXES[suffix]
  if kind == "tmx":
    data = tmx_to_json(text, source=file.name)
    return load_tiled(data, name=stem, base=_parent(file), gravity=gravity, source=file.name,
                      max_bodies=max_bodies)
  if kind == "tiled":
    try:
      data = _parse_json(text)
    except ValueError as e:
      raise ValueError(f"{file.name}: not valid JSON ({e})") from None
    return load_tiled(data, name=stem, base=_parent(file), gravity=gravity, source=file.name,
                      max_bodies=max_bodies)
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
  return parse_ascii(text, legend, name=stem, gravity=gravity, strict=strict, source=file.name,
                     max_bodies=max_bodies)
