"""Levels: ASCII (Sokoban XSB and platformer characters) and Tiled JSON maps."""

import codecs
import collections
import doctest
import json
import math
import pathlib

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

import jaxchain as jc
from jaxchain import levels

DATA = pathlib.Path(__file__).parent / "data" / "levels"
INF = math.inf


def _rows(level, tag):
  """`[x0, y0, x1, y1]` rows of the bodies carrying `tag`, in body order."""
  idx = list(level.tags[tag])
  return np.concatenate([level.pos[idx] - level.half[idx], level.pos[idx] + level.half[idx]], 1)


def _tiled(path):
  return json.loads((DATA / path).read_text())


# ASCII maps.


def test_xsb_characters_make_the_documented_bodies():
  lv = levels.parse_ascii("#@$.*+#")
  assert lv.num_bodies == len(lv) == 9
  # Reading order; `*` is a box then a goal, `+` a player then a goal.
  assert dict(lv.tags) == {"wall": (0, 8), "player": (1, 6), "box": (2, 4), "goal": (3, 5, 7)}
  np.testing.assert_array_equal(lv.pos[:, 1], np.full(9, 0.5))
  np.testing.assert_array_equal(lv.pos[:, 0], [0.5, 1.5, 2.5, 3.5, 4.5, 4.5, 5.5, 5.5, 6.5])
  np.testing.assert_array_equal(lv.half[[1, 2, 3]], [[0.4, 0.4], [0.45, 0.45], [0.05, 0.05]])
  np.testing.assert_array_equal(lv.mass, [INF, 1, 1, INF, 1, INF, 1, INF, INF])
  np.testing.assert_array_equal(lv.sensor, [False, False, False, True, False, True, False, True,
                                            False])
  assert lv.category.dtype == lv.mask.dtype == np.uint32
  np.testing.assert_array_equal(lv.category[[0, 1, 2, 3]],
                                [levels.SOLID, levels.PLAYER, levels.BOX, levels.SENSOR])
  # A goal admits only boxes; everything else interacts with everything.
  np.testing.assert_array_equal(lv.mask[[3, 5, 7]], [levels.BOX] * 3)
  np.testing.assert_array_equal(lv.mask[[0, 1, 2, 4, 6, 8]], [levels.ALL] * 6)
  assert not lv.one_way.any() and not lv.vel.any() and not lv.friction.any()
  assert lv.bounds == (0.0, 0.0, 7.0, 1.0)


def test_xsb_floor_variants_and_letter_variants():
  a = levels.parse_ascii("#@ $.#\n#    #")
  for text in ("#@-$.#\n#____#", "#p b.#\n#    #"):
    b = levels.parse_ascii(text)
    np.testing.assert_array_equal(a.pos, b.pos)
    assert dict(a.tags) == dict(b.tags)
  assert dict(levels.parse_ascii("#P B#").tags) == dict(levels.parse_ascii("#+ *#").tags)


def test_y_points_up_and_cells_are_unit_squares():
  lv = levels.parse_ascii("$  \n   \n  @")
  # Row r from the top, column c: centre (c + 0.5, H - 1 - r + 0.5).
  assert lv.pos[lv.tags["box"][0]].tolist() == [0.5, 2.5]
  assert lv.pos[lv.player].tolist() == [2.5, 0.5]
  assert lv.bounds == (0.0, 0.0, 3.0, 3.0)


def test_walls_merge_into_few_rectangles():
  text = ("#######\n"
          "#     #\n"
          "# ### #\n"
          "#     #\n"
          "#######")
  lv = levels.parse_ascii(text)
  assert text.count("#") == 23 and lv.num_bodies == 5
  assert lv.tags["wall"] == (0, 1, 2, 3, 4)
  # [x0, y0, x1, y1]: top row, left and right columns, the inner bar, bottom row.
  np.testing.assert_array_equal(_rows(lv, "wall"), [[0, 4, 7, 5], [0, 1, 1, 4], [6, 1, 7, 4],
                                                    [2, 2, 5, 3], [0, 0, 7, 1]])


def test_a_floor_is_one_body_without_seams():
  lv = levels.parse_ascii("#" * 40 + "\n" + "#" * 40)
  assert lv.num_bodies == 1
  np.testing.assert_array_equal(_rows(lv, "wall"), [[0, 0, 40, 2]])


@given(st.lists(st.lists(st.booleans(), min_size=6, max_size=6), min_size=1, max_size=6),
       st.booleans())
def test_rectangles_cover_each_cell_exactly_once(cells, vertical):
  cells = np.array(cells)
  count = np.zeros(cells.shape, int)
  rects = levels.rectangles(cells, vertical=vertical)
  for r0, c0, r1, c1 in rects:
    count[r0:r1 + 1, c0:c1 + 1] += 1
    if not vertical:
      assert r0 == r1
  np.testing.assert_array_equal(count, cells.astype(int))
  assert rects == sorted(rects)
  # Never more rectangles than horizontal runs.
  runs = sum(int(np.sum(np.diff(np.concatenate([[0], row, [0]])) == 1)) for row in cells.astype(int))
  assert len(rects) <= runs


def test_one_way_platforms_are_top_slabs_merged_along_rows_only():
  lv = levels.parse_ascii("====\n ===\n----")
  assert lv.tags["platform"] == (0, 1) and lv.one_way.all()
  # A slab SLAB = 0.25 thick at the top of its cells; rows never merge.
  np.testing.assert_array_equal(_rows(lv, "platform"), [[0, 2.75, 4, 3], [1, 1.75, 4, 2]])
  assert (lv.mass == INF).all() and (lv.category == levels.SOLID).all()


def test_kinematic_platforms_merge_runs_of_one_direction():
  lv = levels.parse_ascii(">>><<\n^^ vv")
  assert lv.tags["kinematic"] == (0, 1, 2, 3)
  np.testing.assert_array_equal(lv.vel, [[1, 0], [-1, 0], [0, 1], [0, -1]])
  np.testing.assert_array_equal(_rows(lv, "kinematic"), [[0, 1, 3, 2], [3, 1, 5, 2], [0, 0, 2, 1],
                                                         [3, 0, 5, 1]])
  assert (lv.mass == INF).all() and not lv.one_way.any()


def test_heavy_boxes_flags_and_hazards():
  lv = levels.parse_ascii("H F XXX")
  assert dict(lv.tags) == {"box": (0,), "heavy": (0,), "flag": (1,), "hazard": (2,)}
  assert lv.mass[0] == 10 and lv.category[0] == levels.BOX
  assert lv.sensor[1:].all() and (lv.mask[1:] == levels.PLAYER).all()
  # A flag is a full cell; hazard runs merge.
  np.testing.assert_array_equal(_rows(lv, "flag"), [[2, 0, 3, 1]])
  np.testing.assert_array_equal(_rows(lv, "hazard"), [[4, 0, 7, 1]])


def test_legend_adds_and_overrides_characters():
  ice = levels.Tile(tags=("wall", "ice"), friction=0.0, merge="rect")
  crate = levels.Tile(tags="box", mass=2.0, half=(0.5, 0.5), friction=0.7, category=levels.BOX)
  lv = levels.parse_ascii("#WW$o#", legend={"W": levels.WALL, "$": crate, "o": None})
  # "W" makes the same tile as "#", so the run #WW merges into one wall.
  np.testing.assert_array_equal(_rows(lv, "wall"), [[0, 0, 3, 1], [5, 0, 6, 1]])
  assert lv.mass[1] == 2 and lv.friction[1] == pytest.approx(0.7) and lv.half[1].tolist() == [0.5, 0.5]
  lv = levels.parse_ascii("#I#", legend={"I": ice})
  assert dict(lv.tags) == {"wall": (0, 1, 2), "ice": (1,)}  # Different tiles never merge.
  spring = levels.Tile(tags="spring", half=(0.5, 0.1), offset=(0.0, -0.4))
  lv = levels.parse_ascii("s", legend={"s": spring})
  np.testing.assert_allclose(_rows(lv, "spring"), [[0, 0, 1, 0.2]], atol=1e-12)


@pytest.mark.parametrize("legend, match", [
    ({"ab": levels.WALL}, "single characters"),
    ({"Q": "#"}, "must map to a Tile"),
    ([("Q", levels.WALL)], "expected a dict"),
])
def test_bad_legends_are_errors(legend, match):
  with pytest.raises(ValueError, match=match):
    levels.parse_ascii("#", legend=legend)


@pytest.mark.parametrize("kwargs, match", [
    (dict(mass=0.0), "mass must be > 0"),
    (dict(half=(0.5, 0.0)), "half-extents must be > 0"),
    (dict(half=(0.5,)), "half must be two finite numbers"),
    (dict(friction=-1.0), "friction must be finite and >= 0"),
    (dict(category=-1), r"category must be an int in \[0, 2\*\*32\)"),
    (dict(mask=1 << 32), r"mask must be an int in \[0, 2\*\*32\)"),
    (dict(merge="col"), "merge must be one of"),
    (dict(mass=1.0, merge="rect"), "only immovable tiles"),
    (dict(tags=("",)), "non-empty strings"),
])
def test_bad_tiles_are_errors(kwargs, match):
  with pytest.raises(ValueError, match=match):
    levels.Tile(**kwargs)


def test_comments_blank_edges_and_crlf():
  text = "; a title\r\n\r\n#@ #\r\n#  #\r\n\r\n; 2\r\n"
  lv = levels.parse_ascii(text)
  assert lv.bounds == (0.0, 0.0, 4.0, 2.0) and lv.pos[lv.player].tolist() == [1.5, 1.5]
  # Errors count physical lines, comments and blank lines included.
  with pytest.raises(ValueError, match="line 4, column 2: unknown character '\\?'"):
    levels.parse_ascii("; title\n\n#@ #\n#? #")


def test_ragged_xsb_lines_are_padded_when_they_end_in_a_wall():
  text = ("    #####\n"
          "    #   #\n"
          "  ###$  #\n"
          "  #  @ ##\n"
          "  #####")
  lv = levels.parse_ascii(text)
  assert lv.bounds == (0.0, 0.0, 9.0, 5.0)
  rect = levels.parse_ascii("\n".join(line.ljust(9) for line in text.split("\n")))
  np.testing.assert_array_equal(lv.pos, rect.pos)
  np.testing.assert_array_equal(lv.half, rect.half)
  with pytest.raises(ValueError, match=r"line 5 is ragged: 7 columns, but line 1 has 9 \(strict"):
    levels.parse_ascii(text, strict=True)
  levels.parse_ascii("\n".join(line.ljust(9) for line in text.split("\n")), strict=True)


@pytest.mark.parametrize("text, match", [
    ("#  #\n# $\n#  #", "line 2 is ragged: .*does not end in a wall"),  # Truncated row.
    ("#  #\n#  \n#  #", "line 2 is ragged"),  # Only the left wall.
    ("####\n#@ #\n\n####", "line 3 is ragged"),  # A blank line inside the map.
    ("####\n#@ #\n#  \n####", "line 3 is ragged"),  # Trailing floor but no wall.
])
def test_ragged_lines_that_could_hide_cells_are_errors(text, match):
  with pytest.raises(ValueError, match=match):
    levels.parse_ascii(text)


@pytest.mark.parametrize("text, match", [
    ("#@#\n#?#", r"<ascii>: line 2, column 2: unknown character '\?'"),
    ("#@\t#", "line 1, column 3: tab character"),
    ("#@3#", "line 1, column 3: unknown character '3'"),  # Run-length encoded XSB.
    ("", "no map rows"),
    ("  \n\n", "no map rows"),
    ("; only a title\n", "no map rows"),
])
def test_malformed_ascii_is_an_error_naming_line_and_column(text, match):
  with pytest.raises(ValueError, match=match):
    levels.parse_ascii(text)


def test_player_and_indices():
  lv = levels.parse_ascii("#@$$.#")
  assert lv.player == 1
  assert lv.indices("box").tolist() == [2, 3] and lv.indices("nothing").tolist() == []
  assert lv.indices("goal", "box").tolist() == [2, 3, 4]
  with pytest.raises(ValueError, match="expected one body tagged 'player', found 0"):
    levels.parse_ascii("#$#").player
  with pytest.raises(ValueError, match="found 2"):
    levels.parse_ascii("@@").player


def test_levels_are_immutable():
  lv = levels.parse_ascii("#@$#")
  with pytest.raises(ValueError):
    lv.pos[0, 0] = 3.0
  with pytest.raises(AttributeError):
    lv.name = "x"
  with pytest.raises(TypeError):
    lv.tags["box"] = (0,)
  assert repr(lv) == "Level('', 4 bodies, tags {wall: 2, player: 1, box: 1})"


# Tiled JSON maps.

# room_csv.tmj: walls of 28 tiles, one-way ledges in the "platforms" layer (friction 0.5),
# a decorative layer (solid false) and four objects.
ROOM_WALLS = [[0, 5, 8, 6], [0, 1, 1, 5], [7, 1, 8, 5], [3, 1, 5, 3], [0, 0, 8, 1]]
ROOM_LEDGES = [[5, 4.75, 7, 5], [1, 3.75, 3, 4], [5, 3.75, 7, 4]]


def test_tiled_tile_layers_merge_into_rectangles():
  lv = levels.load(DATA / "room_csv.tmj")
  assert lv.name == "room_csv" and lv.bounds == (0.0, 0.0, 8.0, 6.0)
  assert sum(g == 1 for g in _tiled("room_csv.tmj")["layers"][0]["data"]) == 28
  assert lv.tags["walls"] == (0, 1, 2, 3, 4)
  np.testing.assert_array_equal(_rows(lv, "walls"), ROOM_WALLS)
  # One-way tiles: slabs at the top of their tiles, rows not merged (no "decor" bodies).
  assert lv.tags["platforms"] == (5, 6, 7)
  np.testing.assert_array_equal(_rows(lv, "platforms"), ROOM_LEDGES)
  assert lv.one_way[5:8].all() and not lv.one_way[:5].any()
  np.testing.assert_array_equal(lv.friction[:8], [0] * 5 + [0.5] * 3)
  assert (lv.mass[:8] == INF).all() and (lv.category[:8] == levels.SOLID).all()
  assert "decor" not in lv.tags and lv.num_bodies == 12


def test_tiled_objects_become_bodies_with_their_properties():
  lv = levels.load(DATA / "room_csv.tmj")
  hero, crate, goal, lift = lv.tags["actors"]
  assert (lv.player, lv.tags["box"], lv.tags["goal"], lv.tags["kinematic"]) == (
      hero, (crate,), (goal,), (lift,))
  assert lv.tags["hero"] == (hero,) and lv.tags["crate"] == (crate,)
  np.testing.assert_array_equal(lv.pos[[hero, crate, goal, lift]],
                                [[1.5, 1.375], [5.5, 1.5], [6.5, 1.5], [3, 3.375]])
  np.testing.assert_array_equal(lv.half[[hero, crate, goal, lift]],
                                [[0.375, 0.375], [0.5, 0.5], [0.5, 0.5], [1, 0.125]])
  np.testing.assert_array_equal(lv.mass[[hero, crate, goal, lift]], [1, 2.5, INF, INF])
  assert lv.friction[crate] == 0.4
  assert lv.category[hero] == levels.PLAYER and lv.mask[hero] == levels.ALL
  assert lv.category[crate] == levels.BOX and lv.mask[crate] == 5
  assert lv.sensor[goal] and lv.category[goal] == levels.SENSOR and lv.mask[goal] == levels.BOX
  assert lv.one_way[lift] and lv.vel[lift].tolist() == [0, 1]
  assert not lv.vel[[hero, crate, goal]].any()


@pytest.mark.parametrize("name", ["room_base64", "room_zlib", "room_gzip", "room_flipped"])
def test_tiled_encodings_and_flip_bits_give_the_same_level(name):
  data = _tiled(f"{name}.tmj")
  layer = data["layers"][0]
  if name == "room_flipped":
    assert {g & levels.FLIP_BITS for g in layer["data"]} == {
        0, 0x80000000, 0x40000000, 0x20000000, 0x10000000, 0xA0000000, 0xF0000000}
  else:
    assert layer["encoding"] == "base64" and layer.get("compression", "") == {
        "room_base64": "", "room_zlib": "zlib", "room_gzip": "gzip"}[name]
  ref, lv = levels.load(DATA / "room_csv.tmj"), levels.load(DATA / f"{name}.tmj")
  for field in ("pos", "half", "mass", "vel", "friction", "one_way", "sensor", "category", "mask"):
    np.testing.assert_array_equal(getattr(lv, field), getattr(ref, field), err_msg=field)
  assert dict(lv.tags) == dict(ref.tags)


def test_tiled_groups_units_tile_objects_and_map_properties():
  lv = levels.load(DATA / "objects.tmj")
  # unit = 8 pixels: a 16-pixel tile is 2 units; gravity from the map property.
  assert lv.bounds == (0.0, 0.0, 8.0, 8.0) and lv.gravity == (0.0, -20.0)
  assert dict(lv.tags) == {"movers/belts": (0,), "belt": (0,), "things": (1, 2), "crate": (1,),
                           "anchor": (2,), "heavy": (2,), "static": (2,)}  # "ghost" is solid=false.
  # The group's offset (16 px) moves the belt; its friction is inherited; vx alone sets vel.
  np.testing.assert_array_equal(_rows(lv, "belt"), [[2, 0, 6, 2]])
  assert lv.friction[0] == 0.25 and lv.vel[0].tolist() == [2, 0] and lv.mass[0] == INF
  # A tile object (flipped GID) sits above its (x, y) and takes its tile's properties.
  np.testing.assert_array_equal(_rows(lv, "crate"), [[0, 4, 2, 6]])
  assert lv.mass[1] == 3 and lv.category[1] == levels.BOX
  assert lv.mass[2] == INF and lv.friction[2] == 0


@pytest.mark.parametrize("ext", ["tsx", "tsj"])
def test_tiled_external_tilesets_give_tile_properties(ext):
  lv = levels.load(DATA / f"external_{ext}.tmj")
  # Tile 1 is a one-way ledge (class "ledge"), tile 2 is solid=false, tile 0 plain.
  assert dict(lv.tags) == {"ground": (0, 1), "ledge": (0,)}
  np.testing.assert_array_equal(_rows(lv, "ground"), [[1, 1.75, 3, 2], [0, 0, 4, 1]])
  assert lv.one_way.tolist() == [True, False]


def test_tiled_tile_properties_are_found_through_flip_bits():
  data = {"orientation": "orthogonal", "width": 3, "height": 1, "tilewidth": 8, "tileheight": 8,
          "tilesets": [{"firstgid": 5, "name": "t", "tiles": [
              {"id": 1, "type": "spike", "properties": [
                  {"name": "sensor", "type": "bool", "value": True},
                  {"name": "mask", "type": "string", "value": "player|box"}]}]}],
          "layers": [{"type": "tilelayer", "name": "hazards", "properties": {"solid": True},
                      "data": [6 | 0x80000000, 6 | 0x20000000, 5]}]}
  lv = levels.load_tiled(data)
  assert dict(lv.tags) == {"hazards": (0, 1), "spike": (0,)}
  np.testing.assert_array_equal(_rows(lv, "spike"), [[0, 0, 2, 1]])
  assert lv.sensor.tolist() == [True, False]
  assert lv.mask.tolist() == [levels.PLAYER | levels.BOX, levels.ALL]
  assert lv.category.tolist() == [levels.SENSOR, levels.SOLID]


def _map(objects=None, layer=None, **top):
  data = {"orientation": "orthogonal", "width": 2, "height": 2, "tilewidth": 16,
          "tileheight": 16, "tilesets": [], "layers": []}
  if layer is not None:
    data["layers"].append({"type": "tilelayer", "name": "ground", "id": 1, "width": 2,
                           "height": 2, "data": [0, 0, 1, 1],
                           "properties": [{"name": "solid", "value": True}], **layer})
  if objects is not None:
    data["layers"].append({"type": "objectgroup", "name": "things", "id": 2, "objects": objects})
  data.update(top)
  return data


def _obj(props=None, **fields):
  obj = {"id": 3, "name": "crate", "x": 0, "y": 0, "width": 16, "height": 16, **fields}
  if props is not None:
    obj["properties"] = [{"name": k, "value": v} for k, v in props.items()]
  return obj


def test_tiled_group_properties_reach_objects_and_tile_layers_take_no_motion():
  inner = _map([_obj()], layer={"data": [0, 0, 1, 1]})["layers"]
  group = {"type": "group", "name": "g", "layers": inner, "properties": [
      {"name": "mass", "value": 4}, {"name": "friction", "value": 0.5}]}
  lv = levels.load_tiled(_map(layers=[group]))
  assert dict(lv.tags) == {"g/ground": (0,), "g/things": (1,), "crate": (1,)}
  assert lv.mass.tolist() == [INF, 4] and lv.friction.tolist() == [0.5, 0.5]
  # A tile's mass applies to tile objects only; in a tile layer the tile stays immovable.
  tiles = [{"firstgid": 1, "name": "t", "tiles": [{"id": 0, "properties": [
      {"name": "mass", "value": 2}, {"name": "velocity", "value": "1,0"}]}]}]
  lv = levels.load_tiled(_map([_obj(gid=1, y=32)], layer={}, tilesets=tiles))
  assert lv.mass.tolist() == [INF, 2] and lv.vel.tolist() == [[0, 0], [1, 0]]


def test_tiled_old_style_property_dicts_and_csv_strings():
  lv = levels.load_tiled(_map([{**_obj(), "properties": {"mass": 2, "sensor": False}}],
                              layer={"data": "0,0,\n1,1"}))
  assert lv.mass.tolist() == [INF, 2] and lv.num_bodies == 2


@pytest.mark.parametrize("path, match", [
    ("room_zstd.tmj", r"room_zstd.tmj, layer 'walls': zstd compression is not supported"),
    ("infinite.tmj", r"infinite.tmj: infinite maps are not supported"),
    ("isometric.tmj", r"isometric.tmj: orientation 'isometric' is not supported"),
    ("bad_property.tmj", r"bad_property.tmj, layer 'crates', object 7 'big crate': property "
                         r"'mass': expected a number > 0, or 'inf' for immovable, got 'heavy'"),
])
def test_tiled_fixtures_with_unsupported_or_malformed_input(path, match):
  with pytest.raises(ValueError, match=match):
    levels.load(DATA / path)


@pytest.mark.parametrize("data, match", [
    (_map([_obj({"category": -1})]),
     r"layer 'things', object 3 'crate': property 'category': expected an int in \[0, 2\*\*32\)"),
    (_map([_obj({"mask": True})]), r"object 3 'crate': property 'mask': .*got True"),
    (_map([_obj({"mask": "player|ghost"})]), r"property 'mask': .*got 'player\|ghost'"),
    (_map([_obj({"one_way": "yes"})]), r"property 'one_way': expected a bool"),
    (_map([_obj({"friction": -0.5})]), r"property 'friction': expected a number >= 0"),
    (_map([_obj({"friction": "icy"})]), r"property 'friction': expected a finite number"),
    (_map([_obj({"velocity": "fast"})]), r"property 'velocity': expected a string 'x,y'"),
    (_map([_obj({"vy": "up"})]), r"property 'vy': expected a finite number"),
    (_map([_obj({"mass": -1})]), r"property 'mass': expected a number > 0"),
    (_map([_obj({"tag": 3})]), r"property 'tag': expected a string"),
    (_map([_obj(polyline=[{"x": 0, "y": 0}])]), r"object 3 'crate': polyline objects are not "
                                                r"supported"),
    (_map([_obj(text={"text": "hi"})]), r"text objects are not supported"),
    (_map([_obj(polygon=[{"x": 0, "y": 0}])]), r"polygon objects are not supported"),
    (_map([_obj(rotation=45)]), r"object 3 'crate': rotation 45 is not supported: .* multiples "
                                r"of 90"),
    (_map([_obj(width=0)]), r"object 3 'crate': size 0x16"),
    (_map([_obj(template="crate.tx")]), r"object 3 'crate': template 'crate.tx' cannot be found "
                                        r"without the map's directory"),
    (_map(layer={"data": [1, 1, 1]}), r"layer 'ground': tile data has 3 tiles, expected 2x2 = 4"),
    (_map(layer={"data": [1, 1, 1, -1]}), r"layer 'ground': tile data holds a GID outside"),
    (_map(layer={"data": [1, 1, 1, 1.5]}), r"layer 'ground': tile data must be an array"),
    (_map(layer={"encoding": "base64", "data": "!!!"}), r"layer 'ground': tile data is not valid "
                                                       r"base64"),
    (_map(layer={"encoding": "base64", "data": "AAAA", "compression": "lz4"}),
     r"unknown compression 'lz4'"),
    (_map(layer={"encoding": "base64", "data": "AAAA", "compression": "zlib"}),
     r"does not decompress as zlib"),
    (_map(layer={"encoding": "xml"}), r"unknown encoding 'xml'"),
    (_map(layer={"chunks": [], "data": None}), r"layer 'ground': chunked tile data"),
    (_map(layer={"width": 3}), r"layer 'ground': layer size 3x2 differs from the map's 2x2"),
    (_map(layer={"properties": [{"name": "mass", "value": 2}]}),
     r"layer 'ground': property 'mass': tile layers are immovable"),
    (_map(layer={"type": "portal"}), r"layer 'ground': unknown layer type 'portal'"),
    (_map(orientation="hexagonal"), r"orientation 'hexagonal' is not supported"),
    (_map(orientation="staggered"), r"orientation 'staggered' is not supported"),
    (_map(tilewidth=0), r"'tilewidth' must be an int >= 1, got 0"),
    (_map(properties=[{"name": "unit", "value": 0}]), r"map properties: property 'unit'"),
    (_map(tilesets=[{"firstgid": 1, "source": "missing.tsx"}]),
     r"tileset 'missing.tsx': external tileset 'missing.tsx' cannot be found"),
    (_map(tilesets=[{"firstgid": 1, "name": "t", "tiles": [
        {"id": 0, "properties": [{"name": "one_way", "value": 1}]}]}]),
     r"tileset 't', tile 0: property 'one_way': expected a bool"),
    # Issue 18: these raised TypeError, or loaded a body that World.create then blamed on
    # its half-extents, naming neither layer nor object.
    (_map(tilesets=[{"firstgid": 1, "name": "t", "tiles": 5}]),
     r"m.tmj, tileset 't': 'tiles' must be an array, got 5"),
    (_map(tilesets=[{"firstgid": 1, "source": 7}]), r"'source' .* must be a string, got 7"),
    (_map([{**_obj(), "properties": [{"name": ["mass"], "value": 1}]}]),
     r"layer 'things', object 3 'crate': property 0: a property name must be a string, got "
     r"\['mass'\]"),
    (_map([{**_obj(), "properties": {("mass",): 1}}]), r"property 0: a property name must be a "
                                                      r"string"),
    (_map(layers=[{"type": "group", "name": "g", "layers": 5}]),
     r"layer 'g': 'layers' must be an array, got 5"),
    (_map([_obj(name=["crate"])]), r"layer 'things', object 3: 'name' must be a string"),
    (_map([_obj(type={"a": 1})]), r"object 3 'crate': 'type' must be a string"),
    (_map([_obj(**{"class": 2.5})]), r"object 3 'crate': 'class' must be a string, got 2.5"),
    (_map(layers=[{"type": "objectgroup", "name": None, "objects": []},
                  {"type": "objectgroup", "name": ["x"], "objects": []}]),
     r"layer 1: 'name' must be a string"),
    (_map(tilesets=[{"firstgid": 1, "name": "t", "tiles": [{"id": 0, "type": [1]}]}]),
     r"tileset 't', tile 0: 'class' must be a string"),
    (_map(infinite="maybe"), r"m.tmj: 'infinite' must be a bool \(true or false\), got 'maybe'"),
    (_map(infinite=2), r"'infinite' must be a bool"),
    (_map([_obj({"mass": 1}, x=1e300)]),
     r"layer 'things', object 3 'crate': position \(6.25e\+298, 1.5\) in world units is so far "
     r"from the origin that its size 16x16 px rounds away"),
    (_map([_obj({"mass": 1}, width=1e40)]),
     r"layer 'things', object 3 'crate': position \(3.125e\+38, 1.5\) in world units overflows "
     r"float32"),
    (_map([_obj({"mass": 1}, x=1.7e308, width=1.7e308)]),
     r"object 3 'crate': position .* is not finite"),
    (_map(layer={"offsetx": 1e300}),
     r"layer 'ground', tiles from row 1, column 0: position .* its size 32x16 px rounds away"),
])
def test_tiled_malformed_input_is_an_error_naming_layer_object_and_property(data, match):
  with pytest.raises(ValueError, match=match):
    levels.load_tiled(data, name="m.tmj")


@pytest.mark.parametrize("value, infinite", [
    (False, False), ("false", False), ("False", False), ("0", False), (0, False),
    (True, True), ("true", True), ("TRUE", True), ("1", True), (1, True)])
def test_tiled_infinite_accepts_json_tmx_and_string_bools(value, infinite):
  data = _map([_obj({"mass": 1})], infinite=value)
  if infinite:
    with pytest.raises(ValueError, match=r"m.tmj: infinite maps are not supported"):
      levels.load_tiled(data, name="m.tmj")
  else:
    assert levels.load_tiled(data, name="m.tmj").num_bodies == 1


def test_tiled_names_and_classes_are_string_tags():
  group = {"type": "group", "name": 4, "layers": [
      {"type": "objectgroup", "name": 5, "objects": [_obj(name=7, type=8), _obj(name="")]}]}
  lv = levels.load_tiled(_map(layers=[group]))
  assert dict(lv.tags) == {"4/5": (0, 1), "7": (0,), "8": (0,)}
  assert all(isinstance(t, str) for t in lv.tags)


@pytest.mark.parametrize("fields, props", [
    (dict(type="player"), None), (dict(name="box"), None), ({"class": "box"}, None),
    (dict(name="hero"), {"tag": "player"}), (dict(name="hero", type="player"), {"friction": 0.5})])
def test_tiled_players_and_boxes_without_mass_default_to_mass_one(fields, props):
  lv = levels.load_tiled(_map([_obj(props, **fields)]))
  assert lv.mass.tolist() == [levels.DEFAULT_MASS] == [1.0]
  assert lv.world().inv_mass.tolist() == [1.0]  # Movable: not a wall.


@pytest.mark.parametrize("fields, props, mass", [
    (dict(type="player"), {"mass": "inf"}, INF),  # An explicit mass wins.
    (dict(type="box"), {"mass": 3}, 3.0),
    (dict(type="box"), {"sensor": True}, INF),  # A sensor tagged box is still a sensor.
    (dict(name="crate"), None, INF),  # Untagged: immovable, as before.
    (dict(name="boxes"), None, INF)])  # Tags match whole names.
def test_tiled_mass_rule_for_other_objects(fields, props, mass):
  assert levels.load_tiled(_map([_obj(props, **fields)])).mass.tolist() == [mass]


def test_tiled_tile_object_of_a_box_tile_defaults_to_mass_one():
  tiles = [{"firstgid": 1, "name": "t", "tiles": [{"id": 0, "class": "box"}]}]
  lv = levels.load_tiled(_map([_obj(gid=1, y=16)], tilesets=tiles))
  assert lv.mass.tolist() == [1.0] and lv.tags["box"] == (0,)


def test_tiled_missing_external_tileset_file(tmp_path):
  data = _map(tilesets=[{"firstgid": 1, "source": "gone.tsx"}])
  (tmp_path / "m.tmj").write_text(json.dumps(data))
  with pytest.raises(ValueError, match=r"m.tmj, tileset 'gone.tsx': external tileset 'gone.tsx' "
                                       r"cannot be read"):
    levels.load(tmp_path / "m.tmj")


# Files and shipped levels.


def test_load_picks_the_format_by_extension(tmp_path):
  (tmp_path / "a.txt").write_text("#@ $#\n")
  (tmp_path / "a.xsb").write_text("#@ $#\n")
  (tmp_path / "a.json").write_text(json.dumps(_map([_obj({"mass": 1})])))
  txt, xsb, tiled = (levels.load(tmp_path / f"a.{e}") for e in ("txt", "xsb", "json"))
  np.testing.assert_array_equal(txt.pos, xsb.pos)
  assert (txt.gravity, xsb.gravity, tiled.gravity) == ((0, -9.81), (0, 0), (0, -9.81))
  assert levels.load(tmp_path / "a.xsb", gravity=(0, -1)).gravity == (0, -1)
  assert txt.name == "a" and tiled.mass.tolist() == [1.0]
  (tmp_path / "b.txt").write_text("#@\n#?#\n")
  with pytest.raises(ValueError, match=r"b.txt: line 2, column 2: unknown character"):
    levels.load(tmp_path / "b.txt")
  (tmp_path / "c.txt").write_text("####\n#@ #\n#  \n####\n")
  with pytest.raises(ValueError, match=r"c.txt: line 3 is ragged"):
    levels.load(tmp_path / "c.txt")
  (tmp_path / "d.tmx").write_text("<map/>")
  with pytest.raises(ValueError, match=r"d.tmx: 'width' must be an int >= 1, got None"):
    levels.load(tmp_path / "d.tmx")
  (tmp_path / "d2.tmx").write_text("<map")
  with pytest.raises(ValueError, match=r"d2.tmx: not valid XML"):
    levels.load(tmp_path / "d2.tmx")
  (tmp_path / "d3.png").write_text("")
  with pytest.raises(ValueError, match=r"d3.png: unsupported level file extension '.png'"):
    levels.load(tmp_path / "d3.png")
  (tmp_path / "e.tmj").write_text("{not json")
  with pytest.raises(ValueError, match=r"e.tmj: not valid JSON"):
    levels.load(tmp_path / "e.tmj")
  with pytest.raises(FileNotFoundError, match="no level file"):
    levels.load(tmp_path / "none.txt")


def _same_level(a, b, names=True):
  assert (dict(a.tags), a.bounds, a.gravity) == (dict(b.tags), b.bounds, b.gravity)
  assert a.name == b.name or not names
  for field in ("pos", "half", "mass", "vel", "friction", "one_way", "sensor", "category",
                "mask"):
    np.testing.assert_array_equal(getattr(a, field), getattr(b, field), err_msg=field)


BOM = codecs.BOM_UTF8


def test_a_byte_order_mark_is_not_part_of_the_level(tmp_path):
  """Files saved "UTF-8 with BOM", with CRLF line ends, as editors on Windows save them,
  load as without the mark: a collection that starts with a map keeps that map's top
  wall row (not a title '\ufeff#####' and a room open at the top), and a one-map .xsb,
  a .txt, a .tmj, a .tmx, their external tilesets and templates load."""
  rooms = "#####\r\n#@$.#\r\n#####\r\n\r\n######\r\n#@ $.#\r\n######\r\n"
  (tmp_path / "c.xsb").write_bytes(BOM + rooms.encode())
  got = levels.load_collection(tmp_path / "c.xsb")
  assert [lv.name for lv in got] == ["c 1", "c 2"]
  assert got[0].bounds == (0, 0, 5, 3) and got[0].num_bodies == 7  # 4 walls, @, $, .
  for a, b in zip(got, levels.parse_xsb_collection(rooms.replace("\r", ""), name="c")):
    _same_level(a, b)
  one = "#####\r\n#@$.#\r\n#####\r\n"
  for name in ("one.xsb", "one.txt"):
    (tmp_path / name).write_bytes(BOM + one.encode())
    (tmp_path / ("plain_" + name)).write_text(one.replace("\r", ""))
    a, b = levels.load(tmp_path / name), levels.load(tmp_path / ("plain_" + name))
    _same_level(a, b, names=False)
    assert a.num_bodies == 7
  _same_level(levels.parse_ascii("\ufeff" + one), levels.parse_ascii(one))
  # Tiled: the map, its external tilesets (.tsx, .tsj) and a template, each with a BOM.
  for ext in ("tsx", "tsj"):
    (tmp_path / f"ledges.{ext}").write_bytes(BOM + (DATA / f"ledges.{ext}").read_bytes())
    (tmp_path / f"m_{ext}.tmj").write_bytes(BOM + (DATA / f"external_{ext}.tmj").read_bytes())
    a, b = levels.load(tmp_path / f"m_{ext}.tmj"), levels.load(DATA / f"external_{ext}.tmj")
    _same_level(a, b, names=False)
    assert a.num_bodies == 2 and a.one_way.tolist() == [True, False]
  (tmp_path / "crate.tx").write_bytes(BOM + b'<template><object name="crate" width="16" '
                                      b'height="16"/></template>')
  (tmp_path / "m.tmx").write_bytes(BOM + (
      '<?xml version="1.0" encoding="UTF-8"?>\r\n<map orientation="orthogonal" width="4" '
      'height="4" tilewidth="16" tileheight="16"><objectgroup name="o">'
      '<object id="1" template="crate.tx" x="16" y="32"/></objectgroup></map>').encode())
  lv = levels.load(tmp_path / "m.tmx")
  assert lv.tags["crate"] == (0,) and lv.pos.tolist() == [[1.5, 1.5]]


def test_shipped_levels_load_by_name():
  assert levels.names() == ["platformer1", "platformer2", "sokoban1", "sokoban2", "sokoban3"]
  shipped = pathlib.Path(jc.__file__).parent / "data" / "levels"
  for name in levels.names():
    by_name = levels.load(name)
    (path,) = shipped.glob(f"{name}.*")
    by_path = levels.load(path)
    assert by_name.name == name and len(by_name) > 0
    np.testing.assert_array_equal(by_name.pos, by_path.pos)
  with pytest.raises(FileNotFoundError, match=r"no shipped level of that name \(shipped: "
                                              r"platformer1, platformer2, sokoban1"):
    levels.load("sokoban99")


def _sokoban_moves(level):
  """The fewest moves that solve a Sokoban level, by breadth-first search on its cells (None
  if it cannot be solved): checks the parsed level is a consistent, playable one."""
  walls = set()
  cell = lambda p: (int(math.floor(p[0])), int(math.floor(p[1])))
  for i in level.tags["wall"]:
    (x0, y0), (x1, y1) = level.pos[i] - level.half[i], level.pos[i] + level.half[i]
    walls |= {(x, y) for x in range(int(x0), int(x1)) for y in range(int(y0), int(y1))}
  boxes = frozenset(cell(level.pos[i]) for i in level.tags["box"])
  goals = frozenset(cell(level.pos[i]) for i in level.tags["goal"])
  start = (cell(level.pos[level.player]), boxes)
  depth, queue = {start: 0}, collections.deque([start])
  while queue:
    player, boxes = state = queue.popleft()
    if boxes == goals:
      return depth[state]
    for dx, dy in ((1, 0), (-1, 0), (0, 1), (0, -1)):
      step = (player[0] + dx, player[1] + dy)
      if step in walls:
        continue
      moved = boxes
      if step in boxes:
        push = (step[0] + dx, step[1] + dy)
        if push in walls or push in boxes:
          continue
        moved = (boxes - {step}) | {push}
      nxt = (step, moved)
      if nxt not in depth:
        depth[nxt] = depth[state] + 1
        queue.append(nxt)
  return None


@pytest.mark.parametrize("name, moves", [("sokoban1", 1), ("sokoban2", 11), ("sokoban3", 23)])
def test_shipped_sokoban_levels_are_solvable(name, moves):
  lv = levels.load(name)
  assert lv.gravity == (0.0, 0.0)
  assert len(lv.tags["box"]) == len(lv.tags["goal"]) and lv.player is not None
  assert _sokoban_moves(lv) == moves


@pytest.mark.parametrize("name", ["platformer1", "platformer2"])
def test_shipped_platformer_levels(name):
  lv = levels.load(name)
  assert lv.gravity == (0.0, -9.81)
  assert len(lv.tags["flag"]) == 1 and len(lv.tags["box"]) >= 2 and lv.one_way.sum() >= 3
  flag = lv.tags["flag"][0]
  assert lv.sensor[flag] and lv.mask[flag] == levels.PLAYER
  assert lv.category[lv.player] == levels.PLAYER
  # Every body lies inside the map, and the movable ones overlap nothing solid.
  lo, hi = lv.pos - lv.half, lv.pos + lv.half
  assert (lo >= lv.bounds[:2]).all() and (hi <= lv.bounds[2:]).all()
  solid = ~lv.sensor
  movable = np.flatnonzero(np.isfinite(lv.mass))
  for i in movable:
    overlap = (np.minimum(hi[i], hi) - np.maximum(lo[i], lo) > 1e-9).all(1) & solid
    overlap[i] = False
    assert not overlap.any(), (i, np.flatnonzero(overlap))


# World.


def test_world_carries_every_field():
  lv = levels.load(DATA / "room_csv.tmj")
  w = lv.world()
  assert w.num_bodies == len(lv)
  np.testing.assert_allclose(np.asarray(w.pos), lv.pos)
  np.testing.assert_allclose(np.asarray(w.half), lv.half)
  np.testing.assert_allclose(np.asarray(w.inv_mass), np.where(np.isinf(lv.mass), 0, 1 / lv.mass),
                             rtol=1e-6)
  np.testing.assert_allclose(np.asarray(w.vel), lv.vel)
  np.testing.assert_allclose(np.asarray(w.friction), lv.friction, rtol=1e-6)
  np.testing.assert_array_equal(np.asarray(w.one_way), lv.one_way)
  np.testing.assert_array_equal(np.asarray(w.sensor), lv.sensor)
  np.testing.assert_array_equal(np.asarray(w.category), lv.category)
  np.testing.assert_array_equal(np.asarray(w.mask), lv.mask)
  np.testing.assert_allclose(np.asarray(w.gravity), lv.gravity, rtol=1e-6)


def test_world_overrides():
  lv = levels.load("sokoban1")
  w = lv.world(friction=0.3, gravity=(0.0, -1.0), mass=np.where(np.isinf(lv.mass), INF, 2.0))
  np.testing.assert_allclose(np.asarray(w.friction), 0.3, rtol=1e-6)
  np.testing.assert_allclose(np.asarray(w.gravity), [0, -1])
  assert np.asarray(w.inv_mass)[lv.player] == 0.5
  with pytest.raises(TypeError):
    lv.world(colour="red")


def test_a_loaded_level_settles_on_its_merged_floor():
  lv = levels.load("platformer1")
  w = lv.world()
  final, _ = jc.rollout(w, jc.Config.for_world(w), 60)
  idx = lv.indices("player", "box")
  # Player (half 0.4) and boxes (half 0.45) end resting on the floor's top, y = 1.
  np.testing.assert_allclose(np.asarray(final.pos)[idx], [[3.5, 1.4], [7.5, 1.45], [10.5, 1.45]],
                             atol=2e-3)
  assert int(final.status) == 0


def test_one_module_per_format():
  """`jaxchain.levels` is a package (DESIGN.md section 7): the shared `Level` and one
  module per format, the public names re-exported as they were by the one module."""
  root = pathlib.Path(levels.__file__).parent
  assert root.name == "levels" and levels.__file__.endswith("__init__.py")
  assert sorted(p.name for p in root.glob("*.py")) == [
      "__init__.py", "ascii.py", "files.py", "level.py", "loader.py", "tiled.py", "tmx.py",
      "xsb.py"]
  where = {"Level": "level", "Tile": "level", "rectangles": "level", "parse_ascii": "ascii",
           "parse_xsb_collection": "xsb", "load_collection": "xsb", "parse_moves": "xsb",
           "load_tiled": "tiled", "tmx_to_json": "tmx", "load": "loader", "names": "files"}
  for name, module in where.items():
    assert getattr(levels, name).__module__ == f"jaxchain.levels.{module}", name
  assert set(levels.__all__) == {
      "ALL", "BOX", "BOX_TILE", "CATEGORIES", "DEFAULT_MASS", "FLAG_TILE", "FLIP_BITS",
      "GID_MASK", "GOAL_TILE", "HAZARD_TILE", "HEAVY_TILE", "LEGEND", "Level", "MAX_BODIES",
      "MAX_FILE_BYTES", "MAX_GROUP_DEPTH", "MAX_MOVES", "MAX_TILES", "PLATFORM_TILE",
      "PLAYER", "PLAYER_TILE", "POINT_HALF", "SENSOR", "SLAB", "SOLID", "Tile", "WALL", "load",
      "load_collection", "load_tiled", "names", "parse_ascii", "parse_moves",
      "parse_xsb_collection", "rectangles", "tmx_to_json"}
  assert all(hasattr(levels, name) for name in levels.__all__)
  # No module is the old 1,684-line file again.
  assert max(len(p.read_text().splitlines()) for p in root.glob("*.py")) < 800


def test_doctests():
  """Every module of the package (`testmod(levels)` alone sees only the re-exports'
  package docstring: doctest skips objects defined in another module)."""
  attempted = 0
  for module in (levels, levels.level, levels.ascii, levels.xsb, levels.tmx, levels.tiled,
                 levels.files, levels.loader):
    result = doctest.testmod(module, optionflags=doctest.ELLIPSIS)
    assert result.failed == 0, module.__name__
    attempted += result.attempted
  assert attempted > 30
