"""Sokoban collections (several XSB levels in one text or file) and solutions in LURD
notation.
"""

from __future__ import annotations

from jaxchain.levels.ascii import _legend, _parse_rows
from jaxchain.levels.files import _level_file, _read_text
from jaxchain.levels.level import MAX_BODIES, Level, _max_bodies, _too_many


def _is_map_row(line: str, table) -> bool:
  """A line of a level's map: after leading floor (spaces, `-`, `_`) it starts with a
  wall `#` (every XSB row does: its first solid cell is the outer wall). A line with a
  stray character is still a map row, so `parse_ascii` reports the character."""
  del table
  return line.lstrip(" -_").startswith("#")


def parse_xsb_collection(text: str, legend=None, *, name: str = "", gravity=(0.0, 0.0),
                         strict: bool = False, source: str | None = None,
                         max_bodies: int = MAX_BODIES) -> list[Level]:
  """Reads a Sokoban collection: several XSB levels in one text, as a list of `Level`s.

  The text is read line by line. A level is a run of consecutive map lines (lines
  whose first character after leading floor, spaces `-` `_`, is a wall `#`: every
  XSB row starts at the outer wall); a blank line or a text line ends it. Every other line is text: `; ...` comments,
  `Title: ...`, `Author: ...`, `Comment:` ... `Comment-End:` blocks (text whatever
  their lines look like), a collection's header. Only titles are kept (as the
  levels' names); authors and comments are not read into the `Level`s. A level's title is, in this order: a `Title:` line in the paragraph
  right after its map (the text lines up to the next blank line) or in the last
  paragraph before it; else the first `;` comment of that paragraph before it
  (`; 12 'Lockdown'` gives "12 'Lockdown'"); else its first plain text line; else
  `"{name} {k}"` (k counted from 1; "level k" without a `name`). Each map is read
  by `parse_ascii` with `legend` and `strict`, and errors name the line in the
  whole text.

  Args:
    text: the collection.
    legend: extra characters (see `parse_ascii`).
    name: the collection's name (for untitled levels and errors).
    gravity: every level's gravity (default `(0, 0)`: Sokoban is seen from above).
    strict: every map must be rectangular.
    source: what errors call the text (default `name`, or "<xsb>").
    max_bodies: the most bodies of all the levels together (`MAX_BODIES`), so that a
      huge collection is refused as soon as its levels pass it.

  Returns:
    The levels in file order, each named by its title.

  Raises:
    ValueError: when the text holds no level, or a map is malformed (naming the
      line in the whole text), or the levels have more than `max_bodies` bodies.

  Examples:
    >>> from jaxchain import levels
    >>> c = levels.parse_xsb_collection('''; A tiny collection
    ...
    ... ; 1
    ... #####
    ... #@$.#
    ... #####
    ...
    ... ######
    ... #@$ .#
    ... ######
    ... Title: Two steps
    ... Author: me
    ... ''')
    >>> [lv.name for lv in c], [len(lv.tags["box"]) for lv in c]
    (['1', 'Two steps'], [1, 1])
  """
  source = source or name or "<xsb>"
  table = _legend(legend)
  limit = _max_bodies(max_bodies)
  text = text.removeprefix("\ufeff")  # A byte-order mark (a file read as "utf-8").
  lines = [line.rstrip("\r") for line in text.split("\n")]
  kinds, in_comment = [], False
  for line in lines:
    key = line.strip().lower()
    if in_comment or key.startswith("comment:") or key.startswith("comment-end:"):
      # A Comment: ... Comment-End: block is text, whatever its lines look like.
      in_comment = (in_comment or (key.startswith("comment:") and not key[8:].strip())) and \
          not key.startswith("comment-end:")
      kinds.append("text")
    else:
      kinds.append("blank" if not key else "map" if _is_map_row(line, table) else "text")
  maps = []  # (first line, last line), 0-based, inclusive
  k = 0
  while k < len(lines):
    if kinds[k] == "map":
      start = k
      while k + 1 < len(lines) and kinds[k + 1] == "map":
        k += 1
      maps.append((start, k))
    k += 1
  if not maps:
    raise ValueError(f"{source}: no level (no line starting with a wall '#')")
  # A fast bound first, over the whole text: every cell of an unmerged tile is a body,
  # and every map has its '#' wall; past `max_bodies`, no level is parsed.
  rows = "\n".join(lines[k] for start, end in maps for k in range(start, end + 1))
  least = len(maps) * bool(table.get("#")) + sum(
      rows.count(ch) * sum(t.merge == "none" for t in tiles) for ch, tiles in table.items()
      if any(t.merge == "none" for t in tiles))
  if least > limit:
    raise _too_many(f"{source}: its {len(maps)} levels have at least {least} bodies,", limit,
                    " ")

  def paragraph_after(end):
    out, k = [], end + 1
    while k < len(lines) and kinds[k] == "text":
      out.append(lines[k].strip())
      k += 1
    return out, k

  def title_of(before, after):
    for line in after + before:
      if line.lower().startswith("title:") and line[6:].strip():
        return line[6:].strip()
    for line in before:
      if line.startswith(";") and line.strip(" ;\t"):
        return line.strip(" ;\t")
    for line in before:
      if not line.startswith(";") and ":" not in line:
        return line
    return ""

  out, prev_end, used = [], -1, 0
  for number, (start, end) in enumerate(maps, 1):
    after, _ = paragraph_after(end)
    # The last paragraph of text before the map (after the previous map's own).
    if prev_end >= 0:
      _, prev_end = paragraph_after(prev_end)
    before, k = [], start - 1
    while k > prev_end and kinds[k] == "blank":
      k -= 1
    while k > prev_end and kinds[k] == "text":
      before.append(lines[k].strip())
      k -= 1
    before.reverse()
    prev_end = end
    title = title_of(before, after) or f"{name or 'level'} {number}"
    rows = [(k + 1, lines[k]) for k in range(start, end + 1)]  # Numbered in the whole text.
    too_many = lambda n=number: _too_many(f"{source}: its levels 1 to {n} have", limit, " ")
    out.append(_parse_rows(rows, table, title, gravity, strict, source, limit - used, too_many))
    used += out[-1].num_bodies
  return out


def load_collection(path, legend=None, *, strict: bool = False, gravity=None,
                    max_bodies: int = MAX_BODIES) -> list[Level]:
  """Loads a Sokoban collection file (several XSB levels; `parse_xsb_collection`).

  Args:
    path: a file path, or the name of a shipped level (a one-level collection).
    legend: extra characters (see `parse_ascii`).
    strict: every map must be rectangular.
    gravity: every level's gravity (default `(0, 0)`).
    max_bodies: the most bodies of all the levels together (`MAX_BODIES`).

  Returns:
    The levels in file order, each named by its title.

  Examples:
    >>> from jaxchain import levels
    >>> [lv.name for lv in levels.load_collection("sokoban1")]
    ['sokoban1 (jaxchain): one box, one goal']
  """
  file = _level_file(path)
  try:
    text = _read_text(file)
  except ValueError as e:
    raise ValueError(f"{file.name}: {e}") from None
  stem = file.name.rsplit(".", 1)[0]
  return parse_xsb_collection(text, legend, name=stem, strict=strict, source=file.name,
                              gravity=(0.0, 0.0) if gravity is None else gravity,
                              max_bodies=max_bodies)


_MOVE_LETTERS = frozenset("lurdLURD")
# The most moves `parse_moves` expands a solution to (the longest published solutions
# have tens of thousands).
MAX_MOVES = 1_000_000


def parse_moves(text: str, *, max_moves: int = MAX_MOVES) -> str:
  """Expands a Sokoban solution in LURD notation into one letter per move.

  Letters `l u r d` are moves and `L U R D` pushes (kept as written); a count
  before a letter or a parenthesised group repeats it (`3r` is `rrr`, `2(ul)` is
  `ulul`: the run-length encoding of many published solutions); whitespace and
  line breaks are ignored.

  Args:
    text: the solution.
    max_moves: the most moves it may expand to (`MAX_MOVES`, a million); counts are
      checked as they are read, so `"999999999r"` is refused before anything is
      built.

  Raises:
    ValueError: for any other character, a count before nothing, unbalanced
      parentheses, or more than `max_moves` moves, naming the position.

  Examples:
    >>> from jaxchain import levels
    >>> levels.parse_moves("dl3u 2(rD)")
    'dluuurDrD'
  """
  if isinstance(max_moves, bool) or not isinstance(max_moves, int) or max_moves < 0:
    raise ValueError(f"parse_moves: max_moves must be an int >= 0, got {max_moves!r}")

  def too_many(k):
    return ValueError(f"moves: position {k + 1}: the solution expands to more than max_moves = "
                      f"{max_moves} moves (levels.MAX_MOVES; raise it with max_moves=)")

  # Each open group: (the pieces before it, their length, its count).
  out, size, stack, count = [], 0, [], None
  for k, ch in enumerate(text):
    if ch.isspace():
      if count is not None:
        raise ValueError(f"moves: position {k + 1}: a count ({count}) must come right before a "
                         f"move or a group")
      continue
    if ch in "0123456789":
      count = (count or 0) * 10 + int(ch)
      if count > max_moves:
        raise too_many(k)
    elif ch in _MOVE_LETTERS:
      times = 1 if count is None else count
      size += times
      if size > max_moves:
        raise too_many(k)
      out.append(ch * times)
      count = None
    elif ch == "(":
      stack.append((out, size, 1 if count is None else count))
      out, size, count = [], 0, None
    elif ch == ")":
      if not stack or count is not None:
        raise ValueError(f"moves: position {k + 1}: unbalanced ')'" if not stack else
                         f"moves: position {k + 1}: a count before ')'")
      inner, inner_size = "".join(out), size
      out, size, times = stack.pop()
      size += inner_size * times
      if size > max_moves:
        raise too_many(k)
      out.append(inner * times)
    else:
      raise ValueError(f"moves: position {k + 1}: {ch!r} is not a move (l u r d, L U R D for "
                       f"pushes, counts and parentheses)")
  if stack:
    raise ValueError("moves: unbalanced '(' (a group is never closed)")
  if count is not None:
    raise ValueError(f"moves: the count {count} at the end repeats nothing")
  return "".join(out)
