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
# The one-way rule's constants, as `jaxchain.geometry` has them (this module imports
# nothing but NumPy): a margin, a fraction of the two half-heights, and a speed.
ONE_WAY_MARGIN = 0.05
ONE_WAY_RISE = 1e-6
# Friction solves per substep (`jaxchain.core.friction.ROUNDS`): up to two slip rounds.
FRICTION_ROUNDS = 3


class _Scene:
  """Positions being resolved, with the contact geometry of the seed."""

  def __init__(self, pos, half, mass, skin, start=None, one_way=None, vel=None):
    self.pos = np.array(pos, dtype=np.float64)
    self.half = np.asarray(half, dtype=np.float64)
    self.mass = np.asarray(mass, dtype=np.float64)
    self.skin = skin
    self.start = None if start is None else np.asarray(start, dtype=np.float64)
    self.n = len(self.pos)
    # One-way bodies (`admits`); solid: immovable and not one-way.
    self.one_way = np.zeros(self.n, bool) if one_way is None else np.asarray(one_way, bool)
    self.solid = np.isinf(self.mass) & ~self.one_way
    self.vel = None if vel is None else np.asarray(vel, dtype=np.float64)

  def contact(self, a: int, b: int):
    """(axis, sign, overlap along axis, overlap along the other axis) from a to b:
    b lies in direction `sign` along `axis` from a.

    The axis is the one of smaller overlap (x on a tie), except for a pair that was
    apart at `start` (not overlapping by more than the skin along some axis): then it is
    the axis along which their faces were level at `start` (overlap within the skin)
    while overlapping by more than the skin along the other axis, else the axis along
    which the gap closed last on the straight path from `start` to now (its time of
    impact); the side is the one b lay on at
    `start`. A pair level along both axes at `start` (a corner contact) then takes the
    axis a surface of immovable bodies beside the corner decides, if one does
    (`seam_axis`); a pair level along one axis and apart along the other, overlapping
    within the skin now, the level axis if a slides along a face flush with b's
    (`approach_axis`).
    """
    delta = self.pos[b] - self.pos[a]
    o = self.half[a] + self.half[b] - np.abs(delta)
    axis = 1 if o[1] < o[0] else 0
    if self.start is not None:
      delta0 = self.start[b] - self.start[a]
      o0 = self.half[a] + self.half[b] - np.abs(delta0)
      if min(o0) <= self.skin:  # Apart at the start (a rounding overlap is touching).
        # Level along one axis while overlapping beyond the skin along the other.
        level = [abs(o0[k]) <= self.skin and o0[1 - k] > self.skin for k in range(2)]
        t = [0.0 if o0[k] > 0 else 2.0 if o[k] <= 0 else -o0[k] / (o[k] - o0[k])
             for k in range(2)]
        if level[0] != level[1]:  # Faces level along one axis: it keeps that axis.
          axis = 1 if level[1] else 0
        elif t[0] != t[1]:  # Else the axis of the later time of impact.
          axis = 1 if t[1] > t[0] else 0
      if abs(o0[0]) <= self.skin and abs(o0[1]) <= self.skin:  # A corner contact: seams.
        axis = self.seam_axis(a, b, delta0, axis)
      elif (any(abs(o0[k]) <= self.skin and o0[1 - k] < -self.skin for k in range(2))
            and min(o) >= -self.skin):  # Approaching b's corner, level along one axis.
        axis = self.approach_axis(a, b, o0, delta0, axis)
      if min(o0) <= self.skin:
        delta = delta0
    if delta[axis] > 0 or (delta[axis] == 0 and b > a):
      sign = 1.0
    else:
      sign = -1.0
    if self.vertical(a, b):  # One-way pairs meet along y, the upper body above.
      axis, sign = 1, (1.0 if self.came_down(b, a) else -1.0)
    return axis, sign, o[axis], o[1 - axis]

  def vertical(self, a: int, b: int) -> bool:
    """A pair with a one-way member and no solid one: the one-way rule decides it."""
    return bool((self.one_way[a] or self.one_way[b]) and not (self.solid[a] or self.solid[b]))

  def admits(self, a: int, b: int) -> bool:
    """The one-way rule (`jaxchain.geometry._one_way_rule`): a one-way body blocks only
    a body that came down onto it (`came_down`) or a solid body; two one-way bodies
    meet when one came down onto the other; other pairs always meet."""
    if self.one_way[a] and self.one_way[b]:
      return self.came_down(a, b) or self.came_down(b, a)
    ok_a = not self.one_way[b] or self.solid[a] or self.came_down(a, b)
    ok_b = not self.one_way[a] or self.solid[b] or self.came_down(b, a)
    return bool(ok_a and ok_b)

  def came_down(self, i: int, j: int) -> bool:
    """Whether body i came down onto body j, judged at the start (the current
    positions without one) and from the velocities: i's bottom is at or above j's top;
    or i is not rising relative to j (by more than `ONE_WAY_RISE`) and its bottom is
    below j's top by at most the margin (`ONE_WAY_MARGIN` of the two half-heights); or
    i is pressed into j: its centre is above j's top and its bottom below it by at
    most the margin plus i's press (`press`, > 0), whatever the velocities."""
    ref = self.pos if self.start is None else self.start
    bottom, top = ref[i, 1] - self.half[i, 1], ref[j, 1] + self.half[j, 1]
    margin = ONE_WAY_MARGIN * (self.half[i, 1] + self.half[j, 1])
    press = self.press(i)
    if bottom >= top or (ref[i, 1] > top and press > 0 and bottom >= top - margin - press):
      return True
    rising = self.vel is not None and self.vel[i, 1] - self.vel[j, 1] > ONE_WAY_RISE
    return bool(not rising and bottom >= top - margin)

  def press(self, i: int) -> float:
    """The deepest overlap along y, at the start, of a body above i that is not one-way
    and overlaps it along y less than along x (0 if none)."""
    ref = self.pos if self.start is None else self.start
    out = 0.0
    for k in range(self.n):
      if k == i or self.one_way[k] or ref[k, 1] - ref[i, 1] <= 0:
        continue
      o = self.half[i] + self.half[k] - np.abs(ref[k] - ref[i])
      if o[0] > 0 and 0 < o[1] < o[0]:
        out = max(out, o[1])
    return out

  def seam_axis(self, a: int, b: int, delta0, axis: int) -> int:
    """The axis of a corner contact (faces level along both axes at `start`) next to a
    surface of immovable bodies: of the two quadrants beside the common corner, the
    one beside a's face along y and b's along x, and the one beside a's face along x
    and b's along y, if exactly one lies inside an immovable body, the faces beside it
    are inner sides of a surface and the contact is along the other axis."""
    sx = 1.0 if delta0[0] > 0 else -1.0
    sy = 1.0 if delta0[1] > 0 else -1.0
    beside_x = self.covered(a, 1, sy, sx) or self.covered(b, 0, -sx, -sy)
    beside_y = self.covered(a, 0, sx, sy) or self.covered(b, 1, -sy, -sx)
    if beside_x != beside_y:
      return 1 if beside_x else 0
    return axis

  def approach_axis(self, a: int, b: int, o0, delta0, axis: int) -> int:
    """The axis of a pair level along one axis and apart along the other at `start`,
    near now: if the space just outside a's level face, at its end towards b, lies
    inside an immovable body (a one-way one only walked on), a slides along a surface
    flush with b's face and keeps the level axis; else `axis` (the time of impact)."""
    level = 1 if abs(o0[1]) <= self.skin else 0
    s = [1.0 if delta0[k] > 0 else -1.0 for k in range(2)]
    if self.covered(a, level, s[level], s[1 - level]):
      return level
    return axis

  def covered(self, i: int, face_axis: int, face_sign: float, corner_sign: float) -> bool:
    """Whether the space just outside body i's face (face_axis, face_sign) at `start`,
    next to that face's corner on side corner_sign of the other axis, lies inside an
    immovable body k (a one-way one only under i's bottom face, its top level with that
    face within the skin: a one-way top is a surface when walked on): along the face's
    axis k starts at or before the face (within the skin) and ends beyond it; along the
    other axis it reaches the corner (within the skin) and extends past it into the
    face."""
    a, b, s, t = face_axis, 1 - face_axis, face_sign, corner_sign
    under = face_axis == 1 and face_sign < 0  # The space under i's bottom face.
    for k in range(self.n):
      # A one-way body is a surface only walked on: under i, its top level with i's bottom.
      if k == i or not np.isinf(self.mass[k]) or (self.one_way[k] and not under):
        continue
      d = self.start[k] - self.start[i]
      h_i, h_k = self.half[i], self.half[k]
      face = s * d[a] - h_k[a] - h_i[a] <= self.skin and s * d[a] + h_k[a] - h_i[a] > self.skin
      if self.one_way[k] and not s * d[a] - h_k[a] - h_i[a] >= -self.skin:
        continue
      corner = (t * d[b] + h_k[b] - h_i[b] >= -self.skin
                and t * d[b] - h_k[b] - h_i[b] < -self.skin)
      if face and corner:
        return True
    return False

  def linked(self, a: int, b: int) -> bool:
    """Whether a and b touch (within the skin) or overlap along their contact axis."""
    _, _, o_axis, o_other = self.contact(a, b)
    return o_other > 0 and o_axis >= -self.skin and self.admits(a, b)

  def penetrating(self, a: int, b: int) -> bool:
    _, _, o_axis, o_other = self.contact(a, b)
    return o_axis > TOL and o_other > 0 and self.admits(a, b)

  def in_front(self, i: int, axis: int, sign: float) -> list[int]:
    """Bodies that body i leans on along (axis, sign): touching (within skin) or
    overlapping, on that side."""
    out = []
    for j in range(self.n):
      if j == i:
        continue
      ax, s, o_axis, o_other = self.contact(i, j)
      if ax == axis and s == sign and o_other > 0 and o_axis >= -self.skin and self.admits(i, j):
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
    across a gap (within the skin) moves by the amount less half the gap, so a gap
    pushed from both sides closes exactly once."""
    visited.add(i)
    sign = 1.0 if amount > 0 else -1.0
    ahead = [(j, min(self.contact(i, j)[2], 0.0)) for j in self.in_front(i, axis, sign)]
    self.pos[i, axis] += amount
    for j, gap_overlap in ahead:
      rest = abs(amount) + 0.5 * gap_overlap
      if j not in visited and not np.isinf(self.mass[j]) and rest > 0:
        self.push(j, axis, sign * rest, visited)

  def resolve_between(self, a: int, b: int, crush: np.ndarray) -> bool:
    """The seed's resolveCollisionsBetween, with units and the mass correction.
    Returns whether anything moved. When both units are immovable (a crush) each
    movable body of the pair is to move by half the depth, alone (its unit leans on
    something immovable): recorded in `crush[body, direction]` (the largest per
    direction, as the JAX pass takes it) and applied at the end of the sweep, all at
    once, so a body crushed from two sides ends centred; that does not count as
    moving."""
    axis, sign, depth, _ = self.contact(a, b)
    mass_a, static_a = self.unit(a, axis, -sign, set())
    mass_b, static_b = self.unit(b, axis, sign, set())
    if static_a and static_b:
      for body, direction in ((a, -sign), (b, sign)):
        if not np.isinf(self.mass[body]):
          d = 2 * axis + (0 if direction > 0 else 1)
          crush[body, d] = max(crush[body, d], depth / 2)
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


def resolve(pos, half, mass, *, skin: float = SKIN, max_sweeps: int = 1000,
            start=None, one_way=None, vel=None) -> np.ndarray:
  """Chained resolution of a world of boxes.

  Args:
    pos: `[n, 2]` centres.
    half: `[n, 2]` half-extents.
    mass: `[n]` masses in `(0, inf]`; inf is immovable.
    skin: gap under which bodies still lean on each other.
    max_sweeps: cap on outer sweeps (each resolves every penetrating pair once).
    start: optional `[n, 2]` centres at the start of the step: pairs separated there
      take their contact axis from the motion (see `_Scene.contact`).
    one_way: optional `[n]` bool, one-way (jump-through) bodies (`_Scene.admits`).
    vel: optional `[n, 2]` velocities the one-way rule reads (a body rising relative
      to a one-way body is not coming down onto it).

  Returns:
    `[n, 2]` float64 resolved centres.

  Examples:
    >>> import numpy as np
    >>> from jaxchain import reference
    >>> pos = [[0.0, 0.0], [0.9, 0.0], [1.9, 0.0]]  # player overlapping box, box touching wall
    >>> reference.resolve(pos, np.full((3, 2), 0.5), [1.0, 1.0, np.inf]).round(6).tolist()
    [[-0.1, 0.0], [0.9, 0.0], [1.9, 0.0]]
  """
  scene = _Scene(pos, half, mass, skin, start, one_way, vel)
  for _ in range(max_sweeps):
    moved = False
    crush = np.zeros((scene.n, 4))  # Per body and direction (+x, -x, +y, -y).
    for a in range(scene.n):
      for b in range(a + 1, scene.n):
        if scene.penetrating(a, b) and scene.resolve_between(a, b, crush):
          moved = True
    scene.pos += np.stack([crush[:, 0] - crush[:, 1], crush[:, 2] - crush[:, 3]], axis=-1)
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


def step(pos, vel, half, mass, *, friction=0.0, gravity=(0.0, -9.81), dt: float = 1 / 60,
         accel=None, skin: float = SKIN, substeps: int = 1, stick: float = 1e-3,
         tol: float = 1e-12, max_iterations: int = 10_000, one_way=None):
  """One time step, as `jaxchain.stepping.step` defines it, in plain loops (float64).

  Per substep of `sub_dt = dt / substeps`:

  1. integrate (semi-implicit Euler): `v += accel sub_dt` (every body; that is how a
     kinematic platform is driven), `v += g sub_dt` (movable bodies), `x_pred = x + v sub_dt`;
  2. resolve `x_pred` with `resolve(..., start=x)`;
  3. normal impulses on the links at the resolved positions (touching within the
     skin or overlapping): the perfectly inelastic projection, `min sum m |v' - v|^2`
     subject to no linked pair approaching, solved exactly by an active-set method. A link whose two units both lean on
     immovable bodies (a crush) is left out, and a movable body with such a link takes,
     along its axis, the mean velocity of the bodies it is linked to along that axis. A
     crush needs a push into both sides: the units lean on immovable bodies both at the
     resolved positions and at `x_pred` (a box touching a floor and a ceiling with no
     penetration while gravity presses it onto the floor, a player in a tunnel of its
     height, rests on the floor, friction included);
  4. friction: one Jacobi step on units with mass splitting, as
     `jaxchain.velocity.friction` documents: per link `clip(sliding / (k_i / F_i +
     k_j / F_j), +-mu_ij * normal impulse)`, `mu_ij = pair_coefficient(mu_i, mu_j)`, with k the body's number of
     links whose budget is positive and F each side's unit: the body and what sticks
     to it on its far side (links sliding slower than `stick` before the contacts act),
     which takes the impulse rigidly.

  Args:
    pos, vel, half: `[n, 2]`.
    mass: `[n]` in `(0, inf]`.
    friction: scalar or `[n]` coefficients.
    gravity: `(gx, gy)`.
    dt, substeps: the step and how many substeps it takes.
    accel: optional `[n, 2]` input acceleration.
    skin: link tolerance.
    stick: links sliding slower than this form friction units.
    tol, max_iterations: of the active-set solve.
    one_way: optional `[n]` bool, one-way bodies (the rule reads each substep's start
      positions and its velocities after gravity and input, as `jaxchain.step` does).

  Returns:
    `(pos, vel)` after the step, float64.

  Examples:
    >>> import numpy as np
    >>> from jaxchain import reference
    >>> p, v = reference.step([[0.0, 0.0], [1.1, 0.0]], [[6.0, 0.0], [0.0, 0.0]],
    ...                       np.full((2, 2), 0.5), [1.0, 3.0], gravity=(0.0, 0.0))
    >>> v.round(6).tolist()  # a perfectly inelastic hit: the common velocity
    [[1.5, 0.0], [1.5, 0.0]]
  """
  pos = np.array(pos, np.float64)
  vel = np.array(vel, np.float64)
  half = np.asarray(half, np.float64)
  mass = np.asarray(mass, np.float64)
  n = len(pos)
  mu = np.broadcast_to(np.asarray(friction, np.float64), (n,))
  accel = np.zeros((n, 2)) if accel is None else np.asarray(accel, np.float64)
  movable = ~np.isinf(mass)
  inv_mass = np.where(movable, 1.0 / np.where(movable, mass, 1.0), 0.0)
  sub_dt = dt / substeps
  for _ in range(substeps):
    vel = vel + accel * sub_dt
    vel[movable] += np.asarray(gravity, np.float64) * sub_dt
    start = pos
    predicted = start + vel * sub_dt
    pos = resolve(predicted, half, mass, skin=skin, start=start, one_way=one_way, vel=vel)
    scene = _Scene(pos, half, mass, skin, start, one_way, vel)
    # Where the motion took the bodies: a crush needs a push into both sides there.
    pushed = _Scene(predicted, half, mass, skin, start, one_way, vel)
    links = []  # (i, j, axis, sign): j lies in direction sign along axis from i.
    for i in range(n):
      for j in range(i + 1, n):
        if (movable[i] or movable[j]) and scene.linked(i, j):
          axis, sign, _, _ = scene.contact(i, j)
          links.append((i, j, axis, sign))
    crushed, free = [], []
    for i, j, axis, sign in links:
      jammed = all(sc.unit(i, axis, -sign, set())[1] and sc.unit(j, axis, sign, set())[1]
                   for sc in (scene, pushed))
      (crushed if jammed else free).append((i, j, axis, sign))
    before = vel.copy()
    normal = _inelastic(vel, inv_mass, free, tol, max_iterations)
    vel = _crush(vel, movable, links, crushed, start_vel=vel.copy()) if crushed else vel
    vel = _friction(vel, before, mass, mu, free, normal, stick)
  return pos, vel


def _inelastic(vel, inv_mass, links, tol, max_iterations) -> list[float]:
  """The inelastic projection by an active-set method (exact in float64 on the small
  scenes it serves): solve for the impulses that stop every link in the active set,
  drop a link whose impulse comes out negative (it pulls), add the link that approaches
  most at the result, until neither happens. Updates `vel` in place.
  """
  n_links = len(links)
  if n_links == 0:
    return []
  n = len(vel)
  jac = np.zeros((n_links, 2 * n))  # approach_k = jac[k] @ vel.ravel()
  for k, (i, j, axis, sign) in enumerate(links):
    jac[k, 2 * i + axis] += sign
    jac[k, 2 * j + axis] -= sign
  w = np.repeat(inv_mass, 2)
  v0 = vel.ravel().copy()
  active: list[int] = []
  impulse = np.zeros(n_links)
  for _ in range(max_iterations):
    impulse = np.zeros(n_links)
    if active:
      ja = jac[active]
      lam = np.linalg.lstsq((ja * w) @ ja.T, ja @ v0, rcond=None)[0]
      impulse[active] = lam
      if lam.min() < -tol:
        active.pop(int(np.argmin(lam)))
        continue
    v = v0 - w * (jac.T @ impulse)
    approach = jac @ v
    approach[active] = -np.inf
    worst = int(np.argmax(approach))
    if approach[worst] <= tol or np.all(w[np.nonzero(jac[worst])[0]] == 0):
      break
    active.append(worst)
  vel[:] = (v0 - w * (jac.T @ impulse)).reshape(vel.shape)
  return np.maximum(impulse, 0.0).tolist()


def _crush(vel, movable, links, crushed, start_vel):
  """A movable body with a crushed link takes, along that link's axis, the mean
  velocity of everything it is linked to along that axis."""
  out = vel.copy()
  for body in {b for i, j, _, _ in crushed for b in (i, j) if movable[b]}:
    for axis in {a for i, j, a, _ in crushed if body in (i, j)}:
      partners = [j if i == body else i for i, j, a, _ in links if a == axis and body in (i, j)]
      out[body, axis] = np.mean([start_vel[p, axis] for p in partners])
  return out


def pair_coefficient(a: float, b: float) -> float:
  """A pair's friction coefficient: the smaller of the bodies', `min(a, b)`, as
  `jaxchain.core.layout.pair_coefficient` computes it."""
  return min(a, b)


def _friction(vel, before, mass, mu, links, normal, stick, slip=1e-6):
  """Coulomb friction on units (see `jaxchain.velocity.friction`): `before` are the
  velocities that decide which links stick (slide slower than `stick`); links sliding
  slower than `slip` take no part. Solved on those units, then up to
  `FRICTION_ROUNDS - 1` slip rounds: of the sticking links whose budget
  `pair_coefficient(mu_i, mu_j) * normal` cannot hold the shear that moving as one needs, each
  body's most overloaded one (largest shear over budget) slips: it leaves the units and
  carries its budget the way the shear pointed (kinetic friction), and the impulses are
  solved again."""
  n = len(vel)
  movable = ~np.isinf(mass)
  sticking = [abs(before[i, 1 - a] - before[j, 1 - a]) <= stick for i, j, a, _ in links]
  budgets = [pair_coefficient(mu[i], mu[j]) * lam for (i, j, _, _), lam in zip(links, normal)]
  rubbing = [b > 0 and abs(vel[i, 1 - a] - vel[j, 1 - a]) > slip
             for (i, j, a, _), b in zip(links, budgets)]

  def solve(sticking, carried):
    """Velocity changes on the units of the `sticking` links, the slipped links
    carrying `carried`; also each body's change per unit direction, its units and their
    pushers."""
    def ahead(q, axis, sign):  # Bodies in front of q along (axis, sign), sticking links.
      out = []
      for (i, j, a, s), st in zip(links, sticking):
        if a == axis and st:
          if i == q and s == sign:
            out.append(j)
          elif j == q and s == -sign:
            out.append(i)
      return out

    def pushers(k, axis, sign):
      return sum(1 for q in range(n) if k in ahead(q, axis, sign))

    def unit(q, axis, sign):
      if not movable[q]:
        return 0.0
      return mass[q] + sum(unit(k, axis, sign) / pushers(k, axis, sign)
                           for k in ahead(q, axis, sign))

    def deliver(q, axis, sign, value, dv, along):
      if not movable[q]:
        return
      dv[q, 1 - axis] += value
      along[(axis, sign)][q] += value
      for k in ahead(q, axis, sign):
        deliver(k, axis, sign, value / pushers(k, axis, sign), dv, along)

    count = np.zeros(n)
    for (i, j, _, _), r in zip(links, rubbing):
      if r:
        count[i] += 1
        count[j] += 1
    dv = np.zeros_like(vel)
    along = {(a, s): np.zeros(n) for a in (0, 1) for s in (1.0, -1.0)}
    for (i, j, axis, sign), b, r, sl in zip(links, budgets, rubbing, carried):
      if not r and sl == 0:
        continue
      t = 1 - axis
      unit_i, unit_j = unit(i, axis, -sign), unit(j, axis, sign)
      w = (count[i] / unit_i if unit_i > 0 else 0.0) + (count[j] / unit_j if unit_j > 0 else 0.0)
      impulse = sl if sl != 0 else np.clip((vel[i, t] - vel[j, t]) / w, -b, b)
      if unit_i > 0:
        deliver(i, axis, -sign, -impulse / unit_i, dv, along)
      if unit_j > 0:
        deliver(j, axis, sign, impulse / unit_j, dv, along)
    return dv, along, unit, pushers

  carried = [0.0] * len(links)  # What a slipped link carries.
  for r in range(FRICTION_ROUNDS):
    dv, along, unit, pushers = solve(sticking, carried)
    if r == FRICTION_ROUNDS - 1:
      break

    def share(q, axis, sign):  # The unit q heads along (axis, sign), per pusher.
      p = pushers(q, axis, sign)
      return unit(q, axis, sign) / p if p > 0 else 0.0

    # The shear moving as one needs: j's unit takes i's change along the link's
    # direction, i's unit j's change along the opposite one.
    shear, ratio = {}, {}
    for k, ((i, j, axis, sign), st, b) in enumerate(zip(links, sticking, budgets)):
      if st:
        shear[k] = along[(axis, sign)][i] * share(j, axis, sign) - along[(axis, -sign)][
            j] * share(i, axis, -sign)
        if abs(shear[k]) > b:
          ratio[k] = abs(shear[k]) / b if b > 0 else np.inf
    worst = np.zeros(n)  # Each body's most overloaded slipping link.
    for k, q in ratio.items():
      for body in links[k][:2]:
        worst[body] = max(worst[body], q)
    for k, q in ratio.items():
      i, j = links[k][:2]
      if q >= worst[i] and q >= worst[j]:  # It slips: kinetic friction, out of the units.
        sticking[k] = False
        carried[k] = float(np.clip(shear[k], -budgets[k], budgets[k]))
  return vel + dv
