"""The reference resolver: known answers, termination, and the old system."""

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from jaxchain import reference, scenes

HALF3 = np.full((3, 2), 0.5)


def test_mass_ratio_is_the_corrected_one():
  # Light box (1) overlapping heavy box (3) by 0.4: the light one moves 3/4 of it.
  pos = [[0.0, 0.0], [0.6, 0.0]]
  out = reference.resolve(pos, np.full((2, 2), 0.5), [1.0, 3.0])
  np.testing.assert_allclose(out[:, 0], [-0.3, 0.7])


def test_wall_never_moves_and_player_takes_the_whole_push():
  scene = scenes.push_chain(4, overlap=0.3, wall=True)
  out = reference.resolve(scene.pos, scene.half, scene.mass)
  np.testing.assert_array_equal(out[1:], scene.pos[1:])
  np.testing.assert_allclose(out[0, 0], scene.pos[0, 0] - 0.3)


def test_free_chain_answer():
  L, d = 4, 0.25
  scene = scenes.push_chain(L, overlap=d, wall=False)
  dx = reference.resolve(scene.pos, scene.half, scene.mass)[:, 0] - scene.pos[:, 0]
  np.testing.assert_allclose(dx, np.r_[-d * L / (L + 1), np.full(L, d / (L + 1))], atol=1e-12)


def test_unit_mass_counts_everything_leaned_on():
  # Player pushes a root box backed by 3 rows of 2: the unit in front weighs 7.
  scene = scenes.comb(3, 2, overlap=0.4)
  dx = reference.resolve(scene.pos, scene.half, scene.mass)[:, 0] - scene.pos[:, 0]
  np.testing.assert_allclose(dx[0], -0.4 * 7 / 8, atol=1e-12)
  np.testing.assert_allclose(dx[1:], 0.4 / 8, atol=1e-12)


def test_tie_rules():
  # Equal overlaps on both axes: resolved along x. Coincident centres: larger index to +.
  out = reference.resolve([[0.0, 0.0], [0.5, 0.5]], np.full((2, 2), 0.5), [1.0, 1.0])
  np.testing.assert_allclose(out, [[-0.25, 0.0], [0.75, 0.5]])
  out = reference.resolve([[0.0, 0.0], [0.0, 0.0]], np.full((2, 2), 0.5), [1.0, 1.0])
  np.testing.assert_allclose(out, [[-0.5, 0.0], [0.5, 0.0]])


def test_squeeze_terminates_and_centres_the_crushed_box():
  # Crushed between two walls (both units immovable): it moves half of each overlap,
  # both at once, so it ends centred and the walls stay put.
  pos = np.array([[0.0, 0.0], [0.95, 0.0], [1.8, 0.0]])
  out = reference.resolve(pos, HALF3, [np.inf, 1.0, np.inf])
  np.testing.assert_allclose(out, [[0.0, 0.0], [0.9, 0.0], [1.8, 0.0]], atol=1e-12)


@given(st.integers(0, 2**31 - 1), st.integers(2, 12), st.floats(0.0, 0.5))
def test_terminates_and_never_moves_immovable_bodies(seed, n, immovable_fraction):
  scene = scenes.random_boxes(np.random.default_rng(seed), n, extent=2.0,
                              immovable_fraction=immovable_fraction)
  out = reference.resolve(scene.pos, scene.half, scene.mass, max_sweeps=50)
  fixed = np.isinf(scene.mass)
  np.testing.assert_array_equal(out[fixed], scene.pos[fixed])
  assert np.all(np.isfinite(out))


def test_old_system_depends_on_order():
  scene = scenes.push_chain(2, overlap=0.3, wall=True)
  forward = reference.resolve_old(scene.pos, scene.half, scene.mass)
  backward = reference.resolve_old(scene.pos, scene.half, scene.mass, order=[3, 2, 1, 0])
  assert not np.allclose(forward, backward)
  # Index order: the player's push goes into box 1 and is never passed on to the wall.
  np.testing.assert_allclose(forward[0, 0], scene.pos[0, 0] - 0.15)


@pytest.mark.parametrize("bad", ["pos", "half"])
def test_inputs_are_not_modified(bad):
  scene = scenes.push_chain(2)
  arrays = {"pos": scene.pos.copy(), "half": scene.half.copy()}
  reference.resolve(arrays["pos"], arrays["half"], scene.mass)
  np.testing.assert_array_equal(arrays[bad], getattr(scene, bad))
