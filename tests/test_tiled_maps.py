"""Tiled maps made by others (the Tiled editor's examples, Phaser's example maps), and
the rules for rotations, ellipses, points and solid tile layers. No jit anywhere.

The expected numbers come from the files themselves, read here independently of
`jaxchain.levels` (ElementTree, base64, zlib/gzip, json), or from the pixel
coordinates written in them; see tests/data/tiled/README.md for where each file
comes from.
"""

import base64
import gzip
import json
import math
import pathlib
import warnings
import xml.etree.ElementTree as ElementTree
import zlib

import numpy as np
import pytest

from jaxchain import levels

TILED = pathlib.Path(__file__).parent / "data" / "tiled"
EXAMPLES = TILED / "tiled-examples"
DECORATIVE = r"tile layers are decorative unless marked solid"
SOLID = {"name": "solid", "type": "bool", "value": True}


def _tmx_layers(path):
  """{layer name: [height, width] GIDs (flip bits off)}, decoded here from the XML."""
  root = ElementTree.parse(path).getroot()
  out = {}
  for layer in root.iter("layer"):
    data = layer.find("data")
    raw = base64.b64decode(data.text.strip())
    raw = {"zlib": zlib.decompress, "gzip": gzip.decompress}[data.get("compression")](raw)
    gids = np.frombuffer(raw, "<u4") & 0x0FFFFFFF
    out[layer.get("name")] = gids.reshape(int(layer.get("height")), int(layer.get("width")))
  return out


def _json_layers(path):
  data = json.loads(path.read_text())
  return {l["name"]: np.asarray(l["data"]).reshape(l["height"], l["width"])
          for l in data["layers"] if l["type"] == "tilelayer"}


def _mark_solid(data, names):
  """`data` with the bool property solid=true on the named layers (what a user does
  in Tiled to make a layer collide)."""
  for layer in data["layers"]:
    if layer["name"] in names:
      layer["properties"] = list(layer.get("properties") or []) + [SOLID]
  return data


def _assert_covers_exactly(lv, tag, gids):
  """The bodies tagged `tag` cover exactly the cells with a tile (each once), and
  their area is the number of those cells."""
  height, width = gids.shape
  idx = list(lv.tags[tag])
  lo, hi = lv.pos[idx] - lv.half[idx], lv.pos[idx] + lv.half[idx]
  rows, cols = np.mgrid[0:height, 0:width]
  centres = np.stack([cols + 0.5, height - rows - 0.5], -1).reshape(-1, 1, 2)
  inside = np.all((centres > lo) & (centres < hi), -1)  # [cells, bodies]
  np.testing.assert_array_equal(inside.sum(1), (gids > 0).reshape(-1).astype(int))
  assert np.prod(2 * lv.half[idx], 1).sum() == (gids > 0).sum()


@pytest.mark.parametrize("path, layers", [
    (EXAMPLES / "desert.tmx", ["Ground"]),
    (EXAMPLES / "sewers.tmx", ["Bottom", "Top"]),
    (EXAMPLES / "perspective_walls.tmx", ["Walls", "Walls level 2", "Walls level 3"]),
    (EXAMPLES / "rpg" / "island.tmx", ["Ground", "Fringe", "Over"]),
])
def test_real_maps_load_with_their_tile_layers_decorative(path, layers):
  # None of these maps says `solid` anywhere, so their tile layers make no bodies and
  # the loader warns, naming each layer (the migration note of docs/levels.md).
  with pytest.warns(UserWarning, match=DECORATIVE) as record:
    lv = levels.load(path)
  message = str(record[0].message)
  assert all(repr(name) in message for name in layers)
  island_objects = 3 if path.name == "island.tmx" else 0
  assert lv.num_bodies == island_objects
  grid = (_tmx_layers if path.suffix == ".tmx" else _json_layers)(path)
  assert list(grid) == layers
  height, width = next(iter(grid.values())).shape
  assert lv.bounds == (0.0, 0.0, float(width), float(height))


@pytest.mark.parametrize("path, layer, tiles, bodies", [
    (EXAMPLES / "desert.tmx", "Ground", 1600, 1),  # Zlib; every cell has a tile.
    (EXAMPLES / "sewers.tmx", "Top", 30, None),  # Gzip, a sparse layer.
    (EXAMPLES / "perspective_walls.tmx", "Walls", 77, None),  # Zlib, external .tsx.
    (EXAMPLES / "rpg" / "island.tmx", "Over", 69, None),
])
def test_real_tile_layers_marked_solid_cover_exactly_their_tiles(path, layer, tiles, bodies):
  if path.suffix == ".tmx":
    data = levels.tmx_to_json(path.read_text(), source=path.name)
    gids = _tmx_layers(path)[layer]
  else:
    data = json.loads(path.read_text())
    gids = _json_layers(path)[layer]
  assert (gids > 0).sum() == tiles
  data["layers"] = [l for l in data["layers"] if l["type"] == "tilelayer"]  # Island's objects.
  lv = levels.load_tiled(_mark_solid(data, [layer]), name=path.stem, base=path.parent,
                         source=path.name)
  assert set(lv.tags) == {layer} and lv.num_bodies == len(lv.tags[layer])
  assert bodies is None or lv.num_bodies == bodies
  assert lv.num_bodies < tiles  # Merged into rectangles.
  assert np.all(np.isinf(lv.mass)) and not lv.sensor.any()
  _assert_covers_exactly(lv, layer, gids)


def test_island_objects_land_where_the_map_puts_them():
  # rpg/island.tmx: 58x47 tiles of 16 px; "Starting Point" is a point (type "start")
  # at (794.667, 471.667) px, "Exit" a 48x48 rectangle at (336, 208), "Resting Spot"
  # 48x16 at (528, 416). One tile is one world unit, y up: y_world = 47 - y_px / 16.
  with pytest.warns(UserWarning, match=DECORATIVE):
    lv = levels.load(EXAMPLES / "rpg" / "island.tmx")
  assert dict(lv.tags) == {"Objects": (0, 1, 2), "Starting Point": (0,), "start": (0,),
                           "Exit": (1,), "exit": (1,), "Resting Spot": (2,), "rest": (2,)}
  start, exit_, rest = 0, 1, 2
  np.testing.assert_allclose(lv.pos[start], [794.667 / 16, 47 - 471.667 / 16], rtol=0, atol=1e-12)
  assert lv.half[start].tolist() == [levels.POINT_HALF] * 2
  assert lv.sensor[start] and lv.category[start] == levels.SENSOR  # A trigger.
  assert lv.pos[exit_].tolist() == [(336 + 24) / 16, 47 - (208 + 24) / 16] == [22.5, 32.5]
  assert lv.half[exit_].tolist() == [1.5, 1.5]
  assert lv.pos[rest].tolist() == [(528 + 24) / 16, 47 - (416 + 8) / 16]
  assert lv.half[rest].tolist() == [1.5, 0.5]
  assert not lv.sensor[[exit_, rest]].any() and np.isinf(lv.mass).all()


def test_sticker_knight_templates_tile_objects_and_right_angle_rotations():
  path = EXAMPLES / "sticker-knight" / "map" / "sandbox2.tmx"
  root = ElementTree.parse(path).getroot()
  objects = {o.get("id"): o for o in root.iter("object")}
  with warnings.catch_warnings():
    warnings.simplefilter("error")  # No tile layers, no near-miss property names.
    lv = levels.load(path)
  # Every object is a body (no layer says solid=false); none is dropped.
  assert lv.num_bodies == len(objects) == 103
  layer_counts = {g.get("name"): len(g.findall("object")) for g in root.iter("objectgroup")}
  assert {k: len(lv.tags[k]) for k in layer_counts} == layer_counts
  height_px = 31 * 32
  # Object 58 instantiates templates/hero.tx (name "hero", type "hero", gid 22, 128x160)
  # at (288, 448): a tile object, whose (x, y) is its bottom-left corner.
  (hero,) = lv.tags["hero"]
  assert objects["58"].get("template") == "templates/hero.tx"
  assert lv.pos[hero].tolist() == [(288 + 64) / 32, (height_px - (448 - 80)) / 32] == [11.0, 19.5]
  assert lv.half[hero].tolist() == [2.0, 2.5]
  assert lv.category[hero] == levels.SOLID and np.isinf(lv.mass[hero])  # "hero" is no "player".
  # Objects 341 and 342 (clouds, gid 6) are turned by -270 degrees, i.e. 90 clockwise,
  # about their bottom-left corners: a w x h tile then spans [x, x + h] x [y, y + w] on
  # screen. They frame the 2560 px wide map: 342 ends at its left edge, 341 starts at
  # its right edge.
  for oid, x0, x1 in (("341", 2560, 2560 + 392), ("342", -352, 0)):
    o = objects[oid]
    assert o.get("rotation") == "-270"
    x, y, w = float(o.get("x")), float(o.get("y")), float(o.get("width"))
    assert x + float(o.get("height")) == x1 and x == x0
    # Found by its exact box among the "background" bodies.
    want_pos = [(x0 + x1) / 2 / 32, (height_px - (y + y + w) / 2) / 32]
    want_half = [(x1 - x0) / 2 / 32, w / 2 / 32]
    bg = list(lv.tags["background"])
    hits = [i for i in bg if lv.pos[i].tolist() == want_pos and lv.half[i].tolist() == want_half]
    assert len(hits) == 1, (oid, want_pos, want_half)
  # Untyped TMX properties are strings: friction "1.00" is read as 1.0.
  assert objects["196"].find("properties/property[@name='friction']").get("value") == "1.00"
  assert set(lv.friction[list(lv.tags["ground"])].tolist()) <= {0.0, 1.0}
  assert (lv.friction == 1.0).sum() == sum(
      1 for o in objects.values()
      for p in o.iter("property") if p.get("name") == "friction" and float(p.get("value")) == 1.0)


@pytest.mark.parametrize("path, orientation", [
    (EXAMPLES / "hexagonal-mini.tmx", "hexagonal"),
    (EXAMPLES / "isometric_grass_and_water.tmx", "isometric"),
])
def test_unsupported_orientations_are_errors_naming_them(path, orientation):
  with pytest.raises(ValueError, match=rf"{path.name}: orientation '{orientation}' is not "
                                       rf"supported: jaxchain reads orthogonal maps only"):
    levels.load(path)


# The rules, on small maps written here.


def _map(objects, width=8, height=8, tile=16, layers=()):
  return {"orientation": "orthogonal", "width": width, "height": height, "tilewidth": tile,
          "tileheight": tile, "tilesets": [],
          "layers": list(layers) + [{"type": "objectgroup", "name": "things",
                                     "objects": objects}]}


def _corners_bbox(x, y, w, h, degrees, tile_object=False):
  """An independent reference: Tiled turns an object clockwise on screen (y down)
  about its origin (top-left of a rectangle, bottom-left of a tile object); the
  corners are turned with float trigonometry, and the box of the turned corners is
  the body's, in world units (tile 16 px, map 8 tiles high, y up)."""
  c, s = math.cos(math.radians(degrees)), math.sin(math.radians(degrees))
  y_top = -h if tile_object else 0.0
  xs, ys = [], []
  for dx, dy in ((0, y_top), (w, y_top), (w, y_top + h), (0, y_top + h)):
    xs.append(x + dx * c - dy * s)
    ys.append(y + dx * s + dy * c)
  x0, x1, y0, y1 = min(xs), max(xs), min(ys), max(ys)
  return [(x0 + x1) / 32, 8 - (y0 + y1) / 32], [(x1 - x0) / 32, (y1 - y0) / 32]


@pytest.mark.parametrize("degrees", [0, 90, 180, 270, -90, -180, -270, 360, 450])
@pytest.mark.parametrize("fields", [{}, {"ellipse": True}, {"gid": 1}])
def test_rotations_by_right_angles_turn_about_the_origin_clockwise(degrees, fields):
  obj = {"id": 1, "name": "slab", "x": 48, "y": 64, "width": 32, "height": 16,
         "rotation": degrees, **fields}
  lv = levels.load_tiled(_map([obj]))
  pos, half = _corners_bbox(48, 64, 32, 16, degrees, tile_object="gid" in fields)
  np.testing.assert_allclose(lv.pos[0], pos, rtol=0, atol=1e-12)
  np.testing.assert_allclose(lv.half[0], half, rtol=0, atol=1e-12)


def test_rotation_examples_by_hand():
  # A 32x16 px rectangle at (48, 64) px: its top-left corner is the pivot.
  cases = {0: ((48, 80), (64, 80)), 90: ((32, 48), (64, 96)), 180: ((16, 48), (48, 64)),
           270: ((48, 64), (32, 64))}  # degrees: ((x0, x1), (y0, y1)) in px, y down.
  for degrees, ((x0, x1), (y0, y1)) in cases.items():
    obj = {"id": 1, "x": 48, "y": 64, "width": 32, "height": 16, "rotation": degrees}
    lv = levels.load_tiled(_map([obj]))
    assert lv.pos[0].tolist() == [(x0 + x1) / 32, 8 - (y0 + y1) / 32], degrees
    assert lv.half[0].tolist() == [(x1 - x0) / 32, (y1 - y0) / 32], degrees


@pytest.mark.parametrize("degrees", [45, -10.4469, 89.999])
def test_other_rotations_are_errors_naming_the_object(degrees):
  obj = {"id": 7, "name": "tilted", "x": 0, "y": 0, "width": 16, "height": 16,
         "rotation": degrees}
  with pytest.raises(ValueError, match=rf"m.tmj, layer 'things', object 7 'tilted': rotation "
                                       rf"{degrees:g} is not supported"):
    levels.load_tiled(_map([obj]), name="m.tmj")


def test_points_are_spawns_or_small_sensors_and_player_objects_are_players():
  objects = [
      {"id": 1, "name": "player", "x": 40, "y": 24, "point": True},
      {"id": 2, "type": "box", "x": 72, "y": 24, "point": True},
      {"id": 3, "name": "checkpoint", "x": 8, "y": 8, "point": True},
      {"id": 4, "class": "player", "x": 0, "y": 96, "width": 16, "height": 32},
      {"id": 5, "name": "lamp", "x": 0, "y": 0, "point": True,
       "properties": [{"name": "solid", "type": "bool", "value": False}]},
  ]
  lv = levels.load_tiled(_map(objects))
  assert lv.num_bodies == 4 and lv.tags["player"] == (0, 3) and lv.tags["box"] == (1,)
  assert lv.pos.tolist() == [[2.5, 6.5], [4.5, 6.5], [0.5, 7.5], [0.5, 1.0]]
  assert lv.half.tolist() == [[0.4, 0.4], [0.45, 0.45], [0.05, 0.05], [0.5, 1.0]]
  assert lv.category.tolist() == [levels.PLAYER, levels.BOX, levels.SENSOR, levels.PLAYER]
  assert lv.mass.tolist() == [1.0, 1.0, math.inf, 1.0]
  assert lv.sensor.tolist() == [False, False, True, False]


def test_tile_layers_are_solid_only_where_marked():
  tiles = [{"firstgid": 1, "name": "t", "tiles": [
      {"id": 1, "properties": [{"name": "solid", "type": "bool", "value": True}]},
      {"id": 2, "properties": [{"name": "solid", "type": "bool", "value": False}]}]}]
  row = {"type": "tilelayer", "width": 4, "height": 1}
  layers = [
      {**row, "name": "plain", "data": [1, 1, 0, 0]},  # Unmarked: decorative.
      {**row, "name": "by_tile", "data": [1, 2, 3, 0]},  # Only tile id 1 (gid 2) says solid.
      {**row, "name": "by_layer", "data": [1, 2, 3, 1],  # Tile id 2 (gid 3) opts out.
       "properties": [{"name": "solid", "type": "bool", "value": True}]},
  ]
  data = {"orientation": "orthogonal", "width": 4, "height": 1, "tilewidth": 8,
          "tileheight": 8, "tilesets": tiles, "layers": layers}
  with warnings.catch_warnings():
    warnings.simplefilter("error")  # The map says `solid`: no migration warning.
    lv = levels.load_tiled(data)
  assert dict(lv.tags) == {"by_tile": (0,), "by_layer": (1, 2)}
  assert lv.pos.tolist() == [[1.5, 0.5], [1.0, 0.5], [3.5, 0.5]]
  assert lv.half.tolist() == [[0.5, 0.5], [1.0, 0.5], [0.5, 0.5]]


def test_a_property_close_to_a_known_one_warns():
  obj = {"id": 2, "name": "ledge", "x": 0, "y": 0, "width": 16, "height": 16,
         "properties": [{"name": "oneway", "type": "bool", "value": True},
                        {"name": "door", "type": "bool", "value": True}]}
  with pytest.warns(UserWarning, match=r"object 2 'ledge': property 'oneway' is not one jaxchain "
                                       r"reads \(ignored\); did you mean 'one_way'\?") as record:
    lv = levels.load_tiled(_map([obj]))
  assert len(record) == 1 and not lv.one_way[0]  # "door" is nobody's typo.


def test_tmx_and_json_forms_of_one_map_give_the_same_level(tmp_path):
  tmx = """<?xml version="1.0" encoding="UTF-8"?>
<map version="1.10" orientation="orthogonal" width="4" height="3" tilewidth="16" tileheight="16"
     infinite="0">
 <properties><property name="gravity" value="0,-5"/></properties>
 <tileset firstgid="1" name="t" tilewidth="16" tileheight="16">
  <tile id="1" type="ledge"><properties>
   <property name="one_way" type="bool" value="true"/></properties></tile>
 </tileset>
 <layer id="1" name="ground" width="4" height="3">
  <properties><property name="solid" type="bool" value="true"/></properties>
  <data encoding="csv">
0,0,0,0,
0,2,2,0,
1,1,1,1
</data>
 </layer>
 <group name="g" offsetx="16">
  <objectgroup name="actors">
   <object id="1" name="hero" type="player" x="0" y="0" width="16" height="16"/>
   <object id="2" name="sun" x="16" y="0" width="32" height="16" rotation="90"><ellipse/></object>
   <object id="3" name="crate" x="0" y="32" width="16" height="16">
    <properties><property name="mass" value="2.5"/></properties></object>
  </objectgroup>
 </group>
</map>
"""
  (tmp_path / "m.tmx").write_text(tmx)
  as_json = levels.tmx_to_json(tmx)
  (tmp_path / "m.tmj").write_text(json.dumps(as_json))
  a, b = levels.load(tmp_path / "m.tmx"), levels.load(tmp_path / "m.tmj")
  for field in ("pos", "half", "mass", "one_way", "sensor", "category", "mask", "friction"):
    np.testing.assert_array_equal(getattr(a, field), getattr(b, field))
  assert dict(a.tags) == dict(b.tags) and a.gravity == (0.0, -5.0)
  # Bodies by the top-left cell of each tile rectangle (the ledge's row is above the
  # ground's), then the objects in order.
  assert a.tags["ledge"] == (0,) and a.one_way[0] and a.tags["ground"] == (0, 1)
  assert a.tags["player"] == (2,) and a.category[2] == levels.PLAYER
  assert a.mass.tolist()[2:] == [1.0, math.inf, 2.5]
  # The ellipse turned 90 degrees about its top-left corner (32, 0) px: x in [16, 32],
  # y in [0, 32] px, i.e. centre (1.5, 2.0) and half (0.5, 1.0) in world units.
  assert a.pos[3].tolist() == [1.5, 2.0] and a.half[3].tolist() == [0.5, 1.0]


def test_template_instances_override_the_template(tmp_path):
  (tmp_path / "t.tsx").write_text('<tileset name="t" tilewidth="16" tileheight="16">'
                                  '<tile id="4" type="crate"/></tileset>')
  (tmp_path / "crate.tx").write_text(
      '<template><tileset firstgid="1" source="t.tsx"/>'
      '<object name="crate" gid="5" width="16" height="16"><properties>'
      '<property name="mass" type="float" value="3"/>'
      '<property name="friction" type="float" value="0.5"/></properties></object></template>')
  (tmp_path / "m.tmx").write_text(
      '<map orientation="orthogonal" width="4" height="4" tilewidth="16" tileheight="16">'
      '<tileset firstgid="10" source="t.tsx"/><objectgroup name="o">'
      '<object id="1" template="crate.tx" x="16" y="32"/>'
      '<object id="2" template="crate.tx" x="32" y="64" width="32">'
      '<properties><property name="mass" type="float" value="7"/></properties></object>'
      '</objectgroup></map>')
  lv = levels.load(tmp_path / "m.tmx")
  assert lv.tags["crate"] == (0, 1)  # The template's name and the tile's class (gid 5 -> 14).
  assert lv.pos.tolist() == [[1.5, 2.5], [3.0, 0.5]] and lv.half.tolist() == [[0.5, 0.5],
                                                                               [1.0, 0.5]]
  assert lv.mass.tolist() == [3.0, 7.0] and lv.friction.tolist() == [0.5, 0.5]
  (tmp_path / "n.tmx").write_text(
      '<map orientation="orthogonal" width="4" height="4" tilewidth="16" tileheight="16">'
      '<objectgroup name="o"><object id="9" template="crate.tx" x="0" y="16"/></objectgroup></map>')
  with pytest.raises(ValueError, match=r"n.tmx, layer 'o', object 9: template 'crate.tx' uses a "
                                       r"tile of a tileset the map does not hold"):
    levels.load(tmp_path / "n.tmx")


def test_shipped_platformer2_loads_as_before_the_solid_rule():
  # Its `ground` layer now says solid=true (its `background` layer already said false):
  # the same 11 bodies as under the old rule, the ground merged into 4 walls and 3
  # one-way ledges, no warning.
  with warnings.catch_warnings():
    warnings.simplefilter("error")
    lv = levels.load("platformer2")
  assert {k: len(v) for k, v in lv.tags.items()} == {
      "ground": 7, "ledge": 3, "actors": 4, "hero": 1, "player": 1, "crate": 2, "box": 2,
      "flag": 1}
  ground = list(lv.tags["ground"])
  assert lv.one_way[ground].sum() == 3 and lv.bounds == (0.0, 0.0, 16.0, 10.0)


SHAPED_TSX = ('<tileset name="t" tilewidth="16" tileheight="16" tilecount="4" columns="4">'
              '<tile id="1"><properties><property name="solid" type="bool" value="true"/>'
              '</properties><objectgroup draworder="index"><object id="1" x="0" y="8" width="16"'
              ' height="8"><properties><property name="friction" type="float" value="9"/>'
              '</properties></object></objectgroup></tile>'
              '<tile id="2"><objectgroup><object id="1" x="0" y="0"><polygon points="0,0 16,16 '
              '0,16"/></object></objectgroup></tile></tileset>')


def test_tiles_with_collision_shapes_warn_that_the_shapes_are_ignored(tmp_path):
  """Shapes drawn on tiles in Tiled's collision editor are not read: each solid tile is
  a full cell (a tile object its box). A map that makes bodies of such tiles warns,
  naming them; the shapes' own properties are not the tile's."""
  (tmp_path / "t.tsx").write_text(SHAPED_TSX)
  embedded = SHAPED_TSX.replace('<tileset name="t"', '<tileset firstgid="1" name="t"')

  def tmx(tileset, layer, objects=""):
    return ('<map orientation="orthogonal" width="3" height="1" tilewidth="16" '
            f'tileheight="16">{tileset}<layer name="ground" width="3" height="1">'
            f'<data encoding="csv">{layer}</data></layer>'
            f'<objectgroup name="things">{objects}</objectgroup></map>')

  shaped = r"shape.tmx: tileset 't(\.tsx)?' tile 1 has collision shapes \(drawn in Tiled's "
  for tileset in ('<tileset firstgid="1" source="t.tsx"/>', embedded):
    (tmp_path / "shape.tmx").write_text(tmx(tileset, "2,2,0"))
    with pytest.warns(UserWarning, match=shaped + r"collision editor\), which jaxchain ignores: "
                                              r"a solid tile is its full cell, a tile object "
                                              r"its box"):
      lv = levels.load(tmp_path / "shape.tmx")
    assert lv.pos.tolist() == [[1.0, 0.5]] and lv.half.tolist() == [[1.0, 0.5]]  # Full cells.
    assert lv.friction.tolist() == [0.0]  # Not the shape object's friction.
    # A tile object of a shaped tile warns too (tile 2: not solid in a tile layer).
    (tmp_path / "shape.tmx").write_text(tmx(tileset, "0,3,0", '<object id="5" gid="3" x="0" '
                                                               'y="16" width="16" height="16"/>'))
    with pytest.warns(UserWarning, match=r"shape.tmx: tileset 't(\.tsx)?' tile 2 has collision"):
      assert levels.load(tmp_path / "shape.tmx").num_bodies == 1
    # Shaped tiles that make no body: no warning.
    (tmp_path / "shape.tmx").write_text(tmx(tileset, "0,3,1"))
    with warnings.catch_warnings():
      warnings.simplefilter("error")
      assert levels.load(tmp_path / "shape.tmx").num_bodies == 0
  # The JSON forms: an embedded tileset and an external .tsj.
  data = {"orientation": "orthogonal", "width": 2, "height": 1, "tilewidth": 16,
          "tileheight": 16, "tilesets": [{"firstgid": 1, "name": "j", "tiles": [
              {"id": 0, "objectgroup": {"objects": [{"id": 1, "x": 0, "y": 0, "width": 16,
                                                     "height": 4}]}}]}],
          "layers": [{"type": "tilelayer", "name": "g", "data": [1, 1], "properties": [
              {"name": "solid", "type": "bool", "value": True}]}]}
  with pytest.warns(UserWarning, match=r"<tiled>: tileset 'j' tile 0 has collision shapes"):
    assert levels.load_tiled(data).half.tolist() == [[1.0, 0.5]]
  (tmp_path / "j.tsj").write_text(json.dumps(data["tilesets"][0]))
  data["tilesets"] = [{"firstgid": 1, "source": "j.tsj"}]
  with pytest.warns(UserWarning, match=r"<tiled>: tileset 'j.tsj' tile 0 has collision shapes"):
    levels.load_tiled(data, base=tmp_path)
