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
compiled program holds no collective). On one device it is one block. The blocks are
the context mesh's devices; a batch whose type shards it over explicit mesh axes
(traced outside `jax.set_mesh`) is split as its type says.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
from jax.custom_batching import custom_vmap
from jax.sharding import NamedSharding, PartitionSpec as P


def _devices() -> int:
  """How many devices a batch may be spread over: the context mesh's, else the runtime's."""
  mesh = jax.sharding.get_abstract_mesh()
  return mesh.size if not mesh.empty else jax.device_count()


def _explicit_batch(table: jax.Array) -> tuple[int, NamedSharding] | None:
  """How `table`'s batch axis (0) is split when its type shards it over explicit mesh axes.

  That is a batch placed with a `NamedSharding` over a `jax.make_mesh` mesh and traced
  outside `jax.set_mesh` and outside `sharding.in_auto_axes` (which make the axes Auto).

  Returns:
    `(shards, sharding)`: how many blocks the batch axis is split into, and the sharding
    (`P(batch axes)`) of an array whose leading axis is sharded as that batch axis is.
    `None` when the type says nothing (Auto axes, no mesh, a batch axis not sharded).
  """
  sharding = getattr(jax.typeof(table), "sharding", None)
  mesh, spec = getattr(sharding, "mesh", None), getattr(sharding, "spec", None)
  if mesh is None or mesh.empty or not mesh.explicit_axes or not spec or spec[0] is None:
    return None
  names = spec[0] if isinstance(spec[0], tuple) else (spec[0],)
  if any(name not in mesh.explicit_axes for name in names):
    return None
  return math.prod(mesh.shape[name] for name in names), NamedSharding(mesh, P(spec[0]))


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
  return _take(table, idx), _gather(tangents[0], idx)


def _gather(table, idx):
  # Indices are in range by contract: no clamping, and no wrapping of negative ones
  # (each would add elementwise work to every gather's indices: 6% of the demo's
  # compiled instructions, `benchmarks/compile_time.py`).
  return table.at[idx].get(mode="promise_in_bounds", wrap_negative_indices=False)


_take_flat = custom_vmap(_gather)


def _take_flat_batched(axis_size, in_batched, table, idx):
  mesh = _typed_mesh(table, idx)
  if mesh is None:
    return _take_blocks(axis_size, in_batched, table, idx)
  # Arrays typed with an explicit mesh but no context mesh (a call outside `jax.set_mesh`):
  # JAX's gather rule looks the batch's axis names up in the context mesh, and in the
  # table's mesh, which for a table that is not batched (a constant) is none.
  with jax.sharding.use_abstract_mesh(mesh):
    if in_batched[0]:
      return _take_blocks(axis_size, in_batched, table, idx)
    table = jax.sharding.reshard(table, NamedSharding(mesh, P()))  # Replicated, typed.
    typed = jax.typeof(idx).sharding  # The output is sharded as the indices.
    out_sharding = NamedSharding(mesh, typed.spec if typed.mesh == mesh else P())
    return table.at[idx].get(mode="promise_in_bounds", out_sharding=out_sharding), in_batched[1]


def _typed_mesh(*arrays: jax.Array) -> jax.sharding.AbstractMesh | None:
  """The explicit mesh some of `arrays` is typed with, if there is no context mesh."""
  if not jax.sharding.get_abstract_mesh().empty:
    return None
  for a in arrays:
    mesh = getattr(getattr(jax.typeof(a), "sharding", None), "mesh", None)
    if isinstance(mesh, jax.sharding.AbstractMesh) and not mesh.empty and mesh.explicit_axes:
      return mesh
  return None


def _take_blocks(axis_size, in_batched, table, idx):
  table_batched, idx_batched = in_batched
  if not table_batched:  # One table for every world: index it directly.
    return _take_flat(table, idx), idx_batched
  if not idx_batched:
    idx = jnp.broadcast_to(idx, (axis_size,) + idx.shape)
  size = table.shape[-1]
  typed = _explicit_batch(table)
  blocks = _devices() if typed is None else typed[0]
  blocks = blocks if axis_size % blocks == 0 else 1
  per_block = axis_size // blocks
  if per_block * size >= 2**31:
    raise ValueError(f"take: a batch of {per_block} tables of {size} values is too large for "
                     "int32 offsets; split the batch")
  offsets = (size * jnp.arange(per_block, dtype=idx.dtype)).reshape((-1,) + (1,) * (idx.ndim - 1))
  if blocks == 1:
    return _take_flat(table.reshape(-1), idx + offsets), True
  # Under explicit axes a reshape that splits the sharded batch axis must name its
  # sharding (block k is the shard on device k: no data moves), and the indices must be
  # sharded as the table (a no-op when they are; a local slice when they are replicated).
  split = {} if typed is None else dict(out_sharding=typed[1])
  flat = table.reshape(blocks, per_block * size, **split)
  if typed is not None and _explicit_batch(idx) != typed:
    idx = jax.sharding.reshard(idx, typed[1])
  ids = idx.reshape((blocks, per_block) + idx.shape[1:], **split) + offsets[None]
  out = jax.vmap(_gather)(flat, ids)  # Batched over blocks: each stays on its device.
  return out.reshape(idx.shape, **split), True


_take_flat.def_vmap(_take_flat_batched)
