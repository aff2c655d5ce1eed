"""Second derivatives of a rollout (issue 36 item 2), in a module of their own: compiling
`jax.hessian` and `jacrev(jacrev)` of a rollout takes about two minutes on the suite's
codegen, and pytest-xdist keeps a module on one worker (`--dist loadfile`), so here it
runs beside test_gradients.py rather than after it."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxchain as jc
from tests.test_gradients import FD_STEPS, impact_loss


@jax.jit
def second_derivatives(theta, world, horizon):
  """`jax.hessian` (forward over reverse) and `jacrev(jacrev)` of `impact_loss`, and the
  gradient at each of `theta +- FD_STEPS[1] * e_k` (central differences of the gradient)."""
  hessian = jax.hessian(impact_loss)(theta, world, horizon)
  reverse = jax.jacrev(jax.jacrev(impact_loss))(theta, world, horizon)
  shifts = FD_STEPS[1] * jnp.concatenate([jnp.eye(3), -jnp.eye(3)]).astype(theta.dtype)
  grads = jax.vmap(lambda t: jax.grad(impact_loss)(t, world, horizon))(theta[None] + shifts)
  return hessian, reverse, (grads[:3] - grads[3:]).T / (2 * FD_STEPS[1])


@pytest.mark.parametrize("horizon", [1, 3])
def test_second_derivatives_of_a_rollout_match_differences_of_its_gradient(horizon):
  # Issue 36 item 2: jax.hessian of a rollout recursed without end and jacrev(jacrev)
  # failed ("Linearization failed to produce known values"). A (speed 5) hits B in the
  # first step (gap 0.05); a third box rests on the floor apart. float64.
  with jax.enable_x64(True):
    world = jc.World.create([[0.0, 0.5], [1.05, 0.5], [3.0, 0.4], [0.0, -0.5]],
                            [[0.5, 0.5], [0.5, 0.5], [0.4, 0.4], [50.0, 0.5]],
                            [1.0, 1.0, 2.0, np.inf], friction=0.3)
    world = jax.tree.map(lambda x: x.astype(np.float64) if x.dtype.kind == "f" else x, world)
    theta = jnp.array([5.0, 0.3, 0.6])
    hessian, reverse, wanted = (np.asarray(x) for x in
                                second_derivatives(theta, world, jnp.int32(horizon)))
  assert abs(wanted[0, 2]) > 1.0  # B's mass matters: the boxes collide.
  scale = np.max(np.abs(wanted))
  for name, got in (("hessian", hessian), ("jacrev(jacrev)", reverse)):
    np.testing.assert_allclose(got, wanted, rtol=1e-3, atol=1e-6 * scale, err_msg=name)
  np.testing.assert_allclose(hessian, hessian.T, rtol=1e-9, atol=1e-12 * scale)
