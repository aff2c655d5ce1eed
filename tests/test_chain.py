"""The chain resolver: exact answers, invariants, equivalence with the reference,
and behaviour under jit, vmap and grad."""

import dataclasses

import chex
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

import jaxchain as jc
from jaxchain import reference, scenes
from tests.helpers import DEEP, TOL, pad_world, resolve_scene

masses_st = st.floats(0.1, 10.0)
overlap_st = st.floats(0.01, 0.4)


# --- Exact answers -----------------------------------------------------------------


@pytest.mark.parametrize("length", [1, 3, 8])
def test_push_chain_into_wall_moves_only_the_player(length):
  d = 0.25
  scene = scenes.push_chain(length, overlap=d, wall=True)
  got = resolve_scene(scene)
  want = scene.pos.copy()
  want[0, 0] -= d
  np.testing.assert_allclose(got, want, **TOL["exact_f32"])


def test_free_push_chain_unit_masses():
  L, d = 5, 0.3
  scene = scenes.push_chain(L, overlap=d, wall=False)
  dx = resolve_scene(scene)[:, 0] - scene.pos[:, 0]
  want = np.r_[-d * L / (L + 1), np.full(L, d / (L + 1))]
  np.testing.assert_allclose(dx, want, **TOL["exact_f32"])


def test_free_push_chain_mixed_masses_is_the_mass_weighted_projection():
  masses = np.array([2.0, 0.5, 3.0, 1.0, 0.25])
  overlaps = [0.1, 0.0, 0.05]  # Box-to-box overlaps too: every link is active.
  d = 0.2
  scene = scenes.push_chain(4, overlap=d, wall=False, masses=masses, overlaps=overlaps)
  dx = resolve_scene(scene)[:, 0] - scene.pos[:, 0]
  # Rigid solution: dx_i = c + cumulative overlap up to i, with sum m_i dx_i = 0.
  cum = np.cumsum(np.r_[0.0, d, overlaps])
  c = -np.sum(masses * cum) / np.sum(masses)
  np.testing.assert_allclose(dx, c + cum, **TOL["exact_f32"])


def test_stack_with_overlap_at_every_level_lifts_in_one_pass():
  overlaps = np.array([0.1, 0.05, 0.2, 0.01, 0.15, 0.3])
  scene = scenes.stack(len(overlaps), overlaps=overlaps, masses=[1e-3, 1, 100, 1, 1e3, 1])
  got = resolve_scene(scene)
  want = scene.pos.copy()
  want[1:, 1] += np.cumsum(overlaps)
  np.testing.assert_allclose(got, want, **TOL["exact_f32"])


def test_depth_below_chain_length_is_not_exact_in_one_pass():
  # A wall three links away is invisible with depth 1: the player shares the push.
  scene = scenes.push_chain(3, overlap=0.2, wall=True)
  shallow = resolve_scene(scene, jc.Config(depth=1, gravity=False))
  assert shallow[0, 0] > scene.pos[0, 0] - 0.2 + 1e-3
  assert np.max(np.abs(shallow[1:, 0] - scene.pos[1:, 0])) > 1e-3


def test_squeeze_between_walls_keeps_walls_fixed():
  # Box squeezed between two immovable walls: both units immovable, nothing moves.
  pos = np.array([[0.0, 0.0], [0.9, 0.0], [1.8, 0.0]])
  scene = scenes.Scene(pos, np.full((3, 2), 0.5), np.array([np.inf, 1.0, np.inf]))
  np.testing.assert_array_equal(resolve_scene(scene), pos.astype(np.float32))


# --- Invariants on random scenes -----------------------------------------------------


def _random_world(seed, n=10, immovable_fraction=0.0):
  rng = np.random.default_rng(seed)
  return scenes.random_boxes(rng, n, extent=3.0, immovable_fraction=immovable_fraction)


@given(st.integers(0, 2**31 - 1))
def test_immovable_bodies_move_by_exactly_zero(seed):
  scene = _random_world(seed, immovable_fraction=0.4)
  world = pad_world(scene)
  for config in (DEEP, dataclasses.replace(DEEP, depth=2, iterations=3)):
    out = jc.resolve(world, config)
    fixed = np.asarray(world.inv_mass == 0)
    np.testing.assert_array_equal(np.asarray(out.pos)[fixed], np.asarray(world.pos)[fixed])
    assert np.all(np.isfinite(np.asarray(out.pos)))


@given(st.integers(0, 2**31 - 1), st.permutations(range(10)))
def test_permutation_equivariance(seed, perm):
  perm = np.asarray(perm)
  scene = _random_world(seed, immovable_fraction=0.2)
  permuted = scenes.Scene(scene.pos[perm], scene.half[perm], scene.mass[perm])
  for config in (DEEP, dataclasses.replace(DEEP, depth=3)):
    np.testing.assert_allclose(resolve_scene(permuted, config), resolve_scene(scene, config)[perm],
                               **TOL["equivariance"])


@given(st.integers(1, 8), st.lists(masses_st, min_size=9, max_size=9), overlap_st,
       st.lists(st.floats(0.0, 0.2), min_size=7, max_size=7))
def test_centre_of_mass_kept_on_free_chains(length, masses, d, overlaps):
  scene = scenes.push_chain(length, overlap=d, wall=False, masses=masses[: length + 1],
                            overlaps=overlaps[: length - 1])
  got = resolve_scene(scene)
  m = scene.mass
  np.testing.assert_allclose(m @ got / m.sum(), m @ scene.pos / m.sum(), **TOL["reference"])


# --- Equivalence with the reference ----------------------------------------------------


@given(st.integers(1, 10), st.booleans(), st.lists(masses_st, min_size=11, max_size=11),
       overlap_st, st.lists(st.one_of(st.just(0.0), st.floats(0.0, 0.3)), min_size=9, max_size=9))
def test_matches_reference_on_chains(length, wall, masses, d, overlaps):
  scene = scenes.push_chain(length, overlap=d, wall=wall, masses=masses[: length + 1],
                            overlaps=overlaps[: length - 1])
  want = reference.resolve(scene.pos, scene.half, scene.mass)
  np.testing.assert_allclose(resolve_scene(scene), want, **TOL["reference"])


@given(st.integers(1, 4), st.integers(1, 4), st.booleans(),
       st.lists(masses_st, min_size=18, max_size=18), overlap_st)
def test_matches_reference_on_trees(rows, row_length, wall, masses, d):
  scene = scenes.comb(rows, row_length, overlap=d, masses=masses[: 2 + rows * row_length],
                      wall=wall)
  want = reference.resolve(scene.pos, scene.half, scene.mass)
  np.testing.assert_allclose(resolve_scene(scene), want, **TOL["reference"])


@given(st.integers(1, 12), st.lists(st.floats(0.0, 0.3), min_size=12, max_size=12),
       st.lists(st.sampled_from([1e-3, 1.0, 100.0, 1e4]), min_size=12, max_size=12))
def test_matches_reference_on_stacks(height, overlaps, masses):
  scene = scenes.stack(height, overlaps=overlaps[:height], masses=masses[:height])
  want = reference.resolve(scene.pos, scene.half, scene.mass)
  np.testing.assert_allclose(resolve_scene(scene), want, **TOL["reference"])


# --- The seed's point: the old pairwise system is order-dependent ---------------------


def test_old_system_is_order_dependent_and_chaining_is_not():
  scene = scenes.push_chain(3, overlap=0.3, wall=True)
  n = len(scene.pos)
  perm = np.arange(n)[::-1].copy()
  inverse = np.argsort(perm)
  old_a = reference.resolve_old(scene.pos, scene.half, scene.mass)
  old_b = reference.resolve_old(scene.pos[perm], scene.half[perm], scene.mass[perm])[inverse]
  assert np.max(np.abs(old_a - old_b)) > 0.05  # Visiting order changes the answer...
  permuted = scenes.Scene(scene.pos[perm], scene.half[perm], scene.mass[perm])
  np.testing.assert_allclose(resolve_scene(permuted)[inverse], resolve_scene(scene),
                             **TOL["equivariance"])  # ...but not for the chain resolver.
  # And the old system leaves the chain overlapping after one sweep.
  leftover = jc.metrics.max_penetration(jc.World.create(old_a, scene.half, scene.mass))
  assert leftover > 0.05


# --- Transforms ------------------------------------------------------------------------


def test_jit_equals_eager():
  world = pad_world(_random_world(3, immovable_fraction=0.2), capacity=12)
  config = jc.Config(depth=4, iterations=2, gravity=False)
  jitted = jc.resolve(world, config)
  with jax.disable_jit():
    eager = jc.resolve(world, config)
  chex.assert_trees_all_close(jitted, eager, **TOL["transform"])


def test_vmap_over_padded_batch_equals_one_world_at_a_time():
  rng = np.random.default_rng(7)
  worlds = [scenes.random_boxes(rng, n, extent=2.5, immovable_fraction=0.2).world()
            for n in (3, 7, 5)]
  batch = jc.stack(worlds)
  config = jc.Config(depth=4, iterations=2, gravity=False)
  out = jax.vmap(jc.resolve, in_axes=(0, None))(batch, config)
  for b, w in enumerate(worlds):
    n = w.num_bodies
    np.testing.assert_allclose(out.pos[b, :n], jc.resolve(w, config).pos, **TOL["transform"])
    np.testing.assert_array_equal(out.pos[b, n:], batch.pos[b, n:])  # Padding never moves.


def test_inactive_bodies_never_collide():
  scene = scenes.push_chain(2, overlap=0.3, wall=False)
  world = scene.world()
  world = dataclasses.replace(world, active=jnp.array([True, False, True]))
  out = jc.resolve(world, DEEP)
  np.testing.assert_array_equal(out.pos, world.pos)  # Player overlaps only the inactive box.


def test_second_call_does_not_recompile():
  world = pad_world(scenes.push_chain(3))
  config = jc.Config(depth=5, gravity=False)
  jc.resolve(world, config)
  size = jc.resolve._cache_size()
  shifted = dataclasses.replace(world, pos=world.pos + 0.01)
  jc.resolve(shifted, jc.Config(depth=5, gravity=False))  # Equal config, new instance.
  assert jc.resolve._cache_size() == size


def test_a_batch_resolves_as_its_worlds_do():
  # `resolve` takes a batch (`[B, n, ...]`) directly (issue 27), with the answers of the
  # vmapped call and of each world alone; a world of the wrong rank is a clear error.
  batch = jc.stack([scenes.push_chain(2).world(), scenes.push_chain(2, overlap=0.2).world()])
  got = jc.resolve(batch, DEEP)
  assert np.array_equal(np.asarray(got.pos), np.asarray(jax.vmap(jc.resolve, (0, None))(batch, DEEP).pos))
  for b in range(2):
    one = jc.resolve(jax.tree.map(lambda x: x[b], batch), DEEP)
    assert np.array_equal(np.asarray(got.pos[b]), np.asarray(one.pos))
  with pytest.raises(ValueError, match=r"pos of shape \(n, 2\)"):
    jc.resolve(jax.tree.map(lambda x: x[None], batch), DEEP)


# --- Gradients ---------------------------------------------------------------------------


@pytest.mark.parametrize("wall", [False, True])
def test_grad_on_free_chain_is_the_mass_fraction(wall):
  masses = np.array([1.5, 0.5, 2.0, 1.0])
  scene = scenes.push_chain(3, overlap=0.2, wall=wall, masses=masses)
  world = pad_world(scene)

  def final_player_x(x0):
    return jc.resolve(dataclasses.replace(world, pos=world.pos.at[0, 0].set(x0)), DEEP).pos[0, 0]

  g = jax.grad(final_player_x)(world.pos[0, 0])
  want = 0.0 if wall else masses[0] / masses.sum()  # Into a wall the player just backs off.
  np.testing.assert_allclose(g, want, **TOL["grad"])


GRAD_SCENES = {
    "chain_wall": scenes.push_chain(4, wall=True),
    "chain_free": scenes.push_chain(4, wall=False, overlaps=[0.1, 0.0, 0.2]),
    "stack": scenes.stack(5, overlaps=0.1),
    "tree": scenes.comb(3, 2),
    "coincident": scenes.Scene(np.array([[1.0, 1.0], [1.0, 1.0], [1.0, 1.0]]),
                               np.full((3, 2), 0.5), np.array([1.0, 2.0, np.inf])),
    "touching": scenes.Scene(np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0]]),
                             np.full((3, 2), 0.5), np.ones(3)),
}


@pytest.mark.parametrize("name", sorted(GRAD_SCENES))
def test_grad_is_finite(name):
  world = pad_world(GRAD_SCENES[name])
  config = jc.Config(depth=6, iterations=2, gravity=False)

  def loss(pos, half):
    out = jc.resolve(dataclasses.replace(world, pos=pos, half=half), config)
    return jnp.sum(out.pos**2)

  grads = jax.grad(loss, argnums=(0, 1))(world.pos, world.half)
  for g in grads:
    assert np.all(np.isfinite(np.asarray(g)))
  assert np.any(np.asarray(grads[0]) != 0)


def test_coincident_centres_separate_deterministically():
  # All three at (1, 1), masses (1, 2, inf). Ties go to x and the larger index lies at +x,
  # so body 2 (immovable) is in front of both others and body 1 in front of body 0: body 1
  # backs off by 1 (its whole overlap with 2) and pushes body 0, which backs off by 1 more.
  world = pad_world(GRAD_SCENES["coincident"])
  for iterations in (1, 4):
    out = np.asarray(jc.resolve(world, dataclasses.replace(DEEP, iterations=iterations)).pos)[:3]
    np.testing.assert_allclose(out, [[-1.0, 1.0], [0.0, 1.0], [1.0, 1.0]], **TOL["exact_f32"])


def test_a_body_pushed_by_two_bodies_moves_by_the_larger_push_not_the_sum():
  # A box straddling two immovable floor tiles, sunk 0.1 into each: lifted by 0.1 (max-plus).
  scene = scenes.Scene(np.array([[0.0, -0.5], [1.0, -0.5], [0.5, 0.4]]), np.full((3, 2), 0.5),
                       np.array([np.inf, np.inf, 1.0]))
  np.testing.assert_allclose(resolve_scene(scene)[2], [0.5, 0.5], **TOL["exact_f32"])
  np.testing.assert_allclose(reference.resolve(*scene)[2], [0.5, 0.5], atol=1e-12)


def test_immovable_bodies_never_move_even_with_immovable_tracking_off():
  # Config(immovable=False) is only exact without immovable bodies, but must still never
  # move one: the wall stays, the box and player split the overlap as if it were absent.
  world = pad_world(scenes.push_chain(1, overlap=0.2, wall=True))
  out = jc.resolve(world, jc.Config(depth=4, gravity=False, immovable=False))
  np.testing.assert_array_equal(out.pos[2], world.pos[2])
