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

Beside the peers (`--no-peers` leaves them out): the same fronts where every engine can
be compared, on dynamic scenes with gravity and friction (`peer_fronts`): the room of 64
at rest (boxes settled 270 steps, then a window of 30: penetration and distance to the
exact settled columns) and the push chain (a player driven at 2 units/s into 8 boxes
against a wall, 600 steps: penetration and intrusion over the last 300, distance to the
exact final row). Each engine at a few accuracy settings: jaxchain (depth, iterations,
substeps), Box2D 2.3 (velocity / position iterations), Box2D v3 (substeps; in a worker
under `--v3-python PATH`), pymunk (iterations). Time is CPU seconds per world-step, all of
the process's threads counted (per core: the peers run one thread; jaxchain's XLA
threads are summed), jaxchain batched as users run it.

Writes `results/error_vs_time.md` (a table per scene family),
`results/error_vs_time.png` (log-log error against time per world-step, one line per
method, Pareto front marked), `results/error_vs_time_peers.png` (the fronts of every
engine) and `results/error_vs_time.json` (the rows, and the
header the table is redrawn with by `--replot`); `--quick` writes
`error_vs_time_quick.*` instead, beside the full sweep's.

    python benchmarks/error_vs_time.py           # about 30 minutes on 2 cores
    python benchmarks/error_vs_time.py --v3-python ~/venvs/box2d-v3/bin/python  # Box2D v3 too
    python benchmarks/error_vs_time.py --quick   # fewer scenes and settings
    python benchmarks/error_vs_time.py --smoke --out /tmp/x   # 1 scene, 1 setting: runs, writes
"""

from __future__ import annotations

import argparse
import json
import time

import jax
import jax.numpy as jnp
import numpy as np
from tqdm import tqdm

import jaxchain as jc
from jaxchain import metrics, reference, scenes
import _bench
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
  parser.add_argument("--no-peers", dest="peers", action="store_false",
                      help="leave out the peer engines' fronts")
  parser.add_argument("--v3-python", default=None, metavar="PATH",
                      help="an interpreter with box2d-python and numpy: Box2D v3's fronts too")
  parser.add_argument("--replot", action="store_true",
                      help="rewrite the table and plot from error_vs_time.json (with --quick: "
                           "error_vs_time_quick.json) in --out, no run")
  args = add_common_args(parser).parse_args()
  out = out_dir(args)
  if args.replot:
    saved = json.loads((out / f"{stem(args)}.json").read_text())
    write(saved["rows"], argparse.Namespace(**{"smoke": False, **saved["args"], "out": out}),
          saved.get("header") or ["commit unknown (saved before results named their commit)", ""],
          saved.get("fronts", []), saved.get("notes", []))
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
  fronts, notes = peer_fronts(args) if args.peers else ([], ["Peers left out (--no-peers)."])
  header = run.header()
  saved = {k: v for k, v in vars(args).items() if k not in ("out", "replot")}  # Not JSON.
  (out / f"{stem(args)}.json").write_text(json.dumps(dict(args=saved, header=header, rows=rows,
                                                          fronts=fronts, notes=notes), indent=0))
  write(rows, args, header, fronts, notes)
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


# --- Beside the peers: dynamic scenes, every engine at a few settings -------------------

FRONT_SETTINGS = {  # Engine -> its accuracy settings, cheapest first.
    "jaxchain": [dict(depth=1), dict(depth=2), dict(depth=4), dict(), dict(iterations=2),
                 dict(substeps=2)],
    "Box2D": [dict(iterations=[1, 1]), dict(iterations=[2, 1]), dict(iterations=[4, 2]),
              dict(iterations=[8, 3]), dict(iterations=[20, 10])],
    "Box2D v3": [dict(substeps=1), dict(substeps=2), dict(substeps=4), dict(substeps=8)],
    "pymunk": [dict(iterations=1), dict(iterations=3), dict(iterations=10), dict(iterations=30)],
}
QUICK_FRONTS = {"jaxchain": [dict(depth=2), dict()], "Box2D": [dict(iterations=[2, 1]),
                dict(iterations=[8, 3])], "Box2D v3": [dict(substeps=1), dict(substeps=4)],
                "pymunk": [dict(iterations=3), dict(iterations=10)]}
FRONT_BATCH = 256  # jaxchain's worlds per timed call.
ROOM_N, ROOM_SETTLE, ROOM_WINDOW = 64, 270, 30
PUSH_STEPS, PUSH_TAIL, PUSH_SPEED = 600, 300, 2.0


def setting_name(engine: str, setting: dict) -> str:
  if engine == "jaxchain":
    return ", ".join(f"{k} {v}" for k, v in setting.items()) or "for_world"
  if engine == "Box2D":
    return "iterations {}/{}".format(*setting["iterations"])
  if engine == "Box2D v3":
    return f"substeps {setting['substeps']}"
  return f"iterations {setting['iterations']}"


def exact_room(scene) -> np.ndarray:
  """The room's settled state: every box on the one below it in its column (the lattice's
  columns are 0.1 or more apart, so they never meet), x as it started."""
  exact = scene.pos.copy()
  movable = np.isfinite(scene.mass)
  xs = scene.pos[movable, 0]
  order = np.lexsort((scene.pos[movable, 1], np.round(xs / 1.5)))
  ys = np.empty(int(movable.sum()))
  height = {}
  for k in order:
    col = int(np.round(xs[k] / 1.5))
    ys[k] = 0.5 + height.get(col, 0)
    height[col] = height.get(col, 0) + 1
  exact[movable, 1] = ys
  return exact


def exact_push(scene) -> np.ndarray:
  """The push chain's converged state: the row against the wall, the player against the
  row, all on the floor."""
  exact = scene.pos.copy()
  boxes = list(range(scene.player + 1, scene.last + 1))
  for k, b in enumerate(reversed(boxes)):
    exact[b] = [scene.wall_face - 0.5 - k, 0.5]
  exact[scene.player] = [scene.wall_face - 0.5 - len(boxes), 0.5]
  return exact


def front_errors(kind: str, scene, traj: np.ndarray) -> dict:
  """Errors of a trajectory `[t, n, 2]` (its first position the start)."""
  movable = np.isfinite(scene.mass)
  if kind == "room":
    window = traj[-ROOM_WINDOW:]
    dist = np.max(np.abs(window[-1][movable] - exact_room(scene)[movable]))
    return dict(pen=float(np.max(_bench.penetration(window, scene))), dist=float(dist),
                intrusion=float("nan"))
  tail = traj[-PUSH_TAIL:]
  last = scene.last
  intrusion = np.max(traj[:, last, 0] + 0.5 - scene.wall_face)
  dist = np.max(np.abs(traj[-1][movable] - exact_push(scene)[movable]))
  return dict(pen=float(np.max(_bench.penetration(tail, scene))), dist=float(dist),
              intrusion=float(max(intrusion, 0.0)))


def jax_front(kind: str, scene, setting: dict, steps: int, batch: int, repeats: int) -> dict:
  """jaxchain on `scene`: the first world's trajectory errors, and CPU seconds (every
  thread of the process) per world-step of a batch of `batch` worlds."""
  world = scene.world()
  cfg = jc.Config.for_world(world, **setting)
  controls = None
  if kind == "push":  # The player's velocity set to the drive speed every step: as an
    # acceleration that brings it there (the peers set it).
    def policy(w, t):
      del t
      a = (PUSH_SPEED - w.vel[scene.player, 0]) / cfg.dt
      return jnp.zeros_like(w.pos).at[scene.player, 0].set(a)
    roll = lambda w: jc.rollout(w, cfg, steps, policy=policy)
  else:
    roll = lambda w: jc.rollout(w, cfg, steps)
  single = jax.jit(roll)
  final, traj = single(world)
  start = np.asarray(world.pos)[None]
  errors = front_errors(kind, scene, np.concatenate([start, np.asarray(traj.pos)]))
  if batch > 1:  # Timed as users run it: a batch, the final state only.
    timed, args = jax.jit(jax.vmap(lambda w: roll(w)[0].pos)), jc.stack([world] * batch)
  else:  # (`--smoke`: the program above, one world.)
    timed, args = single, world
  jax.block_until_ready(timed(args))
  cpu = []
  for _ in range(repeats):
    t0 = time.process_time()
    jax.block_until_ready(timed(args))
    cpu.append(time.process_time() - t0)
  return dict(cpu=float(np.median(cpu)) / (batch * steps), status=int(final.status), **errors)


def peer_front(peer, kind: str, scene, setting: dict, steps: int) -> dict:
  """A Python peer on `scene` at `setting`: errors of its trajectory, seconds per
  world-step (one thread: wall = CPU)."""
  ps = scene.peer(speed=PUSH_SPEED if kind == "push" else None)
  ps["solver"] = setting
  pos, _ = peer.record(ps, [(steps, {})])
  timed = peer.time(ps, 0, steps, min_s=0.2, max_reps=20)
  return dict(cpu=timed["seconds"] / (timed["reps"] * steps), status=0,
              **front_errors(kind, scene, pos))


def peer_fronts(args) -> tuple[list[dict], list[str]]:
  """Every engine's errors and CPU time per world-step on the dynamic scenes."""
  table = QUICK_FRONTS if args.quick else FRONT_SETTINGS
  room_steps, push_steps, batch, repeats = ROOM_SETTLE + ROOM_WINDOW, PUSH_STEPS, FRONT_BATCH, 3
  if args.smoke:
    table = {k: v[:1] for k, v in QUICK_FRONTS.items()}
    room_steps, push_steps, batch, repeats = 12, 12, 1, 1
  peers, notes = _bench.load_peers(("Box2D", "Box2D v3", "pymunk"), v3_python=args.v3_python)
  scenes_ = {"room": _bench.room(ROOM_N if not args.smoke else 8), "push": _bench.push_chain()}
  engines = ["jaxchain"] + [p.name for p in peers]
  rows = []
  total = sum(len(table.get(e, ())) for e in engines) * len(scenes_)
  try:
    with tqdm(total=total, desc="beside the peers", unit="setting") as bar:
      for kind, scene in scenes_.items():
        steps = room_steps if kind == "room" else push_steps
        for engine in engines:
          for setting in table.get(engine, ()):
            if engine == "jaxchain":
              r = jax_front(kind, scene, setting, steps, batch, repeats)
            else:
              peer = next(p for p in peers if p.name == engine)
              r = peer_front(peer, kind, scene, setting, steps)
            rows.append(dict(scene=kind, engine=engine, setting=setting_name(engine, setting),
                             **r))
            bar.update()
  finally:
    for p in peers:
      if isinstance(p, _bench.PythonPeer):
        p.close()
  versions = [f"jaxchain {jc.__version__}"] + [p.version for p in peers]
  return rows, ["Engines: " + "; ".join(versions) + "."] + notes


FRONT_TITLES = {
    "room": (f"Room of {ROOM_N} at rest: steps {ROOM_SETTLE}-{ROOM_SETTLE + ROOM_WINDOW}",
             "max penetration over the window; distance of every box to its exact settled place "
             "(on the box below it in its column) at the end"),
    "push": (f"Push chain: a player driven at {PUSH_SPEED} u/s into 8 boxes against a wall, "
             f"{PUSH_STEPS} steps", f"max penetration over the last {PUSH_TAIL} steps, wall "
             "intrusion over the run, distance of every body to the exact final row at the end"),
}


def front_error(r) -> float:
  """A front's error: the larger of penetration and distance to the exact state."""
  return max(r["pen"], r["dist"])


def front_lines(fronts, notes) -> list[str]:
  lines = ["## Beside the peers: dynamic scenes, every engine at a few settings", "",
           "Gravity -9.81, friction 0.5, dt 1/60, unit boxes (the peers' scenes, "
           "`benchmarks/peers.py`). Time: CPU seconds per world-step, every thread of the "
           "process counted, so per core (the peers run one thread; jaxchain "
           f"`Config.for_world` with the overrides named, {FRONT_BATCH} worlds under `vmap`, "
           "its XLA threads summed). Error: the larger of penetration and distance to the exact "
           "state. Box2D keeps boxes a skin apart (0.01 in 2.3) and v3 and pymunk let them sink "
           "a slop, so their distance to the exact state is bounded below by it.", ""]
  lines += [f"- {n}" for n in notes] + [""]
  for kind, (title, what) in FRONT_TITLES.items():
    sel = [r for r in fronts if r["scene"] == kind]
    if not sel:
      continue
    lines += [f"### {title}", "", f"Errors: {what}.", "",
              "| engine | setting | us CPU / world-step | max penetration | distance to exact | "
              "wall intrusion | status |", "|---|---|---|---|---|---|---|"]
    for r in sel:
      lines.append(f"| {r['engine']} | {r['setting']} | {r['cpu'] * 1e6:.1f} | {r['pen']:.2e} | "
                   f"{r['dist']:.2e} | {r['intrusion']:.2e} | {r['status']} |")
    lines.append("")
  return lines


def plot_fronts(fronts, path) -> None:
  import matplotlib
  matplotlib.use("Agg")
  import matplotlib.pyplot as plt
  kinds = [k for k in FRONT_TITLES if any(r["scene"] == k for r in fronts)]
  fig, axes = plt.subplots(1, len(kinds), figsize=(6 * len(kinds), 4.4), squeeze=False)
  floor = 1e-7
  for ax, kind in zip(axes.flat, kinds):
    sel = [r for r in fronts if r["scene"] == kind]
    for engine in dict.fromkeys(r["engine"] for r in sel):
      pts = sorted((r for r in sel if r["engine"] == engine), key=lambda r: r["cpu"])
      ax.plot([r["cpu"] * 1e6 for r in pts], [max(front_error(r), floor) for r in pts], "-o",
              ms=4, lw=1.2, label=engine)
      for r in pts:
        ax.annotate(r["setting"], (r["cpu"] * 1e6, max(front_error(r), floor)), fontsize=6,
                    alpha=0.7, xytext=(3, 3), textcoords="offset points")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_title(FRONT_TITLES[kind][0], fontsize=9)
    ax.set_xlabel("us CPU per world-step (per core)", fontsize=8)
    ax.set_ylabel("error: max(penetration, distance to exact)", fontsize=8)
    ax.grid(True, which="both", alpha=0.2)
    ax.legend(fontsize=7)
  fig.suptitle(f"Error against time per world-step, beside the peers (errors below {floor:g} "
               f"drawn at {floor:g})", fontsize=10)
  fig.tight_layout()
  fig.savefig(path, dpi=110)


def write(rows, args, header: list[str], fronts=(), notes=()) -> None:
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
  if fronts:
    lines += front_lines(fronts, notes)
  write_result(out, f"{stem(args)}.md", lines, header, echo=False)
  plot(rows, out / f"{stem(args)}.png")
  if fronts:
    plot_fronts(fronts, out / f"{stem(args)}_peers.png")
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
