"""The suite's own health: a worker must not run out of memory maps (`tests/conftest.py`,
`_release_compiled_programs`). XLA:CPU maps three regions per kernel it loads, and a
process that passes `vm.max_map_count` segfaults in XLA's next compile."""

import gc
import pathlib

import jax
import jax.numpy as jnp
import pytest

MAPS = pathlib.Path("/proc/self/maps")
LIMIT = pathlib.Path("/proc/sys/vm/max_map_count")
pytestmark = pytest.mark.skipif(not (MAPS.exists() and LIMIT.exists()), reason="Linux only")


def _maps() -> int:
  with MAPS.open("rb") as f:
    return sum(1 for _ in f)


def test_clearing_jax_caches_unmaps_compiled_programs():
  # What the conftest fixture relies on: a program kept by a live `jax.jit` is unmapped
  # by `jax.clear_caches()`.
  jax.jit(lambda x: x + 1)(jnp.ones(8)).block_until_ready()  # One-time set-up of the backend.
  gc.collect()
  before = _maps()
  kept = [jax.jit(lambda x, k=k: jnp.cumsum(jnp.sin(x) * k)) for k in range(20)]
  for f in kept:
    f(jnp.ones(8)).block_until_ready()
  loaded = _maps() - before
  assert loaded >= 20, loaded  # At least one map per program (three per kernel).
  jax.clear_caches()
  gc.collect()
  assert _maps() - before < loaded / 4, (before, loaded, _maps())


def test_this_worker_holds_far_fewer_maps_than_the_limit():
  # Runs late on its worker (not in conftest.HEAVY_FIRST): with the caches dropped after
  # each module it starts near 1,600 maps; without, a worker passed 30,000 by mid-run.
  assert _maps() < int(LIMIT.read_text()) // 4
