"""Shared by the benchmark scripts: the `--smoke` and `--out` options every script
offers, timing (compile apart, median of repeats), the machine line every result file
starts with, and the log-log plot."""

from __future__ import annotations

import argparse
import os
import pathlib
import platform
import statistics
import subprocess
import time

import jax
import numpy as np

# Where the scripts write their tables and plots unless given `--out`.
RESULTS = pathlib.Path(__file__).resolve().parent / "results"
ROOT = RESULTS.parents[1]  # The checkout.


def add_common_args(parser: argparse.ArgumentParser) -> argparse.ArgumentParser:
  """Adds the options every benchmark script offers (`tests/test_benchmarks.py` runs
  each script with both, so a script without them fails the suite):

  - `--smoke`: tiny sizes, a few settings and steps, no waiting: seconds, not minutes.
    It runs the script's whole code path and writes its tables; the figures mean
    nothing.
  - `--out DIR`: the directory for the tables and plots (default `benchmarks/results`,
    the committed ones; the smoke test writes to a temporary directory).
  """
  parser.add_argument("--smoke", action="store_true",
                      help="tiny sizes, a few seconds: checks that the script runs and writes its "
                           "tables (the figures mean nothing)")
  parser.add_argument("--out", type=pathlib.Path, default=RESULTS, metavar="DIR",
                      help="directory to write the tables and plots to (default benchmarks/results)")
  return parser


def out_dir(args: argparse.Namespace) -> pathlib.Path:
  """`args.out`, created if missing."""
  args.out.mkdir(parents=True, exist_ok=True)
  return args.out


def median_time(fn, repeats: int, budget_s: float = float("inf")):
  """`(last result, median seconds)` of `fn()` over up to `repeats` calls; stops
  early once the calls so far took `budget_s` (one long call is enough)."""
  times, out = [], None
  for _ in range(repeats):
    t0 = time.perf_counter()
    out = fn()
    times.append(time.perf_counter() - t0)
    if sum(times) >= budget_s:
      break
  return out, statistics.median(times)


def compile_and_time(fn, *args, repeats: int = 5, budget_s: float = float("inf"),
                     warmup: bool = True):
  """`(result, median seconds per call, compile seconds)` of `jax.jit(fn)(*args)`.

  Compiles ahead of time (`lower(...).compile()`), so compile time is measured on
  its own and never counted in the run time. With `warmup`, one untimed call first.
  """
  t0 = time.perf_counter()
  compiled = jax.jit(fn).lower(*args).compile()
  compile_s = time.perf_counter() - t0
  if warmup:
    jax.block_until_ready(compiled(*args))
  out, sec = median_time(lambda: jax.block_until_ready(compiled(*args)), repeats, budget_s)
  return out, sec, compile_s


def machine() -> str:
  """One line naming what the numbers were measured on."""
  load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
  return (f"jax {jax.__version__} on {jax.devices()[0].device_kind}, {os.cpu_count()} cores, "
          f"{platform.machine()}, Python {platform.python_version()}, numpy {np.__version__}, "
          f"1-min load average at the start {load:.2f}")


def loglog(path, series, *, xlabel: str, ylabel: str, title: str, xbase: int = 10) -> None:
  """Writes a log-log PNG of `series`: label -> `(xs, ys, matplotlib style)`."""
  import matplotlib
  matplotlib.use("Agg")
  import matplotlib.pyplot as plt
  fig, ax = plt.subplots(figsize=(7, 4.5))
  for label, (xs, ys, style) in series.items():
    ax.plot(xs, ys, style, label=label)
  ax.set_xscale("log", base=xbase)
  ax.set_yscale("log")
  ax.set_xlabel(xlabel)
  ax.set_ylabel(ylabel)
  ax.set_title(title)
  ax.grid(True, which="both", alpha=0.3)
  ax.legend()
  fig.tight_layout()
  fig.savefig(path, dpi=120)
  plt.close(fig)


def export_src(rev: str, into: pathlib.Path) -> pathlib.Path:
  """`git archive rev src` of this checkout into `into/rev`; returns its `src` folder
  (an earlier commit's jaxchain, to run beside the working tree's)."""
  dest = into / rev
  dest.mkdir(parents=True)
  archive = subprocess.run(["git", "-C", str(ROOT), "archive", rev, "src"], check=True,
                           capture_output=True).stdout
  subprocess.run(["tar", "-x", "-C", str(dest)], input=archive, check=True)
  return dest / "src"
