"""Seams: a surface made of several coplanar immovable bodies acts as one surface.

A body sliding along a floor of separate tiles, a wall of separate tiles or a merged wall
that changes thickness behind its face never meets an inner side of that surface,
whatever the rounding (no ghost collisions), its contact with the surface is along the
surface's normal, and `grounded` holds only on a real floor (`geometry.seam_axis`,
mirrored by `reference._Scene.seam_axis`).

Every scene here is frictionless, so the motion along a surface has an exact answer:
the free kinematics of semi-implicit Euler, computed in float32 the way the step does.
"""

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, strategies as st

import jaxchain as jc
from jaxchain import reference

INF = float("inf")
DT = 1 / 60
G = 9.81


def free_motion(x0: float, v0: float, accel: float, steps: int) -> tuple[np.ndarray, np.ndarray]:
  """Positions and velocities after each step of semi-implicit Euler, in float32."""
  x, v, dt, a = np.float32(x0), np.float32(v0), np.float32(DT), np.float32(accel)
  xs, vs = [], []
  for _ in range(steps):
    v = np.float32(v + a * dt)
    x = np.float32(x + v * dt)
    xs.append(x)
    vs.append(v)
  return np.array(xs), np.array(vs)


def tile_floor(player_x: float, tiles: int = 30, player_half: float = 0.4, vx: float = 0.0):
  """A player (body 0) resting on a floor of unit tiles (tops at y = 0.5)."""
  pos = [[player_x, 0.5 + player_half]] + [[i + 0.5, 0.0] for i in range(tiles)]
  half = [[player_half, player_half]] + [[0.5, 0.5]] * tiles
  return jc.World.create(pos, half, [1.0] + [INF] * tiles, vel=[[vx, 0.0]] + [[0.0, 0.0]] * tiles)


def tile_wall(player_bottom: float, tiles: int = 8):
  """A player (body 0, half 0.4) against a wall of unit tiles (faces at x = 5), far
  above a floor."""
  pos = [[4.6, player_bottom + 0.4]] + [[5.5, i + 0.5] for i in range(tiles)]
  half = [[0.4, 0.4]] + [[0.5, 0.5]] * tiles
  return jc.World.create(pos, half, [1.0] + [INF] * tiles)


def push(world: jc.World, steps: int, accel) -> jax.Array:
  return jnp.broadcast_to(jnp.zeros_like(world.pos).at[0].set(jnp.asarray(accel, jnp.float32)),
                          (steps,) + world.pos.shape)


@pytest.mark.parametrize("accel", [20.0, 400.0])
def test_a_player_with_its_edge_on_a_seam_runs_off_it(accel):
  # Player half 0.4 at x = 4.6: its right edge is exactly on the seam x = 5 between
  # two unit tiles. On f55f53b it never moved (the next tile's side blocked it).
  world = tile_floor(4.6)
  steps = 20 if accel < 100 else 6  # Below the tunnelling speed (no FAST_BODY).
  final, traj = jc.rollout(world, jc.Config.for_world(world), steps, push(world, steps, [accel, 0.0]))
  xs, vs = free_motion(4.6, 0.0, accel, steps)
  np.testing.assert_allclose(traj.pos[:, 0, 0], xs, rtol=1e-6)
  np.testing.assert_allclose(traj.vel[:, 0, 0], vs, rtol=1e-6)
  np.testing.assert_allclose(traj.pos[:, 0, 1], 0.9, atol=1e-6)  # It rests on the tiles.
  assert int(final.status) == 0
  assert bool(jc.grounded(final)[0])


def test_a_player_pressed_on_a_wall_of_tiles_slides_down_past_a_seam():
  # Its bottom edge is on the seam y = 3 between two wall tiles, pressed into the wall.
  # On f55f53b it hung in mid-air (standing on the lower tile's top), grounded.
  world = tile_wall(3.0)
  steps = 20
  final, traj = jc.rollout(world, jc.Config.for_world(world), steps,
                           push(world, steps, [50.0, 0.0]), record=("touching",))
  ys, vys = free_motion(3.4, 0.0, -G, steps)
  np.testing.assert_allclose(traj.pos[:, 0, 1], ys, rtol=1e-6)
  np.testing.assert_allclose(traj.vel[:, 0, 1], vys, rtol=1e-6)
  np.testing.assert_allclose(traj.pos[:, 0, 0], 4.6, atol=1e-6)  # Held by the wall.
  assert not np.any(np.asarray(traj.touching[:, 0, jc.flags.DOWN]))  # Never grounded.
  assert np.all(np.asarray(traj.touching[:, 0, jc.flags.RIGHT]))  # Always on the wall.


def test_a_runner_on_a_floor_of_two_kinds_crosses_the_seam():
  # Two merged floor pieces (as the Tiled loader keeps two tile kinds apart), the runner
  # starting with its edge on the seam at x = 5.
  world = jc.World.create([[4.6, 0.9], [2.5, 0.0], [10.0, 0.0]],
                          [[0.4, 0.4], [2.5, 0.5], [5.0, 0.5]], [1.0, INF, INF], vel=[[3.0, 0.0]] * 3)
  world = world.replace(vel=world.vel.at[1:].set(0.0))
  steps = 30
  _, traj = jc.rollout(world, jc.Config.for_world(world), steps)
  xs, _ = free_motion(4.6, 3.0, 0.0, steps)
  np.testing.assert_allclose(traj.pos[:, 0, 0], xs, rtol=1e-6)
  np.testing.assert_allclose(traj.pos[:, 0, 1], 0.9, atol=1e-6)


def test_a_player_slides_along_sokoban3s_wall_face():
  # sokoban3's wall at x = 2 is a thick piece ([0, 2] x [2, 3]) on a thinner one
  # ([1, 2] x [1, 2]): one face. The player (half 0.4, top-down: no gravity) slides
  # down along it, pressed into it, its bottom on the seam y = 2 at the start.
  level = jc.levels.load("sokoban3")
  world = level.world()
  player = level.player
  world = world.replace(pos=world.pos.at[player].set(jnp.array([2.4, 2.4])),
                        vel=world.vel.at[player].set(jnp.array([0.0, -2.0])))
  steps = 20
  accel = jnp.zeros_like(world.pos).at[player].set(jnp.array([-20.0, 0.0]))
  _, traj = jc.rollout(world, jc.Config.for_world(world), steps, accel)
  ys, _ = free_motion(2.4, -2.0, 0.0, steps)
  np.testing.assert_allclose(traj.pos[:, player, 1], ys, rtol=1e-6)
  np.testing.assert_allclose(traj.pos[:, player, 0], 2.4, atol=1e-6)


RUNNERS = 64
RUN_TILES = 20


@functools.lru_cache(maxsize=None)
def _runner_fn(steps: int):
  world = tile_floor(1.0, tiles=RUN_TILES)
  cfg = jc.Config.for_world(world, substeps=1)
  return jax.jit(jax.vmap(lambda w: jc.rollout(w, cfg, steps)[0]))


def test_no_runner_gets_stuck_on_a_floor_of_tiles():
  # Players running at constant speed over separate tiles (about 700 crossings): on
  # f55f53b one crossing in about 1300 stopped dead on a rounding gap at a seam (this
  # draw has one).
  steps = 180
  rng = np.random.default_rng(7)
  x0 = rng.uniform(0.5, 2.0, RUNNERS).astype(np.float32)
  speed = rng.uniform(3.0, 5.5, RUNNERS).astype(np.float32)
  worlds = jc.stack([tile_floor(float(x), tiles=RUN_TILES, vx=float(v)) for x, v in zip(x0, speed)])
  final = _runner_fn(steps)(worlds)
  expected = np.array([free_motion(x, v, 0.0, steps)[0][-1] for x, v in zip(x0, speed)])
  np.testing.assert_allclose(final.pos[:, 0, 0], expected, rtol=1e-5)
  np.testing.assert_allclose(final.vel[:, 0, 0], speed, rtol=1e-6)


TILES = 12


def _random_tiling(widths, vertical: bool):
  """Tiles of the given widths side by side from 0 (float64 edges, rounded to float32
  centres and halves: seams off by a rounding error, as in a real level)."""
  edges = np.concatenate([[0.0], np.cumsum(widths)])
  centre = (edges[:-1] + edges[1:]) / 2
  half = np.diff(edges) / 2
  along = np.stack([centre, np.zeros_like(centre)], axis=-1)
  size = np.stack([half, np.full_like(half, 0.5)], axis=-1)
  if vertical:  # A wall: faces at x = 0.5.
    along, size = along[:, ::-1] + [0.0, 0.0], size[:, ::-1]
  return along, size, edges[-1]


@functools.lru_cache(maxsize=None)
def _slide_fn(steps: int):
  cfg = jc.Config(gravity=True, friction=False, depth=4, links=4, one_way=False, layers=False,
                  sensors=False)
  return jax.jit(lambda w, a: jc.rollout(w, cfg, steps, a))


@given(widths=st.lists(st.floats(0.2, 2.0), min_size=TILES, max_size=TILES),
       start=st.floats(0.0, 1.0), speed=st.floats(0.5, 8.0), leftward=st.booleans(),
       vertical=st.booleans())
def test_bodies_sliding_along_random_tilings_never_stop(widths, start, speed, leftward, vertical):
  steps = 30
  tiles, tile_half, length = _random_tiling(np.array(widths), vertical)
  h = 0.3
  travel = speed * steps * DT
  begin = length / 2 - travel / 2 + start * 0.1
  if leftward:
    begin, speed = length - begin, -speed
  if vertical:  # Sliding up or down a wall (face x = 0.5), pressed into it, no gravity.
    body, vel, accel = [0.5 + h, begin], [0.0, speed], [-30.0, 0.0]
  else:  # Running along a floor (tops at y = 0.5) under gravity.
    body, vel, accel = [begin, 0.5 + h], [speed, 0.0], [0.0, 0.0]
  pos = np.concatenate([[body], tiles]).astype(np.float32)
  half = np.concatenate([[[h, h]], tile_half]).astype(np.float32)
  world = jc.World.create(pos, half, [1.0] + [INF] * TILES,
                          vel=[vel] + [[0.0, 0.0]] * TILES,
                          gravity=(0.0, 0.0) if vertical else (0.0, -G))
  a = jnp.zeros_like(world.pos).at[0].set(jnp.asarray(accel, jnp.float32))
  final, traj = _slide_fn(steps)(world, a)
  axis = 1 if vertical else 0
  xs, vs = free_motion(begin, speed, 0.0, steps)
  np.testing.assert_allclose(traj.vel[:, 0, axis], vs, rtol=1e-6)  # Never slowed down.
  np.testing.assert_allclose(traj.pos[:, 0, axis], xs, rtol=1e-5, atol=1e-5)
  # Held on the surface's face, along its normal (within a rounding of the seams).
  np.testing.assert_allclose(traj.pos[:, 0, 1 - axis], 0.5 + h, atol=1e-5)


def test_reference_takes_the_same_seam_axis():
  # The reference resolves the seam scene's first step like the JAX step: the player
  # rides over the seam (resolved along y), not back against the next tile's side.
  world = tile_floor(4.6, tiles=8)
  start = np.asarray(world.pos, np.float64)
  pred = start.copy()
  pred[0] += [20.0 * DT * DT, -G * DT * DT]
  out = reference.resolve(pred, np.asarray(world.half, np.float64),
                          np.where(np.asarray(world.inv_mass) > 0, 1.0, INF), start=start)
  np.testing.assert_allclose(out[0], [pred[0, 0], 0.9], atol=1e-9)
  stepped = jc.step(world, jc.Config.for_world(world), push(world, 1, [20.0, 0.0])[0])
  np.testing.assert_allclose(stepped.pos[0], out[0], atol=1e-6)
  # The wall scene: resolved along x, the player keeps falling.
  wall = tile_wall(3.0)
  start = np.asarray(wall.pos, np.float64)
  pred = start.copy()
  pred[0] += [50.0 * DT * DT, -G * DT * DT]
  out = reference.resolve(pred, np.asarray(wall.half, np.float64),
                          np.where(np.asarray(wall.inv_mass) > 0, 1.0, INF), start=start)
  np.testing.assert_allclose(out[0], [4.6, pred[0, 1]], atol=1e-9)
