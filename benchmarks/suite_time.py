"""Where the test suite's time goes (issue 30): CPU seconds and XLA compiles per module,
per fixture and per test, the slowest tests, the total wall time and the command.

Runs `pytest` (as the README types it: `-n auto --dist loadfile` from tests/conftest.py,
unless `-n` is given) on the working tree (`src/` first on the path) with the plugin
`_suite_plugin.py`, which records on every worker, for each test's set-up, call and
teardown and each fixture's set-up: CPU seconds of the worker (`time.process_time`),
CPU seconds of the subprocesses the test waited for, wall seconds, and the XLA compiles
(`jax.monitoring`'s backend-compile event, count and seconds). The tests' own Python
subprocesses (the benchmark smoke runs, the CLI, x64, sharding) count their compiles
too (a `sitecustomize` on their path). CPU seconds hardly depend on what else runs on
the machine; the wall time does, so the 1-minute load average is written beside it.

    python benchmarks/suite_time.py                        # the whole suite -> results/suite.md
    python benchmarks/suite_time.py tests/test_chain.py    # some modules (any pytest arguments)
    python benchmarks/suite_time.py -n 0 tests/test_config.py
    python benchmarks/suite_time.py --smoke --out /tmp/x   # one small module in this process
"""

from __future__ import annotations

import argparse
import collections
import json
import os
import pathlib
import re
import resource
import shlex
import subprocess
import sys
import tempfile
import time

from _bench import add_common_args, out_dir

ROOT = pathlib.Path(__file__).resolve().parents[1]
HERE = pathlib.Path(__file__).resolve().parent
SMOKE_ARGS = ["-n", "0", "tests/test_layout.py"]  # A small module with no compiles to speak of.

# Imported by the tests' Python subprocesses (on their PYTHONPATH, never by the pytest
# processes: only a process started while a test runs has JAXCHAIN_SUITE_TEST): counts
# its XLA compiles once jax is imported, and writes them at exit.
SITECUSTOMIZE = '''
import os, sys
if os.environ.get("JAXCHAIN_SUITE_TEST") and os.environ.get("JAXCHAIN_SUITE_TIMING"):
  import atexit, json, time
  _counts = [0, 0.0, 0]

  def _listen(event, duration, **kwargs):
    if event == "/jax/core/compile/backend_compile_duration":
      _counts[0] += 1
      _counts[1] += duration

  def _listen_event(event, **kwargs):
    if event == "/jax/compilation_cache/cache_hits":
      _counts[2] += 1

  class _Hook:
    def find_spec(self, name, path=None, target=None):
      if name != "jax._src.monitoring":
        return None
      sys.meta_path.remove(self)
      import importlib.util
      spec = importlib.util.find_spec(name)
      run = spec.loader.exec_module

      def exec_module(module):
        run(module)
        module.register_event_duration_secs_listener(_listen)
        module.register_event_listener(_listen_event)
      spec.loader.exec_module = exec_module
      return spec

  sys.meta_path.insert(0, _Hook())

  def _dump():
    record = dict(kind="sub", nodeid=os.environ["JAXCHAIN_SUITE_TEST"], argv=sys.argv[:3],
                  cpu=time.process_time(), compiles=_counts[0] - _counts[2],
                  compile_s=_counts[1], cache_hits=_counts[2])
    path = os.path.join(os.environ["JAXCHAIN_SUITE_TIMING"], f"sub-{os.getpid()}.jsonl")
    with open(path, "a") as f:
      f.write(json.dumps(record) + "\\n")
  atexit.register(_dump)
'''


def run(pytest_args: list[str], record_dir: pathlib.Path) -> dict:
  """Runs pytest with the plugin; returns the command, wall and CPU seconds, exit code,
  summary line, load averages and the `--durations` lines."""
  site = record_dir / "site"
  site.mkdir(exist_ok=True)
  (site / "sitecustomize.py").write_text(SITECUSTOMIZE)
  env = {k: v for k, v in os.environ.items()
         if not k.startswith(("PYTEST_", "JAXCHAIN_SUITE_"))}  # Not a worker's, if nested.
  path = [str(ROOT / "src"), str(HERE), str(site), env.get("PYTHONPATH", "")]
  env.update(PYTHONPATH=os.pathsep.join(p for p in path if p), JAXCHAIN_SUITE_TIMING=str(record_dir),
             JAX_PLATFORMS="cpu")
  argv = [sys.executable, "-m", "pytest", "-p", "_suite_plugin", "-q", "--durations=0",
          "-p", "no:cacheprovider", *pytest_args]
  load0, busy0 = os.getloadavg()[0], _machine_busy()
  cpu0 = resource.getrusage(resource.RUSAGE_CHILDREN)
  t0 = time.perf_counter()
  loads = []
  with tempfile.TemporaryFile("w+") as out_file, tempfile.TemporaryFile("w+") as err_file:
    proc = subprocess.Popen(argv, cwd=ROOT, env=env, stdout=out_file, stderr=err_file, text=True)
    while proc.poll() is None:  # The 1-minute load average, every 10 s while it runs.
      loads.append(os.getloadavg()[0])
      time.sleep(min(10.0, 0.1 * (len(loads) + 1)))
    out_file.seek(0)
    err_file.seek(0)
    done = subprocess.CompletedProcess(argv, proc.returncode, out_file.read(), err_file.read())
  wall = time.perf_counter() - t0
  cpu1 = resource.getrusage(resource.RUSAGE_CHILDREN)
  busy = _machine_busy() - busy0
  out = done.stdout
  summary = next((line.strip("= ") for line in reversed(out.splitlines())
                  if re.search(r"\d+ (passed|failed|error)", line)), "(no summary)")
  if done.returncode not in (0, 1):
    sys.stderr.write(out[-4000:] + done.stderr[-4000:])
  return dict(command=" ".join(["pytest"] + [shlex.quote(a) for a in pytest_args]), wall=wall,
              cpu=(cpu1.ru_utime + cpu1.ru_stime) - (cpu0.ru_utime + cpu0.ru_stime),
              returncode=done.returncode, summary=summary, load=(load0, os.getloadavg()[0]),
              load_mean=sum(loads) / max(len(loads), 1), load_max=max(loads, default=load0),
              machine_busy=busy, output=out)


def _machine_busy() -> float:
  """CPU seconds the whole machine has been busy since boot (`/proc/stat`; NaN elsewhere):
  the run's own CPU time subtracted, what is left is other processes' load."""
  try:
    with open("/proc/stat") as f:
      fields = [int(x) for x in f.readline().split()[1:]]
  except (OSError, ValueError):
    return float("nan")
  idle = fields[3] + (fields[4] if len(fields) > 4 else 0)  # idle + iowait.
  return (sum(fields[:8]) - idle) / os.sysconf("SC_CLK_TCK")


def read(record_dir: pathlib.Path) -> list[dict]:
  records = []
  for path in sorted(record_dir.glob("*.jsonl")):
    records += [json.loads(line) for line in path.read_text().splitlines() if line.strip()]
  return records


def _f(x: float, digits: int = 1) -> str:
  return f"{x:.{digits}f}"


def tables(meta: dict, records: list[dict], *, top: int) -> str:
  """The Markdown of `results/suite.md`."""
  phases = [r for r in records if r["kind"] == "phase"]
  fixtures = [r for r in records if r["kind"] == "fixture"]
  subs = [r for r in records if r["kind"] == "sub"]
  sub_by_test = collections.defaultdict(lambda: [0, 0, 0.0, 0])  # compiles, processes, s, hits
  for s in subs:
    entry = sub_by_test[s["nodeid"]]
    entry[0] += s["compiles"]
    entry[1] += 1
    entry[2] += s["compile_s"]
    entry[3] += s.get("cache_hits", 0)

  tests = {}
  for r in phases:
    t = tests.setdefault(r["nodeid"], dict(module=r["module"], worker=r["worker"], cpu=0.0,
                                           child_cpu=0.0, wall=0.0, compiles=0, compile_s=0.0,
                                           cache_hits=0, call_wall=0.0, failed=False))
    for k in ("cpu", "child_cpu", "wall", "compiles", "compile_s"):
      t[k] += r[k]
    t["cache_hits"] += r.get("cache_hits", 0)
    if r["when"] == "call":
      t["call_wall"] = r["wall"]
    t["failed"] |= r["failed"]
  for nodeid, t in tests.items():
    t["sub_compiles"] = sub_by_test.get(nodeid, [0])[0]
    t["cache_hits"] += sub_by_test.get(nodeid, [0, 0, 0.0, 0])[3]

  modules = {}
  for t in tests.values():
    m = modules.setdefault(t["module"], dict(tests=0, cpu=0.0, child_cpu=0.0, wall=0.0,
                                             compiles=0, compile_s=0.0, sub_compiles=0,
                                             cache_hits=0, workers=set()))
    m["tests"] += 1
    for k in ("cpu", "child_cpu", "wall", "compiles", "compile_s", "sub_compiles", "cache_hits"):
      m[k] += t[k]
    m["workers"].add(t["worker"])

  total = {k: sum(m[k] for m in modules.values())
           for k in ("tests", "cpu", "child_cpu", "wall", "compiles", "compile_s", "sub_compiles",
                     "cache_hits")}
  lines = [
      "# Where the suite's time goes",
      "",
      "Written by `benchmarks/suite_time.py` (issue 30). CPU seconds are the pytest worker's own",
      "(`time.process_time` around each test's set-up, call and teardown) and, apart, those of",
      "the subprocesses a test waited for (the benchmark smoke runs, the CLI, x64, sharding, the",
      "docs build); compiles are XLA backend compiles (`jax.monitoring`), in the worker and, apart,",
      "in the tests' Python subprocesses; cache hits are programs loaded from JAX's persistent",
      "compilation cache instead (the suite keeps one per run: `tests/conftest.py`).",
      "Wall seconds are per test as the worker saw them; the",
      "total wall time is the whole command's, and depends on the machine's load (given).",
      "",
      f"- command: `{meta['command']}` (from the repository root; `{meta['python']}`)",
      f"- result: {meta['summary']} (exit {meta['returncode']})",
      f"- total wall: {_f(meta['wall'])} s; total CPU of all processes: {_f(meta['cpu'])} s"
      f" ({_f(meta['cpu'] / max(meta['wall'], 1e-9), 2)} cores busy on average)",
      f"- machine: {meta['machine'].split(', 1-min load')[0]}; 1-min load average"
      f" {meta['load'][0]:.2f} at the start, {meta['load'][1]:.2f} at the end, mean"
      f" {meta['load_mean']:.2f} and max {meta['load_max']:.2f} while it ran (sampled every 10 s)",
      f"- other processes' load: the machine was busy {_f(meta['machine_busy'])} CPU s during the"
      f" run, {_f(meta['machine_busy'] - meta['cpu'])} s of them not this run's"
      f" ({_f((meta['machine_busy'] - meta['cpu']) / max(meta['wall'], 1e-9), 2)} cores on"
      f" average)",
      f"- summed over tests: worker CPU {_f(total['cpu'])} s, subprocess CPU"
      f" {_f(total['child_cpu'])} s, {total['compiles']} compiles in workers"
      f" ({_f(total['compile_s'])} s with the cache loads), {total['sub_compiles']} in subprocesses,"
      f" {total['cache_hits']} programs loaded from the compilation cache",
      "",
      "## Per module (by worker CPU + subprocess CPU)",
      "",
      "| module | tests | worker CPU s | subprocess CPU s | wall s | compiles | compile s |"
      " subprocess compiles | cache hits |",
      "|---|---:|---:|---:|---:|---:|---:|---:|---:|",
  ]
  for name, m in sorted(modules.items(), key=lambda kv: -(kv[1]["cpu"] + kv[1]["child_cpu"])):
    lines.append(f"| {name} | {m['tests']} | {_f(m['cpu'])} | {_f(m['child_cpu'])} | "
                 f"{_f(m['wall'])} | {m['compiles']} | {_f(m['compile_s'])} | {m['sub_compiles']} | "
                 f"{m['cache_hits']} |")
  lines.append(f"| **total** | {total['tests']} | {_f(total['cpu'])} | {_f(total['child_cpu'])} | "
               f"{_f(total['wall'])} | {total['compiles']} | {_f(total['compile_s'])} | "
               f"{total['sub_compiles']} | {total['cache_hits']} |")

  lines += ["", f"## Slowest tests (top {top} by wall: set-up + call + teardown)", "",
            "| test | wall s | worker CPU s | subprocess CPU s | compiles | subprocess compiles |",
            "|---|---:|---:|---:|---:|---:|"]
  for nodeid, t in sorted(tests.items(), key=lambda kv: -kv[1]["wall"])[:top]:
    lines.append(f"| `{nodeid}` | {_f(t['wall'])} | {_f(t['cpu'])} | {_f(t['child_cpu'])} | "
                 f"{t['compiles']} | {t['sub_compiles']} |")

  by_fixture = {}
  for r in fixtures:
    key = (r["module"] if r["scope"] != "session" else "(session)", r["name"], r["scope"])
    f = by_fixture.setdefault(key, dict(setups=0, cpu=0.0, wall=0.0, compiles=0))
    f["setups"] += 1
    f["cpu"] += r["cpu"]
    f["wall"] += r["wall"]
    f["compiles"] += r["compiles"]
  lines += ["", f"## Fixtures (top {top} by CPU: set-up only, summed over set-ups)", "",
            "| module | fixture | scope | set-ups | CPU s | wall s | compiles |",
            "|---|---|---|---:|---:|---:|---:|"]
  for (module, name, scope), f in sorted(by_fixture.items(), key=lambda kv: -kv[1]["cpu"])[:top]:
    if f["cpu"] < 0.05 and f["compiles"] == 0:
      continue
    lines.append(f"| {module} | `{name}` | {scope} | {f['setups']} | {_f(f['cpu'])} | "
                 f"{_f(f['wall'])} | {f['compiles']} |")

  per_worker = collections.defaultdict(lambda: [0.0, 0])
  for t in tests.values():
    per_worker[t["worker"]][0] += t["wall"]
    per_worker[t["worker"]][1] += 1
  lines += ["", "## Per worker", "", "| worker | tests | wall s in tests |", "|---|---:|---:|"]
  for w, (wall, n) in sorted(per_worker.items()):
    lines.append(f"| {w} | {n} | {_f(wall)} |")
  return "\n".join(lines) + "\n"


def main(argv=None) -> int:
  parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
  parser.add_argument("--top", type=int, default=30, help="rows of the slowest-tests and fixtures tables")
  parser.add_argument("--keep", type=pathlib.Path, default=None, metavar="DIR",
                      help="keep the raw JSON records in DIR (default: a temporary directory)")
  args, pytest_args = add_common_args(parser).parse_known_args(argv)
  if args.smoke and not pytest_args:
    pytest_args = list(SMOKE_ARGS)
  from _bench import Run, machine, write_result
  started = Run.start(src=ROOT / "src")
  with tempfile.TemporaryDirectory() as tmp:
    record_dir = args.keep or pathlib.Path(tmp)
    record_dir.mkdir(parents=True, exist_ok=True)
    meta = run(pytest_args, record_dir)
    meta.update(machine=machine(), python=f"Python {sys.version.split()[0]}")
    records = read(record_dir)
  text = tables(meta, records, top=args.top)
  path = write_result(out_dir(args), "suite.md", text, started)
  print(f"wrote {path}")
  return 0 if meta["returncode"] in (0, 1) else meta["returncode"]


if __name__ == "__main__":
  sys.exit(main())
