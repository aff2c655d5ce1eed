"""The Python examples of the README and of every docs page paste into the Python REPL and
print what their comments say.

Each ```python block is pasted, line by line, into a fresh `code.InteractiveConsole`, as a
reader pastes it into the Python 3.11 REPL: a blank line ends an indented block, so code
right after a `def` body with no blank line between is a SyntaxError there (a script runs
it). Each block runs alone, with its own imports, as a reader pastes one. Each block is
compiled as a script too.

What a block prints is checked where its comment states it: a top-level `print(...)` whose
comment (at the end of its last line, or else the comment lines right below it) opens with
a value, `# 3.5 0.5` or `# [2.0, 2.0]: carried 2 units`, must print that value, all of it
(doctest's comparison: runs of whitespace are equal, `...` stands for any text; what
follows a `: ` may be a remark). A comment that opens with words (`# > 0: a faster
push...`, `# few bodies: ...`) describes and is not compared; see `OUTPUT`.

Not run (the skip rule of the fence, as before): blocks fenced ```py (docs/rl.md's
Stable-Baselines3 training, its CleanRL-style host loop and the gymnax bridge: minutes of
training, or packages outside the `dev` extra's core; tests/test_sb3.py and
tests/test_bridges.py run the same calls), ```sh (shell commands) and plain ``` (the two
commands, signatures, sketches).
"""

import ast
import code
import contextlib
import doctest
import io
import pathlib
import re
import sys
import tokenize

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[1]
PAGES = [ROOT / "README.md"] + sorted((ROOT / "docs").glob("*.md"))

# A comment that states an output opens with a value: a number, a bracket, a quote,
# True/False/None/nan/inf, or a repr such as `Discrete(n=5, ...)`.
OUTPUT = re.compile(r"""[-+]?\.?\d|[\[({'"]|(True|False|None|nan|inf)\b|[A-Z]\w*\(""")

_FLAGS = doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE


def _python_blocks_at(path: pathlib.Path) -> list[tuple[int, str]]:
  """`(line of the first code line in the page, code)` of each ```python block."""
  text = path.read_text()
  return [(text.count("\n", 0, m.start(1)) + 1, m.group(1))
          for m in re.finditer(r"^```python\n(.*?)^```", text, flags=re.S | re.M)]


def _python_blocks(path: pathlib.Path) -> list[str]:
  return [block for _, block in _python_blocks_at(path)]


class PasteError(Exception):
  """What the REPL would have printed as a traceback."""


class _Console(code.InteractiveConsole):
  """An interactive console that raises where the REPL prints a traceback."""

  def showsyntaxerror(self, filename=None, **kwargs):
    del filename, kwargs
    raise PasteError(f"{sys.exc_info()[1]!r}")

  def showtraceback(self):
    raise PasteError(f"{sys.exc_info()[1]!r}")


def paste(block: str, filename: str = "<paste>") -> dict[int, str]:
  """Pastes `block` line by line into a fresh console, then presses Enter once more (the
  blank line that ends a last indented block).

  Returns:
    `{line: output}`: for each line that completed a statement (1-based), what running
    that statement printed, echoed values included.

  Raises:
    PasteError: naming the line, if the console raised a SyntaxError or the code raised.
  """
  console = _Console(locals={"__name__": "__console__", "__doc__": None}, filename=filename)
  outputs = {}
  out = io.StringIO()
  for number, line in enumerate(block.splitlines() + [""], start=1):
    try:
      with contextlib.redirect_stdout(out):
        more = console.push(line)
    except PasteError as e:
      raise PasteError(f"{filename}, line {number}: {line!r}: {e}") from e.__context__
    if not more:
      outputs[number] = out.getvalue()
      out = io.StringIO()
  return outputs


def claims(block: str) -> dict[int, str]:
  """`{last line of a top-level print(...): its comment}` where the comment states an
  output (`OUTPUT`): the comment at the end of that line, else the comment lines right
  below it (joined by newlines)."""
  comments = {tok.start[0]: tok.string[1:].strip()
              for tok in tokenize.generate_tokens(io.StringIO(block).readline)
              if tok.type == tokenize.COMMENT}
  lines = block.splitlines()
  found = {}
  for node in ast.parse(block).body:
    if not (isinstance(node, ast.Expr) and isinstance(node.value, ast.Call)
            and isinstance(node.value.func, ast.Name) and node.value.func.id == "print"):
      continue
    end = node.end_lineno
    text = comments.get(end)
    if text is None:
      below = []
      while end + len(below) < len(lines) and lines[end + len(below)].lstrip().startswith("#"):
        below.append(comments[end + len(below) + 1])
      text = "\n".join(below)
    if OUTPUT.match(text):
      found[end] = text
  return found


def states(claim: str, output: str) -> bool:
  """Whether `claim` (a comment: an output, then maybe `: ` and a remark) states all of
  `output`, compared as doctest does with ELLIPSIS and NORMALIZE_WHITESPACE."""
  heads = [claim] + [claim[:m.start()] for m in re.finditer(": ", claim)]
  checker = doctest.OutputChecker()
  return any(checker.check_output(head + "\n", output, _FLAGS) for head in heads)


def test_pages_are_found():
  names = [p.relative_to(ROOT).as_posix() for p in PAGES]
  assert "README.md" in names and "docs/index.md" in names and "docs/physics.md" in names


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.relative_to(ROOT).as_posix())
def test_python_blocks_paste_and_print_what_they_say(page):
  name = page.relative_to(ROOT).as_posix()
  printed, wrong = [], []
  for start, block in _python_blocks_at(page):
    compile(block, f"{name}, block at line {start}", "exec")  # A script too.
    try:
      outputs = paste(block, f"{name}, block at line {start}")
    except PasteError as e:
      pytest.fail(f"pasted into the REPL: {e}")
    printed += outputs.values()
    for line, claim in claims(block).items():
      if not states(claim, outputs[line]):
        wrong.append(f"{name}:{start + line - 1}: prints {outputs[line]!r}, its comment says "
                     f"{claim!r}")
  assert not wrong, "\n".join(wrong)
  if page.name in ("README.md", "index.md"):
    assert printed
    assert "-0.2" in "".join(printed)  # The player backs off by the overlap.


def test_readme_two_box_task_is_the_rl_page_s():
  """The README's two-box task is docs/rl.md's, which tests/test_env.py holds to
  examples/two_box_task.py (so the README shows the task examples/ppo.py trains)."""
  def task(path):
    return [b for b in _python_blocks(path) if 'name="two_box"' in b]
  assert task(ROOT / "README.md") == task(ROOT / "docs" / "rl.md")
  assert len(task(ROOT / "README.md")) == 1


@pytest.mark.parametrize("page", ["README.md", "docs/index.md", "docs/toolkit.md"])
def test_every_print_of_the_first_pages_states_its_output(page):
  """The pages a newcomer reads first: no print there only describes what it prints."""
  for start, block in _python_blocks_at(ROOT / page):
    prints = [node.end_lineno for node in ast.parse(block).body
              if isinstance(node, ast.Expr) and isinstance(node.value, ast.Call)
              and getattr(node.value.func, "id", None) == "print"]
    unchecked = sorted(set(prints) - set(claims(block)))
    assert not unchecked, [f"{page}:{start + line - 1}" for line in unchecked]
  assert any(claims(block) for block in _python_blocks(ROOT / page))  # Some are checked.


# --- The checker itself (no JAX) ------------------------------------------------------------


def test_paste_needs_a_blank_line_after_an_indented_block():
  # Issue 31: the README's `def box_x(...)` then `print(...)` raised this in the REPL.
  with pytest.raises(PasteError, match=r"line 3: 'print\(f\(\)\)': SyntaxError"):
    paste("def f():\n  return 1\nprint(f())\n")
  assert paste("def f():\n  return 1\n\nprint(f())\n")[4] == "1\n"


def test_paste_echoes_values_and_raises_what_the_code_raises():
  assert paste("x = 2\nx + 1\n") == {1: "", 2: "3\n", 3: ""}
  assert paste("for k in range(2):\n  print(k)\n")[3] == "0\n1\n"  # Run by the last Enter.
  with pytest.raises(PasteError, match=r"line 2: .*ZeroDivisionError"):
    paste("x = 0\n1 / x\n")
  with pytest.raises(PasteError, match="NameError"):  # Each paste starts afresh.
    paste("x\n")


@pytest.mark.parametrize("block, found", [
    ("print(1.0)  # 1.0\n", {1: "1.0"}),
    ("print(1.0)  # a float, > 0\n", {}),
    ("print(1,\n      2)  # 1 2: two\n", {2: "1 2: two"}),
    ("print([1, 2])\n# [1, 2]: below\nx = 2  # 5\n", {1: "[1, 2]: below"}),
    ("print(1)\n\n# 1\n", {}),
    ("def f():\n  print(1)  # 1\n", {}),
    ("f(1)  # 1\nprint  # 1\n", {}),
    ("print(e)  # Discrete(n=5, ...) (73,)\n", {1: "Discrete(n=5, ...) (73,)"}),
    ("print(x)  # -0.2 True\n", {1: "-0.2 True"}),
])
def test_claims_are_the_comments_that_open_with_a_value(block, found):
  assert claims(block) == found


@pytest.mark.parametrize("claim, output, ok", [
    ("3.5 0.5", "3.4999986 0.49973127\n", False),  # Issue 31's README example 1.
    ("3.5 0.5", "3.5 0.5\n", True),
    ("[-0.2 0.8 1.8]", "[-0.2  0.8  1.8]\n", True),
    ("2.5 True: on the ledge", "2.5 True\n", True),
    ("2.5 True: on the ledge", "2.5 False\n", False),
    ("True: the box crossed", "True [1, 0, 0, 0]\n", False),  # All of it, not a prefix.
    ("True", "True\nFalse\n", False),
    ("Discrete(n=5, ...) (73,)", "Discrete(n=5, start=0) (73,)\n", True),
    ("Discrete(n=5, ...) (73,)", "Discrete(n=4, start=0) (73,)\n", False),
    ("{'a': 1}", "{'a': 1}\n", True),
])
def test_states_compares_all_of_the_output(claim, output, ok):
  assert states(claim, output) is ok
