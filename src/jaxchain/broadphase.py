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
      Unused slots hold any valid index and are masked out.
    mask: `[n, m]` bool, which slots are real candidate pairs. A pair (i, j) is
      listed in both rows i and j, so every pairwise quantity is computed from
      both sides and the resolver stays permutation-equivariant.
  """

  idx: jax.Array
  mask: jax.Array


def dense(active: jax.Array) -> Candidates:
  """All pairs of active bodies: `m = n`, the diagonal masked out. O(n^2).

  Args:
    active: `[n]` bool.
  """
  n = active.shape[0]
  idx = jnp.broadcast_to(jnp.arange(n, dtype=jnp.int32), (n, n))
  mask = active[:, None] & active[None, :] & ~jnp.eye(n, dtype=bool)
  return Candidates(idx=idx, mask=mask)


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
