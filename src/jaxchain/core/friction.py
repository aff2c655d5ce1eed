"""Friction, batch minor: Coulomb impulses per link, acting on units, with mass splitting.

The normal impulses come from the chain resolver (`chain.displacement` with
velocities). Friction adds, per link, the impulse that stops its two units' relative
sliding, each unit counted with mass `S / k` (k: the body's active friction links;
Tonge et al. 2012), clipped to `mu_pair * normal`, equal and opposite on the two
bodies. So friction never reverses a relative tangential velocity, conserves momentum,
and (with the energy guard) never adds kinetic energy beyond what a moving platform
gives through its links.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jax import lax

from jaxchain.core import chain
from jaxchain.core.contacts import Links
from jaxchain.core.layout import (any_world, batch_any, choose, fold, opposite, pair_coefficient,
                                  safe_divide, vary)

# Linked bodies whose tangential velocities differ by at most this (units per second)
# move together for friction: they are one unit, and friction on the bottom one stops
# them all.
STICK = 1e-3
# A link takes part in friction (and counts for mass splitting) only while its bodies
# slide past each other faster than this: float rounding of a sideways velocity
# neither makes friction act nor splits a body's mass among its neighbours.
SLIP = 1e-6
# Solves of the friction impulses per pass: the first on the chain's units, each later
# one after a holding test dropped the links that slip (`friction`): up to two slip
# rounds.
ROUNDS = 3


def friction(vel: jax.Array, f: Links, normal: jax.Array, coefficient: jax.Array,
             shared: jax.Array, sticking: jax.Array, mass: jax.Array, *, depth: int,
             converge: bool = False, short: jax.Array | None = None):
  """Coulomb friction impulses per link, acting on units, with mass splitting.

  Link `(d, i, j)` rubs along the other axis. What moves with i there is i's unit on its
  far side (`shared[e, i]`: the boxes stacked on a box that slides on a floor), and
  what moves with j is j's unit `shared[d, j]`, both made of the links that stick. The
  impulse stops the two units' relative sliding, clipped to the link's budget
  `mu_pair * normal` (`mu_pair = min(mu_i, mu_j)`: `layout.pair_coefficient`, with a
  finite derivative at 0); each unit
  takes it rigidly, its bodies reached in `depth` hops.

  Friction acts per link: a unit moves as one only through links whose own Coulomb
  budget holds the shear that moving as one needs (`holding`). The impulses are solved
  on the units the chain built, then a holding test: of the sticking links that would
  need more shear than their budget, each body's most overloaded one (largest need
  over budget, a frictionless link first) slips, carries its budget the way it was
  needed (kinetic friction) and leaves the units, and the impulses are solved again:
  `ROUNDS` solves, up to `ROUNDS - 1` slip rounds, each run only where the last one
  dropped a link (a batch skips it where no world did). So a frictionless box on a
  sliding stack keeps sliding, the box under it is held by its own link, and a link
  never carries more than its budget once another has slipped. A link found slipping
  only after the last round keeps the units of that round.

  Args:
    vel: `[2, n, B]` velocities after the normal impulses.
    f: the link table the normal impulses were computed on.
    normal: `[L, 4, n, B]` normal impulse per link.
    coefficient: `[n, B]` friction coefficient per body.
    shared: `[4, n, B]` friction units (`chain.Pass.shared`).
    sticking: `[L, 4, n, B]` bool, the links those units are made of.
    mass: `[n, B]` masses of movable bodies, 0 for the others.
    depth: hops a unit's motion travels (static).
    short: optional `[4, n, B]` bool, where the resolver's hops did not reach a chain's
      end (`chain.Pass.short`): the friction units are cut short there too.

  Returns:
    `(vel, scaled, exhausted)`: `[2, n, B]` velocities, and `[B]` bools: the energy
    guard scaled the update down; a link that rubs belongs to a unit the hops did not
    reach the end of (`DEPTH_EXHAUSTED`).
  """
  dtype = vel.dtype
  tangent = jnp.stack([vel[1], vel[1], vel[0], vel[0]])  # [4, n, B]
  sliding = jnp.where(f.mask, tangent[None] - f.front(tangent), 0.0)
  mu_pair = pair_coefficient(coefficient[None, None], f.bodies(coefficient))
  budget = jnp.where(f.mask, mu_pair * normal, 0.0)
  rubbing = (budget > 0) & (jnp.abs(sliding) > SLIP)
  movable = fold("any", shared > 0)[None]
  per_body = lambda links: jnp.broadcast_to(jnp.sum(links, axis=(0, 1)).astype(dtype),
                                            tangent.shape)
  k = per_body(rubbing)
  # Derivatives: a link with a budget that slides by at most `SLIP` (at rest: `SLIP` only
  # keeps rounding from acting) takes the derivative of the impulse that stops it, with
  # mass splitting over its bodies' rubbing links and itself (the piece a perturbation
  # that makes it slide steps into); every other link its impulse's own.
  resting = (budget > 0) & ~rubbing

  def solve(shared, sticking, slip):
    """Impulses on the units `shared`, the slipped links carrying `slip`. Returns
    `(impulse, total, count)`: `total` is each body's tangential velocity change as part
    of its unit along each direction, `count` its sticking pushers along it."""
    unit_i = opposite(shared)  # At (d, i): i's unit along e.

    free = f.mask & (budget == 0) & (jnp.abs(sliding) > SLIP) & ~sticking
    impulse = choose(_impulses, _impulses_at_rest, f, sliding, unit_i, shared, budget, slip,
                     rubbing, k, resting, free)
    source = opposite(safe_divide(-jnp.sum(impulse, axis=0), unit_i))  # At (e, i).
    carries = opposite(sticking, 1)  # Rows of the reversed table, sticking.
    count = jnp.sum(carries, axis=0).astype(dtype)

    def hop(total):  # A unit moves rigidly: each body takes the mean of its pushers'.
      behind = jnp.sum(jnp.where(carries, f.back(total), 0.0), axis=0)
      return jnp.where(movable, source + safe_divide(behind, count), 0.0)

    total = chain.repeat(hop, jnp.where(movable, source, 0.0), depth, converge)
    return impulse, total, count

  def test(sticking, slip, total, shared, count):
    """The holding test: each body's most overloaded slipping link leaves the units and
    carries its budget. Returns the new `(sticking, slip)` and `[B]` whether a world
    dropped a link."""
    need = holding(f, total, shared, count)
    over = sticking & (jnp.abs(need) > budget)
    ratio = jnp.where(over, safe_divide(jnp.abs(need), budget, jnp.inf), 0.0)
    # [n, B]: each body's most overloaded link. An XLA reduction, so it is computed once:
    # as elementwise operations XLA fuses it into the gather below, which recomputes it
    # for every link it reads, unvectorised (a quarter of a settled room's step).
    worst = jnp.max(ratio, axis=(0, 1))
    dropped = over & (ratio >= worst[None, None]) & (ratio >= f.bodies(worst))
    slip = jnp.where(dropped, jnp.clip(need, -budget, budget), slip)
    return sticking & ~dropped, slip, any_world(dropped)

  # Round 0 solves on the chain's units; each slip round tests the last solve, and
  # where a world dropped a link solves again on the units without it (a batch skips
  # the solve where no world did). The slip rounds are one loop: one copy of their code.
  impulse, total, count = solve(shared, sticking, jnp.zeros_like(budget))

  def slip_round(_, carry):
    sticking, slip, impulse, total, count, shared = carry
    held, slip, again = test(sticking, slip, total, shared, count)

    def work():
      units_now = units(f, mass, held, depth, converge)
      return (held, slip) + solve(units_now, held, slip) + (units_now,)

    return lax.cond(batch_any(again), work, lambda: carry)

  carry = (sticking, jnp.zeros_like(budget), impulse, total, count, shared)
  carry = lax.fori_loop(1, ROUNDS, slip_round, vary(carry))
  _, _, impulse, total, _, _ = carry
  # Units along x (e = 0, 1) slide along y, units along y along x.
  change = jnp.stack([total[2] + total[3], total[0] + total[1]])
  scale = chain.energy_scale(vel, change, impulse, f, mass, mass == 0, tangent)
  exhausted = jnp.zeros(scale.shape, bool)
  if short is not None:
    exhausted = any_world(rubbing & (opposite(short)[None] | f.front(short)))
  return vel + scale[None, None] * change, scale < 1, exhausted


def _stops(f: Links, sliding, unit_i, shared, budget, k):
  """The impulses that stop each link's sliding, with mass splitting over `k` links,
  clipped to the budgets."""
  inv_i = safe_divide(k, unit_i)
  inv_j = f.front(safe_divide(k, shared))
  return jnp.clip(safe_divide(sliding, inv_i[None] + inv_j), -budget, budget)


def _impulses(f, sliding, unit_i, shared, budget, slip, rubbing, k, resting, free):
  """Each link's friction impulse: the stopping one where it rubs, else `slip`."""
  del resting, free
  stop = _stops(f, sliding, unit_i, shared, budget, k)
  return jnp.where(rubbing & (slip == 0), stop, slip)


def _impulses_at_rest(f, sliding, unit_i, shared, budget, slip, rubbing, k, resting, free):
  """`_impulses`, with the resting links (a budget, sliding within `SLIP`) stopped too;
  and the sliding links without a budget (`free`: a pair coefficient of 0, outside the
  units) carrying it the way they slide, `sign(sliding) * budget` (0): the piece a
  coefficient raised from 0 steps into, where the link rubs at its budget (`jnp.clip`
  would give half of that derivative at a budget of 0, or none).

  A resting link's derivative is that of the impulse that stops it, each of its bodies
  splitting its mass over its rubbing links and this one (`k + 1`): the piece a
  perturbation that makes this link slide enters, the bodies' other resting links
  staying at rest. So a perturbation that reaches one body of a resting stack (a top box
  pushed sideways, or, the step after, the stack moving on as one over its floor) takes
  the piece it enters (issue 43 item 0: with every link with a budget counted, the lower
  box of two at rest moved twice as far in the derivative as in the finite differences:
  friction stopped only part of the motion at each step), and a stack sliding as one on
  its floor splits each body's mass over the floor link that rubs and the resting link.
  A perturbation that makes several resting links of one body slide at once enters a
  piece with more mass splitting, which this derivative does not take."""
  rest = _stops(f, sliding, unit_i, shared, budget, k + 1.0)
  out = jnp.where(resting & (slip == 0), rest,
                  _impulses(f, sliding, unit_i, shared, budget, slip, rubbing, k, resting, free))
  return jnp.where(free & (slip == 0), jnp.sign(sliding) * budget, out)


def holding(f: Links, total: jax.Array, shared: jax.Array, count: jax.Array) -> jax.Array:
  """`[L, 4, n, B]`: the tangential impulse each link must carry for the units to move
  as one, signed like a friction impulse (entry `(d, i, j)`: momentum from i's side to
  j's); equal and opposite in the rows of the link's two bodies."""
  per_pusher = safe_divide(shared, count)
  to_j = total[None] * f.front(per_pusher)
  to_i = f.front(opposite(total)) * opposite(per_pusher)[None]
  return to_j - to_i


def units(f: Links, mass: jax.Array, sticking: jax.Array, depth: int,
          converge: bool) -> jax.Array:
  """`[4, n, B]` friction units made of the `sticking` links (as
  `chain.link_impulses` builds them)."""
  split = opposite(safe_divide(1.0, jnp.sum(sticking, axis=0).astype(mass.dtype)))
  own = jnp.broadcast_to(mass, split.shape)

  def hop(u):
    return own + jnp.sum(jnp.where(sticking, f.front(u * split), 0.0), axis=0)

  return chain.repeat(hop, own, depth, converge)
