"""Narrowphase: per candidate pair, the contact axis, direction and depth.

Directions are numbered `0: +x, 1: -x, 2: +y, 3: -y`; `d ^ 1` is the opposite.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp

from jaxchain.broadphase import Candidates

DIRECTIONS = ("+x", "-x", "+y", "-y")
NUM_DIRECTIONS = 4


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class Contacts:
  """Contacts over the candidate table, all `[n, m]`.

  Attributes:
    link: the pair touches (gap within `skin`) or overlaps along its contact axis
      and overlaps strictly along the other axis. Links carry pushes and mass.
    direction: int32 in 0..3, direction from body i towards partner j; resolving
      the contact moves j along it and i against it.
    depth: penetration along the contact axis, `max(overlap, 0)`; 0 unless `link`.
    overlap: signed overlap along the contact axis (negative: a gap within `skin`).
  """

  link: jax.Array
  direction: jax.Array
  depth: jax.Array
  overlap: jax.Array


def overlap(pos_a, half_a, pos_b, half_b):
  """Per-axis overlap `h_a + h_b - |p_b - p_a|` (positive means overlapping)."""
  return half_a + half_b - jnp.abs(pos_b - pos_a)


def along_axis(o: jax.Array, use_y: jax.Array) -> tuple[jax.Array, jax.Array]:
  """Splits per-axis values `[..., 2]` into (along the contact axis, along the other)."""
  return jnp.where(use_y, o[..., 1], o[..., 0]), jnp.where(use_y, o[..., 0], o[..., 1])


def contacts(pos: jax.Array, half: jax.Array, cand: Candidates, skin: float) -> Contacts:
  """Contacts of every candidate pair.

  The contact axis is the axis of smaller overlap (ties go to x). Along it the
  partner j lies in direction `sign(p_j - p_i)`; coincident centres go by index:
  the body with the larger index lies in the positive direction. That tie rule is
  the only place body order matters.

  Args:
    pos: `[n, 2]` centres.
    half: `[n, 2]` half-extents.
    cand: candidate table with `[n, m]` entries.
    skin: gap below which separated bodies still count as linked.
  """
  n = pos.shape[0]
  pos_j, half_j = cand.gather_bodies(pos), cand.gather_bodies(half)
  delta = pos_j - pos[:, None, :]
  o = overlap(pos[:, None, :], half[:, None, :], pos_j, half_j)
  use_y = o[..., 1] < o[..., 0]
  o_axis, o_other = along_axis(o, use_y)
  d_axis, _ = along_axis(delta, use_y)
  self_idx = jnp.arange(n, dtype=jnp.int32)[:, None]
  positive = (d_axis > 0) | ((d_axis == 0) & (cand.partner_index() > self_idx))
  link = cand.mask & (o_other > 0) & (o_axis >= -skin)
  direction = 2 * use_y.astype(jnp.int32) + (~positive).astype(jnp.int32)
  depth = jnp.where(link, jnp.maximum(o_axis, 0.0), 0.0)
  return Contacts(link=link, direction=direction, depth=depth, overlap=o_axis)

