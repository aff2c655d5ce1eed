"""Scene generators: the sizes and layouts the benchmarks and the demo rely on."""

import numpy as np
import pytest

from jaxchain import metrics, scenes


@pytest.mark.parametrize("n", [9, 14, 16, 64, 101])
def test_platformer_level_has_n_bodies_at_rest_in_a_closed_room(n):
  level = scenes.platformer_level(n)
  s = level.scene
  assert len(s.pos) == len(s.half) == len(s.mass) == n
  assert float(metrics.max_penetration(s.world())) == 0.0
  assert np.isinf(s.mass[:4]).all() and np.isfinite(s.mass[4:]).all()
  movable = np.isfinite(s.mass)
  left_face = s.pos[2, 0] + s.half[2, 0]
  lo, hi = s.pos[movable] - s.half[movable], s.pos[movable] + s.half[movable]
  assert (lo[:, 0] >= left_face).all() and (hi[:, 0] <= level.wall_face).all()
  assert (lo[:, 1] >= 0.0).all() and (hi[:, 1] <= 13.0).all()  # Floor top 0, ceiling at 13.


def test_platformer_level_14_is_the_demo_scene():
  for a, b in zip(scenes.platformer().scene, scenes.platformer_level(14).scene):
    np.testing.assert_array_equal(a, b)


def test_platformer_level_rejects_too_few_bodies():
  with pytest.raises(ValueError, match="at least 9 bodies"):
    scenes.platformer_level(8)


def test_lattice_room_starts_apart_inside_its_walls():
  s = scenes.lattice_room(10, seed=3)
  assert s.pos.shape == (14, 2) and np.isinf(s.mass[:4]).all() and (s.mass[4:] == 1).all()
  boxes = s.pos[4:]
  gaps = np.abs(boxes[:, None] - boxes[None]) - 1.0  # Unit boxes: centres 1 apart touch.
  apart = np.max(gaps, axis=-1) > 0
  assert apart[~np.eye(10, dtype=bool)].all()
  assert (boxes[:, 1] - 0.5 > 0).all()  # Above the floor's top at y = 0.
