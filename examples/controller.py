"""A kinematic player controller beside the physics: queries and character helpers.

The player (an immovable box that only `jc.move_and_slide` moves) starts on a one-way
ledge, drops through it (`jc.drop_through`), runs to and fro across a room, turning at
walls, and jumps when a ray cast ahead (`jc.raycast`) sees a box within `LOOK` units.
A kinematic platform patrols above the floor carrying a frictionless crate
(`jc.drive_platforms` reverses it and carries the crate by the change); the player rides
it when it lands on it (`SlideInfo.floor_velocity`). Everything but the player is moved
by `jc.step`, with the player's velocity set to 0 for the step, so the step does not move
it twice: to the boxes it is a wall. The frames run in one jitted `lax.scan`, and
`jax.vmap` runs worlds with different run speeds at once.

    python examples/controller.py [--worlds 4] [--frames 360]

Prints, per world, when the player reached the floor below the ledge, its jumps and
highest point after that, whether it rode the platform, and whether the crate stayed on
the platform.
"""

from __future__ import annotations

import argparse

import jax
import jax.numpy as jnp
import numpy as np

import jaxchain as jc

INF = float("inf")
ALL = 0xFFFFFFFF
DT = 1 / 60
G = 9.81
JUMP = 7.5  # Take-off speed (u/s): a jump of about 2.9 units.
LOOK = 1.5  # A box closer than this ahead (from the player's side) makes it jump.
FLOOR, LEFT, RIGHT, LEDGE, PLATFORM, CRATE, BOX, PLAYER = range(8)
PLATFORM_SPEED, PLATFORM_RANGE = 1.5, (3.5, 5.5)  # Patrols x between these.


def level() -> jc.World:
  """A room 16 wide, a one-way ledge (top y = 2.5) with the player on it, a kinematic
  platform (top y = 1.5) with a frictionless crate on it, and a box on the floor that
  the player jumps over (it may land on the platform)."""
  return jc.World.create(
      pos=[[0.0, -0.5], [-8.5, 4.0], [8.5, 4.0], [-4.0, 2.4], [4.0, 1.25], [4.0, 2.0],
           [0.0, 0.5], [-4.0, 3.0]],
      half=[[9.0, 0.5], [0.5, 5.0], [0.5, 5.0], [2.0, 0.1], [1.5, 0.25], [0.5, 0.5],
            [0.5, 0.5], [0.4, 0.5]],
      mass=[INF, INF, INF, INF, INF, 1.0, 1.0, INF],
      one_way=[False, False, False, True, False, False, False, False],
      # Layers: the player (8) does not collide with the crate (4), so it never wedges
      # the crate against the platform it rides.
      category=[1, 1, 1, 1, 1, 4, 2, 8], mask=[ALL] * 7 + [ALL & ~4])


def frame(world: jc.World, carry, config: jc.Config, run: jax.Array):
  """One frame: the platform's patrol, the physics step, then the player's move."""
  v_player, direction, on_floor, floor_v = carry
  # The platform turns at the ends of its range; its riders turn with it.
  x, vx = world.pos[PLATFORM, 0], world.vel[PLATFORM, 0]
  turn = ((x > PLATFORM_RANGE[1]) & (vx > 0)) | ((x < PLATFORM_RANGE[0]) & (vx < 0))
  world = jc.drive_platforms(world, PLATFORM, jnp.stack([jnp.where(turn, -vx, vx), 0.0]))
  # Everything else: one physics step, with the player parked (a wall to the boxes).
  world = jc.step(world.replace(vel=world.vel.at[PLAYER].set(0.0)), config)
  # The player: jump when on the floor and a box is close ahead; run, fall, ride.
  ahead = jc.raycast(world, world.pos[PLAYER], jnp.stack([direction, 0.0]),
                     LOOK + world.half[PLAYER, 0], ignore=PLAYER)
  jump = on_floor & ahead.hit & (ahead.body == BOX)
  vy = jnp.where(jump, JUMP, v_player[1]) - G * DT
  move = jnp.stack([direction * run, vy]) + floor_v * jnp.array([1.0, 0.0])
  world, info = jc.move_and_slide(world, PLAYER, move, DT)
  direction = jnp.where(info.on_wall, -direction, direction)
  v_player = jnp.stack([direction * run, world.vel[PLAYER, 1]])
  carry = (v_player, direction, info.on_floor, info.floor_velocity)
  return world, carry, (info.on_floor, jump, jnp.where(info.on_floor, info.hit_y, -1))


def run_worlds(runs: np.ndarray, frames: int):
  """Runs one world per run speed for `frames` frames; returns the final worlds and the
  per-frame player positions, floor flags, jumps and floor bodies (`[worlds, frames]`)."""
  start = level()
  start = jc.drive_platforms(start, PLATFORM, [PLATFORM_SPEED, 0.0])
  config = jc.Config.for_world(start)
  start, _ = jc.drop_through(start, PLAYER)

  def one(run):
    def body(state, _):
      world, carry = state
      world, carry, (on_floor, jump, floor) = frame(world, carry, config, run)
      return (world, carry), (world.pos, on_floor, jump, floor)

    carry = (jnp.zeros(2), jnp.float32(1.0), jnp.bool_(False), jnp.zeros(2))
    (world, _), trace = jax.lax.scan(body, (start, carry), None, length=frames)
    return world, trace

  return jax.jit(jax.vmap(one))(jnp.asarray(runs, jnp.float32))


def report(runs: np.ndarray, final: jc.World, trace) -> list[str]:
  """One line per world, and the status line."""
  pos, on_floor, jumps, floor = (np.asarray(x) for x in trace)
  lines = []
  for b in range(len(runs)):
    y = pos[b, :, PLAYER, 1]
    landed = int(np.argmax(on_floor[b] & (np.abs(y - 0.5) < 1e-4)))
    crate_on = abs(float(final.pos[b, CRATE, 1] - final.pos[b, PLATFORM, 1]) - 0.75) < 1e-3
    rode = bool(np.any(floor[b] == PLATFORM))
    lines.append(f"world {b} (run {runs[b]:.2f} u/s): dropped through the ledge to the floor at "
                 f"frame {landed}, {int(np.sum(jumps[b]))} jumps, highest y after that "
                 f"{y[landed:].max():.2f}, rode the platform: {rode}, "
                 f"crate still on the platform: {crate_on}")
  problems = jc.check(final)
  lines.append("status: " + ("ok" if not problems else "; ".join(problems)))
  return lines


def main(argv=None) -> int:
  parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
  parser.add_argument("--worlds", type=int, default=4)
  parser.add_argument("--frames", type=int, default=360)
  args = parser.parse_args(argv)
  runs = np.linspace(2.0, 4.0, args.worlds)
  final, trace = run_worlds(runs, args.frames)
  print("\n".join(report(runs, final, trace)))
  return 0


if __name__ == "__main__":
  raise SystemExit(main())
