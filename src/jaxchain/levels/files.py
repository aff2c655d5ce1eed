"""Level files: where they are (paths, and the levels shipped with jaxchain) and
where in them an error is.
"""

from __future__ import annotations

import importlib.resources
import pathlib


class _Where:
  """Where in a Tiled map an error is (for messages)."""

  def __init__(self, source: str, layer: str | None = None, obj: str | None = None):
    self.source, self.layer, self.obj = source, layer, obj

  def __str__(self):
    parts = [self.source] + [p for p in (self.layer, self.obj) if p]
    return ", ".join(parts)

  def error(self, message: str) -> ValueError:
    return ValueError(f"{self}: {message}")


def _read_text(file) -> str:
  """The text of a level file (a path or an `importlib.resources` traversable), read
  as it is saved: UTF-8, with or without a byte-order mark (dropped).

  Raises:
    OSError: when the file cannot be read. ValueError: when it is not UTF-8 (the
      message does not name the file: the caller does).
  """
  data = file.read_bytes()
  try:
    return data.decode("utf-8-sig")
  except UnicodeDecodeError as e:
    raise ValueError(f"not UTF-8 text ({e.reason} at byte {e.start})") from None


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
