"""Command line: `jaxchain demo`."""

from __future__ import annotations

import argparse
import dataclasses
import math
import os
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax
from tqdm import tqdm

from jaxchain import compile_cache, drawing, flags, levels, metrics, scenes, status
from jaxchain.config import Config
from jaxchain.stepping import Trajectory, make_step
from jaxchain.world import stack

# `--level`: the player's jump, an upward acceleration for one step when grounded
# (about 7 units/s at 60 steps/s: 2.5 units high, enough for a ledge two cells up).
JUMP = 420.0

# `--gif`: the border between tiles, in pixels.
GIF_BORDER = 2


@dataclasses.dataclass(frozen=True)
class GifOptions:
  """What `jaxchain demo --gif PATH` records.

  Attributes:
    path: the GIF file to write.
    worlds: how many worlds (the first ones of the batch) to show, tiled in a grid
      of `ceil(sqrt(worlds))` columns, `GIF_BORDER` pixels apart.
    size: `(H, W)` of each tile in pixels.
    every: record every `every`-th step (from the first step, and the last).
    fps: frames per second of the GIF (at most 50).
  """

  path: str
  worlds: int = 4
  size: tuple[int, int] = (96, 160)
  every: int = 2
  fps: float = 30.0


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


def _size(text: str) -> tuple[int, int]:
  """`HxW` (e.g. `96x160`) as `(H, W)`, both positive."""
  parts = text.lower().split("x")
  try:
    h, w = (int(part) for part in parts)
  except ValueError:
    raise argparse.ArgumentTypeError(f"expected HxW such as 96x160, got {text!r}") from None
  if h < 1 or w < 1:
    raise argparse.ArgumentTypeError(f"both sides must be positive, got {text!r}")
  return h, w


def _gif_fps(text: str) -> float:
  value = _finite_float(text)
  if not 0 < value <= drawing.MAX_GIF_FPS:
    raise argparse.ArgumentTypeError(
        f"must be in (0, {drawing.MAX_GIF_FPS:g}], got {value:g} (browsers play GIF delays "
        "under 20 ms as 100 ms)")
  return value


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
         converge: bool = True, level: str | None = None, gif: GifOptions | None = None,
         cache: str | os.PathLike | None = None) -> dict:
  """Runs the platformer demo and returns the figures it prints.

  With `level` (a shipped level's name or a path, `jaxchain.levels.load`) it runs that
  level instead: every world a copy with box masses drawn from `seed`, the player
  pushed along +x by `push` and jumping whenever it is grounded (a closed-loop
  policy, `policy(world, t)` as `rollout` takes it).

  It compiles one program, `chunk` steps of the batch (`chunk_program`), and calls it
  until `steps` are done; when `chunk` does not divide `steps`, the last call masks
  the steps past the end (the same program: the mask is data).

  With `gif` it also writes the rollout of the first `gif.worlds` worlds to a GIF: the
  compiled chunk then also returns their trajectory (so the timed run includes
  writing it, a few percent), and rendering and writing happen after the timing.
  Without `gif` nothing extra is traced.

  With `cache` (a directory: `compile_cache.directory()` is the command line's) the
  program is kept there (`jaxchain.compile_cache`): a second run with the same scene
  sizes and settings loads it instead of tracing and compiling it again.

  Returns:
    The figures: timings, throughput, penetration and wall intrusion, whether every
    state is finite, and `status_messages`, `{message: number of worlds}` for every
    status bit set at the end (empty when all is well). For a level, the player's
    mean x travel and how many worlds end with a sensor triggered instead of the row
    figures. `compile_source`: "compiled", "cache" (loaded from `cache`) or "off" (no
    cache), and `first_compile_s`, the seconds of the first compile on this machine.
    With `gif`, also `gif_frames` (frames written) and `gif_bytes`. And, not
    printed, `final_world` (the batch after the last step) and `chunks` (the steps
    each call of the compiled program advances, `chunk_lengths(steps, chunk)`).

  Raises:
    ValueError: if `steps` or `chunk` is less than 1.
  """
  lengths = chunk_lengths(steps, chunk)
  if level is not None:
    return _level_demo(levels.load(level), batch, lengths, seed, depth, iterations,
                       friction, push, progress, converge, gif, cache)
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
  step_fn = jax.vmap(make_step(config))

  def advance(worlds, t, controls):  # One step of the batch; the push is the same every step.
    del t
    return step_fn(worlds, controls)

  print(f"jaxchain demo: {batch} worlds x {n} bodies, {steps} steps of {config.dt:.4f} s, "
        f"depth {config.depth}{' (converging)' if config.converge else ''}, iterations {config.iterations}, friction {friction:g}, "
        f"device {jax.devices()[0].device_kind}")
  keep = None if gif is None else min(gif.worlds, batch)
  program = chunk_program(advance, lengths[0], keep)
  # The key names what the program closes over: the config (the push is data, `controls`).
  compiled = _compile(program, cache, ("demo", config, lengths[0], keep), worlds, controls)
  compile_s = compiled.seconds

  start_row = np.asarray(worlds.pos[:, first.row, 0])
  clips = []
  world, run_s = _run(compiled.fn, worlds, lengths, progress, clips, controls)
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
      finite=finite, status_messages=messages, final_world=world, chunks=lengths,
      compile_source=compiled.source, first_compile_s=compiled.first_s)
  _print_timing(figures, compiled, cache)
  print(f"row pushed            {figures['row_moved_mean']:8.3f} units on average; "
        f"{at_wall}/{batch} rows against the wall")
  print(f"row intrusion into wall {intrusion:10.3g}")
  _print_status(messages, finite, batch)
  if gif is not None:
    figures.update(_write_gif(gif, worlds, clips, first.player))
  return figures


# What a `--gif` run records per step beside the positions (drawn red, and brighter).
_RECORD = ("crushed", "sensed")


def chunk_program(advance, chunk: int, keep: int | None = None):
  """The one program a demo run compiles: `chunk` steps of a batch, the steps past a
  bound masked.

  Args:
    advance: `advance(worlds, t, *args) -> worlds`, one step of the batch at step
      index `t` (an int32 scalar, counted from the start of the run).
    chunk: the steps of one call (static: the scan's length).
    keep: with a number, the call also returns the trajectory (positions,
      velocities and `_RECORD`) of the first `keep` worlds; None: nothing recorded.

  Returns:
    `jax.jit` of `run(worlds, start, stop, *args) -> (worlds, piece)`: steps
    `t = start, ..., start + chunk - 1`, where each step with `t >= stop` keeps the
    world as it is and computes nothing (a `lax.cond` on data, outside the batch), so
    one program runs every call of a run, the last, shorter one too. `piece` is a
    `Trajectory` of `[keep, chunk, ...]` arrays (the masked steps repeat the last
    state), or None.

  Examples:
    >>> run = chunk_program(lambda x, t: x + t, 4)  # "Worlds" that add up the step indices.
    >>> x, _ = run(jnp.zeros((), jnp.int32), np.int32(0), np.int32(4))  # Steps 0-3.
    >>> x, _ = run(x, np.int32(4), np.int32(6))  # Steps 4 and 5; 6 and 7 masked.
    >>> int(x)  # 0 + 1 + ... + 5, by one program.
    15
  """
  def demo_chunk(worlds, start, stop, *args):
    def body(worlds, k):
      t = start + k
      worlds = lax.cond(t < stop, lambda w: advance(w, t, *args), lambda w: w, worlds)
      if keep is None:
        return worlds, None
      return worlds, Trajectory(**{name: getattr(worlds, name)[:keep]
                                   for name in ("pos", "vel", *_RECORD)})
    worlds, traj = lax.scan(body, worlds, jnp.arange(chunk, dtype=jnp.int32))
    return worlds, jax.tree.map(lambda x: jnp.swapaxes(x, 0, 1), traj)  # Worlds first.
  return jax.jit(demo_chunk)


def _write_gif(gif: GifOptions, worlds, clips: list, player: int) -> dict:
  """Renders the recorded trajectory pieces (`clips`, each `[k, chunk, ...]`) of the
  first worlds, tiles them and writes the GIF: `{"gif_frames", "gif_bytes"}`."""
  k = clips[0].pos.shape[0]
  start = jax.tree.map(lambda x: np.asarray(x)[:k], worlds)  # On the host: no op to compile.
  # Frame 0 is the start; then every `gif.every`-th step, and the last.
  first = dataclasses.replace(clips[0], **{name: getattr(start, name)[:, None] for name in
                                          ("pos", "vel", *_RECORD)})
  traj = jax.tree.map(lambda *xs: np.concatenate(xs, axis=1), first, *clips)
  steps = traj.pos.shape[1]
  keep = np.unique(np.r_[np.arange(0, steps, gif.every), steps - 1])
  traj = jax.tree.map(lambda x: x[:, keep], traj)
  # One camera for every tile and frame: the extent of all of them.
  bounds = drawing.bounds_of(start, jnp.asarray(traj.pos))
  frames = np.asarray(drawing.render_trajectory(start, traj, gif.size, bounds, player=player))
  grid = tile(frames, GIF_BORDER)
  drawing.save_gif(grid, gif.path, fps=gif.fps)
  size = os.path.getsize(gif.path)
  print(f"gif                   {gif.path}: {k} world{'s' * (k > 1)}, {grid.shape[0]} frames "
        f"of {grid.shape[2]}x{grid.shape[1]} px at {gif.fps:g} fps, {size / 1024:.0f} KiB")
  return dict(gif_frames=grid.shape[0], gif_bytes=size)


def tile(frames: np.ndarray, border: int = GIF_BORDER) -> np.ndarray:
  """`[k, t, h, w, 3]` clips side by side: `[t, H, W, 3]`, a grid of `ceil(sqrt(k))`
  columns with `border` pixels of black between tiles (empty cells black too)."""
  k, t, h, w, _ = frames.shape
  cols = math.ceil(math.sqrt(k))
  rows = math.ceil(k / cols)
  out = np.zeros((t, rows * (h + border) - border, cols * (w + border) - border, 3), np.uint8)
  for i in range(k):
    r, c = divmod(i, cols)
    out[:, r * (h + border):r * (h + border) + h, c * (w + border):c * (w + border) + w] = frames[i]
  return out


def chunk_lengths(steps: int, chunk: int) -> list[int]:
  """The steps each call advances, for a run of `steps` steps in chunks of `chunk`.

  `steps // chunk` calls of `chunk` steps, then one of the remainder if `chunk` does not
  divide `steps`: the same program (`chunk_program`), with the steps past the end
  masked. A chunk longer than the run is the run. Chunked or not, the answers are those
  of one rollout of `steps` steps (`tests/test_cli.py` checks it).

  Examples:
    >>> chunk_lengths(600, 50) == [50] * 12
    True
    >>> chunk_lengths(60, 50), chunk_lengths(7, 50)
    ([50, 10], [7])

  Raises:
    ValueError: if `steps` or `chunk` is less than 1.
  """
  if steps < 1 or chunk < 1:
    raise ValueError(f"steps and chunk must be at least 1, got steps={steps}, chunk={chunk}")
  chunk = min(chunk, steps)
  return [chunk] * (steps // chunk) + ([steps % chunk] if steps % chunk else [])


def _compile(program, cache, key, worlds, *args) -> compile_cache.Compiled:
  """`program` (from `chunk_program`) compiled ahead of time for `worlds` and `args`, the
  one compile of a run, through the cache in `cache` (None: none); `key` names every
  constant the program closes over (`compile_cache.compile`)."""
  bound = np.int32(0)  # `start` and `stop` are int32 scalars: data, not part of the program.
  return compile_cache.compile(program, (worlds, bound, bound, *args), key, cache)


def _run(compiled, world, lengths: list[int], progress: bool, clips: list, *args):
  """`compiled` once per chunk length, from `world`, with a progress bar: the final
  world and the run time. Appends each call's recorded piece, cut to the steps it
  ran, to `clips` (when it records)."""
  t0 = time.perf_counter()
  start = 0
  with tqdm(total=sum(lengths), unit="step", disable=not progress, file=sys.stderr) as bar:
    for length in lengths:
      world, piece = compiled(world, np.int32(start), np.int32(start + length), *args)
      jax.block_until_ready(world)
      if piece is not None:
        clips.append(jax.tree.map(lambda x, n=length: x[:, :n], piece))
      start += length
      bar.update(length)
  return world, time.perf_counter() - t0


# One compiled function, not op-by-op dispatch (each op compiles on its own: seconds).
_max_penetration = jax.jit(jax.vmap(metrics.max_penetration))


def _health(world) -> tuple[dict[str, int], bool, float]:
  """Status messages, whether every state is finite, and the largest penetration."""
  codes = np.asarray(world.status)
  finite = bool(np.all(np.isfinite(np.asarray(world.pos))) and
                np.all(np.isfinite(np.asarray(world.vel))) and
                not np.any(codes & status.NON_FINITE))
  with np.errstate(invalid="ignore", over="ignore"):
    penetration = float(np.max(_max_penetration(world)))
  return status_summary(world), finite, penetration


def _print_timing(figures: dict, compiled: compile_cache.Compiled, cache) -> None:
  chunks = figures["chunks"]
  calls = f"{len(chunks)} call{'s' * (len(chunks) > 1)} of {chunks[0]} steps" + (
      f", the last masked to {chunks[-1]}" if chunks[-1] != chunks[0] else "")
  print(f"compile time          {figures['compile_s']:8.2f} s (one program: {calls})")
  if compiled.source == "cache":
    print(f"compile cache         loaded from {cache}; the first compile on this machine took "
          f"{compiled.first_s:.2f} s")
  elif compiled.source == "compiled":
    print(f"compile cache         saved to {cache}: the next run loads it (--no-cache: off)")
  else:
    print("compile cache         off")
  if compiled.note:
    print(f"compile cache note    {compiled.note}")
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


def _level_demo(level, batch, lengths, seed, depth, iterations, friction, push,
                progress, converge, gif=None, cache=None) -> dict:
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
  steps = sum(lengths)

  def policy(world, t):  # Push along +x; jump when standing on something.
    del t
    up = jnp.where(flags.grounded(world)[player], JUMP, 0.0)
    return jnp.zeros_like(world.pos).at[player].set(jnp.stack([jnp.asarray(push, up.dtype), up]))

  step_fn = jax.vmap(make_step(config))

  def advance(worlds, t):  # One step of the batch, the policy's push and jump in it.
    return step_fn(worlds, jax.vmap(policy, in_axes=(0, None))(worlds, t))

  print(f"jaxchain demo --level {level.name}: {batch} worlds x {n} bodies, {steps} steps of "
        f"{config.dt:.4f} s, depth {config.depth}{' (converging)' if config.converge else ''}, "
        f"iterations {config.iterations}, friction {friction:g}, one-way "
        f"{'on' if config.one_way else 'off'}, sensors {'on' if config.sensors else 'off'}, "
        f"device {jax.devices()[0].device_kind}")
  keep = None if gif is None else min(gif.worlds, batch)
  program = chunk_program(advance, lengths[0], keep)
  # The policy closes over the player's index, the push and the jump: all in the key.
  compiled = _compile(program, cache, ("level", config, player, float(push), JUMP, lengths[0],
                                       keep), worlds)
  compile_s = compiled.seconds
  clips = []
  world, run_s = _run(compiled.fn, worlds, lengths, progress, clips)
  messages, finite, penetration = _health(world)
  travel = np.asarray(world.pos[:, player, 0] - worlds.pos[:, player, 0])
  triggered = int(np.sum(np.any(np.asarray(world.sensed), axis=-1)))
  figures = dict(
      compile_s=compile_s, run_s=run_s, world_steps_per_s=batch * steps / run_s,
      body_steps_per_s=batch * steps * n / run_s, max_penetration=penetration,
      player_moved_mean=float(np.mean(travel)), worlds_sensed=triggered, finite=finite,
      status_messages=messages, final_world=world, chunks=lengths,
      compile_source=compiled.source, first_compile_s=compiled.first_s)
  _print_timing(figures, compiled, cache)
  print(f"player moved          {figures['player_moved_mean']:8.3f} units along x on average")
  print(f"sensors triggered     {triggered}/{batch} worlds at the end")
  _print_status(messages, finite, batch)
  if gif is not None:
    figures.update(_write_gif(gif, worlds, clips, player))
  return figures


def build_parser() -> tuple[argparse.ArgumentParser, argparse.ArgumentParser]:
  """The `jaxchain` parser and its `demo` subparser; `--help` states every default."""
  parser = argparse.ArgumentParser(prog="jaxchain", description=__doc__)
  sub = parser.add_subparsers(dest="command", required=True)
  p = sub.add_parser("demo", help="simulate the built-in platformer scene in many worlds at once")
  p.add_argument("--batch", type=_positive_int, default=1024,
                 help="worlds in parallel (default: 1024)")
  p.add_argument("--steps", type=_positive_int, default=600,
                 help="time steps of 1/60 s (default: 600)")
  p.add_argument("--chunk", type=_positive_int, default=50,
                 help="steps per call of the one compiled program (default: 50); if it does "
                      "not divide --steps, the last call masks the steps past the end")
  p.add_argument("--seed", type=_nonnegative_int, default=0,
                 help="seed for the box masses (default: 0)")
  p.add_argument("--depth", type=_nonnegative_int, default=None,
                 help="chain depth K, 0 for pairwise Jacobi (default: from the scene)")
  p.add_argument("--iterations", type=_positive_int, default=1,
                 help="resolution passes per step (default: 1)")
  p.add_argument("--friction", type=_nonnegative_float, default=0.3,
                 help="Coulomb friction of every body (default: 0.3)")
  p.add_argument("--push", type=_finite_float, default=20.0,
                 help="player's push acceleration (default: 20)")
  p.add_argument("--converge", action=argparse.BooleanOptionalAction, default=True,
                 help="forward-only hop loops that stop once every world has converged "
                      "(same answers; the demo takes no gradients) (default: on)")
  p.add_argument("--level", default=None, metavar="NAME|PATH",
                 help="run a level instead of the built-in scene: a shipped level "
                      f"({', '.join(levels.names())}) or a .txt/.xsb/.tmj/.json/.tmx file; the "
                      "player is pushed by --push and jumps when grounded (default: none, "
                      "the built-in scene)")
  p.add_argument("--gif", default=None, metavar="PATH",
                 help="also write the rollout of the first --gif-worlds worlds to an animated "
                      "GIF (tiled in a grid; works with --level) (default: none, no GIF)")
  p.add_argument("--gif-worlds", type=_positive_int, default=4,
                 help="worlds in the GIF, the first of the batch (default: 4)")
  p.add_argument("--gif-size", type=_size, default=(96, 160), metavar="HxW",
                 help="pixels of each world's tile (default: 96x160)")
  p.add_argument("--gif-every", type=_positive_int, default=2,
                 help="one frame every this many steps (default: 2, 30 frames per simulated s)")
  p.add_argument("--gif-fps", type=_gif_fps, default=30.0,
                 help="frames per second of the GIF, at most 50 (default: 30, real time "
                      "with --gif-every 2)")
  p.add_argument("--no-progress", action="store_true",
                 help="no progress bar (default: off, a progress bar on stderr)")
  p.add_argument("--no-cache", action="store_true",
                 help="trace and compile the program again instead of loading it from the cache "
                      "directory ($JAXCHAIN_CACHE_DIR, else ~/.cache/jaxchain; JAXCHAIN_CACHE=off "
                      "also turns it off) (default: off, the cache is used)")
  return parser, p


def main(argv=None) -> int:
  parser, p = build_parser()
  args = parser.parse_args(argv)
  if args.command == "demo":
    if args.level is not None:
      try:
        levels.load(args.level)
      except (ValueError, OSError) as e:
        p.error(f"--level: {e}")
    gif = None if args.gif is None else GifOptions(
        args.gif, worlds=args.gif_worlds, size=args.gif_size, every=args.gif_every,
        fps=args.gif_fps)
    if gif is not None and not os.path.isdir(os.path.dirname(os.path.abspath(gif.path))):
      p.error(f"--gif: no such directory: {os.path.dirname(gif.path)!r}")
    cache = None if args.no_cache else compile_cache.directory()
    with compile_cache.persistent(cache):
      demo(args.batch, args.steps, args.chunk, args.seed, args.depth, args.iterations,
           args.friction, args.push, progress=not args.no_progress, converge=args.converge,
           level=args.level, gif=gif, cache=cache)
  return 0


if __name__ == "__main__":
  sys.exit(main())
