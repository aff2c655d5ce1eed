"""Contacts: axis choice, direction, tie rules and links within the skin."""

import jax.numpy as jnp
import numpy as np
import pytest

import jaxchain as jc
from tests.helpers import contact_table, dense_candidates

HALF = jnp.full((2, 2), 0.5)


def contact(p1, skin=1e-4, half=HALF, active=(True, True)):
  """`(link, direction, depth, code)` of the pair (0, 1) seen from body 0 (`code` is the
  `[2, 2]` table: row i, partner slot j; 4 where no link)."""
  world = jc.World.create([[0.0, 0.0], p1], half, 1.0, active=np.array(active))
  code, overlap, _ = contact_table(world, dense_candidates(world), skin)
  return bool(code[0, 1] < 4), int(code[0, 1]), max(float(overlap[0, 1]), 0.0), code


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
  assert int(c[1, 0]) == direction ^ 1


def test_links_within_skin_only():
  assert contact([1.00005, 0.0])[0]  # Gap below the skin: still a chain link.
  assert not contact([1.001, 0.0])[0]  # Gap above the skin.
  assert not contact([1.0, 1.0])[0]  # Touching at a corner only: not a link.
  link, direction, _, _ = contact([0.5, 1.0], skin=0.0)
  assert link and direction == 2  # Exactly touching along y is a link even with no skin.


def test_masked_candidates_are_not_links():
  _, _, _, code = contact([0.5, 0.0], active=(True, False))
  assert np.all(code == 4)
