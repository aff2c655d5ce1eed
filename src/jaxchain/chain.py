"""The chain resolver: backing-mass propagation, mass split, max-plus push.

One pass over a fixed candidate table (DESIGN.md section 3):

1. contacts (`geometry.contacts`), sorted by direction into a `[4, n, l]` link
   table (`geometry.link_table`; `l = Config.links`, or the candidate row), so
   with a compact table every hop below gathers only real links;
2. backing, K hops: the mass of the unit behind each body in each direction,
   `M_d(i) = m_i + sum_{j in front of i along d} M_d(j)`, and a separate flag
   "leans on something immovable" `S_d(i)` (no inf arithmetic);
3. each penetrating contact (i, j) along d splits its depth: j moves along d by
   `depth * M_{-d}(i) / (M_{-d}(i) + M_d(j))`, i against d by the rest; a unit
   that leans on an immovable body takes none; if both do, nothing moves;
4. forward push, K + 1 hops (max-plus): a body's displacement along e is the
   largest, over the bodies pushing it along e, of their displacement along e
   plus its own share of that contact (minus the gap, for a link within the
   skin), so what a pushed body is pushed into moves with it;
5. net displacement per axis = (along +) - (along -), which also resolves squeezes.

The seed article writes the split as `ratioA = massA / (massA + massB)` applied
to A; taken literally that moves the heavier body more and moves a static wall by
the whole resolution. We implement the stated intent: each side moves in
proportion to the *other* side's mass.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
from jax import lax

from jaxchain import geometry
from jaxchain.broadphase import Candidates

def safe_divide(num: jax.Array, den: jax.Array, default: float = 0.0) -> jax.Array:
  """`num / den` where `den > 0`, else `default`, with finite gradients.

  The inner `where` keeps the division away from 0 so that its gradient is finite
  too: a single outer `where` would select the right value but still propagate
  `0 * inf = nan` through the unselected branch.
  """
  ok = den > 0
  return jnp.where(ok, num / jnp.where(ok, den, 1.0), default)


def body_mass(inv_mass: jax.Array, active: jax.Array) -> jax.Array:
  """`[n]` mass of active movable bodies, 0 for immovable or padding ones."""
  return jnp.where(active, safe_divide(1.0, inv_mass), 0.0)


class Pass(NamedTuple):
  """What one resolution pass computes.

  Attributes:
    disp: `[n, 2]` displacement; exactly 0 for immovable bodies.
    caused: `[n, 2]` the part of it this step's motion caused (with `ref_pos`), else None.
    exhausted: bool, the K hops did not reach the end of some chain (one hop more
      would still have changed a unit mass or a push).
    overflow: bool, some body had more links in one direction than `links` keeps.
  """

  disp: jax.Array
  caused: jax.Array | None
  exhausted: jax.Array
  overflow: jax.Array


def displacement(pos: jax.Array, half: jax.Array, mass: jax.Array, immovable: jax.Array,
                 cand: Candidates, *, depth: int, skin: float, links: int | None = None,
                 track_immovable: bool = True, ref_pos: jax.Array | None = None) -> Pass:
  """The displacement one resolution pass applies to every body.

  With `ref_pos` (where the bodies would be without this step's motion: the step's
  start plus the overlap recovery done so far) the pass also returns the part of
  the displacement that the motion caused: each contact's depth less the overlap
  the same pair has at `ref_pos`, pushed through the same units. A time step turns
  only that part into velocity, so recovering from overlap that was already there
  never adds energy.

  Args:
    pos: `[n, 2]` centres.
    half: `[n, 2]` half-extents.
    mass: `[n]` masses of movable bodies, 0 for the others (`body_mass`).
    immovable: `[n]` bool, bodies that never move (immovable or padding).
    cand: candidate table, `[n, m]`.
    depth: chain depth K (static).
    skin: link tolerance (static).
    links: links kept per body and direction (static; `geometry.link_table`).
    track_immovable: trace the "leans on something immovable" flag (static);
      `False` is only correct when no linked body is immovable.
    ref_pos: optional `[n, 2]` motion-free reference positions.

  Returns:
    A `Pass`: the displacement, the part caused by motion (with `ref_pos`), whether
    the depth was exhausted and whether a link table overflowed.
  """
  c = geometry.contacts(pos, half, cand, skin)
  # [4, n, l]: j in front of i along d. An immovable body's row is never needed: its
  # flag decides every split it is in, and it never moves.
  movable = ~immovable
  front, overflow = geometry.link_table(c, cand, links, rows=movable)
  back = front.reversed()  # [4, n, l]: j behind i along d, i.e. j pushes i along d.

  # 2. Backing: unit mass (and immovable flag) in front of each body, K hops.
  def backing_hop(_, carry):
    unit_mass, leans = carry
    if not track_immovable:
      return mass[None] + jnp.sum(jnp.where(front.mask, front.gather(unit_mass), 0.0), -1), leans
    # One gather for both: the flag rides along as a second float channel.
    ahead = front.gather(jnp.stack([unit_mass, leans.astype(unit_mass.dtype)]))
    unit_mass = mass[None] + jnp.sum(jnp.where(front.mask, ahead[0], 0.0), axis=-1)
    leans = immovable[None] | jnp.any(front.mask & (ahead[1] > 0), axis=-1)
    return unit_mass, leans

  unit_mass = jnp.broadcast_to(mass, (geometry.NUM_DIRECTIONS,) + mass.shape)
  leans = jnp.broadcast_to(immovable, unit_mass.shape)
  unit_mass, leans = lax.fori_loop(0, depth, backing_hop, (unit_mass, leans))
  # One hop more tells whether K hops reached the end of the chains (reporting only).
  more_mass, more_leans = backing_hop(0, (unit_mass, leans))
  unit_short = (more_mass != unit_mass) | (more_leans != leans)  # [4, n]

  # 3. Split each contact. Entry (d, i, j): j is in front of i along d, i moves along
  # e = d ^ 1; i's unit is the one behind it (M_e(i)), j's the one in front of j (M_d(j)).
  def behind(x):  # [4, n] -> [4, n, 1]: the value of row i along e.
    return x[geometry.OPPOSITE][..., None]

  mass_i, leans_i = behind(unit_mass), behind(leans)
  mass_j, leans_j = front.gather(unit_mass), front.gather(leans)
  depth_now = jnp.where(front.mask, jnp.maximum(front.overlap, 0.0), 0.0)
  # Only the units a penetrating contact splits by matter for the report.
  backing_short = jnp.any((depth_now > 0) & (behind(unit_short) | front.gather(unit_short)))
  weight = safe_divide(mass_j, mass_i + mass_j, default=0.5)
  weight = jnp.where(leans_j, 1.0, weight)
  weight = jnp.where(leans_i, 0.0, weight)
  depths = depth_now[None]
  if ref_pos is not None:
    depths = jnp.stack([depth_now, jnp.maximum(depth_now - _overlap_at(ref_pos, half, front), 0.0)])
  # [k, 4, n, l]: how far i is pushed along e by this contact beyond j's own push. Across
  # a gap (a link within the skin) i moves only once j has closed it: share = -gap.
  share = jnp.where(front.overlap[None] > 0, depths * weight[None], front.overlap[None])
  share = share[:, geometry.OPPOSITE]  # Rows of `back`: i pushed along d by j behind it.

  # 4. Forward push, K + 1 hops of max-plus along each direction.

  def push_hop(disp, share):
    pushed = jnp.where(back.mask, back.gather(disp) + share, 0.0)
    return jnp.where(movable[None, None], jnp.max(pushed, axis=-1, initial=0.0), 0.0)

  disp = jnp.zeros((depths.shape[0],) + unit_mass.shape, pos.dtype)
  disp = lax.fori_loop(0, depth + 1, lambda _, x: push_hop(x, share), disp)
  # Reporting only: the position channel alone decides whether a push was cut short.
  push_short = jnp.any(push_hop(disp[:1], share[:1]) != disp[:1])
  exhausted = lax.stop_gradient(backing_short | push_short)
  net = jnp.stack([disp[:, 0] - disp[:, 1], disp[:, 2] - disp[:, 3]], axis=-1)  # [k, n, 2]
  return Pass(net[0], net[1] if ref_pos is not None else None, exhausted, overflow)


def _overlap_at(ref_pos: jax.Array, half: jax.Array, links: geometry.Links) -> jax.Array:
  """`[4, n, l]` penetration each linked pair has at `ref_pos`, measured along the
  link's axis (0 where the pair does not overlap there)."""
  o = geometry.overlap(ref_pos[None, :, None], half[None, :, None], links.gather_bodies(ref_pos),
                       links.gather_bodies(half))
  o_axis, o_other = geometry.along_axis(o, geometry.ALONG_Y)
  return jnp.where(links.mask & (o_other > 0), jnp.maximum(o_axis, 0.0), 0.0)


def measure(pos: jax.Array, half: jax.Array, movable: jax.Array, cand: Candidates, *,
            skin: float, max_hops: int | jax.Array) -> tuple[jax.Array, jax.Array]:
  """What a scene needs now: the links in its longest chain of touching or
  overlapping bodies (a wall at the end counts as a link, along any direction, up
  to `max_hops`) and the most links any movable body has in one direction. Used on
  the host to pick a chain depth and a link table size; not differentiable (a
  `while_loop` that stops when nothing changes).

  Args:
    pos, half: `[n, 2]`.
    movable: `[n]` bool; immovable bodies end chains.
    cand: candidate table.
    skin: static.
    max_hops: int, may be traced (only the loop condition reads it).

  Returns:
    `(longest_chain, most_links)`, int32 scalars.
  """
  c = geometry.contacts(pos, half, cand, skin)
  front = geometry.by_direction(c, rows=movable)  # [4, n, m]
  carries = cand.gather(movable[None].astype(jnp.int32)) > 0  # [1, n, m]: j passes pushes on.

  def hop(state):
    length, _, k = state
    ahead = jnp.where(carries, cand.gather(length), 0)
    new = jnp.max(jnp.where(front, 1 + ahead, 0), axis=-1, initial=0)
    return new, jnp.any(new != length), k + 1

  length = jnp.zeros(front.shape[:2], jnp.int32)
  length, _, _ = lax.while_loop(lambda s: s[1] & (s[2] < jnp.int32(max_hops)), hop,
                                (length, jnp.array(True), jnp.array(0, jnp.int32)))
  return jnp.max(length, initial=0), jnp.max(jnp.sum(front, axis=-1, dtype=jnp.int32), initial=0)
