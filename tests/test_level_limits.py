"""Level loaders under attack: hostile files fail fast with a ValueError naming the file
and the limit (docs/levels.md, "Limits").

Every hostile input is built here, small on disk (a deflate stream of zeros is built by
repeating one flushed block, with its checksum, in well under a second). Each refusal
is timed and its peak memory traced (`tracemalloc` sees Python's and NumPy's
allocations); the issue's bounds are 5 s and 500 MB, and the fixed loaders stay far
below both. No jit anywhere.
"""

import base64
import json
import os
import struct
import time
import tracemalloc
import zlib

import numpy as np
import pytest

from jaxchain import levels

MB = 1 << 20
SOLID = [{"name": "solid", "type": "bool", "value": True}]


def _refused(fn, match, seconds=5.0, megabytes=100):
  """Runs `fn`, which must raise a ValueError matching `match`, within `seconds` and
  `megabytes` of traced peak memory (None: not traced, as tracing slows code that
  makes many small Python objects tenfold); returns the message."""
  if megabytes is not None:
    tracemalloc.start()
  start = time.perf_counter()
  try:
    with pytest.raises(ValueError, match=match) as info:
      fn()
  finally:
    elapsed = time.perf_counter() - start
    if megabytes is not None:
      _, peak = tracemalloc.get_traced_memory()
      tracemalloc.stop()
  assert elapsed < seconds, f"{elapsed:.1f} s"
  if megabytes is not None:
    assert peak < megabytes * MB, f"{peak / MB:.0f} MB"
  return str(info.value)


def _zeros_stream(n: int, wrapper: str) -> bytes:
  """A zlib or gzip stream that inflates to `n` zero bytes (`n` a multiple of 16 MiB),
  checksum and all: one block of 16 MiB of zeros, flushed so that it stands alone,
  repeated; then an empty final block and the trailer."""
  chunk = bytes(16 * MB)
  co = zlib.compressobj(9, zlib.DEFLATED, -15)  # Raw deflate.
  block = co.compress(chunk) + co.flush(zlib.Z_FULL_FLUSH)
  body = block * (n // len(chunk)) + b"\x03\x00"  # BFINAL, fixed codes, end of block.
  if wrapper == "zlib":  # Adler-32 of n zeros: a = 1, b = n (mod 65521).
    return b"\x78\xda" + body + struct.pack(">I", ((n % 65521) << 16) | 1)
  crc = 0
  for _ in range(n // len(chunk)):
    crc = zlib.crc32(chunk, crc)
  header = b"\x1f\x8b\x08\x00\x00\x00\x00\x00\x02\xff"
  return header + body + struct.pack("<II", crc, n & 0xFFFFFFFF)


def _tile_map(data, width, height, **layer):
  return {"orientation": "orthogonal", "width": width, "height": height, "tilewidth": 16,
          "tileheight": 16, "tilesets": [],
          "layers": [{"type": "tilelayer", "name": "ground", "width": width, "height": height,
                      "properties": SOLID, "data": data, **layer}]}


# 5. Compressed tile data is inflated only up to the layer's size.


@pytest.mark.parametrize("wrapper, size", [("zlib", 2 << 30), ("gzip", 1 << 30)])
def test_a_compressed_layer_that_inflates_past_its_size_is_refused(tmp_path, wrapper, size):
  stream = _zeros_stream(size, wrapper)
  assert len(stream) < size // 900  # About 1,000:1.
  assert zlib.decompressobj(47).decompress(stream, 64) == bytes(64)  # A real stream.
  path = tmp_path / "bomb.tmj"
  path.write_text(json.dumps(_tile_map(base64.b64encode(stream).decode(), 64, 64,
                                       encoding="base64", compression=wrapper)))
  message = _refused(lambda: levels.load(path), r"bomb.tmj, layer 'ground': tile data "
                     rf"inflates past the layer's 64x64 tiles \(16384 bytes\) \({wrapper}\)")
  assert "does not decompress" not in message
  # A stream that stops short, or holds data after its end, is an error too.
  for bad in (stream[:1000], zlib.compress(bytes(4 * 64 * 64)) + b"junk"):
    data = _tile_map(base64.b64encode(bad).decode(), 64, 64, encoding="base64",
                     compression="zlib")
    with pytest.raises(ValueError, match=r"layer 'ground': tile data (does not decompress|"
                                         r"inflates past|has data after)"):
      levels.load_tiled(data)


def test_a_map_larger_than_the_tile_limit_is_refused_before_its_data_is_read():
  assert levels.MAX_TILES == 1 << 22
  data = _tile_map("", 1 << 16, 1 << 16, encoding="base64", compression="zlib")
  _refused(lambda: levels.load_tiled(data, source="huge.tmj"),
           r"huge.tmj: the map is 65536x65536 = 4294967296 tiles, more than the limit "
           r"levels.MAX_TILES = 4194304")
  # At the limit: 2048 x 2048 tiles of zeros (zlib) load, to no body.
  raw = zlib.compress(bytes(4 << 22))
  lv = levels.load_tiled(_tile_map(base64.b64encode(raw).decode(), 2048, 2048,
                                   encoding="base64", compression="zlib"))
  assert lv.num_bodies == 0 and lv.bounds == (0, 0, 2048, 2048)


# 6. Files: regular files only, at most MAX_FILE_BYTES each.


def _map_naming(tileset=None, template=None):
  objects = [{"id": 1, "template": template, "x": 0, "y": 16}] if template else []
  return {"orientation": "orthogonal", "width": 2, "height": 1, "tilewidth": 16,
          "tileheight": 16, "tilesets": [{"firstgid": 1, "source": tileset}] if tileset else [],
          "layers": [{"type": "objectgroup", "name": "o", "objects": objects}]}


def _sparse(path, size):
  """A file of `size` bytes that takes no disk (a hole)."""
  with open(path, "wb") as f:
    f.truncate(size)
  return path


def test_files_must_be_regular_files_of_at_most_max_file_bytes(tmp_path):
  assert levels.MAX_FILE_BYTES == 8 * MB
  big = _sparse(tmp_path / "big.tsx", levels.MAX_FILE_BYTES + 1)
  fifo = tmp_path / "fifo.tsx"
  os.mkfifo(fifo)  # Opening it for reading would wait for a writer: it is never opened.
  (tmp_path / "dir.tsx").mkdir()
  cases = [(str(big), r"8388609 bytes, more than the limit levels.MAX_FILE_BYTES = 8388608"),
           (str(fifo), r"not a regular file \(a FIFO\)"),
           ("dir.tsx", r"not a regular file \(a directory\)")]
  if os.path.exists("/dev/zero"):
    cases.append(("/dev/zero", r"not a regular file \(a character device\)"))
  for name, why in cases:
    for kind in ("tileset", "template"):
      path = tmp_path / f"{kind}.tmj"
      path.write_text(json.dumps(_map_naming(**{kind: name})))
      what = "external tileset" if kind == "tileset" else "layer 'o', object 1: template"
      _refused(lambda: levels.load(path), rf"{kind}.tmj, .*{what} '{name}': {why}",
               seconds=2, megabytes=20)
  # The map itself, and a collection.
  for name in ("huge.tmj", "huge.tmx", "huge.xsb", "huge.txt"):
    _refused(lambda: levels.load(_sparse(tmp_path / name, 1 << 30)),
             rf"{name}: 1073741824 bytes, more than the limit levels.MAX_FILE_BYTES",
             seconds=2, megabytes=20)
  _refused(lambda: levels.load_collection(tmp_path / "huge.xsb"),
           r"huge.xsb: 1073741824 bytes, more than the limit", seconds=2, megabytes=20)


# 7. Collections: time linear in the number of levels.


def test_a_collection_of_3000_levels_parses_in_linear_time():
  room = "; {k}\n#####\n#@$.#\n#####\n"
  text = "\n".join(room.format(k=k) for k in range(3000))
  start = time.perf_counter()
  c = levels.parse_xsb_collection(text)  # Quadratic before: 4,000 levels took 105 s.
  assert time.perf_counter() - start < 5.0  # 0.7 s here.
  assert len(c) == 3000 and c[-1].name == "2999" and c[-1].num_bodies == 7
  np.testing.assert_array_equal(c[-1].pos, c[0].pos)
  # Errors still name the line in the whole text: level 3000's map starts at line 14997.
  bad = text[:text.rindex("#@$.#")] + "#@?.#\n#####\n"
  with pytest.raises(ValueError, match=r"<xsb>: line 14998, column 3: unknown character '\?'"):
    levels.parse_xsb_collection(bad)


# 8. Solutions: at most max_moves moves once expanded.


def test_solutions_expanding_past_max_moves_are_refused():
  assert levels.MAX_MOVES == 1_000_000
  limit = r"more than max_moves = 1000000 moves \(levels.MAX_MOVES; raise it with max_moves=\)"
  nested = "2(" * 40 + "r" + ")" * 40  # 2**40 moves from 121 characters.
  for text, where in (("999999999r", 7), ("9(999999999r)", 9), ("d1000000r", 9),
                      (nested, 101), ("9" * 5000 + "r", 7)):
    message = _refused(lambda: levels.parse_moves(text), limit, seconds=1, megabytes=5)
    assert message.startswith(f"moves: position {where}: ")
  assert len(levels.parse_moves("1000000r")) == 1_000_000  # At the limit.
  assert levels.parse_moves("d1000000r", max_moves=1_000_001)[:2] == "dr"
  assert levels.parse_moves("(" * 10_000 + "2r" + ")" * 10_000) == "rr"  # No recursion.
  assert levels.parse_moves("0(rr)u2()") == "u"
  with pytest.raises(ValueError, match=r"max_moves must be an int >= 0, got -1"):
    levels.parse_moves("r", max_moves=-1)


# 9. Bodies: at most max_bodies per level (per collection, in all).

LIMIT = r"more than max_bodies = {} bodies \(levels.MAX_BODIES; raise it with max_bodies=\)"


def _checkerboard(size):
  """A size x size base64-zlib tile layer, every other tile solid: no two merge."""
  cells = (np.add.outer(np.arange(size), np.arange(size)) % 2 == 0).astype("<u4")
  return base64.b64encode(zlib.compress(cells.tobytes(), 9)).decode()


def test_a_small_map_of_two_million_bodies_is_refused(tmp_path):
  assert levels.MAX_BODIES == 100_000
  path = tmp_path / "board.tmj"
  path.write_text(json.dumps(_tile_map(_checkerboard(2000), 2000, 2000, encoding="base64",
                                       compression="zlib")))
  assert path.stat().st_size < 40_000  # 35 KB on disk, 2,000,000 bodies.
  _refused(lambda: levels.load(path), r"board.tmj, layer 'ground': " + LIMIT.format(100000),
           seconds=5, megabytes=300)
  # The keyword moves the limit, exactly: 50 x 50 tiles, every other one solid.
  data = _tile_map(_checkerboard(50), 50, 50, encoding="base64", compression="zlib")
  assert levels.load_tiled(data, max_bodies=1250).num_bodies == 1250
  with pytest.raises(ValueError, match=r"<tiled>, layer 'ground': " + LIMIT.format(1249)):
    levels.load_tiled(data, max_bodies=1249)
  # Objects count too.
  data = _tile_map([0] * 4, 2, 2)
  data["layers"].append({"type": "objectgroup", "name": "crates", "objects": [
      {"id": k, "x": 0, "y": 0, "width": 8, "height": 8} for k in range(3)]})
  assert levels.load_tiled(data, max_bodies=3).num_bodies == 3
  with pytest.raises(ValueError, match=r"<tiled>, layer 'crates', object 2: " + LIMIT.format(2)):
    levels.load_tiled(data, max_bodies=2)


def test_ascii_maps_and_collections_count_their_bodies(tmp_path):
  boxes = "#" + "$ " * 2048 + "#\n"
  path = tmp_path / "boxes.txt"
  path.write_text(boxes * 60)  # 245 KB: 122,880 boxes.
  _refused(lambda: levels.load(path), r"boxes.txt: " + LIMIT.format(100000), seconds=5,
           megabytes=300)
  room = "#####\n#@$.#\n#####\n"  # 7 bodies.
  assert levels.parse_ascii(room, max_bodies=7).num_bodies == 7
  with pytest.raises(ValueError, match=r"<ascii>: " + LIMIT.format(6)):
    levels.parse_ascii(room, max_bodies=6)
  # A collection's limit is on all its levels together.
  text = "\n".join([room] * 3)
  assert len(levels.parse_xsb_collection(text, max_bodies=21)) == 3
  with pytest.raises(ValueError, match=r"<xsb>: its levels 1 to 3 have " + LIMIT.format(20)):
    levels.parse_xsb_collection(text, max_bodies=20)
  (tmp_path / "three.xsb").write_text(text)
  assert len(levels.load_collection(tmp_path / "three.xsb", max_bodies=21)) == 3
  with pytest.raises(ValueError, match=r"three.xsb: its levels 1 to 3 have " + LIMIT.format(20)):
    levels.load_collection(tmp_path / "three.xsb", max_bodies=20)
  # 8 MB of tiny levels: their boxes, goals and players alone pass the limit, counted
  # over the whole text before any level is parsed.
  hostile = "\n".join([room] * 420_000)
  _refused(lambda: levels.parse_xsb_collection(hostile),
           r"<xsb>: its 420000 levels have at least 1680000 bodies, " + LIMIT.format(100000),
           megabytes=None)
  # Walls count as they are parsed: 99 levels of 1,004 bodies pass, the 100th does not.
  big = "#" * 1002 + "\n" + ("#" + "$ " * 500 + "#\n") * 2 + "#" * 1002 + "\n"
  _refused(lambda: levels.parse_xsb_collection("\n".join([big] * 100), max_bodies=100_200),
           r"<xsb>: its levels 1 to 100 have " + LIMIT.format(100200), megabytes=None)
  for bad in (-1, 1.5, True):
    with pytest.raises(ValueError, match=r"max_bodies must be an int >= 0"):
      levels.parse_ascii(room, max_bodies=bad)


# 10. Group layers: at most MAX_GROUP_DEPTH deep.


def _nested(depth, fmt):
  """A map whose object layer sits inside `depth` group layers, as .tmj or .tmx text."""
  if fmt == "tmj":
    head = ('{"orientation": "orthogonal", "width": 2, "height": 1, "tilewidth": 16, '
            '"tileheight": 16, "tilesets": [], "layers": [')
    inner = ('{"type": "objectgroup", "name": "o", "objects": [{"id": 1, "x": 0, "y": 0, '
             '"width": 16, "height": 16}]}')
    return head + '{"type": "group", "name": "g", "layers": [' * depth + inner + "]}" * depth + "]}"
  return ('<map orientation="orthogonal" width="2" height="1" tilewidth="16" tileheight="16">'
          + '<group name="g">' * depth + '<objectgroup name="o"><object id="1" x="0" y="0" '
          'width="16" height="16"/></objectgroup>' + "</group>" * depth + "</map>")


@pytest.mark.parametrize("fmt", ["tmj", "tmx"])
def test_group_layers_nested_too_deep_are_refused(tmp_path, fmt):
  assert levels.MAX_GROUP_DEPTH == 64
  path = tmp_path / f"ok.{fmt}"
  path.write_text(_nested(64, fmt))
  lv = levels.load(path)
  assert lv.num_bodies == 1 and lv.tags["/".join(["g"] * 64 + ["o"])] == (0,)
  for depth in (65, 900, 5000):
    path = tmp_path / f"deep{depth}.{fmt}"
    path.write_text(_nested(depth, fmt))
    if fmt == "tmj" and depth > 400:  # json.loads itself gives up (RecursionError).
      why = r"not valid JSON \(nested too deeply for the JSON parser\)"
    else:
      why = r"group layers nested more than levels.MAX_GROUP_DEPTH = 64 deep"
    _refused(lambda: levels.load(path), rf"deep{depth}.{fmt}(, layer '[g/]+')?: {why}",
             seconds=2)
  with pytest.raises(ValueError, match=r"<tiled>, layer '(g/){64}g': group layers nested more"):
    levels.load_tiled(json.loads(_nested(65, "tmj")))
