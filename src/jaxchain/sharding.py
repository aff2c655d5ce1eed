"""Sharding a batch of worlds over devices (issue 11).

A batch of worlds (a `World` with a leading batch axis) shards over devices with
`jax.sharding` like any array: `jax.device_put(batch, NamedSharding(mesh, P("worlds")))`
and a `jax.vmap`-ped step under `jax.set_mesh(mesh)`. Worlds never interact, so the
step needs no communication, under both mesh axis types:

* `in_auto_axes` runs a computation (the core on a whole batch, or per-world code under
  `vmap`) with the context mesh's explicit axes switched to `AxisType.Auto`. The mesh
  `jax.make_mesh` builds by default has explicit axes, and under them JAX 0.10.1
  type-checks every batched op. Some of its batching rules reject a sharded batch axis
  that the same program runs fine with in Auto mode (see `in_auto_axes`); inside, the
  compiler partitions the batch as in Auto mode, bit-identically and without
  collectives. `jc.step`, `jc.rollout`, `jc.resolve` and `jc.make_step` run the core in it.
* `jaxchain.core.layout.take`, the gather of every chain hop, indexes each world's own
  lane when the batch spans devices (`core.layout.lanes_split`), never across the whole
  batch (which would make XLA all-gather the table on every hop).

`jax.set_mesh` is not needed: a batch placed on a mesh with explicit axes carries the
mesh in its type (`jax.typeof(x).sharding.mesh`), and `in_auto_axes` takes it from
there when there is no context mesh, so
`jax.jit(jax.vmap(lambda w: jc.rollout(w, cfg, 40)[0]))(sharded_batch)` gives the
one-device bits either way (issue 19).

Examples:
  >>> import jax, jax.numpy as jnp
  >>> from jaxchain.sharding import in_auto_axes
  >>> x = jnp.arange(6.0).reshape(3, 2)              # 3 worlds, 2 values each
  >>> jax.vmap(lambda w: in_auto_axes(lambda v: jnp.where(v.sum() > 2, v, 0.0), w))(x).tolist()
  [[0.0, 0.0], [2.0, 3.0], [4.0, 5.0]]
"""

from __future__ import annotations

from typing import Any, Callable

import jax
from jax.sharding import PartitionSpec as P


def in_auto_axes(fn: Callable[..., Any], *args: Any, batched: bool = False) -> Any:
  """`fn(*args)` with every explicit axis of the context mesh made `AxisType.Auto`.

  For code that may run on a batch sharded over an explicit mesh axis: the core (on a
  whole batch, `batched=True`) and per-world code under a user's `jax.vmap`. JAX
  0.10.1 rejects such a batch in several batching rules that the step relies on: a
  `jnp.where` of a per-world scalar between constants (`select_n`), a gather from an
  operand that is not batched with batched indices, and a loop carry that starts as an
  unbatched scalar (`lax.fori_loop`, `jnp.searchsorted`'s default `method="scan"`).
  Inside `jax.sharding.auto_axes` those axes are Auto and the program is partitioned as
  it is for an Auto mesh: no collectives, the same bits as on one device. The outputs
  come back replicated per world (`P()`), so a vmapped batch stays sharded along its
  batch axis; with `batched=True` every output's leading axis is the batch and comes
  back sharded as the inputs' leading axis is. The mesh is the context mesh
  (`jax.set_mesh`), else the one the arrays of `args` are typed with (see `mesh_of`).
  Without a mesh, or with no explicit axes, it just calls `fn(*args)`.

  Args:
    fn: a function of arrays (pytrees) returning arrays (pytrees).
    *args: its arguments.
    batched: every array of `args` and of the outputs has the batch of worlds as its
      leading axis.

  Returns:
    `fn(*args)`.
  """
  mesh = jax.sharding.get_abstract_mesh()
  if mesh.empty:  # No context mesh: a batch may still carry an explicit mesh in its type.
    typed = mesh_of(args)
    if typed is not None:
      with jax.sharding.use_abstract_mesh(typed):
        return _auto(fn, typed, args, batched)
  if mesh.empty or not mesh.explicit_axes:
    return fn(*args)
  return _auto(fn, mesh, args, batched)


def _auto(fn: Callable[..., Any], mesh: jax.sharding.AbstractMesh, args: tuple,
          batched: bool = False) -> Any:
  out = P(_batch_axes(args)) if batched else P()
  return jax.sharding.auto_axes(fn, axes=mesh.explicit_axes, out_sharding=out)(*args)


def _batch_axes(tree: Any):
  """The mesh axes the leading (batch) axis of the arrays of `tree` is sharded over
  (`None`: not sharded), as their types say."""
  for leaf in jax.tree.leaves(tree):
    if not isinstance(leaf, jax.Array) or leaf.ndim == 0:
      continue
    spec = getattr(getattr(jax.typeof(leaf), "sharding", None), "spec", None)
    if spec and spec[0] is not None:
      return spec[0]
  return None


def mesh_of(tree: Any) -> jax.sharding.AbstractMesh | None:
  """The mesh with explicit axes that some array of `tree` is typed with, else `None`.

  An array placed with `jax.device_put(x, NamedSharding(mesh, P("worlds")))` over a mesh
  with explicit axes carries that mesh in its type (`jax.typeof(x).sharding.mesh`), also
  per world inside `jax.vmap` and inside `jax.jit` called outside `jax.set_mesh`.

  Raises:
    ValueError: if arrays of `tree` are typed with two different such meshes.
  """
  found = None
  for leaf in jax.tree.leaves(tree):
    if not isinstance(leaf, jax.Array):  # Tracers are jax.Array too; NumPy has no mesh.
      continue
    sharding = getattr(jax.typeof(leaf), "sharding", None)
    mesh = getattr(sharding, "mesh", None)
    if not isinstance(mesh, jax.sharding.AbstractMesh) or mesh.empty or not mesh.explicit_axes:
      continue
    if found is not None and mesh != found:
      raise ValueError(f"jaxchain: arrays sharded over two different meshes ({found} and {mesh}); "
                       "place the whole batch on one mesh")
    found = mesh
  return found
