"""The previous stepping core ([n, 2] per world, batched by vmap), kept only as the
equivalence check of `jaxchain.core` until it is removed. Time stepping: integrate, resolve, update velocities, friction; and rollouts.

`step` is a flat pipeline of small stages. Every stage that a config switches
off (gravity, friction, immovable handling, substeps) is left out by a Python
`if` on the static config, so it is not traced at all.

The module is `jaxchain.stepping`: `jaxchain.step` is the function (re-exported
by the package), which would shadow a module of that name.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable, Sequence

import jax
import jax.numpy as jnp
from jax import lax

from jaxchain import broadphase, chain, flags, geometry, status, velocity
from jaxchain.config import Config
from jaxchain.sharding import in_auto_axes
from jaxchain.world import World


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class Trajectory:
  """Per-step states of a rollout.

  Attributes:
    pos: `[t, n, 2]` centres after each step.
    vel: `[t, n, 2]` velocities after each step.
    status: `[t]` int32 status bits after each step, if recorded (else None).
    touching: `[t, n, 4]` bool contact flags of each step, if recorded.
    crushed: `[t, n]` bool, crushed in each step, if recorded.
    sensed: `[t, n]` bool, sensors overlapped at any moment of each step (every
      substep, swept over its motion), if recorded.
  """

  pos: jax.Array
  vel: jax.Array
  status: jax.Array | None = None
  touching: jax.Array | None = None
  crushed: jax.Array | None = None
  sensed: jax.Array | None = None


RECORDABLE = ("status", "touching", "crushed", "sensed")  # Opt-in `Trajectory` fields.


def _check_single(world: World, fn: str, batch_hint: str | None = None) -> None:
  if world.pos.ndim != 2:
    hint = batch_hint or (f"jax.vmap({fn}, in_axes=(0, None)) or "
                          f"functools.partial(jc.{fn}, config=cfg)")
    raise ValueError(
        f"{fn}: expected a single world with pos of shape (n, 2), got {world.pos.shape}; "
        f"for a batch use {hint}")


def _passes(world: World, pos: jax.Array, config: Config, *, start: jax.Array | None = None,
            vel: jax.Array | None = None, table: broadphase.Neighbors | None = None):
  """`config.iterations` resolution passes from `pos`.

  A pass is a flat pipeline, one call a stage, each reading what the stages before it
  built at the positions the pass starts from: candidates (broadphase), contacts and
  links (`geometry.links`, built once and read by every later stage), resolution
  (`chain.displacement`: the push hops carry the positions and, with `vel`, the
  contact impulses in the same hops), velocities (the impulses, then the crush rule),
  friction, flags. So a pass's velocities always follow its positions. With
  `config.neighbors` every pass reads one neighbour table, `table` or built here at
  `pos` (`broadphase.build`), and checks its margin.

  Returns:
    `(pos, vel, status, crushed, touching)` (`vel` None without `vel`; `touching`
    `[4, n]`, ORed over the passes).
  """
  mass = chain.body_mass(world.inv_mass, world.active)
  movable = world.movable
  one_way = None
  if config.one_way:
    fixed = world.active & (world.inv_mass == 0)
    one_way = geometry.OneWay(one_way=world.active & world.one_way, solid=fixed & ~world.one_way)
  # Seams: the faces of immovable bodies make surfaces (one-way bodies excepted; sensors
  # are out of every candidate table already).
  surface = None
  if config.immovable and start is not None:
    surface = world.active & (world.inv_mass == 0)
    surface = surface & ~world.one_way if config.one_way else surface
  table = broadphase.build(pos, world, config, start) if table is None else table

  def one_pass(_, carry):
    p, v, code, _, crushed, touching = carry
    cand, found = broadphase.candidates(p, world, config, table)
    cand = flags.admit(cand, world, layers=config.layers, sensors=config.sensors)
    ow = one_way if one_way is None or v is None else dataclasses.replace(one_way, vel=v)
    front, overflow = geometry.links(p, world.half, cand, skin=config.skin, limit=config.links,
                                     rows=movable, start=start, one_way=ow,
                                     surface=surface)
    out = chain.displacement(front, mass, ~movable, depth=config.depth,
                             track_immovable=config.immovable, vel=v, stick=velocity.STICK,
                             converge=config.converge)
    scaled, exhausted = out.scaled, out.exhausted
    if v is not None:
      v = v + out.dvel
      if config.immovable:
        v = velocity.crush(v, front, out.jammed, movable)
    if v is not None and config.has_friction:
      v, rubbed, cut = velocity.friction(v, front, out.impulse, world.friction, out.shared,
                                         out.sticking, mass, depth=config.depth,
                                         converge=config.converge, short=out.short)
      scaled, exhausted = scaled | rubbed, exhausted | cut
    code = code | found | _pass_flags(overflow, scaled)
    touching = touching | flags.touching(front)
    return p + out.disp, v, code, exhausted, crushed | out.crushed, touching

  zero = jnp.zeros((), jnp.int32)
  n = world.num_bodies
  init = (pos, vel, zero, jnp.zeros((), bool), jnp.zeros((n,), bool),
          jnp.zeros((geometry.NUM_DIRECTIONS, n), bool))
  p, v, code, exhausted, crushed, touching = lax.fori_loop(0, config.iterations, one_pass, init)
  # Only the last pass counts: earlier passes may leave work that later ones finish.
  code = code | jnp.where(exhausted, status.DEPTH_EXHAUSTED, 0)
  return p, v, code, crushed, touching


def _sensed(world: World, pos: jax.Array, config: Config,
            table: broadphase.Neighbors | None = None, *,
            start: jax.Array | None = None) -> tuple[jax.Array, jax.Array]:
  """`World.sensed` at `pos`, or with `start` swept over the straight motion from
  `start` to `pos` (a substep: `flags.sensed`); all False without `config.sensors`.
  Also the status bits of the candidate table it reads (built again at `pos`: the
  bodies have moved; or a substep's neighbour `table`, checked against its margin)."""
  if not config.sensors:
    return jnp.zeros_like(world.sensed), jnp.zeros((), jnp.int32)
  cand, found = broadphase.candidates(pos, world, config, table)
  return flags.sensed(world, pos, cand, start), found


def _pass_flags(overflow: jax.Array, scaled: jax.Array) -> jax.Array:
  """The status bits one pass raises: `LINK_OVERFLOW`, `IMPULSES_SCALED`."""
  return (jnp.where(overflow, status.LINK_OVERFLOW, 0)
          | jnp.where(scaled, status.IMPULSES_SCALED, 0))


def _finite_code(world: World, *arrays: jax.Array) -> jax.Array:
  """`NON_FINITE` if a state array (`[n, 2]`) of an active body is NaN or inf, or if a
  parameter is out of its domain: half-extents not finite and `> 0`, inverse masses
  or friction not finite and `>= 0`, gravity not finite (values that traced code, or
  `dataclasses.replace`, can put in a World without `World.replace`'s checks)."""
  active = world.active
  bad = jnp.any(~jnp.isfinite(world.gravity))
  bad = bad | jnp.any(active[:, None] & ~(jnp.isfinite(world.half) & (world.half > 0)))
  for p in (world.inv_mass, world.friction):
    bad = bad | jnp.any(active & ~(jnp.isfinite(p) & (p >= 0)))
  for x in arrays:
    bad = bad | jnp.any(active[:, None] & ~jnp.isfinite(x))
  return jnp.where(bad, status.NON_FINITE, 0)


@functools.partial(jax.jit, static_argnames="config")
def resolve(world: World, config: Config) -> World:
  """Collision resolution only: moves bodies out of each other, velocities untouched.

  Args:
    world: a single world (use `jax.vmap` for a batch).
    config: static configuration (`depth`, `iterations`, `skin`, `immovable`).

  Returns:
    The world with resolved positions and `crushed` set. Immovable and inactive
    bodies do not move. A non-finite position sets `status.NON_FINITE`.

  Examples:
    >>> import jaxchain as jc
    >>> w = jc.World.create([[0.0, 0.0], [0.9, 0.0], [1.9, 0.0]], [0.5, 0.5],
    ...                     [1.0, 1.0, float("inf")])
    >>> [round(float(x), 4) for x in jc.resolve(w, jc.Config()).pos[:, 0]]
    [-0.1, 0.9, 1.9]
  """
  _check_single(world, "resolve")
  return in_auto_axes(lambda w: _resolve(w, config), world)


def _resolve(world: World, config: Config) -> World:
  pos, _, code, crushed, touching = _passes(world, world.pos, config)
  sensed, found = _sensed(world, pos, config)
  code = code | found | _finite_code(world, world.pos, pos) | _crushed_code(crushed)
  code = code | _switched_off(world, config, physics=False)
  return dataclasses.replace(world, pos=pos, crushed=crushed, touching=touching.T, sensed=sensed,
                             status=world.status | code)


def _crushed_code(crushed: jax.Array) -> jax.Array:
  return jnp.where(jnp.any(crushed), status.CRUSHED, 0)


def _switched_off(world: World, config: Config, physics: bool = True) -> jax.Array:
  """`SWITCHED_OFF` and the bit naming each feature when the world uses what the config
  leaves out of the step (`FRICTION_OFF`, ..., `LAYERS_OFF`; `resolve`, with
  `physics=False`, uses neither friction nor gravity)."""
  used = []
  if physics and not config.has_friction:
    used.append((status.FRICTION_OFF, jnp.any(world.active & (world.friction > 0))))
  if physics and not config.has_gravity:
    used.append((status.GRAVITY_OFF, jnp.any(world.gravity != 0) & jnp.any(world.movable)))
  if not config.immovable:
    used.append((status.IMMOVABLE_OFF, jnp.any(world.active & (world.inv_mass == 0))))
  if not config.one_way:
    used.append((status.ONE_WAY_OFF, jnp.any(world.active & world.one_way)))
  if not config.sensors:
    used.append((status.SENSORS_OFF, jnp.any(world.active & world.sensor)))
  if not config.layers:  # As `sizing.uses_layers`: some mask misses a present layer.
    category = jnp.where(world.active, world.category, jnp.zeros_like(world.category))
    present = jnp.bitwise_or.reduce(category)
    used.append((status.LAYERS_OFF, jnp.any(
        world.active & ((category == 0) | ((world.mask & present) != present)))))
  code = jnp.zeros((), jnp.int32)
  for bit, on in used:
    code = code | jnp.where(on, bit | status.SWITCHED_OFF, 0)
  return code


def _substep(world: World, config: Config, sub_dt: float, accel: jax.Array | None) -> World:
  """Integrate (semi-implicit Euler), then resolution passes that move the bodies
  apart and update their velocities from the contact impulses and friction."""
  vel = world.vel
  if accel is not None:
    vel = vel + jnp.where(world.active[:, None], accel * sub_dt, 0.0)
  if config.has_gravity:
    vel = vel + jnp.where(world.movable[:, None], world.gravity[None] * sub_dt, 0.0)
  code = jnp.where(_too_fast(world, vel, sub_dt), status.FAST_BODY, 0)
  motion = jnp.where(world.active[:, None], vel * sub_dt, 0.0)
  code = code | jnp.where(_motion_lost(world.pos, vel, motion), status.PRECISION_LOST, 0)
  predicted = world.pos + motion
  table = broadphase.build(predicted, world, config, world.pos)  # None without neighbors.
  pos, vel, found, crushed, touching = _passes(world, predicted, config, start=world.pos, vel=vel,
                                               table=table)
  # Sensors see every overlap during the step: swept over this substep's motion (from
  # a candidate table at its end positions, or the substep's neighbour table: it holds
  # the swept boxes), ORed over the substeps.
  sensed, seen = _sensed(world, pos, config, table, start=world.pos)
  code = code | found | seen | _finite_code(world, pos, vel) | _crushed_code(crushed)
  return dataclasses.replace(world, pos=pos, vel=vel, crushed=world.crushed | crushed,
                             touching=world.touching | touching.T, sensed=world.sensed | sensed,
                             status=world.status | code)


def _motion_lost(pos: jax.Array, vel: jax.Array, motion: jax.Array) -> jax.Array:
  """Whether a body moving faster than `velocity.STICK` (below it the library already
  treats bodies as at rest relative to each other) moves, in this substep, less than
  the float spacing of its coordinate: its motion rounds away (float32 at x = 1e5
  steps by 0.0078, so 0.1 units/s goes nowhere at 60 steps a second)."""
  pos, vel, motion = (lax.stop_gradient(x) for x in (pos, vel, motion))  # A report only.
  lost = (jnp.abs(vel) > velocity.STICK) & (jnp.abs(motion) < jnp.spacing(jnp.abs(pos)))
  return jnp.any(lost)


def _too_fast(world: World, vel: jax.Array, sub_dt: float) -> jax.Array:
  """Whether some body moves, in one substep, at least its own half-extent plus the
  smallest half-extent of any body along an axis: past that its centre can cross a
  thin body's centre, and the contact would push it out on the far side."""
  thinnest = jnp.min(jnp.where(world.active[:, None], world.half, jnp.inf), axis=0, initial=jnp.inf)
  reach = world.half + thinnest[None]
  return jnp.any(world.active[:, None] & (jnp.abs(vel) * sub_dt >= reach))


def _step(world: World, config: Config, accel: jax.Array | None) -> World:
  """One step of one world, in `in_auto_axes` (a batch sharded over an explicit mesh
  axis then runs as under an Auto one: see `jaxchain.sharding`)."""
  return in_auto_axes(lambda w, a: _step_body(w, config, a), world, accel)


def _step_body(world: World, config: Config, accel: jax.Array | None) -> World:
  sub_dt = config.dt / config.substeps
  # Library code uses dataclasses.replace: World.replace validates concrete values, and
  # under jax.disable_jit a NaN must become NON_FINITE, not an exception.
  world = dataclasses.replace(world, crushed=jnp.zeros_like(world.crushed),  # ORed over substeps.
                              touching=jnp.zeros_like(world.touching),
                              sensed=jnp.zeros_like(world.sensed),
                              status=world.status | _switched_off(world, config))
  if config.substeps == 1:
    world = _substep(world, config, sub_dt, accel)
  else:
    world = lax.fori_loop(0, config.substeps, lambda _, w: _substep(w, config, sub_dt, accel),
                          world)
  return world


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
  """Returns `step_fn(world, accel=None) -> world`, jitted once for `config`.

  Examples:
    >>> import jaxchain as jc
    >>> step_fn = jc.make_step(jc.Config())
    >>> w = step_fn(jc.World.create([[0.0, 0.0]], [0.5, 0.5], 1.0))
    >>> round(float(w.vel[0, 1]), 4)
    -0.1635
  """
  def step_fn(world: World, accel: jax.Array | None = None) -> World:
    _check_single(world, "step_fn", batch_hint="jax.vmap(step_fn), with step_fn = jc.make_step(cfg)")
    return _step(world, config, accel)

  return jax.jit(step_fn)


def rollout(world: World, config: Config, n_steps: int, controls: jax.Array | None = None, *,
            policy: Callable[[World, jax.Array], jax.Array] | None = None,
            record: Sequence[str] = ()) -> tuple[World, Trajectory]:
  """`n_steps` steps under `lax.scan`, open-loop (`controls`) or closed-loop (`policy`).

  Args:
    world: a single world (use `jax.vmap` for a batch).
    config: static configuration.
    n_steps: number of steps (static).
    controls: optional accelerations, `[n_steps, n, 2]` (one per step) or
      `[n, 2]` (the same every step).
    policy: optional `policy(world, t) -> accel` (`[n, 2]`), called before each step
      with the world as it is and the step index `t` (int32 scalar, from 0): a
      closed loop. Jittable, vmappable and differentiable like the rest; it is a
      static argument (hashed by identity), so define it once rather than as a new
      `lambda` per call (each new function compiles again). To differentiate with
      respect to a policy's parameters, close over them inside the function you
      differentiate (see docs/toolkit.md, "Closed-loop rollouts").
    record: which extra per-step outputs the trajectory keeps, of
      `("status", "touching", "crushed", "sensed")` (static; default none, to keep
      memory small).

  Returns:
    `(final_world, trajectory)` with `trajectory.pos` of shape `[n_steps, n, 2]`.

  Raises:
    ValueError: for controls of the wrong shape, both `controls` and `policy`, a
      policy whose output is not `[n, 2]`, or an unknown `record` name.

  Examples:
    >>> import jax.numpy as jnp
    >>> import jaxchain as jc
    >>> w = jc.World.create([[0.0, 0.5], [0.0, -0.5]], [[0.5, 0.5], [5.0, 0.5]],
    ...                     [1.0, float("inf")], gravity=(0.0, 0.0))
    >>> def push_right(world, t):  # Accelerate body 0 for the first 30 steps.
    ...   return jnp.zeros_like(world.pos).at[0, 0].set(jnp.where(t < 30, 6.0, 0.0))
    >>> final, traj = jc.rollout(w, jc.Config(), 60, policy=push_right, record=("touching",))
    >>> round(float(final.vel[0, 0]), 4), traj.touching.shape
    (3.0, (60, 2, 4))
  """
  _check_single(world, "rollout")
  record = (record,) if isinstance(record, str) else tuple(record)  # Hashable: static.
  unknown = [r for r in record if r not in RECORDABLE]
  if unknown:
    raise ValueError(f"rollout: record= takes names from {RECORDABLE}, got {unknown}")
  if controls is not None and policy is not None:
    raise ValueError("rollout: pass controls= (open loop) or policy= (closed loop), not both; "
                     "add the controls inside the policy: policy(world, t) + controls[t]")
  if controls is not None and controls.ndim == 2:
    controls = jnp.broadcast_to(controls, (n_steps,) + controls.shape)
  if controls is not None and controls.shape != (n_steps,) + world.pos.shape:
    raise ValueError(f"rollout: controls must have shape {(n_steps,) + world.pos.shape} "
                     f"or {world.pos.shape}, got {controls.shape}")

  return _rollout(world, config, n_steps, controls, policy, record)


@functools.partial(jax.jit, static_argnames=("config", "n_steps", "policy", "record"))
def _rollout(world: World, config: Config, n_steps: int, controls: jax.Array | None,
             policy: Callable[[World, jax.Array], jax.Array] | None,
             record: tuple[str, ...]) -> tuple[World, Trajectory]:
  """`rollout` after its checks, jitted (config, n_steps, policy and record static)."""
  def accel_of(w, t, given):
    if policy is None:
      return given
    accel = policy(w, t)
    if getattr(accel, "shape", None) != w.pos.shape:
      raise ValueError(f"rollout: policy(world, t) must return accelerations of shape "
                       f"{w.pos.shape}, got {getattr(accel, 'shape', type(accel).__name__)}")
    return jnp.asarray(accel, w.pos.dtype)

  def body(w, xs):
    t, given = xs
    w = _step(w, config, accel_of(w, t, given))
    extra = {name: getattr(w, name) for name in record}
    return w, Trajectory(pos=w.pos, vel=w.vel, **extra)

  steps = jnp.arange(n_steps, dtype=jnp.int32)
  return lax.scan(body, world, (steps, controls), length=n_steps)
