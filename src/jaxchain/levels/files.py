"""Level files: where they are (paths, and the levels shipped with jaxchain) and
where in them an error is.
"""

from __future__ import annotations

import importlib.resources
import json
import os
import pathlib
import stat


class _Where:
  """Where in a Tiled map an error is (for messages)."""

  def __init__(self, source: str, layer: str | None = None, obj: str | None = None):
    self.source, self.layer, self.obj = source, layer, obj

  def __str__(self):
    parts = [self.source] + [p for p in (self.layer, self.obj) if p]
    return ", ".join(parts)

  def error(self, message: str) -> ValueError:
    return ValueError(f"{self}: {message}")


# The largest level file a loader reads (a map, a collection, an external tileset or
# template): 8 MiB. JSON and XML parsers take up to about 33 times a file's size in
# memory (a JSON array of '{"":{}}': 265 MB for 8 MiB), so this bounds a load to ~300 MB.
MAX_FILE_BYTES = 8 << 20
_KINDS = ((stat.S_ISDIR, "a directory"), (stat.S_ISCHR, "a character device"),
          (stat.S_ISBLK, "a block device"), (stat.S_ISFIFO, "a FIFO"),
          (stat.S_ISSOCK, "a socket"))


def _check_regular(mode: int, size: int) -> None:
  if not stat.S_ISREG(mode):
    kind = next((name for test, name in _KINDS if test(mode)), "not a file")
    raise ValueError(f"not a regular file ({kind}): a level, its tilesets and templates must "
                     f"be regular files")
  if size > MAX_FILE_BYTES:
    raise ValueError(f"{size} bytes, more than the limit levels.MAX_FILE_BYTES = "
                     f"{MAX_FILE_BYTES} (8 MiB)")


def _read_bytes(path: pathlib.Path) -> bytes:
  """The bytes of a regular file of at most `MAX_FILE_BYTES`, checked before reading (a
  device, a FIFO or a directory is never read, nor opened for reading), and read with
  that cap in case the file grows meanwhile."""
  st = os.stat(path)
  _check_regular(st.st_mode, st.st_size)
  fd = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_BINARY", 0))
  with os.fdopen(fd, "rb") as f:
    st = os.fstat(f.fileno())  # The file opened is the file checked.
    _check_regular(st.st_mode, st.st_size)
    data = f.read(MAX_FILE_BYTES + 1)
  _check_regular(stat.S_IFREG, len(data))
  return data


def _read_text(file) -> str:
  """The text of a level file (a path, or a shipped level's `importlib.resources`
  traversable), read as it is saved: UTF-8, with or without a byte-order mark
  (dropped). A path must name a regular file of at most `MAX_FILE_BYTES`.

  Raises:
    OSError: when the file cannot be read. ValueError: when it is not a regular file,
      is too large, or is not UTF-8 (the message does not name the file: the caller
      does).
  """
  data = _read_bytes(file) if isinstance(file, (str, os.PathLike)) else file.read_bytes()
  try:
    return data.decode("utf-8-sig")
  except UnicodeDecodeError as e:
    raise ValueError(f"not UTF-8 text ({e.reason} at byte {e.start})") from None


def _parse_json(text: str):
  """`json.loads(text)`, raising ValueError (a `json.JSONDecodeError`, or nesting too
  deep for the parser, which raises RecursionError) for anything it cannot read."""
  try:
    return json.loads(text)
  except RecursionError:
    raise ValueError("nested too deeply for the JSON parser") from None


_SUFFIXES = {".txt": "ascii", ".xsb": "xsb", ".tmj": "tiled", ".json": "tiled", ".tmx": "tmx"}


def _shipped():
  return importlib.resources.files("jaxchain").joinpath("data", "levels")


def names() -> list[str]:
  """The names of the levels shipped with jaxchain (for `load`).

  Examples:
    >>> from jaxchain import levels
    >>> "sokoban1" in levels.names()
    True
  """
  return sorted(p.name.rsplit(".", 1)[0] for p in _shipped().iterdir()
                if "." in p.name and "." + p.name.rsplit(".", 1)[1] in _SUFFIXES)


def _level_file(path):
  """The file of a path, or of a shipped level's name (`names()`)."""
  file = pathlib.Path(path)
  if not file.exists() and isinstance(path, str) and not file.suffix and "/" not in path:
    shipped = {p.name.rsplit(".", 1)[0]: p for p in _shipped().iterdir()}
    if path not in shipped:
      raise FileNotFoundError(f"no level file {path!r}, and no shipped level of that name "
                              f"(shipped: {', '.join(names())})")
    return shipped[path]
  if not file.is_file():
    raise FileNotFoundError(f"no level file {str(path)!r} (shipped levels: "
                            f"{', '.join(names())})")
  return file


def _parent(file):
  """The directory of a path or of an `importlib.resources` traversable."""
  if isinstance(file, pathlib.Path):
    return file.parent
  return _shipped()
