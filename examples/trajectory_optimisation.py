"""Trajectory optimisation: find the player's pushes, one per step, that bring a box to
rest on a target, by gradient descent (Adam) through the whole rollout.

A player stands against a box on a floor with friction. The controls are its
horizontal accelerations at every step (open loop, `rollout(..., controls)`); the loss is
the box's squared distance from the target at the end, plus its squared final speed (it
should be at rest there) and a small effort penalty. The gradient with respect to every
control flows through the contacts, the chain resolution and friction of every step.
The first guess, a constant push, overshoots; gradient descent with a backtracking line
search shapes the pushes: hard early, below what static friction holds at the end. (Adam
with a fixed rate moves every push by about the same amount each iteration: here it
lowered them all below the static-friction threshold, where the box stays put and every
gradient is 0.)

    python examples/trajectory_optimisation.py            # 120 steps, 100 iterations
    python examples/trajectory_optimisation.py --small    # the size the tests run
"""

from __future__ import annotations

import argparse

import jax
import jax.numpy as jnp
import numpy as np

import jaxchain as jc

INF = float("inf")
EFFORT = 1e-5  # Weight of the summed squared pushes.


def scene() -> tuple[jc.World, jc.Config]:
  """Player (body 0) touching a box (body 1) on a floor (body 2), friction 0.3
  everywhere. (A player that starts apart from the box can lose it: pushes that stop
  short of the box have no gradient with respect to where the box ends.)"""
  world = jc.World.create([[0.5, 0.5], [1.5, 0.5], [0.0, -0.5]],
                          [[0.5, 0.5], [0.5, 0.5], [50.0, 0.5]], [1.0, 1.0, INF], friction=0.3)
  # A row on a floor: one link per body and direction (`links=1` compiles a smaller step).
  return world, jc.Config.for_world(world, links=1)


def loss_fn(pushes: jax.Array, world: jc.World, config: jc.Config, target: float):
  """The loss of the pushes (`[steps]` accelerations of the player along x), and where
  the box ends and how fast it moves."""
  steps = pushes.shape[0]
  controls = jnp.zeros((steps,) + world.pos.shape, pushes.dtype).at[:, 0, 0].set(pushes)
  final, _ = jc.rollout(world, config, steps, controls)
  x, v = final.pos[1, 0], final.vel[1, 0]
  return (x - target) ** 2 + v**2 + EFFORT * jnp.sum(pushes**2), (x, v)


# One program per rollout length (the config is static).
value_and_grad = jax.jit(jax.value_and_grad(loss_fn, has_aux=True), static_argnums=(2,))


def optimise(target: float = 4.0, steps: int = 120, iterations: int = 100,
             push: float = 10.0, verbose: bool = False) -> dict[str, float]:
  """Gradient descent on the per-step pushes from a constant `push`, each step accepted
  by a backtracking line search (the step size grows after a success and halves after a
  failure). Returns the first and last loss, where the box ends and its final speed, and
  the pushes."""
  world, config = scene()
  pushes = jnp.full((steps,), push, jnp.float32)
  (loss, (x, speed)), grad = value_and_grad(pushes, world, config, target)
  first, rate = float(loss), 1.0
  for k in range(1, iterations + 1):
    trial = pushes - rate * grad
    (trial_loss, aux), trial_grad = value_and_grad(trial, world, config, target)
    if float(trial_loss) < float(loss):
      pushes, loss, (x, speed), grad = trial, trial_loss, aux, trial_grad
      rate *= 1.5
    else:
      rate *= 0.5
    if verbose and (k == 1 or k % 10 == 0):
      print(f"iteration {k:3d}: loss {float(loss):.3e}  box at {float(x):.4f}, "
            f"speed {float(speed):+.4f}  (step size {rate:.3g})")
  return dict(first_loss=first, loss=float(loss), box_x=float(x), box_speed=float(speed),
              pushes=np.asarray(pushes))


def main():
  parser = argparse.ArgumentParser(description=__doc__,
                                   formatter_class=argparse.RawDescriptionHelpFormatter)
  parser.add_argument("--target", type=float, default=4.0, help="where the box should rest")
  parser.add_argument("--steps", type=int, default=120, help="steps of the rollout")
  parser.add_argument("--iterations", type=int, default=100, help="gradient steps")
  parser.add_argument("--small", action="store_true",
                      help="30 steps, 30 iterations, target 1.7 (what the tests run)")
  args = parser.parse_args()
  steps, iterations = (30, 30) if args.small else (args.steps, args.iterations)
  target = 1.7 if args.small else args.target
  out = optimise(target, steps, iterations, verbose=True)
  print(f"box rests at x = {out['box_x']:.4f} (target {target}), speed {out['box_speed']:+.4f}; "
        f"loss {out['first_loss']:.3e} -> {out['loss']:.3e}")


if __name__ == "__main__":
  main()
