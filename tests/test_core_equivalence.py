"""The batch-minor core (`jaxchain.core`) against the pass it replaces (`jaxchain._legacy`).

Until the previous pass is removed, both run the same batches and must agree: the room of
64 (the benchmark batch, at rest, and a perturbed one: positions moved by up to 0.1,
velocities up to 3 units/s) and the shipped platformer1 level with every feature on
(one-way platforms, sensors, layers, friction, immovable bodies, seams), perturbed, at
`for_world`'s config and with substeps, iterations, the grid and the neighbour table.
Status bits (after every step), touching, crushed and sensed are equal; positions and
velocities are bit-identical (the core's three rounding mirrors, `core.step.substep`'s
prediction, the impulse updates and `layout.world_sum`, make them so).
"""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxchain as jc
from jaxchain import _legacy

B, T = 4, 12
FIELDS = ("pos", "vel", "status", "touching", "crushed", "sensed")


def _perturbed(world, seed=0, dp=0.1, dv=3.0):
  batch = jax.tree.map(lambda x: jnp.broadcast_to(x, (B,) + x.shape), world)
  rng = np.random.default_rng(seed)
  movable = np.asarray(world.movable)[None, :, None]
  shape = (B,) + world.pos.shape
  dpos = (rng.uniform(-dp, dp, shape) * movable).astype(np.float32)
  dvel = (rng.uniform(-dv, dv, shape) * movable).astype(np.float32)
  return dataclasses.replace(batch, pos=batch.pos + dpos, vel=batch.vel + dvel)


def _room():
  s = jc.scenes.lattice_room(64, 0)
  world = jc.World.create(s.pos, s.half, s.mass, friction=0.5, gravity=(0.0, -9.8))
  return world, jc.Config.for_world(world, dt=1 / 60, depth=8)


def _level():
  world = jc.levels.load("platformer1").world(friction=0.5)
  return world, jc.Config.for_world(world, one_way=True, sensors=True, layers=True)


def _room_benchmark():
  world, config = _room()
  return jax.tree.map(lambda x: jnp.broadcast_to(x, (B,) + x.shape), world), config


def _room_perturbed():
  world, config = _room()
  return _perturbed(world), config


def _level_perturbed(seed=0, **overrides):
  world, config = _level()
  batch = _perturbed(world, seed, dp=0.02, dv=2.0)
  if overrides:
    config = jc.Config.for_world(batch, one_way=True, sensors=True, layers=True, **overrides)
  return batch, config


CASES = {
    "room benchmark": _room_benchmark,
    "room perturbed": _room_perturbed,
    "level": _level_perturbed,
    "level substeps iterations": lambda: _level_perturbed(1, substeps=2, iterations=2),
    "level grid neighbours": lambda: _level_perturbed(2, broadphase="grid", neighbors=10),
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_core_equals_the_previous_pass(case):
  batch, config = CASES[case]()
  record = ("status",)
  old = jax.jit(jax.vmap(lambda w: _legacy.rollout(w, config, T, record=record)))(batch)
  new = jc.rollout(batch, config, T, record=record)
  for field in FIELDS:
    a, b = np.asarray(getattr(old[0], field)), np.asarray(getattr(new[0], field))
    assert np.array_equal(a, b), f"{case}: {field} differs (max {np.max(np.abs(a - b)) if a.dtype.kind == 'f' else np.sum(a != b)})"
  assert np.array_equal(np.asarray(old[1].status), np.asarray(new[1].status)), case
