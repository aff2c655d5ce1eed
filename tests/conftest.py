"""Strict tests, lenient library: promotion errors surface here, never in users' code.

The suite compiles with three XLA:CPU flags (`tests/xla_flags.py`, set here before JAX starts
its backend, and inherited by the tests' subprocesses). XLA's own HLO passes (fusion,
layout, the partitioner) run as always; only the code generation differs:
- LLVM at -O0 (`--xla_backend_optimization_level=0`): the machine-code optimisation is
  skipped (test_golden, test_stepping and test_links: 411 s -> 293 s).
- XLA's older loop emitters for fused kernels (`--xla_cpu_use_fusion_emitters=false`)
  instead of the MLIR fusion emitters: test_stepping 161 -> 87 CPU s on top of -O0 (a full
  run: 843 -> 495 s wall). Each kernel compiles faster and runs slower, and the suite is
  compile-bound.
- One LLVM module per program (`--xla_cpu_parallel_codegen_split_count=1`) instead of
  parts compiled on parallel threads: less CPU in all, and the suite keeps both cores busy
  with its own workers (a full run: 879 -> 804 CPU s, 474 -> 433 s wall).
A test whose program runs long compiles it at -O1 (`tests.helpers.RUN_BOUND`).
Users and the benchmarks run at XLA's defaults; `tests/test_golden.py` replays a golden
scene with none of them (`test_same_answers_at_the_default_optimisation_level`), so a
miscompile at the defaults (jax-ml/jax#39103 was one) still fails the suite.

`pytest`, typed as written, runs on pytest-xdist workers (`pytest_cmdline_main` below):
one per core, at most `MAX_WORKERS`, with `--dist loadfile`, so a module's tests share
one worker's compiled functions and module fixtures. `-n N` / `--dist MODE` on the
command line win; `-n 0` or `-p no:xdist` runs in this one process. (The defaults are
set here rather than in pyproject's `addopts`, because `-n` in `addopts` turns
`pytest -p no:xdist` into a usage error.) The workers import this file too, so they
get the same XLA flags, and tests' subprocesses inherit them from the environment.
"""

import gc
import os
import shutil
import tempfile

from tests.xla_flags import SUITE_XLA_FLAGS

for _flag in SUITE_XLA_FLAGS:  # A flag the caller set keeps the caller's value.
  if _flag.split("=")[0] not in os.environ.get("XLA_FLAGS", ""):
    os.environ["XLA_FLAGS"] = f"{os.environ.get('XLA_FLAGS', '')} {_flag}".strip()

# One run's XLA executables in JAX's persistent compilation cache, in a directory this run
# makes and removes (`pytest_unconfigure`): pytest-xdist's workers and the tests'
# subprocesses (the benchmark smoke runs, the CLI, the README's commands) inherit it from
# the environment. A program the suite compiles again (another `jax.jit` of the same
# function, the same step in another module after `_release_compiled_programs`, the demo in
# another subprocess) is loaded instead: about a third of the suite's compiles. A fresh
# clone starts empty, as every run does. `JAX_COMPILATION_CACHE_DIR` set by the caller is
# used as it is (and kept).
# Only the process that made it removes it: not a worker, nor a pytest a test starts
# (benchmarks/suite_time.py's smoke run), which inherit the variable.
_suite_xla_cache = None
if "JAX_COMPILATION_CACHE_DIR" not in os.environ and not os.environ.get("PYTEST_XDIST_WORKER"):
  _suite_xla_cache = tempfile.mkdtemp(prefix="jaxchain-suite-xla-")
  os.environ["JAX_COMPILATION_CACHE_DIR"] = _suite_xla_cache
  os.environ.setdefault("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", "0")

# The command line keeps its compiled programs in a cache directory of the user's
# (`jaxchain.compile_cache`): the suite's runs do not (tests/test_cli.py's cache tests name
# a temporary one), in this process and in the tests' subprocesses.
os.environ.setdefault("JAXCHAIN_CACHE", "off")

import jax  # noqa: E402 - after XLA_FLAGS.
import pytest
from hypothesis import settings

jax.config.update("jax_numpy_rank_promotion", "raise")
jax.config.update("jax_numpy_dtype_promotion", "strict")

settings.register_profile("jaxchain", max_examples=25, deadline=None, derandomize=True,
                          print_blob=True)
settings.load_profile("jaxchain")


# Workers `pytest` starts by itself; each holds its own compiled functions (1-3 GB).
MAX_WORKERS = 4


def _cores() -> int:
  try:
    return len(os.sched_getaffinity(0))
  except AttributeError:  # Not Linux.
    return os.cpu_count() or 1


@pytest.hookimpl(tryfirst=True)
def pytest_cmdline_main(config):
  """Without `-n` on the command line, `-n auto --dist loadfile` (xdist installed, and
  not inside a worker). Runs before xdist's own `pytest_cmdline_main` reads them."""
  if getattr(config.option, "numprocesses", "absent") == "absent":  # -p no:xdist.
    return
  if os.environ.get("PYTEST_XDIST_WORKER"):
    return
  if config.option.numprocesses is None:
    config.option.numprocesses = "auto"
  if config.option.dist == "no" and config.option.numprocesses not in (0, "0"):
    config.option.dist = "loadfile"
    config.option.loadscopereorder = False  # Keep HEAVY_FIRST's order (not by test count).


# The modules that take longest (summed test durations, 2026-12-02), longest first. loadfile hands
# whole modules to the workers in collection order, so starting the long ones first
# leaves no worker alone with one at the end. Only the order changes; a module not
# listed keeps its place after these.
HEAVY_FIRST = ("test_dynamics.py", "test_benchmarks.py", "test_stepping.py", "test_cli.py",
               "test_readme.py", "test_flags.py", "test_broadphase.py", "test_sharding.py",
               "test_gradients.py", "test_bridges.py", "test_env.py", "test_stability.py",
               "test_friction_links.py")


def pytest_collection_modifyitems(config, items):
  """Modules in `HEAVY_FIRST` order; within a module, and among the rest, as collected."""
  del config
  rank = {name: k for k, name in enumerate(HEAVY_FIRST)}
  items.sort(key=lambda item: rank.get(item.path.name, len(rank)))


@pytest.hookimpl(optionalhook=True)  # An xdist hook: unknown under -p no:xdist.
def pytest_xdist_auto_num_workers(config):
  """`-n auto`: one worker per usable core, at most `MAX_WORKERS`; one core runs here."""
  del config
  cores = min(_cores(), MAX_WORKERS)
  return cores if cores > 1 else 0


@pytest.fixture(autouse=True)
def _float32_default():
  assert not jax.config.jax_enable_x64, "the suite runs in float32; x64 tests use a subprocess"


@pytest.fixture(scope="module", autouse=True)
def _release_compiled_programs():
  """After each module, drop every program JAX has compiled (`jax.clear_caches`).

  XLA:CPU loads each kernel it compiles as its own object, with three memory maps (code,
  read-only data, data), and Linux gives a process at most `vm.max_map_count` maps
  (65,530 by default). One jitted step is about 150 kernels, so a long-lived worker that
  keeps every program of the modules it ran (module-level `jax.jit`s keep theirs in JAX's
  caches) passes that limit after a few hundred steps, and the next compile segfaults
  inside XLA (seen at 76% of a full run, in `backend_compile_and_load`). A module then
  starts with no compiled programs, whatever ran before it on its worker (so its compile
  count no longer depends on which modules ran before it there).
  """
  yield
  jax.clear_caches()
  gc.collect()


def pytest_unconfigure(config):
  """The run's XLA cache directory removed, by the process that made it."""
  del config
  if _suite_xla_cache is not None:
    shutil.rmtree(_suite_xla_cache, ignore_errors=True)
