"""The world: a pytree of per-body arrays, validated on the host."""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import jax
import jax.numpy as jnp
import numpy as np

# Collision layers of `World.create`'s defaults: every body in layer 1, colliding
# with every layer.
DEFAULT_CATEGORY = 1
ALL_LAYERS = 0xFFFFFFFF


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class World:
  """State of one world (or, with a leading axis, a batch of worlds).

  Every field is a traced array: `jax.grad` and `jax.vmap` reach the physical
  ones, `pos`, `vel`, `half`, `inv_mass`, `friction` and `gravity`, which are the
  differentiable fields. Masses are stored as `inv_mass`; read them with
  `world.mass` and set them (differentiably) with `world.with_mass(m)`. `active`, `crushed` and `status` are flags (bool or int),
  never differentiated.

  Attributes:
    pos: `[n, 2]` float array, box centres.
    vel: `[n, 2]` float array, velocities.
    half: `[n, 2]` float array, half-extents, all `> 0`.
    inv_mass: `[n]` float array, `1 / mass`; `0` marks an immovable body (a wall,
      or a kinematic platform that moves only by its own velocity).
    active: `[n]` bool array; padding slots are `False` and never collide or move.
    friction: `[n]` float array, per-body Coulomb coefficient `>= 0` (a contact
      combines the two bodies' coefficients). Read only when `Config.friction`
      is on.
    gravity: `[2]` float array, this world's gravity acceleration on movable
      bodies (`[b, 2]` for a batch). Read only when `Config.gravity` is on.
    one_way: `[n]` bool array, jump-through bodies: a one-way body blocks only
      bodies that come down onto it from above (docs/toolkit.md, "One-way"). Read
      only when `Config.one_way` is on.
    sensor: `[n]` bool array, triggers: a sensor never pushes and is never pushed;
      `sensed` says whether something overlaps it. Read only when `Config.sensors`
      is on.
    category: `[n]` uint32 array, the collision layers a body is in (bits).
    mask: `[n]` uint32 array, the layers a body collides with: bodies i and j
      interact only when `category[i] & mask[j]` and `category[j] & mask[i]` are
      both nonzero. Read only when `Config.layers` is on.
    crushed: `[n]` bool array, output flag written by every step (`False` on
      creation).
    touching: `[n, 4]` bool array, output written by every step: `touching[i, d]`
      says movable body i was linked (touching within the skin, or overlapping) to
      a body lying in direction d from it (`geometry.DIRECTIONS`: +x, -x, +y, -y)
      in some pass of the step. `jc.grounded(world)` is `touching[..., 3]`.
    sensed: `[n]` bool array, output written by every step: sensor i overlapped, at
      some moment of the step (every substep, swept over its motion: `flags.sensed`),
      an active movable body its mask admits.
    status: `[]` int32, failure bits (`jaxchain.status`) ORed in by every step and
      kept until the user clears them; `jc.check(world)` explains them.
  """

  pos: jax.Array
  vel: jax.Array
  half: jax.Array
  inv_mass: jax.Array
  active: jax.Array
  friction: jax.Array
  gravity: jax.Array
  one_way: jax.Array
  sensor: jax.Array
  category: jax.Array
  mask: jax.Array
  crushed: jax.Array
  touching: jax.Array
  sensed: jax.Array
  status: jax.Array

  @property
  def num_bodies(self) -> int:
    """Capacity `n` (active and padding slots), from the static shape."""
    return self.pos.shape[-2]

  @property
  def movable(self) -> jax.Array:
    """`[n]` bool: active bodies with finite mass."""
    return self.active & (self.inv_mass > 0)

  @property
  def mass(self) -> jax.Array:
    """`[n]` masses, `inf` for immovable bodies (`inv_mass == 0`): `1 / inv_mass`,
    differentiable, with a zero (not NaN) gradient at the immovable ones."""
    return mass_from_inverse(self.inv_mass)

  def with_mass(self, mass) -> World:
    """A copy with the masses `mass` (`[n]`, `[B, n]` for a batch, or a scalar for
    all bodies), in `(0, inf]`; `inf` is immovable.

    Stored as `inv_mass = 1 / mass`, so `jax.grad` of a rollout with respect to `mass`
    works (`d inv_mass / d mass = -1 / mass**2`); an immovable body (`inf`) has
    inverse 0 and gradient 0, never NaN (the safe-`where` pattern). A concrete `mass`
    is checked like `World.create` checks it; a traced one (inside `jit`, `grad`,
    `vmap`) passes unchecked.

    Raises:
      ValueError: for a concrete mass that is NaN, `<= 0`, or of the wrong shape.

    Examples:
      >>> import jax
      >>> import jaxchain as jc
      >>> w = jc.World.create([[0.0, 0.0], [1.5, 0.0]], [0.5, 0.5], [1.0, float("inf")])
      >>> w.with_mass([2.0, float("inf")]).inv_mass.tolist(), w.mass.tolist()
      ([0.5, 0.0], [1.0, inf])
      >>> jax.grad(lambda m: w.with_mass(m).inv_mass[0])(jax.numpy.array([2.0, jax.numpy.inf]))
      Array([-0.25,  0.  ], dtype=float32)
    """
    shape, dtype = self.inv_mass.shape, self.inv_mass.dtype
    if not isinstance(mass, jax.core.Tracer):
      host = _as_float("mass", mass)
      if host.shape not in ((), shape):
        raise ValueError(f"mass: expected shape {shape} or a scalar, got {host.shape}")
      if np.any(np.isnan(host)):
        raise ValueError(f"mass: NaN mass for {_bodies('inv_mass', np.broadcast_to(np.isnan(host), shape))}")
      if np.any(host <= 0):
        raise ValueError(f"mass: masses must be > 0 (use inf for immovable); "
                         f"{_bodies('inv_mass', np.broadcast_to(host <= 0, shape))} are not")
    mass = jnp.broadcast_to(jnp.asarray(mass, dtype), shape)
    return dataclasses.replace(self, inv_mass=inverse_mass(mass))

  @classmethod
  def create(cls, pos, half, mass, vel=None, active=None, *, friction=0.0,
             gravity=(0.0, -9.81), one_way=False, sensor=False, category=DEFAULT_CATEGORY,
             mask=ALL_LAYERS) -> World:
    """Builds a world from host data, checking every field.

    Args:
      pos: `[n, 2]` centres.
      half: `[n, 2]` half-extents, or `[2]` for one size shared by all bodies.
      mass: `[n]` masses in `(0, inf]`, or a scalar; `inf` means immovable. May be
        traced (inside `jax.grad`, `jit`, `vmap`): then it is not checked and is set
        by `World.with_mass`, so a gradient reaches it; the other fields must stay
        host data.
      vel: optional `[n, 2]` velocities (default zero).
      active: optional `[n]` bool mask (default all active).
      friction: `[n]` per-body Coulomb coefficients `>= 0`, or a scalar for all
        bodies (default 0: frictionless).
      gravity: `[2]` gravity acceleration of this world (default `(0, -9.81)`).
      one_way: `[n]` bool, or one bool for all bodies: jump-through bodies.
      sensor: `[n]` bool, or one bool for all bodies: triggers.
      category: `[n]` integers in `[0, 2**32)`, or one for all: collision layer
        bits (default `1`).
      mask: `[n]` integers in `[0, 2**32)`, or one for all: the layers each body
        collides with (default all bits, `0xFFFFFFFF`).

    Returns:
      A float32 `World` (float64 if x64 is enabled), with the outputs `crushed`,
      `touching`, `sensed` all `False` and `status` 0.

    Raises:
      ValueError: naming the field and the problem (and the bodies), for NaN/inf
        positions or velocities, half-extents `<= 0`, mass `<= 0` or NaN, negative,
        NaN or inf friction, non-finite gravity, `one_way` or `sensor` that is not
        bool, `category` or `mask` that is not an integer in `[0, 2**32)`, or arrays
        of the wrong rank, shape or length; and, checked again after the cast to the stored dtype, for values
        float32 cannot hold: coordinates, velocities, friction or gravity that
        overflow to inf, half-extents that become 0 (subnormal) or inf, and finite
        masses that are subnormal or whose inverse is (a mass above about 8.5e37
        would silently become immovable).

    Examples:
      >>> import jaxchain as jc
      >>> w = jc.World.create([[0.0, 0.0], [1.5, 0.0]], [0.5, 0.5], [1.0, float("inf")],
      ...                     friction=0.3)
      >>> w.pos.shape, w.inv_mass.tolist(), w.gravity.tolist()
      ((2, 2), [1.0, 0.0], [0.0, -9.8100004196167])
    """
    if isinstance(mass, jax.core.Tracer):  # Traced masses: checked by nobody, set last.
      n = np.shape(pos)[0]
      if mass.shape not in ((), (n,)):
        raise ValueError(f"mass: expected shape ({n},) or a scalar to match pos, got {mass.shape}")
      world = cls.create(pos, half, 1.0, vel, active, friction=friction, gravity=gravity,
                         one_way=one_way, sensor=sensor, category=category, mask=mask)
      return world.with_mass(mass)
    pos = _as_float("pos", pos)
    if pos.ndim != 2 or pos.shape[1] != 2:
      raise ValueError(f"pos: expected shape (n, 2), got {pos.shape}")
    n = pos.shape[0]
    half = _as_float("half", half)
    if half.shape == (2,):
      half = np.broadcast_to(half, (n, 2))
    if half.shape != (n, 2):
      raise ValueError(f"half: expected shape ({n}, 2) or (2,) to match pos, got {half.shape}")
    mass = _as_float("mass", mass)
    if mass.ndim == 0:
      mass = np.broadcast_to(mass, (n,))
    if mass.shape != (n,):
      raise ValueError(f"mass: expected shape ({n},) or a scalar to match pos, got {mass.shape}")
    vel = np.zeros((n, 2)) if vel is None else _as_float("vel", vel)
    if vel.shape != (n, 2):
      raise ValueError(f"vel: expected shape ({n}, 2) to match pos, got {vel.shape}")
    active = np.ones(n, bool) if active is None else np.asarray(active)
    if active.shape != (n,) or active.dtype != bool:
      raise ValueError(f"active: expected a bool array of shape ({n},), got {active.dtype} {active.shape}")
    friction = _as_float("friction", friction)
    if friction.ndim == 0:
      friction = np.broadcast_to(friction, (n,))
    if friction.shape != (n,):
      raise ValueError(
          f"friction: expected shape ({n},) or a scalar to match pos, got {friction.shape}")
    gravity = _as_float("gravity", gravity)
    if gravity.shape != (2,):
      raise ValueError(f"gravity: expected shape (2,), one acceleration per world, got {gravity.shape}")
    for name, x in (("pos", pos), ("vel", vel), ("half", half), ("friction", friction),
                    ("gravity", gravity)):
      _check_values(name, x)
    flags = {name: _per_body_bool(name, x, n) for name, x in (("one_way", one_way),
                                                             ("sensor", sensor))}
    layers = {name: _per_body_bits(name, x, n) for name, x in (("category", category),
                                                              ("mask", mask))}
    if np.any(np.isnan(mass)):
      raise ValueError(f"mass: NaN mass for bodies {_where(np.isnan(mass))}")
    if np.any(mass <= 0):
      raise ValueError(
          f"mass: masses must be > 0 (use inf for immovable); bodies {_where(mass <= 0)} are not")
    with np.errstate(divide="ignore"):
      inv_mass = np.where(np.isinf(mass), 0.0, 1.0 / mass)
    # Checked again after the cast to the stored dtype: float32 overflows at 3.4e38 and
    # XLA on CPU flushes subnormals (below 1.2e-38) to zero.
    dtype = np.dtype(jnp.asarray(0.0).dtype)
    with np.errstate(over="ignore", under="ignore"):
      cast = {name: x.astype(dtype) for name, x in (
          ("pos", pos), ("vel", vel), ("half", half), ("mass", mass), ("inv_mass", inv_mass),
          ("friction", friction), ("gravity", gravity))}
    _check_cast(cast, dtype, finite_mass=np.isfinite(mass))
    f = lambda name: jnp.asarray(cast[name])
    return cls(pos=f("pos"), vel=f("vel"), half=f("half"), inv_mass=f("inv_mass"),
               active=jnp.asarray(active), friction=f("friction"), gravity=f("gravity"),
               **{k: jnp.asarray(v) for k, v in {**flags, **layers}.items()},
               crushed=jnp.zeros(n, bool), touching=jnp.zeros((n, 4), bool),
               sensed=jnp.zeros(n, bool), status=jnp.zeros((), jnp.int32))

  @classmethod
  def from_arrays(cls, pos, half, mass, vel=None, active=None, *, friction=0.0,
                  gravity=(0.0, -9.81), one_way=False, sensor=False,
                  category=DEFAULT_CATEGORY, mask=ALL_LAYERS) -> World:
    """Builds a world with `jnp` operations only: it runs under `jit` and `vmap`.

    The same arguments and broadcasting as `World.create` (scalars and `[2]`
    half-extents for all bodies), but nothing is checked on the host: this is the
    constructor for traced code, such as an environment's `reset` that randomises a
    level inside a compiled step. Give it values `World.create` would accept; a NaN
    or a negative mass here is not reported until a step sets `status.NON_FINITE`
    (or never, for a wrong mass). Floats take JAX's default dtype.

    Args:
      pos: `[n, 2]` centres (`n` static).
      half: `[n, 2]` or `[2]` half-extents.
      mass: `[n]` or scalar masses in `(0, inf]`; `inf` is immovable.
      vel, active, friction, gravity, one_way, sensor, category, mask: as in
        `World.create`.

    Examples:
      >>> import jax, jax.numpy as jnp
      >>> import jaxchain as jc
      >>> def reset(key):  # A random drop height, built inside jit.
      ...   y = jax.random.uniform(key, (), minval=1.0, maxval=2.0)
      ...   return jc.World.from_arrays(jnp.array([[0.0, 0.0], [0.0, 0.0]]).at[1, 1].set(y),
      ...                               [0.5, 0.5], jnp.array([jnp.inf, 1.0]))
      >>> w = jax.jit(reset)(jax.random.key(0))
      >>> w.inv_mass.tolist(), bool(w.pos[1, 1] >= 1.0)
      ([0.0, 1.0], True)
    """
    dtype = jnp.asarray(0.0).dtype
    pos = jnp.asarray(pos, dtype)
    n = pos.shape[0]
    per_body = lambda x, d, shape=(n,): jnp.broadcast_to(jnp.asarray(x, d), shape)
    inv_mass = inverse_mass(per_body(mass, dtype))
    return cls(pos=pos, vel=per_body(0.0 if vel is None else vel, dtype, (n, 2)),
               half=per_body(half, dtype, (n, 2)), inv_mass=inv_mass,
               active=per_body(True if active is None else active, bool),
               friction=per_body(friction, dtype), gravity=jnp.asarray(gravity, dtype),
               one_way=per_body(one_way, bool), sensor=per_body(sensor, bool),
               category=per_body(category, jnp.uint32), mask=per_body(mask, jnp.uint32),
               crushed=jnp.zeros(n, bool), touching=jnp.zeros((n, 4), bool),
               sensed=jnp.zeros(n, bool), status=jnp.zeros((), jnp.int32))

  def replace(self, **changes) -> World:
    """A copy with some fields changed, checked when the new values are concrete.

    A concrete value (a NumPy or JAX array, a Python number or list) must have the
    dtype and shape of the field it replaces (Python numbers and lists, which carry
    no dtype, are converted to the field's dtype; an int or float `active` is an
    error, not a mask), and it is checked like `World.create` checks its input: no
    NaN or inf in `pos`, `vel` or `gravity`, `half > 0` and finite, `inv_mass` and
    `friction` finite and `>= 0`. Traced values (inside `jit`, `vmap` or `grad`) are
    passed through unchecked, so `replace` works in traced code. Masses are set
    with `with_mass` (the field is `inv_mass`).

    Raises:
      ValueError: naming the field (and the bodies) for a bad concrete value.
      TypeError: for a name that is not a field.

    Examples:
      >>> import jax.numpy as jnp
      >>> import jaxchain as jc
      >>> w = jc.World.create([[0.0, 0.0], [1.5, 0.0]], [0.5, 0.5], 1.0)
      >>> w.replace(friction=jnp.full(2, 0.3)).friction.tolist()
      [0.30000001192092896, 0.30000001192092896]
      >>> w.replace(active=jnp.array([1, 0]))
      Traceback (most recent call last):
      ...
      ValueError: active: expected bool of shape (2,) like the field it replaces, got int32 (2,); ...
    """
    fields = {f.name for f in dataclasses.fields(self)}
    checked = {}
    for name, value in changes.items():
      if name not in fields:
        hint = "; set masses with world.with_mass(m)" if name == "mass" else ""
        raise TypeError(f"replace: World has no field {name!r} (fields: "
                        f"{', '.join(sorted(fields))}){hint}")
      checked[name] = value if isinstance(value, jax.core.Tracer) else _checked(
          name, value, getattr(self, name))
    return dataclasses.replace(self, **checked)

  def pad(self, capacity: int) -> World:
    """Pads a single world with inactive slots up to `capacity` bodies.

    Padding slots are immovable, inactive unit boxes at the origin: they never
    collide and never move.
    """
    n = self.num_bodies
    if self.pos.ndim != 2:
      raise ValueError(f"pad: expected a single world (pos of rank 2), got pos {self.pos.shape}")
    if capacity < n:
      raise ValueError(f"pad: capacity {capacity} is smaller than the {n} bodies in the world")
    extra = capacity - n
    cat = lambda x, fill: jnp.concatenate([x, jnp.full((extra,) + x.shape[1:], fill, x.dtype)])
    return World(**{f: cat(getattr(self, f), fill) for f, fill in _PAD_FILL.items()},
                 gravity=self.gravity, status=self.status)


def inverse_mass(mass: jax.Array) -> jax.Array:
  """`1 / mass`, 0 where `mass` is `inf`, gradient-safe: the gradient there is 0, not
  NaN (the divide never sees `inf`)."""
  inf = jnp.isinf(mass)
  return jnp.where(inf, 0.0, 1.0 / jnp.where(inf, 1.0, mass)).astype(mass.dtype)


def mass_from_inverse(inv_mass: jax.Array) -> jax.Array:
  """`1 / inv_mass`, `inf` where `inv_mass` is 0, with a zero gradient there."""
  fixed = inv_mass == 0
  return jnp.where(fixed, jnp.inf, 1.0 / jnp.where(fixed, 1.0, inv_mass)).astype(inv_mass.dtype)


def stack(worlds: Sequence[World], capacity: int | None = None) -> World:
  """Batches worlds of different body counts into one padded batch.

  Args:
    worlds: single worlds (rank-2 `pos`).
    capacity: bodies per world after padding; default the largest world.

  Returns:
    A `World` whose arrays have a leading batch axis `[len(worlds), capacity, ...]`,
    with `active` marking the real bodies. Use it with `jax.vmap`.

  Examples:
    >>> import jaxchain as jc
    >>> a = jc.World.create([[0.0, 0.0]], [0.5, 0.5], 1.0)
    >>> b = jc.World.create([[0.0, 0.0], [2.0, 0.0]], [0.5, 0.5], 1.0)
    >>> jc.stack([a, b]).active.tolist()
    [[True, False], [True, True]]
  """
  if not worlds:
    raise ValueError("stack: need at least one world")
  for k, w in enumerate(worlds):
    if w.pos.ndim != 2:
      raise ValueError(f"stack: world {k} is not a single world (pos {w.pos.shape})")
  capacity = max(w.num_bodies for w in worlds) if capacity is None else capacity
  # Pad on the host and transfer once: per-world device ops cost seconds for 1000 worlds.
  host = [jax.tree.map(np.asarray, w) for w in worlds]
  out = {}
  for field, fill in _PAD_FILL.items():
    arrays = [getattr(w, field) for w in host]
    batch = np.full((len(arrays), capacity) + arrays[0].shape[1:], fill, arrays[0].dtype)
    for b, x in enumerate(arrays):
      if len(x) > capacity:
        raise ValueError(f"stack: capacity {capacity} is smaller than the {len(x)} bodies of world {b}")
      batch[b, : len(x)] = x
    out[field] = jnp.asarray(batch)
  # Per-world fields are stacked, not padded.
  gravity = np.stack([np.asarray(w.gravity) for w in host])
  status = np.stack([np.asarray(w.status, np.int32) for w in host])
  return World(**out, gravity=jnp.asarray(gravity), status=jnp.asarray(status))


# Per-body fields and their padding: immovable, inactive, frictionless unit boxes at
# the origin in the default layers, never crushed, touching or sensing. (`gravity`
# and `status` are per world.)
_PAD_FILL = dict(pos=0.0, vel=0.0, half=1.0, inv_mass=0.0, active=False, friction=0.0,
                 one_way=False, sensor=False, category=DEFAULT_CATEGORY, mask=ALL_LAYERS,
                 crushed=False, touching=False, sensed=False)


def _per_body_bool(name: str, x, n: int) -> np.ndarray:
  """A `[n]` bool array from one bool or `n` of them (NumPy or JAX bools, Python bools)."""
  a = np.asarray(x)
  if a.dtype != bool:
    raise ValueError(f"{name}: expected bools (one, or one per body), got {a.dtype} {a.shape}; "
                     f"a mask is needed (e.g. x != 0)")
  if a.ndim == 0:
    a = np.broadcast_to(a, (n,))
  if a.shape != (n,):
    raise ValueError(f"{name}: expected shape ({n},) or a scalar to match pos, got {a.shape}")
  return np.array(a)


def _per_body_bits(name: str, x, n: int) -> np.ndarray:
  """A `[n]` uint32 array of layer bits from one integer or `n` of them."""
  a = np.asarray(x)
  if a.dtype == bool or a.dtype.kind not in "iu":
    raise ValueError(f"{name}: expected integers (layer bits, one or one per body), got "
                     f"{a.dtype} {a.shape}")
  bad = (a.astype(object) < 0) | (a.astype(object) > ALL_LAYERS)
  if np.any(bad):
    which = f"got {a.item()}" if a.ndim == 0 else f"bodies {_where(bad)} are not"
    raise ValueError(f"{name}: layer bits must lie in [0, 2**32) (uint32); {which}")
  if a.ndim == 0:
    a = np.broadcast_to(a, (n,))
  if a.shape != (n,):
    raise ValueError(f"{name}: expected shape ({n},) or a scalar to match pos, got {a.shape}")
  return a.astype(np.uint32)


def _as_float(name: str, x) -> np.ndarray:
  try:
    return np.asarray(x, dtype=np.float64)
  except (TypeError, ValueError) as e:
    raise ValueError(f"{name}: cannot convert to a float array ({e})") from None


# Fields with one entry per body; `*_VEC` ones are `[..., n, 2]`, the rest `[..., n]`.
# `gravity` (`[..., 2]`) and `status` (`[...]`) are per world.
_PER_BODY_VEC = ("pos", "vel", "half")
_PER_BODY = ("inv_mass", "active", "friction", "one_way", "sensor", "category", "mask",
             "crushed", "sensed")


def _bodies(name: str, bad: np.ndarray) -> str:
  """Which bodies (or, for a batch, which (world, body) pairs) a bad mask marks."""
  if name in _PER_BODY_VEC:
    bad = bad.any(-1)
  elif name not in _PER_BODY:  # Per world.
    bad = bad.any(-1) if name == "gravity" else bad
    return f"worlds {_where(np.atleast_1d(bad))}" if bad.ndim >= 1 else "the world"
  if bad.ndim == 1:
    return f"bodies {_where(bad)}"
  idx = np.argwhere(bad)
  pairs = [tuple(int(k) for k in i) for i in idx[:10]] + (["..."] if len(idx) > 10 else [])
  return f"(world, body) {pairs}"


def _check_values(name: str, x: np.ndarray) -> None:
  """The value rules of one float field (any leading batch axes), on the host."""
  if name in ("pos", "vel", "half"):
    bad = ~np.isfinite(x)
    if bad.any():
      raise ValueError(f"{name}: NaN or inf for {_bodies(name, bad)}")
    if name == "half" and np.any(x <= 0):
      raise ValueError(f"half: half-extents must be > 0; {_bodies(name, x <= 0)} are not")
  elif name == "inv_mass":
    bad = ~(np.isfinite(x) & (x >= 0))
    if bad.any():
      raise ValueError(f"inv_mass: inverse masses must be finite and >= 0 (0 = immovable); "
                       f"{_bodies(name, bad)} are not")
  elif name == "friction":
    if np.any(np.isnan(x)):
      raise ValueError(f"friction: NaN friction for {_bodies(name, np.isnan(x))}")
    bad = ~(np.isfinite(x) & (x >= 0))
    if bad.any():
      raise ValueError(
          f"friction: coefficients must be finite and >= 0; {_bodies(name, bad)} are not")
  elif name == "gravity":
    if not np.all(np.isfinite(x)):
      got = f", got {x.tolist()}" if x.ndim == 1 else ""
      raise ValueError(f"gravity: expected finite numbers{got}; NaN or inf for "
                       f"{_bodies(name, ~np.isfinite(x))}")


def _check_cast(cast: dict[str, np.ndarray], dtype: np.dtype, finite_mass: np.ndarray) -> None:
  """What `World.create` checks after casting its (valid, float64) input to `dtype`;
  `finite_mass` marks the bodies whose input mass is finite (not immovable)."""
  info = np.finfo(dtype)
  hint = "enable x64 (JAX_ENABLE_X64=1) or rescale" if dtype != np.float64 else "rescale"
  for name in ("pos", "vel", "friction", "gravity"):
    bad = ~np.isfinite(cast[name])
    if bad.any():
      raise ValueError(f"{name}: too large for {dtype.name} (overflows to inf, above "
                       f"{info.max:.3g}) for {_bodies(name, bad)}; {hint}")
  half = cast["half"]
  bad = ~(np.isfinite(half) & (half >= info.tiny))
  if bad.any():
    raise ValueError(
        f"half: half-extents of {_bodies('half', bad)} become 0 or inf in {dtype.name} (they must "
        f"lie between {info.tiny:.3g} and {info.max:.3g}); {hint}")
  mass, inv = cast["mass"], cast["inv_mass"]
  finite = finite_mass  # inf is immovable, inverse 0 by design.
  small = finite & ~(mass >= info.tiny)
  if small.any():
    raise ValueError(
        f"mass: masses of {_bodies('inv_mass', small)} are below the smallest normal "
        f"{dtype.name} ({info.tiny:.3g}) and flush to 0 on the device (mass must be at least "
        f"{info.tiny:.3g}); {hint}")
  big = finite & ~(np.isfinite(mass) & np.isfinite(inv) & (inv >= info.tiny))
  if big.any():
    raise ValueError(
        f"mass: masses of {_bodies('inv_mass', big)} are so large that 1/mass flushes to 0 in "
        f"{dtype.name} (mass must be at most {1 / info.tiny:.3g}), which would make them "
        f"immovable; use inf for an immovable body, or {hint}")


def _checked(name: str, value, old):
  """`value`, checked against the field `old` it replaces (see `World.replace`)."""
  old_dtype, old_shape = np.dtype(old.dtype), tuple(old.shape)
  if hasattr(value, "dtype") and hasattr(value, "shape"):  # NumPy or JAX array, NumPy scalar.
    host = np.asarray(value)
  else:  # Python numbers and lists carry no dtype: take the field's.
    try:
      host = np.asarray(value)
    except (TypeError, ValueError) as e:
      raise ValueError(f"{name}: cannot convert to an array ({e})") from None
    kind_ok = {"b": "b", "f": "fiu", "i": "iu", "u": "iu"}.get(old_dtype.kind, old_dtype.kind)
    if old_dtype.kind == "u" and host.dtype.kind in "iu":
      host = _per_body_bits(name, host, host.shape[-1] if host.ndim else 1).reshape(host.shape)
    if host.dtype.kind in kind_ok:
      with np.errstate(over="ignore"):
        host = host.astype(old_dtype)
      value = jnp.asarray(host)
  if host.dtype != old_dtype or host.shape != old_shape:
    hint = ("a bool mask is needed (e.g. x != 0)" if old_dtype == bool else
            f"convert with jnp.asarray(x, world.{name}.dtype) and match the shape")
    raise ValueError(f"{name}: expected {old_dtype.name} of shape {old_shape} like the field it "
                     f"replaces, got {host.dtype.name} {host.shape}; {hint}")
  if old_dtype.kind == "f":
    _check_values(name, host)
  return value


def _where(mask: np.ndarray) -> list[int]:
  idx = np.flatnonzero(mask.reshape(mask.shape[0], -1).any(1) if mask.ndim > 1 else mask)
  return idx[:10].tolist() + (["..."] if len(idx) > 10 else [])
