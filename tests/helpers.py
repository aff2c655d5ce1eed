"""Shared tolerances, configs and scene builders for the tests.

One table of named tolerances: float32 positions are O(10), so ~1e-6 relative.
"""

import numpy as np

import jaxchain as jc
from jaxchain import scenes

TOL = {
    "exact_f32": dict(atol=2e-6, rtol=0.0),  # Closed-form answers on O(1) coordinates.
    "reference": dict(atol=2e-5, rtol=0.0),  # float32 JAX vs float64 reference, O(10) coords.
    "equivariance": dict(atol=1e-5, rtol=0.0),  # Same computation, sums in another order.
    "transform": dict(atol=1e-6, rtol=0.0),  # jit vs eager vs vmap.
    "grad": dict(atol=1e-4, rtol=1e-4),
}

CAPACITY = 24  # Every equivalence scene is padded to this many bodies: one compile.

# Configs shared across modules so compiled functions are reused.
DEEP = jc.Config(depth=24, gravity=False)


def pad_world(scene, capacity=CAPACITY):
  return scene.world().pad(capacity)


def resolve_scene(scene, config=DEEP, capacity=CAPACITY):
  """Resolved positions of a host scene with the JAX resolver, float64 host array."""
  world = jc.resolve(pad_world(scene, capacity), config)
  return np.asarray(world.pos, np.float64)[: len(scene.pos)]


def mixed_room(seed, n_boxes=20, n_tiles=3):
  """A 10 x 10 room: long floor, ceiling and walls, a few immovable tiles, and
  overlapping movable boxes of mixed sizes (half-extents 0.1 to 0.5)."""
  rng = np.random.default_rng(seed)
  pos = [[5.0, -0.5], [5.0, 10.5], [-0.5, 5.0], [10.5, 5.0]]
  half = [[6.0, 0.5], [6.0, 0.5], [0.5, 5.0], [0.5, 5.0]]
  pos += rng.uniform(1, 9, (n_tiles, 2)).tolist()
  half += rng.uniform(0.2, 1.5, (n_tiles, 2)).tolist()  # Tiles may be larger than a cell.
  pos += rng.uniform(0.3, 9.7, (n_boxes, 2)).tolist()
  half += rng.uniform(0.1, 0.5, (n_boxes, 2)).tolist()
  mass = np.r_[np.full(4 + n_tiles, np.inf), rng.uniform(0.5, 2.0, n_boxes)]
  return scenes.Scene(np.asarray(pos), np.asarray(half), mass)
