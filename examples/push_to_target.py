"""Gradient descent through a rollout: choose the player's speed so that the box it
pushes slides to a stop on a target.

A player runs at the box along a floor with friction; the box is shoved, slides and
stops. The loss is the squared distance from where the box stops to the target; its
gradient with respect to the player's initial speed flows through 120 steps of
contacts, chain resolution and friction.

    python examples/push_to_target.py [--target 4.0]
"""

from __future__ import annotations

import argparse

import jax
import jax.numpy as jnp

import jaxchain as jc

INF = float("inf")


def scene() -> jc.World:
  """Player (body 0) and box (body 1) on an immovable floor (body 2)."""
  return jc.World.create([[0.0, 0.5], [1.5, 0.5], [0.0, -0.5]],
                         [[0.5, 0.5], [0.5, 0.5], [50.0, 0.5]], [1.0, 1.0, INF], friction=0.3)


CONFIG = jc.Config(friction=True)
STEPS = 120


def box_stop(speed: jax.Array, world: jc.World) -> jax.Array:
  """Where the box is after `STEPS` steps when the player starts at `speed`."""
  start = world.replace(vel=world.vel.at[0, 0].set(speed))
  final, _ = jc.rollout(start, CONFIG, STEPS)
  return final.pos[1, 0]


def optimise(target: float, speed: float = 3.0, iterations: int = 40,
             learning_rate: float = 0.5, verbose: bool = False) -> tuple[float, float]:
  """Plain gradient descent on the player's speed. Returns `(speed, box stop)`."""
  world = scene()

  def loss(s):
    return (box_stop(s, world) - target) ** 2

  value_and_grad = jax.jit(jax.value_and_grad(loss))
  s = jnp.asarray(speed)
  for k in range(iterations):
    value, grad = value_and_grad(s)
    if verbose:
      print(f"iteration {k:2d}: speed {float(s):.4f}  loss {float(value):.3e}  grad {float(grad):+.3e}")
    s = s - learning_rate * grad
  return float(s), float(box_stop(s, world))


def main():
  parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
  parser.add_argument("--target", type=float, default=4.0, help="where the box should stop")
  args = parser.parse_args()
  speed, stop = optimise(args.target, verbose=True)
  print(f"player speed {speed:.4f} stops the box at x = {stop:.4f} (target {args.target})")


if __name__ == "__main__":
  main()
