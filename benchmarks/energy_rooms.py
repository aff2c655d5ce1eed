"""Energy in random closed rooms (issue 18, item 6): where a step gains energy, and how much.

Seeded random rooms: an 8 x 8 interior closed by four immovable walls, 4-16 boxes at
random places that neither overlap nor touch (half-extents and speeds per setting),
masses 0.1 to 100 (log-uniform), friction 0 to 1 per body, gravity. Each setting runs
`B` rooms for `T` steps in one vmapped, jitted rollout and measures, in float64 on the
host, the energy `E = sum 0.5 m |v|^2 + m |g| y` of the movable bodies after every
step and `jc.metrics.max_penetration` before it:

- steps that start without overlap (`max_penetration <= 1e-5`, the README's claim):
  how many, and the largest gain beyond the tests' float32 tolerance (16 ulps of every
  term; `tests/test_dynamics.py::energy_tolerance`), which must be `<= 0`;
- steps that start with overlap (left by the step before: a pass finds contacts at its
  start): how many, the largest gain, and the largest ratio of a gain to the bound
  `|g| * (movable mass) * (penetration at the start)`;
- every stretch from one overlap-free state to the next: the largest energy change
  over it (beyond the tolerance at its start), which must be `<= 0`.

    python benchmarks/energy_rooms.py            # 40 rooms x 90 steps per setting, minutes
    python benchmarks/energy_rooms.py --smoke    # 2 rooms x 10 steps: the code path only
"""

from __future__ import annotations

import argparse
import time

import jax
import jax.numpy as jnp
import numpy as np

import jaxchain as jc
import _bench

INF = np.inf
G = 9.81
EPS32 = float(np.finfo(np.float32).eps)
CAPACITY = 20  # 4 walls + up to 16 boxes.
# (name, seed, half-extent range, speed, Config keywords)
SETTINGS = (
    ("sizes 0.2-0.6, speeds to 6", 0, (0.2, 0.6), 6.0, dict(depth=12)),
    ("sizes 0.3-1.0, speeds to 10", 9, (0.3, 1.0), 10.0, dict(depth=12)),
    ("sizes 0.2-0.6, speeds to 6, iterations=2", 0, (0.2, 0.6), 6.0, dict(depth=12, iterations=2)),
)


def room(rng: np.random.Generator, halves: tuple[float, float], speed: float) -> jc.World:
  """One random closed room, padded to `CAPACITY`."""
  n = int(rng.integers(4, 17))
  pos, half = [], []
  while len(pos) < n:  # Rejection sampling: no two boxes overlap or touch.
    h = rng.uniform(*halves, 2)
    c = rng.uniform(h, 8.0 - h)
    if all(np.any(np.abs(c - p) >= h + q) for p, q in zip(pos, half)):
      pos.append(c)
      half.append(h)
  mass = 10 ** rng.uniform(-1, 2, n)
  vel = rng.uniform(-speed, speed, (n, 2))
  mu = rng.uniform(0, 1, n + 4)
  walls_pos = [[4.0, -0.5], [4.0, 8.5], [-0.5, 4.0], [8.5, 4.0]]
  walls_half = [[5.0, 0.5], [5.0, 0.5], [0.5, 5.0], [0.5, 5.0]]
  world = jc.World.create(walls_pos + [list(p) for p in pos], walls_half + [list(h) for h in half],
                          [INF] * 4 + list(mass), vel=[[0.0, 0.0]] * 4 + vel.tolist(), friction=mu)
  return world.pad(CAPACITY)


def measure(name, seed, halves, speed, kw, rooms: int, steps: int) -> dict:
  rng = np.random.default_rng(seed)
  worlds = [room(rng, halves, speed) for _ in range(rooms)]
  batch = jc.stack(worlds)
  cfg = jc.Config(**kw)
  t0 = time.perf_counter()
  _, traj = jax.jit(jax.vmap(lambda w: jc.rollout(w, cfg, steps, record=("status",))))(batch)
  pos = jnp.concatenate([batch.pos[:, None], traj.pos], axis=1)  # [b, t + 1, n, 2]

  def pen_of(w, p):
    return jax.vmap(lambda q: jc.metrics.max_penetration(w.replace(pos=q)))(p)
  pen = np.asarray(jax.jit(jax.vmap(pen_of))(batch, pos), np.float64)
  seconds = time.perf_counter() - t0
  inv = np.asarray(batch.inv_mass, np.float64)
  m = np.where(inv > 0, 1.0 / np.where(inv > 0, inv, 1.0), 0.0) * np.asarray(batch.active)
  p = np.asarray(pos, np.float64)
  v = np.concatenate([np.asarray(batch.vel)[:, None], np.asarray(traj.vel)], axis=1).astype(np.float64)
  mm = m[:, None, :]
  energy = np.sum(0.5 * mm * np.sum(v * v, -1) + mm * G * p[..., 1], axis=-1)  # [b, t + 1]
  tol = 16 * EPS32 * np.sum(mm * (G * (np.abs(p[..., 1]) + 1.0) + np.sum(v * v + 1e-2, -1)), -1)
  gain = np.diff(energy, axis=1)
  clean = pen[:, :-1] <= 1e-5
  over = gain - tol[:, :-1]
  bound = G * np.sum(m, axis=1)[:, None] * pen[:, :-1]
  ratio = np.where(~clean, (gain - tol[:, :-1]) / np.where(clean, 1.0, bound), -np.inf)
  window = -np.inf
  for b in range(rooms):
    ok = np.flatnonzero(pen[b] <= 1e-5)
    for a, c in zip(ok[:-1], ok[1:]):
      if c > a + 1:
        window = max(window, energy[b, c] - energy[b, a] - tol[b, a])
  status = np.asarray(traj.status)[:, -1]
  return {
      "setting": name, "rooms x steps": f"{rooms} x {steps}",
      "clean starts": str(int(clean.sum())),
      "max gain beyond tol, clean start (J)": f"{np.max(np.where(clean, over, -np.inf)):+.2e}",
      "overlapping starts": str(int((~clean).sum())),
      "max gain, overlapping start (J)": (f"{np.max(np.where(clean, -np.inf, gain)):+.3g}"
                                          if (~clean).any() else "-"),
      "max gain / (g M pen)": f"{np.max(ratio):.3f}" if (~clean).any() else "-",
      "max dE between overlap-free states (J)": f"{window:+.3g}" if np.isfinite(window) else "-",
      "worlds with status bits": str(int(np.sum(status != 0))),
      "run s": f"{seconds:.0f}",
  }


def main():
  parser = argparse.ArgumentParser(description=__doc__,
                                   formatter_class=argparse.RawDescriptionHelpFormatter)
  args = _bench.add_common_args(parser).parse_args()
  run = _bench.Run.start()
  rooms, steps = (2, 10) if args.smoke else (40, 90)
  settings = SETTINGS[:1] if args.smoke else SETTINGS
  rows = [measure(*s, rooms=rooms, steps=steps) for s in settings]
  cols = list(rows[0])
  lines = ["# Energy in random closed rooms", "",
           __doc__.split("\n\n")[1].replace("\n", " "), "", __doc__.split("\n\n")[2], "",
           "| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
  lines += ["| " + " | ".join(r[c] for c in cols) + " |" for r in rows]
  _bench.write_result(_bench.out_dir(args), "energy_rooms.md", lines, run)


if __name__ == "__main__":
  main()
