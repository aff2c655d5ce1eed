"""Contacts: axis choice, direction, tie rules and links within the skin."""

import jax.numpy as jnp
import numpy as np
import pytest

from jaxchain import broadphase, geometry

HALF = jnp.full((2, 2), 0.5)


def contact(p1, skin=1e-4, half=HALF):
  pos = jnp.array([[0.0, 0.0], p1])
  c = geometry.contacts(pos, half, broadphase.dense(jnp.ones(2, bool)), skin)
  return bool(c.link[0, 1]), int(c.direction[0, 1]), float(c.depth[0, 1]), c


@pytest.mark.parametrize("p1, direction, depth", [
    ([0.8, 0.1], 0, 0.2),  # Smaller overlap along x, partner to the right: +x.
    ([-0.8, 0.1], 1, 0.2),
    ([0.1, 0.7], 2, 0.3),
    ([0.1, -0.7], 3, 0.3),
    ([0.6, 0.6], 0, 0.4),  # Tie between the axes goes to x.
    ([0.0, 0.0], 0, 1.0),  # Coincident centres: the larger index lies at +x.
    ([1.0, 0.3], 0, 0.0),  # Exactly touching: a link of depth 0.
])
def test_direction_and_depth(p1, direction, depth):
  link, d, got_depth, c = contact(p1)
  assert link and d == direction
  np.testing.assert_allclose(got_depth, depth, atol=1e-6)
  # The same contact seen from the other body points the other way.
  assert int(c.direction[1, 0]) == direction ^ 1 and bool(c.link[1, 0])


def test_links_within_skin_only():
  assert contact([1.00005, 0.0])[0]  # Gap below the skin: still a chain link.
  assert not contact([1.001, 0.0])[0]  # Gap above the skin.
  assert not contact([1.0, 1.0])[0]  # Touching at a corner only: not a link.
  link, direction, _, _ = contact([0.5, 1.0], skin=0.0)
  assert link and direction == 2  # Exactly touching along y is a link even with no skin.


def test_masked_candidates_are_not_links():
  pos = jnp.array([[0.0, 0.0], [0.5, 0.0]])
  c = geometry.contacts(pos, HALF, broadphase.dense(jnp.array([True, False])), 1e-4)
  assert not bool(c.link.any()) and float(c.depth.max()) == 0.0
