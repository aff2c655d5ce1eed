"""Grid against dense broadphase: time per step and per body over bodies per world.

Scene: `jaxchain.scenes.box_room`, boxes at constant density in a closed room
(long floor, ceiling and walls), gravity and friction on. Each setting times a
jitted, vmapped 10-step rollout (compile excluded, median of repeats) for one
world (B=1) and for a batch of worlds. Writes `results/scaling.md` and
`results/scaling.png`.

    python benchmarks/scaling.py            # full sweep, about 5 minutes on 2 cores
    python benchmarks/scaling.py --quick    # smaller sweep
    python benchmarks/scaling.py --smoke --out /tmp/x   # grid, N=16, B=2: runs, writes
"""

from __future__ import annotations

import argparse

import jax
import numpy as np
from tqdm import tqdm

import jaxchain as jc
from jaxchain import scenes
from _bench import Run, add_common_args, compile_and_time, loglog, out_dir, write_result

STEPS = 10


def time_setting(n: int, batch: int, kind: str, repeats: int) -> dict:
  rng = np.random.default_rng(n)
  worlds = jc.stack([scenes.box_room(rng, n).world(friction=0.3) for _ in range(batch)])
  # As a user gets it (link table sized from the scene), with the broadphase forced.
  cfg = jc.Config.for_world(worlds, depth=4, substeps=1, broadphase=kind)
  out, sec, compile_s = compile_and_time(jax.vmap(lambda w: jc.rollout(w, cfg, STEPS)[0]), worlds,
                                         repeats=repeats)
  step_s = sec / STEPS
  return dict(n=n, batch=batch, kind=kind, compile_s=compile_s, step_s=step_s,
              body_step_s=step_s / (n * batch), status=int(np.max(np.asarray(out.status))),
              row=cfg.grid.row_size if kind == "grid" else n, links=cfg.links)


def main():
  parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
  parser.add_argument("--quick", action="store_true", help="N up to 1024, fewer repeats")
  args = add_common_args(parser).parse_args()
  run = Run.start()
  sizes = [64, 128, 256, 512, 1024] if args.quick else [64, 128, 256, 512, 1024, 2048, 4096]
  repeats = 3 if args.quick else 5
  # (kind, batch, largest n): dense is O(n^2) in time and memory, so it stops earlier.
  plan = [("grid", 1, 4096), ("dense", 1, 2048), ("grid", 16, 4096), ("dense", 16, 1024)]
  if args.smoke:
    sizes, repeats, plan = [16], 1, [("grid", 2, 16)]  # The grid: dense runs everywhere else.
  settings = [(n, b, k) for k, b, top in plan for n in sizes if n <= top]
  rows = []
  for n, b, k in tqdm(settings, desc="scaling", unit="setting"):
    rows.append(time_setting(n, b, k, repeats))
  write(rows, out_dir(args), run)


def write(rows: list[dict], out, run: Run) -> None:
  lines = [
      "# Grid against dense: time per step over bodies per world",
      "",
      "Scene: `scenes.box_room` "
      "(constant density, long floor/ceiling/walls), gravity, friction 0.3, depth 4, 1 iteration, "
      "`Config.for_world` for the rest (the link table). "
      f"Median of repeats of a jitted, vmapped {STEPS}-step rollout, compile excluded.",
      "",
      "| broadphase | worlds B | bodies N | row size M | links | compile s | ms / step | ns / body-step | per-body vs N=64 | status |",
      "|---|---|---|---|---|---|---|---|---|---|",
  ]
  for r in rows:
    first = next(x for x in rows if x["kind"] == r["kind"] and x["batch"] == r["batch"])
    lines.append(
        f"| {r['kind']} | {r['batch']} | {r['n']} | {r['row']} | {r['links']} | {r['compile_s']:.2f} | "
        f"{r['step_s'] * 1e3:.3f} | {r['body_step_s'] * 1e9:.0f} | "
        f"{r['body_step_s'] / first['body_step_s']:.2f}x | {r['status']} |")
  lines += ["", "Crossover (grid faster than dense), per batch size:", ""]
  for b in sorted({r["batch"] for r in rows}):
    both = [(r["n"], r["step_s"], s["step_s"]) for r in rows for s in rows
            if r["batch"] == s["batch"] == b and r["n"] == s["n"] and r["kind"] == "grid"
            and s["kind"] == "dense"]
    faster = [n for n, g, d in both if g < d]
    lines.append(f"- B={b}: grid faster from N={min(faster)}" if faster
                 else f"- B={b}: dense faster at every N measured")
  write_result(out, "scaling.md", lines, run)
  plot(rows, out)


def plot(rows: list[dict], out) -> None:
  series = {}
  for kind, style in (("grid", "-o"), ("dense", "--s")):
    for b in sorted({r["batch"] for r in rows}):
      sel = [r for r in rows if r["kind"] == kind and r["batch"] == b]
      if sel:
        series[f"{kind}, B={b}"] = ([r["n"] for r in sel], [r["body_step_s"] * 1e9 for r in sel], style)
  loglog(out / "scaling.png", series, xlabel="bodies per world N", ylabel="ns per body-step",
         title="jaxchain: time per body-step (flat = O(N))", xbase=2)


if __name__ == "__main__":
  main()
