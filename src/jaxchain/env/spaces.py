"""Action and observation spaces (gymnax's `Discrete` and `Box`)."""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np


@dataclasses.dataclass(frozen=True)
class Discrete:
  """The integers `0 .. n - 1`, as int32 scalars.

  Examples:
    >>> import jax
    >>> from jaxchain import env
    >>> space = env.Discrete(6)
    >>> a = space.sample(jax.random.key(0))
    >>> a.shape, a.dtype, bool(space.contains(a)), bool(space.contains(6))
    ((), dtype('int32'), True, False)
  """

  n: int
  shape: tuple[int, ...] = ()
  dtype: np.dtype = np.dtype(np.int32)

  def sample(self, key: jax.Array) -> jax.Array:
    """A uniformly random element (jittable)."""
    return jax.random.randint(key, self.shape, 0, self.n, dtype=self.dtype)

  def contains(self, x) -> jax.Array:
    """Whether `x` is an integer of this shape in `[0, n)` (a bool array; jittable)."""
    x = jnp.asarray(x)
    if x.shape != self.shape or not jnp.issubdtype(x.dtype, jnp.integer):
      return jnp.asarray(False)
    return jnp.all((x >= 0) & (x < self.n))


@dataclasses.dataclass(frozen=True)
class Box:
  """Arrays of one shape with every entry in `[low, high]` (bounds may be inf).

  A float `dtype` (the default, float32) holds real vectors; an integer one
  (`uint8` for pixel observations) holds integers.

  Examples:
    >>> import jax
    >>> from jaxchain import env
    >>> space = env.Box(-1.0, 1.0, (2,))
    >>> a = space.sample(jax.random.key(0))
    >>> a.shape, a.dtype, bool(space.contains(a)), bool(space.contains(a * 3.0))
    ((2,), dtype('float32'), True, False)
  """

  low: float
  high: float
  shape: tuple[int, ...]
  dtype: np.dtype = np.dtype(np.float32)

  @property
  def _integer(self) -> bool:
    return bool(np.issubdtype(np.dtype(self.dtype), np.integer))

  def sample(self, key: jax.Array) -> jax.Array:
    """A random element (jittable): uniform when both bounds are finite, else a
    standard normal draw clipped to the bounds."""
    if self._integer:
      return jax.random.randint(key, self.shape, int(self.low), int(self.high) + 1,
                                dtype=jnp.int32).astype(self.dtype)
    if math.isfinite(self.low) and math.isfinite(self.high):
      return jax.random.uniform(key, self.shape, self.dtype, self.low, self.high)
    return jnp.clip(jax.random.normal(key, self.shape, self.dtype), self.low, self.high)

  def contains(self, x) -> jax.Array:
    """Whether `x` is an array of this shape and kind (float, or integer for an
    integer space) inside the bounds (no NaN); a bool array, jittable."""
    x = jnp.asarray(x)
    kind = jnp.integer if self._integer else jnp.floating
    if x.shape != self.shape or not jnp.issubdtype(x.dtype, kind):
      return jnp.asarray(False)
    return jnp.all((x >= self.low) & (x <= self.high))
