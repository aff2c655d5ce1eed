"""Candidate pairs: a fixed-size neighbour table that the narrowphase consumes.

Every broadphase fills the same `Candidates` table, `[n, m]` neighbour indices
plus a mask, so the chain resolver does not care how the candidates were found.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np

from jaxchain.config import DENSE_MAX_BODIES, Config


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class Candidates:
  """Neighbour table.

  Attributes:
    idx: `[n, m]` int32, `idx[i, k]` is the k-th candidate partner of body i.
      Unused slots hold any valid index and are masked out. `None` means dense:
      `m = n` and `idx[i, k] = k`, so gathers become broadcasts.
    mask: `[n, m]` bool, which slots are real candidate pairs. A pair (i, j) is
      listed in both rows i and j, so every pairwise quantity is computed from
      both sides and the resolver stays permutation-equivariant.
  """

  idx: jax.Array | None
  mask: jax.Array

  def gather(self, x: jax.Array) -> jax.Array:
    """Partner values of `x` with bodies on the last axis: `[..., n]` -> `[..., n, m]`."""
    if self.idx is None:
      return jnp.broadcast_to(x[..., None, :], x.shape[:-1] + (x.shape[-1], x.shape[-1]))
    return x[..., self.idx]

  def gather_bodies(self, x: jax.Array) -> jax.Array:
    """Per-partner values of a per-body array `x` of shape `[n, *f]`: `[n, m, *f]`."""
    if self.idx is None:
      n = x.shape[0]
      return jnp.broadcast_to(x[None], (n,) + x.shape)
    return x[self.idx]

  def partner_index(self) -> jax.Array:
    """`[n, m]` int32 partner indices (materialised for dense)."""
    if self.idx is None:
      n = self.mask.shape[0]
      return jnp.broadcast_to(jnp.arange(n, dtype=jnp.int32), (n, n))
    return self.idx


def dense(active: jax.Array) -> Candidates:
  """All pairs of active bodies: `m = n`, the diagonal masked out. O(n^2).

  Args:
    active: `[n]` bool.
  """
  n = active.shape[0]
  mask = active[:, None] & active[None, :] & ~jnp.eye(n, dtype=bool)
  return Candidates(idx=None, mask=mask)


def candidates(world, config: Config) -> Candidates:
  """The candidate table the config asks for (traced; shapes fixed by `n`)."""
  del config  # Only dense pairs exist so far; "grid" and "auto" fall back to them.
  return dense(world.active)


def choose(num_bodies: int) -> str:
  """The broadphase "auto" resolves to for worlds of `num_bodies` bodies."""
  return "dense" if num_bodies <= DENSE_MAX_BODIES else "grid"


def pair_count(num_bodies: int) -> int:
  """Number of candidate slots per world, `n * m`, for sizing estimates."""
  return int(np.int64(num_bodies) * num_bodies)
