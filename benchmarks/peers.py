"""jaxchain beside peer engines (Box2D 2.3, Box2D v3, pymunk, Jax2D), timed interleaved.

Every engine runs in this one process (Box2D v3, whose wheels need Python 3.12 or later,
in a worker under `--v3-python PATH` that times its own steps), and every setting is
measured once per round, round after round: a shared machine's load hits all alike, and
ratios are taken within a round. The table gives every round, with the 1-minute load
average when it was measured, and the median.

- **Room of N boxes** (`_bench.room`): N unit boxes (mass 1) on a lattice in a closed room
  of 4 immovable walls, g = -9.81, dt = 1/60, friction 0.5, restitution 0, fixed rotation,
  no sleeping. Two windows of `STEPS` (30) steps: **from rest** (steps 0-30: the boxes
  fall, and first touch at about step 19) and **settled** (steps 270-300: each engine
  steps its own copy of the room 270 steps, untimed, and the timed steps start from that
  state: a room at rest, what long rollouts spend their time on). Body-steps/s = N x
  worlds x steps / seconds. jaxchain: one world, and a batch (B = 1024 at N = 16 and 64,
  B = 256 at N = 256: `jax.jit(jax.vmap(rollout))`), `Config.for_world`; the batch again
  with `converge=True` (forward-only: the hop loops stop once nothing changes), on the
  settled window only (from rest it would time free fall). Peers: one world on one
  thread; Jax2D up to N = 64. A measurement repeats its window until `MIN_S` (0.25 s)
  is timed: jitted engines call their compiled window again on the same state, Python
  peers build, settle and time a fresh world each time. Compile apart.
- **Push chain** (`_bench.push_chain`): a player driven at 2 units/s along +x into a row
  of 8 touching unit boxes on a floor, an immovable wall right behind the last box; 600
  steps. Accuracy only: max penetration between any two bodies over the last 300 steps,
  wall intrusion over the run, jitter (std of x over the last 30 steps).

**Per core**: jaxchain lets XLA use every core, the peers use one thread, and a user with
C cores can run C peer processes; so the same rooms are measured again with every engine
pinned to one core (`--cores both`, the default): a child process started with its CPU
affinity set to one core (`os.sched_setaffinity`, before Python starts, so XLA's thread
pool and the Box2D v3 worker see one core), interleaved rounds as above, and its rows and
ratios are a section of the table. `--cores all` measures on every core only; `--cores
one` pinned only. The table names the CPU model.

Engines that do not import are skipped with a message (`pip install -e .[peers]`
installs Box2D 2.3, pymunk and Jax2D). Before timing, waits (up to `--wait` s) until no
other benchmark or pytest runs. Writes `results/peers.md`.

    python benchmarks/peers.py                         # about 15 minutes on 2 quiet cores
    python benchmarks/peers.py --v3-python ~/venvs/box2d-v3/bin/python   # with Box2D v3
    python benchmarks/peers.py --quick                 # the room of 64 only
    python benchmarks/peers.py --cores all             # every core only (no pinned child)
    python benchmarks/peers.py --smoke --out /tmp/x    # N=8, B=2, a few steps: runs, writes
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import pathlib
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable

import jax
import numpy as np
from tqdm import tqdm

import jaxchain as jc
import _bench
from _bench import PythonPeer, Scene, load_peers, penetration, push_chain, room

ROOMS = {16: 1024, 64: 1024, 256: 256}  # N -> worlds in jaxchain's batch.
QUICK_ROOMS = {64: 1024}
SETTLE = 270  # Untimed steps before the settled window (a multiple of STEPS).
STEPS = 30  # Steps in a timed window.
ROUNDS = 3
MIN_S = 0.25  # A measurement repeats its window until this much is timed...
MAX_REPS = 400  # ... or this many windows ran.
JAX2D_MAX_N = 64  # Jax2D builds its all-pairs index lists in a Python loop; see `_bench.Jax2D`.
PUSH_STEPS = 600
PUSH_SPEED = 2.0
TAIL_PEN = 300  # Penetration is measured over the last this many push-chain steps.
TAIL_JITTER = 30  # Jitter is the std of x over the last this many steps.
BUSY = r"benchmarks/(stability|specialisation|error_vs_time|throughput)\.py|pytest"
REST, SETTLED = "from rest", "settled"


# --- Settings: one engine at one size, measured once a round -----------------------------


@dataclasses.dataclass
class Setting:
  """One engine at one size. `measure(window) -> seconds per body-step` times one
  window (`REST` or `SETTLED`) and keeps the positions it ended with in `end[window]`."""

  engine: str
  n: int
  batch: int
  windows: tuple[str, ...]
  measure: Callable[[str], float]
  compile_s: float = 0.0
  notes: str = ""
  end: dict = dataclasses.field(default_factory=dict)
  converge: bool = False
  status: list | None = None  # jaxchain: the OR of the status bits of every measured window.


def jitted_setting(engine: str, n: int, batch: int, fn, start, windows, steps: int, settle: int,
                   min_s: float, positions, notes: str = "", converge: bool = False,
                   after: Callable | None = None) -> Setting:
  """A jitted engine's setting: `fn(state) -> state` advances `steps` steps; it is
  compiled ahead (compile timed apart), and settles its state by `settle // steps` calls.
  `positions(state)` gives the first world's `[n, 2]`; `after(state)` runs after each
  measured window (jaxchain reads its status bits there)."""
  t0 = time.perf_counter()
  compiled = jax.jit(fn).lower(start).compile()
  compile_s = time.perf_counter() - t0
  states = {REST: start}
  if SETTLED in windows:
    s = start
    for _ in range(settle // steps):
      s = compiled(s)
    states[SETTLED] = jax.block_until_ready(s)
  jax.block_until_ready(compiled(start))  # Warm-up.
  setting = Setting(engine, n, batch, windows, None, compile_s, notes, converge=converge)

  def measure(window: str) -> float:
    x, seconds, calls = states[window], 0.0, 0
    while calls == 0 or (seconds < min_s and calls < MAX_REPS):
      t0 = time.perf_counter()
      out = jax.block_until_ready(compiled(x))
      seconds += time.perf_counter() - t0
      calls += 1
    setting.end[window] = np.asarray(positions(out), float)
    if after is not None:
      after(out)
    return seconds / (calls * n * batch * steps)

  setting.measure = measure
  return setting


def jaxchain_setting(n: int, batch: int, windows, steps: int, settle: int, min_s: float,
                     **overrides) -> Setting:
  """jaxchain on the room of `n` in `batch` worlds (one world when `batch` is 1)."""
  world = room(n).world()
  cfg = jc.Config.for_world(world, dt=_bench.DT, **overrides)
  status = [0]

  def roll(w):
    return jc.rollout(w, cfg, steps)[0]
  if batch > 1:
    world, roll = jc.stack([world] * batch), jax.vmap(roll)
  first = (lambda w: w.pos[0]) if batch > 1 else (lambda w: w.pos)

  def after(w):
    status[0] |= int(np.bitwise_or.reduce(np.ravel(np.asarray(w.status))))

  notes = (f"depth {cfg.depth}, links {cfg.links}, {cfg.broadphase}"
           f"{f', neighbors {cfg.neighbors}' if getattr(cfg, 'neighbors', None) else ''}, "
           f"substeps {cfg.substeps}{', converge (forward-only)' if cfg.converge else ''}")
  s = jitted_setting("jaxchain", n, batch, roll, world, windows, steps, settle, min_s, first,
                     notes, converge=bool(cfg.converge), after=after)
  s.status = status
  return s


def jax2d_setting(peer, n: int, windows, steps: int, settle: int, min_s: float) -> Setting:
  state, step = peer.build(room(n))

  def roll(s):
    return jax.lax.fori_loop(0, steps, lambda _, x: step(x), s)
  return jitted_setting("Jax2D", n, 1, roll, state, windows, steps, settle, min_s, peer.positions,
                        "default StaticSimParams (10 iterations), SimParams")


def python_setting(peer: PythonPeer, n: int, windows, steps: int, settle: int, min_s: float,
                   max_reps: int) -> Setting:
  scene = room(n).peer()
  setting = Setting(peer.name, n, 1, windows, None)

  def measure(window: str) -> float:
    out = peer.time(scene, settle if window == SETTLED else 0, steps, min_s, max_reps)
    setting.end[window] = out["pos"]
    return out["seconds"] / (out["reps"] * n * steps)

  setting.measure = measure
  return setting


def room_settings(rooms: dict[int, int], peers, notes, steps, settle, min_s, max_reps,
                  smoke: bool = False) -> list[Setting]:
  """Every setting of the room, compiled and settled, in the order a round runs them
  (`smoke`: the batch with `converge` only, one compile less)."""
  plan = []
  for n, batch in rooms.items():
    plan.append(("jaxchain", n, 1, {}))
    if batch > 1:
      if not smoke:
        plan.append(("jaxchain", n, batch, {}))
      plan.append(("jaxchain", n, batch, dict(converge=True)))
    for p in peers:
      if p.name == "Jax2D" and n > JAX2D_MAX_N:
        notes.append(f"Jax2D, room of {n}: skipped. Its `PhysicsEngine` builds all-pairs index "
                     f"lists in a Python loop over ({n + 4})^2 pairs at construction and its "
                     "solver walks all pairs in sequential batches of 16, 10 iterations a step: "
                     "far past this run's time budget.")
        continue
      plan.append((p.name, n, 1, p))
  settings = []
  for name, n, batch, extra in tqdm(plan, desc="compile and settle", unit="setting"):
    both = (REST, SETTLED)
    if name == "jaxchain":
      windows = (SETTLED,) if extra.get("converge") else both
      settings.append(jaxchain_setting(n, batch, windows, steps, settle, min_s, **extra))
    elif name == "Jax2D":
      settings.append(jax2d_setting(extra, n, both, steps, settle, min_s))
    else:
      settings.append(python_setting(extra, n, both, steps, settle, min_s, max_reps))
  return settings


def measure_rounds(settings: list[Setting], n_rounds: int) -> _bench.Rounds:
  """Every (setting, window) once a round, `n_rounds` rounds; figures are body-steps/s."""
  measures = {(i, w): (lambda s=s, w=w: 1.0 / s.measure(w))
              for i, s in enumerate(settings) for w in s.windows}
  with tqdm(total=n_rounds * len(measures), desc="rounds", unit="window") as bar:
    def progress(r, key):
      s = settings[key[0]]
      bar.set_postfix_str(f"round {r + 1}, done: {s.engine} N={s.n} B={s.batch} {key[1]}")
      bar.update()
    return _bench.rounds(measures, n_rounds, progress)


# --- Push chain ------------------------------------------------------------------------


def push_metrics(traj: np.ndarray, scene: Scene) -> dict:
  """Accuracy figures of a push-chain trajectory `[steps, n, 2]`."""
  right = traj[:, scene.last, 0] + scene.half[scene.last, 0]
  tail = traj[-TAIL_JITTER:]
  return dict(pen=float(np.max(penetration(traj[-TAIL_PEN:], scene))),
              intrusion=float(max(np.max(right - scene.wall_face), 0.0)),
              jit_player=float(np.std(tail[:, scene.player, 0])),
              jit_last=float(np.std(tail[:, scene.last, 0])),
              player_x=float(traj[-1, scene.player, 0]))


def push_rows(peers, steps: int = PUSH_STEPS) -> list[dict]:
  """One row of push-chain accuracy per engine (jaxchain first), over `steps` steps."""
  scene = push_chain()
  rows = []
  for name in tqdm(["jaxchain"] + [p.name for p in peers], desc="push chain", unit="engine"):
    extra = ""
    if name == "jaxchain":
      world = scene.world()
      cfg = jc.Config.for_world(world, dt=_bench.DT)

      def body(w, _):
        w = jc.step(w.replace(vel=w.vel.at[scene.player, 0].set(PUSH_SPEED)), cfg)
        return w, w.pos
      final, traj = jax.jit(lambda w: jax.lax.scan(body, w, None, length=steps))(world)
      extra = (f"depth {cfg.depth}, {cfg.broadphase}, substeps {cfg.substeps}; "
               f"status {status_names(int(final.status))}")
    else:
      peer = next(p for p in peers if p.name == name)
      if name == "Jax2D":
        state, step = peer.build(scene, speed=PUSH_SPEED)
        def advance(x, _):
          x = step(x)
          return x, peer.positions(x)
        _, traj = jax.jit(lambda s: jax.lax.scan(advance, s, None, length=steps))(state)
      else:
        traj = peer.record(scene.peer(speed=PUSH_SPEED), [(steps, {})])[0][1:]
    rows.append(dict(engine=name, extra=extra, **push_metrics(np.asarray(traj, float), scene)))
  return rows


# --- Runs ------------------------------------------------------------------------------


def status_names(code: int) -> str:
  """Names of the jaxchain status bits set in `code`, or `0`."""
  names = [k for k, bit in vars(jc.status).items()
           if k.isupper() and isinstance(bit, int) and bit in jc.status.MESSAGES and code & bit]
  return " ".join(names) or "0"


def busy() -> list[str]:
  """Command lines of other benchmark processes running now."""
  try:
    out = subprocess.run(["pgrep", "-af", BUSY], capture_output=True, text=True).stdout
  except OSError:
    return []
  return [line for line in out.splitlines() if line.strip()]


def wait_quiet(limit_s: float, poll_s: float = 30.0) -> bool:
  """Waits (up to `limit_s`) until no other benchmark runs; whether it got there."""
  t0 = time.perf_counter()
  while busy():
    if time.perf_counter() - t0 >= limit_s:
      return False
    print(f"waiting for a quiet machine: {busy()}", file=sys.stderr)
    time.sleep(poll_s)
  return True


def main():
  parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
  parser.add_argument("--quick", action="store_true", help="the room of 64 only (B = 1 and 1024)")
  parser.add_argument("--v3-python", default=None, metavar="PATH",
                      help="an interpreter with box2d-python and numpy (Python >= 3.12) that runs "
                           "Box2D v3 in a worker, interleaved with the rest")
  parser.add_argument("--rounds", type=int, default=ROUNDS, help=f"rounds (default {ROUNDS})")
  parser.add_argument("--wait", type=float, default=900.0,
                      help="seconds to wait for other benchmarks to finish before timing")
  parser.add_argument("--cores", choices=("both", "all", "one"), default="both",
                      help="measure on every core (all), with every engine pinned to one core "
                           "(one), or both (default)")
  parser.add_argument("--pinned-json", default=None, help=argparse.SUPPRESS)  # The child's.
  args = _bench.add_common_args(parser).parse_args()
  run = _bench.Run.start()
  if args.cores == "one" and args.pinned_json is None:
    lines = ["# jaxchain beside peer engines, every engine pinned to one core", ""]
    lines += pinned_section(args)
    _bench.write_result(_bench.out_dir(args), "peers.md", lines, run)
    return
  rooms, steps, settle, min_s, max_reps = (QUICK_ROOMS if args.quick else ROOMS), STEPS, SETTLE, MIN_S, MAX_REPS
  push_steps = PUSH_STEPS
  if args.smoke:  # A room of 8 in one world and a batch of 2, a few steps; no wait.
    rooms, steps, settle, min_s, max_reps, push_steps = {8: 2}, 2, 4, 0.0, 1, 8
    args.rounds, args.wait = min(args.rounds, 2), 0.0
    if args.pinned_json is not None:  # The pinned child's smoke: its plumbing, one compile
      rooms, args.rounds = {8: 1}, 1  # of the room (the parent's smoke runs the rest).
  if args.rounds < 1 or settle % steps:
    parser.error(f"--rounds must be >= 1 (got {args.rounds}) and SETTLE ({settle}) a multiple of "
                 f"STEPS ({steps})")
  peers, notes = load_peers(v3_python=args.v3_python)
  if args.smoke and args.pinned_json is not None:  # Jax2D's programs compile in the parent's.
    peers = [p for p in peers if p.name != "Jax2D"]
  for line in notes:
    print(line, file=sys.stderr)
  try:
    t_wait = time.perf_counter()
    quiet = wait_quiet(args.wait) if args.wait > 0 else not busy()
    notes.append(f"Waited {time.perf_counter() - t_wait:.0f} s for other benchmarks and tests to "
                 f"finish; machine quiet at the start: {'yes' if quiet else 'NO'} (other "
                 f"benchmarks or pytest: {'none' if quiet else busy()}).")
    settings = room_settings(rooms, peers, notes, steps, settle, min_s, max_reps, args.smoke)
    measured = measure_rounds(settings, args.rounds)
    push = push_rows(peers, push_steps)
  finally:
    for p in peers:
      if isinstance(p, PythonPeer):
        p.close()
  late = busy()
  if late:
    notes.append(f"Running at the end of the run: {late}; timings may be disturbed.")
  lines = table(settings, measured, peers, notes, steps, settle, args.rounds, push, push_steps)
  if args.pinned_json is not None:  # The pinned child: its rows and ratios, for the parent.
    pathlib.Path(args.pinned_json).write_text(json.dumps(dict(
        cpus=sorted(os.sched_getaffinity(0)), rooms=room_lines(lines), targets=target_lines(lines))))
    return
  if args.cores == "both":
    lines += [""] + pinned_section(args)
  _bench.write_result(_bench.out_dir(args), "peers.md", lines, run)


PINNED_CPU = 0  # The core the per-core run pins every engine to.


def pinned_section(args) -> list[str]:
  """The same measurement in a child process pinned to one core (its CPU affinity set
  before it starts: XLA's thread pool, the Python peers and the Box2D v3 worker all run
  on `PINNED_CPU`): the room rows and the ratios, as lines of a section."""
  argv = [sys.executable, str(pathlib.Path(__file__).resolve()), "--rounds", str(args.rounds),
          "--wait", "0"]
  argv += ["--quick"] * args.quick + ["--smoke"] * args.smoke
  if args.v3_python:
    argv += ["--v3-python", args.v3_python]
  header = [f"## Per core: every engine pinned to CPU {PINNED_CPU} ({_bench.cpu_model()})", ""]
  with tempfile.TemporaryDirectory() as tmp:
    out = pathlib.Path(tmp) / "pinned.json"
    argv += ["--out", tmp, "--pinned-json", str(out)]
    print(f"per core: {' '.join(argv[1:])} (pinned to CPU {PINNED_CPU})", file=sys.stderr)
    done = subprocess.run(argv, preexec_fn=lambda: os.sched_setaffinity(0, {PINNED_CPU}))
    if done.returncode or not out.exists():
      return header + [f"The pinned run failed (exit {done.returncode}); no per-core figures."]
    child = json.loads(out.read_text())
  return header + [
      f"The same rooms, windows and rounds in a child process whose CPU affinity is "
      f"{child['cpus']} from its start (`os.sched_setaffinity` before Python starts): jaxchain's "
      "XLA threads, the Python peers and the Box2D v3 worker share that one core, so each "
      "figure is per core. A machine with C cores runs C such processes.", "",
  ] + child["rooms"] + ["", "Ratios per core (median of rounds):", ""] + child["targets"]


def room_lines(lines: list[str]) -> list[str]:
  """The room table of `table`'s lines (its header row to its last row)."""
  start = next(k for k, line in enumerate(lines) if line.startswith("| engine | N |"))
  end = next(k for k in range(start, len(lines)) if not lines[k].startswith("|"))
  return lines[start:end]


def target_lines(lines: list[str]) -> list[str]:
  """The ratio lines of `table`'s "Targets" section."""
  start = lines.index("## Targets")
  return [line for line in lines[start:] if line.startswith("- room of")]


# --- Output ----------------------------------------------------------------------------


def ratio_line(label: str, mine: list[float], theirs: list[float]) -> str:
  per_round = [a / b for a, b in zip(mine, theirs)]
  return (f"{label}: **{statistics.median(per_round):.2f}x** (median of rounds; rounds "
          + ", ".join(f"{r:.2f}x" for r in per_round) + ")")


def table(settings, measured, peers, notes, steps, settle, n_rounds, push, push_steps) -> list[str]:
  engines = [f"jaxchain {jc.__version__} (jax {jax.__version__})"] + [p.version for p in peers]
  lines = [
      "# jaxchain beside peer engines", "",
      "Engines: " + "; ".join(engines) + ".", "",
      "Shared setup: unit boxes of mass 1, fixed rotation, g = -9.81, dt = 1/60, friction 0.5, "
      "restitution 0, no sleeping. Box2D 2.3: 8 velocity / 3 position iterations. Box2D v3: "
      "4 substeps (its soft-step solver's default). pymunk: default 10 iterations (and its "
      "default collision slop 0.1). Jax2D: default `StaticSimParams` (10 iterations, warm "
      "starting) and `SimParams`. jaxchain: `Config.for_world(world)` with friction 0.5 on "
      "every body. Peers run on one thread; jaxchain and Jax2D let XLA use every core "
      f"({len(os.sched_getaffinity(0))} here). CPU: {_bench.cpu_model()}.", "",
  ]
  lines += [f"- {n}" for n in notes] + ([""] if notes else [])
  lines += [
      "## Room of N boxes: body-steps/s, interleaved rounds", "",
      f"Windows of {steps} steps: *from rest* (steps 0-{steps}: the boxes fall) and *settled* "
      f"(steps {settle}-{settle + steps}, after each engine stepped its own copy {settle} steps, "
      f"untimed). {n_rounds} rounds; in each, every row below is measured once, in this order "
      "(jitted engines repeat their compiled window, Python peers a fresh world settled again, "
      f"until {MIN_S} s are timed). Each round's cell: body-steps/s (the 1-min load average "
      "when it was measured). Compile apart. End penetration: the largest pairwise overlap "
      "at the end of the window (first world).", "",
      "| engine | N | worlds B | window | median body-steps/s | "
      + " | ".join(f"round {r + 1} (load)" for r in range(n_rounds))
      + " | compile s | end penetration | notes |",
      "|---|---|---|---|---|" + "---|" * n_rounds + "---|---|---|",
  ]
  for i, s in enumerate(settings):
    for w in s.windows:
      rs, loads = measured.figures[i, w], measured.loads[i, w]
      note = s.notes
      if s.status is not None:
        note += f"; status {status_names(s.status[0])}"
      scene = room(s.n)
      pen = float(penetration(s.end[w][None], scene)[0]) if w in s.end else float("nan")
      lines.append(f"| {s.engine} | {s.n} | {s.batch} | {w} | **{statistics.median(rs):.3g}** | "
                   + " | ".join(f"{r:.3g} ({l:.2f})" for r, l in zip(rs, loads))
                   + f" | {s.compile_s:.1f} | {pen:.2e} | {note} |")
  lines += [
      "", f"## Push chain: accuracy ({push_steps} steps)", "",
      f"Player driven at {PUSH_SPEED} units/s (+x) into {_bench.PUSH_BOXES} touching boxes on a "
      "floor, an immovable wall right behind the last box. Penetration: max over pairs (not "
      f"both immovable) of min(overlap_x, overlap_y) over the last {TAIL_PEN} steps. Intrusion: "
      "max over the run of (last box right edge - wall face). Jitter: std of x over the last "
      f"{TAIL_JITTER} steps.", "",
      "| engine | max penetration | wall intrusion | jitter player x | jitter last box x | "
      "player end x | notes |",
      "|---|---|---|---|---|---|---|",
  ]
  for r in push:
    lines.append(f"| {r['engine']} | {r['pen']:.2e} | {r['intrusion']:.2e} | {r['jit_player']:.2e} | "
                 f"{r['jit_last']:.2e} | {r['player_x']:.4f} | {r['extra']} |")
  lines += [
      "",
      "Box2D keeps polygons apart by a skin (`b2_polygonRadius` = 0.01): boxes rest about 0.015 "
      "above the floor and the touching chain is spread by its skins, so geometric penetration "
      "stays 0 and the player stops short of x = 2.5. pymunk allows `collision_slop` (0.1) of "
      "overlap and corrects it softly; a player whose velocity is reset every step pushes with "
      "unbounded force, so its chain compresses. Jax2D (10 iterations, slop 0.01) rests about "
      "0.01 deep.",
      "", "## Targets", "",
      "Ratios of body-steps/s taken within each round (same process, interleaved), then the "
      "median over rounds; the peers on one thread.", "",
  ]
  jc_push = next(r for r in push if r["engine"] == "jaxchain")
  ok = jc_push["pen"] < 1e-4 and jc_push["intrusion"] < 1e-4
  lines.append(f"- jaxchain push chain, penetration {jc_push['pen']:.2e} and intrusion "
               f"{jc_push['intrusion']:.2e} below 1e-4: {'yes' if ok else 'NO'}")

  def find(engine, n, batch=1, converge=False):
    return next((i for i, s in enumerate(settings) if s.engine == engine and s.n == n
                 and s.batch == batch and s.converge == converge), None)

  for n in dict.fromkeys(s.n for s in settings):
    big = max((s.batch for s in settings if s.n == n and s.engine == "jaxchain"), default=1)
    for peer in ("Box2D", "Box2D v3"):
      j = find(peer, n)
      if j is None:
        lines.append(f"- room of {n}: {peer} not measured (see the notes above)")
        continue
      for converge in (False, True):
        i = find("jaxchain", n, big, converge)
        if i is None:
          continue
        label = (f"room of {n}, settled, jaxchain B={big}{' converge' if converge else ''} over "
                 f"{peer} one thread")
        lines.append("- " + ratio_line(label, measured.figures[i, SETTLED],
                                       measured.figures[j, SETTLED]))
      i = find("jaxchain", n, big)
      if i is not None:
        lines.append("- " + ratio_line(f"room of {n}, from rest, jaxchain B={big} over {peer} one "
                                       "thread", measured.figures[i, REST], measured.figures[j, REST]))
    one, batch = find("jaxchain", n), find("jaxchain", n, big)
    if one is not None and batch is not None and big > 1:
      lines.append("- " + ratio_line(f"room of {n}, settled, jaxchain B={big} over B=1 (issue 23 "
                                     "asks >= 3x at N=64)", measured.figures[batch, SETTLED],
                                     measured.figures[one, SETTLED]))
  return lines


if __name__ == "__main__":
  main()
