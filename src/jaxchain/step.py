"""Time stepping: integrate, resolve, update velocities, friction; and rollouts.

`step` is a flat pipeline of small stages. Every stage that a config switches
off (gravity, friction, immovable handling, substeps) is left out by a Python
`if` on the static config, so it is not traced at all.
"""

from __future__ import annotations

import dataclasses
import functools

import jax
import jax.numpy as jnp
from jax import lax

from jaxchain import broadphase, chain, geometry, status
from jaxchain.config import Config
from jaxchain.world import World


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class Trajectory:
  """Per-step states of a rollout.

  Attributes:
    pos: `[t, n, 2]` centres after each step.
    vel: `[t, n, 2]` velocities after each step.
  """

  pos: jax.Array
  vel: jax.Array


def _check_single(world: World, fn: str) -> None:
  if world.pos.ndim != 2:
    raise ValueError(
        f"{fn}: expected a single world with pos of shape (n, 2), got {world.pos.shape}; "
        f"for a batch use jax.vmap({fn}, in_axes=(0, None)) or functools.partial(jc.{fn}, config=cfg)")


def _resolve_positions(world: World, pos: jax.Array, config: Config,
                       start: jax.Array | None = None):
  """Positions after `config.iterations` chain passes, and the status bits they raised.

  Grid candidates are rebuilt at the start of every pass, from the positions that
  pass starts at. With `start` (positions at the start of the step) also returns the
  part of the displacement this step's motion caused: every pass measures the
  overlap that was there anyway at `ref`, the start moved by the recovery part of
  the passes so far (see `chain.displacement`).

  Returns:
    `(pos, status)`, or `(pos, motion_push, status)` with `start`.
  """
  mass = chain.body_mass(world.inv_mass, world.active)
  immovable = ~world.movable
  pass_fn = functools.partial(chain.displacement, half=world.half, mass=mass, immovable=immovable,
                              depth=config.depth, skin=config.skin, links=config.links,
                              track_immovable=config.immovable)

  def one_pass(_, carry):
    p, ref, motion, code, _ = carry
    cand, found = broadphase.candidates(p, world, config)
    out = pass_fn(p, cand=cand, ref_pos=None if start is None else ref)
    if start is not None:
      ref, motion = ref + (out.disp - out.caused), motion + out.caused
    found = found | jnp.where(out.overflow, status.LINK_OVERFLOW, 0)
    return p + out.disp, ref, motion, code | found, out.exhausted

  ref = pos if start is None else start
  zero = jnp.zeros((), jnp.int32)
  p, _, motion, code, exhausted = lax.fori_loop(
      0, config.iterations, one_pass, (pos, ref, jnp.zeros_like(pos), zero, jnp.zeros((), bool)))
  # Only the last pass counts: earlier passes may leave work that later ones finish.
  code = code | jnp.where(exhausted, status.DEPTH_EXHAUSTED, 0)
  return (p, code) if start is None else (p, motion, code)


@functools.partial(jax.jit, static_argnames="config")
def resolve(world: World, config: Config) -> World:
  """Collision resolution only: moves bodies out of each other, velocities untouched.

  Args:
    world: a single world (use `jax.vmap` for a batch).
    config: static configuration (`depth`, `iterations`, `skin`, `immovable`).

  Returns:
    The world with resolved positions. Immovable and inactive bodies do not move.

  Examples:
    >>> import jaxchain as jc
    >>> w = jc.World.create([[0.0, 0.0], [0.9, 0.0], [1.9, 0.0]], [0.5, 0.5],
    ...                     [1.0, 1.0, float("inf")])
    >>> [round(float(x), 4) for x in jc.resolve(w, jc.Config()).pos[:, 0]]
    [-0.1, 0.9, 1.9]
  """
  _check_single(world, "resolve")
  pos, code = _resolve_positions(world, world.pos, config)
  return world.replace(pos=pos, status=world.status | code)


def _substep(world: World, config: Config, h: float, accel: jax.Array | None) -> World:
  movable = world.movable[:, None]
  vel = world.vel
  if accel is not None:
    vel = vel + jnp.where(world.active[:, None], accel * h, 0.0)
  if config.has_gravity:
    vel = vel + jnp.where(movable, world.gravity[None] * h, 0.0)
  predicted = world.pos + jnp.where(world.active[:, None], vel * h, 0.0)
  resolved, push, code = _resolve_positions(world, predicted, config, start=world.pos)
  code = code | jnp.where(_too_fast(world, vel, h), status.FAST_BODY, 0)
  # Position-based velocity update, perfectly inelastic: a body stopped by a contact
  # loses its velocity into it and a pushed body moves on with its pusher. Only the
  # push this step's motion caused counts (overlap the step started with is removed
  # by position alone), and no resolution reverses a velocity: recovering from
  # penetration never becomes a bounce or an explosion.
  moved = vel + push / h
  vel = jnp.where(vel * moved < 0, 0.0, moved)
  if config.has_friction:
    vel, friction_code = _friction(world, resolved, vel, push, config, h)
    code = code | friction_code
  bad = world.active[:, None] & ~(jnp.isfinite(resolved) & jnp.isfinite(vel))
  code = code | jnp.where(jnp.any(bad), status.NON_FINITE, 0)
  return world.replace(pos=resolved, vel=vel, status=world.status | code)


def _too_fast(world: World, vel: jax.Array, h: float) -> jax.Array:
  """Whether some body moves, in one substep, at least its own half-extent plus the
  smallest half-extent of any body along an axis: past that its centre can cross a
  thin body's centre, and the contact would push it out on the far side."""
  thinnest = jnp.min(jnp.where(world.active[:, None], world.half, jnp.inf), axis=0, initial=jnp.inf)
  reach = world.half + thinnest[None]
  return jnp.any(world.active[:, None] & (jnp.abs(vel) * h >= reach))


def _friction(world: World, pos, vel, push, config: Config, h: float):
  """Coulomb friction, Jacobi style, per body.

  The normal impulse of body i along an axis is taken as its own resolution
  velocity change along that axis, `|push| / h`; friction reduces i's velocity
  along the other (tangent) axis, relative to the mean tangent velocity of the
  bodies it is linked to along the normal axis, by at most `mu` times that. A box
  sliding at `v0` on a floor stops after about `v0**2 / (2 mu g)`.

  Returns:
    `(vel, code)`: the new velocities and `LINK_OVERFLOW` if the link table at the
    resolved positions overflowed (the grid's bits were taken by the resolution).
  """
  cand, _ = broadphase.candidates(pos, world, config)
  c = geometry.contacts(pos, world.half, cand, config.skin)
  links, overflow = geometry.link_table(c, cand, config.links, rows=world.movable)
  partner_vel = links.gather_bodies(vel)  # [4, n, l, 2] ([1, n, m, 2] uncompacted)
  out = []
  for tangent in (0, 1):  # A loop over the two axes, not over bodies.
    normal = slice(2, 4) if tangent == 0 else slice(0, 2)  # Directions along the normal axis.
    along_normal = links.mask[normal]  # [2, n, l]
    v = partner_vel[..., tangent]
    v = v[normal] if links.idx is not None else v  # Uncompacted: [1, n, m], shared.
    count = jnp.sum(along_normal, axis=(0, 2))
    ref = chain.safe_divide(jnp.sum(jnp.where(along_normal, v, 0.0), axis=(0, 2)),
                            count.astype(vel.dtype))
    rel = vel[:, tangent] - ref
    budget = world.friction * jnp.abs(push[:, 1 - tangent]) / h
    out.append(vel[:, tangent] - jnp.sign(rel) * jnp.minimum(jnp.abs(rel), budget))
  vel = jnp.where(world.movable[:, None], jnp.stack(out, axis=-1), vel)
  return vel, jnp.where(overflow, status.LINK_OVERFLOW, 0)


def _step(world: World, config: Config, accel: jax.Array | None) -> World:
  h = config.dt / config.substeps
  if config.substeps == 1:
    return _substep(world, config, h, accel)
  return lax.fori_loop(0, config.substeps, lambda _, w: _substep(w, config, h, accel), world)


@functools.partial(jax.jit, static_argnames="config")
def step(world: World, config: Config, accel: jax.Array | None = None) -> World:
  """One time step: gravity and `accel`, semi-implicit Euler, chain resolution,
  velocity update, friction; `config.substeps` times with `dt / substeps`.

  Args:
    world: a single world (use `jax.vmap` for a batch).
    config: static configuration.
    accel: optional `[n, 2]` external acceleration for this step (a player's
      input, say); applied to every active body, immovable ones included (that is
      how a kinematic platform is driven).

  Returns:
    The world after `config.dt`.

  Examples:
    >>> import jaxchain as jc
    >>> w = jc.World.create([[0.0, 0.5], [0.0, -0.5]], [[0.5, 0.5], [5.0, 0.5]], [1.0, float("inf")])
    >>> w = jc.step(w, jc.Config())
    >>> float(w.pos[0, 1]), float(w.vel[0, 1])  # rests on the floor, stopped by it
    (0.5, 0.0)
  """
  _check_single(world, "step")
  return _step(world, config, accel)


def make_step(config: Config):
  """Returns `step_fn(world, accel=None) -> world`, jitted once for `config`."""
  return jax.jit(lambda world, accel=None: _step(world, config, accel))


@functools.partial(jax.jit, static_argnames=("config", "n_steps"))
def rollout(world: World, config: Config, n_steps: int,
            controls: jax.Array | None = None) -> tuple[World, Trajectory]:
  """`n_steps` steps under `lax.scan`.

  Args:
    world: a single world (use `jax.vmap` for a batch).
    config: static configuration.
    n_steps: number of steps (static).
    controls: optional accelerations, `[n_steps, n, 2]` (one per step) or
      `[n, 2]` (the same every step).

  Returns:
    `(final_world, trajectory)` with `trajectory.pos` of shape `[n_steps, n, 2]`.
  """
  _check_single(world, "rollout")
  if controls is not None and controls.ndim == 2:
    controls = jnp.broadcast_to(controls, (n_steps,) + controls.shape)
  if controls is not None and controls.shape != (n_steps,) + world.pos.shape:
    raise ValueError(f"rollout: controls must have shape {(n_steps,) + world.pos.shape} "
                     f"or {world.pos.shape}, got {controls.shape}")

  def body(w, accel):
    w = _step(w, config, accel)
    return w, Trajectory(pos=w.pos, vel=w.vel)

  return lax.scan(body, world, controls, length=n_steps)
