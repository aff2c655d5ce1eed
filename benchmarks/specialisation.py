"""What each feature costs on the demo scene, and so what `Config.for_world` saves.

The demo scene (`scenes.platformer`, 14 bodies, walls, friction 0.3) is stepped in a
batch of worlds with the config `Config.for_world` picks, then with one feature
switched on or made bigger at a time: immovable tracking off vs on is not a choice
here (the room has walls), so the scene-free variants are timed on the same bodies
with the walls made movable. Each variant is timed as a jitted, vmapped 20-step
rollout, compile excluded; variants are measured in interleaved rounds and each
reported as a ratio to the lean config measured in the same round (the machines are
noisy). Writes `results/specialisation.md`.

    python benchmarks/specialisation.py [--batch 256] [--rounds 5]
    python benchmarks/specialisation.py --smoke --out /tmp/x   # lean only, B=2: runs, writes
"""

from __future__ import annotations

import argparse
import statistics

import jax
import jax.numpy as jnp
import numpy as np
from tqdm import tqdm

import jaxchain as jc
from jaxchain import broadphase, scenes
import _bench
from _bench import add_common_args, out_dir

STEPS = 20
# `--smoke` compiles only these (every variant's config is still built and checked).
SMOKE_VARIANTS = ("lean (for_world)",)


def build(batch: int):
  rng = np.random.default_rng(0)
  layouts = [scenes.platformer(rng) for _ in range(batch)]
  worlds = jc.stack([p.scene.world(friction=0.3) for p in layouts])
  controls = np.zeros(worlds.pos.shape, np.float32)
  controls[:, layouts[0].player, 0] = 20.0
  return worlds, jnp.asarray(controls)


def variants(worlds) -> dict[str, tuple[jc.Config, object]]:
  lean = jc.Config.for_world(worlds)
  free = worlds.replace(inv_mass=jnp.where(worlds.active, jnp.maximum(worlds.inv_mass, 1e-3), 0.0))
  lean_free = jc.Config.for_world(free)
  frictionless = worlds.replace(friction=jnp.zeros_like(worlds.friction))
  top_down = worlds.replace(gravity=jnp.zeros_like(worlds.gravity))
  n = worlds.num_bodies
  body = jnp.arange(n)
  # Issue 12's features, used: the floor is a one-way platform (first body), one box
  # (body n - 1) is a sensor, and the player's layer ignores the last box.
  used = worlds.replace(one_way=jnp.broadcast_to(body == 0, worlds.active.shape),
                        sensor=jnp.broadcast_to(body == n - 1, worlds.active.shape),
                        mask=jnp.where(body == n - 2, jnp.uint32(1), worlds.mask).astype(jnp.uint32),
                        category=jnp.where(body == n - 3, jnp.uint32(2),
                                           worlds.category).astype(jnp.uint32))
  lean_used = jc.Config.for_world(used)
  assert lean_used.one_way and lean_used.sensors and lean_used.layers, lean_used
  return {
      "lean (for_world)": (lean, worlds),
      "one-way traced, unused": (lean.replace(one_way=True), worlds),
      "layers traced, unused": (lean.replace(layers=True), worlds),
      "sensors traced, unused": (lean.replace(sensors=True), worlds),
      "one-way, layers and sensors used (for_world)": (lean_used, used),
      "friction off": (lean.replace(friction=False), frictionless),
      "gravity off (top-down scene)": (lean.replace(gravity=False), top_down),
      "substeps 2": (lean.replace(substeps=2), worlds),
      "iterations 2": (lean.replace(iterations=2), worlds),
      f"depth 32 (for_world picks {lean.depth})": (lean.replace(depth=32), worlds),
      "grid instead of dense": (lean.replace(broadphase="grid", grid=broadphase.allocate(worlds)), worlds),
      "no walls, immovable tracking off (for_world)": (lean_free, free),
      "no walls, immovable tracking on": (lean_free.replace(immovable=True), free),
  }


def main():
  parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
  parser.add_argument("--batch", type=int, default=256)
  parser.add_argument("--rounds", type=int, default=5)
  args = add_common_args(parser).parse_args()
  run = _bench.Run.start()
  if args.smoke:
    args.batch, args.rounds = 2, 1
  worlds, controls = build(args.batch)
  compiled = {}
  todo = variants(worlds)
  if args.smoke:
    todo = {name: todo[name] for name in SMOKE_VARIANTS}
  for name, (cfg, w) in tqdm(todo.items(), desc="compile", unit="variant"):
    fn = jax.jit(jax.vmap(lambda w, u, cfg=cfg: jc.rollout(w, cfg, STEPS, u)[0]))
    compiled[name] = (fn.lower(w, controls).compile(), w)
    jax.block_until_ready(compiled[name][0](w, controls))
  with tqdm(total=args.rounds * len(compiled), desc="rounds", unit="call") as bar:
    measured = _bench.rounds({name: _bench.wall(fn, w, controls) for name, (fn, w) in compiled.items()},
                             args.rounds, lambda *_: bar.update())
  times = {name: [t / STEPS for t in ts] for name, ts in measured.figures.items()}
  write(times, args.batch, out_dir(args), run)


def write(times: dict[str, list[float]], batch: int, out, run) -> None:
  base = times["lean (for_world)"]
  lines = [
      "# What each feature costs on the demo scene",
      "",
      f"`scenes.platformer` (14 bodies), {batch} worlds, jitted vmapped "
      f"{STEPS}-step rollouts, compile excluded. Ratio = variant / lean config, per round "
      "(interleaved), median over rounds.",
      "",
      "| variant | ms / batched step (median) | ratio to lean | world-steps/s |",
      "|---|---|---|---|",
  ]
  for name, ts in times.items():
    ratios = [t / b for t, b in zip(ts, base)]
    med = statistics.median(ts)
    lines.append(f"| {name} | {med * 1e3:.3f} | {statistics.median(ratios):.2f}x | {batch / med:.3g} |")
  lines += [
      "",
      "Ratios above 1 are what the lean config saves by leaving the feature out. The",
      "\"no walls\" rows use the same bodies with the walls made movable (mass 1000), so",
      "that switching off immovable tracking is allowed; they compare with each other.",
  ]
  _bench.write_result(out, "specialisation.md", lines, run)


if __name__ == "__main__":
  main()
