"""Stiff and extreme cases: every one finite, immovable bodies fixed, penetration and
energy bounded; failures reported as status bits, per world."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxchain as jc
from jaxchain import metrics, reference, scenes, status

INF = np.inf
G = 9.81


def energy(world, traj, g=G):
  """`[t]` kinetic + potential energy of the movable bodies along a trajectory."""
  m = np.where(np.asarray(world.movable), 1 / np.where(np.asarray(world.movable),
                                                        np.asarray(world.inv_mass), 1), 0)
  v, y = np.asarray(traj.vel, np.float64), np.asarray(traj.pos, np.float64)[..., 1]
  return 0.5 * np.sum(m[None, :, None] * v**2, axis=(1, 2)) + g * np.sum(m[None] * y, axis=1)


def penetrations(world, traj):
  return np.asarray(jax.vmap(lambda p: metrics.max_penetration(world.replace(pos=p)))(traj.pos))


def assert_sane(world, final, traj, pen_bound=None, g=G, dt=1 / 60):
  """The guarantees every case must hold (docs/physics.md, "Limits and guarantees"):
  finite state, immovable bodies at rest exactly still, penetration after every
  step at most `pen_bound` (default: the largest distance a body travels in one
  step, the bound for contacts a pass creates), and energy that never grows except
  by lifting what the step before left sunk."""
  pos, vel = np.asarray(traj.pos), np.asarray(traj.vel)
  assert np.all(np.isfinite(pos)) and np.all(np.isfinite(vel))
  still = np.asarray(world.active & (world.inv_mass == 0)) & ~np.any(np.asarray(world.vel) != 0, -1)
  np.testing.assert_array_equal(pos[:, still], np.broadcast_to(np.asarray(world.pos)[still],
                                                                pos[:, still].shape))
  pen = penetrations(world, traj)
  if pen_bound is None:
    speed_in = np.r_[np.abs(np.asarray(world.vel)).max(initial=0.0), np.abs(vel).max(axis=(1, 2))[:-1]]
    travel = (speed_in + g * dt) * dt
    assert np.all(pen <= travel + 1e-6), np.max(pen - travel)
  else:
    assert pen.max() <= pen_bound, pen.max()
  e = energy(world, traj, g)
  movable = np.asarray(world.movable)
  m_total = float(np.sum(1 / np.asarray(world.inv_mass)[movable]))
  allowed = g * m_total * np.r_[0.0, pen[:-1]] + 1e-4 * (1 + np.abs(e))
  assert np.all(np.diff(e) <= allowed[1:]), np.max(np.diff(e) - allowed[1:])
  assert int(np.max(np.asarray(final.status))) & status.NON_FINITE == 0


# --- Mass ratios ---------------------------------------------------------------------


@pytest.mark.parametrize("ratio", [1e-6, 1e-3, 1e3, 1e6])
def test_mass_ratio_chains_match_the_reference(ratio):
  masses = np.array([1.0, ratio, 1.0, ratio, 1.0])
  scene = scenes.push_chain(4, overlap=0.3, wall=False, masses=masses, overlaps=[0.1, 0.0, 0.2])
  world = scene.world().pad(8)
  out = np.asarray(jc.resolve(world, jc.Config(depth=8, gravity=False)).pos)[:5]
  want = reference.resolve(scene.pos, scene.half, scene.mass)
  np.testing.assert_allclose(out, want, atol=2e-6 * max(1.0, np.log10(max(ratio, 1 / ratio))))
  com = lambda p: masses @ p / masses.sum()
  np.testing.assert_allclose(com(out), com(scene.pos), atol=1e-5)


@pytest.mark.parametrize("ratio", [1e-6, 1e6])
def test_heavy_on_light_stack_rests(ratio):
  masses = np.where(np.arange(8) % 2 == 0, 1.0, ratio)  # Alternating light and heavy.
  scene = scenes.stack(8, overlaps=0.0, masses=masses)
  world = scene.world(friction=0.5)
  final, traj = jc.rollout(world, jc.Config.for_world(world), 120)
  assert_sane(world, final, traj, pen_bound=1e-5)
  np.testing.assert_allclose(final.pos, world.pos, atol=1e-5)


# --- Tall stacks and long chains -----------------------------------------------------


def test_stack_100_high_stays_standing():
  world = scenes.stack(100, overlaps=0.0).world(friction=0.5)
  cfg = jc.Config.for_world(world, depth=100)
  final, traj = jc.rollout(world, cfg, 100)
  assert_sane(world, final, traj, pen_bound=1e-5)  # float32 at heights up to 100.
  np.testing.assert_allclose(final.pos, world.pos, atol=1e-5)
  assert int(final.status) == 0


def test_chain_of_256_boxes_against_a_wall_moves_only_the_player():
  scene = scenes.push_chain(256, overlap=0.25, wall=True)
  world = scene.world()
  out = jc.resolve(world, jc.Config(depth=256, gravity=False))
  want = scene.pos.astype(np.float32)
  want[0, 0] -= 0.25
  np.testing.assert_allclose(out.pos, want, atol=1e-4)  # float32 at x up to 257.
  np.testing.assert_array_equal(out.pos[1:], world.pos[1:])
  assert int(out.status) == 0
  short = jc.resolve(world, jc.Config(depth=16, gravity=False))
  assert int(short.status) == status.DEPTH_EXHAUSTED  # Too shallow: reported, not hidden.


# --- Scale ---------------------------------------------------------------------------


def test_far_coordinates_and_tiny_boxes_in_float32():
  # Boxes of half-size 1e-3 around (1e4, 1e4): float32 spacing there is 2 ** -10 ~ 1e-3.
  ulp = float(np.spacing(np.float32(1e4)))
  pos = np.array([[1e4, 1e4 - 0.5], [1e4, 1e4 + 1e-3], [1e4, 1e4 + 3e-3]])
  half = np.array([[1.0, 0.5], [1e-3, 1e-3], [1e-3, 1e-3]])
  world = jc.World.create(pos, half, [INF, 1.0, 1.0], friction=0.3)
  final, traj = jc.rollout(world, jc.Config.for_world(world), 60)
  assert_sane(world, final, traj, pen_bound=2 * ulp)


@pytest.mark.parametrize("dt", [1e-4, 1e-3, 1 / 60, 1 / 30])
def test_resting_stack_for_every_dt(dt):
  world = scenes.stack(5, overlaps=0.0).world(friction=0.5)
  final, traj = jc.rollout(world, jc.Config.for_world(world, dt=dt), 100)
  assert_sane(world, final, traj, pen_bound=1e-5, dt=dt)
  np.testing.assert_allclose(final.pos, world.pos, atol=1e-5)


# --- Tunnelling ----------------------------------------------------------------------


def _bullet(speed):
  """A unit box flying at `speed` toward a wall 0.1 thick, 2 units away."""
  return jc.World.create([[0.0, 0.0], [3.05, 0.0]], [[0.5, 0.5], [0.05, 2.0]], [1.0, INF],
                         vel=[[speed, 0.0], [0.0, 0.0]])


def test_fast_body_is_stopped_with_substeps_from_for_world():
  # 3.3 units per 1/60 s step: more than the box and wall are thick.
  world = _bullet(200.0).replace(gravity=jnp.zeros(2))
  cfg = jc.Config.for_world(world)
  assert cfg.substeps > 1
  final, traj = jc.rollout(world, cfg, 30)
  assert float(np.max(np.asarray(traj.pos)[:, 0, 0])) <= 2.5 + 1e-5  # Never past the wall.
  assert int(final.status) == 0


def test_fast_body_without_substeps_is_reported():
  final, traj = jc.rollout(_bullet(200.0).replace(gravity=jnp.zeros(2)), jc.Config(gravity=False),
                           30)
  assert int(final.status) & status.FAST_BODY
  assert any("substeps" in m for m in jc.check(final))


# --- Degenerate worlds ---------------------------------------------------------------


def test_exactly_touching_boxes_stay_exactly_put():
  pos = np.array([[0.0, -0.5], [-1.0, 0.5], [0.0, 0.5], [1.0, 0.5], [0.0, 1.5]])
  half = np.array([[5.0, 0.5]] + [[0.5, 0.5]] * 4)
  world = jc.World.create(pos, half, [INF, 1.0, 2.0, 1.0, 3.0], friction=0.3)
  final, traj = jc.rollout(world, jc.Config.for_world(world), 60)
  assert_sane(world, final, traj, pen_bound=1e-6)
  np.testing.assert_allclose(final.pos, world.pos, atol=1e-6)


def test_all_immovable_world():
  world = jc.World.create([[0.0, 0.0], [0.5, 0.0], [3.0, 0.0]], [0.5, 0.5], INF,
                          vel=[[0.0, 0.0], [0.0, 0.0], [1.0, 0.0]])  # One kinematic mover.
  final, traj = jc.rollout(world, jc.Config.for_world(world), 60)
  np.testing.assert_array_equal(final.pos[:2], world.pos[:2])
  np.testing.assert_allclose(final.pos[2], [4.0, 0.0], rtol=1e-5)
  assert int(final.status) == 0


def test_empty_world_and_one_body():
  empty = jc.World.create(np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0))
  final, traj = jc.rollout(empty, jc.Config.for_world(empty), 3)
  assert final.pos.shape == (0, 2) and traj.pos.shape == (3, 0, 2)
  one = jc.World.create([[0.0, 1.0]], [0.5, 0.5], 2.0)
  final, _ = jc.rollout(one, jc.Config.for_world(one), 10)
  k = np.arange(1, 11)
  np.testing.assert_allclose(final.pos[0, 1], 1.0 - G * (1 / 60) ** 2 * np.sum(k), rtol=1e-5)


def test_batch_with_all_padding_worlds():
  real = scenes.platformer().scene.world(friction=0.3)
  empty = jc.World.create(np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0))
  batch = jc.stack([real, empty, real])
  cfg = jc.Config.for_world(batch)
  final, traj = jax.vmap(lambda w: jc.rollout(w, cfg, 30))(batch)
  np.testing.assert_array_equal(final.pos[1], batch.pos[1])
  np.testing.assert_array_equal(final.status, 0)
  np.testing.assert_allclose(final.pos[0], final.pos[2])


def test_one_bad_world_does_not_take_down_the_batch():
  world = scenes.stack(3, overlaps=0.0).world()
  batch = jc.stack([world, world])
  accel = jnp.zeros((2,) + world.pos.shape).at[1, 1, 0].set(jnp.inf)  # World 1 gets inf.
  cfg = jc.Config.for_world(batch)
  out = jax.vmap(lambda w, a: jc.step(w, cfg, a))(batch, accel)
  assert int(out.status[0]) == 0 and int(out.status[1]) & status.NON_FINITE
  np.testing.assert_allclose(out.pos[0], world.pos, atol=1e-6)
  assert jc.check(out)[0].startswith("world 1: the state went NaN or inf")


# --- Energy on a clean start -----------------------------------------------------------


@pytest.mark.parametrize("seed", [0, 1])
def test_falling_room_loses_energy(seed):
  world = scenes.box_room(np.random.default_rng(seed), 40).world(friction=0.3)
  assert float(metrics.max_penetration(world)) == 0.0
  final, traj = jc.rollout(world, jc.Config.for_world(world), 300)
  assert_sane(world, final, traj)  # Bounded by one step's travel while falling.
  assert float(metrics.max_penetration(final)) < 1e-5
  e = energy(world, traj)
  assert e[-1] < 0.5 * e[0]


def test_overlap_recovery_adds_no_kinetic_energy():
  rng = np.random.default_rng(0)
  pos = np.r_[[[3, -0.5], [3, 6.5], [-0.5, 3], [6.5, 3]], rng.uniform(0.5, 5.5, (30, 2))]
  half = np.r_[[[4, 0.5], [4, 0.5], [0.5, 3.5], [0.5, 3.5]], np.full((30, 2), 0.45)]
  world = jc.World.create(pos, half, np.r_[np.full(4, INF), rng.uniform(0.5, 2, 30)],
                          gravity=(0.0, 0.0))
  assert float(metrics.max_penetration(world)) > 0.5  # Packed, heavily overlapping.
  cfg = jc.Config.for_world(world, iterations=4)
  final, traj = jc.rollout(world, cfg, 50)
  np.testing.assert_array_equal(traj.vel, 0.0)  # Pushed apart by position alone.
  assert float(penetrations(world, traj)[-1]) < float(metrics.max_penetration(world))
