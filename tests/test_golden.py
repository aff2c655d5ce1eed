"""Same answers: the benchmark scenes replayed against stored values (`tests/data/golden.npz`,
written by `tests/data/make_golden.py` from the physics issue's final commit)."""

import importlib.util
import os
import pathlib
import subprocess
import sys
import textwrap

import numpy as np
import pytest

from tests.xla_flags import SUITE_XLA_FLAGS

DATA = pathlib.Path(__file__).parent / "data"
_spec = importlib.util.spec_from_file_location("make_golden", DATA / "make_golden.py")
make_golden = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(make_golden)
GOLDEN = np.load(DATA / "golden.npz")
CASES = make_golden.cases()


@pytest.mark.parametrize("name", sorted(CASES))
def test_same_answers_as_stored(name):
  world, kwargs, controls = CASES[name]
  final = make_golden.run(world, kwargs, controls)
  np.testing.assert_allclose(np.asarray(final.pos), GOLDEN[f"{name}/pos"], rtol=0, atol=1e-6)
  np.testing.assert_allclose(np.asarray(final.vel), GOLDEN[f"{name}/vel"], rtol=0, atol=1e-6)
  assert int(final.status) == int(GOLDEN[f"{name}/status"])


def test_stored_scenes_move():
  """The stored states are not the initial ones: the comparison above can fail."""
  for name, (world, _, _) in CASES.items():
    assert np.max(np.abs(GOLDEN[f"{name}/pos"] - np.asarray(world.pos))) > 1e-3, name


def test_same_answers_at_the_default_optimisation_level():
  """The demo's scene replayed in a subprocess compiled with XLA's defaults (the suite
  compiles with faster codegen, see conftest.py): the bits users get match the
  stored ones."""
  suite_only = [flag.split("=")[0] for flag in SUITE_XLA_FLAGS]
  flags = " ".join(f for f in os.environ.get("XLA_FLAGS", "").split()
                   if f.split("=")[0] not in suite_only)
  code = textwrap.dedent(f"""
      import importlib.util, numpy as np
      spec = importlib.util.spec_from_file_location("make_golden", {str(DATA / "make_golden.py")!r})
      mg = importlib.util.module_from_spec(spec); spec.loader.exec_module(mg)
      golden = np.load({str(DATA / "golden.npz")!r})
      world, kwargs, controls = mg.cases()["platformer"]
      final = mg.run(world, kwargs, controls)
      for k in ("pos", "vel"):
        np.testing.assert_allclose(np.asarray(getattr(final, k)), golden["platformer/" + k],
                                   rtol=0, atol=1e-6)
      print("SAME")
  """)
  env = {**os.environ, "XLA_FLAGS": flags, "JAX_PLATFORMS": "cpu"}
  done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env,
                        timeout=600)
  assert done.returncode == 0 and "SAME" in done.stdout, done.stderr[-3000:]
