"""The chain resolver, batch minor: backing, mass split, max-plus push, link impulses.

One pass over a link table `[L, 4, n, B]` (DESIGN.md section 3):

1. backing, K hops: the mass of the unit in front of each body in each direction,
   `M_d(i) = m_i + sum over j in front of i along d of M_d(j)`, and a flag "leans on
   something immovable" `S_d(i)` (no inf arithmetic);
2. each penetrating contact (i, j) along d splits its depth: j moves along d by
   `depth * M_e(i) / (M_e(i) + M_d(j))` (e = d ^ 1), i against d by the rest; a unit
   that leans on an immovable body takes none; if both do, the contact is jammed;
3. forward push, K + 1 hops of max-plus: a body's displacement along d is the largest,
   over the bodies pushing it along d, of their displacement plus its share of that
   contact, so what a pushed body is pushed into moves with it;
4. net displacement per axis = (along +) - (along -), which also resolves squeezes.

The seed article writes the split as `ratioA = massA / (massA + massB)` applied to A;
taken literally that moves the heavier body more and moves a static wall by the whole
resolution. jaxchain implements the stated intent: each side moves in proportion to
the *other* side's mass.

With velocities, the same units and hops carry the approach speeds (a perfectly
inelastic projection on chains and trees), turned into one compressive impulse per
link, refined by Jacobi steps with mass splitting and guarded against adding energy.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
from jax import lax

from jaxchain.core.contacts import Links
from jaxchain.core.layout import (any_world, along, choose, fold, opposite, positive,
                                  push_max, safe_divide, vary, world_sum)

# Jacobi refinement steps on the contact impulses after the chain's estimate.
REFINE = 4
# Ulps of the kinetic energy below which `energy_scale` takes an energy change for
# rounding (the tests' energy tolerance is 16 ulps of every term).
ROUNDING = 2.0


def repeat(hop, init, times: int, converge: bool = False, check: bool = False):
  """`times` applications of `hop` (a pytree to the same pytree) from `init`.

  With `converge` (forward-only), a `while_loop` that stops after its second hop when
  that hop changed nothing in the whole batch, else runs the `times` hops: every hop
  loop of the resolver is a fixed-point iteration, so the answer is that of `times`
  hops, bit for bit. Not reverse-differentiable.

  With `check`, also returns where one hop more would still change a value (a pytree of
  bool arrays like `init`: the chain is longer than `times`).
  """
  changes = lambda x, y: jax.tree_util.tree_map(jnp.not_equal, x, y)
  if not converge:
    if not check:
      return lax.fori_loop(0, times, lambda _, x: hop(x), vary(init))
    # The check hop runs as the loop's last iteration (one copy of the hop's code):
    # the carry holds the last two values, `hop^times` and `hop^(times + 1)`.
    before, after = lax.fori_loop(0, times + 1, lambda _, c: (c[1], hop(c[1])),
                                  vary((init, init)))
    return before, changes(before, after)

  # One test, after the second hop: a chain that carries nothing is still after one hop
  # (free fall, a batch at rest without contacts: the loop stops there), and one that
  # carries something runs its `times` hops without a test each (the test compares
  # every value of the batch: about the cost of a hop).
  def step(state):
    k, _, x, changed = state
    y = hop(x)
    changed = lax.cond(k == 1, lambda: jnp.any(jnp.stack(
        [jnp.any(c) for c in jax.tree_util.tree_leaves(changes(x, y))])), lambda: changed)
    return k + 1, x, y, changed

  last = times + 1 if check else times
  k, before, after, changed = lax.while_loop(
      lambda s: s[3] & (s[0] < last), step,
      vary((jnp.zeros((), jnp.int32), init, init, jnp.ones((), bool))))
  if not check:
    return after
  past = k > times  # Ran the check hop: `before` holds `times` hops, `after` one more.
  out = jax.tree_util.tree_map(lambda b, a: jnp.where(past, b, a), before, after)
  diff = jax.tree_util.tree_map(lambda b, a: past & changed & (b != a), before, after)
  return out, diff


def body_mass(inv_mass: jax.Array, active: jax.Array) -> jax.Array:
  """`[n, B]` mass of active movable bodies, 0 for immovable or padding ones."""
  return jnp.where(active, safe_divide(1.0, inv_mass), 0.0)


class Pass(NamedTuple):
  """What one resolution pass computes.

  Attributes:
    disp: `[2, n, B]` displacement; exactly 0 for immovable bodies.
    exhausted: `[B]` bool, the K hops did not reach the end of a chain that carries
      something (a depth, an approach speed, a push of either channel).
    crushed: `[n, B]` bool, movable bodies in a penetrating jammed contact.
    dvel: with velocities, `[2, n, B]` velocity change from the link impulses.
    impulse: with velocities, `[L, 4, n, B]` compressive impulse per link.
    jammed: `[L, 4, n, B]` bool, links whose two units both lean on immovable bodies.
    shared: with velocities, `[4, n, B]` friction units (`link_impulses`).
    sticking: with velocities, `[L, 4, n, B]` bool, the links those units are made of.
    scaled: `[B]` bool, the energy guard scaled the impulses down.
    short: `[4, n, B]` bool, where the backing's K hops did not reach the chain's end.
  """

  disp: jax.Array
  exhausted: jax.Array
  crushed: jax.Array
  dvel: jax.Array | None
  impulse: jax.Array | None
  jammed: jax.Array
  shared: jax.Array | None
  sticking: jax.Array | None
  scaled: jax.Array
  short: jax.Array


def backing(f: Links, mass: jax.Array, immovable: jax.Array, depth: int, *,
            track_immovable: bool = True, converge: bool = False):
  """Unit masses `M_d` and "leans on something immovable" flags `S_d`, `depth` hops.

  Returns:
    `(unit_mass, leans, short)`: `[4, n, B]` each; `short` says where one hop more
    would still change a value (the chain is longer than `depth`).
  """
  def hop(carry):
    unit, leans = carry
    unit = mass[None] + jnp.sum(jnp.where(f.mask, f.front(unit), 0.0), axis=0)
    if track_immovable:
      leans = immovable[None] | fold("any", f.mask & f.front(leans))
    return unit, leans

  shape = (4,) + mass.shape
  init = (jnp.broadcast_to(mass, shape), jnp.broadcast_to(immovable, shape))
  (unit, leans), short = repeat(hop, init, depth, converge, check=True)
  return unit, leans, short[0] | short[1]


def displacement(f: Links, mass: jax.Array, immovable: jax.Array, *, depth: int,
                 track_immovable: bool = True, vel: jax.Array | None = None,
                 stick: float = 0.0, converge: bool = False) -> Pass:
  """The displacement one pass applies to every body, and with `vel` the contact
  impulses that make the velocities follow it.

  Rules beyond DESIGN.md section 3, each mirrored by `jaxchain.reference`:
  * Crushing: a penetrating contact whose two units both lean on immovable bodies
    cannot be resolved by moving a unit. Each of its movable bodies moves by half its
    depth, alone, so a body squeezed between a floor and a descending ceiling sits
    centred between them, and a row crushed between closing walls shares the overlap
    out over the following steps instead of being pushed through a wall.
  * Gaps within the skin: a push across a gap moves the body in front by the push less
    half the gap. A gap pushed from both sides is closed exactly once, and rounding
    cannot ratchet a stack upward.
  * Velocities: the same units and hops run on a second channel whose "depth" is how
    fast each linked pair approaches (a pair moving apart gives a negative share). On
    chains and trees that is the perfectly inelastic, mass-weighted projection of the
    velocities. It is turned into one compressive impulse per link
    (`link_impulses`); where several bodies push one together (a fan) a body's change is
    the sum of the impulses on its own links, so momentum is conserved in every scene.
    Only relative velocities act: overlap already there adds no velocity.

  Args:
    f: the pass's link table (rows of immovable bodies empty).
    mass: `[n, B]` masses of movable bodies, 0 for the others (`body_mass`).
    immovable: `[n, B]` bool, bodies that never move (immovable or padding).
    depth: chain depth K (static).
    track_immovable: trace the "leans on something immovable" flag (static).
    vel: optional `[2, n, B]` velocities to act on.
    stick: linked bodies whose tangential velocities differ by at most this move
      together for friction (static).
    converge: forward-only hop loops that stop once nothing changes (`repeat`).
  """
  movable = ~immovable
  unit, leans, unit_short = backing(f, mass, immovable, depth, track_immovable=track_immovable,
                                    converge=converge)
  # Entry (d, i, j): j is in front of i along d, i moves along e = d ^ 1; i's unit is the
  # one behind it (M_e(i)), j's the one in front of j (M_d(j)).
  mass_i, leans_i = opposite(unit)[None], opposite(leans)[None]
  mass_j, leans_j = f.front(unit), f.front(leans)
  # Ties (a depth or a push of exactly 0) take the derivative of the piece that pushes
  # only where the link closes (its bodies approach at the start of the pass), else of
  # the piece that does not (`layout.positive`, `layout.push_max`).
  lead = jnp.zeros(f.mask.shape, bool)
  if vel is not None:
    m_dir = along(vel[0], vel[1])
    approach = jnp.where(f.mask, m_dir[None] - f.front(m_dir), 0.0)
    lead = f.mask & (approach > 0)
  depth_now = jnp.where(f.mask, positive(f.overlap, lead), 0.0)
  carries = depth_now > 0
  if vel is not None:
    carries = carries | (approach != 0)
  # Only a link with something to carry (a depth, an approach speed) reports a unit the
  # hops cut short: a resting row longer than K that nothing pushes is exact.
  short_link = opposite(unit_short)[None] | f.front(unit_short)
  backing_short = any_world(carries & short_link)
  jammed = f.mask & leans_i & leans_j
  weight = safe_divide(mass_j, mass_i + mass_j, default=0.5)
  weight = jnp.where(leans_j, 1.0, weight)
  weight = jnp.where(leans_i, 0.0, weight)
  crushed = movable & fold("any", jammed & (depth_now > 0), 2)
  # How far i is pushed along e by this contact beyond j's own push. Across a gap i moves
  # only once j has closed half of it. A jammed contact moves its two bodies only (half
  # its depth each), not their units.
  push_now = jnp.where(jammed, 0.0, depth_now * weight)
  shares = [choose(_share, _share_at_tie, f.overlap, push_now, lead)]
  crush_push = opposite(push_max(jnp.where(jammed, 0.5 * depth_now, 0.0), jammed & lead))
  leads = [lead]
  if vel is not None:
    shares.append(jnp.where(approach > 0, approach * jnp.where(jammed, 0.0, weight), approach))
    leads.append(lead)
  shares = [opposite(s, 1) for s in shares]  # Rows of the reversed table.
  leads = [opposite(x, 1) for x in leads]

  def push_hop(disps):
    out = []
    for disp, share, ahead in zip(disps, shares, leads):
      pushed = push_max(jnp.where(f.back_mask, f.back(disp) + share, 0.0), ahead)
      out.append(jnp.where(movable[None], pushed, 0.0))
    return tuple(out)

  zero = jnp.zeros((4,) + mass.shape, mass.dtype)
  disps, pushed_on = repeat(push_hop, (zero,) * len(shares), depth + 1, converge, check=True)
  push_short = any_world(jnp.stack(pushed_on))
  exhausted = backing_short | push_short  # Bools: no gradient to stop.
  # A tie between the chain's push and the crush rule's takes the chain's derivative.
  disp = jnp.where(movable[None], choose(jnp.maximum, _chain_first, disps[0], crush_push), 0.0)
  net = jnp.stack([disp[0] - disp[1], disp[2] - disp[3]])
  if vel is None:
    B = mass.shape[-1]
    return Pass(net, exhausted, crushed, None, None, jammed, None, None, jnp.zeros((B,), bool),
                unit_short)
  net_vel = jnp.stack([disps[1][0] - disps[1][1], disps[1][2] - disps[1][3]])
  # Links whose bodies slide past each other slower than `stick` move together along
  # the other axis: they make the units friction moves.
  t_dir = along(vel[1], vel[0])
  sliding = jnp.where(f.mask, t_dir[None] - f.front(t_dir), 0.0)
  sticking = f.mask & (jnp.abs(sliding) <= stick)
  impulse, shared, tree, impulse_short = link_impulses(net_vel, f, mass, leans, jammed, sticking,
                                                       depth, converge, lead=lead)
  exhausted = exhausted | impulse_short
  inv_mass = safe_divide(jnp.ones_like(mass), mass)
  free = f.mask & ~jammed

  def velocity_change(lam):
    """On trees the chain's own value plus what the refinement added (no rounding of a
    light body passing on a heavy one's impulse); elsewhere (fans) the impulses, which
    conserve momentum exactly."""
    return jnp.where(tree[None], net_vel + apply_impulses(lam - impulse, inv_mass),
                     apply_impulses(lam, inv_mass))

  # Refinement: Jacobi steps on the inelastic contact problem with mass splitting (a
  # body with k links counts with mass m / k in each), which never raise its energy and
  # keep every impulse >= 0 and equal in both rows.
  k = jnp.sum(f.mask, axis=(0, 1)).astype(mass.dtype)
  split_inv = jnp.broadcast_to(k * inv_mass, unit.shape)
  stiffness = split_inv[None] + f.front(split_inv)

  def refine(_, lam):
    c = velocity_change(lam)
    v_dir = along(vel[0] + c[0], vel[1] + c[1])
    closing = v_dir[None] - f.front(v_dir)
    return jnp.where(free, positive(lam + safe_divide(closing, stiffness), lead), 0.0)

  lam = lax.fori_loop(0, REFINE, refine, vary(impulse))
  change = velocity_change(lam)
  scale = energy_scale(vel, change, lam, f, mass, immovable, m_dir)
  return Pass(net, exhausted, crushed, scale[None, None] * change,
              scale[None, None, None] * lam, jammed, shared, sticking,
              scale < 1, unit_short)


def _share(overlap, push, lead):
  """How far a link pushes (`push` where it overlaps, minus half the gap across a gap)."""
  del lead
  return jnp.where(overlap > 0, push, 0.5 * overlap)


def _share_at_tie(overlap, push, lead):
  """`_share` with the pushing piece at `overlap = 0` where the link leads (closes)."""
  return jnp.where((overlap > 0) | ((overlap == 0) & lead), push, 0.5 * overlap)


def _chain_first(chain_push, crush_push):
  """`max(chain_push, crush_push)`, the chain's piece at a tie."""
  return jnp.where(crush_push > chain_push, crush_push, chain_push)


def energy_scale(vel: jax.Array, change: jax.Array, impulse: jax.Array, f: Links,
                 mass: jax.Array, immovable: jax.Array, v_dir: jax.Array) -> jax.Array:
  """The factor in `[0, 1]` per world (`[B]`) on a velocity update that keeps it from
  adding energy.

  With `change = scale * dv`, the kinetic energy the contacts add beyond the work the
  moving immovable bodies (kinematic platforms) do through their links is
  `f = scale * A + scale^2 B / 2`, `A = sum m v.dv - W`, `B = sum m |dv|^2`. Returns 1
  when `f(1)` is at most the rounding of the kinetic energies involved (`ROUNDING`
  ulps; always, on chains and trees), else the energy-optimal `-A / B` clipped to
  `[0, 1]`.

  Args:
    vel, change: `[2, n, B]`.
    impulse: `[L, 4, n, B]` impulses of entries `(d, i, j)` pushing i against d, or any
      signed per-link impulse whose partner velocity `v_dir` (`[4, n, B]`) gives the
      platform's work.
  """
  fixed = f.bodies(immovable)
  work = -jnp.sum(jnp.where(f.mask & fixed, impulse * f.front(v_dir), 0.0), axis=(0, 1, 2))
  first = world_sum(mass * vel[0] * change[0], mass * vel[1] * change[1]) - work
  second = world_sum(mass * change[0] * change[0], mass * change[1] * change[1])
  after = vel + change
  rounding = ROUNDING * jnp.finfo(vel.dtype).eps * world_sum(
      mass * (vel[0] * vel[0] + after[0] * after[0]), mass * (vel[1] * vel[1] + after[1] * after[1]))
  return jnp.where(first + 0.5 * second <= rounding, 1.0,
                   jnp.clip(safe_divide(-first, second), 0.0, 1.0))


def link_impulses(change: jax.Array, f: Links, mass: jax.Array, leans: jax.Array,
                  jammed: jax.Array, sticking: jax.Array, depth: int, converge: bool = False,
                  lead: jax.Array | None = None):
  """One compressive impulse per link that carries the velocity changes `change`.

  The impulse through link (i, j) along d is the momentum change of everything j pushes
  along d (`Q_d(j) = m_j change_d(j) + sum over j's front of Q / pushers`), or, where
  that side leans on an immovable body (which absorbs an unknown part), the same sum over
  i's side along e. Where both sides are free the smaller is taken; a jammed link
  carries none. On a tree both sides agree and the impulses reproduce `change` exactly.
  The same hops give the friction units: `F_d(i) = m_i + sum over i's front, through
  sticking links, of F_d(j) / (j's sticking pushers)`.

  The momentum sums run `depth` hops and a check hop: a link whose sums one hop more
  would still change (a momentum change farther than `depth` links behind it: the
  impulses of a row hit at one end run through every link of the row) reports the cut.
  The friction units are cut short no later than the backing (`Pass.short`, which
  friction reads).

  `lead` (`[L, 4, n, B]` bool, default none): links whose bodies close on each other; an
  impulse of exactly 0 takes the pushing piece's derivative there (`layout.positive`).

  Returns:
    `(impulse, units, tree, exhausted)`: `[L, 4, n, B]` impulses `>= 0`; `[4, n, B]`
    friction units; `[n, B]` bool, bodies all of whose links got the same impulse from
    both sides (as on a tree); `[B]` bool, a link's momentum sums were cut short.
  """
  dtype = mass.dtype
  count = jnp.sum(f.mask, axis=0).astype(dtype)
  split = opposite(safe_divide(jnp.ones_like(count), count))  # 1 / c_e(j) at (d, j).
  stick_split = opposite(safe_divide(jnp.ones_like(count), jnp.sum(sticking, axis=0).astype(dtype)))
  own_q = mass[None] * along(change[0], change[1])
  own_u = jnp.broadcast_to(mass, count.shape)

  def hop(carry):
    q, units = carry
    ahead_q = jnp.where(leans, 0.0, q * split)
    return (own_q + jnp.sum(jnp.where(f.mask, f.front(ahead_q), 0.0), axis=0),
            own_u + jnp.sum(jnp.where(sticking, f.front(units * stick_split), 0.0), axis=0))

  (q, units), (q_short, _) = repeat(hop, (own_q, own_u), depth, converge, check=True)
  r = q * split  # Momentum per pusher.
  r_j, r_i = f.front(r), opposite(r)[None]
  leans_j, leans_i = f.front(leans), opposite(leans)[None]
  estimate = jnp.where(leans_j, r_i, jnp.where(leans_i, r_j, jnp.minimum(r_j, r_i)))
  agree = leans_j | leans_i | (jnp.abs(r_j - r_i) <= 1e-5 * jnp.maximum(jnp.abs(r_j), jnp.abs(r_i)))
  tree = fold("all", agree | ~f.mask, 2)
  cut = f.mask & ~jammed & (f.front(q_short) | opposite(q_short)[None])
  lead = jnp.zeros(f.mask.shape, bool) if lead is None else lead
  return (jnp.where(f.mask & ~jammed, positive(estimate, lead), 0.0), units, tree,
          any_world(cut))


def apply_impulses(impulse: jax.Array, inv_mass: jax.Array) -> jax.Array:
  """`[2, n, B]` velocity change from compressive link impulses `[L, 4, n, B]`:
  entry `(d, i, .)` pushes i against d."""
  total = jnp.sum(impulse, axis=0)
  return jnp.stack([inv_mass * (total[1] - total[0]), inv_mass * (total[3] - total[2])])


def crush(vel: jax.Array, f: Links, jammed: jax.Array, movable: jax.Array) -> jax.Array:
  """Velocities of crushed bodies: along the axis of a jammed link a movable body takes
  the mean velocity of the bodies it is linked to along that axis (both sides), so it
  gains no velocity of its own into what crushes it."""
  on_axis = jnp.stack([vel[0], vel[0], vel[1], vel[1]])
  partner = jnp.sum(jnp.where(f.mask, f.front(on_axis), 0.0), axis=0)
  count = jnp.sum(f.mask, axis=0).astype(vel.dtype)
  mean = jnp.stack([safe_divide(partner[0] + partner[1], count[0] + count[1]),
                    safe_divide(partner[2] + partner[3], count[2] + count[3])])
  hit = fold("any", jammed)
  hit = jnp.stack([hit[0] | hit[1], hit[2] | hit[3]]) & movable[None]
  return jnp.where(hit, mean, vel)
