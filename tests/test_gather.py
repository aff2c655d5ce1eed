"""jaxchain.gather.take: the same values as plain indexing under every transformation."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxchain.gather import take

RNG = np.random.default_rng(0)
TABLE = jnp.asarray(RNG.random((3, 5, 10)), jnp.float32)
IDX = jnp.asarray(RNG.integers(0, 10, (3, 5, 4, 2)), jnp.int32)


def plain(t, i):
  return t[i]


def test_one_table():
  np.testing.assert_array_equal(take(TABLE[0, 0], IDX[0, 0]), TABLE[0, 0][IDX[0, 0]])


@pytest.mark.parametrize("jit", [False, True])
def test_nested_vmap_matches_plain_indexing(jit):
  fn = jax.vmap(jax.vmap(take))
  fn = jax.jit(fn) if jit else fn
  np.testing.assert_array_equal(fn(TABLE, IDX), jax.vmap(jax.vmap(plain))(TABLE, IDX))


def test_batched_table_shared_index_and_shared_table_batched_index():
  i = IDX[0, 0]
  np.testing.assert_array_equal(jax.vmap(lambda t: take(t, i))(TABLE[0]), TABLE[0][:, i])
  t = TABLE[0, 0]
  np.testing.assert_array_equal(jax.vmap(lambda i: take(t, i))(IDX[0]), t[IDX[0]])


def test_integer_and_bool_tables():
  t = jnp.arange(10, dtype=jnp.int32) * 3
  np.testing.assert_array_equal(jax.vmap(lambda i: take(t, i))(IDX[0]), t[IDX[0]])
  b = jnp.asarray(RNG.random((5, 10)) < 0.5)
  np.testing.assert_array_equal(jax.vmap(take)(b, IDX[0, :, :, 0]), jax.vmap(plain)(b, IDX[0, :, :, 0]))


def test_gradients_in_both_modes_and_under_vmap():
  i = IDX[0, 0]

  def loss(fn):
    return lambda t: jnp.sum(jnp.sin(fn(t, i)) * jnp.arange(i.size, dtype=t.dtype).reshape(i.shape))

  t = TABLE[0, 0]
  want = jax.grad(loss(plain))(t)
  np.testing.assert_allclose(jax.grad(loss(take))(t), want, rtol=1e-6)
  np.testing.assert_allclose(jax.jacfwd(loss(take))(t), want, rtol=1e-6)
  batched = jax.vmap(jax.grad(lambda t, i: jnp.sum(jnp.sin(take(t, i)))))(TABLE[0], IDX[0])
  batched_want = jax.vmap(jax.grad(lambda t, i: jnp.sum(jnp.sin(t[i]))))(TABLE[0], IDX[0])
  np.testing.assert_allclose(batched, batched_want, rtol=1e-6)
  outer = jax.grad(lambda t: jnp.sum(jax.vmap(take)(t, IDX[0]) ** 2))(TABLE[0])
  outer_want = jax.grad(lambda t: jnp.sum(jax.vmap(plain)(t, IDX[0]) ** 2))(TABLE[0])
  np.testing.assert_allclose(outer, outer_want, rtol=1e-6)


def test_rejects_a_table_that_is_not_1d():
  with pytest.raises(ValueError, match="1-D table"):
    take(TABLE[0], IDX[0, 0])
