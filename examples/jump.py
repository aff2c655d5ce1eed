"""A player that jumps only when it stands on something: contact flags in a closed loop.

The player runs right across the shipped level `platformer1` (one-way ledges, boxes, a
drifting platform) and jumps whenever `jc.grounded` says it is on something: on the
floor, on a box, or on a one-way ledge it jumped up through. The policy reads the
world each step (`jc.rollout(..., policy=...)`), so the same compiled loop runs a
batch of worlds with different box masses under `jax.vmap`.

    python examples/jump.py [--worlds 8] [--steps 300]

Prints, per world, how many jumps it made, the highest point the player reached, and
whether it ever stood on a one-way ledge.
"""

from __future__ import annotations

import argparse

import jax
import jax.numpy as jnp
import numpy as np

import jaxchain as jc
from jaxchain import levels

JUMP = 420.0  # One step of this upward acceleration: a jump of about 7 units/s.
RUN = 3.0  # Rightward acceleration while grounded (air control: a third of it).


def main(argv=None) -> int:
  parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
  parser.add_argument("--worlds", type=int, default=8)
  parser.add_argument("--steps", type=int, default=300)
  args = parser.parse_args(argv)

  level = levels.load("platformer1")
  player, ledges = level.player, list(level.tags["platform"])
  rng = np.random.default_rng(0)
  boxes = np.isfinite(level.mass) & (np.arange(len(level)) != player)
  worlds = jc.stack([level.world(friction=0.3, mass=np.where(
      boxes, level.mass * rng.uniform(0.5, 2.0, len(level)), level.mass))
      for _ in range(args.worlds)])
  config = jc.Config.for_world(worlds)

  def policy(world, t):
    del t
    grounded = jc.grounded(world)[player]
    ax = jnp.where(grounded, RUN, RUN / 3)
    ay = jnp.where(grounded, JUMP, 0.0)  # Jump only when standing on something.
    return jnp.zeros_like(world.pos).at[player].set(jnp.stack([ax, ay]))

  run = jax.jit(jax.vmap(lambda w: jc.rollout(w, config, args.steps, policy=policy,
                                              record=("touching",))))
  final, traj = run(worlds)
  grounded = np.asarray(traj.touching[:, :, player, 3])  # [worlds, steps]
  jumps = np.sum(grounded[:, :-1], axis=1)  # Each grounded step is followed by a jump.
  y = np.asarray(traj.pos[:, :, player, 1])
  feet = y - level.half[player, 1]
  ledge_tops = level.pos[ledges, 1] + level.half[ledges, 1]
  on_ledge = grounded & np.any(np.isclose(feet[..., None], ledge_tops, atol=1e-3), axis=-1)
  for b in range(args.worlds):
    print(f"world {b}: {int(jumps[b]):3d} jumps, highest y {y[b].max():6.2f}, "
          f"stood on a one-way ledge: {bool(on_ledge[b].any())}")
  problems = jc.check(final)
  print("status: " + ("ok" if not problems else "; ".join(problems)))
  return 0


if __name__ == "__main__":
  raise SystemExit(main())
