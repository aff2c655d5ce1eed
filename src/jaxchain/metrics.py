"""Error measures over one world (vmap them over a batch)."""

from __future__ import annotations

import jax
import jax.numpy as jnp

from jaxchain import flags, geometry
from jaxchain.world import World


def penetration(world: World) -> jax.Array:
  """`[n, n]` penetration depth of each pair that can be resolved: both active, at
  least one movable, neither a sensor nor one-way (they may overlap by design), and
  in layers that collide; 0 elsewhere. Depth is the overlap along the axis of
  smaller overlap, clipped at 0. Dense O(n^2)."""
  pos, half = world.pos, world.half
  o = geometry.overlap(pos[:, None, :], half[:, None, :], pos[None], half[None])
  depth = jnp.maximum(jnp.minimum(o[..., 0], o[..., 1]), 0.0)
  pair = world.active[:, None] & world.active[None, :] & ~jnp.eye(pos.shape[0], dtype=bool)
  pair &= world.movable[:, None] | world.movable[None, :]
  pair &= ~world.one_way[:, None] & ~world.one_way[None, :]
  pair = flags.admit(geometry.Candidates(None, pair), world, layers=True, sensors=True).mask
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
