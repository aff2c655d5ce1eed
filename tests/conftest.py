"""Strict tests, lenient library: promotion errors surface here, never in users' code."""

import jax
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
