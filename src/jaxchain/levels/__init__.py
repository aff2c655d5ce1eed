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

Limits: a loader reads regular files of at most `MAX_FILE_BYTES` (UTF-8, a byte-order
mark dropped), maps of at most `MAX_TILES` cells with group layers at most
`MAX_GROUP_DEPTH` deep, and makes at most `max_bodies` (`MAX_BODIES`) bodies, counted
before they are built; `parse_moves` expands at most `max_moves` (`MAX_MOVES`). Past a
limit, a ValueError names the file and the limit (docs/levels.md, "Limits").

Modules: `level` (`Level`, `Tile`, the categories, `rectangles`), one per format
(`ascii`, `xsb`: collections and solutions, `tiled`: the JSON structure, `tmx`: XML
into it), `files` (reading files, shipped levels) and `loader` (`load`).
"""

from jaxchain.levels.ascii import LEGEND, parse_ascii
from jaxchain.levels.files import MAX_FILE_BYTES, names
from jaxchain.levels.level import (ALL, BOX, BOX_TILE, CATEGORIES, FLAG_TILE, GOAL_TILE,
                                   HAZARD_TILE, HEAVY_TILE, MAX_BODIES, MAX_TILES, PLATFORM_TILE,
                                   PLAYER, PLAYER_TILE, SENSOR, SLAB, SOLID, WALL, Level, Tile,
                                   rectangles)
from jaxchain.levels.loader import load
from jaxchain.levels.tiled import DEFAULT_MASS, FLIP_BITS, GID_MASK, POINT_HALF, load_tiled
from jaxchain.levels.tmx import MAX_GROUP_DEPTH, tmx_to_json
from jaxchain.levels.xsb import MAX_MOVES, load_collection, parse_moves, parse_xsb_collection

__all__ = [
    "ALL", "BOX", "BOX_TILE", "CATEGORIES", "DEFAULT_MASS", "FLAG_TILE", "FLIP_BITS", "GID_MASK",
    "GOAL_TILE", "HAZARD_TILE", "HEAVY_TILE", "LEGEND", "Level", "MAX_BODIES", "MAX_FILE_BYTES",
    "MAX_GROUP_DEPTH", "MAX_MOVES", "MAX_TILES", "PLATFORM_TILE", "PLAYER", "PLAYER_TILE",
    "POINT_HALF", "SENSOR", "SLAB", "SOLID", "Tile", "WALL", "load", "load_collection",
    "load_tiled", "names", "parse_ascii", "parse_moves", "parse_xsb_collection", "rectangles",
    "tmx_to_json",
]
