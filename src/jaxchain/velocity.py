"""Friction and crushing: what acts on velocities after the contact impulses.

The normal (contact) impulses come from the chain resolver itself
(`chain.displacement` with `motion`): they are exact on chains and trees, carry a
push through a row of boxes, and conserve momentum in every scene. This module adds:

* **Friction** (`friction`): Coulomb impulses per link, equal and opposite on the two
  bodies, at most `mu * normal impulse` of that link, computed with mass splitting
  (Tonge et al. 2012): a body with k active friction links counts with mass `m / k`
  in each. Each impulse is then at most what stops its link's relative sliding, so
  friction never reverses a relative tangential velocity, and the whole update is a
  majorised Jacobi step of the friction problem from zero: it never adds kinetic
  energy relative to what the bodies rub against, and conserves momentum.
* **Crushing** (`crush`): a body squeezed between two units that lean on immovable
  bodies cannot be pushed out; along that axis it takes the mean velocity of the
  bodies it is linked to, so it gains no velocity of its own into what crushes it.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jax import lax

from jaxchain import chain, geometry
from jaxchain.chain import safe_divide

# Linked bodies whose tangential velocities differ by at most this (units per second)
# move together for friction: they are one unit, and friction on the bottom one
# stops them all.
STICK = 1e-3
# A link takes part in friction (and counts for mass splitting) only while its bodies
# slide past each other faster than this: float rounding of a sideways velocity
# neither makes friction act nor splits a body's mass among its neighbours.
SLIP = 1e-6


def friction(vel: jax.Array, front: geometry.Links, normal: jax.Array, coefficient: jax.Array,
             shared: jax.Array, sticking: jax.Array, mass: jax.Array, *, depth: int,
             converge: bool = False,
             short: jax.Array | None = None) -> tuple[jax.Array, jax.Array, jax.Array]:
  """Coulomb friction impulses per link, acting on units, with mass splitting.

  Link `(d, i, j)` rubs along the other axis. What moves with i there is i's unit on
  its far side, the bodies pressing i into j (`shared[e, i]`, e opposite to d: the
  boxes stacked on a box that slides on a floor), and what moves with j is j's unit
  `shared[d, j]`, both made of the links that stick (whose bodies slide past each
  other slower than `STICK`; a box sliding under another is not part of its unit). The
  impulse is the one that stops the two units' relative sliding, each unit counted
  with mass `S / k` (k: the body's active friction links, those with a normal impulse
  that slide faster than `SLIP`; Tonge et al. 2012), clipped to `mu_pair * normal`;
  each unit takes it rigidly, its bodies reached in `depth` hops as the resolver
  reaches them (a body on several supports takes the mean of theirs, the share its
  unit mass counted). So a sliding stack stops as one on its floor's friction, and
  momentum is conserved. An energy guard (`chain.energy_scale`) scales the update
  down, per world, if it would ever add energy beyond what moving platforms give.

  Friction acts per link: a unit moves as one only through links whose own Coulomb
  budget holds the shear that moving as one needs (`_holding`). The impulses are
  solved once on the units the chain built; a sticking link whose share of its unit's
  velocity change needs more shear than `mu_pair * normal` slips, and the impulses are
  solved again on the units without it. The slipping link is then an ordinary link:
  it rubs (at most its budget, never reversing its sliding) once its bodies slide
  apart, from the next pass or step. So a frictionless box on a sliding stack keeps
  sliding, one on a box held by friction on a slope slides down it, and the motion
  depends on every link's coefficient.

  Args:
    vel: `[n, 2]` velocities after the normal impulses.
    front: the link table the normal impulses were computed on.
    normal: `[l, 4, n]` normal impulse per link (momentum units).
    coefficient: `[n]` friction coefficient per body; a pair uses the geometric mean
      `sqrt(mu_i mu_j)` (as Box2D does): 0 if either is 0.
    shared: `[4, n]` friction units (`chain.Pass.shared`), 0 for immovable bodies.
    sticking: `[l, 4, n]` bool, the links those units are made of (`chain.Pass.sticking`).
    mass: `[n]` masses of movable bodies, 0 for the others (`chain.body_mass`).
    depth: hops a unit's motion travels (static).
    short: optional `[4, n]` bool, where the resolver's `depth` hops did not reach the
      end of a chain (`chain.Pass.short`): the friction units, made of a subset of the
      same links, are cut short there too.

  Returns:
    `(vel, scaled, exhausted)`: `[n, 2]` velocities (immovable bodies unchanged),
    whether the energy guard scaled the update down, and whether a link that rubs
    belongs to a unit the `depth` hops did not reach the end of (`DEPTH_EXHAUSTED`).
  """
  dtype = vel.dtype
  tangent = jnp.stack([vel[:, 1], vel[:, 1], vel[:, 0], vel[:, 0]])  # [4, n]
  sliding = jnp.where(front.mask, tangent[None] - front.gather(tangent), 0.0)
  mu_pair = _safe_sqrt(coefficient[None, None] * front.gather_bodies(coefficient))
  budget = jnp.where(front.mask, mu_pair * normal, 0.0)
  rubbing = (budget > 0) & (jnp.abs(sliding) > SLIP)
  back = front.reversed()
  movable = jnp.any(shared > 0, axis=0)[None]

  def solve(shared, sticking):
    """Impulses on the units `shared` (made of `sticking` links). Returns `(impulse
    [l, 4, n], total [4, n], count [4, n])`: `total` is each body's tangential velocity
    change as part of its unit along each direction, `count` its sticking pushers
    along it."""
    k = jnp.broadcast_to(jnp.sum(rubbing, axis=(0, 1)).astype(dtype), tangent.shape)  # [4, n]
    unit_i = geometry.opposite(shared)  # [4, n]: at (d, i), i's unit along e.
    inv_i = safe_divide(k, unit_i)  # k_i / S_e(i): 0 for an immovable body.
    inv_j = front.gather(safe_divide(k, shared))  # k_j / S_d(j).
    stop = jnp.clip(safe_divide(sliding, inv_i[None] + inv_j), -budget, budget)
    impulse = jnp.where(rubbing, stop, 0.0)
    # Entry (d, i): i's unit along e changes its tangential velocity by -impulse / S_e(i).
    source = geometry.opposite(safe_divide(-jnp.sum(impulse, axis=0), unit_i))  # At (e, i).
    carries = geometry.opposite(sticking, 1)  # Rows of `back`: k behind j, sticking.
    count = jnp.sum(carries, axis=0).astype(dtype)  # Sticking bodies behind each body.

    def hop(total):  # A unit moves rigidly: each body takes the mean of its pushers'.
      behind = back.reduce("sum", total, lambda k, x: jnp.where(carries[k], x, 0.0))
      return jnp.where(movable, source + safe_divide(behind, count), 0.0)

    total = chain.repeat(hop, jnp.where(movable, source, 0.0), depth, converge)
    return impulse, total, count

  impulse, total, count = solve(shared, sticking)
  holds = jnp.abs(_holding(front, total, shared, count)) <= budget
  sticking = sticking & holds
  impulse, total, _ = solve(_units(front, mass, sticking, depth, converge), sticking)
  # Units along x (e = 0, 1) slide along y, units along y along x.
  change = jnp.stack([total[2] + total[3], total[0] + total[1]], axis=-1)
  # Energy guard, as for the normal impulses: friction may only take energy, beyond
  # what a moving platform gives through its links.
  scale = chain.energy_scale(vel, change, impulse, front, mass, mass == 0, tangent)
  exhausted = jnp.zeros((), bool)
  if short is not None:
    exhausted = jnp.any(rubbing & (chain.behind(short) | front.gather(short)))
  return vel + scale * change, lax.stop_gradient(scale < 1), lax.stop_gradient(exhausted)


def _holding(front: geometry.Links, total: jax.Array, shared: jax.Array,
             count: jax.Array) -> jax.Array:
  """`[l, 4, n]`: the tangential impulse each link must carry for the units to move
  as one, signed like a friction impulse (entry `(d, i, j)`: momentum from i's side to
  j's). Along d, j's unit `shared[d, j]` takes i's change `total[d, i]` (its share,
  over j's `count[d, j]` sticking pushers); along e the same from j to i. Equal and
  opposite in the rows of the link's two bodies."""
  per_pusher = safe_divide(shared, count)  # [4, n]
  to_j = total[None] * front.gather(per_pusher)
  to_i = front.gather(geometry.opposite(total)) * geometry.opposite(per_pusher)[None]
  return to_j - to_i


def _units(front: geometry.Links, mass: jax.Array, sticking: jax.Array, depth: int,
           converge: bool) -> jax.Array:
  """`[4, n]` friction units made of the `sticking` links: `F_d(i) = m_i + sum over
  i's front, through sticking links, of F_d(j) / (j's sticking pushers)` (as
  `chain._link_impulses` builds them)."""
  split = geometry.opposite(safe_divide(1.0, jnp.sum(sticking, axis=0).astype(mass.dtype)))
  own = jnp.broadcast_to(mass, split.shape)

  def hop(units):
    return own + front.reduce("sum", units * split, lambda k, x: jnp.where(sticking[k], x, 0.0))

  return chain.repeat(hop, own, depth, converge)


def _safe_sqrt(x: jax.Array) -> jax.Array:
  """`sqrt(x)` for `x >= 0` with a finite gradient at 0 (where it is 0)."""
  ok = x > 0
  return jnp.where(ok, jnp.sqrt(jnp.where(ok, x, 1.0)), 0.0)


def crush(vel: jax.Array, front: geometry.Links, jammed: jax.Array, movable: jax.Array):
  """Velocities of crushed bodies: along the axis of a crushed link, a movable body
  takes the mean velocity of the bodies it is linked to along that axis (both sides),
  so it gains no velocity of its own (gravity, momentum) into what crushes it.

  Args:
    vel: `[n, 2]` velocities.
    front: link table.
    jammed: `[l, 4, n]` links whose two units both lean on immovable bodies.
    movable: `[n]` bool.

  Returns:
    `[n, 2]` velocities. (Which bodies are crushed the resolution pass reports:
    `chain.Pass.crushed`.)
  """
  on_axis = jnp.stack([vel[:, 0], vel[:, 0], vel[:, 1], vel[:, 1]])  # [4, n]
  partner = jnp.where(front.mask, front.gather(on_axis), 0.0)
  count = jnp.sum(front.mask, axis=0)
  per_axis = lambda x: jnp.stack([x[0] + x[1], x[2] + x[3]], axis=-1)  # [4, n] -> [n, 2]
  mean = safe_divide(per_axis(jnp.sum(partner, axis=0)), per_axis(count).astype(vel.dtype))
  hit = per_axis(jnp.any(jammed, axis=0)) & movable[:, None]
  return jnp.where(hit, mean, vel)
