"""Tiled maps (`load_tiled`): the JSON format's structure, from a `.tmj`/`.json` file
or from a TMX map read by `tmx_to_json`.
"""

from __future__ import annotations

import base64
import binascii
import dataclasses
import difflib
import math
import os
import warnings
import xml.etree.ElementTree as ElementTree
import zlib
from collections.abc import Mapping

import numpy as np

from jaxchain.levels.files import _parse_json, _read_text, _Where
from jaxchain.levels.level import (ALL, BOX, BOX_TILE, CATEGORIES, MAX_BODIES, MAX_TILES, PLAYER,
                                   PLAYER_TILE, SENSOR, SLAB, SOLID, Level, _Body,
                                   _label_rectangles, _level, _max_bodies, _too_many, _U32)
from jaxchain.levels.tmx import MAX_GROUP_DEPTH, _xml_int, _xml_object, _xml_value

FLIP_BITS = 0xF0000000  # Tiled GID flags: flipped horizontally, vertically, diagonally; hex 120
GID_MASK = 0x0FFFFFFF  # the tile id bits of a Tiled GID
# The mass of a Tiled object tagged "player" or "box" (by its name, class, tile class,
# layer or `tag` property) that has no `mass` property: the mass of the ASCII `@` and
# `$`. Other objects without `mass` are immovable.
DEFAULT_MASS = 1.0
_MOVABLE_TAGS = ("player", "box")
# Half-extents (world units) of the small sensor a Tiled point object becomes (one not
# tagged "player" or "box": those are spawns, bodies of the ASCII `@` and `$` sizes).
POINT_HALF = 0.05
_F32_MAX = float(np.finfo(np.float32).max)


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
    if compression in ("zlib", "gzip"):
      raw = _inflate(raw, compression, 4 * width * height, width, height, where)
    elif compression:
      raise where.error(f"unknown compression {compression!r} (expected zlib, gzip or none)")
    if len(raw) % 4:
      raise where.error(f"decoded tile data has {len(raw)} bytes, not a multiple of 4")
    gids = np.frombuffer(raw, "<u4").astype(np.uint32)
  else:
    raise where.error(f"unknown encoding {encoding!r} (expected csv or base64)")
  if gids.size != width * height:
    raise where.error(f"tile data has {gids.size} tiles, expected {width}x{height} = "
                      f"{width * height}")
  return (gids & np.uint32(GID_MASK)).reshape(height, width)


def _inflate(raw: bytes, compression: str, size: int, width: int, height: int,
             where: _Where) -> bytes:
  """Decompresses zlib or gzip tile data that must inflate to exactly `size` bytes,
  never producing more than `size + 1` of them (a bomb stops there)."""
  d = zlib.decompressobj(zlib.MAX_WBITS | (16 if compression == "gzip" else 0))
  try:
    out = d.decompress(raw, size + 1)
  except zlib.error as e:
    raise where.error(f"tile data does not decompress as {compression} ({e})") from None
  if len(out) > size:
    raise where.error(f"tile data inflates past the layer's {width}x{height} tiles ({size} "
                      f"bytes) ({compression}): refused before inflating further")
  if not d.eof:
    raise where.error(f"tile data does not decompress as {compression} (the stream stops "
                      f"short of its end)")
  if d.unused_data:
    raise where.error(f"tile data has data after the end of its {compression} stream")
  return out


def _read_tileset(ts: Mapping, base, where: _Where) -> list:
  """A tileset's tiles that have data: `[(local id, properties element, class, shaped)]`,
  `shaped` saying whether the tile has collision shapes (objects drawn in Tiled's
  collision editor: its `objectgroup`)."""
  source = ts.get("source")
  if source is None:
    tiles = _array(ts.get("tiles"), "tiles", where)
    if not all(isinstance(t, Mapping) for t in tiles):
      raise where.error("'tiles' must be an array of objects")
    shaped = lambda og: isinstance(og, Mapping) and bool(og.get("objects"))
    return [(t.get("id"), t.get("properties"),
             _name(t.get("class") or t.get("type"), "class", _Where(where.source, where.layer,
                                                                    f"tile {t.get('id')!r}")),
             shaped(t.get("objectgroup")))
            for t in tiles]
  if not isinstance(source, str):
    raise where.error(f"'source' (an external tileset's file) must be a string, got {source!r}")
  if base is None:
    raise where.error(f"external tileset {source!r} cannot be found without the map's directory")
  path = base.joinpath(source)
  try:
    text = _read_text(path)
  except OSError as e:
    raise where.error(f"external tileset {source!r} cannot be read ({e}); embed the tileset "
                      f"in the map or ship the file beside it") from None
  except ValueError as e:
    raise where.error(f"external tileset {source!r}: {e}") from None
  if source.endswith(".tsx"):
    try:
      root = ElementTree.fromstring(text)
    except ElementTree.ParseError as e:
      raise where.error(f"external tileset {source!r} is not valid XML ({e})") from None
    tiles = []
    for t in root.iter("tile"):
      # The tile's own properties (not those of the objects of its collision shapes).
      props = [dict(name=p.get("name"), value=_xml_value(p))
               for p in t.findall("properties/property")]
      local = t.get("id", "")
      tiles.append((int(local) if local.isdigit() else local, props,
                    t.get("class") or t.get("type") or "", t.find("objectgroup/object") is not None))
    return tiles
  try:
    data = _parse_json(text)
  except ValueError as e:
    raise where.error(f"external tileset {source!r} is not valid JSON ({e})") from None
  return _read_tileset(data, None, where)



def _tile_properties(tilesets, base, where: _Where
                     ) -> tuple[dict[int, tuple[dict, tuple[str, ...]]], dict[int, str]]:
  """GID -> (checked properties, tags from the tile's class) of the tiles that have any;
  and GID -> "tileset 'name' tile k" of the tiles that have collision shapes."""
  out, shaped = {}, {}
  if not isinstance(tilesets, list):
    raise where.error("'tilesets' must be an array")
  for k, ts in enumerate(tilesets):
    if not isinstance(ts, Mapping):
      raise where.error(f"tileset {k} must be a JSON object")
    label = ts.get("name") or ts.get("source") or k
    ts_where = _Where(where.source, f"tileset {label!r}")
    first = _int_field(ts, "firstgid", ts_where)
    tiles = _read_tileset(ts, base, ts_where)
    for local, props, cls, has_shapes in tiles:
      if not isinstance(local, int) or local < 0:
        raise ts_where.error(f"a tile has an invalid id {local!r}")
      tile_where = _Where(where.source, f"tileset {label!r}", f"tile {local}")
      out[first + local] = (_properties(props, tile_where), (cls,) if cls else ())
      if has_shapes:
        shaped[first + local] = f"tileset {label!r} tile {local}"
  return out, shaped


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
  max_bodies: int
  shaped: dict  # GID -> its name, of the tiles with collision shapes
  bodies: list = dataclasses.field(default_factory=list)
  shaped_used: set = dataclasses.field(default_factory=set)  # of them, the ones made bodies
  decorative: list = dataclasses.field(default_factory=list)  # tile layers with no solid tile
  solid_seen: bool = False  # some layer, group or tile has a `solid` property


def load_tiled(data: Mapping, *, name: str = "", base=None, gravity=None,
               source: str | None = None, max_bodies: int = MAX_BODIES) -> Level:
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
    max_bodies: the most bodies the level may have (`MAX_BODIES`; a tile layer's
      rectangles are counted before they are built).

  Warns:
    UserWarning: when tile layers hold tiles but no layer, group or tile of the map
      has a `solid` property (a map written for the old rule, under which every
      tile layer was solid: see the migration note in `load`); when tiles with
      collision shapes (Tiled's collision editor) make bodies: the shapes are
      ignored, each such tile is a full cell (a tile object its box).

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
  if width * height > MAX_TILES:
    raise where.error(f"the map is {width}x{height} = {width * height} tiles, more than the "
                      f"limit levels.MAX_TILES = {MAX_TILES} (2048x2048)")
  map_props = _properties(data.get("properties"), _Where(where.source, "map properties"),
                          known=_MAP_PROPERTIES)
  unit = map_props.get("unit")
  units = _Units(unit or tw, unit or th, height * th)
  if gravity is None:
    gravity = map_props.get("gravity", (0.0, -9.81))
  tilesets = data.get("tilesets", [])
  tiles, shaped = _tile_properties(tilesets, base, where)
  firstgids = {}
  if base is not None:
    for ts in tilesets:
      if isinstance(ts.get("source"), str) and isinstance(ts.get("firstgid"), int):
        firstgids[_normpath(base.joinpath(ts["source"]))] = ts["firstgid"]
  ctx = _Context(where, (width, height, tw, th), units, tiles, base, firstgids,
                 _max_bodies(max_bodies), shaped, solid_seen=any("solid" in props for props, _ in tiles.values()))
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
  if ctx.shaped_used:
    names_ = ", ".join(ctx.shaped[g] for g in sorted(ctx.shaped_used))
    warnings.warn(
        f"{where}: {names_} ha{'s' if len(ctx.shaped_used) == 1 else 've'} collision shapes "
        f"(drawn in Tiled's collision editor), which jaxchain ignores: a solid tile is its full "
        f"cell, a tile object its box. Draw the shapes as objects of an object layer instead "
        f"(boxes: rectangles), or give those tiles solid=false", UserWarning, stacklevel=2)
  bounds = (0.0, 0.0, width * tw / units.ux, height * th / units.uy)
  return _level(name, ctx.bodies, bounds, gravity)


def _normpath(path) -> str:
  return os.path.normpath(str(path))


def _walk(layers, inherited, offset, prefix, ctx: _Context, depth: int = 0):
  """Adds the bodies of `layers` (and of groups within them, at most `MAX_GROUP_DEPTH`
  deep) to `ctx.bodies`; `depth` counts the groups around `layers`."""
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
      if depth >= MAX_GROUP_DEPTH:
        raise lwhere.error(f"group layers nested more than levels.MAX_GROUP_DEPTH = "
                           f"{MAX_GROUP_DEPTH} deep")
      _walk(_array(layer.get("layers"), "layers", lwhere), props, off, lname + "/", ctx,
            depth + 1)
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
  resolved `solid` (the tile's own property over its layer's and groups') is true.
  Vectorised over the tiles: one spec (properties and tags) per tile that has data in
  its tileset, one for all others; the rectangles are counted before bodies are built."""
  width, height, tw, th = ctx.grid
  gids = _gids(layer, width, height, where)
  layer_tags = (lname,) if lname else ()
  specs, index = [], {}  # The solid specs, and spec -> its label.

  def label(tile_props, tile_tags) -> int:
    resolved = {**props, **{k: v for k, v in tile_props.items() if k not in _MOTION}}
    if not resolved.get("solid", False):
      return -1
    spec = _spec(resolved, layer_tags + tile_tags)
    if spec not in index:
      index[spec] = len(specs)
      specs.append(spec)
    return index[spec]

  used = gids > 0
  labels = np.where(used, label({}, ()), -1)
  keys = np.intersect1d(np.fromiter(ctx.tiles, np.int64, len(ctx.tiles)),
                        np.unique(gids[used]).astype(np.int64))
  if len(keys):  # The tiles with data in the layer: their own labels, for every cell at once.
    values = np.asarray([label(*ctx.tiles[g]) for g in keys.tolist()], np.int64)
    ctx.shaped_used.update(g for g, v in zip(keys.tolist(), values.tolist())
                           if v >= 0 and g in ctx.shaped)
    at = np.minimum(np.searchsorted(keys, gids), len(keys) - 1)
    labels = np.where(keys[at] == gids, values[at], labels)
  if not np.any(labels >= 0):
    if np.any(used):
      ctx.decorative.append(lname)
    return
  room = ctx.max_bodies - len(ctx.bodies)
  rects = _label_rectangles(labels, np.asarray([not spec[0] for spec in specs]), room)
  if rects is None or len(rects) > room:
    raise _too_many(where, ctx.max_bodies)
  order = len(ctx.bodies)
  for r0, c0, r1, c1, lab in rects.tolist():
    one_way, sensor, friction, category, mask, tags = specs[lab]
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
    gid = None
    if "gid" in obj:  # A tile object: its origin (x, y) is its bottom-left corner.
      gid = _int_field(obj, "gid", owhere, minimum=0) & GID_MASK
      tile_props, tile_tags = ctx.tiles.get(gid, ({}, ()))
      resolved.update(tile_props)
      tags += tile_tags
      box = (0.0, -h, w, 0.0)
    resolved.update(_properties(obj.get("properties"), owhere))
    if resolved.get("solid") is False:
      continue
    if gid in ctx.shaped:
      ctx.shaped_used.add(gid)
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
    if len(ctx.bodies) >= ctx.max_bodies:
      raise _too_many(owhere, ctx.max_bodies)
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
    text = _read_text(file)
  except OSError as e:
    raise where.error(f"template {path!r} cannot be read ({e}); ship it beside the map, or "
                      f"detach the template in Tiled") from None
  except ValueError as e:
    raise where.error(f"template {path!r}: {e}") from None
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
      data = _parse_json(text)
      template, tileset = data["object"], data.get("tileset")
  except (ElementTree.ParseError, ValueError, KeyError, TypeError) as e:
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
