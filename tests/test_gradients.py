"""Gradients: checked against finite differences away from contact switches, finite
on every stiff scene, one piece's at every tie (bounded after an impact, at rest), and
useful: gradient descent through a rollout reaches a target."""

import importlib.util
import pathlib

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import assume, example, given, settings
from hypothesis import strategies as st
from jax.test_util import check_grads

import jaxchain as jc
from jaxchain import scenes
from tests.helpers import RUN_BOUND, TOL

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


# --- One piece at every tie: bounded after an impact, equal to the differences -----------
# Issue 37 item 1: box A (mass 1) slides along a floor into box B (mass m) and both come to
# rest together. At rest every later step meets ties (a push of exactly 0), where JAX's own
# rules pass half the tangent to each side: the step's Jacobian had spectral radius 2.9
# there, and the gradient of a 60-step loss reached 1e22 (float64) or NaN (float32), reverse
# and forward mode disagreeing, while central differences were smooth. Issue 36 item 2: on
# an offset stack sliding on a floor, jvp was off by up to 5.9% where the differences agree
# to 6 digits (a body's vertical velocity perturbed at rest meets the same ties). Each tie
# now takes one piece's derivative (`core.layout.positive`, `push_max`; docs/physics.md).
#
# Both tests run one family of programs (compiled once per dtype): three movable bodies in a
# closed room, the loss a function of their inverse masses and velocities, rolled out for
# `GRAD_STEPS` steps and masked to a horizon.

GRAD_CFG = jc.Config(depth=3, links=3, broadphase="dense", one_way=False, layers=False,
                     sensors=False)
GRAD_STEPS = 120


def room_with(pos, half, mass, friction, vel):
  """Three movable bodies in a closed 14 x 9 room (floor, walls, ceiling; friction 0.5)."""
  walls_pos = [[0.0, -0.5], [-7.5, 4.0], [7.5, 4.0], [0.0, 8.5]]
  walls_half = [[8.0, 0.5], [0.5, 4.0], [0.5, 4.0], [8.0, 0.5]]
  world = jc.World.create(list(pos) + walls_pos, list(half) + walls_half,
                          list(mass) + [np.inf] * 4, friction=list(friction) + [0.5] * 4)
  return world.replace(vel=world.vel.at[:3].set(jnp.asarray(vel, world.vel.dtype)))


def parameters(world):
  """`[9]`: the inverse masses and velocities of the three movable bodies."""
  return jnp.concatenate([world.inv_mass[:3], world.vel[:3].reshape(-1)])


def rollout_loss(theta, world, horizon, weights):
  """Over the first `horizon` steps, the mean of `sum(weights[0] * (pos - pos0)**2 +
  weights[1] * vel)` (`weights`: `[2, 3, 2]`), at parameters `theta` (`parameters`)."""
  w = world.replace(inv_mass=world.inv_mass.at[:3].set(theta[:3]),
                    vel=world.vel.at[:3].set(theta[3:].reshape(3, 2)))
  _, traj = jc.rollout(w, GRAD_CFG, GRAD_STEPS)
  moved = traj.pos[:, :3] - world.pos[:3][None]
  per_step = jnp.sum(weights[0][None] * moved * moved + weights[1][None] * traj.vel[:, :3],
                     axis=(1, 2))
  kept = jnp.arange(GRAD_STEPS, dtype=jnp.int32) < horizon
  return jnp.sum(jnp.where(kept, per_step, 0.0)) / horizon.astype(theta.dtype)


@jax.jit
def loss_derivatives(*args):
  """`grad` and `jacfwd` of `rollout_loss`: one program (per dtype) for every example of
  both tests (compiled together they share the forward pass: 6 s, apart 7.8)."""
  return jax.grad(rollout_loss)(*args), jax.jacfwd(rollout_loss)(*args)

FD_BATCH = 9  # Worlds per batch of finite differences (one program).
FD_STEPS = (1e-4, 1e-5)  # Steps of the central differences (float64), times each direction.


@jax.jit
def batch_losses(thetas, world, horizon, weights):
  """`rollout_loss` at each of `thetas` (`[FD_BATCH, 9]`), as one batch of worlds."""
  k = thetas.shape[0]
  batch = jax.tree.map(lambda x: jnp.broadcast_to(x, (k,) + x.shape), world)
  batch = batch.replace(inv_mass=batch.inv_mass.at[:, :3].set(thetas[:, :3]),
                        vel=batch.vel.at[:, :3].set(thetas[:, 3:].reshape(k, 3, 2)))
  _, traj = jc.rollout(batch, GRAD_CFG, GRAD_STEPS)
  moved = traj.pos[:, :, :3] - world.pos[:3][None, None]
  per_step = jnp.sum(weights[0][None, None] * moved * moved
                     + weights[1][None, None] * traj.vel[:, :, :3], axis=(2, 3))
  kept = (jnp.arange(GRAD_STEPS, dtype=jnp.int32) < horizon)[None]
  return jnp.sum(jnp.where(kept, per_step, 0.0), axis=1) / horizon.astype(thetas.dtype)


def finite_differences(theta, directions, world, horizon, weights):
  """Central differences of `rollout_loss` along each of `directions` (`[k, 9]`, k <= 2)
  at the smaller of `FD_STEPS` (float64), whether the loss is smooth there (both one-sided
  differences and both central ones agree to 1e-4 of the largest), and that largest."""
  theta, directions = np.asarray(theta), np.asarray(directions)
  k = len(directions)
  points = [theta + s * sign * d for s in FD_STEPS for d in directions for sign in (1, -1)]
  points = np.stack(points + [theta] * (FD_BATCH - len(points)))
  values = np.asarray(batch_losses(jnp.asarray(points), world, horizon, weights))
  base, values = values[-1], values[:4 * k].reshape(2, k, 2)
  h = np.asarray(FD_STEPS)[:, None]
  central = (values[..., 0] - values[..., 1]) / (2 * h)
  right, left = (values[..., 0] - base) / h, (base - values[..., 1]) / h
  scale = np.max(np.abs(central[1])) + 1e-12
  smooth = ((np.abs(right[1] - left[1]) <= 1e-4 * scale)
            & (np.abs(central[0] - central[1]) <= 1e-4 * scale))
  return central[1], smooth, scale


def derivatives(dtype, world, horizon, weights):
  """`grad` and `jacfwd` of `rollout_loss` at the world's parameters, in `dtype`."""
  with jax.enable_x64(dtype == np.float64):
    world = jax.tree.map(lambda x: x.astype(dtype) if x.dtype.kind == "f" else x, world)
    theta, steps = parameters(world), jnp.int32(horizon)
    weights = jnp.asarray(weights, dtype)
    grad, fwd = (np.asarray(x, np.float64)
                 for x in loss_derivatives(theta, world, steps, weights))
  assert np.all(np.isfinite(grad)) and np.all(np.isfinite(fwd)), (dtype, grad, fwd)
  return grad, fwd


@settings(max_examples=3)  # Beside the two scenes: each example runs 120-step rollouts.
@given(mass_b=st.floats(1.0, 500.0), speed=st.floats(3.0, 8.0), gap=st.floats(0.5, 2.0),
       half_b=st.floats(0.3, 0.7), mu=st.floats(0.2, 0.6), horizon=st.integers(60, 120))
@example(mass_b=60.0, speed=8.0, gap=1.5, half_b=0.5, mu=0.37, horizon=60)
@example(mass_b=500.0, speed=8.0, gap=1.5, half_b=0.5, mu=0.37, horizon=60)
def test_gradients_after_an_impact_match_finite_differences(mass_b, speed, gap, half_b, mu,
                                                            horizon):
  # A hits B and both stop; a third box rests on the floor far from them.
  with jax.enable_x64(True):
    world = room_with([[-5.0, 0.5], [-4.5 + gap + half_b, half_b], [5.0, 0.4]],
                      [[0.5, 0.5], [half_b, half_b], [0.4, 0.4]], [1.0, mass_b, 2.0],
                      [mu, mu, mu], [[speed, 0.0], [0.0, 0.0], [0.0, 0.0]])
    weights = np.zeros((2, 3, 2))
    weights[0, :2] = 1.0  # Squared displacements of A and B.
    theta = np.asarray(parameters(world))
    directions = np.zeros((2, 9))
    directions[0, 1] = theta[1]  # d / d inv_mass of B (relative steps),
    directions[1, 3] = theta[3]  # d / d speed of A.
    wanted, smooth, scale = finite_differences(theta, directions, world, jnp.int32(horizon),
                                               jnp.asarray(weights))
  for dtype, tol in ((np.float64, TOL["grad_f64"]), (np.float32, TOL["grad_f32"])):
    grad, fwd = derivatives(dtype, world, horizon, weights)
    # Reverse and forward mode take the same piece everywhere, kinks included.
    np.testing.assert_allclose(grad, fwd, rtol=tol["rtol"], atol=tol["atol"] * np.max(np.abs(fwd)))
    for k in np.flatnonzero(smooth):  # Where the loss is smooth: its derivative.
      np.testing.assert_allclose(directions[k] @ grad, wanted[k], rtol=tol["rtol"],
                                 atol=tol["atol"] * scale,
                                 err_msg=f"{np.dtype(dtype).name}: along direction {k}")
    assert smooth.any() or mass_b not in (60.0, 500.0)  # The scenes are smooth.


@settings(max_examples=6)
@given(data=st.data())
@example(data=None)  # The offset stack.
def test_jvp_matches_finite_differences_on_smooth_scenes(data):
  # Offset stacks of three boxes (no aligned edges) sliding on a floor with friction: jvp
  # (forward mode) and grad along random directions of the velocities, with y components.
  if data is None:
    pos = [[0.13, 0.45], [0.41, 1.25], [-0.07, 1.9]]
    half = [[0.6, 0.45], [0.45, 0.35], [0.3, 0.3]]
    mass, mu, speeds = [1.3, 0.8, 0.5], [0.3, 0.5, 0.4], [1.2, 0.9, 1.5]
    rng = np.random.default_rng(0)
  else:
    draw = lambda lo, hi: data.draw(st.floats(lo, hi))
    half = [[draw(0.2, 0.7), draw(0.2, 0.5)] for _ in range(3)]
    x, y = [draw(-0.3, 0.3)], [half[0][1]]
    for k in (1, 2):  # Each box on the one below, offset so no two x edges align.
      x.append(x[-1] + data.draw(st.sampled_from([-1, 1])) * draw(0.05, 0.6)
               * min(half[k][0], half[k - 1][0]))
      y.append(y[-1] + half[k - 1][1] + half[k][1])
    edges = np.array([[xi - h[0], xi + h[0]] for xi, h in zip(x, half)]).ravel()
    assume(np.min(np.abs(edges[:, None] - edges[None]) + np.eye(6)) > 0.02)
    pos = np.stack([x, y], 1).tolist()
    mass = [draw(0.3, 2.0) for _ in range(3)]
    mu = [draw(0.1, 0.7) for _ in range(3)]
    speeds = [draw(-1.5, 1.5) for _ in range(3)]
    rng = np.random.default_rng(data.draw(st.integers(0, 2**16)))
  vel = [[v, 0.0] for v in speeds]
  weights = rng.normal(size=(2, 3, 2))
  direction = np.zeros(9)
  direction[3:] = rng.normal(size=6)
  with jax.enable_x64(True):
    world = room_with(pos, half, mass, mu, vel)
    horizon = jnp.int32(30)
    wanted, smooth, _ = finite_differences(parameters(world), direction[None], world, horizon,
                                           jnp.asarray(weights))
  grad, fwd = derivatives(np.float64, world, 30, weights)
  if data is None:
    assert smooth[0]
  if smooth[0]:
    tol = TOL["jvp_smooth"]
    for name, got in (("jvp", fwd @ direction), ("grad", grad @ direction)):
      np.testing.assert_allclose(got, wanted[0], rtol=tol["rtol"], atol=tol["atol"], err_msg=name)


# --- Parameters where researchers look (issue 43 item 2) ----------------------------------

def test_mass_is_first_class_and_differentiable_through_a_rollout():
  # Box 0 (mass 1, speed 2) hits box 1 (mass m) and both move on at 2 / (1 + m); a wall
  # (mass inf) stands beyond reach. The world is built by `World.create` from the traced
  # masses (`with_mass` inside): d x1 / d m equals central differences, and the wall's
  # entry of the gradient is 0, not NaN.
  cfg = jc.Config(depth=2, gravity=False, friction=False, one_way=False, layers=False,
                  sensors=False)
  pos, half, vel = [[0.0, 0.0], [1.5, 0.0], [9.0, 0.0]], [0.5, 0.5], [[2.0, 0.0], [0.0, 0.0],
                                                                    [0.0, 0.0]]

  def x1(mass):
    world = jc.World.create(pos, half, mass, vel=vel, gravity=(0.0, 0.0))
    return jc.rollout(world, cfg, 30)[0].pos[1, 0]

  m = jnp.array([1.0, 2.0, jnp.inf])
  x1_and_grad = jax.jit(jax.value_and_grad(x1))  # One program for the gradient and values.
  grad = np.asarray(x1_and_grad(m)[1])
  h = 1e-2
  xs = [float(x1_and_grad(m.at[1].add(s))[0]) for s in (h, -h)]
  assert np.all(np.isfinite(grad)) and grad[2] == 0.0
  np.testing.assert_allclose(grad[1], (xs[0] - xs[1]) / (2 * h), rtol=1e-2)
  assert grad[1] < 0  # A heavier box is pushed less far.
  w = jc.World.create(pos, half, [1.0, 2.0, np.inf])
  np.testing.assert_array_equal(w.with_mass(m).inv_mass, w.inv_mass)
  assert w.mass.tolist() == [1.0, 2.0, np.inf]
  g = jax.grad(lambda inv: jnp.sum(w.replace(inv_mass=inv).mass[:2]))(w.inv_mass)
  assert g.tolist() == [-1.0, -4.0, 0.0]  # d (1 / inv) / d inv, 0 at the wall.
  with pytest.raises(ValueError, match="masses must be > 0"):
    w.with_mass([1.0, 0.0, 1.0])



# --- Friction at rest: the piece a perturbation of one body enters (issue 43 item 0) ------
# Two boxes stacked on a floor, at rest, the top box given vx = s: the lower box's final x
# is s / 120 for |s| in 1e-5..1e-2, a linear piece through 0, but jax.grad gave 1/60 at
# s = 0 (the resting links' derivative split each body's mass over every link with a
# budget, so the floor stopped only part of the motion in the derivative).

REST_CFG = jc.Config(depth=2, links=1, broadphase="dense", one_way=False, layers=False,
                     sensors=False)
REST_STEPS = 20


def _rest_loss(s, world, weights):
  w = world.replace(vel=world.vel.at[2, 0].set(s))
  final, _ = jc.rollout(w, REST_CFG, REST_STEPS)
  return jnp.sum(weights * final.pos[1:, 0])


_rest_value_and_grad = jax.jit(jax.value_and_grad(_rest_loss))


@settings(max_examples=4)
@given(half_a=st.floats(0.3, 0.8), half_b=st.floats(0.2, 0.5), offset=st.floats(-0.5, 0.5),
       mass_a=st.floats(0.5, 3.0), mass_b=st.floats(0.5, 3.0), mu=st.floats(0.2, 0.8),
       w_b=st.floats(-1.0, 1.0))
@example(half_a=0.5, half_b=0.5, offset=0.0, mass_a=1.0, mass_b=1.0, mu=0.3, w_b=0.0)
def test_a_push_on_a_resting_stack_has_the_gradient_of_its_piece(half_a, half_b, offset, mass_a,
                                                                  mass_b, mu, w_b):
  # A box (B) on a box (A) on a floor, at rest; B gets vx = s. The loss weighs the two
  # boxes' final x. Where the loss is linear in s around 0 (one-sided differences agree),
  # grad at 0 equals the central difference (float64).
  with jax.enable_x64(True):
    x_b = offset * min(half_a, half_b)
    world = jc.World.create([[0.0, -0.5], [0.0, half_a], [x_b, 2 * half_a + half_b]],
                            [[5.0, 0.5], [half_a, half_a], [half_b, half_b]],
                            [np.inf, mass_a, mass_b], friction=mu)
    weights = jnp.array([1.0, w_b])
    value = lambda s: float(_rest_value_and_grad(jnp.float64(s), world, weights)[0])
    base, grad = _rest_value_and_grad(jnp.float64(0.0), world, weights)
    h = 1e-4
    right, left = (value(h) - float(base)) / h, (float(base) - value(-h)) / h
    central = (value(h) - value(-h)) / (2 * h)
  scale = abs(central) + 1e-12
  if (half_a, half_b, offset, mass_a, mass_b, w_b) == (0.5, 0.5, 0.0, 1.0, 1.0, 0.0):
    assert abs(right - left) <= 1e-6 * scale and abs(central - 1 / 120) < 1e-9  # The issue's.
  assume(abs(right - left) <= 1e-6 * scale)
  np.testing.assert_allclose(float(grad), central, rtol=1e-6)
