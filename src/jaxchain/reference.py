"""Reference resolver: the seed article's algorithm in plain NumPy, float64.

This is the executable specification the JAX resolver is tested against. It is
written to be read, not to be fast, and it depends on nothing but NumPy.

`resolve` follows the seed's recursive `resolveCollisionsBetween(a, b, addedMass,
forceStatic)`:

* a penetrating pair (a, b) is separated along the axis of smaller overlap;
* each side acts as a *unit*: the body plus everything it leans on in the
  direction it is pushed (the seed's `addedMass`, found by recursion over
  touching or overlapping neighbours), and a unit that leans on anything
  immovable is immovable (the seed's `forceStatic`);
* the depth is split by unit mass. The seed writes `ratioA = massA / (massA +
  massB)` and moves A by `ratioA * r`; taken literally that moves the heavier
  body more and moves a static wall by the whole resolution, contradicting the
  seed's own examples. We implement the intent: A moves by `r * M_b / (M_a +
  M_b)` and B by `-r * M_a / (M_a + M_b)`; an immovable unit takes nothing;
* then the resolution is chained: whatever a moved body was leaning on in the
  direction it moved is pushed with it, recursively (the pair moves as one unit);
* an outer sweep repeats over all pairs until nothing penetrates.

Every recursion carries a `visited` set, so it terminates on any input, and the
outer sweep has a cap. Tie rules match the JAX resolver exactly: the contact axis
is the axis of smaller overlap (x on a tie), and on coincident centres the body
with the larger index lies in the positive direction.

`resolve_old` is the seed's "old system": pairs resolved one at a time in index
order, no chaining. It is order-dependent, the baseline chaining improves on.
"""

from __future__ import annotations

import numpy as np

SKIN = 1e-4
TOL = 1e-9  # Penetration below this counts as resolved.


class _Scene:
  """Positions being resolved, with the contact geometry of the seed."""

  def __init__(self, pos, half, mass, skin):
    self.pos = np.array(pos, dtype=np.float64)
    self.half = np.asarray(half, dtype=np.float64)
    self.mass = np.asarray(mass, dtype=np.float64)
    self.skin = skin
    self.n = len(self.pos)

  def contact(self, a: int, b: int):
    """(axis, sign, overlap along axis, overlap along the other axis) from a to b:
    b lies in direction `sign` along `axis` from a."""
    delta = self.pos[b] - self.pos[a]
    o = self.half[a] + self.half[b] - np.abs(delta)
    axis = 1 if o[1] < o[0] else 0
    if delta[axis] > 0 or (delta[axis] == 0 and b > a):
      sign = 1.0
    else:
      sign = -1.0
    return axis, sign, o[axis], o[1 - axis]

  def penetrating(self, a: int, b: int) -> bool:
    _, _, o_axis, o_other = self.contact(a, b)
    return o_axis > TOL and o_other > 0

  def in_front(self, i: int, axis: int, sign: float) -> list[int]:
    """Bodies that body i leans on along (axis, sign): touching (within skin) or
    overlapping, on that side."""
    out = []
    for j in range(self.n):
      if j == i:
        continue
      ax, s, o_axis, o_other = self.contact(i, j)
      if ax == axis and s == sign and o_other > 0 and o_axis >= -self.skin:
        out.append(j)
    return out

  def unit(self, i: int, axis: int, sign: float, visited: set[int]) -> tuple[float, bool]:
    """(added mass, force static) of the unit body i forms along (axis, sign):
    its own mass plus that of everything it leans on, recursively."""
    visited.add(i)
    if np.isinf(self.mass[i]):
      return 0.0, True
    total, static = self.mass[i], False
    for j in self.in_front(i, axis, sign):
      if j not in visited:
        m, s = self.unit(j, axis, sign, visited)
        total, static = total + m, static or s
    return total, static

  def push(self, i: int, axis: int, amount: float, visited: set[int]) -> None:
    """Moves body i by `amount` along axis and, first, everything it leans on in
    that direction by the same amount (the unit moves rigidly); a body it leans on
    across a gap (within the skin) moves by the amount less the gap."""
    visited.add(i)
    sign = 1.0 if amount > 0 else -1.0
    ahead = [(j, min(self.contact(i, j)[2], 0.0)) for j in self.in_front(i, axis, sign)]
    self.pos[i, axis] += amount
    for j, gap_overlap in ahead:
      rest = abs(amount) + gap_overlap
      if j not in visited and not np.isinf(self.mass[j]) and rest > 0:
        self.push(j, axis, sign * rest, visited)

  def resolve_between(self, a: int, b: int) -> bool:
    """The seed's resolveCollisionsBetween, with units and the mass correction.
    Returns whether anything moved (not when both units are immovable)."""
    axis, sign, depth, _ = self.contact(a, b)
    mass_a, static_a = self.unit(a, axis, -sign, set())
    mass_b, static_b = self.unit(b, axis, sign, set())
    if static_a and static_b:
      return False
    if static_a:
      share_a, share_b = 0.0, depth
    elif static_b:
      share_a, share_b = depth, 0.0
    else:
      share_a = depth * mass_b / (mass_a + mass_b)
      share_b = depth * mass_a / (mass_a + mass_b)
    if share_a > 0:
      self.push(a, axis, -sign * share_a, set())
    if share_b > 0:
      self.push(b, axis, sign * share_b, set())
    return True


def resolve(pos, half, mass, *, skin: float = SKIN, max_sweeps: int = 1000) -> np.ndarray:
  """Chained resolution of a world of boxes.

  Args:
    pos: `[n, 2]` centres.
    half: `[n, 2]` half-extents.
    mass: `[n]` masses in `(0, inf]`; inf is immovable.
    skin: gap under which bodies still lean on each other.
    max_sweeps: cap on outer sweeps (each resolves every penetrating pair once).

  Returns:
    `[n, 2]` float64 resolved centres.

  Examples:
    >>> import numpy as np
    >>> from jaxchain import reference
    >>> pos = [[0.0, 0.0], [0.9, 0.0], [1.9, 0.0]]  # player overlapping box, box touching wall
    >>> reference.resolve(pos, np.full((3, 2), 0.5), [1.0, 1.0, np.inf]).round(6).tolist()
    [[-0.1, 0.0], [0.9, 0.0], [1.9, 0.0]]
  """
  scene = _Scene(pos, half, mass, skin)
  for _ in range(max_sweeps):
    moved = False
    for a in range(scene.n):
      for b in range(a + 1, scene.n):
        if scene.penetrating(a, b) and scene.resolve_between(a, b):
          moved = True
    if not moved:
      break
  return scene.pos


def resolve_old(pos, half, mass, *, order=None, sweeps: int = 1) -> np.ndarray:
  """The seed's old pairwise system: no chaining, order-dependent.

  Each penetrating pair, visited in `order` (default index order), is separated
  by the corrected mass split of the two bodies alone; the resolution may push
  either body into a third one, which is left for a later pair or sweep.

  Args:
    pos, half, mass: as in `resolve`.
    order: optional permutation of body indices fixing the visiting order.
    sweeps: passes over all pairs.
  """
  scene = _Scene(pos, half, mass, SKIN)
  order = np.arange(scene.n) if order is None else np.asarray(order)
  for _ in range(sweeps):
    for ia in range(scene.n):
      for ib in range(ia + 1, scene.n):
        a, b = int(order[ia]), int(order[ib])
        if not scene.penetrating(a, b):
          continue
        axis, sign, depth, _ = scene.contact(a, b)
        ma, mb = scene.mass[a], scene.mass[b]
        if np.isinf(ma) and np.isinf(mb):
          continue
        share_a = depth if np.isinf(mb) else 0.0 if np.isinf(ma) else depth * mb / (ma + mb)
        scene.pos[a, axis] -= sign * share_a
        scene.pos[b, axis] += sign * (depth - share_a)
  return scene.pos
