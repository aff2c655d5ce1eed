"""Neighbour tables (`Config.neighbors`) against dense pairs and the grid, in one run.

Rows, all compile excluded, medians of rounds that alternate the settings (so drift of
a shared machine hits them alike):

- room of 64 (`jaxchain.scenes.lattice_room(64)`, 68 bodies, friction 0.5, settled 120
  steps, `Config.for_world`): 30-step rollouts of B worlds, jitted and vmapped, with
  the neighbour table `for_world` picks and with `neighbors=None` (dense pairs in every
  pass: the same config otherwise). Body-steps/s and the ratio.
- the pair stages' share of that step: one jitted, vmapped substep's pair work (the
  neighbour table's build, then contacts at the predicted and start positions and the
  link table, as a pass runs them) over the full step, each timed alone.
- the demo scene (14 bodies): `for_world` (which leaves the table out at 14 bodies)
  beside forced tables of 8 and 12.
- the grid: lattice rooms of N = 64 and 4096 (B = 256 and 4), 10-step rollouts, ns
  per body-step, with `for_world` (grid rows compacted to the neighbour table at 4096)
  and with `neighbors=None` (the grid rows in every pass).
- with `--against REV`: the room rollout of commit REV (exported with `git archive`,
  run in a child interpreter with only that tree on the path), alternating with this
  tree's.

Writes `neighbors.md` into `--out` (default `benchmarks/results`).

    python benchmarks/neighbors.py                      # about 6 minutes on 2 quiet cores
    python benchmarks/neighbors.py --against f55f53b
    python benchmarks/neighbors.py --smoke --out /tmp/x # tiny sizes: runs, writes the table
"""

from __future__ import annotations

import argparse
import os
import pathlib
import statistics
import subprocess
import sys
import tempfile

import jax
import jax.numpy as jnp

import jaxchain as jc
from jaxchain import broadphase, core, scenes
import _bench
from _bench import demo_world, room_world


def rollout_fn(cfg: jc.Config, steps: int):
  return lambda w: jc.rollout(w, cfg, steps)[0].pos  # A batch: the core, batch minor.


def pair_fn(cfg: jc.Config):
  """One substep's pair work, as `core.step.substep` and a pass run it, on a batch: the
  table (if any) at the predicted positions, the candidates, contacts at predicted and
  start, the link table."""
  def fn(w):
    state, bodies = core.from_world(w)
    predicted = state.pos + state.vel * (cfg.dt / cfg.substeps)
    table = core.pairs.build(predicted, bodies, cfg, state.pos)
    cand, code = core.pairs.candidates(predicted, bodies, cfg, table)
    c = core.contacts.contacts(predicted, bodies.half, cand, cfg.skin, start=state.pos)
    front, overflow = core.contacts.link_table(c, cand, cfg.links, rows=bodies.movable)
    return jnp.sum(front.overlap), jnp.sum(front.mask), code | overflow
  return fn


def step_fn(cfg: jc.Config):
  return lambda w: jc.step(w, cfg).pos


def timed(fns: dict, args: dict, rounds: int) -> dict:
  """Median seconds of each compiled `fns[k](args[k])`, rounds alternating the keys."""
  compiled, done = {}, {}  # `done`: one compile per function object and argument.
  for k, fn in fns.items():
    key = (id(fn), id(args[k]))
    if key not in done:
      done[key] = jax.jit(fn).lower(args[k]).compile()
    compiled[k] = done[key]
    jax.block_until_ready(compiled[k](args[k]))
  measured = _bench.rounds({k: _bench.wall(compiled[k], args[k]) for k in fns}, rounds)
  return {k: measured.median(k) for k in fns}


CHILD = """
import sys, time, statistics, jax, numpy as np, jaxchain as jc
from jaxchain import scenes
b, steps, settle, rounds = (int(x) for x in sys.argv[1:5])
s = scenes.lattice_room(64, 0)
w = jc.World.create(s.pos, s.half, s.mass, friction=0.5)
cfg = jc.Config.for_world(w)
if settle:
  w, _ = jc.rollout(w, cfg, settle)
ws = jc.stack([w] * b)
f = jax.jit(jax.vmap(lambda w: jc.rollout(w, cfg, steps)[0].pos)).lower(ws).compile()
jax.block_until_ready(f(ws))
for _ in range(rounds):
  t0 = time.perf_counter(); jax.block_until_ready(f(ws)); print(time.perf_counter() - t0, flush=True)
"""


def against(rev: str, b: int, steps: int, settle: int, rounds: int) -> list[float]:
  """Seconds per room rollout of commit `rev`, from a child interpreter."""
  with tempfile.TemporaryDirectory() as tmp:
    env = dict(os.environ, PYTHONPATH=str(_bench.export_src(rev, pathlib.Path(tmp))))
    out = subprocess.run([sys.executable, "-c", CHILD, str(b), str(steps), str(settle),
                          str(rounds)], env=env, check=True, capture_output=True, text=True,
                         cwd=tmp).stdout
  return [float(x) for x in out.split()]


def main():
  parser = argparse.ArgumentParser(description=__doc__,
                                   formatter_class=argparse.RawDescriptionHelpFormatter)
  _bench.add_common_args(parser)
  parser.add_argument("--rounds", type=int, default=5)
  parser.add_argument("--against", default=None, metavar="REV",
                      help="also time the room rollout of this commit (git archive)")
  args = parser.parse_args()
  smoke = args.smoke
  rounds = 1 if smoke else args.rounds
  settle = 0 if smoke else 120
  steps = 1 if smoke else 30
  batches = (2,) if smoke else (256, 1024)
  run = _bench.Run.start()
  lines = ["# Neighbour tables against dense pairs and the grid", "",
           f"Medians of {rounds} rounds alternating the settings, compile excluded."]

  # Room of 64: rollouts.
  world, cfg = room_world(16 if smoke else 64, settle)
  if cfg.neighbors is None:  # The smoke room is small: force a table to run its path.
    cfg = cfg.replace(neighbors=8, margin=0.25)
  dense = cfg.replace(neighbors=None, margin=0.0)
  n = world.num_bodies
  lines += ["", f"## Room of {n - 4} ({n} bodies), {steps}-step rollouts", "",
            f"`for_world`: neighbors {cfg.neighbors}, margin {cfg.margin:.3g}, links {cfg.links}, "
            f"depth {cfg.depth}, {cfg.broadphase}, substeps {cfg.substeps}.", "",
            "| B | dense pairs, body-steps/s | neighbour table, body-steps/s | speedup |"
            + (f" {args.against}, body-steps/s | speedup over {args.against} |" if args.against else ""),
            "|---|---|---|---|" + ("---|---|" if args.against else "")]
  for b in batches:
    ws = jc.stack([world] * b)
    t = timed({"dense": rollout_fn(dense, steps), "table": rollout_fn(cfg, steps)},
              {"dense": ws, "table": ws}, rounds)
    rate = {k: b * n * steps / v for k, v in t.items()}
    row = f"| {b} | {rate['dense']:.3g} | {rate['table']:.3g} | {t['dense'] / t['table']:.2f}x |"
    if args.against:
      base = statistics.median(against(args.against, b, steps, settle, rounds))
      row += f" {b * n * steps / base:.3g} | {base / t['table']:.2f}x |"
    lines.append(row)

  # Pair-stage share.
  b = batches[0]
  ws = jc.stack([world] * b)
  fns = {"pair dense": pair_fn(dense), "step dense": step_fn(dense),
         "pair table": pair_fn(cfg), "step table": step_fn(cfg)}
  if smoke:  # The table's two functions run the path; the dense ones are the same code.
    fns = {k: fns[k.replace("dense", "table")] for k in fns}
  t = timed(fns, {k: ws for k in fns}, 1 if smoke else 9)
  per = {k: v * 1e9 / (b * n) for k, v in t.items()}
  lines += ["", f"## Pair stages' share of a room-of-{n - 4} step (B = {b})", "",
            "Pair stages: the neighbour table's build (none for dense), contacts at the predicted "
            "and the start positions, the link table; each function timed alone.", "",
            "| candidates | pair stages, ns/body | step, ns/body | share |", "|---|---|---|---|"]
  for k, name in (("dense", "dense pairs (m = n)"), ("table", f"neighbour table (m = {cfg.neighbors})")):
    lines.append(f"| {name} | {per['pair ' + k]:.0f} | {per['step ' + k]:.0f} | "
                 f"{per['pair ' + k] / per['step ' + k]:.0%} |")

  # Demo scene.
  world, cfg = demo_world(0 if smoke else 60)
  b = batches[-1]
  ws = jc.stack([world] * b)
  n = world.num_bodies
  settings = {"for_world": cfg}
  settings.update({f"neighbors={k}": cfg.replace(neighbors=k, margin=0.25)
                   for k in (() if smoke else (8, 12))})  # Smoke: the for_world row runs the path.
  t = timed({k: rollout_fn(c, steps) for k, c in settings.items()}, {k: ws for k in settings},
            rounds)
  lines += ["", f"## Demo scene ({n} bodies), B = {b}, {steps}-step rollouts", "",
            f"`for_world` picks neighbors {cfg.neighbors} (a table of 12 at 14 bodies saves nothing).",
            "", "| config | world-steps/s | against for_world |", "|---|---|---|"]
  for k in settings:
    lines.append(f"| {k} | {b * steps / t[k]:.3g} | {t['for_world'] / t[k]:.2f}x |")

  # Grid at N = 4096 against N = 64.
  sizes = ((256, 2),) if smoke else ((64, 256), (4096, 4))  # Smoke: B = 2 (one world is unrolled)
  gsteps = 1 if smoke else 10
  lines += ["", f"## Per body-step against N, {gsteps}-step rollouts", "",
            "| N | B | config | ns per body-step |", "|---|---|---|---|"]
  for size, b in sizes:
    s = scenes.lattice_room(size, 0)
    world = jc.World.create(s.pos, s.half, s.mass, friction=0.5)
    cfg = jc.Config.for_world(world)
    ws = jc.stack([world] * b)
    n = world.num_bodies
    settings = {"for_world": cfg, "neighbors=None": cfg.replace(neighbors=None, margin=0.0)}
    if smoke:  # for_world's row runs the path (a grid with a table); one program.
      settings = {"for_world": cfg}
    if cfg.uses_grid(n) and "neighbors=None" in settings:
      settings["neighbors=None"] = settings["neighbors=None"].replace(
          grid=broadphase.allocate(world, cfg.skin))
    t = timed({k: rollout_fn(c, gsteps) for k, c in settings.items()}, {k: ws for k in settings},
              rounds)
    for k, c in settings.items():
      what = (f"{'grid' if c.uses_grid(n) else 'dense'}, neighbors {c.neighbors}"
              + (f", row {c.grid.row_size}" if c.uses_grid(n) else ""))
      lines.append(f"| {n} | {b} | {k}: {what} | {t[k] * 1e9 / (b * n * gsteps):.0f} |")

  _bench.write_result(_bench.out_dir(args), "neighbors.md", lines, run)


if __name__ == "__main__":
  main()
