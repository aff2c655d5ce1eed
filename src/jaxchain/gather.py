"""The one gather every chain hop is made of, formulated for XLA on CPU.

`take(table, idx)` is `table[idx]` for a 1-D `table`. Under `jax.vmap` the plain
gather becomes a batched gather, which XLA:CPU runs at 2.4-3.9 ns per element on the
link tables of a chain hop; `take` instead flattens the batch and gathers once from
the flat table with per-world offsets, 0.8-1 ns per element
(`benchmarks/results/profile.md`, `../shared/perf/xla_cpu_formulations.py`). The
answer is the same value for value; only the formulation differs.

Differentiable in both modes: the tangent of a gather is the same gather of the
tangent, written as a plain `jnp` gather so that reverse mode can transpose it (a
scatter-add); only the primal takes the flat path.

Over several devices the batch is flattened per block of worlds that lives on one
device (one block per device of the mesh, or of the runtime without one): a single
flat gather across a sharded batch would make XLA all-gather the table on every hop,
while one gather per block stays on its device (`tests/test_sharding.py` checks the
compiled program holds no collective). On one device it is one block.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jax.custom_batching import custom_vmap


def _devices() -> int:
  """How many devices a batch may be spread over: the context mesh's, else the runtime's."""
  mesh = jax.sharding.get_abstract_mesh()
  return mesh.size if not mesh.empty else jax.device_count()


def take(table: jax.Array, idx: jax.Array) -> jax.Array:
  """`table[idx]`: a 1-D `table` of `s` values, int32 `idx` of any shape, all in
  `[0, s)` (not checked: an index out of range gives an unspecified value).

  Under `vmap` (any number of levels) the batch is flattened into one gather.
  """
  if table.ndim != 1:
    raise ValueError(f"take: expected a 1-D table, got shape {table.shape}")
  if not jnp.issubdtype(table.dtype, jnp.inexact):  # Integers: nothing to differentiate.
    return _take_flat(table, idx)
  return _take(table, idx)


@jax.custom_jvp
def _take(table, idx):
  return _take_flat(table, idx)


@_take.defjvp
def _take_jvp(primals, tangents):
  table, idx = primals
  return _take(table, idx), tangents[0][idx]


def _gather(table, idx):
  return table.at[idx].get(mode="promise_in_bounds")


_take_flat = custom_vmap(_gather)


def _take_flat_batched(axis_size, in_batched, table, idx):
  table_batched, idx_batched = in_batched
  if not table_batched:  # One table for every world: index it directly.
    return _take_flat(table, idx), idx_batched
  if not idx_batched:
    idx = jnp.broadcast_to(idx, (axis_size,) + idx.shape)
  size = table.shape[-1]
  blocks = _devices()
  blocks = blocks if axis_size % blocks == 0 else 1
  per_block = axis_size // blocks
  if per_block * size >= 2**31:
    raise ValueError(f"take: a batch of {per_block} tables of {size} values is too large for "
                     "int32 offsets; split the batch")
  offsets = (size * jnp.arange(per_block, dtype=idx.dtype)).reshape((-1,) + (1,) * (idx.ndim - 1))
  if blocks == 1:
    return _take_flat(table.reshape(-1), idx + offsets), True
  flat = table.reshape(blocks, per_block * size)
  ids = idx.reshape((blocks, per_block) + idx.shape[1:]) + offsets[None]
  out = jax.vmap(_gather)(flat, ids)  # Batched over blocks: each stays on its device.
  return out.reshape(idx.shape), True


_take_flat.def_vmap(_take_flat_batched)
