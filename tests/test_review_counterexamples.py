"""Counterexamples from a review of issue 18 items 1 (seams, 95f8132) and 2 (friction per
link, 58064c2). Each test states what the project promises (DESIGN.md sections 1, 3, 3b;
docs/physics.md) on a minimal scene, and fails today (strict xfail)."""

import numpy as np
import pytest

import jaxchain as jc
from jaxchain import reference

INF = float("inf")
DT = 1 / 60
G = 9.81


def free_x(x0: float, v0: float, accel: float, steps: int) -> float:
  """x after `steps` steps of semi-implicit Euler in float32 (no contact along x)."""
  x, v, dt, a = np.float32(x0), np.float32(v0), np.float32(DT), np.float32(accel)
  for _ in range(steps):
    v = np.float32(v + a * dt)
    x = np.float32(x + v * dt)
  return float(x)


def tiles(n: int = 10):
  """Unit floor tiles side by side, tops at y = 0.5 (seams at x = 1, 2, ...)."""
  return [[i + 0.5, 0.0] for i in range(n)], [[0.5, 0.5]] * n


# --- Seams (issue 18 item 1) -------------------------------------------------------------


def test_a_player_on_a_one_way_platform_runs_onto_a_flush_solid_tile():
  # Tiles 0-4 (x in [0, 5]) are one-way (a jump-through ledge), tiles 5-9 solid, all tops
  # at y = 0.5: one flat surface. The player (half 0.4) stands on the one-way tile 4 with
  # its right edge exactly on the seam x = 5 and is pushed right at 20 u/s^2: the issue's
  # first scene with one-way tiles on one side. Today it never moves (x stays 4.6): the
  # quadrant under its bottom face lies in a one-way body, which makes no surface, so the
  # corner contact with tile 5 goes to the time-of-impact rule and the side of tile 5
  # blocks it. (Solid to one-way, leftward from x = 5.4 with tiles 5-9 one-way the other
  # way round, and solid-only floors all run on.)
  pos, half = tiles()
  world = jc.World.create([[4.6, 0.9]] + pos, [[0.4, 0.4]] + half, [1.0] + [INF] * 10,
                          one_way=[False] + [i < 5 for i in range(10)])
  steps = 30
  accel = np.zeros((steps, 11, 2), np.float32)
  accel[:, 0, 0] = 20.0
  final, traj = jc.rollout(world, jc.Config.for_world(world), steps, accel)
  np.testing.assert_allclose(traj.pos[-1, 0, 0], free_x(4.6, 0.0, 20.0, steps), rtol=1e-6)
  np.testing.assert_allclose(traj.pos[:, 0, 1], 0.9, atol=1e-6)


def test_a_body_landing_on_a_tile_floor_at_a_seam_keeps_its_speed():
  # A frictionless player (half 0.4) falls at 6 u/s onto a floor of unit tiles while
  # moving right at 2 u/s, its right edge exactly on the seam x = 5 at the start of the
  # landing step (bottom 0.1 above the tiles). The floor is flat: it lands and runs on at
  # 2 u/s, as reference.step says (vx = 2 every step). Today the pair with tile 5 is
  # "level along x" at the start, keeps the x axis, and the inner side of tile 5 stops the
  # player dead on landing (vx = 0, x stays 4.6, status 0).
  pos, half = tiles()
  world = jc.World.create([[4.6, 1.0]] + pos, [[0.4, 0.4]] + half, [1.0] + [INF] * 10,
                          vel=[[2.0, -6.0]] + [[0.0, 0.0]] * 10)
  steps = 10
  final, traj = jc.rollout(world, jc.Config.for_world(world), steps)
  ref_pos, ref_vel = np.asarray(world.pos, np.float64), np.asarray(world.vel, np.float64)
  ref_pos, ref_vel = reference.step(ref_pos, ref_vel, np.asarray(world.half, np.float64),
                                    [1.0] + [INF] * 10)
  assert ref_vel[0, 0] == pytest.approx(2.0)  # The reference lands and runs on.
  np.testing.assert_allclose(traj.vel[:, 0, 0], 2.0, rtol=1e-6)
  np.testing.assert_allclose(traj.pos[-1, 0, 0], free_x(4.6, 2.0, 0.0, steps), rtol=1e-6)


def test_a_body_hitting_a_wall_of_tiles_at_a_seam_keeps_falling():
  # A frictionless player (half 0.4) flies right at 9 u/s into a wall of unit tiles (faces
  # at x = 5) with its bottom edge exactly on the seam y = 3, 0.1 from the wall. It hits
  # the wall and falls down along it, never grounded, as reference.step says (vy = -g dt
  # after the first step). Today the pair with the lower tile is "level along y", keeps
  # that axis, and the tile's top catches it: lifted back to y = 3.4, vy = 0 and
  # `grounded` True in the first step, 0.0027 above the free fall ever after.
  world = jc.World.create([[4.5, 3.4]] + [[5.5, i + 0.5] for i in range(8)],
                          [[0.4, 0.4]] + [[0.5, 0.5]] * 8, [1.0] + [INF] * 8,
                          vel=[[9.0, 0.0]] + [[0.0, 0.0]] * 8)
  final, traj = jc.rollout(world, jc.Config.for_world(world), 5, record=("touching",))
  ref_pos, ref_vel = reference.step(np.asarray(world.pos, np.float64),
                                    np.asarray(world.vel, np.float64),
                                    np.asarray(world.half, np.float64), [1.0] + [INF] * 8)
  assert ref_vel[0, 1] == pytest.approx(-G * DT)  # The reference keeps falling.
  assert not np.any(np.asarray(traj.touching[:, 0, jc.flags.DOWN]))  # Never grounded.
  np.testing.assert_allclose(traj.vel[0, 0], ref_vel[0], atol=1e-5)
  np.testing.assert_allclose(traj.pos[0, 0], ref_pos[0], atol=1e-5)


def test_a_slow_body_crosses_a_seam():
  # Fixed: a rounding overlap within the skin at the start counts as touching
  # (geometry.contacts, reference._Scene.contact), so the level and seam rules apply.
  # A frictionless box (half 0.3) rests on unit tile B (x in [6, 7]) with its left edge on
  # the seam x = 6 to tile A, moving left at 0.0207 u/s (3.45e-4 per step). In the second
  # step its edge is 3.45e-4 over A (beyond the skin) and, in float32, 6e-8 into A's top:
  # "overlapping at the start" on both axes, so neither the level rule nor the seam rule
  # applies; at the predicted positions gravity has sunk it 0.0027 but its edge is only
  # 6.9e-4 into A, so the smaller overlap is along x and A's side pushes it back to 6.3
  # with vx = 0, for good (status 0). reference.step runs on at -0.0207 (its sweep lifts it
  # out of B first). About 1 in 10 slow movers (0.02-0.2 u/s) crossing a seam at
  # non-dyadic heights stop so.
  world = jc.World.create([[6.3, 1.3], [5.5, 0.5], [6.5, 0.5]],
                          [[0.3, 0.3], [0.5, 0.5], [0.5, 0.5]],
                          [2.0, INF, INF], vel=[[-0.0207, 0.0], [0.0, 0.0], [0.0, 0.0]])
  steps = 6
  final, traj = jc.rollout(world, jc.Config.for_world(world), steps)
  pos, vel = np.asarray(world.pos, np.float64), np.asarray(world.vel, np.float64)
  for _ in range(steps):
    pos, vel = reference.step(pos, vel, np.asarray(world.half, np.float64), [2.0, INF, INF])
  assert vel[0, 0] == pytest.approx(-0.0207, rel=1e-6)  # The reference runs on.
  np.testing.assert_allclose(traj.vel[:, 0, 0], np.float32(-0.0207), rtol=1e-5)
  np.testing.assert_allclose(traj.pos[-1, 0], pos[0], atol=1e-5)


# --- Friction per link (issue 18 item 2) ---------------------------------------------------


def three_stack(m_b: float):
  """A floor; box A (mass 1) on it, a thin box B (mass m_b) on A and a heavy frictionless
  box C (mass 10) on B, all sliding right at 3 u/s. Pair coefficients (the smaller of
  the bodies' 0.5, 1, 0.225, 0): floor-A 0.5, A-B 0.225, B-C 0 (under the geometric
  mean of issue 18 the bodies had 1, 0.25, 0.2025, 0: the same pairs)."""
  return jc.World.create([[0.0, -0.5], [0.0, 0.5], [0.0, 1.25], [0.0, 2.0]],
                         [[50.0, 0.5], [1.0, 0.5], [1.0, 0.25], [1.0, 0.5]],
                         [INF, 1.0, m_b, 10.0], vel=[[0.0, 0.0]] + [[3.0, 0.0]] * 3,
                         friction=[0.5, 1.0, 0.225, 0.0])


def test_friction_never_drives_a_link_to_slide_the_way_it_pushes():
  # Coulomb: C is frictionless and keeps 3 u/s; A and B slow down together on the floor's
  # budget 0.5 * 11.1 g dt (B needs 0.1 * 0.825 of shear from A, its link holds 0.743):
  # both at 2.175 u/s after the first step. Today the first solve (one unit A+B+C) finds
  # that the A-B link cannot hold C's share, so it slips and carries its whole budget
  # 0.45 * 10.1 g dt = 0.743 onto B of mass 0.1: B ends at -0.716 u/s while A moves at
  # 2.464 (status 0), the friction on B pointing the way B now slides relative to A.
  # reference._friction does the same (-0.716); with m_b = 0.01 it gives B -33.8 u/s.
  final = jc.step(three_stack(0.1), jc.Config.for_world(three_stack(0.1), substeps=1))
  v = np.asarray(final.vel[:, 0])
  assert v[3] == pytest.approx(3.0)
  assert v[2] - v[1] == pytest.approx(0.0, abs=1e-3)  # The A-B link sticks.
  assert v[1] == pytest.approx(3.0 - 0.5 * 11.1 / 1.1 * G * DT, abs=1e-3)
  # Fixed: each slip round drops each body's most overloaded link only (C's, whose
  # budget is 0), so A-B is tested again on A+B and holds; the reference the same.
  world = three_stack(0.1)
  _, ref_vel = reference.step(np.asarray(world.pos, np.float64),
                              np.asarray(world.vel, np.float64),
                              np.asarray(world.half, np.float64), [INF, 1.0, 0.1, 10.0],
                              friction=np.asarray(world.friction, np.float64))
  np.testing.assert_allclose(v, ref_vel[:, 0], atol=1e-5)


def test_a_link_never_carries_more_than_its_budget():
  # A floor; box A (mass 1) on it; on A a frictionless box B (mass 2) and a box C (mass 1)
  # side by side, all sliding at 3 u/s. Pair coefficients: floor-A 0.5, A-C 0.7, A-B 0.
  # First solve, one unit A+B+C: deceleration 0.5 g, C needs 0.5 g dt of shear, the A-C
  # link holds 0.7 g dt: kept. B's link slips; solved again on A+C alone the deceleration
  # is 0.5 * 4 / 2 = 1.0 g: C needs 1.0 g dt > 0.7 g dt, yet it stays in A's unit. Coulomb:
  # C slips at 0.7 g (2.8855 u/s after the step), A at 1.3 g (2.7875). Today both change
  # by 1.0 g dt (2.8365): the A-C link carried 0.1635 of friction on a budget of 0.1145.
  # reference._friction does the same.
  world = jc.World.create([[0.0, -0.5], [0.0, 0.5], [-1.0, 1.5], [1.0, 1.5]],
                          [[50.0, 0.5], [2.0, 0.5], [0.5, 0.5], [0.5, 0.5]],
                          [INF, 1.0, 2.0, 1.0], vel=[[0.0, 0.0]] + [[3.0, 0.0]] * 3,
                          friction=[0.5, 1.0, 0.0, 0.7])  # The pairs above.
  final = jc.step(world, jc.Config.for_world(world, substeps=1))
  v = np.asarray(final.vel[:, 0], np.float64)
  budget = 0.7 * 1.0 * G * DT  # mu_pair * C's normal impulse on A.
  assert abs(v[3] - 3.0) * 1.0 <= budget * (1 + 1e-4)
  assert v[3] == pytest.approx(3.0 - 0.7 * G * DT, abs=1e-4)
  assert v[1] == pytest.approx(3.0 - 1.3 * G * DT, abs=1e-4)
  # Fixed: a second slip round tests A-C again on A+C; it slips and carries its budget
  # (kinetic friction). The reference the same.
  _, ref_vel = reference.step(np.asarray(world.pos, np.float64),
                              np.asarray(world.vel, np.float64),
                              np.asarray(world.half, np.float64), [INF, 1.0, 2.0, 1.0],
                              friction=np.asarray(world.friction, np.float64))
  np.testing.assert_allclose(v, ref_vel[:, 0], atol=1e-4)


def test_reference_friction_never_adds_energy():
  # Fixed: a slipping link no longer carries a forced impulse (it rubs like any link).
  # The three-box stack with a thin box of mass 0.01: reference.step gains 4.2 J in the
  # first step (B at -33.8 u/s). (jc.step scales the update down and sets
  # IMPULSES_SCALED, on a plain stack.)
  world = three_stack(0.01)
  mass = np.array([INF, 1.0, 0.01, 10.0])
  pos0, vel0 = np.asarray(world.pos, np.float64), np.asarray(world.vel, np.float64)
  pos, vel = reference.step(pos0, vel0, np.asarray(world.half, np.float64), mass,
                            friction=np.asarray(world.friction, np.float64))
  m = np.where(np.isinf(mass), 0.0, mass)
  energy = lambda p, v: float(np.sum(0.5 * m * np.sum(v * v, -1)) + np.sum(m * G * p[:, 1]))
  assert energy(pos, vel) <= energy(pos0, vel0) + 1e-9


def test_a_box_sliding_in_a_corridor_of_its_height_matches_the_reference():
  # A box (half 0.5, friction 0.5) slides at 2 u/s between a floor and a ceiling exactly
  # 1 apart (a player in a one-tile tunnel). reference.step found the box touching both
  # after resolving, called the link crushed and gave it no normal impulse and no
  # friction: 2.0 u/s every step. Fixed (issue 44 item 1): a crush needs a push into both
  # sides; gravity presses the box onto the floor only (its motion opens 0.0027 to the
  # ceiling), so it rests on the floor and friction acts: 1.918, 1.837, 1.755, in both,
  # and no CRUSHED bit.
  world = jc.World.create([[0.0, 0.5], [0.0, -0.5], [0.0, 1.5]],
                          [[0.5, 0.5], [5.0, 0.5], [5.0, 0.5]], [1.0, INF, INF],
                          vel=[[2.0, 0.0], [0.0, 0.0], [0.0, 0.0]], friction=0.5)
  steps = 3
  final, traj = jc.rollout(world, jc.Config.for_world(world, substeps=1), steps)
  pos, vel = np.asarray(world.pos, np.float64), np.asarray(world.vel, np.float64)
  for t in range(steps):
    pos, vel = reference.step(pos, vel, np.asarray(world.half, np.float64), [1.0, INF, INF],
                              friction=0.5)
    np.testing.assert_allclose(traj.vel[t], vel, atol=1e-5, err_msg=f"step {t}")
    np.testing.assert_allclose(traj.pos[t], pos, atol=1e-5, err_msg=f"step {t}")
  assert vel[0, 0] == pytest.approx(2.0 - steps * 0.5 * G * DT, abs=1e-6)
  assert not np.asarray(final.crushed).any() and int(final.status) == 0
