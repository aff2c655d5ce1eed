"""Gradients: checked against finite differences away from contact switches, finite
on every stiff scene, and useful: gradient descent through a rollout reaches a target."""

import importlib.util
import pathlib

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.test_util import check_grads

import jaxchain as jc
from jaxchain import scenes
from tests.helpers import RUN_BOUND

ROOT = pathlib.Path(__file__).resolve().parents[1]


def test_resolve_matches_finite_differences_on_a_chain():
  # Overlaps of 0.1 to 0.3 at every link: small perturbations switch no contact.
  scene = scenes.push_chain(4, overlap=0.3, wall=False, masses=[1.0, 2.0, 0.5, 1.0, 3.0],
                            overlaps=[0.1, 0.2, 0.15])
  world = scene.world()
  cfg = jc.Config(depth=4, gravity=False)

  def f(pos, half):
    return jc.resolve(world.replace(pos=pos, half=half), cfg).pos

  check_grads(f, (world.pos, world.half), order=1, modes=["rev", "fwd"], eps=1e-2,
              atol=2e-2, rtol=2e-2)


def test_rollout_matches_finite_differences():
  # Player shoves a box that slides and stops on a floor with friction.
  world = jc.World.create([[0.0, 0.5], [1.5, 0.5], [0.0, -0.5]],
                          [[0.5, 0.5], [0.5, 0.5], [50.0, 0.5]], [1.0, 1.0, np.inf],
                          friction=0.3)
  cfg = jc.Config(friction=True)

  def f(speed, box_x):
    w = world.replace(vel=world.vel.at[0, 0].set(speed), pos=world.pos.at[1, 0].set(box_x))
    return jc.rollout(w, cfg, 60)[0].pos[:2, 0]

  check_grads(f, (jnp.float32(5.0), jnp.float32(1.5)), order=1, modes=["rev"], eps=1e-2,
              atol=5e-2, rtol=5e-2)


STIFF = {
    "mass_1e6": scenes.stack(6, overlaps=0.02, masses=[1.0, 1e6, 1.0, 1e6, 1.0, 1e6]),
    "mass_1e-6": scenes.push_chain(5, overlap=0.2, masses=[1.0, 1e-6, 1.0, 1e-6, 1.0, 1e-6]),
    "tall_stack": scenes.stack(40, overlaps=0.01),
    "coincident": scenes.Scene(np.array([[1.0, 1.0]] * 3 + [[1.0, -0.5]]),
                               np.array([[0.5, 0.5]] * 3 + [[5.0, 0.5]]),
                               np.array([1.0, 2.0, 3.0, np.inf])),
    "touching": scenes.Scene(np.array([[0.0, -0.5], [0.0, 0.5], [1.0, 0.5], [0.5, 1.5]]),
                             np.array([[5.0, 0.5]] + [[0.5, 0.5]] * 3),
                             np.array([np.inf, 1.0, 1.0, 1.0])),
    "far_tiny": scenes.Scene(np.array([[1e4, 1e4 - 0.5], [1e4, 1e4 + 1e-3]]),
                             np.array([[1.0, 0.5], [1e-3, 1e-3]]), np.array([np.inf, 1.0])),
    "room": scenes.box_room(np.random.default_rng(0), 24),
}


@pytest.fixture(scope="module")
def stiff_grads():
  """Gradients of a 20-step rollout loss for every stiff scene, padded to one size and
  run as one batch with one config (`for_world` of the batch): one compile for all."""
  names = sorted(STIFF)
  batch = jc.stack([STIFF[k].world(friction=0.3) for k in names])
  cfg = jc.Config.for_world(batch)

  def loss(world, pos, vel):
    final, traj = jc.rollout(world.replace(pos=pos, vel=vel), cfg, 20)
    return jnp.sum(traj.pos[:, :, 1]) + jnp.sum(final.vel**2)

  grads = jax.jit(jax.vmap(jax.grad(loss, argnums=(1, 2))), compiler_options=RUN_BOUND)(
      batch, batch.pos, batch.vel)
  return {k: [np.asarray(g[b]) for g in grads] for b, k in enumerate(names)}


@pytest.mark.parametrize("name", sorted(STIFF))
def test_grad_through_rollout_is_finite_on_stiff_scenes(name, stiff_grads):
  for g in stiff_grads[name]:
    assert np.all(np.isfinite(g)), name
    assert np.any(g != 0), name  # A loss of positions and speeds depends on them.


def test_example_gradient_descent_reaches_the_target():
  spec = importlib.util.spec_from_file_location("push_to_target", ROOT / "examples" / "push_to_target.py")
  example = importlib.util.module_from_spec(spec)
  spec.loader.exec_module(example)
  speed, stop = example.optimise(target=4.0, iterations=25)
  assert abs(stop - 4.0) < 1e-2
  assert speed > 3.0  # It had to speed up from the initial guess.
