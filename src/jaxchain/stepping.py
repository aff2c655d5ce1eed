"""The public entry points of the step: `step`, `make_step`, `resolve`, `rollout`.

They take a single world (`[n, ...]`) or a batch (`[B, n, ...]`) and run the batch-minor
core (`jaxchain.core`) on it, transposing once on the way in and once on the way out
(a rollout stays batch-minor through its scan). A user's own `jax.vmap` over `step`,
`resolve` or `rollout` (and over an environment's `step`, which calls them) reaches the
same core: the single-world functions are `jax.custom_batching.custom_vmap` functions
whose batching rule runs the core on the whole batch (nested `vmap`s fold into one
batch), inside a `jax.custom_jvp` whose tangent rule is the plain core at one world, so
`jax.grad` and `jax.jvp` work under every combination of transformations.

The module is `jaxchain.stepping`: `jaxchain.step` is the function (re-exported by the
package), which would shadow a module of that name.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable, Sequence

import jax
import jax.numpy as jnp
from jax.custom_batching import custom_vmap

from jaxchain import core
from jaxchain.config import Config
from jaxchain.sharding import in_auto_axes
from jaxchain.world import World


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class Trajectory:
  """Per-step states of a rollout (with a leading batch axis `[B, ...]` for a batch).

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


def _check_world(world: World, fn: str) -> bool:
  """Whether `world` is a batch (`[B, n, 2]` positions) rather than one world."""
  if world.pos.ndim not in (2, 3) or world.pos.shape[-1] != 2:
    raise ValueError(f"{fn}: expected a world with pos of shape (n, 2), or a batch of worlds "
                     f"(B, n, 2), got {world.pos.shape}")
  return world.pos.ndim == 3


def _xy_minor(x: jax.Array) -> jax.Array:
  """`[B, ..., n, 2]` -> `[..., 2, n, B]` (controls, accelerations)."""
  x = jnp.moveaxis(x, 0, -1)  # [..., n, 2, B]
  return jnp.swapaxes(x, -3, -2)


def _xy_major(x: jax.Array) -> jax.Array:
  """The inverse of `_xy_minor`."""
  return jnp.moveaxis(jnp.swapaxes(x, -3, -2), -1, 0)


# ---------------------------------------------------------------- kernels on batches

def _step_kernel(config: Config, world: World, accel: jax.Array | None) -> World:
  state, bodies = core.from_world(world)
  accel = None if accel is None else _xy_minor(accel)
  return core.to_world(world, core.step.step(state, bodies, config, accel))


def _resolve_kernel(config: Config, world: World) -> World:
  state, bodies = core.from_world(world)
  return core.to_world(world, core.step.resolve(state, bodies, config))


def _rollout_kernel(config: Config, n_steps: int, policy, record: tuple[str, ...],
                    world: World, controls: jax.Array | None,
                    horizon: jax.Array | None = None) -> tuple[World, Trajectory]:
  state, bodies = core.from_world(world)
  controls = None if controls is None else _xy_minor(controls)  # [T, 2, n, B]
  policy_minor = None
  if policy is not None:
    def policy_minor(s, t):
      view = core.to_world(world, s)
      accel = jax.vmap(lambda w: _policy_accel(policy, w, t))(view)
      return _xy_minor(accel)

  final, traj = core.step.rollout(state, bodies, config, n_steps, controls, policy_minor, record,
                                  horizon)
  # [T, k, n, B] -> [B, T, n, k]; [T, n, B] -> [B, T, n]; [T, B] -> [B, T].
  def major(name, x):
    if name in ("pos", "vel", "touching"):
      return jnp.moveaxis(x, (0, 1, 3), (1, 3, 0))
    if name == "status":
      return x.T
    return jnp.moveaxis(x, (0, 2), (1, 0))

  traj = Trajectory(**{name: major(name, x) for name, x in traj.items()})
  return core.to_world(world, final), traj


def _policy_accel(policy, world: World, t: jax.Array) -> jax.Array:
  accel = policy(world, t)
  if getattr(accel, "shape", None) != world.pos.shape:
    raise ValueError(f"rollout: policy(world, t) must return accelerations of shape "
                     f"{world.pos.shape}, got {getattr(accel, 'shape', type(accel).__name__)}")
  return jnp.asarray(accel, world.pos.dtype)


# -------------------------------------------------------- one world, and the vmap route

def _add_axis(tree, size: int = 1):
  """`tree` with a leading batch axis of `size` copies, concatenated rather than
  broadcast: XLA sees through a broadcast, simplifies the program around it (other
  fusions, other shapes, and so other fused multiply-adds), and one world then rounded
  differently from the same world in a batch (a free fall: 1 ulp at step 12, at XLA's
  default flags; issue 44 item 2). Concatenated, the program is the batch's."""
  return jax.tree.map(lambda x: jnp.concatenate([x[None]] * size), tree)


# One small world runs as a batch of two copies of it (the first is returned). XLA:CPU
# simplifies a program whose batch axis has size 1 except inside loops, where it keeps
# each loop body whole: with the closing stage's loop around the passes, a room of 16's
# step compiled to 1014 fusions in 7.6 s at B = 1, against 364 in 4.5 s at B = 2, for the
# same latency within 11% (`jax.jit(jc.step)` on one world, one process). A large world
# (more than `ONE_WORLD_MAX_BODIES`) runs at B = 1: there the work, not the kernels, counts.
ONE_WORLD, ONE_WORLD_MAX_BODIES = 2, 256


def _one_world(args) -> int:
  pos = getattr(args[0], "pos", None) if args else None
  return ONE_WORLD if pos is not None and pos.shape[0] <= ONE_WORLD_MAX_BODIES else 1


def _drop_axis(tree):
  return jax.tree.map(lambda x: x[0], tree)


def _broadcast(axis_size: int, in_batched, args):
  return jax.tree.map(lambda b, x: x if b else jnp.broadcast_to(x, (axis_size,) + x.shape),
                      in_batched, args)


def _all_batched(tree):
  return jax.tree.map(lambda _: True, tree)


def batch_route(kernel: Callable) -> Callable:
  """`kernel(*batched_args) -> batched outputs` (every array with a leading batch axis)
  made into a function of one world whose `jax.vmap` calls `kernel` on the whole batch.

  * One world: the kernel at `B = 1`, or on a batch of `ONE_WORLD` copies of it for a
    small world (see `ONE_WORLD`).
  * Under `vmap`: a `custom_vmap` rule calls the kernel on the batch (leaves the vmap
    does not batch are broadcast); under nested `vmap`s the outer axes fold into one
    batch (`[A, B, ...]` -> `[A * B, ...]`).
  * Under `jax.jvp` / `jax.grad` (a `custom_jvp`: `custom_vmap` alone does not support
    reverse mode): the tangents of the plain kernel at one world, which reverse mode
    transposes; differentiating a vmapped call batches that rule as JAX batches any
    code. (The kernel at one world has no `lax.cond` over its batch, whose batching
    rule would put a `stop_gradient` on those tangents.)
  * Sharded batches: the kernel runs in `sharding.in_auto_axes` (its gathers then stay
    within each device's block of worlds: `core.layout.lanes_split`).
  """
  def run(args):
    return in_auto_axes(lambda *a: kernel(*a), *args, batched=True)

  @custom_vmap
  def batched(args):
    return run(args)

  @batched.def_vmap
  def fold(axis_size, in_batched, args):
    args = _broadcast(axis_size, in_batched[0], args)
    flat = jax.tree.map(lambda x: x.reshape((-1,) + x.shape[2:]), args)
    out = jax.tree.map(lambda x: x.reshape((axis_size, -1) + x.shape[1:]), batched(flat))
    return out, _all_batched(out)

  @custom_vmap
  def single(args):
    return _drop_axis(kernel(*_add_axis(args, _one_world(args))))

  @single.def_vmap
  def rule(axis_size, in_batched, args):
    out = batched(_broadcast(axis_size, in_batched[0], args))
    return out, _all_batched(out)

  plain = lambda a: _drop_axis(kernel(*_add_axis(a, _one_world(a))))

  @jax.custom_jvp
  def one(args):
    return single(args)

  @one.defjvp
  def one_jvp(primals, tangents):
    return jax.jvp(plain, primals, tangents)
  return lambda *args: one(args)


@functools.lru_cache(maxsize=None)
def _single_step(config: Config) -> Callable:
  return batch_route(functools.partial(_step_kernel, config))


@functools.lru_cache(maxsize=None)
def _single_resolve(config: Config) -> Callable:
  return batch_route(functools.partial(_resolve_kernel, config))


@functools.lru_cache(maxsize=None)
def _single_rollout(config: Config, n_steps: int, record: tuple[str, ...]) -> Callable:
  return batch_route(functools.partial(_rollout_kernel, config, n_steps, None, record))


def _batched(kernel: Callable, *args):
  return in_auto_axes(kernel, *args, batched=True)


# -------------------------------------------------------------------- public functions

def resolve(world: World, config: Config) -> World:
  """Collision resolution only: moves bodies out of each other, velocities untouched.

  Args:
    world: a world, or a batch of worlds (`[B, n, ...]`, e.g. from `jc.stack`); a
      `jax.vmap` over single worlds runs as one batch too.
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
  check_differentiable(config, "resolve", world)
  return _resolve_jit(world, config)


@functools.partial(jax.jit, static_argnames="config")
def _resolve_jit(world: World, config: Config) -> World:
  if _check_world(world, "resolve"):
    return _batched(functools.partial(_resolve_kernel, config), world)
  return _single_resolve(config)(world)


def _step(world: World, config: Config, accel: jax.Array | None) -> World:
  if _check_world(world, "step"):
    if accel is not None and accel.shape != world.pos.shape:
      raise ValueError(f"step: accel must have the shape of pos {world.pos.shape}, got "
                       f"{accel.shape}")
    return _batched(functools.partial(_step_kernel, config), world, accel)
  return _single_step(config)(world, accel)


def step(world: World, config: Config, accel: jax.Array | None = None) -> World:
  """One time step: gravity and `accel`, semi-implicit Euler, chain resolution,
  velocity update, friction; `config.substeps` times with `dt / substeps`.

  Args:
    world: a world, or a batch of worlds (`[B, n, ...]`, e.g. from `jc.stack`); a
      `jax.vmap` over single worlds runs as one batch too.
    config: static configuration.
    accel: optional `[n, 2]` (`[B, n, 2]` for a batch) external acceleration for this
      step (a player's input, say); applied to every active body, immovable ones
      included (that is how a kinematic platform is driven).

  Returns:
    The world after `config.dt`.

  Examples:
    >>> import jaxchain as jc
    >>> w = jc.World.create([[0.0, 0.5], [0.0, -0.5]], [[0.5, 0.5], [5.0, 0.5]], [1.0, float("inf")])
    >>> w = jc.step(w, jc.Config())
    >>> float(w.pos[0, 1]), float(w.vel[0, 1])  # rests on the floor, stopped by it
    (0.5, 0.0)
  """
  check_differentiable(config, "step", world, accel)
  return _step_jit(world, config, accel)


_step_jit = jax.jit(_step, static_argnames="config")
# `step` and `resolve` check their arguments, then call these jitted programs.
step._cache_size = _step_jit._cache_size
resolve._cache_size = _resolve_jit._cache_size


def make_step(config: Config):
  """Returns `step_fn(world, accel=None) -> world`, jitted once for `config` (a world
  or a batch of worlds, as `step` takes them).

  Examples:
    >>> import jaxchain as jc
    >>> step_fn = jc.make_step(jc.Config())
    >>> w = step_fn(jc.World.create([[0.0, 0.0]], [0.5, 0.5], 1.0))
    >>> round(float(w.vel[0, 1]), 4)
    -0.1635
  """
  def step_fn(world: World, accel: jax.Array | None = None) -> World:
    return _step(world, config, accel)

  return jax.jit(step_fn)


def rollout(world: World, config: Config, n_steps: int, controls: jax.Array | None = None, *,
            policy: Callable[[World, jax.Array], jax.Array] | None = None,
            record: Sequence[str] = (),
            horizon: jax.Array | int | None = None) -> tuple[World, Trajectory]:
  """`n_steps` steps under `lax.scan`, open-loop (`controls`) or closed-loop (`policy`).

  Args:
    world: a world, or a batch of worlds (`[B, n, ...]`, e.g. from `jc.stack`); a
      `jax.vmap` over single worlds runs as one batch too (a rollout with a `policy`
      under `vmap` runs per world: pass the batch itself to run it as one).
    config: static configuration.
    n_steps: number of steps (static).
    controls: optional accelerations, `[n_steps, n, 2]` (one per step) or
      `[n, 2]` (the same every step); for a batch `[B, n_steps, n, 2]` or `[B, n, 2]`.
    policy: optional `policy(world, t) -> accel` (`[n, 2]`), called before each step
      with the world as it is and the step index `t` (int32 scalar, from 0): a
      closed loop; for a batch it is called on each world (`jax.vmap`). Jittable,
      vmappable and differentiable like the rest; it is a static argument (hashed by
      identity), so define it once rather than as a new `lambda` per call (each new
      function compiles again). To differentiate with respect to a policy's
      parameters, close over them inside the function you differentiate (see
      docs/toolkit.md, "Closed-loop rollouts").
    record: which extra per-step outputs the trajectory keeps, of
      `("status", "touching", "crushed", "sensed")` (static; default none, to keep
      memory small).
    horizon: optional int (traced: any value runs the same compiled program), or one
      per world (`[B]`) for a batch: only the first `horizon` steps are taken, at most
      `n_steps`. From step `horizon` on the world is kept as it is (velocities
      included), so `final` is the world after `horizon` steps and the trajectory's
      entries `t >= horizon` repeat it; a loss masked to `t < horizon` (or read from
      `final`) is the loss of a `horizon`-step rollout, gradients included. The steps
      past the horizon cost nothing once every world of the batch is past it (a
      `lax.cond` skips them); under `jax.grad` and `jax.vmap` the condition is a
      select and they are computed and discarded. `n_steps` (static) is the maximum:
      compile once for the longest horizon.

  Returns:
    `(final_world, trajectory)` with `trajectory.pos` of shape `[n_steps, n, 2]`
    (`[B, n_steps, n, 2]` for a batch, as `jax.vmap` would give).

  Raises:
    ValueError: for controls of the wrong shape, both `controls` and `policy`, a
      policy whose output is not `[n, 2]`, an unknown `record` name, or a `horizon`
      that is not an integer of shape `()` (or `[B]` for a batch); and for
      `Config(converge=True)` under reverse-mode differentiation (`jax.grad`,
      `jax.vjp`, `jax.linearize`), whose `while_loop`s JAX cannot transpose: use
      `converge=False` for gradients (the same answers). Under `jax.grad` of a function
      that is itself jitted the check cannot see the differentiation: JAX's own
      `while_loop` error comes instead.

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
  batch = _check_world(world, "rollout")
  record = (record,) if isinstance(record, str) else tuple(record)  # Hashable: static.
  unknown = [r for r in record if r not in RECORDABLE]
  if unknown:
    raise ValueError(f"rollout: record= takes names from {RECORDABLE}, got {unknown}")
  if controls is not None and policy is not None:
    raise ValueError("rollout: pass controls= (open loop) or policy= (closed loop), not both; "
                     "add the controls inside the policy: policy(world, t) + controls[t]")
  check_differentiable(config, "rollout", world, controls)
  if horizon is not None:
    horizon = jnp.asarray(horizon)
    want = world.pos.shape[:1] if batch else ()
    if horizon.dtype.kind not in "iu" or horizon.shape not in ((), want):
      raise ValueError(f"rollout: horizon must be an integer of shape () or {want}, got "
                       f"{horizon.dtype} {horizon.shape}")
    horizon = jnp.broadcast_to(horizon.astype(jnp.int32), want)
  if controls is not None:
    controls = jnp.asarray(controls)
    one = world.pos.shape[-2:]
    lead = world.pos.shape[:1] if batch else ()
    if controls.shape == lead + one:
      controls = jnp.broadcast_to(controls[..., None, :, :], lead + (n_steps,) + one)
    if controls.shape != lead + (n_steps,) + one:
      raise ValueError(f"rollout: controls must have shape {lead + (n_steps,) + one} "
                       f"or {lead + one}, got {controls.shape}")
  return _rollout(world, config, n_steps, controls, policy, record, horizon)


@functools.partial(jax.jit, static_argnames=("config", "n_steps", "policy", "record"))
def _rollout(world: World, config: Config, n_steps: int, controls: jax.Array | None,
             policy: Callable[[World, jax.Array], jax.Array] | None,
             record: tuple[str, ...], horizon: jax.Array | None = None
             ) -> tuple[World, Trajectory]:
  """`rollout` after its checks, jitted (config, n_steps, policy and record static)."""
  kernel = functools.partial(_rollout_kernel, config, n_steps, policy, record)
  if world.pos.ndim == 3:
    return _batched(kernel, world, controls, horizon)
  if policy is not None:  # A policy is user code closing over anything: no custom rule.
    return _drop_axis(kernel(_add_axis(world), None, _add_axis(horizon)))
  return _single_rollout(config, n_steps, record)(world, controls, horizon)


def _reverse_mode(x) -> bool:
  """Whether `x` is traced by reverse-mode differentiation (`jax.grad`, `jax.vjp`,
  `jax.linearize`: a linearize tracer, perhaps under `vmap`); forward mode (`jax.jvp`)
  and plain values are not."""
  for _ in range(64):  # Nested transformations: one tracer inside the next.
    if not isinstance(x, jax.core.Tracer):
      return False
    kind = type(x).__name__
    if kind == "LinearizeTracer":
      return True
    if kind == "JVPTracer":  # Linearize by jvp + partial evaluation: an unknown tangent.
      if type(getattr(x, "tangent", None)).__name__ == "JaxprTracer":
        return True
      x = x.primal
    else:
      x = getattr(x, "val", getattr(x, "primal", None))
  return False


def check_differentiable(config: Config, fn: str, *trees) -> None:
  """Raises the error `Config.converge` gives under reverse-mode differentiation (its
  hop loops are `while_loop`s, which JAX cannot transpose), naming the alternative."""
  if config.converge and any(_reverse_mode(x) for x in jax.tree.leaves(trees)):
    raise ValueError(
        f"{fn}: Config(converge=True) is forward-only: its hop loops are while_loops, which "
        f"jax.grad (reverse mode) cannot differentiate. Use config.replace(converge=False) "
        f"for gradients: the same answers bit for bit, with fixed-length hop loops "
        f"(jax.jvp, forward mode, works with either)")
