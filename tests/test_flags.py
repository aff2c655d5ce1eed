"""The platformer toolkit (issue 12): contact flags, one-way bodies, layers, sensors.

Every scene is a world of at most `N` bodies padded to `N`, and all of them run in one
batch through one compiled rollout (`_runs`, module-scoped) with every feature on:
one compile for the whole module. Each test reads its own scene's trajectory.
"""

import importlib.util
import pathlib

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxchain as jc
from jaxchain import cli, levels
from tests.helpers import TOL

INF = float("inf")
N = 4
T = 90
DT = 1 / 60
CFG = jc.Config(depth=4, links=4, one_way=True, layers=True, sensors=True)
PLAYER, BOX = levels.PLAYER, levels.BOX
FLOOR = dict(pos=[0.0, -0.5], half=[8.0, 0.5], mass=INF)


def body(pos, half, mass=1.0, **kw):
  return dict(pos=pos, half=[half, half] if np.isscalar(half) else half, mass=mass, **kw)


def world(*bodies, gravity=(0.0, -9.81), friction=0.0):
  """A world of `bodies` (dicts of per-body keywords), padded to `N`."""
  keys = ("vel", "one_way", "sensor", "category", "mask")
  defaults = dict(vel=[0.0, 0.0], one_way=False, sensor=False, category=1, mask=0xFFFFFFFF)
  arrays = {k: [b.get(k, defaults[k]) for b in bodies] for k in keys}
  w = jc.World.create([b["pos"] for b in bodies], [b["half"] for b in bodies],
                      [b["mass"] for b in bodies], vel=arrays["vel"], gravity=gravity,
                      friction=friction, one_way=np.array(arrays["one_way"]),
                      sensor=np.array(arrays["sensor"]), category=np.array(arrays["category"]),
                      mask=np.array(arrays["mask"], np.uint64))
  return w.pad(N)


def push(index, ax, steps=T):
  """Controls `[T, N, 2]` accelerating body `index` along x by `ax` for `steps` steps."""
  u = np.zeros((T, N, 2), np.float32)
  u[:steps, index, 0] = ax
  return u


# name: (world, controls)
SCENES = {
    # One-way platform (immovable slab, top at 0.1).
    "drop_on_platform": (world(body([0.0, 0.0], [2.0, 0.1], INF, one_way=True),
                               body([0.0, 1.0], 0.5)), None),
    "up_through_platform": (world(body([0.0, 0.0], [2.0, 0.1], INF, one_way=True),
                                  body([0.0, -1.0], 0.5, vel=[0.0, 8.0])), None),
    "side_through_platform": (world(body([0.0, 0.0], [1.0, 0.5], INF, one_way=True),
                                    body([-3.0, 0.0], 0.5, vel=[4.0, 0.0]), gravity=(0.0, 0.0)),
                              None),
    "push_on_platform": (world(body([0.0, 0.0], [4.0, 0.1], INF, one_way=True),
                               body([-1.0, 0.6], 0.5), body([0.0, 0.6], 0.5), friction=0.3),
                         push(1, 10.0)),
    # A movable one-way crate rests on the floor; a box dropped on it rests on it.
    "movable_one_way": (world(FLOOR, body([0.0, 0.5], 0.5, one_way=True),
                              body([0.0, 2.0], 0.5)), None),
    # Layers: the top box (category 4, mask 1) ignores the lower one (category 2).
    "layers_apart": (world(FLOOR, body([0.0, 0.5], 0.5, category=2),
                           body([0.0, 1.6], 0.5, category=4, mask=1)), None),
    "layers_meet": (world(FLOOR, body([0.0, 0.5], 0.5, category=2),
                          body([0.0, 1.6], 0.5, category=4, mask=3)), None),
    # Layers in a chain: the player pushes box A; box B (layer 8) collides with layer 8
    # only, so the chain passes through it.
    "layers_chain": (world(body([0.0, 0.0], 0.5, category=PLAYER),
                           body([1.0, 0.0], 0.5, category=BOX, mask=PLAYER | BOX),
                           body([2.0, 0.0], 0.5, category=8, mask=8),
                           gravity=(0.0, 0.0)), push(0, 6.0)),
    # Sensors: a goal at x = 2 that admits boxes only; a box and a player cross it.
    "sensor_sees_box": (world(body([2.0, 0.5], 0.5, INF, sensor=True, category=8, mask=BOX),
                              body([4.0, 0.5], 0.45, vel=[-2.0, 0.0], category=BOX),
                              gravity=(0.0, 0.0)), None),
    "sensor_ignores_player": (world(body([2.0, 0.5], 0.5, INF, sensor=True, category=8, mask=BOX),
                                    body([4.0, 0.5], 0.4, vel=[-2.0, 0.0], category=PLAYER),
                                    gravity=(0.0, 0.0)), None),
    # Flags: a box on the floor pushed against a wall on its right.
    "against_wall": (world(FLOOR, body([2.0, 1.0], [0.5, 1.0], INF), body([0.0, 0.5], 0.5)),
                     push(2, 5.0)),
}
NAMES = list(SCENES)


@pytest.fixture(scope="module")
def runs():
  """Every scene's `(final, trajectory)`, from one compiled, vmapped rollout."""
  worlds = jc.stack([w for w, _ in SCENES.values()])
  controls = jnp.asarray(np.stack([np.zeros((T, N, 2), np.float32) if u is None else u
                                   for _, u in SCENES.values()]))
  run = jax.jit(jax.vmap(lambda w, u: jc.rollout(w, CFG, T, u, record=jc.stepping.RECORDABLE)))
  final, traj = run(worlds, controls)
  pick = lambda tree, b: jax.tree.map(lambda x: np.asarray(x[b]), tree)
  return {name: (pick(final, b), pick(traj, b)) for b, name in enumerate(NAMES)}


def test_no_scene_raises_a_status_bit(runs):
  for name, (final, traj) in runs.items():
    assert int(final.status) == 0, (name, jc.check(final))


# --- One-way platforms ------------------------------------------------------------------


def test_body_dropped_onto_a_one_way_platform_rests_on_it(runs):
  final, traj = runs["drop_on_platform"]
  np.testing.assert_allclose(final.pos[1], [0.0, 0.6], **TOL["exact_f32"])
  np.testing.assert_array_equal(final.vel[1], [0.0, 0.0])
  assert final.touching[1].tolist() == [False, False, False, True]
  assert np.all(traj.pos[:, 1, 1] >= 0.6 - 1e-6)  # Never sank into it.


def test_body_passes_up_through_a_one_way_platform_and_lands_on_top(runs):
  final, traj = runs["up_through_platform"]
  y = traj.pos[:, 1, 1]
  inside = (y - 0.5 < 0.1) & (y + 0.5 > -0.1)
  assert inside.any()  # It went through the slab from below ...
  np.testing.assert_allclose(y[: np.argmax(inside) + 1], -1.0 + np.cumsum(
      8.0 - 9.81 * DT * np.arange(1, np.argmax(inside) + 2)) * DT, atol=1e-4)  # ... unhindered,
  assert y.max() > 0.6 + 1.0  # ... rose well above it,
  np.testing.assert_allclose(final.pos[1], [0.0, 0.6], **TOL["exact_f32"])  # and landed on it.
  np.testing.assert_array_equal(final.vel[1], [0.0, 0.0])


def test_body_passes_a_one_way_platform_from_the_side(runs):
  final, traj = runs["side_through_platform"]
  want = -3.0 + 4.0 * DT * np.arange(1, T + 1)
  np.testing.assert_allclose(traj.pos[:, 1, 0], want, atol=1e-5)  # Never slowed.
  np.testing.assert_array_equal(traj.vel[:, 1], np.tile([4.0, 0.0], (T, 1)))
  assert not traj.touching[:, 1].any()


def test_chain_works_along_a_one_way_platform(runs):
  final, traj = runs["push_on_platform"]
  # The player pushes the box along the platform: both stay on it, moving as one.
  np.testing.assert_allclose(final.pos[1:3, 1], [0.6, 0.6], **TOL["exact_f32"])
  np.testing.assert_allclose(final.vel[1], final.vel[2], atol=1e-5)
  assert final.vel[1, 0] > 1.0
  np.testing.assert_allclose(final.pos[2, 0] - final.pos[1, 0], 1.0, atol=1e-4)
  assert final.touching[1, 0] and final.touching[2, 1]  # Pushing, pushed.
  assert final.touching[1, 3] and final.touching[2, 3]  # Both standing on the platform.


def test_movable_one_way_body_rests_on_the_floor_and_carries_a_box(runs):
  final, _ = runs["movable_one_way"]
  np.testing.assert_allclose(final.pos[1:3, 1], [0.5, 1.5], **TOL["exact_f32"])
  np.testing.assert_allclose(final.vel[1:3], 0.0, atol=1e-6)


# --- Collision layers --------------------------------------------------------------------


def test_layers_that_do_not_collide_pass_through(runs):
  final, _ = runs["layers_apart"]
  np.testing.assert_allclose(final.pos[1:3, 1], [0.5, 0.5], **TOL["exact_f32"])  # Both on the floor.
  assert final.touching[2].tolist() == [False, False, False, True]  # Only the floor.


def test_layers_that_collide_stack(runs):
  final, _ = runs["layers_meet"]
  np.testing.assert_allclose(final.pos[1:3, 1], [0.5, 1.5], **TOL["exact_f32"])


def test_chain_stops_at_a_layer_it_does_not_share(runs):
  final, traj = runs["layers_chain"]
  # Player and box A move as one (the push shared over both masses); box B never moves.
  v = 6.0 * DT * np.arange(1, T + 1) / 2
  np.testing.assert_allclose(traj.vel[:, 0, 0], v, atol=1e-4)
  np.testing.assert_allclose(traj.vel[:, 1, 0], v, atol=1e-4)
  np.testing.assert_array_equal(traj.pos[:, 2], np.tile([2.0, 0.0], (T, 1)))
  assert final.pos[0, 0] > 2.5  # Both passed through B.
  assert not final.touching[2].any()


# --- Sensors ------------------------------------------------------------------------------


def test_sensor_sees_a_box_while_it_overlaps_and_never_pushes(runs):
  final, traj = runs["sensor_sees_box"]
  x = 4.0 - 2.0 * DT * np.arange(1, T + 1)
  np.testing.assert_allclose(traj.pos[:, 1, 0], x, atol=1e-5)  # Not pushed.
  np.testing.assert_array_equal(traj.pos[:, 0], np.tile([2.0, 0.5], (T, 1)))  # Not moved.
  # Sensed in every step during which it overlaps: at the step's end or on the way there
  # (the step from x = 1.067 to 1.033 leaves the goal: sensed, not overlapping at its end).
  before = np.concatenate([[4.0], x[:-1]])
  overlapping = (np.minimum(x, before) < 2.0 + 0.95) & (np.maximum(x, before) > 2.0 - 0.95)
  np.testing.assert_array_equal(traj.sensed[:, 0], overlapping)
  assert overlapping.sum() == (np.abs(x - 2.0) < 0.95).sum() + 1
  assert overlapping.any() and not overlapping.all()
  assert not traj.sensed[:, 1].any()  # Only sensors sense.


def test_sensor_does_not_see_a_body_its_mask_refuses(runs):
  final, traj = runs["sensor_ignores_player"]
  assert not traj.sensed.any()
  np.testing.assert_allclose(traj.pos[:, 1, 0], 4.0 - 2.0 * DT * np.arange(1, T + 1), atol=1e-5)


# --- Contact flags --------------------------------------------------------------------------


def test_flags_on_a_floor_and_against_a_wall(runs):
  final, traj = runs["against_wall"]
  np.testing.assert_allclose(final.pos[2], [1.0, 0.5], **TOL["exact_f32"])
  assert final.touching[2].tolist() == [True, False, False, True]  # Wall on the right, floor below.
  assert jc.grounded(final)[2] and jc.blocked(final)["right"][2]
  assert not jc.blocked(final)["left"][2]
  assert not final.touching[0].any() and not final.touching[1].any()  # Immovable: no rows.
  # Grounded from the first step on (it starts resting on the floor).
  assert traj.touching[:, 2, 3].all()


def test_trajectory_records_only_what_is_asked():
  w = SCENES["drop_on_platform"][0]
  _, traj = jc.rollout(w, CFG, 3)
  assert traj.status is None and traj.touching is None
  with pytest.raises(ValueError, match="record= takes names from"):
    jc.rollout(w, CFG, 3, record=("touch",))
  # A list or one name works too (made a hashable tuple for the compiled rollout).
  assert jc.rollout(w, CFG, 3, record=["touching"])[1].touching.shape == (3, N, 4)
  assert jc.rollout(w, CFG, 3, record="sensed")[1].sensed.shape == (3, N)


# --- The grid respects layers, sensors and one-way bodies --------------------------------


def test_grid_broadphase_gives_the_dense_answers(runs):
  names = ["drop_on_platform", "up_through_platform", "layers_apart", "layers_chain",
           "sensor_sees_box", "against_wall"]
  worlds = jc.stack([SCENES[k][0] for k in names])
  controls = jnp.asarray(np.stack([np.zeros((T, N, 2), np.float32) if SCENES[k][1] is None
                                   else SCENES[k][1] for k in names]))
  grid = jc.Config.for_world(worlds, broadphase="grid", depth=4, links=4, one_way=True,
                             layers=True, sensors=True)
  assert grid.uses_grid(N)
  _, traj = jax.jit(jax.vmap(lambda w, u: jc.rollout(w, grid, T, u, record=("touching", "sensed"))))(
      worlds, controls)
  for b, name in enumerate(names):
    want = runs[name][1]
    np.testing.assert_allclose(traj.pos[b], want.pos, atol=1e-5, err_msg=name)
    np.testing.assert_array_equal(traj.sensed[b], want.sensed, err_msg=name)
    np.testing.assert_array_equal(traj.touching[b], want.touching, err_msg=name)


# --- Levels end to end --------------------------------------------------------------------


def test_sokoban_box_pushed_onto_its_goal_is_sensed():
  level = levels.load("sokoban1")
  w = level.world()
  player, goal = level.player, level.tags["goal"][0]
  cfg = jc.Config.for_world(w)
  u = jnp.zeros_like(w.pos).at[player, 0].set(4.0)
  _, traj = jc.rollout(w, cfg, 90, u, record=("sensed",))
  box = level.tags["box"][0]
  sensed = np.asarray(traj.sensed[:, goal])
  box_x = np.asarray(traj.pos[:, box, 0])
  np.testing.assert_array_equal(sensed, np.abs(box_x - level.pos[goal, 0]) < 0.45 + 0.05)
  assert not sensed[0] and sensed[-1]  # Not at the start; on the goal at the end.
  np.testing.assert_allclose(box_x[-1], 5.0 - 0.45, atol=1e-5)  # Against the wall behind it.


def _climb(world, t):
  """Push right gently and jump whenever grounded (the demo's policy)."""
  del t
  up = jnp.where(jc.grounded(world)[_CLIMBER], 420.0, 0.0)  # A 7 u/s jump: 2.5 high.
  return jnp.zeros_like(world.pos).at[_CLIMBER].set(jnp.stack([jnp.asarray(2.0), up]))


_CLIMBER = levels.load("platformer1").player


def test_player_jumps_up_through_a_one_way_ledge_and_stands_on_it():
  level = levels.load("platformer1")
  ledge_top = 3.0  # The `===` of row 6: a slab at the top of the cell y in [2, 3].
  w = level.world(friction=0.3)
  _, traj = jc.rollout(w, jc.Config.for_world(w), 240, policy=_climb, record=("touching",))
  y = np.asarray(traj.pos[:, _CLIMBER, 1])
  standing = np.isclose(y, ledge_top + 0.4, atol=1e-4) & np.asarray(traj.touching[:, _CLIMBER, 3])
  assert standing.any()
  first = np.argmax(standing)
  assert (y[:first] < ledge_top - 0.4).any()  # It came from below the ledge.


def test_jump_example_jumps_only_when_grounded_and_reaches_a_ledge(capsys):
  spec = importlib.util.spec_from_file_location(
      "jump_example", pathlib.Path(__file__).resolve().parents[1] / "examples" / "jump.py")
  example = importlib.util.module_from_spec(spec)
  spec.loader.exec_module(example)
  assert example.main(["--worlds", "2", "--steps", "150"]) == 0
  out = capsys.readouterr().out
  assert out.count("stood on a one-way ledge: True") == 2 and "status: ok" in out


def test_demo_runs_a_level_and_rejects_an_unknown_one(capsys):
  figures = cli.demo(batch=2, steps=120, chunk=120, seed=0, depth=None, iterations=1,
                     friction=0.3, push=2.0, progress=False, level="sokoban1")
  assert figures["finite"] and figures["status_messages"] == {}
  assert figures["worlds_sensed"] == 2  # The box ends on its goal in both worlds.
  assert figures["max_penetration"] < 1e-4  # The goal sensor's overlap is not counted.
  with pytest.raises(SystemExit) as exit_info:
    cli.main(["demo", "--no-progress", "--level", "no_such_level"])
  assert exit_info.value.code == 2
  assert "no shipped level of that name" in capsys.readouterr().err


# --- Sensors see every overlap during a step (issue 18, item 3) ----------------------------


def _trip_wire(speed, wire_x=1.17):
  """A bullet (half 0.1) at `speed` along x towards a trip-wire sensor (half-width 0.05)."""
  return world(body([0.0, 0.0], 0.1, vel=[speed, 0.0]),
               body([wire_x, 0.0], [0.05, 1.0], INF, sensor=True), gravity=(0.0, 0.0))


def _crossing_steps(speed, steps, wire_x=1.17, reach=0.15):
  """Steps whose motion `[x(k-1), x(k)]` meets the open interval where the bullet
  overlaps the wire: `|x - wire_x| < reach`."""
  k = np.arange(1, steps + 1)
  x0, x1 = speed * DT * (k - 1), speed * DT * k
  return (x1 > wire_x - reach) & (x0 < wire_x + reach)


@pytest.mark.parametrize("speed", [20.0, 30.0])
def test_sensor_sees_a_bullet_crossing_a_trip_wire_under_substeps(speed):
  # for_world raises substeps for the thin wire; no substep ends with the bullet on the
  # wire's x at the end of a step, so a sensor read once per step never saw it.
  w = _trip_wire(speed)
  cfg = jc.Config.for_world(w)
  assert cfg.substeps > 1 and cfg.sensors
  _, traj = jc.rollout(w, cfg, 8, record=("sensed", "status"))
  want = _crossing_steps(speed, 8)
  assert want.sum() == 1  # The bullet crosses within one step.
  np.testing.assert_array_equal(np.asarray(traj.sensed[:, 1]), want)
  assert not np.asarray(traj.sensed[:, 0]).any()
  assert int(traj.status[-1]) == 0  # Substeps enough: no FAST_BODY.
  np.testing.assert_allclose(np.asarray(traj.pos[:, 0, 0]), speed * DT * np.arange(1, 9), rtol=1e-6)


def test_sensor_sweep_catches_a_crossing_within_one_substep():
  # One substep of 0.5: the bullet jumps from x = 0.5 to 1.0, over the whole wire (it
  # overlaps for 0.6 < x < 0.9), in one substep; FAST_BODY reports that it could
  # tunnel, and the swept test still sees the crossing.
  w = _trip_wire(30.0, wire_x=0.75)
  _, traj = jc.rollout(w, CFG, 3, record=("sensed", "status"))
  np.testing.assert_array_equal(np.asarray(traj.sensed[:, 1]), [False, True, False])
  np.testing.assert_array_equal(_crossing_steps(30.0, 3, wire_x=0.75), [False, True, False])
  assert int(traj.status[-1]) & jc.status.FAST_BODY


@pytest.mark.parametrize("begin, end, want", [
    ((-1.0, 0.0), (1.0, 0.0), True),     # Straight through.
    ((-1.0, 0.0), (-0.3, 0.0), False),   # Stops short.
    ((-1.0, 0.0), (-0.25, 0.0), False),  # Ends exactly touching: not strict.
    ((-1.0, 0.25), (1.0, 0.25), False),  # Slides along a face, exactly level: not strict.
    ((-1.0, 0.2), (1.0, 0.2), True),     # Overlaps in y throughout: crossing in x.
    ((-0.6, -0.6), (0.0, 0.6), True),    # Diagonal through the middle.
    ((-0.6, 0.0), (0.0, 0.6), False),    # Diagonal past the corner: x and y never overlap together.
    ((0.1, 0.1), (0.1, 0.1), True),      # At rest, overlapping.
    ((0.3, 0.1), (0.3, 0.1), False),     # At rest, apart.
])
def test_swept_overlap_of_a_straight_motion(begin, end, want):
  b = [jnp.float32(x) for x in begin]
  e = [jnp.float32(x) for x in end]
  r = [jnp.float32(0.25), jnp.float32(0.25)]
  assert bool(jc.core.flags.swept_overlap(b, e, r)) is want


# --- One-way bodies under crushes and margin snaps (issue 18, items 4 and 5) -------------

LEDGE = dict(pos=[0.0, -0.1], half=[3.0, 0.1], mass=INF, one_way=True)  # Top at y = 0.
ONE_WAY_SCENES = {
    # A box on a one-way ledge under a ceiling descending at 1 u/s (its bottom at y = 1).
    "crush_on_ledge": world(body([0.0, 0.5], 0.5), LEDGE,
                            body([0.0, 1.5], [3.0, 0.5], INF, vel=[0.0, -1.0])),
    # A box on a one-way elevator (top at y = 0) rising at 1 u/s into a ceiling at y = 1.5.
    "crush_on_elevator": world(body([0.0, 0.5], 0.5), dict(LEDGE, half=[2.0, 0.1], vel=[0.0, 1.0]),
                               body([0.0, 2.0], [5.0, 0.5], INF)),
    # A box of mass 80 rising at 0.3 with its bottom 0.03 below a one-way top (the margin).
    "rising_in_margin": world(body([0.0, 0.47], 0.5, 80.0, vel=[0.0, 0.3]), LEDGE),
    # The same box coming down with its bottom 0.02 below the top: it lands on it.
    "landing_in_margin": world(body([0.0, 0.48], 0.5, 80.0, vel=[0.0, -0.3]), LEDGE),
}
# The elevator of crush_on_elevator stopped after 60 steps (its top at 1, the box
# crushed 0.25 deep into both): the box keeps the crush's mean velocity, +0.5, upward
# relative to the stopped elevator, and must still be held.
ONE_WAY_SCENES["crush_on_stopped_elevator"] = ONE_WAY_SCENES["crush_on_elevator"]
T_CRUSH = 90
STOP = 60
ONE_WAY_CONTROLS = {"crush_on_stopped_elevator": (1, STOP, -1.0 / DT)}  # body, step, accel y.


@pytest.fixture(scope="module")
def one_way_runs():
  """Every one-way scene's `(start, trajectory)`, from one compiled, vmapped rollout."""
  worlds = jc.stack(list(ONE_WAY_SCENES.values()))
  controls = np.zeros((len(ONE_WAY_SCENES), T_CRUSH, N, 2), np.float32)
  for b, name in enumerate(ONE_WAY_SCENES):
    if name in ONE_WAY_CONTROLS:
      k, t, a = ONE_WAY_CONTROLS[name]
      controls[b, t, k, 1] = a
  run = jax.jit(jax.vmap(lambda w, u: jc.rollout(w, CFG, T_CRUSH, u,
                                                 record=("crushed", "status"))[1]))
  traj = run(worlds, jnp.asarray(controls))
  pick = lambda tree, b: jax.tree.map(lambda x: np.asarray(x[b]), tree)
  return {name: (w, pick(traj, b)) for b, (name, w) in enumerate(ONE_WAY_SCENES.items())}


def _energy(world, pos, vel):
  inv = np.asarray(world.inv_mass, np.float64)
  m = np.where(inv > 0, 1.0 / np.where(inv > 0, inv, 1.0), 0.0) * np.asarray(world.active)
  v, p = np.asarray(vel, np.float64), np.asarray(pos, np.float64)
  return np.sum(0.5 * m * np.sum(v * v, axis=-1), axis=-1) + 9.81 * np.sum(m * p[..., 1], axis=-1)


def test_box_crushed_onto_a_one_way_ledge_stays_centred_and_never_drops(one_way_runs):
  _, traj = one_way_runs["crush_on_ledge"]
  k = np.arange(1, T_CRUSH + 1)
  ceiling = 1.0 - k * DT  # Bottom face of the ceiling; the ledge's top is at 0.
  y = traj.pos[:, 0, 1]
  meet = 60  # The faces meet after 60 steps.
  # Centred between the two faces in every step of the squeeze: the crush rule's equal
  # split, and the ledge holds the box however deep it is pressed into it.
  np.testing.assert_allclose(y[:meet], ceiling[:meet] / 2, atol=2e-5)
  assert traj.crushed[:meet, 0].all()
  assert traj.status[meet - 1] & jc.status.CRUSHED
  np.testing.assert_allclose(traj.vel[:meet, 0, 1], -0.5, atol=1e-5)  # The mean of its crushers.
  assert np.all(np.isfinite(traj.pos))


def test_box_on_a_one_way_elevator_rising_into_a_ceiling_stays_between(one_way_runs):
  _, traj = one_way_runs["crush_on_elevator"]
  k = np.arange(1, T_CRUSH + 1)
  lift = k * DT  # The elevator's top; the ceiling's bottom is at 1.5.
  y = traj.pos[:, 0, 1]
  np.testing.assert_allclose(y[:29], lift[:29] + 0.5, atol=2e-5)  # Riding it.
  np.testing.assert_allclose(y[31:89], (lift[31:89] + 1.5) / 2, atol=2e-5)  # Centred.
  assert traj.crushed[31:89, 0].all() and not traj.crushed[:29, 0].any()
  assert np.all((y[:89] > lift[:89]) & (y[:89] < 1.5))  # Never drops out, never passes.


def test_box_crushed_on_an_elevator_that_stops_is_still_held(one_way_runs):
  _, traj = one_way_runs["crush_on_stopped_elevator"]
  lift = traj.pos[:, 1, 1] + 0.1
  np.testing.assert_allclose(lift[STOP:], 1.0, atol=1e-5)  # Stopped at step 60.
  np.testing.assert_allclose(traj.pos[STOP - 1:, 0, 1], 1.25, atol=2e-5)  # Centred, held.
  np.testing.assert_allclose(traj.vel[STOP + 1:, 0, 1], 0.0, atol=1e-5)
  assert traj.crushed[STOP:, 0].all()


def test_box_rising_within_the_one_way_margin_is_not_lifted_onto_it(one_way_runs):
  w, traj = one_way_runs["rising_in_margin"]
  vy = 0.3 - 9.81 * DT
  # Free flight in the first step: no snap onto the ledge (it was +20.7 J).
  np.testing.assert_allclose(traj.pos[0, 0, 1], 0.47 + vy * DT, atol=1e-6)
  np.testing.assert_allclose(traj.vel[0, 0, 1], vy, atol=1e-6)
  e0, e1 = _energy(w, w.pos, w.vel), _energy(w, traj.pos[0], traj.vel[0])
  assert e1 <= e0 + 1e-3, e1 - e0
  assert int(traj.status[0]) == 0


def test_one_way_snaps_are_counted_as_penetration_and_bounded_by_it(one_way_runs):
  # Every step of both margin scenes: the energy gained is at most m g times the
  # penetration at the start (`metrics.max_penetration` counts a sink within the
  # one-way margin); the snap happens only to a body that is not rising.
  for name in ("rising_in_margin", "landing_in_margin"):
    w, traj = one_way_runs[name]
    pos = np.concatenate([np.asarray(w.pos)[None], traj.pos])
    vel = np.concatenate([np.asarray(w.vel)[None], traj.vel])
    e = _energy(w, pos, vel)
    pen = np.array([float(jc.metrics.max_penetration(w.replace(pos=jnp.asarray(p)))) for p in pos[:6]])
    for t in range(5):
      assert e[t + 1] - e[t] <= 80.0 * 9.81 * pen[t] + 1e-3, (name, t, e[t + 1] - e[t], pen[t])
    np.testing.assert_allclose(traj.pos[-1, 0, 1], 0.5, atol=1e-5)  # Both end on the ledge.
  w, _ = one_way_runs["landing_in_margin"]
  np.testing.assert_allclose(float(jc.metrics.max_penetration(w)), 0.02, atol=1e-6)


def test_reference_mirrors_the_one_way_rule(one_way_runs):
  exact = CFG.replace(iterations=3, depth=12)
  step = jax.jit(lambda w: jc.step(w, exact))
  for name in ONE_WAY_SCENES:
    w = ONE_WAY_SCENES[name]
    n = int(np.sum(np.asarray(w.active)))
    inv = np.asarray(w.inv_mass, np.float64)[:n]
    mass = np.where(inv > 0, 1.0 / np.where(inv > 0, inv, 1.0), INF)
    pos, vel = np.asarray(w.pos, np.float64)[:n], np.asarray(w.vel, np.float64)[:n]
    for _ in range(40):
      pos, vel = jc.reference.step(pos, vel, np.asarray(w.half)[:n], mass,
                                   one_way=np.asarray(w.one_way)[:n])
      w = step(w)
      np.testing.assert_allclose(np.asarray(w.pos)[:n], pos, atol=2e-5, err_msg=name)
      np.testing.assert_allclose(np.asarray(w.vel)[:n], vel, atol=2e-4, err_msg=name)
