"""Writes the encoded variants of room_csv.tmj (a map written by hand against the Tiled
JSON map format documentation): the same map with its tile layers' data as base64
(uncompressed, zlib, gzip, zstd) and with flip flags set on the GIDs.

Tiled's base64 layer data: the GIDs as little-endian uint32, optionally compressed,
then base64-encoded; `encoding` is "base64" and `compression` "zlib", "gzip", "zstd" or
"" (or absent). The top four bits of a GID are flags (flipped horizontally 0x80000000,
vertically 0x40000000, diagonally 0x20000000, rotated 120 degrees on hexagonal maps
0x10000000) that readers clear before looking the tile up.

Run from anywhere: `python tests/data/levels/make_fixtures.py`; the outputs are committed.
"""

import base64
import copy
import gzip
import json
import pathlib
import struct
import zlib

HERE = pathlib.Path(__file__).parent
FLAGS = (0x80000000, 0x40000000, 0x20000000, 0x10000000, 0xA0000000, 0xF0000000, 0)


def zstd_raw_frame(payload: bytes) -> bytes:
  """A Zstandard frame holding `payload` uncompressed in one raw block (RFC 8878): no zstd
  library needed, and any zstd decoder reads it back."""
  assert len(payload) < 256
  magic = struct.pack("<I", 0xFD2FB528)
  header = bytes([0x20, len(payload)])  # Single_Segment_flag, 1-byte Frame_Content_Size.
  block = struct.pack("<I", 1 | (0 << 1) | (len(payload) << 3))[:3]  # Last_Block, Raw_Block.
  return magic + header + block + payload


def encode(gids, compression):
  raw = struct.pack(f"<{len(gids)}I", *gids)
  packed = {"": raw, "zlib": zlib.compress(raw), "gzip": gzip.compress(raw, mtime=0),
            "zstd": zstd_raw_frame(raw)}[compression]
  return base64.b64encode(packed).decode("ascii")


def write(name, data):
  (HERE / name).write_text(json.dumps(data, indent=1) + "\n")


def main():
  room = json.loads((HERE / "room_csv.tmj").read_text())
  for compression, name in (("", "room_base64.tmj"), ("zlib", "room_zlib.tmj"),
                            ("gzip", "room_gzip.tmj"), ("zstd", "room_zstd.tmj")):
    out = copy.deepcopy(room)
    for layer in out["layers"]:
      if layer["type"] == "tilelayer":
        layer["data"] = encode(layer["data"], compression)
        layer["encoding"] = "base64"
        if compression:
          layer["compression"] = compression
    write(name, out)
  out = copy.deepcopy(room)
  for layer in out["layers"]:
    if layer["type"] == "tilelayer":
      layer["data"] = [g | FLAGS[k % len(FLAGS)] if g else 0 for k, g in enumerate(layer["data"])]
  write("room_flipped.tmj", out)


if __name__ == "__main__":
  main()
