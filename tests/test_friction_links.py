"""Friction acts per link: bodies move as one only through links whose own Coulomb
budget holds the shear that moving as one needs (`velocity.friction`, `_holding`;
mirrored in `reference._friction`). Scenes from issue 18, item 2."""

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxchain as jc
from jaxchain import reference

INF = float("inf")
DT = 1 / 60
G = 9.81
SLOPE = np.deg2rad(20.0)
TILTED = (-G * np.sin(SLOPE), -G * np.cos(SLOPE))  # Gravity of a 20-degree slope.


def stack(mu_top: float, *, vel=(0.0, 0.0), gravity=(0.0, -G), floor_mu: float = 1.0):
  """A floor, a wide box (mass 1, friction 1) on it and a small box (mass 2) on that."""
  return jc.World.create(pos=[[0.0, -0.5], [0.0, 0.5], [0.0, 1.5]],
                         half=[[50.0, 0.5], [5.0, 0.5], [0.5, 0.5]], mass=[INF, 1.0, 2.0],
                         friction=[floor_mu, 1.0, mu_top], vel=[[0.0, 0.0], list(vel), list(vel)],
                         gravity=gravity)


@functools.lru_cache(maxsize=None)
def _rollout(steps: int):
  cfg = jc.Config.for_world(stack(0.5), substeps=1)
  return jax.jit(lambda w: jc.rollout(w, cfg, steps))


def free_speed(accel: float, v0: float, steps: int) -> float:
  v, a = np.float32(v0), np.float32(accel)
  for _ in range(steps):
    v = np.float32(v + a * np.float32(DT))
  return float(v)


def test_a_frictionless_box_slides_down_a_box_held_on_a_slope():
  # f55f53b: the top box stuck to the bottom one (one friction unit) and the floor's
  # static friction held both. Coulomb: it slides at g sin 20 (3.36 u/s after 1 s).
  final, traj = _rollout(60)(stack(0.0, gravity=TILTED))
  assert float(final.vel[2, 0]) == pytest.approx(free_speed(TILTED[0], 0.0, 60), rel=1e-6)
  assert float(final.vel[2, 0]) == pytest.approx(-3.355, abs=1e-3)
  np.testing.assert_array_equal(traj.vel[:, 1], 0.0)  # The bottom box is held.
  assert int(final.status) == 0


def test_a_rough_box_stays_on_a_box_held_on_a_slope():
  # Held by static friction: no velocity. (Positions creep by g sin 20 dt^2 a step, the
  # same for both: semi-implicit Euler moves them before friction stops them.)
  final, traj = _rollout(60)(stack(1.0, gravity=TILTED))
  np.testing.assert_array_equal(traj.vel[:, 1:], 0.0)
  np.testing.assert_array_equal(final.pos[1, 0], final.pos[2, 0])


def test_a_frictionless_box_on_a_sliding_stack_keeps_sliding():
  # f55f53b: it stopped with the stack. Coulomb: it keeps its 5 u/s.
  final, traj = _rollout(30)(stack(0.0, vel=(5.0, 0.0), floor_mu=0.5))
  np.testing.assert_array_equal(traj.vel[:, 2, 0], 5.0)
  assert float(final.vel[1, 0]) == 0.0  # The bottom box stopped on the floor.


def test_a_rough_box_on_a_sliding_stack_stops_with_it():
  # The top link's budget (mu_pair(1, 1) g = g) holds the floor's deceleration
  # (mu_pair(0.5, 1) g = min(0.5, 1) g; sqrt(0.5) g under issue 18's geometric mean): the
  # two slow down as one, at Coulomb's rate.
  final, traj = _rollout(30)(stack(1.0, vel=(5.0, 0.0), floor_mu=0.5))
  np.testing.assert_array_equal(traj.vel[:, 1, 0], traj.vel[:, 2, 0])
  mu_floor = min(0.5, 1.0)
  assert float(final.vel[1, 0]) == pytest.approx(5.0 - 0.5 * mu_floor * G, rel=1e-5)


def _top_travel(mu):
  """How far the top box of a sliding stack travels in 30 steps, its coefficient `mu`."""
  world = stack(0.0, vel=(5.0, 0.0), floor_mu=0.5)
  world = world.replace(friction=world.friction.at[2].set(mu))
  return _rollout(30)(world)[0].pos[2, 0]


def test_travel_depends_on_the_top_links_coefficient():
  # f55f53b: d(travel)/d(mu_top) = 0 (the link's budget was never applied).
  grad = float(jax.grad(_top_travel)(0.05))
  eps = 1e-3
  fd = (float(_top_travel(0.05 + eps)) - float(_top_travel(0.05 - eps))) / (2 * eps)
  assert grad < 0
  assert grad == pytest.approx(fd, rel=0.05)


def test_travel_has_a_finite_derivative_in_a_coefficient_at_zero():
  # Issue 43 item 2: with the pair coefficient sqrt(mu_i mu_j), d travel / d mu_top was 0 at
  # mu_top = 0 and unbounded just above. min(mu_i, mu_j) has derivative 1 there, and the
  # gradient at 0 (a link without a budget, sliding: friction's tie rule) equals the
  # one-sided difference (travel is linear in the budget while the top box slips).
  grad = float(jax.grad(_top_travel)(0.0))
  eps = 1e-2
  fd = (float(_top_travel(eps)) - float(_top_travel(0.0))) / eps
  assert grad < 0
  assert grad == pytest.approx(fd, rel=0.05)


@pytest.mark.parametrize("mu_top", [0.0, 0.09, 1.0])
@pytest.mark.parametrize("case", ["slope", "sliding"])
def test_friction_per_link_matches_the_reference(case, mu_top):
  world = (stack(mu_top, gravity=TILTED) if case == "slope"
           else stack(mu_top, vel=(5.0, 0.0), floor_mu=0.5))
  steps = 30
  final, traj = _rollout(steps)(world)
  pos, vel = np.asarray(world.pos, np.float64), np.asarray(world.vel, np.float64)
  half, mass = np.asarray(world.half, np.float64), [INF, 1.0, 2.0]
  for t in range(steps):
    pos, vel = reference.step(pos, vel, half, mass, friction=np.asarray(world.friction, np.float64),
                              gravity=tuple(np.asarray(world.gravity, np.float64)))
    np.testing.assert_allclose(traj.vel[t], vel, atol=2e-5, err_msg=f"step {t}")
    np.testing.assert_allclose(traj.pos[t], pos, atol=2e-5, err_msg=f"step {t}")
