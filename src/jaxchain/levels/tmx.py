"""TMX, Tiled's XML format, read into the structure of its JSON format
(`tmx_to_json`), so that both formats share `load_tiled`.
"""

from __future__ import annotations

import xml.etree.ElementTree as ElementTree

from jaxchain.levels.files import _Where

# How deep group layers may nest (Tiled maps rarely nest more than a few).
MAX_GROUP_DEPTH = 64


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
  text = text.removeprefix("\ufeff")  # A byte-order mark (a file read as "utf-8").
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
    shapes = t.findall("objectgroup/object")
    if shapes:  # Collision shapes (only whether there are any is read).
      tile["objectgroup"] = {"objects": [dict(o.attrib) for o in shapes]}
    tiles.append(tile)
  out["tiles"] = tiles
  return out


_XML_LAYERS = {"layer": "tilelayer", "objectgroup": "objectgroup", "imagelayer": "imagelayer",
               "group": "group"}


def _xml_layers(parent, where: _Where, depth: int = 0) -> list:
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
      if depth >= MAX_GROUP_DEPTH:
        raise lwhere.error(f"group layers nested more than levels.MAX_GROUP_DEPTH = "
                           f"{MAX_GROUP_DEPTH} deep")
      layer["layers"] = _xml_layers(child, where, depth + 1)
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
