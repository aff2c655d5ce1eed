"""The chain resolver: backing-mass propagation, mass split, max-plus push.

One pass over a fixed candidate table (DESIGN.md section 3):

1. contacts (`geometry.contacts`), sorted by direction into a `[l, 4, n]` link
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

# Jacobi refinement steps on the contact impulses after the chain's estimate.
REFINE = 4


def safe_divide(num: jax.Array, den: jax.Array, default: float = 0.0) -> jax.Array:
  """`num / den` where `den > 0`, else `default`, with finite gradients.

  The inner `where` keeps the division away from 0 so that its gradient is finite
  too: a single outer `where` would select the right value but still propagate
  `0 * inf = nan` through the unselected branch.
  """
  ok = den > 0
  return jnp.where(ok, num / jnp.where(ok, den, 1.0), default)


def repeat(hop, init, times: int, converge: bool = False, check: bool = False):
  """`times` applications of `hop` (a pytree to the same pytree) from `init`.

  With `converge` (forward-only), a `while_loop` that stops as soon as a hop changes
  nothing: every hop loop of the resolver is a fixed-point iteration, so the answer is
  the same as `times` hops, bit for bit, but a world whose chains are short stops
  early (under `vmap`, once every world in the batch has). Not reverse-differentiable.

  With `check`, also returns where one hop more would still change a value (a pytree
  of bool arrays like `init`: the chain is longer than `times`). The fixed loop runs
  that hop after the loop; the converging loop knows it without one when it stopped
  early (nothing changes), and otherwise runs it as its last iteration.

  Returns:
    The values after `times` hops, and with `check` the pytree of changes.
  """
  changes = lambda x, y: jax.tree_util.tree_map(jnp.not_equal, x, y)
  if not converge:
    out = lax.fori_loop(0, times, lambda _, x: hop(x), init)
    return (out, changes(out, hop(out))) if check else out

  def step(state):
    k, _, x, _ = state
    y = hop(x)
    changed = jnp.any(jnp.stack([jnp.any(c) for c in jax.tree_util.tree_leaves(changes(x, y))]))
    return k + 1, x, y, changed

  # (k, hop^(k-1), hop^k, whether the last hop changed anything); with `check` one hop
  # past `times`, whose values are dropped.
  last = times + 1 if check else times
  k, before, after, changed = lax.while_loop(
      lambda s: s[3] & (s[0] < last), step,
      (jnp.zeros((), jnp.int32), init, init, jnp.ones((), bool)))
  if not check:
    return after
  past = k > times  # Ran the check hop: `before` holds `times` hops, `after` one more.
  out = jax.tree_util.tree_map(lambda b, a: jnp.where(past, b, a), before, after)
  diff = jax.tree_util.tree_map(lambda b, a: past & changed & (b != a), before, after)
  return out, diff


def body_mass(inv_mass: jax.Array, active: jax.Array) -> jax.Array:
  """`[n]` mass of active movable bodies, 0 for immovable or padding ones."""
  return jnp.where(active, safe_divide(1.0, inv_mass), 0.0)


class Pass(NamedTuple):
  """What one resolution pass computes.

  Attributes:
    disp: `[n, 2]` displacement; exactly 0 for immovable bodies.
    exhausted: bool, the K hops did not reach the end of some chain that carries
      something (one hop more would still have changed a unit mass behind a link with
      a depth, or with `vel` an approach speed, or a push of either channel).
    crushed: `[n]` bool, movable bodies in a penetrating contact whose two units both
      lean on immovable bodies (see `displacement`).
    dvel: with `vel`: `[n, 2]` velocity change from the link impulses; else None.
    impulse: with `vel`: `[l, 4, n]` compressive impulse (momentum) on each link, equal
      in both rows of a movable pair; else None.
    jammed: `[l, 4, n]` bool, links whose two units both lean on immovable bodies.
    shared: with `vel`: `[4, n]` friction units, the mass that slides with each body
      along the other axis (`_link_impulses`); else None.
    sticking: with `vel`: `[l, 4, n]` bool, the links those units are made of.
    scaled: bool, the energy guard scaled the impulses down (`energy_scale < 1`).
    short: `[4, n]` bool, where the K hops of the backing did not reach the end of the
      chain (the units and every hop loop that walks the links from there: impulses,
      friction, are cut short there too).
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


def backing(front: geometry.Links, mass: jax.Array, immovable: jax.Array, depth: int, *,
            track_immovable: bool = True, split: jax.Array | None = None,
            converge: bool = False):
  """Unit masses and "leans on something immovable" flags, `depth` hops.

  `M_d(i) = m_i + sum over j in front of i along d of M_d(j) * split_d(j)` and
  `S_d(i) = immovable_i or any S_d(j)`, both `[4, n]`. With `split=None` (the
  position resolver) every body in front counts whole; `jaxchain.velocity` passes
  `1 / (bodies pushing j along d)`, which shares a body among the units that push it
  together (mass splitting).

  Returns:
    `(unit_mass, leans, short)`: `[4, n]` each; `short` says where one hop more would
    still change a value (the chain is longer than `depth`).
  """
  def hop(carry):
    unit_mass, leans = carry
    share = unit_mass if split is None else unit_mass * split
    unit_mass = mass[None] + front.reduce("sum", share, lambda k, x: jnp.where(front.mask[k], x, 0.0))
    if track_immovable:
      leans = immovable[None] | front.reduce("any", leans, lambda k, x: front.mask[k] & x)
    return unit_mass, leans

  unit_mass = jnp.broadcast_to(mass, (geometry.NUM_DIRECTIONS,) + mass.shape)
  leans = jnp.broadcast_to(immovable, unit_mass.shape)
  (unit_mass, leans), short = repeat(hop, (unit_mass, leans), depth, converge, check=True)
  return unit_mass, leans, short[0] | short[1]


def behind(x: jax.Array) -> jax.Array:
  """`[..., 4, n]` -> `[..., 1, 4, n]`: for entry `(., d, i)` of a link table, the
  value of row i along the opposite direction (the unit behind i when i pushes along d)."""
  return geometry.opposite(x, -2)[..., None, :, :]


def displacement(front: geometry.Links, mass: jax.Array, immovable: jax.Array, *, depth: int,
                 track_immovable: bool = True, vel: jax.Array | None = None,
                 stick: float = 0.0, converge: bool = False) -> Pass:
  """The displacement one resolution pass applies to every body, and with `vel` the
  contact impulses that make the velocities follow it.

  Rules beyond DESIGN.md section 3, each mirrored by `jaxchain.reference`:

  * Contact axis: from the motion since the start of the step for pairs separated
    there (`geometry.contacts`, in the link table `front`).
  * Crushing: a penetrating contact whose two units both lean on immovable bodies
    cannot be resolved by moving a unit. Each of its two bodies, if movable, moves by
    half its depth, alone (immovable ones still never move), so a body squeezed
    between a floor and a descending ceiling sits centred between them, overlapping
    both equally, and a row crushed between closing walls shares the overlap out
    along the row over the following steps instead of being pushed through a wall.
    Its movable bodies are reported in `Pass.crushed`.
  * Gaps within the skin: a push across a gap moves the body in front by the push
    less half the gap. A gap pushed from both sides is thus closed exactly once, and a
    one-sided push leaves half of it open, so rounding cannot ratchet a stack upward.

  Velocities (with `vel`): the same units and max-plus hops run on a second channel
  whose "depth" is how fast each linked pair approaches, `(v_i - v_j) . n_d` (a pair
  moving apart gives a negative share, like a gap). On chains and trees that channel
  is the perfectly inelastic, mass-weighted projection of the velocities: a hit ends
  at the common velocity and a push through a row moves the row as one. It is then
  turned into one compressive impulse per link (`_link_impulses`). Where several
  bodies push one together (a fan, where the max-plus channel is not the projection
  and would lose momentum) a body's velocity change is the sum of the impulses on its
  own links, equal and opposite on the two bodies of a link, so total momentum is
  conserved to float rounding in every scene; on chains and trees the impulses and
  the channel agree and the channel's value is used (free of the rounding the impulse
  sums carry when a light body passes on a heavy one's impulse). Immovable bodies
  absorb what reaches them. Only relative velocities act, so overlap that was there at
  the start adds no velocity.

  Args:
    front: the pass's link table (`geometry.links`), rows of immovable bodies empty.
    mass: `[n]` masses of movable bodies, 0 for the others (`body_mass`).
    immovable: `[n]` bool, bodies that never move (immovable or padding).
    depth: chain depth K (static).
    track_immovable: trace the "leans on something immovable" flag (static);
      `False` is only correct when no linked body is immovable.
    vel: optional `[n, 2]` velocities (after gravity and input) to act on.
    stick: linked bodies whose tangential velocities differ by at most this count as
      moving together for friction (static).
    converge: forward-only hop loops that stop once nothing changes (`repeat`).

  Returns:
    A `Pass`.
  """
  movable = ~immovable
  dtype = mass.dtype
  back = front.reversed()  # [l, 4, n]: j behind i along d, i.e. j pushes i along d.

  # 2. Backing: unit mass (and immovable flag) in front of each body, K hops.
  unit_mass, leans, unit_short = backing(front, mass, immovable, depth,
                                         track_immovable=track_immovable, converge=converge)

  # 3. Split each contact. Entry (d, i, j): j is in front of i along d, i moves along
  # e = d ^ 1; i's unit is the one behind it (M_e(i)), j's the one in front of j (M_d(j)).
  mass_i, leans_i = behind(unit_mass), behind(leans)
  mass_j, leans_j = front.gather(unit_mass), front.gather(leans)
  depth_now = jnp.where(front.mask, jnp.maximum(front.overlap, 0.0), 0.0)
  carries = depth_now > 0
  if vel is not None:
    m_dir = _along(vel)
    approach = jnp.where(front.mask, m_dir[None] - front.gather(m_dir), 0.0)
    carries = carries | (approach != 0)
  # Only the units a link with something to carry (a depth to split, with `vel` an
  # approach speed: the impulses walk the same units) splits by matter for the report:
  # a resting row longer than K that nothing pushes is exact.
  backing_short = jnp.any(carries & (behind(unit_short) | front.gather(unit_short)))
  jammed = front.mask & leans_i & leans_j
  weight = safe_divide(mass_j, mass_i + mass_j, default=0.5)
  weight = jnp.where(leans_j, 1.0, weight)
  weight = jnp.where(leans_i, 0.0, weight)
  crushed = movable & jnp.any(jammed & (depth_now > 0), axis=(0, 1))
  # [k, 4, n, l]: how far i is pushed along e by this contact beyond j's own push. Across
  # a gap (a link within the skin) i moves only once j has closed half of it. A crushed
  # contact moves its two bodies only, half its depth each, not their units (which
  # lean on immovable bodies): a crush spreads over the jammed row step by step.
  shares = [jnp.where(front.overlap > 0, jnp.where(jammed, 0.0, depth_now * weight),
                      0.5 * front.overlap)]
  crush_push = jnp.max(jnp.where(jammed, 0.5 * depth_now, 0.0), axis=0, initial=0.0)
  crush_push = geometry.opposite(crush_push)
  if vel is not None:
    shares.append(jnp.where(approach > 0, approach * jnp.where(jammed, 0.0, weight), approach))
  share = geometry.opposite(jnp.stack(shares), 2)  # Rows of `back`: i pushed along d by j.

  # 4. Forward push, K + 1 hops of max-plus along each direction.

  def push_hop(disp, share):
    pushed = back.reduce("max", disp, lambda k, x: jnp.where(back.mask[k], x + share[:, k], 0.0))
    return jnp.where(movable[None, None], pushed, 0.0)

  disp = jnp.zeros((share.shape[0],) + unit_mass.shape, dtype)
  disp, pushed_on = repeat(lambda x: push_hop(x, share), disp, depth + 1, converge, check=True)
  # Reporting only: a push of either channel (positions, approach speeds) that one hop
  # more would still change was cut short.
  push_short = jnp.any(pushed_on)
  exhausted = lax.stop_gradient(backing_short | push_short)
  disp = disp.at[0].set(jnp.where(movable[None], jnp.maximum(disp[0], crush_push), 0.0))
  net = jnp.stack([disp[:, 0] - disp[:, 1], disp[:, 2] - disp[:, 3]], axis=-1)  # [k, n, 2]
  if vel is None:
    return Pass(net[0], exhausted, crushed, None, None, jammed, None, None, jnp.zeros((), bool),
                unit_short)
  # Links whose two bodies slide past each other slower than `stick` move
  # together along the other axis: they form the units friction moves.
  t_dir = _along(vel[:, ::-1])  # Tangential velocity: y for links along x, x along y.
  sliding = jnp.where(front.mask, t_dir[None] - front.gather(t_dir), 0.0)
  sticking = front.mask & (jnp.abs(sliding) <= stick)
  impulse, shared, tree = _link_impulses(net[1], front, mass, leans, jammed, sticking, depth,
                                         converge)
  inv_mass = safe_divide(jnp.ones_like(mass), mass)
  free = front.mask & ~jammed

  def velocity_change(lam):
    """Where the impulses agree with the chain (trees) the chain's own value plus what
    the refinement added: the same velocities, without the rounding of a light body
    passing on a heavy one's impulse (a difference of two large numbers). Elsewhere
    (fans) the impulses themselves, which conserve momentum exactly."""
    return jnp.where(tree[:, None], net[1] + apply_impulses(lam - impulse, inv_mass),
                     apply_impulses(lam, inv_mass))

  # Refinement: Jacobi steps on the inelastic contact problem with mass splitting (a
  # body with k links counts with mass m / k in each), which never raise its energy and
  # keep every impulse >= 0 and equal in both rows: on a tree the impulses are already
  # the solution and stay; in a fan they pull a body the estimate left approaching or
  # flying apart back to rest against its partners.
  k = jnp.sum(front.mask, axis=(0, 1)).astype(dtype)
  split_inv = jnp.broadcast_to(k * inv_mass, unit_mass.shape)
  stiffness = split_inv[None] + front.gather(split_inv)

  def refine(_, lam):
    v_dir = _along(vel + velocity_change(lam))
    closing = v_dir[None] - front.gather(v_dir)
    return jnp.where(free, jnp.maximum(lam + safe_divide(closing, stiffness), 0.0), 0.0)

  impulse_final = lax.fori_loop(0, REFINE, refine, impulse)
  change = velocity_change(impulse_final)
  scale = energy_scale(vel, change, impulse_final, front, mass, immovable, m_dir)
  return Pass(net[0], exhausted, crushed, scale * change, scale * impulse_final, jammed, shared,
              sticking, lax.stop_gradient(scale < 1), unit_short)


# Ulps of the kinetic energy below which `energy_scale` takes an energy change for
# rounding (the tests' energy tolerance is 16 ulps of every term).
ROUNDING = 2.0


def energy_scale(vel: jax.Array, change: jax.Array, impulse: jax.Array, front: geometry.Links,
                 mass: jax.Array, immovable: jax.Array, v_dir: jax.Array) -> jax.Array:
  """The factor in `[0, 1]` on a velocity update that keeps it from adding energy.

  With `change = scale * dv`, the kinetic energy the contacts add, beyond the work the
  moving immovable bodies (kinematic platforms) do through their links, is
  `f = scale * A + scale^2 B / 2` with `A = sum m v.dv - W` and `B = sum m |dv|^2`.
  Returns 1 when `f(1)` is at most the rounding of the kinetic energies involved
  (`ROUNDING` ulps of `sum m (|v|^2 + |v + dv|^2)`; always, on chains and trees), else
  the energy-optimal `-A / B` clipped to `[0, 1]`, for the whole world. Without that
  tolerance, bodies that already move as one (a column coasting in contact) gave
  `f(1)` of a few ulps above 0 from rounding, and the world was damped and flagged
  `IMPULSES_SCALED` for nothing.

  Args:
    vel: `[n, 2]` velocities before the update; `change`: `[n, 2]` the update.
    impulse: `[l, 4, n]` impulses of entries `(d, i, j)`, pushing i against d (normal
      impulses; `v_dir` the velocities along each direction, `[4, n]`), or any signed
      per-link impulse whose partner velocity `v_dir` gives the platform's work.
  """
  dtype = vel.dtype
  fixed = front.gather_bodies(immovable)
  platform_work = -jnp.sum(jnp.where(front.mask & fixed, impulse * front.gather(v_dir), 0.0))
  first = jnp.sum(mass[:, None] * vel * change) - platform_work
  second = jnp.sum(mass[:, None] * change * change)
  after = vel + change
  rounding = ROUNDING * jnp.finfo(dtype).eps * jnp.sum(mass[:, None] * (vel * vel + after * after))
  return jnp.where(first + 0.5 * second <= rounding, 1.0,
                   jnp.clip(safe_divide(-first, second), 0.0, 1.0))


def _along(x: jax.Array) -> jax.Array:
  """`[n, 2]` -> `[4, n]`: the component along each direction (+x, -x, +y, -y)."""
  return jnp.stack([x[:, 0], -x[:, 0], x[:, 1], -x[:, 1]])


def _link_impulses(change: jax.Array, front: geometry.Links, mass: jax.Array,
                   leans: jax.Array, jammed: jax.Array, sticking: jax.Array, depth: int,
                   converge: bool = False):
  """One compressive impulse per link that carries the velocity changes `change`.

  The impulse through link (i, j) along d is the momentum change of everything j
  pushes along d (j and the bodies in front of it, `Q_d(j) = m_j change_d(j) + sum
  over j's front of Q / pushers`, a body shared by several pushers split equally
  among them), or, where that side leans on an immovable body (which absorbs an
  unknown part), the same sum over i's side along e. Where both sides are free the
  smaller of the two is taken; a jammed link carries none. On a tree both sides agree
  and the impulses reproduce `change` exactly.

  The same hops also give the friction units: `F_d(i) = m_i + sum over i's front,
  through sticking links only, of F_d(j) / (j's sticking pushers)`, the mass that
  slides with i along the other axis (`jaxchain.velocity.friction`).

  Returns:
    `(impulse, units, tree)`: `[l, 4, n]` impulses (momentum), `>= 0`, equal in the
    rows of both bodies; `[4, n]` friction units; `[n]` bool, bodies all of whose links
    got the same impulse from both sides (as on a tree).
  """
  dtype = mass.dtype
  count = jnp.sum(front.mask, axis=0).astype(dtype)  # [4, n]: c_d(i).
  split = geometry.opposite(safe_divide(jnp.ones_like(count), count))  # 1 / c_e(j) at (d, j).
  stick_count = jnp.sum(sticking, axis=0).astype(dtype)
  stick_split = geometry.opposite(safe_divide(jnp.ones_like(count), stick_count))
  own = jnp.stack([mass[None] * _along(change), jnp.broadcast_to(mass, count.shape)])
  mask = jnp.stack([front.mask, sticking])

  def hop(carry):
    q, units = carry
    ahead = jnp.stack([jnp.where(leans, 0.0, q * split), units * stick_split])
    total = own + front.reduce("sum", ahead, lambda k, x: jnp.where(mask[:, k], x, 0.0))
    return total[0], total[1]

  q, units = repeat(hop, (own[0], own[1]), depth, converge)
  r = q * split  # Momentum per pusher.
  r_j, r_i = front.gather(r), behind(r)
  leans_j, leans_i = front.gather(leans), behind(leans)
  both = jnp.minimum(r_j, r_i)
  impulse = jnp.where(leans_j, r_i, jnp.where(leans_i, r_j, both))
  # Where both sides are free the two sums agree on a tree (up to rounding).
  agree = leans_j | leans_i | (jnp.abs(r_j - r_i) <= 1e-5 * jnp.maximum(jnp.abs(r_j), jnp.abs(r_i)))
  ok = jnp.all(agree | ~front.mask, axis=(0, 1))
  return jnp.where(front.mask & ~jammed, jnp.maximum(impulse, 0.0), 0.0), units, ok


def apply_impulses(impulse: jax.Array, inv_mass: jax.Array) -> jax.Array:
  """`[n, 2]` velocity change from compressive link impulses `[l, 4, n]`:
  entry `(d, i, .)` pushes i against d."""
  total = jnp.sum(impulse, axis=-3)  # [4, n]
  return inv_mass[:, None] * jnp.stack([total[1] - total[0], total[3] - total[2]], axis=-1)
