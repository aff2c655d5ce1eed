"""The step, batch minor: one call per stage, on `State` and `Bodies` (`[..., n, B]`).

A pass reads, at the positions it starts from: candidates (`pairs`), contacts and links
(`contacts`, built once and read by every later stage), resolution (`chain`: positions
and, with velocities, the contact impulses in the same hops), crushing, friction, and
the flags. A substep integrates (semi-implicit Euler), runs `Config.iterations` passes
and the sensors; a step runs `Config.substeps` substeps; a rollout scans steps and
stays in this layout throughout. Every feature a config switches off is left out by a
Python `if` on the static config: it is not traced at all.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence

import jax
import jax.numpy as jnp
from jax import lax

from jaxchain import status
from jaxchain.core import chain, contacts, flags, friction, pairs
from jaxchain.core.layout import (NUM_DIRECTIONS, Bodies, State, any_world, batch_any,
                                  manual_axes, vary)


CLOSING_GATE = "closing_gate"


def passes(bodies: Bodies, pos: jax.Array, config, *, start: jax.Array | None = None,
           vel: jax.Array | None = None, table: pairs.Neighbors | None = None):
  """`config.iterations` resolution passes from `pos` (`[2, n, B]`).

  Returns:
    `(pos, vel, status [B], crushed [n, B], touching [4, n, B])` (`vel` None without
    `vel`; `touching` ORed over the passes). `DEPTH_EXHAUSTED` is that of every pass: a
    later pass redoes the positions an earlier one cut short, not the velocities, and
    starts from other positions than a full-depth pass would have left.
  """
  n, B = bodies.shape
  mass = chain.body_mass(bodies.inv_mass, bodies.active)
  movable = bodies.movable
  one_way = None
  if config.one_way:
    one_way = contacts.OneWay(one_way=bodies.active & bodies.one_way,
                              solid=bodies.fixed & ~bodies.one_way)
  # Seams: the faces of immovable bodies make surfaces (one-way bodies excepted; sensors
  # are out of every candidate table already).
  surface = walk = None
  if config.immovable and start is not None:
    surface = bodies.fixed & ~bodies.one_way if config.one_way else bodies.fixed
    if config.one_way:  # One-way tops are surfaces when walked on.
      walk = bodies.fixed & bodies.one_way
  table = pairs.build(pos, bodies, config, start) if table is None else table

  def resolve(f, p, v):
    """The stages after the link table: chain, crushing, friction."""
    out = chain.displacement(f, mass, ~movable, depth=config.depth,
                             track_immovable=config.immovable, vel=v, stick=friction.STICK,
                             converge=config.converge)
    scaled, exhausted = out.scaled, out.exhausted
    if v is not None:
      # The select (a no-op: immovable bodies' changes are 0) keeps LLVM from
      # contracting the update into a fused multiply-add.
      v = v + jnp.where(movable[None], out.dvel, 0.0)
      if config.immovable:
        v = chain.crush(v, f, out.jammed, movable)
      if config.has_friction:
        v, rubbed, cut = friction.friction(v, f, out.impulse, bodies.friction, out.shared,
                                           out.sticking, mass, depth=config.depth,
                                           converge=config.converge, short=out.short)
        scaled, exhausted = scaled | rubbed, exhausted | cut
    return p + out.disp, v, scaled, exhausted, out.crushed

  def overlap_parts(cand):
    """What `overlap_left` reads of the candidates that does not move: the pairs it may
    report (movable row, neither body one-way: a one-way body lets bodies through, the
    one-way rule decides its contacts) and their summed half sizes less the skin."""
    g = cand.gather
    ok = cand.mask & movable[None]
    if config.one_way:
      ok = ok & ~bodies.one_way[None] & ~g(bodies.one_way)
    return ok, [bodies.half[k][None] + g(bodies.half[k]) - config.skin for k in (0, 1)]

  def source(tab):
    """`(table, admitted candidates, overlap_parts)` of a neighbour table or dense pairs:
    candidates that do not move, admitted once and read by every pass."""
    cand = contacts.admit(pairs.candidates(pos, bodies, config, tab)[0], bodies,
                          layers=config.layers, sensors=config.sensors)
    return tab, cand, overlap_parts(cand)

  # The grid's rows without a table are built per pass (`fixed` None).
  fixed = source(table) if table is not None or not config.uses_grid(n) else None

  def candidates(p, src):
    """The admitted candidates at `p` and the status bits of reading them there."""
    if src is not None:
      tab, cand, _ = src
      found = jnp.zeros((B,), jnp.int32)
      if tab is not None:  # The margin check.
        found = tab.code | pairs.moved(tab, p, bodies.active, config.margin)
      return cand, found
    cand, found = pairs.candidates(p, bodies, config, table)
    return contacts.admit(cand, bodies, layers=config.layers, sensors=config.sensors), found

  def overlap_left(p, crushed, src):
    """`[B]`: a pair of the candidates overlaps by more than the skin along both axes at
    `p`, neither body crushed in this step."""
    if src is not None:
      cand, (ok, reach) = src[1], src[2]
    else:
      cand = candidates(p, src)[0]
      ok, reach = overlap_parts(cand)
    ok = ok & ~crushed[None]
    for k in (0, 1):  # A crushed partner sits at infinity: no overlap.
      ok = ok & (reach[k] > jnp.abs(cand.gather(jnp.where(crushed, jnp.inf, p[k])) - p[k][None]))
    return any_world(ok)

  def one_pass(_, carry, src=fixed):
    p, v, code, cut, crushed, touching = carry
    cand, found = candidates(p, src)
    ow = one_way if one_way is None or v is None else dataclasses.replace(one_way, vel=v)
    c = contacts.contacts(p, bodies.half, cand, config.skin, start, ow, surface, walk)
    f, overflow = contacts.link_table(c, cand, config.links, rows=movable)
    if f.slots > 1 and f.idx is not None:
      # Link slots that cost what the batch needs: a settled room has at most one link
      # per body and direction, and a batch in which no body has a second one runs the
      # chain on one slot (the same answer, half the hops' gathers).
      new_p, v, scaled, exhausted, hit = lax.cond(
          batch_any(f.mask[1:]), lambda: resolve(f, p, v), lambda: resolve(f.first(1), p, v))
    else:
      new_p, v, scaled, exhausted, hit = resolve(f, p, v)
    code = (code | found | flags.bit(overflow, status.LINK_OVERFLOW)
            | flags.bit(scaled, status.IMPULSES_SCALED))
    return new_p, v, code, cut | exhausted, crushed | hit, touching | contacts.touching(f)

  init = vary((pos, vel, jnp.zeros((B,), jnp.int32), jnp.zeros((B,), bool),
               jnp.zeros((n, B), bool), jnp.zeros((NUM_DIRECTIONS, n, B), bool)))
  if vel is None:  # `resolve`: positions alone, no closing stage.
    state = one_pass(0, init) if config.iterations == 1 else lax.fori_loop(
        0, config.iterations, one_pass, init)
  elif config.closing == 0:  # No budget: the overlap left is reported, not closed.
    state = one_pass(0, init) if config.iterations == 1 else lax.fori_loop(
        0, config.iterations, one_pass, init)
    left = overlap_left(state[0], state[4], fixed)
    state = state[:2] + (state[2] | flags.bit(left, status.OVERLAP_LEFT),) + state[3:]
  else:
    # The closing stage: more passes, from the positions reached (contact axes from the
    # substep's start, on the velocities the passes left), for the worlds that still
    # have a pair overlapping by more than the skin, at most `closing` of them; a world
    # with none left keeps its state, bit for bit. One loop with the passes: one copy
    # of the pass's code, and a batch with nothing left skips the rest (`lax.cond`).
    # Closing passes read the substep's candidates, neighbour table and its margin
    # check included (`NEIGHBOR_MARGIN`), as a second pass does.
    def body(k, carry):
      state, need, src = carry
      main = k < config.iterations

      def run(state, src):
        new = one_pass(k, state, src)
        return new, overlap_left(new[0], new[4], src), src

      with jax.named_scope(CLOSING_GATE):  # The work meter's mark: run on main passes.
        new, left, src = lax.cond(main | batch_any(need), jax.checkpoint(run),
                                  lambda s, src: (s, jnp.zeros_like(need), src), state, src)
      take = main | need  # [B]: the worlds this pass is for.
      state = jax.tree.map(lambda x, y: jnp.where(per_world(take, x), x, y), new, state)
      return state, jnp.where(take, left, need), src

    carry = vary((init, jnp.zeros((B,), bool), fixed))
    if B == 1:  # XLA:CPU keeps a loop's body whole at one world; unrolled, it simplifies.
      for k in range(config.iterations + config.closing):
        carry = body(k, carry)
      state, need, _ = carry
    else:
      state, need, _ = lax.fori_loop(0, config.iterations + config.closing, body, carry)
    state = state[:2] + (state[2] | flags.bit(need, status.OVERLAP_LEFT),) + state[3:]
  p, v, code, exhausted, crushed, touching = state
  return p, v, code | flags.bit(exhausted, status.DEPTH_EXHAUSTED), crushed, touching


def per_world(flag: jax.Array, like: jax.Array) -> jax.Array:
  """`[B]` bool reshaped to broadcast against `like` (`[..., B]`)."""
  return flag.reshape((1,) * (like.ndim - 1) + flag.shape)


def sensors(bodies: Bodies, pos: jax.Array, config, table: pairs.Neighbors | None = None, *,
            start: jax.Array | None = None) -> tuple[jax.Array, jax.Array]:
  """`sensed` (`[n, B]`) at `pos`, or with `start` swept over the motion from `start`
  (a substep), and the status bits of the candidate table it reads; all False without
  `config.sensors`."""
  n, B = bodies.shape
  if not config.sensors:
    return jnp.zeros((n, B), bool), jnp.zeros((B,), jnp.int32)
  cand, found = pairs.candidates(pos, bodies, config, table)
  return flags.sensed(bodies, pos, cand, start), found


def crushed_bit(crushed: jax.Array) -> jax.Array:
  return flags.bit(any_world(crushed), status.CRUSHED)


def substep(state: State, bodies: Bodies, config, sub_dt: float, accel: jax.Array | None,
            table: pairs.Neighbors | None = None) -> tuple[State, pairs.Neighbors | None]:
  """Integrate (semi-implicit Euler), then the passes, which move the bodies apart and
  update their velocities from the contact impulses and friction. `table`: the
  neighbour table of the substep before (`pairs.refresh` keeps it while it holds);
  returns the state and the table this substep read."""
  pos, vel = state.pos, state.vel
  active, movable = bodies.active[None], bodies.movable[None]
  if accel is not None:
    vel = vel + jnp.where(active, accel * sub_dt, 0.0)
  if config.has_gravity:
    vel = vel + jnp.where(movable, bodies.gravity[:, None, :] * sub_dt, 0.0)
  code = flags.too_fast(bodies, vel, sub_dt)
  motion = jnp.where(active, vel * sub_dt, 0.0)
  # pos + motion, written to round as XLA:CPU rounds the [n, 2] layout of the previous
  # core (one fused multiply-add along x, two roundings along y): bit-identical results
  # while both exist.
  predicted = jnp.stack([jnp.where(active[0], pos[0] + vel[0] * sub_dt, pos[0]),
                         pos[1] + motion[1]])
  table = pairs.refresh(table, predicted, bodies, config, pos)  # None without neighbours.
  p, v, found, crushed, touching = passes(bodies, predicted, config, start=pos, vel=vel,
                                          table=table)
  # Sensors see every overlap during the step: swept over this substep's motion.
  sensed, seen = sensors(bodies, p, config, table, start=pos)
  code = (code | found | seen | flags.finite(bodies, p, v) | crushed_bit(crushed)
          | flags.motion_lost(bodies, pos, p, v, sub_dt))
  return State(pos=p, vel=v, status=state.status | code, touching=state.touching | touching,
               crushed=state.crushed | crushed, sensed=state.sensed | sensed), table


def step(state: State, bodies: Bodies, config, accel: jax.Array | None = None) -> State:
  """One step: `config.substeps` substeps of `dt / substeps`. `accel`: optional
  `[2, n, B]` accelerations for this step (every active body)."""
  with manual_axes(state, bodies, accel):
    return advance(state, None, bodies, config, accel)[0]


def advance(state: State, table: pairs.Neighbors | None, bodies: Bodies, config,
            accel: jax.Array | None = None) -> tuple[State, pairs.Neighbors | None]:
  """`step` that also takes and returns the neighbour table (`pairs.refresh`): a
  rollout carries it from step to step and rebuilds it only when a body left its
  margin. The same answer as `step`."""
  sub_dt = config.dt / config.substeps
  zeros = lambda x: jnp.zeros_like(x)
  state = dataclasses.replace(state, crushed=zeros(state.crushed),
                              touching=zeros(state.touching), sensed=zeros(state.sensed),
                              status=state.status | flags.switched_off(bodies, config))
  if config.substeps == 1:
    return substep(state, bodies, config, sub_dt, accel, table)
  if table is None:
    table = pairs.empty(bodies, config)
  return lax.fori_loop(0, config.substeps,
                       lambda _, c: substep(c[0], bodies, config, sub_dt, accel, c[1]),
                       vary((state, table)))


def resolve(state: State, bodies: Bodies, config) -> State:
  """Collision resolution only: positions, `crushed`, `touching`, `sensed`, status;
  velocities untouched."""
  with manual_axes(state, bodies):
    return _resolve(state, bodies, config)


def _resolve(state: State, bodies: Bodies, config) -> State:
  pos, _, code, crushed, touching = passes(bodies, state.pos, config)
  sensed, found = sensors(bodies, pos, config)
  code = (code | found | flags.finite(bodies, state.pos, pos) | crushed_bit(crushed)
          | flags.switched_off(bodies, config, physics=False))
  return dataclasses.replace(state, pos=pos, crushed=crushed, touching=touching, sensed=sensed,
                             status=state.status | code)


def rollout(state: State, bodies: Bodies, config, n_steps: int,
            controls: jax.Array | None = None,
            policy: Callable[[State, jax.Array], jax.Array] | None = None,
            record: Sequence[str] = (),
            horizon: jax.Array | None = None) -> tuple[State, dict[str, jax.Array]]:
  """`n_steps` steps under `lax.scan`, in this layout throughout.

  Args:
    controls: optional `[n_steps, 2, n, B]` accelerations.
    policy: optional `policy(state, t) -> [2, n, B]` accelerations (closed loop).
    record: names of `State` fields kept per step besides `pos` and `vel`.
    horizon: optional `[B]` int: world b takes only its first `horizon[b]` steps; from
      step `horizon[b]` on its state is kept as it is (the steps are computed for the
      batch while any world still runs them, and skipped, by `lax.cond`, once none
      does).

  Returns:
    `(final, trajectory)`, the trajectory a dict of `[n_steps, ...]` arrays.
  """
  def body(carry, xs):
    s, table = carry
    t, given = xs
    accel = given if policy is None else policy(s, t)
    if horizon is None:
      s, table = advance(s, table, bodies, config, accel)
    else:
      live = t < horizon  # [B]
      new, table = lax.cond(batch_any(live), lambda: advance(s, table, bodies, config, accel),
                            lambda: (s, table))
      s = jax.tree.map(lambda x, y: jnp.where(per_world(live, x), x, y), new, s)
    out = {"pos": s.pos, "vel": s.vel}
    out.update({name: getattr(s, name) for name in record})
    return (s, table), out

  steps = jnp.arange(n_steps, dtype=jnp.int32)
  with manual_axes(state, bodies, controls):
    (state, _), traj = lax.scan(body, vary((state, pairs.empty(bodies, config))),
                                (steps, controls), length=n_steps)
  return state, traj
