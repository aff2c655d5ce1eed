"""Second derivatives of a rollout (issue 36 item 2), in a module of their own: tracing and
compiling `jax.hessian`, `jacrev(jacrev)` and a batch of `jax.grad` of a rollout is the
largest program of the suite (about a minute on the suite's codegen), and pytest-xdist
keeps a module on one worker (`--dist loadfile`), so here it runs beside
test_gradients.py rather than after it."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxchain as jc
from tests.test_gradients import FD_STEPS, GRAD_CFG

HESSIAN_STEPS = 3
# One link per body and direction: in this scene no body has two links in one direction,
# so the answers (and their derivatives) are those of GRAD_CFG's three, bit for bit, and
# the program holds one copy of the resolver, not the copy for wider link tables too
# (measured on this test's program: trace 58 s and compile 101 s with links=3; 33 s and
# 42 s with links=1). The closing stage and friction's slip rounds, with their
# `lax.cond`s, stay in the program.
HESSIAN_CFG = GRAD_CFG.replace(links=1)


def impact_loss(theta, world, horizon):
  """Over the first `horizon` (<= 3) steps, `sum(pos**2) + 0.1 * sum(vel**3)` of the two
  boxes that collide in the first step; `theta`: A's velocity, B's inverse mass."""
  w = world.replace(vel=world.vel.at[0].set(theta[:2]),
                    inv_mass=world.inv_mass.at[1].set(theta[2]))
  _, traj = jc.rollout(w, HESSIAN_CFG, HESSIAN_STEPS)
  per_step = (jnp.sum(traj.pos[:, :2] ** 2, axis=(1, 2))
              + 0.1 * jnp.sum(traj.vel[:, :2] ** 3, axis=(1, 2)))
  return jnp.sum(jnp.where(jnp.arange(HESSIAN_STEPS, dtype=jnp.int32) < horizon, per_step, 0.0))


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
    # No second link in any direction here: HESSIAN_CFG's answers are GRAD_CFG's.
    same = [np.asarray(jc.rollout(world, cfg, HESSIAN_STEPS)[1].pos)
            for cfg in (GRAD_CFG, HESSIAN_CFG)]
  np.testing.assert_array_equal(*same)
  assert abs(wanted[0, 2]) > 1.0  # B's mass matters: the boxes collide.
  scale = np.max(np.abs(wanted))
  for name, got in (("hessian", hessian), ("jacrev(jacrev)", reverse)):
    np.testing.assert_allclose(got, wanted, rtol=1e-3, atol=1e-6 * scale, err_msg=name)
  np.testing.assert_allclose(hessian, hessian.T, rtol=1e-9, atol=1e-12 * scale)
