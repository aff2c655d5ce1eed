"""Compact link tables: the same answers as the full candidate table, overflow never silent."""

import functools
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from jax.test_util import check_grads

import jaxchain as jc
from jaxchain import core, scenes, sizing, status
from tests.helpers import TOL, mixed_room

N = 32  # Every room is padded to this: one compile per config.
SPEC = jc.GridSpec(origin=(-2.0, -2.0), cell=1.0 + 1e-4, shape=(16, 16), reach=0.5,
                   cell_capacity=8, static_capacity=8, static_entries=512)
FULL = jc.Config(gravity=False, depth=6, iterations=2)
COMPACT = {"dense": FULL.replace(links=4),
           "grid": FULL.replace(links=4, broadphase="grid", grid=SPEC)}

@functools.partial(jax.jit, static_argnames="limit")
def first_set(sel, limit):
  """The core's compaction (`pairs.pack`, `pairs.peel`) along the last axis of `sel`:
  `(slot, valid, overflow)`, slot-major, overflow over everything."""
  words = core.pairs.pack(lambda k: sel[..., k], sel.shape[-1])
  slot, valid, rest = core.pairs.peel(words, limit)
  return slot, valid, jnp.any(rest)
measure = jax.jit(jax.vmap(lambda w: sizing.measure(
    w.pos, w.half, w.active, w.movable, spec=None, skin=1e-4, max_hops=N)[1]))


@pytest.mark.parametrize("m, limit", [(5, 3), (32, 2), (33, 4), (64, 4), (70, 6)])
@given(seed=st.integers(0, 2**31 - 1))
def test_first_set_finds_the_first_entries_of_each_row(m, limit, seed):
  # Word boundaries (32 bits a word) at 32, 33 and 64; rows from empty to full.
  rng = np.random.default_rng(seed)
  sel = rng.random((4, 6, m)) < rng.uniform(0, 1, (4, 6, 1))
  slot, valid, overflow = map(np.asarray, first_set(jnp.asarray(sel), limit=limit))
  slot, valid = np.moveaxis(slot, 0, -1), np.moveaxis(valid, 0, -1)  # Slot-major -> per row.
  for row in np.ndindex(4, 6):
    want = np.flatnonzero(sel[row])[:limit]
    np.testing.assert_array_equal(slot[row][valid[row]], want)
    assert not valid[row][len(want):].any() and (slot[row][~valid[row]] == 0).all()
  assert bool(overflow) == bool((sel.sum(-1) > limit).any())


def test_first_set_under_jit_and_vmap_matches_one_world_at_a_time():
  # The packing is an unrolled walk followed by peels in a scan; under vmap (the pattern
  # jax 0.10.2 miscompiles on CPU, jax-ml/jax#39103) batched must equal unbatched.
  sel = jnp.asarray(np.random.default_rng(0).random((16, 4, 12, 30)) < 0.2)
  batched = jax.jit(jax.vmap(lambda s: first_set(s, 3)))(sel)
  for b in range(sel.shape[0]):
    for got, want in zip(batched, first_set(sel[b], limit=3)):
      np.testing.assert_array_equal(got[b], want)


@pytest.mark.parametrize("broadphase_name", ["dense", "grid"])
@given(seed=st.integers(0, 2**31 - 1))
def test_compact_links_resolve_like_the_full_table(broadphase_name, seed):
  world = mixed_room(seed).world(gravity=(0.0, 0.0)).pad(N)
  compact = jc.resolve(world, COMPACT[broadphase_name])
  full = jc.resolve(world, FULL)
  overflowed = bool(compact.status & status.LINK_OVERFLOW)
  # The first pass sees the input: more than 4 links there must be reported.
  assert overflowed or int(measure(jc.stack([world]))[0]) <= 4
  if not overflowed:
    np.testing.assert_allclose(compact.pos, full.pos, **TOL["transform"])
    assert int(compact.status) == int(full.status)


def test_compact_rollout_with_gravity_and_friction_matches_the_full_table():
  world = scenes.platformer(np.random.default_rng(3)).scene.world(friction=0.4)
  cfg = jc.Config.for_world(world)
  assert cfg.links == 3  # The demo scene is compacted (boxes of half-width 0.4 to 0.6).
  final, traj = jc.rollout(world, cfg, 90, controls=jnp.zeros_like(world.pos).at[4, 0].set(20.0))
  full, full_traj = jc.rollout(world, cfg.replace(links=None), 90,
                               controls=jnp.zeros_like(world.pos).at[4, 0].set(20.0))
  np.testing.assert_allclose(traj.pos, full_traj.pos, **TOL["transform"])
  assert int(final.status) == int(full.status) == 0


def plank_on_boxes(boxes=6):
  """A movable plank resting, slightly sunk, on `boxes` unit boxes on a floor."""
  pos = [[0.0, -0.5], [boxes / 2, 1.45]] + [[0.5 + k, 0.5] for k in range(boxes)]
  half = [[50.0, 0.5], [boxes / 2, 0.5]] + [[0.5, 0.5]] * boxes
  return scenes.Scene(np.asarray(pos), np.asarray(half), np.r_[np.inf, 1.0, np.ones(boxes)])


def test_too_many_links_are_reported_not_silently_dropped():
  world = plank_on_boxes(6).world(gravity=(0.0, 0.0))
  cfg = jc.Config(gravity=False, depth=4)
  short = jc.resolve(world, cfg.replace(links=4))
  assert short.status & status.LINK_OVERFLOW
  assert any("Config.links" in line for line in jc.check(short))
  exact = jc.resolve(world, cfg)
  assert int(exact.status) == 0
  enough = jc.resolve(world, cfg.replace(links=6))
  assert int(enough.status) == 0
  np.testing.assert_allclose(enough.pos, exact.pos, **TOL["transform"])
  np.testing.assert_allclose(exact.pos[1, 1], 1.5, **TOL["exact_f32"])  # Plank lifted out.


def test_for_world_sizes_the_link_table_from_the_scene():
  # Boxes of one size: a face meets at most 2 boxes that do not overlap each other.
  room = scenes.lattice_room(16)
  assert jc.Config.for_world(room.world()).links == 2
  # The demo scene: half-widths 0.4 to 0.6 and heights 0.4 to 0.6 -> ceil(0.6 / 0.4) + 1.
  world = scenes.platformer().scene.world()
  assert jc.Config.for_world(world).links == 3 == sizing.link_bound(world)
  plank = plank_on_boxes(6)  # Its face of 6 can meet 7 unit boxes: 7 of a row of 8.
  assert jc.Config.for_world(plank.world()).links == 7
  lone = plank_on_boxes(1)._replace(half=np.array([[50.0, 0.5], [3.0, 0.5], [0.5, 0.5]]))
  assert sizing.link_bound(lone.world()) == 7  # Not below the row of 3: the whole row.
  assert jc.Config.for_world(lone.world()).links is None
  assert jc.Config.for_world(plank.world(), links=3).links == 3  # Overrides win.
  # A unit box on tiles a quarter wide: 4 under it, 5 when it straddles their seams.
  tiles = scenes.Scene(np.array([[0.125, -0.5], [0.375, -0.5], [0.5, 0.5]]),
                       np.array([[0.125, 0.5], [0.125, 0.5], [0.5, 0.5]]),
                       np.array([np.inf, np.inf, 1.0]))
  assert sizing.link_bound(tiles.world()) == 5
  # Thin one-way ledges (half-height 0.125) meet bodies along y only: along x only the
  # solid bodies count (unit boxes: 2), along y the ledges' widths (>= 1: 2).
  ledges = scenes.Scene(np.array([[0.0, -0.5], [3.0, 1.0], [3.0, 2.0], [0.5, 0.5]]),
                        np.array([[5.0, 0.5], [1.0, 0.125], [1.0, 0.125], [0.5, 0.5]]),
                        np.array([np.inf, np.inf, np.inf, 1.0]))
  one_way = jc.World.create(*ledges, one_way=[False, True, True, False])
  assert sizing.link_bound(one_way) == 2
  assert sizing.link_bound(ledges.world()) == 5  # As solid bodies: 0.5 / 0.125 + 1.
  # Nothing movable: no row needs a link.
  assert sizing.link_bound(tiles._replace(mass=np.full(3, np.inf)).world()) == 0


def test_a_staggered_landing_fits_the_width_for_world_picks():
  # A unit box falling onto two unit boxes side by side (offset by half): 2 links
  # down, the width `link_bound` gives; no overflow, and the same as the whole row.
  scene = scenes.Scene(np.array([[0.0, -0.5], [0.5, 0.5], [1.5, 0.5], [1.0, 1.6]]),
                       np.array([[5.0, 0.5], [0.5, 0.5], [0.5, 0.5], [0.5, 0.5]]),
                       np.array([np.inf, 1.0, 1.0, 1.0]))
  world = scene.world(friction=0.5)
  cfg = jc.Config.for_world(world)
  assert cfg.links == 2
  final, traj = jc.rollout(world, cfg, 30)
  full, full_traj = jc.rollout(world, cfg.replace(links=None), 30)
  assert int(final.status) == int(full.status) == 0
  np.testing.assert_array_equal(traj.pos, full_traj.pos)
  np.testing.assert_allclose(final.pos[3, 1], 1.5, atol=1e-4)  # Resting on both.


def test_compact_links_have_finite_difference_gradients():
  scene = scenes.push_chain(4, overlap=0.3, wall=False, masses=[1.0, 2.0, 0.5, 1.0, 3.0],
                            overlaps=[0.1, 0.2, 0.15])
  world = scene.world(gravity=(0.0, 0.0))
  cfg = jc.Config(depth=4, gravity=False, links=2)

  def f(pos, half):
    return jc.resolve(world.replace(pos=pos, half=half), cfg).pos

  check_grads(f, (world.pos, world.half), order=1, modes=["rev", "fwd"], eps=1e-2,
              atol=2e-2, rtol=2e-2)


@pytest.mark.parametrize("links", [0, -1, 2.5, True])
def test_bad_links_raise_a_clear_error(links):
  with pytest.raises(ValueError, match="Config.links: expected None or an integer >= 1"):
    jc.Config(links=links)
