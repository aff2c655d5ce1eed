"""Throughput: body-steps/s and world-steps/s over bodies per world N and worlds B.

Scene: the demo platformer grown to N bodies (`scenes.platformer_level`: the room,
the player pushing right, a row of 4 boxes, the rest stacked in columns of 5 behind
the player), friction 0.3 on every body and `Config.for_world(batch)`, as in
`jaxchain demo`. Each setting times a jitted, vmapped rollout of a few steps (compile apart, median of
repeats). Settings whose candidate tables would pass the memory budget are skipped
and listed. Writes `results/throughput.md` and `results/throughput.png`.

    python benchmarks/throughput.py            # N 16..1024 x B 1..4096, about 5 minutes
    python benchmarks/throughput.py --quick    # B up to 1024
    python benchmarks/throughput.py --smoke --out /tmp/x   # N=16, B=2: runs, writes
"""

from __future__ import annotations

import argparse

import jax
import jax.numpy as jnp
import numpy as np
from tqdm import tqdm

import jaxchain as jc
from jaxchain import scenes
from _bench import Run, add_common_args, compile_and_time, loglog, out_dir, write_result

PUSH = 20.0  # The player's acceleration along +x, as `jaxchain demo --push`.
# Largest candidate table (worlds x bodies x row slots) a setting may hold: about
# 0.5 GB per float32 array, and a step keeps a handful of them alive.
MAX_PAIRS = 2**27
# Bodies moved per timed call: enough that dispatch is noise, few enough to stay quick.
BODY_STEPS_PER_CALL = 4e5


def setting(n: int, batch: int, repeats: int, max_steps: int = 100) -> dict:
  level = scenes.platformer_level(n)
  world = level.scene.world(friction=0.3)
  worlds = jax.tree.map(lambda x: jnp.broadcast_to(x, (batch,) + x.shape), world)
  cfg = jc.Config.for_world(world)
  row = cfg.grid.row_size if cfg.uses_grid(n) else n
  row_info = dict(n=n, batch=batch, broadphase=cfg.broadphase, depth=cfg.depth,
                  links=cfg.links, row=row)
  if batch * n * row > MAX_PAIRS:
    return dict(row_info, skipped=f"{batch} x {n} x {row} candidate slots > 2^27")
  steps = int(np.clip(BODY_STEPS_PER_CALL // (n * batch), 2, max_steps))
  controls = jnp.zeros((n, 2), world.pos.dtype).at[level.player, 0].set(PUSH)

  def run(w):
    final, _ = jc.rollout(w, cfg, steps, controls)
    return final.status

  code, sec, compile_s = compile_and_time(jax.vmap(run), worlds, repeats=repeats, budget_s=10.0)
  step_s = sec / steps
  return dict(row_info, steps=steps, compile_s=compile_s, step_s=step_s,
              world_steps=batch / step_s, body_steps=batch * n / step_s,
              status=int(np.bitwise_or.reduce(np.asarray(code).ravel())))


def main():
  parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
  parser.add_argument("--quick", action="store_true", help="B up to 1024, fewer repeats")
  parser.add_argument("--sizes", type=int, nargs="+", default=[16, 64, 256, 1024])
  parser.add_argument("--batches", type=int, nargs="+", default=None)
  args = add_common_args(parser).parse_args()
  batches = args.batches or ([1, 64, 1024] if args.quick else [1, 64, 1024, 4096])
  repeats = 3 if args.quick else 5
  if args.smoke:
    args.sizes, batches, repeats = [16], [2], 1
  run = Run.start()
  rows = []
  plan = [(n, b) for n in args.sizes for b in batches]
  with tqdm(plan, desc="throughput", unit="setting") as bar:
    for n, b in bar:
      bar.set_postfix(N=n, B=b)
      rows.append(setting(n, b, repeats, max_steps=2 if args.smoke else 100))
  write(rows, args, run)


def write(rows, args, run: Run) -> None:
  lines = [
      "# Throughput over bodies per world and batch size",
      "",
      "Scene: `scenes.platformer_level(N)`, the demo platformer grown to N bodies (player "
      f"accelerated at {PUSH} along +x into a row of 4 boxes, the rest stacked in columns of 5), "
      "friction 0.3, `Config.for_world(world)`. Timed: a jitted, vmapped rollout of `steps` "
      "steps (median of up to 5 calls, at least one after a warm-up call), compile apart.",
      "",
      "| N | worlds B | broadphase | depth | links | row M | steps | compile s | ms / step | "
      "world-steps/s | body-steps/s | status |",
      "|---|---|---|---|---|---|---|---|---|---|---|---|",
  ]
  for r in rows:
    head = (f"| {r['n']} | {r['batch']} | {r['broadphase']} | {r['depth']} | {r['links']} | "
            f"{r['row']} |")
    if "skipped" in r:
      lines.append(f"{head} - | - | - | - | - | skipped: {r['skipped']} |")
    else:
      lines.append(f"{head} {r['steps']} | {r['compile_s']:.2f} | {r['step_s'] * 1e3:.3f} | "
                   f"{r['world_steps']:.3g} | {r['body_steps']:.3g} | {r['status']} |")
  done = [r for r in rows if "skipped" not in r]
  if done:
    best = max(done, key=lambda r: r["body_steps"])
    lines += ["", f"Highest: {best['body_steps']:.3g} body-steps/s at N={best['n']}, "
              f"B={best['batch']}. Status 0 means no failure bit was raised (`jc.check`)."]
    for n in sorted({r["n"] for r in done}):
      one = [r for r in done if r["n"] == n]
      lines.append(f"- N={n}: batching gains {max(r['body_steps'] for r in one) / one[0]['body_steps']:.1f}x "
                   f"over B={one[0]['batch']}")
  out = out_dir(args)
  write_result(out, "throughput.md", lines, run)
  plot(done, out)


def plot(rows, out) -> None:
  series = {}
  for n in sorted({r["n"] for r in rows}):
    sel = [r for r in rows if r["n"] == n]
    series[f"N={n}"] = ([r["batch"] for r in sel], [r["body_steps"] for r in sel], "-o")
  loglog(out / "throughput.png", series, xlabel="worlds per batch B", ylabel="body-steps/s",
         title="jaxchain throughput, platformer scene (2-core CPU)", xbase=2)


if __name__ == "__main__":
  main()
