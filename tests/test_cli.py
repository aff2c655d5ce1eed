"""The demo: it runs, reports its figures, and the row ends against the wall."""

import doctest
import importlib
import os
import subprocess
import sys

import numpy as np
import pytest

import jaxchain
from jaxchain import cli


def test_demo_figures():
  figures = cli.demo(batch=3, steps=420, chunk=210, seed=1, depth=None, iterations=1,
                     friction=0.3, push=20.0, progress=False)
  assert figures["finite"]
  assert figures["worlds_at_wall"] == 3
  assert figures["wall_intrusion"] < 1e-4
  assert figures["max_penetration"] < 1e-4
  np.testing.assert_allclose(figures["row_moved_mean"], 2.0, atol=1e-3)  # Gap to the wall.
  assert figures["world_steps_per_s"] > 0 and figures["compile_s"] > 0


def test_console_script_runs_and_rejects_bad_flags():
  env = {**os.environ, "JAX_PLATFORMS": "cpu"}
  ok = subprocess.run([sys.executable, "-m", "jaxchain.cli", "demo", "--batch", "2", "--steps",
                       "20", "--chunk", "10", "--no-progress"], capture_output=True, text=True,
                      env=env, timeout=300)
  assert ok.returncode == 0, ok.stderr
  for line in ("compile time", "world-steps/s", "body-steps/s", "final max penetration",
               "row intrusion into wall"):
    assert line in ok.stdout
  bad = subprocess.run([sys.executable, "-m", "jaxchain.cli", "demo", "--batch", "0"],
                       capture_output=True, text=True, env=env, timeout=300)
  assert bad.returncode == 2 and "must be a positive integer" in bad.stderr


@pytest.mark.parametrize("name", ["world", "config", "step", "reference"])
def test_docstring_examples(name):
  module = importlib.import_module(f"jaxchain.{name}")
  result = doctest.testmod(module, extraglobs={"jc": jaxchain}, optionflags=doctest.ELLIPSIS)
  assert result.attempted > 0 and result.failed == 0
