"""jaxchain.gather.take: the same values as plain indexing under every transformation."""

import jax
import jax.extend
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


def _primitives(jaxpr) -> list[str]:
  """Every primitive of `jaxpr` and of the jaxprs inside it."""
  out = []
  for eqn in jaxpr.eqns:
    subs = [v for v in eqn.params.values() if isinstance(v, (jax.extend.core.ClosedJaxpr,
                                                              jax.extend.core.Jaxpr))]
    for sub in subs:
      out += _primitives(getattr(sub, "jaxpr", sub))
    if not subs:
      out.append(eqn.primitive.name)
  return out


@pytest.mark.parametrize("nested", [False, True])
def test_batched_take_is_one_gather_without_index_fixups(nested):
  """Under vmap `take` is one flat gather plus the per-world offsets: no clamping or
  wrapping of the indices (in range by contract), which would add elementwise work to
  every hop's gather and to the compiled program (`benchmarks/compile_time.py`)."""
  fn = jax.vmap(jax.vmap(take)) if nested else jax.vmap(take)
  args = (TABLE, IDX) if nested else (TABLE[0], IDX[0])
  prims = _primitives(jax.make_jaxpr(fn)(*args).jaxpr)
  assert prims.count("gather") == 1, prims
  assert not {"select_n", "lt", "clamp", "min", "max", "rem"} & set(prims), prims
  assert set(prims) <= {"gather", "iota", "mul", "add", "reshape", "broadcast_in_dim"}, prims
