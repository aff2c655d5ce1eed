"""Sharding a batch of worlds over devices: the pieces the step needs (issue 11).

A batch of worlds (a `World` with a leading batch axis) shards over devices with
`jax.sharding` like any array: `jax.device_put(batch, NamedSharding(mesh, P("worlds")))`
and a `jax.vmap`-ped step under `jax.set_mesh(mesh)`. Worlds never interact, so the
step needs no communication; these helpers keep it that way under both mesh axis types:

* `in_auto_axes` runs a per-world computation with the context mesh's explicit axes
  switched to `AxisType.Auto`. The mesh `jax.make_mesh` builds by default has explicit
  axes, and under them JAX 0.10.1 type-checks every batched op. Some of its batching
  rules reject a sharded batch axis that the same program runs fine with in Auto mode
  (see `in_auto_axes`); inside, the compiler partitions the batch as in Auto mode,
  bit-identically and without collectives.
* `take` is a batched gather, `x.reshape(-1)[idx]` per world, that under `vmap` does one
  flat 1-D gather per device-sized block of worlds (offsets `arange(per_block) * size`),
  never one across the whole batch: a flat gather over a sharded batch axis makes XLA
  all-gather the operand on every call, while per-block gathers stay on their device.
  It works under explicit and Auto meshes and on one device, with gradients.

Examples:
  >>> import jax, jax.numpy as jnp
  >>> from jaxchain.sharding import take
  >>> x = jnp.arange(12.0).reshape(3, 4)             # 3 worlds, 4 values each
  >>> idx = jnp.array([[3, 0], [1, 1], [2, 3]])      # per world
  >>> jax.vmap(take)(x, idx).tolist()
  [[3.0, 0.0], [5.0, 5.0], [10.0, 11.0]]
"""

from __future__ import annotations

import math
from typing import Any, Callable

import jax
import jax.numpy as jnp
from jax import lax
from jax.sharding import NamedSharding, PartitionSpec as P


def in_auto_axes(fn: Callable[..., Any], *args: Any) -> Any:
  """`fn(*args)` with every explicit axis of the context mesh made `AxisType.Auto`.

  For per-world code (the body of `jc.step`, `jc.rollout`, `jc.resolve`) that may run
  under a user's `jax.vmap` with the batch sharded over an explicit mesh axis. JAX
  0.10.1 rejects such a batch in several batching rules that the step relies on: a
  `jnp.where` of a per-world scalar between constants (`select_n`), a gather from an
  operand that is not batched with batched indices, and a loop carry that starts as an
  unbatched scalar (`lax.fori_loop`, `jnp.searchsorted`'s default `method="scan"`).
  Inside `jax.sharding.auto_axes` those axes are Auto and the program is partitioned as
  it is for an Auto mesh: no collectives, the same bits as on one device. The outputs
  come back replicated per world (`P()`), so a vmapped batch stays sharded along its
  batch axis. Without a mesh, or with no explicit axes, it just calls `fn(*args)`.

  Args:
    fn: a function of arrays (pytrees) returning arrays (pytrees).
    *args: its arguments.

  Returns:
    `fn(*args)`.
  """
  mesh = jax.sharding.get_abstract_mesh()
  if mesh.empty or not mesh.explicit_axes:
    return fn(*args)
  return jax.sharding.auto_axes(fn, axes=mesh.explicit_axes, out_sharding=P())(*args)


def _batch_axes(x: jax.Array) -> tuple[tuple[str, ...], Any]:
  """The mesh axes the leading axis of `x` is explicitly sharded over, and the mesh."""
  sharding = jax.typeof(x).sharding
  axes = sharding.spec[0] if len(sharding.spec) else None
  if axes is None:
    return (), sharding.mesh
  return (axes if isinstance(axes, tuple) else (axes,)), sharding.mesh


def _spec(axes: tuple[str, ...], ndim: int) -> P:
  return P(axes if len(axes) > 1 else axes[0], *([None] * (ndim - 1)))


def _blocks(x: jax.Array, batch: int) -> tuple[int, tuple[str, ...]]:
  """Into how many blocks of worlds to split a batch of `batch` so that no block spans
  two devices, and the explicit mesh axes of the batch (if any).

  Explicitly sharded: the devices along its batch axes. Otherwise (Auto axes, or no
  mesh) the type does not say, so every device of the context mesh, or of the runtime
  without one; one world per block (vmap's own batched gather) if that does not divide
  the batch. On one device: a single block, one flat gather for the whole batch.
  """
  axes, mesh = _batch_axes(x)
  if axes:
    devices = math.prod(mesh.shape[a] for a in axes)
  else:
    context = jax.sharding.get_abstract_mesh()
    devices = context.size if not context.empty else jax.device_count()
  return (devices if batch % devices == 0 else batch), axes


def _reshape(x: jax.Array, shape: tuple[int, ...], axes: tuple[str, ...], mesh) -> jax.Array:
  """`x.reshape(shape)` keeping the leading axis on explicit mesh `axes` (if any)."""
  if not axes:
    return x.reshape(shape)
  return lax.reshape(x, shape, out_sharding=NamedSharding(mesh, _spec(axes, len(shape))))


def _flat_gather(flat: jax.Array, idx: jax.Array) -> jax.Array:
  return flat.at[idx].get(mode="promise_in_bounds")


@jax.custom_batching.custom_vmap
def _take(x: jax.Array, idx: jax.Array) -> jax.Array:
  return _flat_gather(x.reshape(-1), idx)


@_take.def_vmap
def _take_vmap(axis_size: int, in_batched, x: jax.Array, idx: jax.Array):
  """The batch rule: `x` `[b, *s]`, `idx` `[b, *k]` (either may be unbatched)."""
  x_batched, idx_batched = in_batched
  if not x_batched:
    # One operand for every world (a constant table): gather it with the batched
    # indices directly; explicit typing wants the output spec, which is the indices'.
    out_sharding = jax.typeof(idx).sharding if _batch_axes(idx)[0] else None
    return x.reshape(-1).at[idx].get(mode="promise_in_bounds", out_sharding=out_sharding), True
  axes, mesh = _batch_axes(x)
  if not idx_batched:
    shape, dims = (axis_size,) + idx.shape, tuple(range(1, idx.ndim + 1))
    idx = lax.broadcast_in_dim(idx, shape, dims, out_sharding=(
        NamedSharding(mesh, _spec(axes, len(shape))) if axes else None))
  blocks, axes = _blocks(x, axis_size)
  per_block = axis_size // blocks
  size = math.prod(x.shape[1:])
  xs = _reshape(x, (blocks, per_block * size), axes, mesh)
  ids = _reshape(idx, (blocks, per_block) + idx.shape[1:], axes, mesh)
  offsets = jnp.arange(per_block, dtype=idx.dtype) * size
  ids = ids + offsets.reshape((1, per_block) + (1,) * (idx.ndim - 1))
  if blocks == 1:
    out = _flat_gather(xs[0], ids[0])[None]
  else:
    out = jax.vmap(_flat_gather)(xs, ids)  # Batched over blocks: each stays on its device.
  return _reshape(out, idx.shape, axes, mesh), True


@jax.custom_vjp
def take(x: jax.Array, idx: jax.Array) -> jax.Array:
  """`x.reshape(-1)[idx]`: values of one world's array `x` at flat indices `idx`.

  Under `jax.vmap` it does one flat gather per block of worlds that lives on one
  device (see the module docstring); the result is the same as `x.reshape(-1)[idx]`
  in every world, bit for bit. Indices must be in bounds (`0 <= idx < x.size`).
  Differentiable in `x` (reverse mode; the transpose is a scatter-add).

  Args:
    x: any array (one world's values).
    idx: int array of flat indices into `x`.

  Returns:
    An array shaped like `idx`, dtype of `x`.
  """
  return _take(x, idx)


def _take_fwd(x, idx):
  return _take(x, idx), (idx, jnp.zeros_like(x))


def _take_bwd(res, cotangent):
  idx, zeros = res
  grad = zeros.reshape(-1).at[idx].add(cotangent, mode="promise_in_bounds")
  return grad.reshape(zeros.shape), None


take.defvjp(_take_fwd, _take_bwd)
