"""The XLA:CPU flags the suite compiles with (see `tests/conftest.py`, which sets them
before JAX starts its backend). Apart from conftest, and importing nothing, so that a
test can name them too: `test_golden`'s canary runs without them."""

SUITE_XLA_FLAGS = ("--xla_backend_optimization_level=0", "--xla_cpu_use_fusion_emitters=false",
                   "--xla_cpu_parallel_codegen_split_count=1")
