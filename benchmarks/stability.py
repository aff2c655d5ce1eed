"""Stiff and extreme cases over long runs: the long versions of `tests/test_stability.py`.

Every case reports what the tests' `assert_sane` guarantees, measured after every
step: the state stays finite (status bit and `isfinite`), immovable bodies at rest
move by exactly 0, penetration stays bounded, and energy never grows by more than
lifting the previous step's residual penetration (`g * total movable mass *
penetration`). Status bits are decoded with `jc.check`. Cases: alternating mass
ratios in stacks of 20, a stack of 100, a chain of 256 boxes pushed into a wall,
tiny boxes at far coordinates in float32, a dt sweep, tunnelling against a thin
wall with and without substeps, and the soak: the platformer room in many worlds
with the player pushed in random directions for 10^4 steps. Writes
`results/stability.md` and `results/stability.png`.

    python benchmarks/stability.py            # full run, about 3 minutes on 2 cores
    python benchmarks/stability.py --quick    # shorter soak (B=8, 2000 steps)
    python benchmarks/stability.py --smoke --out /tmp/x   # every case once, tiny: runs, writes
"""

from __future__ import annotations

import argparse
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np
from tqdm import tqdm

import jaxchain as jc
from jaxchain import metrics, scenes, status
import _bench
from _bench import add_common_args, out_dir

INF = np.inf
RATIOS = (1e-6, 1e-3, 1e3, 1e6)
DTS = (1e-4, 1e-3, 1 / 60, 1 / 30)
SPEEDS = (10.0, 50.0, 100.0, 200.0, 400.0)
BIT_NAMES = {getattr(status, k): k for k in ("CELL_OVERFLOW", "STATIC_OVERFLOW", "BODY_TOO_LARGE",
                                             "NON_FINITE", "DEPTH_EXHAUSTED", "FAST_BODY")}
SOAK_PUSH = 30.0  # Largest player acceleration in the soak.
SOAK_HOLD = 30  # Steps between direction changes.
SOAK_CHUNK = 500  # Steps per compiled call.
ROOM_TOL = 1e-3  # A centre this far outside the room interior has left the room.
# `--smoke` only: compiled rollouts by (config, steps, shapes), so cases that build the
# same program (its stacks of 10 at depth 10) compile it once. The full run compiles each
# case itself, so every row's compile time is its own.
SHARED: dict | None = None


# --- Measures ------------------------------------------------------------------------


def bit_names(code: int) -> str:
  """Short names of the status bits in `code`, or `-` for none."""
  names = [name for bit, name in BIT_NAMES.items() if code & bit]
  unknown = code & ~sum(BIT_NAMES)
  if unknown:
    names.append(f"{unknown:#x}")
  return ", ".join(names) or "-"


def check_messages(world) -> set[str]:
  """The distinct `jc.check` messages of a (batched) world, without the world index."""
  return {m.split(": ", 1)[1] for m in jc.check(world)}


@jax.jit
def penetrations(world, pos):
  """`[t]` largest penetration after each step of a trajectory `pos [t, n, 2]`."""
  return jax.lax.map(lambda p: metrics.max_penetration(world.replace(pos=p)), pos, batch_size=100)


def energy(mass: np.ndarray, pos: np.ndarray, vel: np.ndarray, g: float) -> np.ndarray:
  """`[t]` kinetic + potential energy (float64) of bodies with masses `mass` (0 for
  immovable) along `pos, vel [t, n, 2]`."""
  v, y = np.asarray(vel, np.float64), np.asarray(pos, np.float64)[..., 1]
  return 0.5 * np.sum(mass[None, :, None] * v**2, axis=(1, 2)) + g * np.sum(mass[None] * y, axis=1)


def run_case(world: jc.World, cfg: jc.Config, steps: int, controls=None, driven: bool = False) -> dict:
  """Rolls one world out for `steps` steps and measures the `assert_sane` guarantees.

  Args:
    world: a single world.
    cfg: its configuration.
    steps: number of steps.
    controls: optional accelerations, `[steps, n, 2]` or `[n, 2]`.
    driven: the controls do work, so the energy bound does not apply (reported n/a).

  Returns:
    A dict of figures (see `common_cells`), plus `final` and `traj` for case-specific
    measures.
  """
  u = None if controls is None else jnp.asarray(controls, world.pos.dtype)
  key = (cfg, steps, jax.tree.structure(world), tuple(x.shape for x in jax.tree.leaves(world)),
         None if u is None else u.shape)
  t0 = time.perf_counter()
  if SHARED is not None and key in SHARED:  # `--smoke`: the same program as a case before.
    compiled = SHARED[key]
  else:
    compiled = jax.jit(lambda w, u: jc.rollout(w, cfg, steps, u)).lower(world, u).compile()
    if SHARED is not None:
      SHARED[key] = compiled
  compile_s = time.perf_counter() - t0
  t0 = time.perf_counter()
  final, traj = jax.block_until_ready(compiled(world, u))
  run_s = time.perf_counter() - t0

  pos, vel = np.asarray(traj.pos), np.asarray(traj.vel)
  pos0, vel0 = np.asarray(world.pos), np.asarray(world.vel)
  code = int(final.status)
  non_finite = bool(code & status.NON_FINITE) or not (np.all(np.isfinite(pos)) and np.all(np.isfinite(vel)))
  active, inv_mass = np.asarray(world.active), np.asarray(world.inv_mass)
  movable = active & (inv_mass > 0)
  still = active & (inv_mass == 0) & ~np.any(vel0 != 0, -1)
  immovable_moved = float(np.max(np.abs(pos[:, still] - pos0[still]), initial=0.0))
  pen = np.asarray(penetrations(world, traj.pos), np.float64)
  pen0 = float(metrics.max_penetration(world))
  g = (0.0 - float(world.gravity[1])) if cfg.has_gravity else 0.0  # 0.0 - keeps -0.0 out.
  mass = np.where(movable, 1 / np.where(movable, inv_mass, 1), 0.0)
  e = energy(mass, np.concatenate([pos0[None], pos]), np.concatenate([vel0[None], vel]), g)
  gain = np.diff(e)  # gain[k]: energy added by step k.
  bound = g * mass.sum() * np.r_[pen0, pen[:-1]]  # Lifting what the previous step left sunk.
  excess = gain - bound
  worst = int(np.argmax(excess))
  tolerance = 1e-4 * (1 + np.abs(e[1:]))  # The tests' float tolerance.
  return dict(
      final=final, traj=traj, steps=steps, depth=cfg.depth, substeps=cfg.substeps, dt=cfg.dt,
      compile_s=compile_s, run_s=run_s, pen_max=float(pen.max()), pen_final=float(pen[-1]),
      pen_step=int(np.argmax(pen)), non_finite=non_finite, immovable_moved=immovable_moved,
      drift=float(np.max(np.abs(pos[-1][movable] - pos0[movable]), initial=0.0)),
      gain_max=float(gain.max()), gain_bound=float(bound[int(np.argmax(gain))]),
      excess_max=float(excess[worst]), excess_step=worst, driven=driven,
      energy_ok=bool(np.all(excess <= tolerance)), status=code, messages=check_messages(final))


def energy_verdict(r: dict) -> str:
  if r["driven"]:
    return "n/a (driven)"
  if r["energy_ok"]:
    return "ok"
  return f"**EXCEEDS** (step {r['excess_step']})"


COMMON_HEADER = ("max pen | final pen | non-finite | immovable moved | max dE/step | bound at that step "
                 "| max (dE - bound) | energy | status | compile s | run s")


def common_cells(r: dict) -> str:
  return (f"{r['pen_max']:.3g} | {r['pen_final']:.3g} | {'**yes**' if r['non_finite'] else 'no'} | "
          f"{r['immovable_moved']:.3g} | {r['gain_max']:.3g} | {r['gain_bound']:.3g} | "
          f"{r['excess_max']:.3g} | {energy_verdict(r)} | {bit_names(r['status'])} | "
          f"{r['compile_s']:.2f} | {r['run_s']:.2f}")


def table(first: str, rows: list[tuple[str, dict]]) -> list[str]:
  """A Markdown table: the case-specific leading cells, then the common ones."""
  cols = first.count("|") + 1 + COMMON_HEADER.count("|") + 1
  lines = [f"| {first} | {COMMON_HEADER} |", "|" + "---|" * cols]
  lines += [f"| {lead} | {common_cells(r)} |" for lead, r in rows]
  return lines


# --- Cases ---------------------------------------------------------------------------


def depth_configs(world: jc.World, height: int, **overrides) -> list[tuple[jc.Config, str]]:
  """The config `Config.for_world` picks and, if its depth is below `height` (the
  longest chain the case builds), also one with `depth=height`, labelled."""
  cfg = jc.Config.for_world(world, **overrides)
  out = [(cfg, "for_world")]
  if cfg.depth < height:
    out.append((jc.Config.for_world(world, depth=height, **overrides), "override"))
  return out


def mass_ratio_cases(steps: int, bar, ratios=RATIOS, height: int = 20) -> list[tuple[str, dict]]:
  """Stacks of 20 with alternating masses 1 and `ratio`, friction 0.5, at the depth
  `Config.for_world` picks (and at depth 20 if that is less)."""
  rows = []
  for ratio in ratios:
    masses = np.where(np.arange(height) % 2 == 0, 1.0, ratio)
    world = scenes.stack(height, overlaps=0.0, masses=masses).world(friction=0.5)
    for cfg, label in depth_configs(world, height):
      r = run_case(world, cfg, steps)
      r.update(label=label, height=height)
      rows.append((f"{ratio:g} | {cfg.depth} ({label}) | {r['drift']:.3g}", r))
    bar.update()
  return rows


def tall_stack_case(steps: int, bar, height: int = 100) -> list[tuple[str, dict]]:
  """A stack of 100 unit boxes on a floor, depth 100, friction 0.5."""
  world = scenes.stack(height, overlaps=0.0).world(friction=0.5)
  r = run_case(world, jc.Config.for_world(world, depth=height), steps)
  r.update(label="override", height=height)
  bar.update()
  return [(f"{height} | {r['depth']} | {r['drift']:.3g}", r)]


def chain_world(length: int = 256) -> tuple[jc.World, float]:
  """A player (body 0) touching a row of `length` unit boxes on a floor, an immovable
  wall touching the last box, friction 0.3. Returns the world and the wall's inner face."""
  x = np.arange(length + 1, dtype=float)  # Player at 0, boxes at 1..length.
  face = length + 0.5
  pos = np.r_[np.stack([x, np.full(length + 1, 0.5)], -1), [[face + 0.5, 2.0]], [[face / 2, -0.5]]]
  half = np.r_[np.full((length + 1, 2), 0.5), [[0.5, 2.0]], [[face / 2 + 2, 0.5]]]
  mass = np.r_[np.ones(length + 1), INF, INF]
  return jc.World.create(pos, half, mass, friction=0.3), face


def chain_cases(steps: int, bar, length: int = 256) -> list[tuple[str, dict]]:
  """The player pushed at +20 along +x into 256 boxes against a wall, gravity, a floor,
  friction 0.3; at the depth `Config.for_world` picks (and at 257, the player and
  every box, if that is less)."""
  world, face = chain_world(length)
  controls = np.zeros((world.num_bodies, 2), np.float32)
  controls[0, 0] = 20.0
  rows = []
  boxes = slice(1, length + 1)
  for cfg, label in depth_configs(world, length + 1):
    r = run_case(world, cfg, steps, controls, driven=True)
    right = np.asarray(r["traj"].pos)[:, boxes, 0] + 0.5
    intrusion = float(np.max(right - face))
    moved = float(np.max(np.abs(np.asarray(r["final"].pos)[boxes] - np.asarray(world.pos)[boxes])))
    r.update(intrusion=intrusion, label=label, height=length + 1)
    rows.append((f"{cfg.depth} ({label}) | {cfg.broadphase} | {intrusion:.3g} | {moved:.3g}", r))
  bar.update()
  return rows


def far_case(steps: int, bar) -> tuple[list[tuple[str, dict]], float]:
  """Five boxes of half-size 1e-3 stacked on a floor around (1e4, 1e4), float32."""
  ulp = float(np.spacing(np.float32(1e4)))
  y = 1e4 + 1e-3 + 2e-3 * np.arange(5)
  pos = np.r_[[[1e4, 1e4 - 0.5]], np.stack([np.full(5, 1e4), y], -1)]
  half = np.r_[[[1.0, 0.5]], np.full((5, 2), 1e-3)]
  world = jc.World.create(pos, half, np.r_[INF, np.ones(5)], friction=0.3)
  r = run_case(world, jc.Config.for_world(world), steps)
  bar.update()
  lead = f"5 x 1e-3 at (1e4, 1e4) | {r['substeps']} | {r['pen_max'] / ulp:.2f} | {r['drift'] / ulp:.2f}"
  return [(lead, r)], ulp


def dt_cases(steps: int, bar, dts=DTS) -> list[tuple[str, dict]]:
  """A resting stack of 10, friction 0.5, for each dt; at the `for_world` depth (and
  at depth 10 if that is less)."""
  world = scenes.stack(10, overlaps=0.0).world(friction=0.5)
  rows = []
  for dt in dts:
    for cfg, label in depth_configs(world, 10, dt=dt):
      r = run_case(world, cfg, steps)
      r.update(label=label, height=10)
      rows.append((f"{dt:.4g} | {cfg.depth} ({label}) | {cfg.substeps} | {steps * dt:.3g} | "
                   f"{r['drift']:.3g}", r))
    bar.update()
  return rows


def bullet(speed: float) -> jc.World:
  """A unit box at x=0 flying at `speed` toward a wall 0.1 thick (centre x=3.05), no
  gravity."""
  return jc.World.create([[0.0, 0.0], [3.05, 0.0]], [[0.5, 0.5], [0.05, 2.0]], [1.0, INF],
                         vel=[[speed, 0.0], [0.0, 0.0]], gravity=(0.0, 0.0))


def tunnel_cases(steps: int, bar, speeds=SPEEDS, forcing=(False, True)) -> list[tuple[str, dict]]:
  """The bullet at every speed, substeps from `Config.for_world` and forced to 1; no
  gravity."""
  rows = []
  for speed in speeds:
    world = bullet(speed)
    for forced in forcing:
      extra = dict(substeps=1) if forced else {}
      cfg = jc.Config.for_world(world, **extra)
      r = run_case(world, cfg, steps)
      x = np.asarray(r["traj"].pos)[:, 0, 0]
      per_sub = speed * cfg.dt / cfg.substeps
      passed = float(x[-1]) > 3.05
      label = "forced 1" if forced else "for_world"
      r.update(speed=speed, passed=passed, forced=forced, safe=per_sub < 0.55)
      lead = (f"{speed:g} | {cfg.substeps} ({label}) | {per_sub:.3f} | {'yes' if per_sub < 0.55 else '**no**'} | "
              f"{x.max():.4g} | {x[-1]:.4g} | {abs(float(r['final'].vel[0, 0])):.4g} | "
              f"{'**yes**' if passed else 'no'} | "
              f"{'set' if r['status'] & status.FAST_BODY else '-'}")
      rows.append((lead, r))
      bar.update()
  return rows


# --- The soak ------------------------------------------------------------------------


def soak(batch: int, steps: int, seed: int = 0) -> dict:
  """The platformer room in `batch` worlds (box masses per world), the player pushed
  by random piecewise-constant accelerations for `steps` steps, friction 0.3.

  Rolled out in compiled chunks of `SOAK_CHUNK` steps; each chunk returns only
  reductions (per-step max penetration and speed per world, which bodies left the
  room, finiteness, immovable motion), so memory stays small.
  """
  rng = np.random.default_rng(seed)
  layouts = [scenes.platformer(rng) for _ in range(batch)]
  room = layouts[0]
  worlds = jc.stack([p.scene.world(friction=0.3) for p in layouts])
  cfg = jc.Config.for_world(worlds)
  n = worlds.num_bodies
  sp, sh = room.scene.pos, room.scene.half
  lo = np.array([sp[2, 0] + sh[2, 0], sp[0, 1] + sh[0, 1]])  # Left wall's and floor's inner faces.
  hi = np.array([sp[3, 0] - sh[3, 0], sp[1, 1] - sh[1, 1]])  # Right wall's and ceiling's.
  segments = -(-steps // SOAK_HOLD)
  angle = rng.uniform(0, 2 * np.pi, (batch, segments))
  push = SOAK_PUSH * rng.uniform(0, 1, (batch, segments))
  accel = np.stack([push * np.cos(angle), push * np.sin(angle)], -1).astype(np.float32)  # [B, S, 2]
  chunk = min(SOAK_CHUNK, steps)
  if steps % chunk:
    raise SystemExit(f"soak: steps ({steps}) must be a multiple of {chunk}")

  def one(w, u, p0):
    final, traj = jc.rollout(w, cfg, chunk, u)
    depth = jax.vmap(lambda p: metrics.penetration(w.replace(pos=p)))(traj.pos)  # [C, n, n]
    flat = depth.reshape(chunk, -1)
    pen, pair = jnp.max(flat, -1), jnp.argmax(flat, -1)  # [C]: worst pair per step.
    fixed = ~w.movable
    walls = jnp.where(fixed[:, None] | fixed[None], depth, 0.0).reshape(chunk, -1)
    intrusion, wall_pair = jnp.max(walls, -1), jnp.argmax(walls, -1)  # [C]
    mov = w.movable[None, :, None]
    speed = jnp.max(jnp.where(mov, jnp.abs(traj.vel), 0.0), axis=(1, 2))  # [C]
    low, high = (jnp.asarray(x, traj.pos.dtype) for x in (lo - ROOM_TOL, hi + ROOM_TOL))
    out = (traj.pos < low) | (traj.pos > high)
    left = jnp.any(jnp.any(out, -1) & w.movable[None], axis=0)  # [n]
    finite = jnp.all(jnp.isfinite(traj.pos)) & jnp.all(jnp.isfinite(traj.vel))
    still = (w.active & ~w.movable)[None, :, None]
    moved = jnp.max(jnp.where(still, jnp.abs(traj.pos - p0[None]), 0.0))
    return final, pen, pair, intrusion, wall_pair, speed, left, ~finite, moved

  run = jax.jit(jax.vmap(one))
  controls = jnp.zeros((batch, chunk, n, 2), jnp.float32)
  t0 = time.perf_counter()
  compiled = run.lower(worlds, controls, worlds.pos).compile()
  compile_s = time.perf_counter() - t0

  world, pos0 = worlds, worlds.pos
  pens, pairs, intrusions, wall_pairs, speeds = [], [], [], [], []
  left = np.zeros((batch, n), bool)
  non_finite = np.zeros(batch, bool)
  immovable_moved = 0.0
  run_s = 0.0
  for start in tqdm(range(0, steps, chunk), desc="soak", unit="chunk", file=sys.stderr):
    u = np.zeros((batch, chunk, n, 2), np.float32)
    u[:, :, room.player] = accel[:, np.arange(start, start + chunk) // SOAK_HOLD]
    u = jnp.asarray(u)
    t0 = time.perf_counter()
    world, pen, pair, intrusion, wall_pair, speed, gone, bad, moved = jax.block_until_ready(
        compiled(world, u, pos0))
    run_s += time.perf_counter() - t0
    pens.append(np.asarray(pen))
    pairs.append(np.asarray(pair))
    intrusions.append(np.asarray(intrusion))
    wall_pairs.append(np.asarray(wall_pair))
    speeds.append(np.asarray(speed))
    left |= np.asarray(gone)
    non_finite |= np.asarray(bad)
    immovable_moved = max(immovable_moved, float(np.nan_to_num(np.max(np.asarray(moved)), nan=np.inf)))

  pen = np.concatenate(pens, axis=1)  # [B, T]
  speed = np.concatenate(speeds, axis=1)
  codes = np.asarray(world.status)
  non_finite |= (codes & status.NON_FINITE) != 0
  # The tests' default bound: the distance a body travels in one step, here with the
  # largest push on top of gravity.
  g = -float(np.min(np.asarray(worlds.gravity)[:, 1]))
  speed_in = np.concatenate([np.zeros((batch, 1)), speed[:, :-1]], axis=1)
  travel = (speed_in + (g + SOAK_PUSH) * cfg.dt) * cfg.dt
  worst = np.unravel_index(np.nanargmax(pen), pen.shape)
  pair = np.concatenate(pairs, axis=1)
  intrusion = np.concatenate(intrusions, axis=1)
  ratio = pen / travel
  over = np.unravel_index(np.nanargmax(ratio), ratio.shape)
  names = body_names(room, n)
  i, j = divmod(int(pair[over]), n)
  worst_ratio = dict(world=int(over[0]), step=int(over[1]), pen=float(pen[over]), bound=float(travel[over]),
                     ratio=float(ratio[over]), pair=f"{names[i]} and {names[j]}",
                     before=float(pen[over[0], over[1] - 1]) if over[1] else 0.0)
  i, j = divmod(int(pair[worst]), n)
  worst_pair = f"{names[i]} and {names[j]}"
  deepest = np.unravel_index(np.nanargmax(intrusion), intrusion.shape)
  i, j = divmod(int(np.concatenate(wall_pairs, axis=1)[deepest]), n)
  intrusion_at = f"world {deepest[0]}, step {deepest[1]}, {names[i]} and {names[j]}"
  return dict(
      batch=batch, steps=steps, n=n, depth=cfg.depth, substeps=cfg.substeps, broadphase=cfg.broadphase,
      compile_s=compile_s, run_s=run_s, world_steps_per_s=batch * steps / run_s,
      pen_max=float(np.nanmax(pen)), pen_worst=(int(worst[0]), int(worst[1])), worst_pair=worst_pair,
      bound_at_worst=float(travel[worst]), worst_ratio=worst_ratio,
      intrusion_max=float(np.nanmax(intrusion)), intrusion_at=intrusion_at,
      intrusion_final=float(np.nanmax(intrusion[:, -1])),
      pen_p999=float(np.nanpercentile(pen, 99.9)), pen_p99=float(np.nanpercentile(pen, 99)),
      pen_median=float(np.nanmedian(pen)), pen_final=float(np.nanmax(pen[:, -1])),
      over_1e3=int(np.sum(pen > 1e-3)), over_travel=int(np.sum(pen > travel + 1e-6)),
      travel_max=float(travel.max()), speed_max=float(np.nanmax(speed)),
      left=int(left.sum()), left_worlds=int(left.any(1).sum()), non_finite=int(non_finite.sum()),
      immovable_moved=immovable_moved, codes=codes, messages=check_messages(world),
      pen_all=pen.ravel(), ratio_all=ratio.ravel(),
      lo=lo, hi=hi)


def body_names(room: scenes.Platformer, n: int) -> list[str]:
  """Readable names of the platformer's bodies, by index."""
  names = ["floor", "ceiling", "left wall", "right wall"] + [f"body {k}" for k in range(4, n)]
  names[room.player] = "player"
  for k, b in enumerate(room.row):
    names[b] = f"row box {k + 1}"
  stack_first = int(max(room.row)) + 1
  for b in range(stack_first, n):
    names[b] = f"stack box {b - stack_first + 1}"
  return names


# --- Report --------------------------------------------------------------------------


def main():
  parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
  parser.add_argument("--quick", action="store_true", help="soak of 8 worlds for 2000 steps")
  args = add_common_args(parser).parse_args()
  run = _bench.Run.start()
  soak_batch, soak_steps = (8, 2000) if args.quick else (64, 10_000)
  # `--smoke`: every case once, small and short (the tables' titles keep the full sizes).
  steps, ratios, dts, speeds, tall, chain = 2000, RATIOS, DTS, SPEEDS, 100, 256
  if args.smoke:
    global SHARED
    SHARED = {}
    soak_batch, soak_steps = 2, 10
    # Stacks of 10 throughout: one shape, so the penetration measure compiles once.
    steps, ratios, dts, speeds, tall, chain = 10, RATIOS[-1:], DTS[2:3], SPEEDS[-1:], 10, 4
  groups = {}
  n_runs = len(ratios) + 1 + 1 + 1 + len(dts) + len(speeds) * (1 if args.smoke else 2)
  with tqdm(total=n_runs, desc="cases", unit="run", file=sys.stderr) as bar:
    groups["ratio"] = mass_ratio_cases(steps, bar, ratios, height=10 if args.smoke else 20)
    groups["tall"] = tall_stack_case(steps, bar, tall)
    groups["chain"] = chain_cases(steps // 2, bar, chain)
    groups["far"], ulp = far_case(steps, bar)
    groups["dt"] = dt_cases(steps, bar, dts)
    groups["tunnel"] = tunnel_cases(min(steps, 60), bar, speeds,
                                    forcing=(True,) if args.smoke else (False, True))
  s = soak(soak_batch, soak_steps)
  write(groups, ulp, s, run, out_dir(args))


def write(groups: dict, ulp: float, s: dict, run, out) -> None:
  lines = [
      "# Stability: stiff and extreme cases over long runs",
      "",
      "Every case is measured after every step. *pen*: largest penetration between "
      "resolvable pairs (`metrics.max_penetration`). *non-finite*: the `NON_FINITE` bit or a "
      "NaN/inf in the trajectory. *immovable moved*: largest displacement of an immovable body "
      "at rest (must be exactly 0). *dE/step*: energy (kinetic + potential, float64 from the "
      "float32 trajectory) gained in one step; *bound*: `g * total movable mass * penetration "
      "after the previous step` (lifting what the previous step left sunk); *energy ok* when "
      "`dE - bound <= 1e-4 (1 + |E|)` at every step (the tests' float tolerance). *drift*: "
      "largest displacement of a movable body from its start at the end. *status*: the "
      "status bits set at the end (sticky), decoded below the tables with `jc.check`. "
      "Steps are counted from 0. Compile time is apart from run time. dt = 1/60 s unless stated.",
      "",
      "## 1. Mass ratios: stacks of 20, masses alternating 1 and the ratio, friction 0.5, 2000 steps",
      "",
  ]
  lines += table("mass ratio | depth | drift", groups["ratio"])
  lines += ["", "## 2. A stack of 100, depth 100 (override), friction 0.5, 2000 steps", ""]
  lines += table("height | depth | drift", groups["tall"])
  lines += [
      "", "## 3. A chain of 256 boxes pushed into a wall, 1000 steps", "",
      "A player (unit box, mass 1) touching a row of 256 touching unit boxes on a floor, an "
      "immovable wall touching the last box; the player is pushed with a constant acceleration "
      "of 20 along +x, gravity, friction 0.3. *intrusion*: the largest, over steps and boxes, of "
      "box right edge minus the wall's inner face (> 0 is inside the wall). *boxes moved*: the "
      "largest displacement of a box at the end. The controls do work, so the energy bound "
      "does not apply.", ""]
  lines += table("depth | broadphase | wall intrusion | boxes moved", groups["chain"])
  lines += [
      "", "## 4. Far coordinates in float32, friction 0.3, 2000 steps", "",
      f"Five boxes of half-size 1e-3 stacked on a floor around (1e4, 1e4); float32 spacing "
      f"there is 1 ulp = `np.spacing(np.float32(1e4))` = {ulp:.4g}, so a box is about 2 ulps tall "
      f"and its position is rounded to whole ulps (the initial overlaps are rounding, and cannot "
      f"be resolved below an ulp).{far_note(groups['far'][0][1])}",
      ""]
  lines += table("scene | substeps | max pen in ulps | drift in ulps", groups["far"])
  lines += ["", "## 5. dt sweep: a resting stack of 10, friction 0.5, 2000 steps each", ""]
  lines += table("dt | depth | substeps | simulated s | drift", groups["dt"])
  lines += [
      "", "## 6. Tunnelling: a unit box fired at a wall 0.1 thick, no gravity, 60 steps", "",
      "The box starts at x=0, the wall's centre is at x=3.05 (faces at 3.0 and 3.1). A body "
      "cannot tunnel while it moves, per substep, less than its half-extent plus the thinnest "
      "body's: `|v| * dt / substeps < half_box + half_wall = 0.5 + 0.05 = 0.55`. "
      "`Config.for_world` picks substeps from the initial speeds (plus one step of gravity, "
      "none here) with a 1.25 safety factor. "
      "*passed*: the final centre x is beyond the wall's centre. Max x <= 2.5 means stopped at "
      "the wall. A box that tunnels is pushed out on the far side of the wall (or, while its "
      "centre has not crossed the wall's, back); *final speed* shows what the velocity "
      "update made of it (velocities come from contact impulses, not from the push, so a "
      "tunnelling box gains no speed).", ""]
  lines += table("speed | substeps | travel per substep | < 0.55 | max x | final x | final speed | passed | FAST_BODY",
                 groups["tunnel"])
  codes = s["codes"]
  bits = {name: int(np.sum((codes & bit) != 0)) for bit, name in BIT_NAMES.items()}
  bit_text = "; ".join(f"{name} in {k}: worlds {', '.join(map(str, np.flatnonzero(codes & bit)[:10]))}"
                       f"{' ...' if k > 10 else ''}"
                       for bit, name in BIT_NAMES.items() if (k := bits[name])) or "none"
  w = s["worst_ratio"]
  lines += [
      "", f"## 7. Soak: the platformer room, {s['batch']} worlds x {s['steps']} steps", "",
      f"`scenes.platformer` (closed room: floor, ceiling, walls; player, a row of 4 boxes, a "
      f"stack of 5; box masses drawn per world), {s['n']} bodies, friction 0.3, depth {s['depth']}, "
      f"substeps {s['substeps']}, {s['broadphase']} broadphase. The player is pushed by a random "
      f"piecewise-constant acceleration: magnitude uniform in [0, {SOAK_PUSH:g}], direction uniform, "
      f"both resampled every {SOAK_HOLD} steps, different per world. Rolled out in compiled "
      f"chunks of {min(SOAK_CHUNK, s['steps'])} steps; penetration and room membership are checked "
      f"after every step. Room interior: x in [{s['lo'][0]:g}, {s['hi'][0]:g}], y in "
      f"[{s['lo'][1]:g}, {s['hi'][1]:g}]; a body has *left* when its centre is more than "
      f"{ROOM_TOL:g} outside. *travel bound*: `(largest speed after the previous step + (g + "
      f"{SOAK_PUSH:g}) dt) dt`, the distance a body can move in one step (the tests' default "
      f"penetration bound).", "",
      "| measure | value |",
      "|---|---|",
      f"| world-steps | {s['batch'] * s['steps']:,} |",
      f"| worst penetration (all steps, all worlds) | {s['pen_max']:.3g} (world {s['pen_worst'][0]}, "
      f"step {s['pen_worst'][1]}, {s['worst_pair']}; travel bound there {s['bound_at_worst']:.3g}) |",
      f"| worst penetration into the floor, ceiling or walls | {s['intrusion_max']:.3g} "
      f"({s['intrusion_at']}; after the last step: {s['intrusion_final']:.3g}) |",
      f"| penetration 99.9th / 99th percentile / median | {s['pen_p999']:.3g} / {s['pen_p99']:.3g} / "
      f"{s['pen_median']:.3g} |",
      f"| worst penetration after the last step | {s['pen_final']:.3g} |",
      f"| world-steps with penetration > 1e-3 | {s['over_1e3']} |",
      f"| world-steps over the travel bound | {s['over_travel']} (largest bound {s['travel_max']:.3g}) |",
      f"| largest penetration / travel bound | {w['ratio']:.2f}x: {w['pen']:.3g} vs {w['bound']:.3g} "
      f"(world {w['world']}, step {w['step']}, {w['pair']}; penetration after the step before: "
      f"{w['before']:.3g}) |",
      f"| fastest movable body | {s['speed_max']:.3g} units/s |",
      f"| bodies that left the room | {s['left']} (in {s['left_worlds']} worlds) |",
      f"| worlds with non-finite state | {s['non_finite']} |",
      f"| immovable bodies moved | {s['immovable_moved']:.3g} |",
      f"| worlds with status bits | {int(np.sum(codes != 0))} of {s['batch']} ({bit_text}) |",
      f"| compile s | {s['compile_s']:.2f} |",
      f"| run s | {s['run_s']:.2f} |",
      f"| world-steps/s (with the per-step checks) | {s['world_steps_per_s']:.3g} |",
      "",
      "Share of world-steps above a penetration (left) and above a multiple of the travel "
      "bound (right):",
      "",
      "![soak penetration distribution](stability.png)",
  ]
  messages = set()
  for group in groups.values():
    for _, r in group:
      messages |= r["messages"]
  messages |= s["messages"]
  lines += ["", "## Status messages seen (`jc.check`)", ""]
  lines += [f"- {m}" for m in sorted(messages)] or ["- none"]
  lines += ["", "## Bounds", "", bounds_paragraph(groups, ulp, s)]
  _bench.write_result(out, "stability.md", lines, run, echo=False)
  plot(s, out)
  print("\n".join(lines))


def far_note(r: dict) -> str:
  if not r["status"] & status.FAST_BODY:
    return ""
  g, dt = 9.81, r["dt"] / r["substeps"]
  return (f" FAST_BODY is set although the boxes rest: gravity alone carries a resting box "
          f"`g h^2` = {g * dt * dt:.2g} into the box below in one substep h = {dt:.3g} s, more than its "
          f"half-extent plus the thinnest body's (2e-3), and `Config.for_world` picked "
          f"{r['substeps']} substep(s) from the (zero) initial speeds.")


def bounds_paragraph(groups: dict, ulp: float, s: dict) -> str:
  """The observed bounds, in words."""
  rows = [r for g in groups.values() for _, r in g]
  stacks = [r for g in ("ratio", "tall", "dt") for _, r in groups[g]]
  exact = [r for r in stacks if r["depth"] >= r["height"]]
  short = [r for r in stacks if r["depth"] < r["height"]]
  short_bad = [r for r in short if r["status"] & status.DEPTH_EXHAUSTED]
  picked = sorted({r["depth"] for g in ("ratio", "chain", "dt") for _, r in groups[g] if r["label"] == "for_world"})
  undriven = [r for r in rows if not r["driven"]]
  energy_bad = [r for r in undriven if not r["energy_ok"]]
  chain = {r["depth"]: r["intrusion"] for _, r in groups["chain"]}
  far = groups["far"][0][1]
  tunnel = groups["tunnel"]
  through_sub = [f"{r['speed']:g}" for _, r in tunnel if not r["forced"] and r["passed"]]
  through_one = [f"{r['speed']:g}" for _, r in tunnel if r["forced"] and r["passed"]]
  flagged = all(r["status"] & status.FAST_BODY for _, r in tunnel if r["passed"] or not r["safe"])
  parts = [
      f"Over {len(rows)} case runs and the soak: "
      f"non-finite state in {sum(r['non_finite'] for r in rows) + s['non_finite']}; immovable bodies "
      f"moved by at most {max([r['immovable_moved'] for r in rows] + [s['immovable_moved']]):.3g}.",
      f"`Config.for_world` picked depths {', '.join(map(str, picked))} for the stacks of 20 and 10 "
      f"and the chain of 256.",
      f"Stacks with depth at least their height ({len(exact)} runs: 20, 10 and 100 high, every "
      f"mass ratio and dt) kept penetration at most {max(r['pen_max'] for r in exact):.3g} and "
      f"drifted at most {max(r['drift'] for r in exact):.3g}." if exact else "",
      f"With depth below the stack height {len(short_bad)} of {len(short)} stack runs set "
      f"DEPTH_EXHAUSTED and kept up to {max(r['pen_max'] for r in short):.3g} of penetration."
      if short else "",
      "Energy never grew beyond lifting the previous step's penetration in any undriven run"
      if not energy_bad else
      f"**Energy grew beyond the bound in {len(energy_bad)} undriven runs**, "
      f"{sum(bool(r['status'] & status.FAST_BODY) for r in energy_bad)} of them flagged FAST_BODY",
      f"(largest dE - bound {max(r['excess_max'] for r in undriven):.3g}; see the tables).",
      "The chain of 256 entered the wall by at most "
      + " and ".join(f"{v:.3g} at depth {k}" for k, v in sorted(chain.items(), reverse=True)) + ".",
      f"Tiny boxes at 1e4 in float32 stayed within {far['pen_max'] / ulp:.2f} ulps of penetration.",
      f"Tunnelling: with `for_world` substeps the box "
      f"{'passed through at speeds ' + ', '.join(through_sub) if through_sub else 'never passed through'}; "
      f"with one substep it {'passed through at speeds ' + ', '.join(through_one) if through_one else 'never did'}"
      + ("; every run over the speed limit set FAST_BODY." if flagged
         else "; FAST_BODY was NOT set on every run over the limit."),
      f"Soak ({s['batch']} x {s['steps']} world-steps): worst penetration {s['pen_max']:.3g} "
      f"(into the floor, ceiling or walls {s['intrusion_max']:.3g}), "
      f"{s['over_travel']} world-steps over the one-step travel bound (at most "
      f"{s['worst_ratio']['ratio']:.2f}x it), {s['left']} bodies left the room, "
      f"{s['non_finite']} worlds went non-finite.",
  ]
  return " ".join(p for p in parts if p)


def plot(s: dict, out) -> None:
  """Soak: the share of world-steps whose penetration (left) and penetration over the
  one-step travel bound (right) exceed a value."""
  import matplotlib
  matplotlib.use("Agg")
  import matplotlib.pyplot as plt
  fig, axes = plt.subplots(1, 2, figsize=(10, 4))
  for ax, values, label in ((axes[0], s["pen_all"], "penetration after a step"),
                            (axes[1], s["ratio_all"], "penetration / one-step travel bound")):
    v = np.sort(values[np.isfinite(values) & (values > 0)])
    ax.set_xlabel(label)
    if not v.size:  # Nothing to draw on log axes: no world-step had any penetration.
      ax.text(0.5, 0.5, "no penetration in any world-step", ha="center", transform=ax.transAxes)
      continue
    share = (len(v) - np.arange(len(v))) / len(values)  # Share of all world-steps >= v[k].
    ax.step(v, share, where="post")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.grid(True, which="both", alpha=0.3)
  axes[1].axvline(1.0, color="k", lw=0.8, ls="--")
  axes[0].set_ylabel("share of world-steps above")
  fig.suptitle(f"jaxchain soak: platformer, {s['batch']} worlds x {s['steps']} steps, random pushes")
  fig.tight_layout()
  fig.savefig(out / "stability.png", dpi=120)


if __name__ == "__main__":
  main()
