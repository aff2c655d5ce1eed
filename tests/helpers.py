"""Shared tolerances, configs and scene builders for the tests.

One table of named tolerances: float32 positions are O(10), so ~1e-6 relative.
"""

import functools

import jax
import jax.numpy as jnp
import numpy as np

import jaxchain as jc
from jaxchain import scenes

TOL = {
    "exact_f32": dict(atol=2e-6, rtol=0.0),  # Closed-form answers on O(1) coordinates.
    "reference": dict(atol=2e-5, rtol=0.0),  # float32 JAX vs float64 reference, O(10) coords.
    "equivariance": dict(atol=1e-5, rtol=0.0),  # Same computation, sums in another order.
    "transform": dict(atol=1e-6, rtol=0.0),  # jit vs eager vs vmap.
    "grad": dict(atol=1e-4, rtol=1e-4),
    # Gradients of rollouts against float64 central differences; `atol` is relative to the
    # largest derivative of the loss (a component near 0 is not held to its own scale).
    "grad_f64": dict(atol=1e-6, rtol=1e-5),
    "grad_f32": dict(atol=2e-3, rtol=2e-2),
    "jvp_smooth": dict(atol=1e-9, rtol=1e-3),  # float64 jvp on smooth scenes (issue 36 item 2).
}

CAPACITY = 24  # Every equivalence scene is padded to this many bodies: one compile.

# `compiler_options` for a program whose time goes to running it, not compiling it: the
# suite's codegen (tests/conftest.py: LLVM -O0, no fusion emitters) compiles fast and runs
# 4-5x slower, so a long rollout pays more than it saves (test_gradients' stiff scenes:
# compile 2.5 s + run 17.4 s at the suite's flags, 5.2 s + 3.7 s with these).
RUN_BOUND = {"xla_backend_optimization_level": 1}

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


# --- The core's stages on one world (`B = 1`), for tests of a single stage ---------------
# The core is batch minor: `[2, n, B]` positions, `[W, n, B]` candidate tables, `[B]`
# status. These helpers run a stage on one world and read its tables back as `[n, ...]`.


def xy(x):
  """`[n, 2]` -> `[2, n, 1]`, the core's layout of one world."""
  return jnp.asarray(x).T[..., None]


def bodies_of(world):
  """The core's `Bodies` of one world (`B = 1`)."""
  return jc.core.from_world(world)[1]


def dense_candidates(world):
  """Dense pairs of one world, `[n, n, 1]`."""
  return jc.core.pairs.dense(jnp.asarray(world.active)[:, None])


def contact_table(world, cand, skin, pos=None, **kwargs):
  """`(code, overlap, partner)` of `core.contacts.contacts` on one world, each `[n, W]`
  (row i, candidate slot k): code 0..3 a link in that direction, 4 none."""
  pos = world.pos if pos is None else pos
  c = _contacts(xy(pos), xy(world.half), cand, skin, **kwargs)
  row = lambda x: np.asarray(x)[..., 0].T
  return row(c.code), row(c.overlap), row(cand.index())


@functools.partial(jax.jit, static_argnames="skin")
def _contacts(pos, half, cand, skin, **kwargs):
  return jc.core.contacts.contacts(pos, half, cand, skin, **kwargs)


def contact_set(world, cand, skin):
  """`{(i, j, direction, depth)}` of the links of movable bodies i, depth to 6 places."""
  code, overlap, idx = contact_table(world, cand, skin)
  movable = np.asarray(world.movable)
  return {(int(i), int(idx[i, k]), int(code[i, k]), round(max(float(overlap[i, k]), 0.0), 6))
          for i, k in zip(*np.nonzero(code < 4)) if movable[i]}
