"""Contact flags by name: `grounded` and `blocked` read `World.touching`.

A step writes `World.touching` (`[n, 4]`: body i was linked to a body lying in
direction d from it, in some pass of the step) from the link tables it built anyway,
so the flags cost no extra pass (`jaxchain.core.contacts.touching`). Directions are
those of `DIRECTIONS`: `0: +x, 1: -x, 2: +y, 3: -y`.
"""

from __future__ import annotations

import jax

from jaxchain.core.layout import DIRECTIONS, NUM_DIRECTIONS
from jaxchain.world import World

RIGHT, LEFT, UP, DOWN = range(NUM_DIRECTIONS)  # Indices into `touching[..., d]`.
__all__ = ["DIRECTIONS", "DOWN", "LEFT", "RIGHT", "UP", "blocked", "grounded"]


def grounded(world: World) -> jax.Array:
  """Whether each body stands on something: `world.touching[..., 3]` (`[..., n]` bool).

  Examples:
    >>> import jaxchain as jc
    >>> w = jc.World.create([[0.0, 0.5], [0.0, -0.5]], [[0.5, 0.5], [5.0, 0.5]],
    ...                     [1.0, float("inf")])
    >>> jc.grounded(jc.step(w, jc.Config())).tolist()
    [True, False]
  """
  return world.touching[..., DOWN]


def blocked(world: World) -> dict[str, jax.Array]:
  """`touching` by name, like Phaser's `body.blocked`: `{"right", "left", "up",
  "down"}`, each `[..., n]` bool. Only movable bodies get flags."""
  t = world.touching
  return dict(right=t[..., RIGHT], left=t[..., LEFT], up=t[..., UP], down=t[..., DOWN])
