"""Every benchmark script runs at a tiny size and writes its tables: benchmarks cannot rot.

The scripts are found, not listed: every `benchmarks/*.py` except the private `_*.py`
helpers. Each runs as `python benchmarks/NAME.py --smoke --out DIR` would (tiny sizes, a
few settings and steps, no waiting for a quiet machine) with DIR a temporary directory,
so the committed tables in `benchmarks/results/` are never overwritten; it must exit 0
and write at least one Markdown table into DIR. The figures of a smoke run mean nothing
and are not checked: speed is never asserted in a test. Peer engines that are not
installed (Box2D, pymunk, Jax2D) are skipped by the scripts with a message, never a
failure.

The smoke runs share one interpreter (`benchmarks/_smoke.py`, started once for the
module, runs each script as `__main__` with that command line, one after another): one
`import jax` (torch, matplotlib, ...) for all of them instead of one each, and the
programs several scripts compile are compiled once (issue 30: 23 interpreters took
about 300 CPU seconds). A script that kills or hangs the interpreter fails alone: the
rest run in a new one.
"""

import importlib
import json
import os
import pathlib
import subprocess
import sys
import time

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


class SmokeRuns:
  """Every script's smoke run in one interpreter (`benchmarks/_smoke.py`), started at once
  in the background, in the tests' order; `result(script)` waits for one script's result:
  its exit code, stdout, stderr and output directory. So each test's duration is its own
  script's. A script that ends the interpreter (a crash) or runs past `TIMEOUT_S` gets
  the exit code None and the interpreter's output; the scripts after it run in a new
  interpreter."""

  def __init__(self, scripts: list[str], root: pathlib.Path):
    self.todo, self.root, self.results, self.runner = list(scripts), root, {}, None
    self.env = {**os.environ, "JAX_PLATFORMS": "cpu", "MPLBACKEND": "Agg"}

  def _start(self):
    self.log = self.root / f"runner-{len(self.results)}.txt"
    with open(self.log, "w") as out:
      self.runner = subprocess.Popen(
          [sys.executable, str(BENCHMARKS / "_smoke.py"), str(self.root), *self.todo],
          cwd=self.root, env=self.env, stdout=out, stderr=subprocess.STDOUT)
    self.deadline = time.monotonic() + TIMEOUT_S

  def _next(self):
    """Waits for the next script's end (or the interpreter's)."""
    script = self.todo[0]
    if self.runner is None:
      self._start()
    done = self.root / pathlib.Path(script).stem / "result.json"
    while not done.exists():
      if self.runner.poll() is not None or time.monotonic() > self.deadline:
        if self.runner.poll() is None:
          self.runner.kill()
          self.runner.wait()
          why = f"ran past {TIMEOUT_S} s"
        else:
          why = f"ended the interpreter (exit {self.runner.returncode})"
        self.runner = None
        return self._finish(self.todo.pop(0), dict(code=None, why=why, runner=self.log.read_text()))
      time.sleep(0.1)
    self.deadline = time.monotonic() + TIMEOUT_S
    return self._finish(self.todo.pop(0), json.loads(done.read_text()))

  def _finish(self, script, result):
    work = self.root / pathlib.Path(script).stem
    for name in ("stdout", "stderr"):
      path = work / f"{name}.txt"
      result[name] = path.read_text() if path.exists() else ""
    result["out"] = work / "out"
    self.results[script] = result
    if not self.todo and self.runner is not None:
      self.runner.wait()
    return result

  def result(self, script: str) -> dict:
    while script not in self.results:
      self._next()
    return self.results[script]

  def close(self):
    if self.runner is not None and self.runner.poll() is None:
      self.runner.kill()
      self.runner.wait()


@pytest.fixture(scope="module")
def smoke_runs(request, tmp_path_factory):
  """The selected scripts' smoke runs (in the tests' order), in one interpreter, and the
  committed results' mtimes before."""
  committed = {p.name: p.stat().st_mtime_ns for p in (BENCHMARKS / "results").glob("*")}
  scripts = [item.callspec.params["script"] for item in request.session.items
             if item.path == request.path and hasattr(item, "callspec")
             and "script" in item.callspec.params]
  runs = SmokeRuns(list(dict.fromkeys(scripts)), tmp_path_factory.mktemp("smoke"))
  yield runs, committed
  runs.close()


@pytest.mark.parametrize("script", SCRIPTS)
def test_smoke_run_writes_its_tables(script, smoke_runs):
  runs, committed = smoke_runs
  done = runs.result(script)
  if done["code"] is None:
    pytest.fail(f"{script} --smoke {done['why']}: {CONTRACT}\n"
                f"--- interpreter (end) ---\n{_tail(done['runner'])}\n"
                f"--- stderr (end) ---\n{_tail(done['stderr'])}")
  if done["code"] and "unrecognized arguments" in done["stderr"]:
    pytest.fail(f"{script} has no smoke mode ({_tail(done['stderr'], 2)}): {CONTRACT}")
  assert done["code"] == 0, (
      f"{script} --smoke --out DIR failed (exit {done['code']}). {CONTRACT}\n"
      f"--- stdout (end) ---\n{_tail(done['stdout'])}\n--- stderr (end) ---\n{_tail(done['stderr'])}")
  out = done["out"]
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
