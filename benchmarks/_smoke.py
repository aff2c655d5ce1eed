"""Runs benchmark scripts' smoke runs one after another in this one interpreter.

    python benchmarks/_smoke.py DIR peers.py throughput.py ...

Each script runs as `python benchmarks/NAME.py --smoke --out DIR/NAME/out` would (as
`__main__`, with that `sys.argv`, from the directory `DIR/NAME`), its stdout and stderr
going to `DIR/NAME/stdout.txt` and `stderr.txt`, and its exit code (0 for a normal end
or `sys.exit(0)`, 1 for an exception, whose traceback goes to stderr) to
`DIR/NAME/result.json`, written as soon as the script ends. `refresh.py --smoke` (and
through it `tests/test_benchmarks.py`) uses it so that the smoke runs share one
interpreter: one `import jax` (and torch,
matplotlib, ...) instead of one per script, and the programs that several scripts
compile (the demo scene's step, the env steps) compiled once.
"""

from __future__ import annotations

import contextlib
import json
import os
import pathlib
import resource
import runpy
import sys
import time
import traceback

HERE = pathlib.Path(__file__).resolve().parent


def run_one(script: str, root: pathlib.Path) -> dict:
  """Runs `script --smoke --out root/NAME/out` here; its exit code, seconds, CPU seconds."""
  work = root / pathlib.Path(script).stem
  work.mkdir(parents=True, exist_ok=True)
  argv, cwd, path = list(sys.argv), os.getcwd(), list(sys.path)
  sys.argv = [str(HERE / script), "--smoke", "--out", str(work / "out")]
  cpu0, t0 = time.process_time(), time.perf_counter()
  child0 = resource.getrusage(resource.RUSAGE_CHILDREN)
  code = 0
  with open(work / "stdout.txt", "w") as out, open(work / "stderr.txt", "w") as err:
    try:
      os.chdir(work)
      with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
          runpy.run_path(str(HERE / script), run_name="__main__")
        except SystemExit as stop:
          code = stop.code if isinstance(stop.code, int) else (0 if stop.code is None else 1)
          if not isinstance(stop.code, (int, type(None))):
            print(stop.code, file=sys.stderr)
        except BaseException:  # noqa: BLE001 - a script's failure is its result.
          traceback.print_exc()
          code = 1
    finally:
      os.chdir(cwd)
      sys.argv, sys.path[:] = argv, path
  child1 = resource.getrusage(resource.RUSAGE_CHILDREN)
  result = dict(script=script, code=code, seconds=time.perf_counter() - t0,
                cpu=time.process_time() - cpu0,
                child_cpu=(child1.ru_utime + child1.ru_stime) - (child0.ru_utime + child0.ru_stime))
  # Written whole, then renamed: a reader polling for result.json never sees half of it.
  (work / "result.json.tmp").write_text(json.dumps(result))
  os.replace(work / "result.json.tmp", work / "result.json")
  return result


def main(argv: list[str]) -> int:
  root = pathlib.Path(argv[0])
  sys.path.insert(0, str(HERE))  # As `python benchmarks/NAME.py` has it: `import _bench`.
  for script in argv[1:]:
    result = run_one(script, root)
    print(json.dumps(result), flush=True)
  return 0


if __name__ == "__main__":
  sys.exit(main(sys.argv[1:]))
