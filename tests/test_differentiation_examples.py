"""examples/system_identification.py and examples/trajectory_optimisation.py at a tiny size
(issue 43 item 4): the fits recover what they should, in float32. Full size: the numbers
in docs/differentiation.md."""

import importlib.util
import pathlib

import numpy as np

ROOT = pathlib.Path(__file__).resolve().parents[1]


def _load(name):
  spec = importlib.util.spec_from_file_location(name, ROOT / "examples" / f"{name}.py")
  module = importlib.util.module_from_spec(spec)
  spec.loader.exec_module(module)
  return module


def test_system_identification_recovers_mass_and_friction():
  # 30 noisy steps (the full example records 90): mass and mu from a guess of (1, 0).
  example = _load("system_identification")
  out = example.identify(steps=30, iterations=8)
  assert out["mass_error"] < 0.02 and out["mu_error"] < 0.03, out
  # The loss reached is the noise's: 60 residuals of standard deviation NOISE.
  assert out["loss"] < 2 * 60 * example.NOISE**2, out


def test_trajectory_optimisation_brings_the_box_to_rest_near_the_target():
  example = _load("trajectory_optimisation")
  out = example.optimise(target=1.7, steps=30, iterations=30)
  assert out["loss"] < out["first_loss"] / 20, out
  assert abs(out["box_speed"]) < 0.05 and abs(out["box_x"] - 1.7) < 0.2, out
  pushes = out["pushes"]
  assert np.all(np.isfinite(pushes)) and pushes[0] > pushes[-1]  # Hard early, soft late.
