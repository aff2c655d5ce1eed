"""Grid broadphase: same contacts and answers as dense pairs, overflow never silent."""

import functools
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

import jaxchain as jc
from jaxchain import broadphase, core, scenes, sizing, status
from tests.helpers import TOL, bodies_of, contact_set, dense_candidates, mixed_room as room, xy

N = 32  # Every scene is padded to this: one compile per config.
SKIN = 1e-4
# One fixed layout for a 12 x 12 room, so hypothesis examples share compiled code.
SPEC = jc.GridSpec(origin=(-2.0, -2.0), cell=1.0 + SKIN, shape=(16, 16), reach=0.5,
                   cell_capacity=8, static_capacity=8, static_entries=512)
GRID = jc.Config(gravity=False, depth=6, iterations=2, broadphase="grid", grid=SPEC)
DENSE = GRID.replace(broadphase="dense")


@functools.partial(jax.jit, static_argnames=("spec", "skin"))
def grid_fn(pos, half, active, movable, spec, skin):
  """The core's grid table of one world: `([m, n, 1] candidates, status)`."""
  cand, code = core.pairs.grid(xy(pos), xy(half), active[:, None], movable[:, None], spec, skin)
  return cand, code[0]


def links(world, cand):
  return contact_set(world, cand, SKIN)


@given(st.integers(0, 2**31 - 1))
def test_grid_finds_the_same_contacts_as_dense(seed):
  world = room(seed).world().pad(N)
  cand, code = grid_fn(world.pos, world.half, world.active, world.movable, SPEC, SKIN)
  assert int(code) == 0
  assert links(world, cand) == links(world, dense_candidates(world))


@given(st.integers(0, 2**31 - 1))
def test_grid_and_dense_resolve_to_the_same_positions(seed):
  world = room(seed).world(gravity=(0.0, 0.0)).pad(N)
  grid, dense = jc.resolve(world, GRID), jc.resolve(world, DENSE)
  np.testing.assert_allclose(grid.pos, dense.pos, **TOL["equivariance"])
  # Boxes overlapping between tiles and walls may be crushed; the grid must see the
  # same crushes and report nothing of its own.
  np.testing.assert_array_equal(grid.crushed, dense.crushed)
  assert int(grid.status) == int(dense.status) and int(grid.status) & ~jc.status.CRUSHED == 0


def test_grid_and_dense_rollouts_agree():
  world = room(11).world(friction=0.4).pad(N)
  cfg = GRID.replace(gravity=True, friction=True, iterations=1)
  grid, _ = jc.rollout(world, cfg, 30)
  dense, _ = jc.rollout(world, cfg.replace(broadphase="dense"), 30)
  np.testing.assert_allclose(grid.pos, dense.pos, atol=1e-4)
  assert int(grid.status) == 0


def test_long_floor_neither_grows_the_cell_nor_misses_contacts():
  # A floor 100 long and 200 unit boxes resting on it: cells stay box-sized.
  xs = np.arange(200) * 0.5 - 49.75
  pos = np.r_[[[0.0, -0.5]], np.stack([xs, np.full(200, 0.2)], -1)]  # Boxes sunk 0.05.
  half = np.r_[[[50.0, 0.5]], np.full((200, 2), 0.25)]
  world = jc.World.create(pos, half, np.r_[np.inf, np.ones(200)], gravity=(0.0, 0.0))
  spec = broadphase.allocate(world)
  assert spec.cell < 1.0 and spec.row_size < 64
  cfg = jc.Config(gravity=False, depth=2, broadphase="grid", grid=spec)
  out = jc.resolve(world, cfg)
  assert int(out.status) == 0
  np.testing.assert_allclose(out.pos[1:, 1], 0.25, atol=1e-6)  # All lifted onto the floor.


def test_full_cell_is_reported():
  pos = np.array([[0.2, 0.2], [0.3, 0.6], [0.7, 0.4]])  # Three boxes in cell (0, 0).
  world = jc.World.create(pos, [0.1, 0.1], 1.0, gravity=(0.0, 0.0))
  spec = jc.GridSpec(origin=(0.0, 0.0), cell=1.0, shape=(4, 4), reach=0.5, cell_capacity=2)
  out = jc.resolve(world, jc.Config(gravity=False, broadphase="grid", grid=spec))
  assert int(out.status) & status.CELL_OVERFLOW
  assert "cell_capacity" in jc.check(out)[0]
  ok = jc.resolve(world, jc.Config(gravity=False, broadphase="grid",
                                   grid=spec.__class__(**{**spec.__dict__, "cell_capacity": 3})))
  assert int(ok.status) == 0


def test_full_static_table_and_too_large_bodies_are_reported():
  world = room(3).world(gravity=(0.0, 0.0))
  small = jc.GridSpec(**{**SPEC.__dict__, "static_entries": 8})
  out = jc.resolve(world, GRID.replace(grid=small))
  assert int(out.status) == status.STATIC_OVERFLOW
  narrow = jc.GridSpec(**{**SPEC.__dict__, "static_capacity": 1})
  assert int(jc.resolve(world, GRID.replace(grid=narrow)).status) & status.STATIC_OVERFLOW
  big = world.replace(half=world.half.at[-1].set(0.8))  # A movable box wider than reach.
  assert int(jc.resolve(big, GRID).status) == status.BODY_TOO_LARGE


def test_status_is_sticky_and_per_world_under_vmap():
  good = jc.World.create([[0.2, 0.2], [3.0, 3.0]], [0.1, 0.1], 1.0, gravity=(0.0, 0.0))
  bad = jc.World.create([[0.2, 0.2], [0.3, 0.3]], [0.1, 0.1], 1.0, gravity=(0.0, 0.0))
  spec = jc.GridSpec(origin=(0.0, 0.0), cell=1.0, shape=(4, 4), reach=0.5, cell_capacity=1)
  cfg = jc.Config(gravity=False, broadphase="grid", grid=spec)
  out = jax.vmap(lambda w: jc.rollout(w, cfg, 3)[0])(jc.stack([good, bad]))
  # The full cell hid the pair from the passes, so its overlap is also left (OVERLAP_LEFT).
  np.testing.assert_array_equal(out.status, [0, status.CELL_OVERFLOW | status.OVERLAP_LEFT])
  assert len(jc.check(out)) == 2 and all(line.startswith("world 1:") for line in jc.check(out))
  again = jc.step(jc.World.create([[0.2, 0.2]], [0.1, 0.1], 1.0, gravity=(0.0, 0.0)).replace(
      status=jnp.asarray(status.CELL_OVERFLOW, jnp.int32)), cfg)
  assert int(again.status) == status.CELL_OVERFLOW  # Kept until the user clears it.


def test_padded_inactive_bodies_never_enter_the_grid():
  world = room(5).world().pad(N)
  # Pile the padding onto one cell next to a box: capacity 8 would overflow if entered.
  world = world.replace(pos=world.pos.at[27:].set(world.pos[10]))
  cand, code = grid_fn(world.pos, world.half, world.active, world.movable, SPEC, SKIN)
  assert int(code) == 0
  listed = np.asarray(cand.index())[np.asarray(cand.mask)]
  assert not np.isin(listed, np.arange(27, N)).any()
  assert not np.asarray(cand.mask)[:, 27:].any()


def test_vmap_over_worlds_of_different_layouts():
  worlds = [room(s, n_boxes=n).world(gravity=(0.0, 0.0)) for s, n in ((1, 5), (2, 20), (3, 12))]
  batch = jc.stack(worlds, capacity=N)
  spec = broadphase.allocate(batch)
  cfg = GRID.replace(grid=spec)
  out = jax.vmap(jc.resolve, in_axes=(0, None))(batch, cfg)
  np.testing.assert_array_equal(out.status, 0)
  for b, w in enumerate(worlds):
    np.testing.assert_allclose(out.pos[b, : w.num_bodies], jc.resolve(w, DENSE).pos,
                               **TOL["equivariance"])


def test_bodies_outside_the_grid_are_clamped_not_lost():
  pos = np.array([[-50.0, 0.0], [-49.2, 0.0], [60.0, 60.0]])  # Far outside a 4 x 4 grid.
  world = jc.World.create(pos, [0.5, 0.5], 1.0, gravity=(0.0, 0.0))
  spec = jc.GridSpec(origin=(0.0, 0.0), cell=1.0 + SKIN, shape=(4, 4), reach=0.5)
  out = jc.resolve(world, jc.Config(gravity=False, broadphase="grid", grid=spec))
  np.testing.assert_allclose(out.pos[:2, 0], [-50.1, -49.1], atol=1e-5)


def test_allocate_sizes_from_the_scene():
  world = room(4).world()
  spec = broadphase.allocate(world)
  assert spec.reach == pytest.approx(float(np.max(np.asarray(world.half)[4 + 3:])), rel=1e-6)
  assert spec.cell >= 2 * spec.reach
  cand, code = grid_fn(world.pos, world.half, world.active, world.movable, spec, SKIN)
  assert int(code) == 0
  assert links(world, cand) == links(world, dense_candidates(world))


def test_config_rejects_grid_without_spec():
  with pytest.raises(ValueError, match="'grid' needs Config.grid"):
    jc.Config(broadphase="grid")
  with pytest.raises(ValueError, match="GridSpec.cell_capacity"):
    jc.GridSpec(origin=(0, 0), cell=1.0, shape=(2, 2), reach=0.5, cell_capacity=0)


def test_for_world_picks_the_broadphase_by_size_and_crowding():
  rng = np.random.default_rng(0)
  small = scenes.box_room(rng, 100).world()
  assert jc.Config.for_world(small).broadphase == "dense"
  large = scenes.box_room(rng, 600).world()
  cfg = jc.Config.for_world(large)
  assert cfg.broadphase == "grid" and cfg.grid.row_size < 100
  assert jc.Config.for_world(large, broadphase="dense").grid is None  # Overrides win.
  pile = jc.World.create(rng.uniform(0, 2, (600, 2)), [0.1, 0.1], 1.0)  # 600 boxes, 2 x 2 area.
  assert jc.Config.for_world(pile).broadphase == "dense"  # Too crowded for cells to help.
  assert jc.Config.for_world(pile, broadphase="grid").broadphase == "grid"


# --- Neighbour tables (Config.neighbors): exact, or a status bit ------------------------

NB = 16  # Neighbour-table scenes are padded to this.
WIDTH = 6  # Narrower than the row: the table really compacts.
NEAR = jc.Config(gravity=False, depth=6, iterations=2, broadphase="dense", neighbors=WIDTH,
                 margin=0.3)
FAR = NEAR.replace(neighbors=None, margin=0.0)


@st.composite
def small_rooms(draw, max_boxes=9):
  """A 6 x 6 walled room with up to `max_boxes` movable boxes, overlapping or not."""
  k = draw(st.integers(1, max_boxes))
  coord = st.floats(0.375, 5.625, width=32)
  size = st.floats(0.125, 0.625, width=32)
  pos = [[3.0, -0.5], [3.0, 6.5], [-0.5, 3.0], [6.5, 3.0]]
  half = [[4.0, 0.5], [4.0, 0.5], [0.5, 3.0], [0.5, 3.0]]
  pos += [[draw(coord), draw(coord)] for _ in range(k)]
  half += [[draw(size), draw(size)] for _ in range(k)]
  mass = [np.inf] * 4 + [draw(st.sampled_from([0.5, 1.0, 2.0])) for _ in range(k)]
  vel = [[0.0, 0.0]] * 4 + [[draw(st.floats(-3, 3, width=32)), draw(st.floats(-3, 3, width=32))]
                            for _ in range(k)]
  return jc.World.create(pos, half, mass, vel=vel, gravity=(0.0, -9.81), friction=0.3).pad(NB)


def partners_within(world, reach):
  """Host count of each movable body's partners within `reach` on both axes."""
  p, h = np.asarray(world.pos, np.float64), np.asarray(world.half, np.float64)
  active, movable = np.asarray(world.active), np.asarray(world.movable)
  gap = np.abs(p[:, None] - p[None]) - (h[:, None] + h[None])
  near = np.all(gap <= reach, -1) & active[None] & movable[:, None] & ~np.eye(len(p), dtype=bool)
  return near.sum(1)


@functools.partial(jax.jit, static_argnames="config")
def build_fn(pos, world, config):
  """The core's neighbour table of one world at `pos`, its rows read as `[n, w]`."""
  return core.pairs.build(xy(pos), bodies_of(world), config)


def rows(table):
  """`(idx, mask)` of a neighbour table of one world, `[n, w]` each."""
  return (np.asarray(table.cand.idx)[..., 0].T, np.asarray(table.cand.mask)[..., 0].T)


def candidates_at(pos, world, config, table):
  """The table a pass at `pos` reads, and its status (one world)."""
  cand, code = core.pairs.candidates(xy(pos), bodies_of(world), config, table)
  return cand, code[0]


@given(small_rooms())
def test_neighbor_table_resolves_exactly_as_dense_pairs(world):
  near, far = jc.resolve(world, NEAR), jc.resolve(world, FAR)
  overflow = int(near.status) & status.NEIGHBOR_OVERFLOW
  # No silent miss: the bit is set exactly when some row has more partners than fit.
  reach = broadphase.neighbor_reach(NEAR.skin, NEAR.margin)
  assert bool(overflow) == bool(np.max(partners_within(world, reach)) > WIDTH)
  if int(near.status) & (status.NEIGHBOR_OVERFLOW | status.NEIGHBOR_MARGIN):
    return
  # Same pairs in the same order (body order): the same answer, bit for bit.
  np.testing.assert_array_equal(near.pos, far.pos)
  np.testing.assert_array_equal(near.touching, far.touching)
  np.testing.assert_array_equal(near.crushed, far.crushed)
  assert int(near.status) == int(far.status)


@given(small_rooms())
def test_neighbor_table_steps_exactly_as_dense_pairs(world):
  cfg = NEAR.replace(gravity=True, iterations=1, substeps=2)
  near, far = jc.step(world, cfg), jc.step(world, cfg.replace(neighbors=None, margin=0.0))
  if int(near.status) & (status.NEIGHBOR_OVERFLOW | status.NEIGHBOR_MARGIN):
    reach = broadphase.neighbor_reach(cfg.skin, cfg.margin)
    assert (np.max(partners_within(world, reach)) > WIDTH - 2
            or int(near.status) & status.NEIGHBOR_MARGIN)
    return
  np.testing.assert_array_equal(near.pos, far.pos)
  np.testing.assert_array_equal(near.vel, far.vel)
  assert int(near.status) == int(far.status)


@given(small_rooms())
def test_neighbor_rows_are_the_partners_within_the_margin_in_body_order(world):
  table = build_fn(world.pos, world, NEAR)
  reach = broadphase.neighbor_reach(NEAR.skin, NEAR.margin)
  p, h = np.asarray(world.pos, np.float64), np.asarray(world.half, np.float64)
  idx, mask = rows(table)
  for i in range(NB):
    want = [j for j in range(NB) if j != i and bool(world.active[j]) and bool(world.movable[i])
            and np.all(np.abs(p[j] - p[i]) - (h[i] + h[j]) <= reach)]
    got = idx[i][mask[i]].tolist()
    if len(want) <= WIDTH:
      assert got == want
    else:
      assert got == want[:WIDTH] and int(table.code[0]) & status.NEIGHBOR_OVERFLOW


def test_full_neighbor_row_is_reported():
  # One box with 8 touching neighbours and a table of 6.
  pos = [[x, y] for y in (0.0, 1.0, 2.0) for x in (0.0, 1.0, 2.0)]
  world = jc.World.create(pos, [0.5, 0.5], 1.0, gravity=(0.0, 0.0))
  cfg = jc.Config(gravity=False, neighbors=6, margin=0.1)
  out = jc.resolve(world, cfg)
  assert int(out.status) == status.NEIGHBOR_OVERFLOW
  assert any("Config.neighbors" in line for line in jc.check(out))
  assert int(jc.resolve(world, cfg.replace(neighbors=8)).status) == 0


def test_motion_past_half_the_margin_is_reported_not_missed():
  # Two boxes 0.5 apart; the table is built with margin 0.6, and then box 1 moves 0.45
  # (more than 0.3) towards box 0: they touch, and the table must say it may be stale.
  world = jc.World.create([[0.0, 0.0], [1.5, 0.0]], [0.5, 0.5], 1.0, gravity=(0.0, 0.0))
  cfg = jc.Config(gravity=False, neighbors=4, margin=0.6)
  table = build_fn(world.pos, world, cfg)
  assert rows(table)[1][0].sum() == 1  # 0.5 apart: within the margin.
  moved = world.pos.at[1, 0].set(1.05)
  _, code = candidates_at(moved, world, cfg, table)
  assert int(code) == status.NEIGHBOR_MARGIN
  _, code = candidates_at(world.pos.at[1, 0].set(1.25), world, cfg, table)
  assert int(code) == 0  # 0.25 < 0.3: still exact.
  # A pair outside the margin at the build that then meets: the bit, never a silent miss.
  narrow = cfg.replace(margin=0.2)
  table = build_fn(world.pos, world, narrow)
  assert not np.asarray(table.cand.mask).any()
  cand, code = candidates_at(moved, world, narrow, table)
  assert int(code) == status.NEIGHBOR_MARGIN and not np.asarray(cand.mask).any()


def test_a_second_pass_past_the_margin_sets_the_bit():
  # Box 1 sunk 0.4 into box 0 against a wall: the first pass moves it 0.4, more than
  # margin / 2 = 0.05, and the second pass reads the table built before it.
  world = jc.World.create([[-1.0, 0.0], [0.0, 0.0], [0.6, 0.0]], [0.5, 0.5],
                          [np.inf, 1.0, 1.0], gravity=(0.0, 0.0))
  cfg = jc.Config(gravity=False, depth=3, iterations=2, neighbors=4, margin=0.1)
  out = jc.resolve(world, cfg)
  assert int(out.status) & status.NEIGHBOR_MARGIN
  wide = jc.resolve(world, cfg.replace(margin=1.0))
  assert int(wide.status) == 0
  np.testing.assert_array_equal(wide.pos, jc.resolve(world, cfg.replace(neighbors=None)).pos)


def test_padded_inactive_bodies_never_enter_the_neighbor_table():
  world = room(5).world().pad(N)
  world = world.replace(pos=world.pos.at[27:].set(world.pos[10]))  # Padding piled on a box.
  cfg = jc.Config(neighbors=10, margin=0.2)
  table = build_fn(world.pos, world, cfg)
  idx, mask = rows(table)
  assert not np.isin(idx[mask], np.arange(27, N)).any()
  assert not mask[27:].any()
  assert not mask[np.asarray(~world.movable)].any()  # Immovable rows.


def test_neighbor_table_from_the_grid_matches_dense():
  world = room(7).world(friction=0.4).pad(N)
  sized = jc.Config.for_world(world, broadphase="grid", depth=6, neighbors=16)
  assert sized.margin > 1.0  # From the overlaps it starts with.
  cfg = jc.Config.for_world(world, broadphase="grid", depth=6, neighbors=16, margin=0.6)
  dense, _ = jc.rollout(world, cfg.replace(broadphase="dense", neighbors=None), 20)
  for c in (sized, cfg):
    assert c.grid.cell >= 2 * c.grid.reach + broadphase.grid_skin(SKIN, c.margin)
    grid_nb, _ = jc.rollout(world, c, 20)
    np.testing.assert_allclose(grid_nb.pos, dense.pos, atol=1e-6)
    # The margin for_world gives covers every use; 0.6 is too small for the closing
    # passes, which read the step's table after bodies were pushed out of deep overlaps:
    # flagged (and here the answer still matches).
    extra = 0 if c is sized else status.NEIGHBOR_MARGIN
    assert int(grid_nb.status) & ~status.CRUSHED == extra
  with pytest.raises(ValueError, match="a neighbour table with margin 3.0 needs cells"):
    jc.resolve(world, cfg.replace(margin=3.0))


def test_neighbor_table_under_vmap_and_grad_matches_dense():
  worlds = jc.stack([room(s, n_boxes=8).world(gravity=(0.0, 0.0)) for s in (1, 2)], capacity=NB)
  cfg = jc.Config(gravity=False, depth=4, neighbors=8, margin=0.2)

  def loss(pos, config):
    out = jax.vmap(jc.resolve, in_axes=(0, None))(worlds.replace(pos=pos), config)
    return jnp.sum(out.pos[..., 0] ** 2 + out.pos[..., 1])

  near = jax.jit(jax.grad(loss), static_argnums=1)(worlds.pos, cfg)
  far = jax.jit(jax.grad(loss), static_argnums=1)(worlds.pos, cfg.replace(neighbors=None))
  np.testing.assert_array_equal(near, far)
  assert np.all(np.isfinite(near))


def test_for_world_picks_and_sizes_the_neighbor_table():
  lattice = scenes.lattice_room(64, 0)
  world = jc.World.create(lattice.pos, lattice.half, lattice.mass, friction=0.5)
  cfg = jc.Config.for_world(world)
  assert cfg.neighbors == sizing.MIN_NEIGHBORS and cfg.margin == pytest.approx(0.25)
  assert cfg.broadphase == "dense" and cfg.links < cfg.neighbors
  assert jc.Config.for_world(world, neighbors=None).neighbors is None  # Overrides win.
  assert jc.Config.for_world(world, margin=0.4).margin == 0.4
  fast = world.replace(vel=world.vel.at[10].set([0.0, -6.0]))  # Speeds widen the margin.
  assert jc.Config.for_world(fast).margin == pytest.approx(4 * 2 * (6 + 9.81 / 60) / 60)
  faster = world.replace(vel=world.vel.at[10].set([0.0, -30.0]))  # Margin 4: rows of ~60.
  assert jc.Config.for_world(faster, substeps=1).neighbors is None
  big = scenes.lattice_room(256, 0)  # The grid: a table narrower than its rows of 22.
  big = jc.Config.for_world(jc.World.create(big.pos, big.half, big.mass, friction=0.5))
  assert big.broadphase == "grid" and big.neighbors == sizing.MIN_NEIGHBORS
  assert big.neighbors < big.grid.row_size
  small = scenes.platformer().scene.world()  # 14 bodies: a table of 12 would save nothing.
  assert jc.Config.for_world(small).neighbors is None
  final, _ = jc.rollout(world, cfg, 60)
  assert int(final.status) == 0


def test_swept_sensors_read_the_neighbor_table_without_missing_a_crossing():
  # A bullet (half 0.1) jumps 0.5 a step over a trip wire (half-width 0.05) at x = 0.75:
  # at no step's end does it overlap the wire. The table holds the swept boxes, so the
  # sensor sees the crossing in step 2, as with dense pairs, and the margin is not hit.
  world = jc.World.create([[0.0, 0.0], [0.75, 0.0]], [[0.1, 0.1], [0.05, 1.0]], [1.0, np.inf],
                          vel=[[30.0, 0.0], [0.0, 0.0]], sensor=[False, True],
                          gravity=(0.0, 0.0)).pad(4)
  cfg = jc.Config(gravity=False, friction=False, neighbors=2, margin=0.02)
  _, near = jc.rollout(world, cfg, 3, record=("sensed", "status"))
  _, far = jc.rollout(world, cfg.replace(neighbors=None), 3, record=("sensed", "status"))
  np.testing.assert_array_equal(np.asarray(near.sensed[:, 1]), [False, True, False])
  np.testing.assert_array_equal(near.sensed, far.sensed)
  np.testing.assert_array_equal(near.pos, far.pos)
  np.testing.assert_array_equal(near.status, far.status)  # FAST_BODY only, in both.


# --- A neighbour table carried across steps (rollout) --------------------------------

CARRY = NEAR.replace(gravity=True, iterations=1)


@functools.partial(jax.jit, static_argnames="config")
def step_fn(world, config):
  return jc.step(world, config)


@functools.partial(jax.jit, static_argnames="config")
def rollout_fn(world, config):
  return jc.rollout(world, config, 24, record=("status", "touching"))[1]


@given(small_rooms(), st.sampled_from([1, 2]))
def test_a_rollout_carrying_its_neighbor_table_steps_as_fresh_tables(world, substeps):
  # The rollout keeps its table while every body stays within margin / 2 of where it
  # was built; `jc.step` builds one every substep. The same answers, bit for bit.
  cfg = CARRY.replace(substeps=substeps)
  traj = rollout_fn(world, cfg)
  w = world
  for t in range(traj.pos.shape[0]):
    w = step_fn(w, cfg)
    np.testing.assert_array_equal(traj.pos[t], w.pos)
    np.testing.assert_array_equal(traj.vel[t], w.vel)
    np.testing.assert_array_equal(traj.touching[t], w.touching)
    assert int(traj.status[t]) == int(w.status)


@functools.partial(jax.jit, static_argnames="config")
def refresh_fn(table, pos, start, worlds, config):
  bodies = bodies_of(worlds)
  return core.pairs.refresh(table, pos, bodies, config, start)


def test_a_neighbor_table_is_kept_within_half_its_margin_and_rebuilt_past_it():
  a = jc.World.create([[0.0, 0.0], [1.5, 0.0], [0.0, 3.0]], [0.5, 0.5], 1.0, gravity=(0.0, 0.0))
  worlds = jc.stack([a, a.replace(pos=a.pos.at[2, 1].set(4.0))])
  cfg = jc.Config(gravity=False, neighbors=2, margin=0.6)
  pos = jnp.moveaxis(worlds.pos, (0, 2), (2, 0))  # [2, n, B]
  table = jax.jit(core.pairs.build, static_argnames="config")(pos, bodies_of(worlds), cfg)
  # Body 1 moves 0.29 < margin / 2 at the substep's end: the same table, in both worlds.
  near = pos.at[0, 1, :].add(-0.29)
  kept = refresh_fn(table, near, pos, worlds, cfg)
  np.testing.assert_array_equal(kept.ref, table.ref)
  # Past it in world 1 only: both worlds get a table built where the substep ends.
  far = near.at[0, 1, 1].add(-0.02)
  new = refresh_fn(table, far, pos, worlds, cfg)
  np.testing.assert_array_equal(new.ref, far)
  # Past it at the substep's start (a body the step before moved): rebuilt too.
  new = refresh_fn(table, pos, far, worlds, cfg)
  np.testing.assert_array_equal(new.ref, pos)
  # A table that was never built (a rollout's first step) is always rebuilt.
  empty = core.pairs.empty(bodies_of(worlds), cfg)
  fresh = refresh_fn(empty, pos, pos, worlds, cfg)
  np.testing.assert_array_equal(fresh.cand.mask, table.cand.mask)
  np.testing.assert_array_equal(fresh.cand.idx, table.cand.idx)


def test_a_cell_filling_up_gives_step_and_rollout_one_answer_and_no_flag():
  # Issue 44 item 6: a grid of cell capacity 2 with a neighbour table; box 2 drifts at
  # 1.5 u/s into the cell of boxes 0 and 1 (step 2) and hits box 1 (step 5). The step loop
  # builds its table every step: from step 2 the full cell dropped box 2 (CELL_OVERFLOW),
  # while the rollout kept its exact table (nothing set) until it rebuilt at step 4; and
  # both lost the pair 1-2, so box 2 stopped dead on box 1, which never moved. A full
  # cell is built again with RETRY times the capacity: both paths give the inelastic hit
  # (1 and 2 at -0.75 u/s), bit for bit, with no bit set.
  spec = broadphase.GridSpec(origin=(0.0, 0.0), cell=1.0, shape=(6, 6), reach=0.1,
                             cell_capacity=2, static_capacity=1, static_entries=4)
  cfg = jc.Config(gravity=False, friction=False, immovable=False, broadphase="grid", grid=spec,
                  neighbors=2, margin=0.2, depth=1, closing=0)  # The smallest step.
  world = jc.World.create([[2.3, 2.5], [2.7, 2.5], [3.05, 2.5]], [0.1, 0.1], 1.0,
                          vel=[[0.0, 0.0], [0.0, 0.0], [-1.5, 0.0]], gravity=(0.0, 0.0))
  steps = 8
  final, traj = jc.rollout(world, cfg, steps, record=("status",))
  w = world
  for t in range(steps):
    w = jc.step(w, cfg)
    assert int(w.status) == int(traj.status[t]) == 0, (t, int(w.status), int(traj.status[t]))
    assert np.array_equal(np.asarray(w.pos), np.asarray(traj.pos[t])), t
  np.testing.assert_allclose(np.asarray(final.vel)[:, 0], [0.0, -0.75, -0.75], atol=1e-6)
  assert float(final.pos[1, 0]) < 2.7 - 0.02  # Box 1 pushed along.
