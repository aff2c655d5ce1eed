"""Shared tolerances, configs and scene builders for the tests.

One table of named tolerances: float32 positions are O(10), so ~1e-6 relative.
"""

import numpy as np

import jaxchain as jc

TOL = {
    "exact_f32": dict(atol=2e-6, rtol=0.0),  # Closed-form answers on O(1) coordinates.
    "reference": dict(atol=2e-5, rtol=0.0),  # float32 JAX vs float64 reference, O(10) coords.
    "equivariance": dict(atol=1e-5, rtol=0.0),  # Same computation, sums in another order.
    "transform": dict(atol=1e-6, rtol=0.0),  # jit vs eager vs vmap.
    "grad": dict(atol=1e-4, rtol=1e-4),
}

CAPACITY = 24  # Every equivalence scene is padded to this many bodies: one compile.

# Configs shared across modules so compiled functions are reused.
DEEP = jc.Config(depth=24, gravity=(0.0, 0.0))


def pad_world(scene, capacity=CAPACITY):
  return scene.world().pad(capacity)


def resolve_scene(scene, config=DEEP, capacity=CAPACITY):
  """Resolved positions of a host scene with the JAX resolver, float64 host array."""
  world = jc.resolve(pad_world(scene, capacity), config)
  return np.asarray(world.pos, np.float64)[: len(scene.pos)]
