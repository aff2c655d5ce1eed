"""Same answers: the benchmark scenes replayed against stored values (`tests/data/golden.npz`,
written by `tests/data/make_golden.py` from the physics issue's final commit)."""

import importlib.util
import pathlib

import numpy as np
import pytest

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
