"""Command line: `jaxchain demo`."""

from __future__ import annotations

import argparse
import math
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np
from tqdm import tqdm

from jaxchain import flags, levels, metrics, scenes, status
from jaxchain.config import Config
from jaxchain.stepping import rollout
from jaxchain.world import stack

# `--level`: the player's jump, an upward acceleration for one step when grounded
# (about 7 units/s at 60 steps/s: 2.5 units high, enough for a ledge two cells up).
JUMP = 420.0

# Status bit -> its name in `jaxchain.status` (FAST_BODY, ...), for the summary.
_BIT_NAMES = {bit: bit.name for bit in status.Status if bit}


def _integer(text: str, lo: int) -> int:
  try:
    value = int(text)
  except ValueError:
    raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
  if value < lo:
    what = "a positive integer" if lo == 1 else f"an integer >= {lo}"
    raise argparse.ArgumentTypeError(f"must be {what}, got {value}")
  return value


def _positive_int(text: str) -> int:
  return _integer(text, 1)


def _nonnegative_int(text: str) -> int:
  return _integer(text, 0)


def _finite_float(text: str, nonnegative: bool = False) -> float:
  try:
    value = float(text)
  except ValueError:
    raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
  if not math.isfinite(value):
    raise argparse.ArgumentTypeError(f"must be a finite number, got {text}")
  if nonnegative and value < 0:
    raise argparse.ArgumentTypeError(f"must be >= 0, got {value:g}")
  return value


def _nonnegative_float(text: str) -> float:
  return _finite_float(text, nonnegative=True)


def status_summary(world) -> dict[str, int]:
  """`{message: number of worlds}` for every status bit set in any world of the
  batch, each message once, in `jc.check` order (from `status.check`)."""
  counts: dict[str, int] = {}
  for line in status.check(world):
    text = line.split(": ", 1)[1]  # Drop the "world b: " prefix.
    counts[text] = counts.get(text, 0) + 1
  return counts


def demo(batch: int, steps: int, chunk: int, seed: int, depth: int | None,
         iterations: int, friction: float, push: float, progress: bool,
         converge: bool = True, level: str | None = None) -> dict:
  """Runs the platformer demo and returns the figures it prints.

  With `level` (a shipped level's name or a path, `jaxchain.levels.load`) it runs that
  level instead: every world a copy with box masses drawn from `seed`, the player
  pushed along +x by `push` and jumping whenever it is grounded (a closed-loop
  `rollout` policy).

  Returns:
    The figures: timings, throughput, penetration and wall intrusion, whether every
    state is finite, and `status_messages`, `{message: number of worlds}` for every
    status bit set at the end (empty when all is well). For a level, the player's
    mean x travel and how many worlds end with a sensor triggered instead of the row
    figures.
  """
  chunk = min(chunk, steps)
  if steps % chunk:
    raise ValueError(f"--steps ({steps}) must be a multiple of --chunk ({chunk})")
  if level is not None:
    return _level_demo(levels.load(level), batch, steps, chunk, seed, depth, iterations,
                       friction, push, progress, converge)
  rng = np.random.default_rng(seed)
  layouts = [scenes.platformer(rng) for _ in range(batch)]
  first = layouts[0]
  worlds = stack([p.scene.world(friction=friction) for p in layouts])
  overrides = dict(iterations=iterations, converge=converge)
  if depth is not None:
    overrides["depth"] = depth
  config = Config.for_world(worlds, **overrides)
  n = worlds.num_bodies
  controls = np.zeros((batch, n, 2), np.float32)
  controls[:, first.player, 0] = push  # The player's input: a constant push to the right.
  controls = jnp.asarray(controls)

  run = jax.jit(jax.vmap(lambda w, u: rollout(w, config, chunk, u)[0]))
  print(f"jaxchain demo: {batch} worlds x {n} bodies, {steps} steps of {config.dt:.4f} s, "
        f"depth {config.depth}{' (converging)' if config.converge else ''}, iterations {config.iterations}, friction {friction:g}, "
        f"device {jax.devices()[0].device_kind}")
  t0 = time.perf_counter()
  compiled = run.lower(worlds, controls).compile()
  compile_s = time.perf_counter() - t0

  start_row = np.asarray(worlds.pos[:, first.row, 0])
  world, run_s = _run(lambda w: compiled(w, controls), worlds, steps, chunk, progress)
  messages, finite, penetration = _health(world)
  with np.errstate(invalid="ignore", over="ignore"):
    row_right = np.asarray(world.pos[:, first.row, 0] + world.half[:, first.row, 0])
    intrusion = float(np.max(np.maximum(row_right - first.wall_face, 0.0)))
    moved = np.asarray(world.pos[:, first.row, 0])[:, -1] - start_row[:, -1]
    at_wall = int(np.sum(first.wall_face - row_right[:, -1] < 1e-3))
  figures = dict(
      compile_s=compile_s, run_s=run_s, world_steps_per_s=batch * steps / run_s,
      body_steps_per_s=batch * steps * n / run_s, max_penetration=penetration,
      wall_intrusion=intrusion, row_moved_mean=float(np.mean(moved)), worlds_at_wall=at_wall,
      finite=finite, status_messages=messages)
  _print_timing(figures)
  print(f"row pushed            {figures['row_moved_mean']:8.3f} units on average; "
        f"{at_wall}/{batch} rows against the wall")
  print(f"row intrusion into wall {intrusion:10.3g}")
  _print_status(messages, finite, batch)
  return figures


def _run(call, world, steps: int, chunk: int, progress: bool):
  """`steps // chunk` calls of the compiled `call` from `world`, with a progress bar:
  the final world and the run time."""
  t0 = time.perf_counter()
  with tqdm(total=steps, unit="step", disable=not progress, file=sys.stderr) as bar:
    for _ in range(steps // chunk):
      world = call(world)
      jax.block_until_ready(world)
      bar.update(chunk)
  return world, time.perf_counter() - t0


def _health(world) -> tuple[dict[str, int], bool, float]:
  """Status messages, whether every state is finite, and the largest penetration."""
  codes = np.asarray(world.status)
  finite = bool(np.all(np.isfinite(np.asarray(world.pos))) and
                np.all(np.isfinite(np.asarray(world.vel))) and
                not np.any(codes & status.NON_FINITE))
  with np.errstate(invalid="ignore", over="ignore"):
    penetration = float(np.max(jax.vmap(metrics.max_penetration)(world)))
  return status_summary(world), finite, penetration


def _print_timing(figures: dict) -> None:
  print(f"compile time          {figures['compile_s']:8.2f} s")
  print(f"run time              {figures['run_s']:8.2f} s")
  print(f"world-steps/s         {figures['world_steps_per_s']:12.4g}")
  print(f"body-steps/s          {figures['body_steps_per_s']:12.4g}")
  print(f"final max penetration {figures['max_penetration']:12.3g}")


def _print_status(messages: dict[str, int], finite: bool, batch: int) -> None:
  if not messages:
    print("status: ok")
  for text, count in messages.items():
    bits = [name for bit, name in _BIT_NAMES.items() if status.MESSAGES[bit] == text]
    print(f"status {bits[0] if bits else '?'} in {count}/{batch} worlds: {text}")
  # "finite True" alone would read as "all is well": say it only when no bit is set.
  if not finite or not messages:
    print(f"all states finite     {finite}")


def _level_demo(level, batch, steps, chunk, seed, depth, iterations, friction, push,
                progress, converge) -> dict:
  """`demo` on a level: copies with box masses from `seed`, the player pushed and
  jumping when grounded."""
  player = level.player
  rng = np.random.default_rng(seed)
  movable = np.isfinite(level.mass) & (np.arange(len(level)) != player)
  worlds = stack([level.world(friction=friction, mass=np.where(
      movable, level.mass * rng.uniform(0.5, 2.0, len(level)), level.mass)) for _ in range(batch)])
  overrides = dict(iterations=iterations, converge=converge)
  if depth is not None:
    overrides["depth"] = depth
  config = Config.for_world(worlds, **overrides)
  n = worlds.num_bodies

  def policy(world, t):  # Push along +x; jump when standing on something.
    del t
    up = jnp.where(flags.grounded(world)[player], JUMP, 0.0)
    return jnp.zeros_like(world.pos).at[player].set(jnp.stack([jnp.asarray(push, up.dtype), up]))

  run = jax.jit(jax.vmap(lambda w: rollout(w, config, chunk, policy=policy)[0]))
  print(f"jaxchain demo --level {level.name}: {batch} worlds x {n} bodies, {steps} steps of "
        f"{config.dt:.4f} s, depth {config.depth}{' (converging)' if config.converge else ''}, "
        f"iterations {config.iterations}, friction {friction:g}, one-way "
        f"{'on' if config.one_way else 'off'}, sensors {'on' if config.sensors else 'off'}, "
        f"device {jax.devices()[0].device_kind}")
  t0 = time.perf_counter()
  compiled = run.lower(worlds).compile()
  compile_s = time.perf_counter() - t0
  world, run_s = _run(compiled, worlds, steps, chunk, progress)
  messages, finite, penetration = _health(world)
  travel = np.asarray(world.pos[:, player, 0] - worlds.pos[:, player, 0])
  triggered = int(np.sum(np.any(np.asarray(world.sensed), axis=-1)))
  figures = dict(
      compile_s=compile_s, run_s=run_s, world_steps_per_s=batch * steps / run_s,
      body_steps_per_s=batch * steps * n / run_s, max_penetration=penetration,
      player_moved_mean=float(np.mean(travel)), worlds_sensed=triggered, finite=finite,
      status_messages=messages)
  _print_timing(figures)
  print(f"player moved          {figures['player_moved_mean']:8.3f} units along x on average")
  print(f"sensors triggered     {triggered}/{batch} worlds at the end")
  _print_status(messages, finite, batch)
  return figures


def main(argv=None) -> int:
  parser = argparse.ArgumentParser(prog="jaxchain", description=__doc__)
  sub = parser.add_subparsers(dest="command", required=True)
  p = sub.add_parser("demo", help="simulate the built-in platformer scene in many worlds at once")
  p.add_argument("--batch", type=_positive_int, default=1024, help="worlds in parallel (default 1024)")
  p.add_argument("--steps", type=_positive_int, default=600, help="time steps of 1/60 s (default 600)")
  p.add_argument("--chunk", type=_positive_int, default=50,
                 help="steps per compiled call; must divide --steps if smaller (default 50)")
  p.add_argument("--seed", type=_nonnegative_int, default=0, help="seed for the box masses (default 0)")
  p.add_argument("--depth", type=_nonnegative_int, default=None,
                 help="chain depth K, 0 for pairwise Jacobi (default: from the scene)")
  p.add_argument("--iterations", type=_positive_int, default=1, help="resolution passes per step")
  p.add_argument("--friction", type=_nonnegative_float, default=0.3,
                 help="Coulomb friction of every body (default 0.3)")
  p.add_argument("--push", type=_finite_float, default=20.0,
                 help="player's push acceleration (default 20)")
  p.add_argument("--converge", action=argparse.BooleanOptionalAction, default=True,
                 help="forward-only hop loops that stop once every world has converged "
                      "(same answers; the demo takes no gradients; default on)")
  p.add_argument("--level", default=None, metavar="NAME|PATH",
                 help="run a level instead of the built-in scene: a shipped level "
                      f"({', '.join(levels.names())}) or a .txt/.xsb/.tmj/.json file; the "
                      "player is pushed by --push and jumps when grounded")
  p.add_argument("--no-progress", action="store_true", help="no progress bar")
  args = parser.parse_args(argv)
  if args.command == "demo":
    chunk = min(args.chunk, args.steps)
    if args.steps % chunk:
      p.error(f"--steps ({args.steps}) must be a multiple of --chunk ({chunk})")
    if args.level is not None:
      try:
        levels.load(args.level)
      except (ValueError, OSError) as e:
        p.error(f"--level: {e}")
    demo(args.batch, args.steps, args.chunk, args.seed, args.depth, args.iterations,
         args.friction, args.push, progress=not args.no_progress, converge=args.converge,
         level=args.level)
  return 0


if __name__ == "__main__":
  sys.exit(main())
