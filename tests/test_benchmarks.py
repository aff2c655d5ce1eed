"""Every benchmark script runs at a tiny size and writes its tables: benchmarks cannot rot.

The scripts are found, not listed: every `benchmarks/*.py` except the private `_*.py`
helpers. Each runs in its own interpreter as `python benchmarks/NAME.py --smoke --out
DIR` (tiny sizes, a few settings and steps, no waiting for a quiet machine) with DIR a
temporary directory, so the committed tables in `benchmarks/results/` are never
overwritten; it must exit 0 and write at least one Markdown table into DIR. The figures
of a smoke run mean nothing and are not checked: speed is never asserted in a test.
Peer engines that are not installed (Box2D, pymunk, Jax2D) are skipped by the scripts
with a message, never a failure.
"""

import importlib
import os
import pathlib
import subprocess
import sys

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[1]
BENCHMARKS = ROOT / "benchmarks"
SCRIPTS = sorted(p.name for p in BENCHMARKS.glob("*.py") if not p.name.startswith("_"))
# What a script must offer; said whenever one does not.
CONTRACT = (
    "every benchmarks/*.py script (except private _*.py helpers) must accept `--smoke` (tiny "
    "sizes: seconds, not minutes; the whole code path, no waiting) and `--out DIR` (the directory "
    "for its tables and plots), and write at least one Markdown table (a .md file with a "
    "`|---|` row) into DIR. `_bench.add_common_args(parser)` adds both options and "
    "`_bench.out_dir(args)` gives DIR; see benchmarks/README.md.")
TIMEOUT_S = 900  # Per script; a smoke run takes seconds on a quiet machine.


def _tail(text: str, lines: int = 40) -> str:
  return "\n".join(text.strip().splitlines()[-lines:])


def test_scripts_are_found():
  # The discovery itself: the scripts this suite knew when it was written are among them.
  assert {"peers.py", "profile_step.py", "throughput.py", "against.py"} <= set(SCRIPTS)
  assert not any(name.startswith("_") for name in SCRIPTS)


@pytest.mark.parametrize("script", SCRIPTS)
def test_smoke_run_writes_its_tables(script, tmp_path):
  out = tmp_path / "out"
  committed = {p.name: p.stat().st_mtime_ns for p in (BENCHMARKS / "results").glob("*")}
  env = {**os.environ, "JAX_PLATFORMS": "cpu", "MPLBACKEND": "Agg"}
  try:
    done = subprocess.run([sys.executable, str(BENCHMARKS / script), "--smoke", "--out", str(out)],
                          cwd=tmp_path, env=env, capture_output=True, text=True, timeout=TIMEOUT_S)
  except subprocess.TimeoutExpired:
    pytest.fail(f"{script} --smoke ran past {TIMEOUT_S} s: {CONTRACT}")
  if done.returncode and "unrecognized arguments" in done.stderr:
    pytest.fail(f"{script} has no smoke mode ({_tail(done.stderr, 2)}): {CONTRACT}")
  assert done.returncode == 0, (
      f"{script} --smoke --out DIR failed (exit {done.returncode}). {CONTRACT}\n"
      f"--- stdout (end) ---\n{_tail(done.stdout)}\n--- stderr (end) ---\n{_tail(done.stderr)}")
  tables = sorted(out.glob("*.md")) if out.is_dir() else []
  assert tables, f"{script} --smoke wrote no .md into --out {out}: {CONTRACT}"
  for table in tables:
    assert "|---" in table.read_text(), f"{script} wrote {table.name} without a table: {CONTRACT}"
    # The committed result of the same name was not touched (it went to --out instead).
    before = committed.get(table.name)
    if before is not None:
      assert (BENCHMARKS / "results" / table.name).stat().st_mtime_ns == before, (
          f"{script} --smoke --out DIR also rewrote benchmarks/results/{table.name}")


def test_missing_peers_are_skipped_with_a_message(monkeypatch):
  monkeypatch.syspath_prepend(str(BENCHMARKS))
  peers = importlib.import_module("peers")
  for module in ("Box2D", "box2d", "pymunk", "jax2d"):
    monkeypatch.setitem(sys.modules, module, None)  # `import` raises ImportError.
  found, skipped = peers.load_peers()
  assert found == []
  names = [line.split(":", 1)[0] for line in skipped]
  assert names == ["Box2D", "Box2D v3", "pymunk", "Jax2D"]
  assert all("skipped, import failed" in line for line in skipped)
