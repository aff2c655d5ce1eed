"""Error against run time: the project's central measurement.

For each scene family, one `jc.step` (zero gravity and velocity, so the step is pure
overlap resolution and every setting solves the same problem) is timed batched over
B worlds under jit + vmap (compile excluded, median of repeats) and its result is
scored:
  - max and mean residual penetration;
  - distance to the reference resolver's answer (chains, trees and stacks, where the
    reference is order-independent);
  - drift of the movable centre of mass (meaningful without immovable bodies);
  - movement of immovable bodies (must be exactly 0).
Settings: chain depth K in (0, 1, 2, 4, 8, 16, 32, 64) x iterations in (1, 2, 4, 8,
16, 32) at 1 substep (skipping (K + 1) * iterations > 300), and substeps (1, 2, 4) at
K=8, each with the link table `Config.for_world` sizes for the scene. K=0 is plain
pairwise Jacobi (no chain propagation). The seed's old sequential pairwise system (NumPy, one world
at a time, 1 to 32 sweeps) is the order-dependent baseline, timed per world.

Writes `results/error_vs_time.md` (a table per scene family),
`results/error_vs_time.png` (log-log error against time per world-step, one line per
method, Pareto front marked) and `results/error_vs_time.json` (the rows, and the
header the table is redrawn with by `--replot`); `--quick` writes
`error_vs_time_quick.*` instead, beside the full sweep's.

    python benchmarks/error_vs_time.py           # about 30 minutes on 2 cores
    python benchmarks/error_vs_time.py --quick   # fewer scenes and settings
    python benchmarks/error_vs_time.py --smoke --out /tmp/x   # 1 scene, 1 setting: runs, writes
"""

from __future__ import annotations

import argparse
import json
import time

import jax
import numpy as np
from tqdm import tqdm

import jaxchain as jc
from jaxchain import metrics, reference, scenes
from _bench import Run, add_common_args, compile_and_time, median_time, out_dir, write_result

DEPTHS = (0, 1, 2, 4, 8, 16, 32, 64)
ITERATIONS = (1, 2, 4, 8, 16, 32)
SUBSTEPS = (1, 2, 4)
INF = np.inf


def pyramid(rows: int, overlap: float = 0.05) -> scenes.Scene:
  """Rows of unit boxes on a floor, each row half a box in and sunk `overlap` into
  the row below (a brick pyramid: every box rests on two)."""
  pos, half, mass = [[0.0, -0.5]], [[rows + 2.0, 0.5]], [INF]
  y = 0.5 - overlap
  for r in range(rows):
    for k in range(rows - r):
      pos.append([k - (rows - r - 1) / 2, y])
      half.append([0.5, 0.5])
      mass.append(1.0)
    y += 1.0 - overlap
  return scenes.Scene(np.asarray(pos), np.asarray(half), np.asarray(mass))


def packed_room(rng, n: int) -> scenes.Scene:
  """A closed room with `n` unit boxes dropped in at random, overlapping heavily."""
  side = float(np.ceil(np.sqrt(n / 0.6)))
  pos = np.r_[[[side / 2, -0.5], [side / 2, side + 0.5], [-0.5, side / 2], [side + 0.5, side / 2]],
              rng.uniform(0.5, side - 0.5, (n, 2))]
  half = np.r_[[[side / 2 + 1, 0.5]] * 2, [[0.5, side / 2]] * 2, np.full((n, 2), 0.45)]
  return scenes.Scene(pos, half, np.r_[np.full(4, INF), rng.uniform(0.5, 2, n)])


def loose_pile(rng, n: int) -> scenes.Scene:
  """Random boxes of mixed sizes over a floor, some overlapping."""
  side = float(np.sqrt(n) * 1.2)
  pos = np.r_[[[side / 2, -0.5]], rng.uniform([0, 0.2], [side, side], (n, 2))]
  half = np.r_[[[side / 2 + 1, 0.5]], rng.uniform(0.15, 0.5, (n, 2))]
  return scenes.Scene(pos, half, np.r_[INF, rng.uniform(0.5, 2, n)])


def families(quick: bool, smoke: bool = False) -> dict[str, tuple[scenes.Scene, bool]]:
  """name -> (scene, reference defined)."""
  rng = np.random.default_rng(0)
  masses = lambda n: rng.uniform(0.5, 2.0, n)
  if smoke:  # One small scene with a reference.
    return {"chain L=4 wall": (scenes.push_chain(4, 0.3, True, masses(5), rng.uniform(0, .1, 3)), True)}
  out = {}
  for L in ((4, 16) if quick else (4, 16, 64)):
    out[f"chain L={L} wall"] = (scenes.push_chain(L, 0.3, True, masses(L + 1), rng.uniform(0, .1, L - 1)), True)
    out[f"chain L={L} free"] = (scenes.push_chain(L, 0.3, False, masses(L + 1), rng.uniform(0, .1, L - 1)), True)
  stacks = ((5, 100), (20, 1e4)) if quick else [(h, r) for h in (5, 20, 50) for r in (1, 100, 1e4)]
  for H, ratio in stacks:
    light_to_heavy = np.geomspace(1.0, ratio, H) if ratio > 1 else np.ones(H)  # Heavy on light.
    out[f"stack H={H} ratio={ratio:g}"] = (scenes.stack(H, 0.05, light_to_heavy), True)
  out["pyramid 6 rows"] = (pyramid(6), False)
  out["packed room 30"] = (packed_room(rng, 30), False)
  if not quick:
    out["loose pile 40"] = (loose_pile(rng, 40), False)
  return out


def settings(quick: bool, smoke: bool = False):
  if smoke:
    return [(2, 1, 1)]
  depths = (0, 1, 4, 16) if quick else DEPTHS
  iterations = (1, 4, 16) if quick else ITERATIONS
  # Skip settings that do more hop work than any scene here can use: (K + 1) * iterations
  # above 300 (e.g. K=64 with 32 passes) only costs time.
  grid = [(k, it, 1) for k in depths for it in iterations if (k + 1) * it <= 300]
  return grid + [(8, 1, s) for s in SUBSTEPS if s > 1]


def score(scene, pos, want, start) -> dict:
  """Errors of resolved positions `pos` (host, float64) for one world; `start` is the
  input exactly as the method saw it (float32 for JAX), so rounding is not movement."""
  world = jc.World.create(pos, scene.half, scene.mass)
  fixed = np.isinf(scene.mass)
  free = ~fixed
  m = scene.mass[free]
  com = lambda p: m @ p[free] / m.sum()
  return dict(
      max_pen=float(metrics.max_penetration(world)),
      mean_pen=float(metrics.mean_penetration(world)),
      ref_dist=float(np.max(np.abs(pos - want))) if want is not None else np.nan,
      com_drift=float(np.linalg.norm(com(pos) - com(scene.pos))),
      fixed_moved=float(np.max(np.abs(pos[fixed] - start[fixed]), initial=0.0)))


def time_jax(world_batch, cfg, repeats) -> tuple[float, np.ndarray]:
  out, sec, _ = compile_and_time(jax.vmap(lambda w: jc.step(w, cfg)), world_batch, repeats=repeats)
  return sec / world_batch.pos.shape[0], np.asarray(out.pos[0], np.float64)


def time_old(scene, sweeps, repeats) -> tuple[float, np.ndarray]:
  return median_time(lambda: reference.resolve_old(scene.pos, scene.half, scene.mass, sweeps=sweeps),
                     repeats)[::-1]


def main():
  parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
  parser.add_argument("--quick", action="store_true")
  parser.add_argument("--batch", type=int, default=64, help="worlds per timed call (default 64)")
  parser.add_argument("--repeats", type=int, default=5)
  parser.add_argument("--replot", action="store_true",
                      help="rewrite the table and plot from error_vs_time.json (with --quick: "
                           "error_vs_time_quick.json) in --out, no run")
  args = add_common_args(parser).parse_args()
  out = out_dir(args)
  if args.replot:
    saved = json.loads((out / f"{stem(args)}.json").read_text())
    write(saved["rows"], argparse.Namespace(**{"smoke": False, **saved["args"], "out": out}),
          saved.get("header") or ["commit unknown (saved before results named their commit)", ""])
    return
  run = Run.start()
  if args.smoke:
    args.batch, args.repeats = 2, 1
  fams = families(args.quick, args.smoke)
  plan = settings(args.quick, args.smoke)
  sweeps_of_old = ITERATIONS[:1] if args.smoke else ITERATIONS
  rows = []
  total = len(fams) * (len(plan) + len(sweeps_of_old))
  started = time.perf_counter()
  with tqdm(total=total, desc="error vs time", unit="setting") as bar:
    for name, (scene, has_ref) in fams.items():
      want = reference.resolve(scene.pos, scene.half, scene.mass) if has_ref else None
      batch = jc.stack([scene.world(gravity=(0.0, 0.0))] * args.batch)
      as_f32 = np.asarray(batch.pos[0], np.float64)
      links = jc.Config.for_world(scene.world()).links  # The link table a user would get.
      for k, it, sub in plan:
        cfg = jc.Config(gravity=False, friction=False, depth=k, iterations=it, substeps=sub,
                        immovable=bool(np.isinf(scene.mass).any()), links=links)
        t, pos = time_jax(batch, cfg, args.repeats)
        method = "pairwise Jacobi (K=0)" if k == 0 else f"chain K={k}"
        if sub > 1:
          method = f"chain K=8, substeps {sub}"
        rows.append(dict(family=name, method=method, depth=k, iterations=it, substeps=sub,
                         time=t, **score(scene, pos, want, as_f32)))
        bar.update()
      for sweeps in sweeps_of_old:
        t, pos = time_old(scene, sweeps, max(1, args.repeats // 2))
        rows.append(dict(family=name, method="old sequential (NumPy, 1 world)", depth=0,
                         iterations=sweeps, substeps=1, time=t,
                         **score(scene, pos, want, scene.pos)))
        bar.update()
  header = run.header()
  saved = {k: v for k, v in vars(args).items() if k not in ("out", "replot")}  # Not JSON.
  (out / f"{stem(args)}.json").write_text(json.dumps(dict(args=saved, header=header, rows=rows),
                                                     indent=0))
  write(rows, args, header)
  print(f"wall time {time.perf_counter() - started:.0f} s")


def stem(args) -> str:
  """The results' file name without suffix: `--quick` writes beside the full sweep."""
  return "error_vs_time_quick" if args.quick and not args.smoke else "error_vs_time"


def error_of(r) -> float:
  """The plotted error: residual penetration, or distance to the reference if larger."""
  return max(r["max_pen"], 0.0 if np.isnan(r["ref_dist"]) else r["ref_dist"])


def pareto(rows):
  """Rows not beaten on both time and error by another row."""
  front = []
  for r in sorted(rows, key=lambda r: (r["time"], error_of(r))):
    if not front or error_of(r) < error_of(front[-1]):
      front.append(r)
  return front


TARGET = 1e-4  # The accuracy the summary asks for (the push-chain target).
KINDS = {"chain": lambda r: r["depth"] > 0 and not r["method"].startswith("old"),
         "pairwise Jacobi": lambda r: r["method"].startswith("pairwise"),
         "old sequential": lambda r: r["method"].startswith("old")}


def summary(rows) -> list[str]:
  """Per family and kind of method: the fastest setting with error <= TARGET, and the
  best error any setting of that kind reached."""
  lines = ["## Summary", "",
           f"Fastest setting with error <= {TARGET:g} per kind of method (time per world-step; "
           "`-`: no setting in the sweep got there), and the best error each kind reached. "
           "Chain settings include substeps; the old system's times are single-world NumPy.", "",
           "| family | chain | pairwise Jacobi | old sequential | best error: chain / Jacobi / old |",
           "|---|---|---|---|---|"]
  for family in dict.fromkeys(r["family"] for r in rows):
    cells, best = [], []
    for test in KINDS.values():
      sel = [r for r in rows if r["family"] == family and test(r)]
      ok = sorted((r for r in sel if error_of(r) <= TARGET), key=lambda r: r["time"])
      cells.append(f"{ok[0]['time'] * 1e6:.1f} us (K={ok[0]['depth']}, {ok[0]['iterations']} it, "
                   f"{ok[0]['substeps']} sub)" if ok else "-")
      best.append(f"{min(error_of(r) for r in sel):.1e}" if sel else "-")
    lines.append(f"| {family} | {' | '.join(cells)} | {' / '.join(best)} |")
  return lines + [""]


def write(rows, args, header: list[str]) -> None:
  out = out_dir(args)
  lines = [
      "# Error against run time", "",
      f"Batch {args.batch}. One step with zero gravity and velocity (pure overlap resolution), time per world-step "
      "under jit + vmap, compile excluded. Error = max(residual penetration, distance to the "
      "reference). `*` marks the Pareto front (nothing both faster and more accurate). The old "
      "sequential system is plain Python/NumPy on one world: its times are not comparable in "
      "absolute terms, only its errors.", ""] + summary(rows)
  for family in dict.fromkeys(r["family"] for r in rows):
    sel = [r for r in rows if r["family"] == family]
    front = {id(r) for r in pareto(sel)}
    lines += [f"## {family}", "",
              "| method | K | iter | substeps | us / world-step | max pen | mean pen | dist to ref | COM drift | immovable moved | |",
              "|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in sel:
      lines.append(
          f"| {r['method']} | {r['depth']} | {r['iterations']} | {r['substeps']} | {r['time'] * 1e6:.1f} | "
          f"{r['max_pen']:.2e} | {r['mean_pen']:.2e} | {r['ref_dist']:.2e} | {r['com_drift']:.2e} | "
          f"{r['fixed_moved']:.0e} | {'*' if id(r) in front else ''} |")
    lines.append("")
  write_result(out, f"{stem(args)}.md", lines, header, echo=False)
  plot(rows, out / f"{stem(args)}.png")
  print("\n".join(header + lines[:8]))
  moved = max(r["fixed_moved"] for r in rows)
  print(f"largest movement of an immovable body over all settings: {moved}")


def plot(rows, path) -> None:
  import matplotlib
  matplotlib.use("Agg")
  import matplotlib.pyplot as plt
  fams = list(dict.fromkeys(r["family"] for r in rows))
  cols = 4
  nrows = int(np.ceil(len(fams) / cols))
  fig, axes = plt.subplots(nrows, cols, figsize=(4.2 * cols, 3.4 * nrows), squeeze=False)
  floor = 1e-8
  for ax, family in zip(axes.flat, fams):
    sel = [r for r in rows if r["family"] == family]
    for method in dict.fromkeys(r["method"] for r in sel):
      pts = sorted((r for r in sel if r["method"] == method), key=lambda r: r["time"])
      ax.plot([r["time"] * 1e6 for r in pts], [max(error_of(r), floor) for r in pts], "-o",
              ms=3, lw=1, label=method)
    front = pareto(sel)
    ax.plot([r["time"] * 1e6 for r in front], [max(error_of(r), floor) for r in front], "k--",
            lw=1.5, alpha=0.6, label="Pareto front")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_title(family, fontsize=9)
    ax.set_xlabel("us per world-step", fontsize=8)
    ax.set_ylabel("error", fontsize=8)
    ax.tick_params(labelsize=7)
    ax.grid(True, which="both", alpha=0.2)
  for ax in axes.flat[len(fams):]:
    ax.axis("off")
  handles, labels = axes.flat[0].get_legend_handles_labels()
  fig.legend(handles, labels, loc="lower center", ncol=6, fontsize=7)
  fig.suptitle(f"jaxchain: error against time per world-step (errors below {floor:g} drawn at {floor:g})")
  fig.tight_layout(rect=(0, 0.06, 1, 0.97))
  fig.savefig(path, dpi=110)


if __name__ == "__main__":
  main()
