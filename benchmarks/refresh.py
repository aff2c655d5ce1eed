"""Regenerates every result in `benchmarks/results/`, in order, one line per benchmark.

    python benchmarks/refresh.py --list              # the plan, with estimated times
    python benchmarks/refresh.py                     # everything (hours on a quiet 2-core machine)
    python benchmarks/refresh.py --quick             # each script's quick mode where it has one
    python benchmarks/refresh.py --only peers targets --v3-python ~/venvs/box2d-v3/bin/python
    python benchmarks/refresh.py --skip ppo_sb3 suite_time
    python benchmarks/refresh.py --smoke --out /tmp/smoke   # every script's smoke run (the suite's)

Order (`PLAN`): `error_vs_time` first (error against run time: the mission's report),
then the figures the README quotes (peers, targets, the demo against earlier commits, the
work meter), then the rest; `suite_time` (the whole test suite) last. Each benchmark runs
in its own interpreter as `python benchmarks/NAME.py ARGS [--out DIR]`, its output in a
log file (the folder is printed first; a failure prints the end of its log), and ends
with one line: its name, seconds and `ok` or `FAILED`. A failure does not stop the run:
the failures are listed at the end and the exit code is 1. A benchmark whose packages
are not installed (`Bench.requires`) is skipped with a message naming them, never
silently. Every script writes its results with the commit it measured in their first
lines (`_bench.Run`); this writes `refresh.md` (what ran, how long, what failed) into
the output folder too.

`--smoke --out DIR` runs every script's `--smoke` in ONE interpreter (`_smoke.py`: one
`import jax` for all, and the programs several scripts compile compiled once), each
writing into `DIR/NAME/out`, its exit code and times into `DIR/NAME/result.json`; a script
that ends the interpreter or runs past `--timeout` fails alone and the rest go on in a
new one. `tests/test_benchmarks.py` runs this and checks each script's tables.

Estimated times are for a quiet 2-core machine, from the scripts' docstrings and the
results' own run times; a loaded machine takes longer.
"""

from __future__ import annotations

import argparse
import dataclasses
import importlib.util
import json
import os
import pathlib
import subprocess
import sys
import tempfile
import time

HERE = pathlib.Path(__file__).resolve().parent
RESULTS = HERE / "results"
SMOKE_TIMEOUT_S = 900.0  # Per script, in --smoke: a smoke run takes seconds on a quiet machine.


@dataclasses.dataclass(frozen=True)
class Bench:
  """One benchmark of the plan.

  Attributes:
    name: the script `benchmarks/NAME.py` (a plan entry may run a script again with
      other arguments: `script`).
    args: its arguments for a full run (the command the docs quote).
    quick: its arguments under `--quick`; None where it has no quick mode (the full run).
    estimate: seconds of the full and the quick run, quiet 2-core machine.
    writes: the files it writes into `results/`.
    requires: modules it cannot run without, and how to get them.
    script: the script's name when it is not `name`.
    in_quick: whether `--quick` runs it (False where another entry's quick run is it).
  """

  name: str
  args: tuple[str, ...] = ()
  quick: tuple[str, ...] | None = None
  estimate: tuple[float, float] = (60.0, 60.0)
  writes: tuple[str, ...] = ()
  requires: tuple[tuple[str, ...], str] = ((), "")
  script: str | None = None
  in_quick: bool = True

  @property
  def file(self) -> str:
    return f"{self.script or self.name}.py"

  def argv(self, quick: bool) -> list[str]:
    return list(self.quick if quick and self.quick is not None else self.args)

  def missing(self) -> list[str]:
    """The required modules that do not import here."""
    return [m for m in self.requires[0] if importlib.util.find_spec(m) is None]


PEERS = (("Box2D", "pymunk"), '`pip install -e ".[peers]"`')
SB3 = (("stable_baselines3", "torch"), '`pip install -e ".[sb3]"` and torch (docs/rl.md)')

PLAN = (
    Bench("error_vs_time", (), ("--quick",), (1800, 900),
          ("error_vs_time.md", "error_vs_time.png", "error_vs_time.json")),
    Bench("error_vs_time_quick", ("--quick",), None, (900, 900),
          ("error_vs_time_quick.md", "error_vs_time_quick.png", "error_vs_time_quick.json"),
          script="error_vs_time", in_quick=False),
    Bench("peers", (), ("--quick",), (900, 300), ("peers.md",), PEERS),
    Bench("targets", (), None, (360, 360), ("targets.md",)),
    Bench("against", ("--against", "b26b41f", "6272a46", "--batch", "1024", "--steps", "200",
                      "--rounds", "2"), None, (300, 300), ("against.md",)),
    Bench("work_meter", (), None, (60, 60), ("work_meter.md",)),
    Bench("profile_step", (), None, (150, 150), ("profile.md",)),
    Bench("neighbors", (), None, (360, 360), ("neighbors.md",)),
    Bench("throughput", (), ("--quick",), (300, 140), ("throughput.md", "throughput.png")),
    Bench("scaling", (), ("--quick",), (300, 150), ("scaling.md", "scaling.png")),
    Bench("specialisation", (), None, (180, 180), ("specialisation.md",)),
    Bench("env_throughput", (), ("--quick",), (285, 120), ("env_throughput.md",)),
    Bench("compile_time", (), None, (600, 600), ("compile_time.md",)),
    Bench("render_throughput", (), None, (420, 420), ("render_throughput.md",)),
    Bench("scaleout", (), ("--quick",), (720, 200), ("scaleout.md",)),
    Bench("conservation", (), ("--quick",), (120, 60), ("conservation.md",), PEERS),
    Bench("energy_rooms", (), None, (120, 120), ("energy_rooms.md",)),
    Bench("stability", (), ("--quick",), (180, 60), ("stability.md", "stability.png")),
    Bench("sokoban_replay", (), None, (300, 300), ("sokoban_replay.md",)),
    Bench("ppo_sb3", (), None, (720, 720), ("ppo_sb3.md", "ppo_sb3_curve.csv", "ppo_sb3_curve.png"),
          SB3),
    Bench("suite_time", (), None, (480, 480), ("suite.md",), (("pytest", "xdist"),
                                                              '`pip install -e ".[dev]"`')),
)
# In results/ but written by no script here: say so in --list rather than pretend.
NOT_REGENERATED = {
    "ppo.md": "hand-written from `examples/ppo.py` runs (its commands are in the file)",
    "ppo_platformer1.csv": "`examples/ppo.py --out` (see ppo.md)",
    "ppo_platformer1.png": "`examples/ppo.py --out` (see ppo.md)",
    "ppo_push_box_easy.csv": "`examples/ppo.py --out` (see ppo.md)",
    "ppo_push_box_easy.png": "`examples/ppo.py --out` (see ppo.md)",
    "ppo_push_box_easy_defaults.csv": "`examples/ppo.py --out` (see ppo.md)",
    "ppo_push_box_easy_defaults.png": "`examples/ppo.py --out` (see ppo.md)",
    "ppo_two_box.csv": "`examples/ppo.py --out` (see ppo.md)",
    "ppo_two_box.png": "`examples/ppo.py --out` (see ppo.md)",
    "ppo.png": "`examples/ppo.py --plot` (see ppo.md)",
    "refresh.md": "this script (what the last refresh ran)",
}


def scripts() -> list[str]:
  """Every benchmark script (`benchmarks/*.py` but the private `_*.py` helpers)."""
  return sorted(p.name for p in HERE.glob("*.py") if not p.name.startswith("_"))


def select(plan, only, skip, quick: bool) -> list[Bench]:
  names = [b.name for b in plan]
  for name in (only or []) + (skip or []):
    if name not in names:
      raise SystemExit(f"refresh.py: no benchmark {name!r}; the plan has {', '.join(names)}")
  chosen = [b for b in plan if (not only or b.name in only) and b.name not in (skip or [])]
  return [b for b in chosen if b.in_quick or not quick or (only and b.name in only)]


def minutes(s: float) -> str:
  return f"{s / 60:.0f} min" if s >= 90 else f"{s:.0f} s"


def show_plan(plan: list[Bench], quick: bool) -> None:
  total = 0.0
  print(f"{'benchmark':22s} {'estimate':>9s}  command")
  for b in plan:
    est = b.estimate[1 if quick else 0]
    missing = b.missing()
    total += 0 if missing else est
    cmd = " ".join(["python", f"benchmarks/{b.file}", *b.argv(quick)])
    extra = f"  (skipped here: needs {', '.join(missing)}; {b.requires[1]})" if missing else ""
    print(f"{b.name:22s} {minutes(est):>9s}  {cmd}{extra}")
  print(f"{'total':22s} {minutes(total):>9s}  (quiet 2-core machine)")
  claimed = {f for b in PLAN for f in b.writes}
  stray = sorted(p.name for p in RESULTS.glob("*") if p.is_file() and p.name not in claimed)
  for name in stray:
    print(f"not regenerated: results/{name}: {NOT_REGENERATED.get(name, 'written by no benchmark')}")
  scripted = {b.file for b in PLAN}
  for name in scripts():
    if name not in scripted and name != "refresh.py":
      print(f"not in the plan: benchmarks/{name}")


# --- Full and quick runs ---------------------------------------------------------------


def run_plan(plan: list[Bench], quick: bool, out: pathlib.Path | None, v3_python: str | None,
             logs: pathlib.Path) -> list[dict]:
  """Runs each benchmark in its own interpreter; one line each; the outcomes."""
  done = []
  env = {**os.environ, "MPLBACKEND": "Agg"}
  for k, b in enumerate(plan):
    prefix = f"[{k + 1:2d}/{len(plan)}] {b.name:22s}"
    missing = b.missing()
    if missing:
      print(f"{prefix} skipped: needs {', '.join(missing)} ({b.requires[1]})", flush=True)
      done.append(dict(name=b.name, outcome="skipped", seconds=0.0, argv=b.argv(quick),
                       why=f"needs {', '.join(missing)}"))
      continue
    argv = b.argv(quick)
    if b.file in ("peers.py", "error_vs_time.py") and v3_python:
      argv += ["--v3-python", v3_python]
    if out is not None:
      argv += ["--out", str(out)]
    print(f"{prefix} (about {minutes(b.estimate[1 if quick else 0])}) ...", end=" ", flush=True)
    log = logs / f"{b.name}.log"
    t0 = time.perf_counter()
    with open(log, "w") as f:
      code = subprocess.run([sys.executable, str(HERE / b.file), *argv], cwd=HERE.parent, env=env,
                            stdout=f, stderr=subprocess.STDOUT).returncode
    seconds = time.perf_counter() - t0
    outcome = "ok" if code == 0 else "FAILED"
    print(f"{seconds:6.0f} s  {outcome}" + (f" (exit {code}; log {log})" if code else ""), flush=True)
    if code:
      tail = log.read_text(errors="replace").strip().splitlines()[-15:]
      print("\n".join("    " + line for line in tail), flush=True)
    done.append(dict(name=b.name, outcome=outcome, seconds=seconds, argv=argv, code=code,
                     log=str(log)))
  return done


# --- Smoke runs: every script in one interpreter ---------------------------------------


def smoke_runs(names: list[str], out: pathlib.Path, timeout: float) -> list[dict]:
  """Every script's `--smoke` run in one interpreter (`_smoke.py`), in order; a script
  that ends the interpreter or runs past `timeout` fails alone and the rest go on in a
  new one. Each script's result lands in `out/NAME/result.json` as soon as it ends."""
  todo, done, runner, log, deadline = list(names), [], None, None, 0.0
  env = {**os.environ, "MPLBACKEND": "Agg"}
  while todo:
    name = todo[0]
    prefix = f"[{len(done) + 1:2d}/{len(names)}] {pathlib.Path(name).stem:22s}"
    bench = next((b for b in PLAN if b.file == name), None)
    missing = bench.missing() if bench else []
    work = out / pathlib.Path(name).stem
    if missing:
      work.mkdir(parents=True, exist_ok=True)
      why = f"needs {', '.join(missing)} ({bench.requires[1]})"
      result = dict(script=name, code=0, skipped=why, seconds=0.0, cpu=0.0, child_cpu=0.0)
      _write_json(work / "result.json", result)
      print(f"{prefix} skipped: {why}", flush=True)
      done.append(result)
      todo.pop(0)
      continue
    if runner is None:
      runnable = [s for s in todo if not _missing(s)]
      log = out / f"runner-{len(done)}.txt"
      with open(log, "w") as f:
        runner = subprocess.Popen([sys.executable, str(HERE / "_smoke.py"), str(out), *runnable],
                                  cwd=out, env=env, stdout=f, stderr=subprocess.STDOUT)
      deadline = time.monotonic() + timeout
    path = work / "result.json"
    while not path.exists():
      if runner.poll() is not None or time.monotonic() > deadline:
        if runner.poll() is None:
          runner.kill()
          runner.wait()
          why = f"ran past {timeout:g} s"
        else:
          why = f"ended the interpreter (exit {runner.returncode})"
        work.mkdir(parents=True, exist_ok=True)
        _write_json(path, dict(script=name, code=None, why=why, runner=log.read_text()[-20000:],
                               seconds=timeout, cpu=0.0, child_cpu=0.0))
        runner = None
        break
      time.sleep(0.1)
    result = json.loads(path.read_text())
    deadline = time.monotonic() + timeout
    outcome = "ok" if result["code"] == 0 else "FAILED"
    print(f"{prefix} {result['seconds']:6.1f} s  {outcome}"
          + (f" ({result.get('why') or 'exit ' + str(result['code'])}; "
             f"{work / 'stderr.txt'})" if outcome != "ok" else ""), flush=True)
    done.append(result)
    todo.pop(0)
  if runner is not None:
    runner.wait()
  return done


def _missing(script: str) -> list[str]:
  bench = next((b for b in PLAN if b.file == script), None)
  return bench.missing() if bench else []


def _write_json(path: pathlib.Path, data: dict) -> None:
  tmp = path.with_suffix(".tmp")  # Written whole, then renamed: a poller never sees half.
  tmp.write_text(json.dumps(data))
  os.replace(tmp, path)


# --- Main ------------------------------------------------------------------------------


def summary(rows: list[dict], smoke: bool) -> list[str]:
  lines = ["# Benchmarks regenerated", "",
           ("Every script's `--smoke` run (tiny sizes: the figures mean nothing), in one "
            "interpreter." if smoke else "Each benchmark in its own interpreter, in this order."),
           "", "| benchmark | command | seconds | outcome |", "|---|---|---|---|"]
  for r in rows:
    name = pathlib.Path(r.get("name") or r["script"]).stem
    cmd = (f"`python benchmarks/{name}.py --smoke`" if smoke else
           f"`{' '.join(['python', f'benchmarks/{name}.py', *r.get('argv', [])])}`")
    outcome = ("skipped: " + (r.get("skipped") or r.get("why", "")) if r.get("skipped")
               or r.get("outcome") == "skipped" else
               "ok" if r.get("code") == 0 or r.get("outcome") == "ok" else
               f"FAILED ({r.get('why') or 'exit ' + str(r.get('code'))})")
    lines.append(f"| {name} | {cmd} | {r['seconds']:.0f} | {outcome} |")
  return lines


def main(argv=None) -> int:
  parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                   epilog="Benchmarks: " + ", ".join(b.name for b in PLAN))
  parser.add_argument("--quick", action="store_true",
                      help="each script's quick mode where it has one (else its full run)")
  parser.add_argument("--smoke", action="store_true",
                      help="every script's --smoke run, in one interpreter (needs --out)")
  parser.add_argument("--out", type=pathlib.Path, default=None, metavar="DIR",
                      help="write there instead of benchmarks/results (required with --smoke)")
  parser.add_argument("--only", nargs="+", metavar="NAME", help="run these benchmarks only")
  parser.add_argument("--skip", nargs="+", metavar="NAME", help="leave these out")
  parser.add_argument("--list", action="store_true", help="print the plan and estimated times")
  parser.add_argument("--v3-python", default=None, metavar="PATH",
                      help="passed on to peers.py and error_vs_time.py: an interpreter with "
                           "box2d-python for Box2D v3")
  parser.add_argument("--timeout", type=float, default=SMOKE_TIMEOUT_S,
                      help=f"--smoke: seconds a script may run (default {SMOKE_TIMEOUT_S:g})")
  args = parser.parse_args(argv)
  if args.smoke and args.quick:
    parser.error("--smoke and --quick are two different runs: give one")
  if args.smoke and args.out is None:
    parser.error("--smoke writes its tables into --out DIR (never into benchmarks/results)")
  if args.smoke:  # Every script, whether in the plan or not (a new script is smoke-tested too).
    known = [f"{n}.py" for n in (args.only or [])] or scripts()
    unknown = [n for n in known if n not in scripts()]
    if unknown:
      parser.error(f"no such scripts: {', '.join(unknown)}; scripts: {', '.join(scripts())}")
    names = [n for n in known if n != "refresh.py" and n[:-3] not in (args.skip or [])]
    if args.list:
      print("\n".join(names))
      return 0
  else:
    plan = select(list(PLAN), args.only, args.skip, args.quick)
    if args.list:
      show_plan(plan, args.quick)
      return 0

  sys.path.insert(0, str(HERE))
  import _bench  # Imports jax: after --list, which needs none of it.
  run = _bench.Run.start()
  if args.out is not None:  # The scripts run from the checkout: a relative --out is the caller's.
    args.out = args.out.resolve()
  out = args.out or RESULTS
  out.mkdir(parents=True, exist_ok=True)
  if args.smoke:
    rows = smoke_runs(names, out, args.timeout)
    failed = [r["script"] for r in rows if r["code"] != 0]
  else:
    logs = pathlib.Path(tempfile.mkdtemp(prefix="jaxchain-refresh-"))
    print(f"{run.commit}; logs in {logs}", flush=True)
    rows = run_plan(plan, args.quick, args.out, args.v3_python, logs)
    failed = [r["name"] for r in rows if r["outcome"] == "FAILED"]
  _bench.write_result(out, "refresh.md", summary(rows, args.smoke), run, echo=False)
  skipped = [r.get("name") or r["script"] for r in rows if r.get("skipped")
             or r.get("outcome") == "skipped"]
  if skipped:
    print(f"skipped (packages missing): {', '.join(skipped)}")
  if failed:
    print(f"FAILED: {', '.join(failed)}")
    return 1
  print(f"all {len(rows) - len(skipped)} ran; wrote {out / 'refresh.md'}")
  return 0


if __name__ == "__main__":
  sys.exit(main())
