"""Every benchmark script runs at a tiny size and writes its tables: benchmarks cannot rot.

The scripts are found, not listed: every `benchmarks/*.py` except the private `_*.py`
helpers. Each runs as `python benchmarks/NAME.py --smoke --out DIR` would (tiny sizes, a
few settings and steps, no waiting for a quiet machine) with DIR a temporary directory,
so the committed tables in `benchmarks/results/` are never overwritten; it must exit 0
and write at least one Markdown table into DIR, whose first line names the commit it
measured (`commit <sha>`: every result says which code it is from). The figures of a
smoke run mean nothing and are not checked: speed is never asserted in a test. Peer
engines that are not installed (Box2D, pymunk, Jax2D) are skipped by the scripts with a
message, never a failure; a script whose packages are missing altogether (SB3) is
skipped by `refresh.py`, with the message, and its test skipped with it.

The smoke runs are `benchmarks/refresh.py --smoke`, the command a developer types: it
runs every script in one interpreter (`benchmarks/_smoke.py`, one after another): one
`import jax` (torch, matplotlib, ...) for all of them instead of one each, and the
programs several scripts compile are compiled once (issue 30: 23 interpreters took
about 300 CPU seconds). A script that kills or hangs the interpreter fails alone: the
rest run in a new one. `refresh.py`'s own test checks its summary table.
"""

import importlib
import json
import os
import pathlib
import re
import subprocess
import sys
import time

import numpy as np
import pytest

ROOT = pathlib.Path(__file__).resolve().parents[1]
BENCHMARKS = ROOT / "benchmarks"
SCRIPTS = sorted(p.name for p in BENCHMARKS.glob("*.py") if not p.name.startswith("_"))
# What a script must offer; said whenever one does not.
CONTRACT = (
    "every benchmarks/*.py script (except private _*.py helpers) must accept `--smoke` (tiny "
    "sizes: seconds, not minutes; the whole code path, no waiting) and `--out DIR` (the directory "
    "for its tables and plots), and write at least one Markdown table (a .md file with a "
    "`|---|` row) into DIR, starting with `_bench.Run.header()` (`_bench.write_result` writes "
    "both). `_bench.add_common_args(parser)` adds both options and `_bench.out_dir(args)` gives "
    "DIR; see benchmarks/README.md.")
TIMEOUT_S = 900  # Per script; a smoke run takes seconds on a quiet machine.
HEADER = re.compile(r"commit ([0-9a-f]{12,}|unknown)\b")
DRIVER = "refresh.py"


def _tail(text: str, lines: int = 40) -> str:
  return "\n".join(text.strip().splitlines()[-lines:])


def _bench_module(monkeypatch, name: str):
  monkeypatch.syspath_prepend(str(BENCHMARKS))
  return importlib.import_module(name)


def test_scripts_are_found():
  # The discovery itself: the scripts this suite knew when it was written are among them.
  assert {"peers.py", "profile_step.py", "throughput.py", "against.py", DRIVER} <= set(SCRIPTS)
  assert not any(name.startswith("_") for name in SCRIPTS)


class SmokeRuns:
  """`benchmarks/refresh.py --smoke` of the selected scripts (in the tests' order), started
  at once in the background; `result(script)` waits for one script's result (its exit
  code, stdout, stderr and output directory; `refresh.py`'s is the whole run's). So each
  test's duration is its own script's."""

  def __init__(self, scripts: list[str], root: pathlib.Path):
    self.root, self.results = root, {}
    self.scripts = [s for s in scripts if s != DRIVER]
    env = {**os.environ, "JAX_PLATFORMS": "cpu", "MPLBACKEND": "Agg"}
    self.log = root / "refresh.txt"
    with open(self.log, "w") as out:
      self.proc = subprocess.Popen(
          [sys.executable, str(BENCHMARKS / DRIVER), "--smoke", "--out", str(root),
           "--timeout", str(TIMEOUT_S), "--only", *[s[:-3] for s in self.scripts]],
          cwd=root, env=env, stdout=out, stderr=subprocess.STDOUT)

  def result(self, script: str) -> dict:
    if script == DRIVER:
      code = self.proc.wait()
      text = self.log.read_text()
      return dict(code=code, stdout=text, stderr="", out=self.root)
    work = self.root / script[:-3]
    done = work / "result.json"
    while not done.exists():
      if self.proc.poll() is not None and not done.exists():
        return dict(code=None, why=f"refresh.py ended (exit {self.proc.returncode}) without it",
                    runner=self.log.read_text(), stdout="", stderr="", out=work / "out")
      time.sleep(0.1)
    result = json.loads(done.read_text())
    for name in ("stdout", "stderr"):
      path = work / f"{name}.txt"
      result[name] = path.read_text() if path.exists() else ""
    result["out"] = work / "out"
    return result

  def close(self):
    if self.proc.poll() is None:
      self.proc.kill()
      self.proc.wait()


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
  if done.get("skipped"):
    pytest.skip(f"{script}: {done['skipped']}")
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
    text = table.read_text()
    assert "|---" in text, f"{script} wrote {table.name} without a table: {CONTRACT}"
    assert HEADER.match(text), (
        f"{script} wrote {table.name} without naming its commit in the first line "
        f"(got {text.splitlines()[0]!r}): {CONTRACT}")
    # The committed result of the same name was not touched (it went to --out instead).
    before = committed.get(table.name)
    if before is not None:
      assert (BENCHMARKS / "results" / table.name).stat().st_mtime_ns == before, (
          f"{script} --smoke --out DIR also rewrote benchmarks/results/{table.name}")


def test_missing_peers_are_skipped_with_a_message(monkeypatch):
  peers = _bench_module(monkeypatch, "peers")
  for module in ("Box2D", "box2d", "pymunk", "jax2d"):
    monkeypatch.setitem(sys.modules, module, None)  # `import` raises ImportError.
  found, skipped = peers.load_peers()
  assert found == []
  names = [line.split(":", 1)[0] for line in skipped]
  assert names == ["Box2D", "Box2D v3", "pymunk", "Jax2D"]
  assert all("skipped, import failed" in line for line in skipped)


def test_a_peer_worker_that_cannot_start_is_skipped_with_its_reason(monkeypatch):
  bench = _bench_module(monkeypatch, "_bench")
  found, skipped = bench.load_peers(("Box2D v3",), v3_python="/nonexistent/python3.12")
  assert found == []
  assert len(skipped) == 1 and skipped[0].startswith("Box2D v3: skipped, the worker failed")
  assert "/nonexistent/python3.12" in skipped[0]


def test_the_worker_answers_as_the_engine_in_this_process(monkeypatch):
  """`_peer_worker.py` in another interpreter (here, this one) gives what the same
  adapter gives in this process: the JSON-lines protocol `--v3-python` relies on."""
  pytest.importorskip("Box2D")
  bench = _bench_module(monkeypatch, "_bench")
  here, there = bench.PythonPeer("Box2D"), bench.PythonPeer("Box2D", python=sys.executable)
  try:
    assert there.version.startswith(here.version)
    scene = bench.push_chain().peer(speed=2.0)
    timed = [p.time(scene, settle=6, steps=4, min_s=1e9, max_reps=2) for p in (here, there)]
    assert [t["reps"] for t in timed] == [2, 2]
    assert all(t["seconds"] > 0 for t in timed)
    assert timed[0]["pos"].tolist() == timed[1]["pos"].tolist()
    kicked = [(3, {2: (1.0, 0.0)}), (2, {})]  # The player set moving, then left alone.
    (p0, v0), (p1, v1) = (p.record(scene, kicked) for p in (here, there))
    assert p0.shape == v0.shape == (6, len(scene["mass"]), 2)
    assert p0.tolist() == p1.tolist() and v0.tolist() == v1.tolist()
    with pytest.raises(RuntimeError, match="KeyError"):
      there.time({"half": []}, 1, 1)  # A malformed scene: the worker says what failed.
    assert there.time(scene, 0, 1)["reps"] == 1  # The worker goes on after an error.
  finally:
    there.close()
  assert there.proc.returncode == 0


def test_result_header_names_the_commit_and_the_command(monkeypatch):
  bench = _bench_module(monkeypatch, "_bench")
  line = bench.commit_line(ROOT / "src")
  sha = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "HEAD"], capture_output=True,
                       text=True).stdout.strip()
  if not sha:
    pytest.skip("not a git checkout")
  m = re.fullmatch(r"commit ([0-9a-f]{12,})( dirty)?", line)
  assert m and sha.startswith(m.group(1)), line
  dirty = subprocess.run(["git", "-C", str(ROOT), "status", "--porcelain", "--", "src"],
                         capture_output=True, text=True).stdout.strip()
  assert bool(m.group(2)) == bool(dirty)
  argv = [str(BENCHMARKS / "peers.py"), "--quick", "--out", "/tmp/x", "--out=/tmp/y", "--rounds", "5"]
  assert bench.command_line(argv) == "python benchmarks/peers.py --quick --rounds 5"
  run = bench.Run.start(src=ROOT / "src", command="python benchmarks/x.py")
  header = run.header()
  assert header[0] == line and "`python benchmarks/x.py`" in header[1] and "UTC" in header[1]
  assert "cores" in header[2] and "jax" in header[2] and "Python" in header[2]
  assert "at the start" in header[3] and "at the end" in header[3] and header[-1] == ""


def test_refresh_plans_every_script_and_names_every_result(monkeypatch):
  refresh = _bench_module(monkeypatch, "refresh")
  planned = {b.file for b in refresh.PLAN}
  assert set(SCRIPTS) - planned == {DRIVER}, "a benchmark script missing from refresh.PLAN"
  assert refresh.PLAN[0].name == "error_vs_time"  # The mission's report comes first.
  claimed = {f for b in refresh.PLAN for f in b.writes}
  for path in (BENCHMARKS / "results").iterdir():
    assert path.name in claimed or path.name in refresh.NOT_REGENERATED, (
        f"results/{path.name} is written by no entry of refresh.PLAN and not listed in "
        "refresh.NOT_REGENERATED")
  listed = subprocess.run([sys.executable, str(BENCHMARKS / DRIVER), "--list"], capture_output=True,
                          text=True, check=True).stdout
  assert all(b.name in listed for b in refresh.PLAN) and "total" in listed


def test_the_workers_take_each_engines_accuracy_setting(monkeypatch):
  """`scene["solver"]` sets each peer's accuracy (error_vs_time's fronts): fewer Box2D
  iterations and fewer pymunk iterations change a push chain's trajectory."""
  bench = _bench_module(monkeypatch, "_bench")
  scene = bench.push_chain().peer(speed=2.0)
  for name, cheap, default in (("Box2D", {"iterations": [1, 1]}, {"iterations": [8, 3]}),
                               ("pymunk", {"iterations": 1}, {"iterations": 10})):
    pytest.importorskip({"Box2D": "Box2D", "pymunk": "pymunk"}[name])
    peer = bench.PythonPeer(name)
    runs = [peer.record({**scene, "solver": s}, [(150, {})])[0] for s in (cheap, default, None)]
    assert not np.array_equal(runs[0], runs[1]), name
    np.testing.assert_array_equal(runs[1], runs[2], err_msg=name)  # The default is the default.
