"""Command line: `jaxchain demo`."""

from __future__ import annotations

import argparse
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np
from tqdm import tqdm

from jaxchain import metrics, scenes
from jaxchain.config import Config
from jaxchain.step import rollout
from jaxchain.world import stack


def _positive_int(text: str) -> int:
  value = int(text)
  if value < 1:
    raise argparse.ArgumentTypeError(f"must be a positive integer, got {value}")
  return value


def demo(batch: int, steps: int, chunk: int, seed: int, depth: int | None,
         iterations: int, friction: float, push: float, progress: bool) -> dict:
  """Runs the platformer demo and returns the figures it prints."""
  rng = np.random.default_rng(seed)
  layouts = [scenes.platformer(rng) for _ in range(batch)]
  first = layouts[0]
  worlds = stack([p.scene.world(friction=friction) for p in layouts])
  overrides = dict(iterations=iterations)
  if depth is not None:
    overrides["depth"] = depth
  config = Config.for_world(worlds, **overrides)
  n = worlds.num_bodies
  controls = np.zeros((batch, n, 2), np.float32)
  controls[:, first.player, 0] = push  # The player's input: a constant push to the right.
  controls = jnp.asarray(controls)
  chunk = min(chunk, steps)
  if steps % chunk:
    raise SystemExit(f"jaxchain demo: --steps ({steps}) must be a multiple of --chunk ({chunk})")

  run = jax.jit(jax.vmap(lambda w, u: rollout(w, config, chunk, u)[0]))
  print(f"jaxchain demo: {batch} worlds x {n} bodies, {steps} steps of {config.dt:.4f} s, "
        f"depth {config.depth}, iterations {config.iterations}, friction {friction}, "
        f"device {jax.devices()[0].device_kind}")
  t0 = time.perf_counter()
  compiled = run.lower(worlds, controls).compile()
  compile_s = time.perf_counter() - t0

  start_row = np.asarray(worlds.pos[:, first.row, 0])
  t0 = time.perf_counter()
  world = worlds
  with tqdm(total=steps, unit="step", disable=not progress, file=sys.stderr) as bar:
    for _ in range(steps // chunk):
      world = compiled(world, controls)
      jax.block_until_ready(world)
      bar.update(chunk)
  run_s = time.perf_counter() - t0

  finite = bool(np.all(np.isfinite(np.asarray(world.pos))))
  penetration = float(np.max(jax.vmap(metrics.max_penetration)(world)))
  row_right = np.asarray(world.pos[:, first.row, 0] + world.half[:, first.row, 0])
  intrusion = float(np.max(np.maximum(row_right - first.wall_face, 0.0)))
  moved = np.asarray(world.pos[:, first.row, 0])[:, -1] - start_row[:, -1]
  at_wall = int(np.sum(first.wall_face - row_right[:, -1] < 1e-3))
  figures = dict(
      compile_s=compile_s, run_s=run_s, world_steps_per_s=batch * steps / run_s,
      body_steps_per_s=batch * steps * n / run_s, max_penetration=penetration,
      wall_intrusion=intrusion, row_moved_mean=float(np.mean(moved)), worlds_at_wall=at_wall,
      finite=finite)
  print(f"compile time          {compile_s:8.2f} s")
  print(f"run time              {run_s:8.2f} s")
  print(f"world-steps/s         {figures['world_steps_per_s']:12.4g}")
  print(f"body-steps/s          {figures['body_steps_per_s']:12.4g}")
  print(f"final max penetration {penetration:12.3g}")
  print(f"row pushed            {figures['row_moved_mean']:8.3f} units on average; "
        f"{at_wall}/{batch} rows against the wall")
  print(f"row intrusion into wall {intrusion:10.3g}")
  print(f"all states finite     {finite}")
  return figures


def main(argv=None) -> int:
  parser = argparse.ArgumentParser(prog="jaxchain", description=__doc__)
  sub = parser.add_subparsers(dest="command", required=True)
  p = sub.add_parser("demo", help="simulate the built-in platformer scene in many worlds at once")
  p.add_argument("--batch", type=_positive_int, default=1024, help="worlds in parallel (default 1024)")
  p.add_argument("--steps", type=_positive_int, default=600, help="time steps of 1/60 s (default 600)")
  p.add_argument("--chunk", type=_positive_int, default=50, help="steps per compiled call (default 50)")
  p.add_argument("--seed", type=int, default=0, help="seed for the box masses (default 0)")
  p.add_argument("--depth", type=int, default=None, help="chain depth K (default: from the scene)")
  p.add_argument("--iterations", type=_positive_int, default=1, help="resolution passes per step")
  p.add_argument("--friction", type=float, default=0.3, help="Coulomb friction (default 0.3)")
  p.add_argument("--push", type=float, default=20.0, help="player's push acceleration (default 20)")
  p.add_argument("--no-progress", action="store_true", help="no progress bar")
  args = parser.parse_args(argv)
  if args.command == "demo":
    demo(args.batch, args.steps, args.chunk, args.seed, args.depth, args.iterations,
         args.friction, args.push, progress=not args.no_progress)
  return 0


if __name__ == "__main__":
  sys.exit(main())
