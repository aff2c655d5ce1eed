"""The Python examples of the README and of every docs page run as written.

Each file's ```python blocks run in order in one namespace (a later block may use names an
earlier one defined). Blocks fenced without `python` (shell commands, signatures, sketches)
are not run.
"""

import pathlib
import re

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[1]
PAGES = [ROOT / "README.md"] + sorted((ROOT / "docs").glob("*.md"))


def _python_blocks(path: pathlib.Path) -> list[str]:
  return re.findall(r"^```python\n(.*?)^```", path.read_text(), flags=re.S | re.M)


def test_pages_are_found():
  names = [p.relative_to(ROOT).as_posix() for p in PAGES]
  assert "README.md" in names and "docs/index.md" in names and "docs/physics.md" in names


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.relative_to(ROOT).as_posix())
def test_python_blocks_run(page, capsys):
  blocks = _python_blocks(page)
  namespace = {"__name__": "__docs__"}
  for block in blocks:
    exec(compile(block, str(page), "exec"), namespace)
  out = capsys.readouterr().out
  if page.name in ("README.md", "index.md"):
    assert blocks
    assert "-0.2" in out  # The player backs off by the overlap.


def test_readme_two_box_task_is_the_rl_page_s():
  """The README's two-box task is docs/rl.md's, which tests/test_env.py holds to
  examples/two_box_task.py (so the README shows the task examples/ppo.py trains)."""
  def task(path):
    return [b for b in _python_blocks(path) if 'name="two_box"' in b]
  assert task(ROOT / "README.md") == task(ROOT / "docs" / "rl.md")
  assert len(task(ROOT / "README.md")) == 1
