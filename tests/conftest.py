"""Strict tests, lenient library: promotion errors surface here, never in users' code.

The suite compiles with LLVM at -O0 (`--xla_backend_optimization_level=0`, set here
before JAX starts its backend, and inherited by the tests' subprocesses): XLA's own
HLO passes (fusion, layout, the partitioner) run as always, only the machine-code
optimisation is skipped. The suite is compile-bound, and this cuts its time by about a
third (measured on test_golden, test_stepping and test_links: 411 s -> 293 s). Users and
the benchmarks run at the default level; `tests/test_golden.py` replays a golden scene
at the default level too (`test_same_answers_at_the_default_optimisation_level`), so a
miscompile there (jax-ml/jax#39103 was one) still fails the suite.
"""

import os

OPT_FLAG = "--xla_backend_optimization_level=0"
if "xla_backend_optimization_level" not in os.environ.get("XLA_FLAGS", ""):
  os.environ["XLA_FLAGS"] = f"{os.environ.get('XLA_FLAGS', '')} {OPT_FLAG}".strip()

import jax  # noqa: E402 - after XLA_FLAGS.
import pytest
from hypothesis import settings

jax.config.update("jax_numpy_rank_promotion", "raise")
jax.config.update("jax_numpy_dtype_promotion", "strict")

settings.register_profile("jaxchain", max_examples=25, deadline=None, derandomize=True,
                          print_blob=True)
settings.load_profile("jaxchain")


@pytest.fixture(autouse=True)
def _float32_default():
  assert not jax.config.jax_enable_x64, "the suite runs in float32; x64 tests use a subprocess"
