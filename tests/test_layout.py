"""Layout (DESIGN.md section 7): modules import only modules before them, never inside a function."""

import ast
import pathlib
import subprocess
import sys

import pytest

SRC = pathlib.Path(__file__).resolve().parents[1] / "src" / "jaxchain"

# Every module of src/jaxchain (but the package's __init__), in dependency order: each
# may import only modules before it.
ORDER = ("reference", "sharding", "status", "world", "scenes", "broadphase", "core", "flags", "metrics",
         "sizing", "config", "stepping", "queries", "levels", "drawing", "env", "bridges",
         "compile_cache", "cli")


def _jaxchain_imports(node: ast.AST) -> list[str]:
  """The jaxchain modules one import statement names (`[]` for other imports)."""
  if isinstance(node, ast.Import):
    return [a.name.split(".")[1] if "." in a.name else "jaxchain" for a in node.names
            if a.name.split(".")[0] == "jaxchain"]
  if isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
    parts = node.module.split(".")
    if parts[0] != "jaxchain":
      return []
    if len(parts) > 1:
      return [parts[1]]
    return [a.name for a in node.names]
  return []


def _files(name: str) -> list[pathlib.Path]:
  """A module's file, or every file of a subpackage (`env/`)."""
  path = SRC / f"{name}.py"
  return [path] if path.is_file() else sorted((SRC / name).glob("*.py"))


def test_order_lists_every_module():
  modules = [p.stem for p in SRC.glob("*.py") if p.stem != "__init__"]
  packages = [p.parent.name for p in SRC.glob("*/__init__.py")]
  assert sorted(ORDER) == sorted(modules + packages)


@pytest.mark.parametrize("name", ORDER)
def test_imports_only_earlier_modules_at_the_top(name):
  for path in _files(name):  # A subpackage's files may also import each other.
    tree = ast.parse(path.read_text(), filename=str(path))
    where = path.relative_to(SRC)
    top = [node for node in tree.body if isinstance(node, (ast.Import, ast.ImportFrom))]
    for node in top:
      for dep in _jaxchain_imports(node):
        assert dep in ORDER[:ORDER.index(name)] + (name,) * (path.name != f"{name}.py"), (
            f"{where} line {node.lineno} imports jaxchain.{dep}, which is not before it")
    nested = [node for node in ast.walk(tree)
              if isinstance(node, (ast.Import, ast.ImportFrom)) and node not in top
              and _jaxchain_imports(node)]
    assert not nested, f"{where} imports jaxchain modules below the top level: " + ", ".join(
        f"line {node.lineno}" for node in nested)


def test_modules_import_in_layout_order_in_a_fresh_interpreter():
  code = "; ".join(f"import jaxchain.{name}" for name in ORDER) + "; import jaxchain as jc; jc.Config.for_world"
  out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
  assert out.returncode == 0, out.stderr
