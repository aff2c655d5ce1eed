"""The batch-minor layout of the core: every array is `[..., n, B]`.

The last axis is the batch of worlds, so every elementwise operation runs over B
contiguous worlds (XLA:CPU's vector lanes), and a gather for `(k, d, i)` reads B
neighbouring worlds' values side by side. A single world is `B = 1`.

* `Bodies`: what a step reads (half-extents, masses, flags, gravity), fixed over a
  rollout; `State`: what a step changes (positions, velocities, outputs, status).
* `from_world` / `to_world` transpose a `World` (`[n, ...]` or `[B, n, ...]`) into this
  layout once on the way in and once on the way out; a rollout stays in it.
* `take` is the one gather every stage is made of: a flat index into a flattened
  table, built once per stage (`flat_index`), never per hop.
"""

from __future__ import annotations

import contextlib
import contextvars
import dataclasses
import functools
import math

import jax
import jax.numpy as jnp
from jax import lax
from jax.custom_batching import custom_vmap

DIRECTIONS = ("+x", "-x", "+y", "-y")  # Direction d; `d ^ 1` is the opposite.
NUM_DIRECTIONS = 4


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class Bodies:
  """The per-body parameters a step reads, batch minor.

  Attributes:
    half: `[2, n, B]` half-extents (x and y slabs).
    inv_mass: `[n, B]` inverse masses (0: immovable).
    active: `[n, B]` bool.
    friction: `[n, B]` Coulomb coefficients.
    gravity: `[2, B]` per-world gravity.
    one_way, sensor: `[n, B]` bool.
    category, mask: `[n, B]` uint32 collision layers.
  """

  half: jax.Array
  inv_mass: jax.Array
  active: jax.Array
  friction: jax.Array
  gravity: jax.Array
  one_way: jax.Array
  sensor: jax.Array
  category: jax.Array
  mask: jax.Array

  @property
  def movable(self) -> jax.Array:
    """`[n, B]` bool: active bodies with finite mass."""
    return self.active & (self.inv_mass > 0)

  @property
  def fixed(self) -> jax.Array:
    """`[n, B]` bool: active immovable bodies."""
    return self.active & (self.inv_mass == 0)

  @property
  def shape(self) -> tuple[int, int]:
    """`(n, B)`."""
    return self.inv_mass.shape


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class State:
  """What a step changes, batch minor.

  Attributes:
    pos, vel: `[2, n, B]`.
    status: `[B]` int32 status bits (sticky).
    touching: `[4, n, B]` bool (`World.touching`, directions first).
    crushed, sensed: `[n, B]` bool.
  """

  pos: jax.Array
  vel: jax.Array
  status: jax.Array
  touching: jax.Array
  crushed: jax.Array
  sensed: jax.Array


def _minor(x: jax.Array, batched: bool) -> jax.Array:
  """`[B, n, k...]` (or `[n, k...]`) -> `[k..., n, B]` (`[k..., n, 1]`)."""
  x = jnp.asarray(x)
  if not batched:
    x = x[None]
  return jnp.moveaxis(x, (0, 1), (-1, -2))


def _major(x: jax.Array, batched: bool) -> jax.Array:
  """The inverse of `_minor`."""
  x = jnp.moveaxis(x, (-1, -2), (0, 1))
  return x if batched else x[0]


def from_world(world) -> tuple[State, Bodies]:
  """A `World` (single `[n, ...]` or batched `[B, n, ...]`) -> `(State, Bodies)`."""
  batched = world.pos.ndim == 3
  m = lambda x: _minor(x, batched)
  per_world = lambda x: jnp.asarray(x) if batched else jnp.asarray(x)[None]
  state = State(pos=m(world.pos), vel=m(world.vel), status=per_world(world.status),
                touching=m(world.touching), crushed=m(world.crushed), sensed=m(world.sensed))
  gravity = jnp.moveaxis(per_world(world.gravity), 0, -1)  # [2, B]
  bodies = Bodies(half=m(world.half), inv_mass=m(world.inv_mass), active=m(world.active),
                  friction=m(world.friction), gravity=gravity, one_way=m(world.one_way),
                  sensor=m(world.sensor), category=m(world.category), mask=m(world.mask))
  return state, bodies


def to_world(world, state: State):
  """`world` with the outputs of `state` (the layout of `world`: single or batched)."""
  batched = world.pos.ndim == 3
  m = lambda x: _major(x, batched)
  status = state.status if batched else state.status[0]
  return dataclasses.replace(world, pos=m(state.pos), vel=m(state.vel), status=status,
                             touching=m(state.touching), crushed=m(state.crushed),
                             sensed=m(state.sensed))


def world_index(shape: tuple[int, ...]) -> jax.Array:
  """`[B]` int32 `0..B-1`, the world lane of the last axis of `shape`."""
  return jnp.arange(shape[-1], dtype=jnp.int32)


def lanes_split() -> bool:
  """Whether gathers index each world's lane apart (several devices) or one flat table.

  On one device a gather of `x[..., j, b]` is one flat `take` at `j * B + b`: B
  neighbouring worlds side by side. With the batch spread over devices a flat index
  would cross devices (XLA would all-gather the table on every hop); there each gather
  is batched over the world lane instead (`jax.vmap` over the last axis), which the
  partitioner keeps on each device. The devices are the context mesh's, else the
  runtime's (decided at trace time).
  """
  mesh = jax.sharding.get_abstract_mesh()
  return (mesh.size if not mesh.empty else jax.device_count()) > 1


def lane_index(rows: jax.Array) -> jax.Array:
  """The index `take` reads for rows `rows` (`[..., B]` int32, a row of the table
  flattened to `[R, B]`, in the lane of the last axis): `rows * B + b`, or the rows
  themselves when the lanes are split (`lanes_split`)."""
  if lanes_split():
    return rows
  lanes = world_index(rows.shape).reshape((1,) * (rows.ndim - 1) + rows.shape[-1:])
  return rows * rows.shape[-1] + lanes


def shift(index: jax.Array, rows: jax.Array | int) -> jax.Array:
  """`index` (from `lane_index`) moved by `rows` rows (`rows` may have more leading
  axes than `index`: the result has them too)."""
  rows = jnp.asarray(rows, jnp.int32)
  index = index.reshape((1,) * max(rows.ndim - index.ndim, 0) + index.shape)
  return index + (rows if lanes_split() else rows * index.shape[-1])


def take(table: jax.Array, index: jax.Array) -> jax.Array:
  """`table[..., b]` at the rows `index` names (`lane_index`), lane by lane: `[..., B]`.
  The indices are in range by construction (no clamping, no wrapping of negative
  indices: each would add work to every gather)."""
  get = lambda t, i: t.at[i].get(mode="promise_in_bounds", wrap_negative_indices=False)
  if lanes_split():
    rows = table.reshape(-1, table.shape[-1])
    return jax.vmap(get, in_axes=(-1, -1), out_axes=-1)(rows, index)
  return get(table.reshape(-1), index)


def scatter_max(rows: int, index: jax.Array, values: jax.Array) -> jax.Array:
  """`[rows, B]`: per lane the maximum of `values` scattered to the rows `index` names
  (`lane_index`), 0 where nothing lands."""
  B = index.shape[-1]
  put = lambda size, i, v: jnp.zeros((size,), values.dtype).at[i].max(v, mode="promise_in_bounds")
  if lanes_split():
    return jax.vmap(lambda i, v: put(rows, i, v), in_axes=(-1, -1), out_axes=-1)(
        index.reshape(-1, B), values.reshape(-1, B))
  return put(rows * B, index.reshape(-1), values.reshape(-1)).reshape(rows, B)


def opposite(x: jax.Array, axis: int = 0) -> jax.Array:
  """`x` with its direction axis (size 4) permuted `d -> d ^ 1`, as a reshape and a
  reversal (XLA runs it as a copy; an index gather is slower)."""
  axis = axis % x.ndim
  pairs = x.reshape(x.shape[:axis] + (2, 2) + x.shape[axis + 1:])
  return jnp.flip(pairs, axis + 1).reshape(x.shape)


def along(x: jax.Array, y: jax.Array) -> jax.Array:
  """The components along +x, -x, +y, -y of a vector given by its slabs: `[4, ...]`."""
  return jnp.stack([x, -x, y, -y])


def per_axis(x: jax.Array) -> jax.Array:
  """`[4, ...]` per direction -> `[2, ...]` per axis: `(x0 + x1, x2 + x3)`."""
  return jnp.stack([x[0] + x[1], x[2] + x[3]])


def safe_divide(num, den, default: float = 0.0):
  """`num / den` where `den > 0`, else `default`, with finite gradients: the inner
  `where` keeps the division away from 0 (a single outer `where` would still send
  `0 * inf = nan` back through the branch it did not select)."""
  ok = den > 0
  return jnp.where(ok, num / jnp.where(ok, den, 1.0), default)


def pair_coefficient(a: jax.Array, b: jax.Array) -> jax.Array:
  """The friction coefficient of a pair: the smaller of the bodies' coefficients
  (`>= 0`), `min(a, b)`: 0 if either is 0, `a` when both are `a` (exactly).

  Its derivative is finite everywhere: 1 in the smaller coefficient, 0 in the other, so 1
  at `a = 0 < b` (the geometric mean `sqrt(ab)` it replaces has derivative 0 there and
  `0.5 sqrt(b/a)`, unbounded, just above). At `a = b` (a coefficient shared by the
  bodies) each gets 1/2, so the derivative of `mu(x, x)` in `x` is 1 everywhere, 0
  included: a shared coefficient fitted from a guess of 0 moves. (The harmonic mean,
  smooth at `a = b`, was tried first: it put the offset stack of
  tests/test_gradients.py's jvp test within 3e-5 of a slip switch, where the geometric
  mean, the minimum and the arithmetic mean keep it smooth; the arithmetic mean gives a
  frictionless body friction.)
  """
  return jnp.minimum(a, b)


# --- Derivatives at ties: one piece, by a rule (docs/physics.md, "Gradients at ties") ---
# The resolver is piecewise smooth. At a tie (a `max` whose arguments are equal, a
# `max(x, 0)` at `x = 0`) JAX's own rules pass half the tangent to each side: a mixture of
# the pieces, the derivative of none. Chained through the hops, the impulses and the
# steps of a rollout, such mixtures are not even bounded: two boxes resting together after
# an impact gave a step Jacobian of spectral radius 2.9, so gradients grew about 2x per
# step (issue 37). The rules below give the derivative of one piece at every tie: that of
# the piece that pushes where the tie `lead`s (a link whose bodies close on each other),
# else that of the piece that does not.


@jax.custom_jvp
def positive(x: jax.Array, lead: jax.Array) -> jax.Array:
  """`max(x, 0)`, whose derivative at `x = 0` is `x`'s where `lead` (bool, broadcasting
  with `x`), else 0's (`jnp.maximum` gives half of each)."""
  del lead
  return jnp.maximum(x, 0.0)


@positive.defjvp
def _positive_jvp(primals, tangents):
  x, lead = primals
  return positive(x, lead), jnp.where((x > 0) | ((x == 0) & lead), tangents[0], 0.0)


@jax.custom_jvp
def push_max(x: jax.Array, lead: jax.Array) -> jax.Array:
  """`max(0, max over axis 0 of x)`: a body's push, the largest of its pushers'.

  Derivative: the mean of the tied largest entries' where the push is > 0; where it is 0,
  the mean of the entries at 0 that `lead` (bool, like `x`: a pusher that closes on the
  body), else 0 (nothing pushes: the piece in which the contact does not push)."""
  del lead
  return jnp.max(x, axis=0, initial=0.0)


@push_max.defjvp
def _push_max_jvp(primals, tangents):
  x, lead = primals
  m = push_max(x, lead)
  top = (x == m[None]) & ((m[None] > 0) | lead)
  count = jnp.sum(top, axis=0).astype(x.dtype)
  total = jnp.sum(jnp.where(top, tangents[0], 0.0), axis=0)
  return m, safe_divide(total, count)


@functools.partial(jax.custom_jvp, nondiff_argnums=(0, 1))
def choose(fn, chosen, *args):
  """`fn(*args)`, with the derivative of `chosen(*args)`: the same function written with
  the piece a tie rule chose (equal to `fn` wherever the two select different pieces, at
  ties). `chosen` is traced only under differentiation, so the forward step is `fn`'s."""
  del chosen
  return fn(*args)


@choose.defjvp
def _choose_jvp(fn, chosen, primals, tangents):
  return fn(*primals), jax.jvp(chosen, primals, tangents)[1]


def _materialise(x: jax.Array) -> jax.Array:
  if x.size == 0:
    return x
  # An offset XLA cannot prove is 0: whether the first element, as a float, is NaN (for
  # an integer array `x != x` is provably false and the copy would be simplified away).
  first = x.reshape(-1)[0].astype(jnp.float32)
  zero = jnp.zeros((), jnp.int32) * jnp.isnan(first).astype(jnp.int32)
  return lax.dynamic_update_slice(jnp.zeros_like(x), x, (zero,) * x.ndim)


@jax.custom_jvp
def materialise(x: jax.Array) -> jax.Array:
  """`x`, computed into memory once. XLA fuses cheap elementwise producers into each
  consumer (recomputing them there) and XLA:CPU drops `optimization_barrier`; a
  dynamic-update-slice at an offset it cannot prove is 0 it keeps, as one copy. Its
  tangent is the tangent itself (a copy changes no derivative, and a tangent needs no
  copy).

  The core runs batched by hand, so `vmap` reaches this only in a vmapped gradient's
  tangent rule, a vmapped closed-loop rollout or a vmapped query, where the copy becomes
  a batched update (a scatter: a vmapped rollout with a policy, 256 worlds, measured
  within 3% of a copy over the whole batch). It was a `custom_vmap` that copied the
  batch whole, but JAX drops a `custom_jvp` rule when a scan's partial evaluation hoists
  the loop's known values (`lax.scan` of a rollout, under `jax.grad`), leaving the
  `custom_vmap` bare where a second derivative linearizes it: `jax.jacrev(jax.jacrev(
  rollout))` failed ("Linearization failed to produce known values") and `jax.hessian`
  recursed without end (issue 36 item 2). Plain operations differentiate in every order."""
  return _materialise(x)


@materialise.defjvp
def _materialise_jvp(primals, tangents):
  return materialise(primals[0]), tangents[0]


_FOLDS = {"sum": jnp.add, "max": jnp.maximum, "min": jnp.minimum, "any": jnp.logical_or,
          "all": jnp.logical_and}


def fold(kind: str, x: jax.Array, axes: int = 1) -> jax.Array:
  """`x` reduced over its first `axes` axes by `kind` ("sum", "max", "min", "any" or
  "all"), as a pairwise tree of elementwise operations on its slabs.

  XLA:CPU runs a reduction of bools over leading axes that keeps the minor (batch) axis
  as a strided scalar loop: measured on `[3, 4, 20, 1024]`, `jnp.any` over three axes
  took 340 us; the same fold as elementwise operations, which XLA fuses into one loop
  vectorised over the batch, 27 us. The core folds its bools this way (`any_world`,
  the link and contact flags); its float sums and maxima stay XLA reductions (as
  elementwise trees XLA fused them into their producers and recomputed them there).
  """
  rows = math.prod(x.shape[:axes])
  if rows == 0:  # Nothing to fold (an empty world): the reduction's identity.
    return getattr(jnp, kind)(x, axis=tuple(range(axes)))
  x = x.reshape((rows,) + x.shape[axes:])
  op = _FOLDS[kind]
  while x.shape[0] > 1:  # Halve: log2(rows) elementwise operations, not one per row.
    half = x.shape[0] // 2
    folded = op(x[:half], x[half:2 * half])
    if x.shape[0] % 2:
      folded = jnp.concatenate([op(folded[:1], x[2 * half:]), folded[1:]])
    x = folded
  return x[0]


def any_world(x: jax.Array) -> jax.Array:
  """`[..., B]` bool -> `[B]`: any over every axis but the last (`fold`)."""
  return fold("any", x, x.ndim - 1) if x.ndim > 1 else x


@custom_vmap
def _batch_any(x: jax.Array) -> jax.Array:
  return jnp.any(x)


@_batch_any.def_vmap
def _batch_any_rule(axis_size, in_batched, x):
  del axis_size, in_batched
  return _batch_any(x), False  # Over the vmapped worlds too: a predicate, unbatched.


def batch_any(x: jax.Array) -> jax.Array:
  """Whether any element of `x` (bool) is set, in this batch and in every batch a
  `jax.vmap` runs beside it: a `[]` bool that is never batched.

  The predicate of each of the core's `lax.cond`s, which skip work no world of the
  batch needs (the seam rule, a link table's second slot, friction's slip rounds,
  rebuilding the neighbour table). Their other branch gives every world the same
  answer, so running it because some world under the same `vmap` needs it changes no
  value. Under a `vmap` (a user's over a single-world call, or JAX's over the tangent
  rule when differentiating one) the `cond` stays a `cond`: one on a batched predicate
  would become a `select` of both branches, and reverse mode cannot transpose the
  `stop_gradient` that `select` puts on its predicate's branches."""
  return _batch_any(lax.stop_gradient(x))


def world_sum(x: jax.Array, y: jax.Array) -> jax.Array:
  """Per-world sum of per-body terms along x and y (`[n, B]` each) -> `[B]`."""
  return jnp.sum(lax.optimization_barrier(jnp.stack([x, y], axis=1)), axis=(0, 1))


# --- jax.shard_map: loop carries that start as constants ------------------------------

# Inside `jax.shard_map` (its `check_vma`, on by default) every value has a type saying
# over which manual mesh axes it varies, and a loop's carry must start with the type it
# ends with. The core's loops start from constants (zeros, an empty neighbour table)
# and end with values computed from the worlds, which vary over the axes the batch is
# split over: `vary` casts the constants (`lax.pcast(..., to="varying")`) to the axes
# the step's inputs vary over (`manual_axes`, set by the core's entry points). Outside
# `shard_map` there are none, and both are no-ops at trace time.
_MANUAL_AXES: contextvars.ContextVar[frozenset] = contextvars.ContextVar(
    "jaxchain_manual_axes", default=frozenset())


def _varying(tree) -> frozenset:
  """The manual mesh axes the arrays of `tree` vary over (their types say)."""
  axes = set()
  for leaf in jax.tree.leaves(tree):
    if not isinstance(leaf, jax.Array):
      continue
    aval = jax.typeof(leaf)
    manual = getattr(aval, "manual_axis_type", None)
    found = getattr(manual, "varying", None) if manual is not None else getattr(aval, "vma", None)
    axes.update(found or ())
  return frozenset(axes)


@contextlib.contextmanager
def manual_axes(*trees):
  """Within it, `vary` casts to the manual axes the arrays of `trees` vary over."""
  token = _MANUAL_AXES.set(_MANUAL_AXES.get() | _varying(trees))
  try:
    yield
  finally:
    _MANUAL_AXES.reset(token)


def vary(tree):
  """`tree` with every array cast to vary over the axes of `manual_axes` (a loop's
  initial carry built from constants, under `jax.shard_map`); unchanged outside it."""
  axes = _MANUAL_AXES.get()
  if not axes:
    return tree

  def cast(x):
    x = jnp.asarray(x)
    missing = tuple(sorted(axes - _varying(x)))
    return lax.pcast(x, missing, to="varying") if missing else x
  return jax.tree.map(cast, tree)
