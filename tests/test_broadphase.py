"""Grid broadphase: same contacts and answers as dense pairs, overflow never silent."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

import jaxchain as jc
from jaxchain import broadphase, geometry, scenes, status
from tests.helpers import TOL, mixed_room as room

N = 32  # Every scene is padded to this: one compile per config.
SKIN = 1e-4
# One fixed layout for a 12 x 12 room, so hypothesis examples share compiled code.
SPEC = jc.GridSpec(origin=(-2.0, -2.0), cell=1.0 + SKIN, shape=(16, 16), reach=0.5,
                   cell_capacity=8, static_capacity=8, static_entries=512)
GRID = jc.Config(gravity=False, depth=6, iterations=2, broadphase="grid", grid=SPEC)
DENSE = GRID.replace(broadphase="dense")


grid_fn = jax.jit(broadphase.grid, static_argnames=("spec", "skin"))
contacts_fn = jax.jit(geometry.contacts, static_argnames="skin")


def links(world, cand):
  c = contacts_fn(world.pos, world.half, cand, SKIN)
  idx = np.asarray(cand.partner_index())
  out = set()
  for i, k in zip(*np.nonzero(np.asarray(c.link))):
    if bool(world.movable[i]):
      out.add((int(i), int(idx[i, k]), int(c.direction[i, k]), round(float(c.depth[i, k]), 6)))
  return out


@given(st.integers(0, 2**31 - 1))
def test_grid_finds_the_same_contacts_as_dense(seed):
  world = room(seed).world().pad(N)
  cand, code = grid_fn(world.pos, world.half, world.active, world.movable, SPEC, SKIN)
  assert int(code) == 0
  assert links(world, cand) == links(world, broadphase.dense(world.active))


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
  np.testing.assert_array_equal(out.status, [0, status.CELL_OVERFLOW])
  assert len(jc.check(out)) == 1 and jc.check(out)[0].startswith("world 1:")
  again = jc.step(jc.World.create([[0.2, 0.2]], [0.1, 0.1], 1.0, gravity=(0.0, 0.0)).replace(
      status=jnp.asarray(status.CELL_OVERFLOW, jnp.int32)), cfg)
  assert int(again.status) == status.CELL_OVERFLOW  # Kept until the user clears it.


def test_padded_inactive_bodies_never_enter_the_grid():
  world = room(5).world().pad(N)
  # Pile the padding onto one cell next to a box: capacity 8 would overflow if entered.
  world = world.replace(pos=world.pos.at[27:].set(world.pos[10]))
  cand, code = grid_fn(world.pos, world.half, world.active, world.movable, SPEC, SKIN)
  assert int(code) == 0
  listed = np.asarray(cand.partner_index())[np.asarray(cand.mask)]
  assert not np.isin(listed, np.arange(27, N)).any()
  assert not np.asarray(cand.mask)[27:].any()


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
  assert links(world, cand) == links(world, broadphase.dense(world.active))


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
