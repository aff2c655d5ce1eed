"""Sokoban replay: every published Microban solution through `jc.env.SokobanMoves`.

The 155 levels of David W. Skinner's Microban and their published solutions
(`tests/data/sokoban/`, see its README) are replayed in the physics: levels sorted by
body count and cut into batches (one env per batch, its slots sized by the batch);
each batch is one jitted `jc.env.make_replay` (a `jax.vmap` over its levels of a scan
of `env.step_env` over the solution's moves, padded with noops to the batch's longest:
`jc.env.sokoban_actions`).
Checked per level, exactly (float32 equality): the player ends on the cell a
plain-Python grid Sokoban puts it, every box ends on a goal, and the world is at
rest with no status bit set. Compile time is measured apart (ahead-of-time
`lower().compile()`), then one timed call. Writes `results/sokoban_replay.md`.

    python benchmarks/sokoban_replay.py            # all 155 levels, a few minutes on 2 cores
    python benchmarks/sokoban_replay.py --smoke --out /tmp/x   # 3 levels: runs, writes
"""

from __future__ import annotations

import argparse
import pathlib
import time

import jax
import jax.numpy as jnp
import numpy as np
from tqdm import tqdm

import jaxchain as jc
from jaxchain import levels
from _bench import Run, add_common_args, out_dir, write_result

DATA = pathlib.Path(__file__).resolve().parent.parent / "tests" / "data" / "sokoban"
STEP = {"l": (0, -1), "r": (0, 1), "d": (1, 0), "u": (-1, 0)}


def microban():
  """`[(number, Level, map rows, moves)]` for the 155 levels."""
  collection = levels.load_collection(DATA / "microban.xsb")
  maps, run = [], []
  for line in (DATA / "microban.xsb").read_text().split("\n") + [""]:
    if line.strip() and not line.startswith(";"):
      run.append(line)
    elif run:
      maps.append(run)
      run = []
  text = (DATA / "microban_solutions.txt").read_text()
  moves = [levels.parse_moves(l) for l in text.split("\n") if l.strip() and not l.startswith(";")]
  assert len(collection) == len(maps) == len(moves) == 155
  return [(k + 1, lv, rows, m) for k, (lv, rows, m) in enumerate(zip(collection, maps, moves))]


def grid_replay(rows, moves):
  """The player's final cell, the number of pushes, and whether every box ends on a
  goal, by the rules on the XSB grid (world centres, y up)."""
  height = len(rows)
  cells = {(r, c): ch for r, line in enumerate(rows) for c, ch in enumerate(line)}
  walls = {k for k, ch in cells.items() if ch == "#"}
  boxes = {k for k, ch in cells.items() if ch in "$*"}
  goals = {k for k, ch in cells.items() if ch in ".*+"}
  (player,) = [k for k, ch in cells.items() if ch in "@+"]
  pushes = 0
  for m in moves.lower():
    dr, dc = STEP[m]
    one, two = (player[0] + dr, player[1] + dc), (player[0] + 2 * dr, player[1] + 2 * dc)
    if one in walls or (one in boxes and (two in walls or two in boxes)):
      continue
    if one in boxes:
      boxes, pushes = (boxes - {one}) | {two}, pushes + 1
    player = one
  return (player[1] + 0.5, height - player[0] - 0.5), pushes, boxes == goals


def batch_run(batch):
  task = jc.env.Task(name="microban", levels=[lv for _, lv, _, _ in batch],
                     actions=jc.env.SokobanMoves(), reward=jc.env.push_reward,
                     terminate=jc.env.sokoban_terminate,
                     params=jc.env.PushBoxParams(jitter=0.0, max_steps=100_000))
  env, params = jc.env.make(task, dt=1 / 64)
  actions = jc.env.sokoban_actions([m for *_, m in batch])
  steps = actions.shape[1]
  replay = jc.env.make_replay(env, params)
  args = (jnp.arange(len(batch), dtype=jnp.int32), jnp.asarray(actions))
  t0 = time.perf_counter()
  compiled = jax.jit(replay).lower(*args).compile()
  compile_s = time.perf_counter() - t0
  t0 = time.perf_counter()
  state, _, _ = jax.block_until_ready(compiled(*args))
  run_s = time.perf_counter() - t0
  world = jax.device_get(state.world)
  box, goal = env.slots_of("box"), env.slots_of("goal")
  solved = exact = pushes = 0
  for k, (_, _, rows, m) in enumerate(batch):
    player, n_push, grid_solved = grid_replay(rows, m)
    pushes += n_push
    on = lambda idx: sorted(map(tuple, world.pos[k][idx][world.active[k][idx]].tolist()))
    exact += tuple(world.pos[k][0].tolist()) == player
    solved += grid_solved and on(box) == on(goal) and bool(
        np.all(world.vel[k] == 0)) and int(world.status[k]) == 0
  moves = sum(len(m) for *_, m in batch)
  return dict(levels=len(batch), first=min(n for n, *_ in batch), bodies=env.num_bodies,
              steps=steps, moves=moves, pushes=pushes, compile_s=compile_s, run_s=run_s,
              padded=len(batch) * steps, physics=len(batch) * steps * env.actions.repeat,
              solved=solved, exact=exact)


def main():
  parser = argparse.ArgumentParser(description=__doc__,
                                   formatter_class=argparse.RawDescriptionHelpFormatter)
  parser.add_argument("--batch", type=int, default=40, help="levels per batch (default 40)")
  args = add_common_args(parser).parse_args()
  data = microban()
  if args.smoke:
    data, args.batch = data[:3], 3
  ordered = sorted(data, key=lambda d: (d[1].num_bodies, d[0]))
  batches = [ordered[k:k + args.batch] for k in range(0, len(ordered), args.batch)]
  run = Run.start()
  rows = []
  for batch in tqdm(batches, desc="sokoban replay", unit="batch"):
    rows.append(batch_run(batch))
  write(rows, args, run)


def write(rows, args, run: Run) -> None:
  total = {k: sum(r[k] for r in rows) for k in ("levels", "moves", "pushes", "solved", "exact",
                                                 "padded", "physics")}
  run_s = sum(r["run_s"] for r in rows)
  lines = [
      "# Sokoban replay: published Microban solutions through SokobanMoves",
      "",
      "Each batch (levels sorted by body count) is one env (`jc.env.make(task, dt=1/64)`, "
      "`SokobanMoves()`: 5 physics steps per move) and one jitted `jc.env.make_replay` (a "
      "`vmap` over its levels of a scan of `env.step_env` over the moves), padded with noops "
      "to the batch's longest solution; compile apart, one timed call. Solved: every box on a "
      "goal, exactly (float32 equality), the world at rest, no status bit, and the grid replay "
      "solved too. Player exact: the player's final centre equals the grid replay's cell.",
      "",
      "| first level | levels | bodies | T (moves) | moves | pushes | compile s | run s | "
      "env-steps/s (padded) | solved | player exact |",
      "|---|---|---|---|---|---|---|---|---|---|---|",
  ]
  for r in rows:
    lines.append(f"| {r['first']} | {r['levels']} | {r['bodies']} | {r['steps']} | {r['moves']} | "
                 f"{r['pushes']} | {r['compile_s']:.1f} | {r['run_s']:.1f} | "
                 f"{r['padded'] / r['run_s']:.3g} | {r['solved']}/{r['levels']} | "
                 f"{r['exact']}/{r['levels']} |")
  lines += [
      "",
      f"- {total['solved']} of {total['levels']} levels solved, {total['exact']} with the player "
      f"exactly on its cell; {total['moves']} moves ({total['pushes']} pushes) replayed as "
      f"{total['padded']} padded env steps, {total['physics']} world-steps of physics, in "
      f"{run_s:.1f} s of runs.",
  ]
  write_result(out_dir(args), "sokoban_replay.md", lines, run)


if __name__ == "__main__":
  main()
