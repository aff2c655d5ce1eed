"""Error measures over one world (vmap them over a batch)."""

from __future__ import annotations

import jax
import jax.numpy as jnp

from jaxchain.core import contacts
from jaxchain.world import World


def penetration(world: World) -> jax.Array:
  """`[n, n]` penetration depth of each pair that can be resolved: both active, at
  least one movable, neither a sensor, and in layers that collide; 0 elsewhere.
  Depth is the overlap along the axis of smaller overlap, clipped at 0. A pair with
  a one-way member and no solid one (a one-way body blocks only what comes down onto
  it: `core.contacts.ONE_WAY_MARGIN`) counts with the upper body's sink below the one-way
  top where the one-way rule lifts it out: at most the margin (deeper sinks pass
  through, or are crushes, flagged). Dense O(n^2)."""
  pos, half = world.pos, world.half
  o = half[:, None, :] + half[None] - jnp.abs(pos[None] - pos[:, None, :])  # Per axis.
  depth = jnp.maximum(jnp.minimum(o[..., 0], o[..., 1]), 0.0)
  pair = world.active[:, None] & world.active[None, :] & ~jnp.eye(pos.shape[0], dtype=bool)
  pair &= world.movable[:, None] | world.movable[None, :]
  col, row = (lambda x: x[:, None]), (lambda x: x[None, :])
  pair &= contacts.admits(col(world.category), col(world.mask), col(world.sensor),
                          row(world.category), row(world.mask), row(world.sensor))
  solid = world.active & (world.inv_mass == 0) & ~world.one_way
  vertical = ((world.one_way[:, None] | world.one_way[None, :])
              & ~solid[:, None] & ~solid[None, :])
  # i above j: i's bottom below j's top by `sink`; one pair entry per orientation.
  sink = (pos[None, :, 1] + half[None, :, 1]) - (pos[:, None, 1] - half[:, None, 1])
  margin = contacts.ONE_WAY_MARGIN * (half[:, None, 1] + half[None, :, 1])
  above = pos[:, None, 1] > pos[None, :, 1]
  lifted = jnp.where(above & (o[..., 0] > 0) & (sink > 0) & (sink <= margin), sink, 0.0)
  depth = jnp.where(vertical, jnp.maximum(lifted, lifted.T), depth)
  return jnp.where(pair, depth, 0.0)


def max_penetration(world: World) -> jax.Array:
  """Largest residual penetration between resolvable pairs (scalar)."""
  return jnp.max(penetration(world), initial=0.0)


def mean_penetration(world: World) -> jax.Array:
  """Mean penetration over the resolvable pairs that penetrate (0 if none)."""
  p = penetration(world)
  count = jnp.sum(p > 0)
  return jnp.where(count > 0, jnp.sum(p) / jnp.maximum(count, 1), 0.0)


def movable_com(world: World) -> jax.Array:
  """`[2]` centre of mass of the active movable bodies."""
  m = jnp.where(world.movable, 1.0 / jnp.where(world.movable, world.inv_mass, 1.0), 0.0)
  return jnp.sum(m[:, None] * world.pos, axis=0) / jnp.maximum(jnp.sum(m), 1e-30)
