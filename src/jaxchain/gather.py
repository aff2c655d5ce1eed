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
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jax.custom_batching import custom_vmap


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


@custom_vmap
def _take_flat(table, idx):
  return table.at[idx].get(mode="promise_in_bounds")


@_take_flat.def_vmap
def _take_flat_batched(axis_size, in_batched, table, idx):
  table_batched, idx_batched = in_batched
  if not table_batched:  # One table for every world: index it directly.
    return _take_flat(table, idx), idx_batched
  if not idx_batched:
    idx = jnp.broadcast_to(idx, (axis_size,) + idx.shape)
  size = table.shape[-1]
  if axis_size * size >= 2**31:
    raise ValueError(f"take: a batch of {axis_size} tables of {size} values is too large for "
                     "int32 offsets; split the batch")
  offsets = (size * jnp.arange(axis_size, dtype=idx.dtype)).reshape((-1,) + (1,) * (idx.ndim - 1))
  flat = table.reshape(-1)
  return _take_flat(flat, idx + offsets), True
