"""Scene generators: host-side NumPy arrays `(pos, half, mass)` with known layouts.

Each generator returns float64 arrays so the same scene feeds both the reference
resolver and `World.create`. `platformer` builds the demo scene.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from jaxchain.world import World

INF = np.inf


class Scene(NamedTuple):
  """Host arrays of a scene: `pos [n, 2]`, `half [n, 2]`, `mass [n]`."""

  pos: np.ndarray
  half: np.ndarray
  mass: np.ndarray

  def world(self, vel=None, *, friction=0.0, gravity=(0.0, -9.81)) -> World:
    """The scene as a `World` (see `World.create` for `vel`, `friction`, `gravity`)."""
    return World.create(self.pos, self.half, self.mass, vel=vel, friction=friction,
                        gravity=gravity)


def push_chain(length: int, overlap: float = 0.1, wall: bool = True, masses=None,
               overlaps=None) -> Scene:
  """A player (body 0) overlapping box 1 of a row of `length` unit boxes along +x.

  Boxes touch (or overlap by `overlaps[k]` between box k and k+1); with `wall`, an
  immovable wall (the last body) touches the last box.

  Args:
    length: number of boxes L.
    overlap: depth d by which the player overlaps box 1.
    wall: append an immovable wall behind box L.
    masses: optional `[L + 1]` masses of the player and boxes (default 1).
    overlaps: optional `[L - 1]` overlaps between consecutive boxes (default 0).
  """
  masses = np.ones(length + 1) if masses is None else np.asarray(masses, float)
  gaps = np.zeros(max(length - 1, 0)) if overlaps is None else np.asarray(overlaps, float)
  x = [0.0, 1.0 - overlap]
  for k in range(length - 1):
    x.append(x[-1] + 1.0 - gaps[k])
  mass = list(masses)
  if wall:
    x.append(x[-1] + 1.0)
    mass.append(INF)
  pos = np.stack([np.asarray(x), np.zeros(len(x))], axis=-1)
  return Scene(pos, np.full((len(x), 2), 0.5), np.asarray(mass, float))


def stack(height: int, overlaps=0.05, masses=None) -> Scene:
  """A column of `height` unit boxes on an immovable floor (body 0).

  Args:
    height: number of boxes H.
    overlaps: scalar or `[H]`, the overlap of box k with what is below it.
    masses: optional `[H]` box masses (default 1).
  """
  overlaps = np.broadcast_to(np.asarray(overlaps, float), (height,))
  masses = np.ones(height) if masses is None else np.asarray(masses, float)
  y, top = [], 0.0
  for k in range(height):
    y.append(top + 0.5 - overlaps[k])
    top = y[-1] + 0.5
  pos = np.concatenate([[[0.0, -0.5]], np.stack([np.zeros(height), y], -1)])
  half = np.concatenate([[[5.0, 0.5]], np.full((height, 2), 0.5)])
  return Scene(pos, half, np.concatenate([[INF], masses]))


def comb(rows: int, row_length: int, overlap: float = 0.1, masses=None, wall: bool = False) -> Scene:
  """A push tree: a player (body 0) overlapping a tall root box whose right face
  touches `rows` rows of `row_length` unit boxes each (a tree of branching `rows`).

  Args:
    rows: number of branches.
    row_length: boxes per branch.
    overlap: depth by which the player overlaps the root box.
    masses: optional masses of `[player, root, row boxes...]`.
    wall: put an immovable wall behind the first row only.
  """
  pos = [[0.0, 0.0], [0.5 + 0.5 * rows - overlap, 0.0]]
  half = [[0.5, 0.5], [0.5 * rows, 0.5 * rows]]
  x0 = pos[1][0] + 0.5 * rows + 0.5
  for r in range(rows):
    y = -0.5 * rows + 0.5 + r
    for k in range(row_length):
      pos.append([x0 + k, y])
      half.append([0.5, 0.5])
  n = len(pos)
  mass = np.ones(n) if masses is None else np.asarray(masses, float)
  if wall:
    pos.append([x0 + row_length, -0.5 * rows + 0.5])
    half.append([0.5, 0.5])
    mass = np.append(mass, INF)
  return Scene(np.asarray(pos, float), np.asarray(half, float), np.asarray(mass, float))


def random_boxes(rng: np.random.Generator, n: int, extent: float = 4.0,
                 immovable_fraction: float = 0.0) -> Scene:
  """`n` random boxes (sizes 0.2 to 1) in a square of side `extent`; random masses."""
  pos = rng.uniform(0, extent, (n, 2))
  half = rng.uniform(0.1, 0.5, (n, 2))
  mass = rng.uniform(0.5, 2.0, n)
  mass[rng.random(n) < immovable_fraction] = INF
  return Scene(pos, half, mass)


class Platformer(NamedTuple):
  """The demo scene with the indices a report needs."""

  scene: Scene
  player: int
  row: np.ndarray  # Indices of the pushed row, left to right.
  wall: int  # The wall the row is pushed towards.
  wall_face: float  # x of that wall's inner face.


def platformer(rng: np.random.Generator | None = None, row_length: int = 4,
               stack_height: int = 5, stacked: int | None = None) -> Platformer:
  """A closed room: floor, ceiling and walls (immovable), a player on the left,
  a row of boxes on the floor to push toward the right wall, and stacked boxes
  behind the player.

  With `rng`, box masses are drawn from `[0.5, 2]` (a different world per draw).
  `stacked` boxes (default `stack_height`) stand in columns of `stack_height`,
  1.5 apart, leftwards from the player; the room widens to the left to hold them.
  `platformer_level(n)` sizes it to `n` bodies.
  """
  stacked = stack_height if stacked is None else stacked
  columns = max(1, -(-stacked // stack_height))
  left = -10.0 - 1.5 * (columns - 1)  # Inner face of the left wall.
  centre, width = (left + 10.0) / 2, (10.0 - left) / 2
  pos, half, mass = [], [], []

  def add(p, h, m):
    pos.append(p)
    half.append(h)
    mass.append(m)
    return len(pos) - 1

  add([centre, -0.5], [width + 2.0, 0.5], INF)  # floor, top at y = 0
  add([centre, 13.5], [width + 1.0, 0.5], INF)  # ceiling
  add([left - 0.5, 6.5], [0.5, 6.5], INF)  # left wall
  wall = add([10.5, 6.5], [0.5, 6.5], INF)  # right wall, inner face at x = 10
  player = add([-6.0, 0.6], [0.4, 0.6], 1.0)
  draw = (lambda: float(rng.uniform(0.5, 2.0))) if rng is not None else (lambda: 1.0)
  row = [add([4.5 + k, 0.5], [0.5, 0.5], draw()) for k in range(row_length)]
  for k in range(stacked):
    add([-8.5 - 1.5 * (k // stack_height), 0.5 + k % stack_height], [0.5, 0.5], draw())
  scene = Scene(np.asarray(pos, float), np.asarray(half, float), np.asarray(mass, float))
  return Platformer(scene, player, np.asarray(row), wall, 10.0)


def platformer_level(n: int, rng: np.random.Generator | None = None) -> Platformer:
  """The demo scene grown (or shrunk) to `n` bodies, `n >= 9`: the same room, player
  and row of 4, with `n - 9` boxes stacked in columns of 5 behind the player."""
  if n < 9:
    raise ValueError(f"platformer_level: need at least 9 bodies (room, player, row), got {n}")
  return platformer(rng, stacked=n - 9)


def lattice_room(n: int, seed: int = 0) -> Scene:
  """`n` unit boxes on a lattice of pitch 1.5 (x jittered by up to 0.2) in a closed room
  (bodies 0-3 are the floor, ceiling and walls): the benchmarks' room of falling boxes.

  Interior `[0, W] x [0, H]`: `ceil(sqrt(n))` columns, boxes start 0.5 above the
  floor and 0.5 apart, so nothing overlaps at the start.
  """
  rng = np.random.default_rng(seed)
  cols = int(np.ceil(np.sqrt(n)))
  rows = int(np.ceil(n / cols))
  w, h = 1.5 * cols + 0.5, 1.5 * rows + 1.5
  k = np.arange(n)
  boxes = np.stack([1.0 + 1.5 * (k % cols) + rng.uniform(-0.2, 0.2, n), 1.0 + 1.5 * (k // cols)], -1)
  walls_pos = [[w / 2, -0.5], [w / 2, h + 0.5], [-0.5, h / 2], [w + 0.5, h / 2]]
  walls_half = [[w / 2 + 1, 0.5], [w / 2 + 1, 0.5], [0.5, h / 2], [0.5, h / 2]]
  pos = np.concatenate([walls_pos, boxes])
  half = np.concatenate([walls_half, np.full((n, 2), 0.5)])
  return Scene(pos, half, np.r_[np.full(4, INF), np.ones(n)])


def box_room(rng: np.random.Generator, n: int, density: float = 0.35) -> Scene:
  """A closed room (floor, ceiling, two walls) holding `n - 4` movable boxes at
  constant density: the room's area grows with `n`, so the work per body does
  not. Boxes (half-extents 0.2 to 0.45) sit on a jittered lattice, some touching.

  Args:
    rng: random generator.
    n: total bodies, at least 5.
    density: fraction of lattice sites holding a box.
  """
  if n < 5:
    raise ValueError(f"box_room: need at least 5 bodies, got {n}")
  boxes = n - 4
  side = int(np.ceil(np.sqrt(boxes / density)))
  sites = rng.choice(side * side, boxes, replace=False)
  centre = np.stack([sites % side, sites // side], -1) + 0.5
  half = rng.uniform(0.2, 0.45, (boxes, 2))
  centre = centre + rng.uniform(-1, 1, (boxes, 2)) * (0.5 - half)
  w = float(side)
  walls_pos = [[w / 2, -0.5], [w / 2, w + 0.5], [-0.5, w / 2], [w + 0.5, w / 2]]
  walls_half = [[w / 2 + 1, 0.5], [w / 2 + 1, 0.5], [0.5, w / 2], [0.5, w / 2]]
  pos = np.concatenate([np.asarray(walls_pos), centre])
  half = np.concatenate([np.asarray(walls_half), half])
  mass = np.r_[np.full(4, INF), rng.uniform(0.5, 2.0, boxes)]
  return Scene(pos, half, mass)
