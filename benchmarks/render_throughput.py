"""Render throughput: frames/s of `jc.render` on batches of worlds, against the
previous formulation measured in the same run.

For each scene, image size (64 x 64, and `render`'s default 96 x 160) and batch size
B (1, 64, 1024): one jitted call `jc.render(worlds, size, bounds, player=0)` on a
batch of B worlds (leading axis mapped by `render`), compile measured apart
(ahead-of-time `lower().compile()`), then the median of repeated calls, wall clock
and CPU time of this process (all threads: on a loaded machine the CPU time per
frame moves much less than the wall time).

The baseline is the formulation `render` had before (8ca4e3e .. f55f53b): the same
layers composited by a `lax.scan` over the bodies, each step blending one body into
the whole `[H, W, 3]` float image (under `vmap` the scan carries every frame of the
batch, so each body streams the whole batch's images through memory). The new one
composites up to `drawing.GROUP` (20) bodies in one fused pass, each pixel held in
registers through the chain (`drawing._over`), and on an AVX-512 CPU it is compiled
with `drawing.CPU_OPTIONS` (512-bit vectors for its own compiled function, what a
direct `jc.render` call does; timed here compiled ahead of time with those options);
the baseline is compiled as it was, with XLA's defaults. Both give the same pixels
(checked).

Scenes: `sokoban3` (18 bodies, 3 goal sensors) padded to 20 slots, as the push_box
env holds it, one pass; a closed room of 64 boxes (68 bodies,
`scenes.lattice_room`), four passes of 17. Movable bodies jittered per world.

    python benchmarks/render_throughput.py                    # about 7 minutes on 2 cores
    python benchmarks/render_throughput.py --smoke --out /tmp/r   # tiny: runs, writes

A second table times the first scene again in a fresh process with
`XLA_FLAGS=--xla_cpu_prefer_vector_width=512`, so that the baseline gets 512-bit vectors
too (the gain of the formulation alone), and checks that the pixels are the same.

Formulations tried on this machine before choosing (2 cores, load 15-20, CPU time per
frame, B = 1024, 64 x 64, 20 slots unless said; ratios against the baseline in the
same run): the baseline's scan chunked by `lax.map` over 64 frames 1.5-2x; a
variadic `lax.reduce` with the associative "over" monoid 0.6-0.8x (XLA:CPU does not
vectorise it); one fused pass of 20 bodies 3.7-4.3x; passes of 10 bodies inside a
`lax.scan` 1.7-2.5x, and at 68 bodies passes of 8-14 as slow as the baseline (the
scan's dynamic index lands inside the fused pass; reading the group with a static
index from rolled tables fixes it: 2.2x); one fused pass of 36 or 68 bodies 1.0-1.2x
(too long a chain). Outer-product matmuls per channel (`[H, n] @ [n, W]`) sum the
layers instead of compositing them: exact only for disjoint bodies, so not used.
"""

from __future__ import annotations

import argparse
import dataclasses
import hashlib
import json
import os
import pathlib
import subprocess
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np

import jaxchain as jc
from _bench import Run, add_common_args, out_dir, write_result
from jaxchain import drawing

SIZES = ((64, 64), (96, 160))
BATCHES = (1, 64, 1024)
SLOTS = 20
# The XLA flag of the second table: XLA:CPU vectorises for 256-bit registers by default;
# on an AVX-512 machine this lets it use 512-bit ones (a process-wide choice, the user's:
# jaxchain never sets flags).
WIDE = "--xla_cpu_prefer_vector_width=512"


def level_batch(batch: int, seed: int = 0):
  """`batch` copies of sokoban3 in 20 slots (2 inactive), movable bodies jittered."""
  lv = jc.levels.load("sokoban3")
  n = lv.num_bodies
  pad = lambda x, v: np.concatenate([x, np.full((SLOTS - n,) + x.shape[1:], v, x.dtype)])
  world = lv.world(pos=pad(lv.pos, 0.0), half=pad(lv.half, 0.5), mass=pad(lv.mass, 1.0),
                   vel=pad(lv.vel, 0.0), friction=pad(lv.friction, 0.0),
                   one_way=pad(lv.one_way, False), sensor=pad(lv.sensor, False),
                   category=pad(lv.category, 1), mask=pad(lv.mask, 1),
                   active=np.arange(SLOTS) < n)
  return _jitter(world, batch, seed), np.asarray(lv.bounds, np.float32)


def room_batch(batch: int, seed: int = 0):
  """`batch` copies of a closed room of 64 boxes (68 bodies), boxes jittered."""
  scene = jc.scenes.lattice_room(64)
  world = jc.World.create(scene.pos, scene.half, scene.mass)
  return _jitter(world, batch, seed), np.asarray(drawing.bounds_of(world))


def _jitter(world, batch, seed):
  rng = np.random.default_rng(seed)
  stacked = jax.tree.map(lambda x: np.stack([np.asarray(x)] * batch), world)
  pos = np.array(stacked.pos)
  movable = (np.asarray(world.inv_mass) > 0) & np.asarray(world.active)
  pos[:, movable] += rng.uniform(-0.2, 0.2, (batch, int(movable.sum()), 2)).astype(pos.dtype)
  return dataclasses.replace(stacked, pos=pos)


SCENES = {"sokoban3, 20 slots": level_batch, "room of 64 boxes, 68 slots": room_batch}


def baseline(world, size, bounds, player=0, palette=drawing.PALETTE):
  """The previous formulation: a `lax.scan` over the layers, each blended into the
  whole image; `vmap`ped over the batch."""
  h, w = size

  def one(world):
    layers = drawing._layers(world, jnp.asarray(bounds), player, h=h, w=w, antialias=True,
                             keep_aspect=True, palette=palette)

    def blend(image, layer):
      pa, pb, cx, cb, rgb = layer
      alpha = pa[:, None] * cx[None, :] - pb[:, None] * cb[None, :]
      return image + alpha[..., None] * (rgb[None, None, :] - image), None

    start = jnp.broadcast_to(jnp.asarray(palette.background, world.pos.dtype), (h, w, 3))
    image, _ = jax.lax.scan(blend, start, layers)
    return jnp.round(jnp.clip(image, 0.0, 255.0)).astype(jnp.uint8)

  return jax.vmap(one)(world)


def timed(fns: dict, args, repeats: int) -> dict:
  """name -> (compile s, median wall s, median CPU s, result); calls interleaved.
  `fns`: name -> (function, compile options)."""
  compiled, out, results = {}, {}, {}
  for name, (fn, options) in fns.items():
    t0 = time.perf_counter()
    compiled[name] = jax.jit(fn, compiler_options=options or None).lower(*args).compile()
    out[name] = [time.perf_counter() - t0, [], []]
    results[name] = jax.block_until_ready(compiled[name](*args))
  for _ in range(repeats):
    for name, fn in compiled.items():
      wall, cpu = time.perf_counter(), time.process_time()
      jax.block_until_ready(fn(*args))
      out[name][1].append(time.perf_counter() - wall)
      out[name][2].append(time.process_time() - cpu)
  return {k: (c, float(np.median(w)), float(np.median(p)), results[k])
          for k, (c, w, p) in out.items()}


def setting(scene: str, size, batch: int, repeats: int) -> dict:
  world, bounds = SCENES[scene](batch)
  # `render` as a direct call compiles itself with `drawing.CPU_OPTIONS`; here it is
  # compiled ahead of time (to time the compile apart), with the same options.
  fns = {"render": (lambda w: jc.render(w, size, bounds, player=0), dict(drawing.CPU_OPTIONS)),
         "baseline": (lambda w: baseline(w, size, bounds), None)}
  t = timed(fns, (world,), repeats)
  (c_new, w_new, p_new, new), (c_old, w_old, p_old, old) = t["render"], t["baseline"]
  same = np.abs(np.asarray(new).astype(int) - np.asarray(old).astype(int)).max()
  return dict(scene=scene, size=list(size), batch=batch, bodies=world.num_bodies,
              digest=hashlib.sha256(np.asarray(new).tobytes()).hexdigest(),
              passes=drawing._groups(world.num_bodies)[0], compile_s=c_new, compile_old_s=c_old,
              fps=batch / w_new, fps_old=batch / w_old, cpu_fps=batch / p_new,
              cpu_fps_old=batch / p_old, max_diff=int(same))


def main():
  parser = argparse.ArgumentParser(description=__doc__,
                                   formatter_class=argparse.RawDescriptionHelpFormatter)
  add_common_args(parser)
  parser.add_argument("--repeats", type=int, default=5, help="timed calls per setting")
  parser.add_argument("--wide", action="store_true",
                      help="internal: the second table's run (started by the script itself with "
                           "XLA_FLAGS=" + WIDE + "); prints its rows as JSON")
  args = parser.parse_args()
  first = next(iter(SCENES))
  plan = [(scene, size, batch) for scene in SCENES for size in SIZES for batch in BATCHES]
  if args.wide:
    plan = [p for p in plan if p[0] == first]
  repeats = args.repeats
  if args.smoke:
    plan, repeats = [(first, (16, 16), 2)], 1
  run = Run.start()
  rows = []
  for scene, size, batch in plan:
    rows.append(setting(scene, size, batch, repeats))
    r = rows[-1]
    print(f"{scene}, {size[0]}x{size[1]}, B={batch}: {r['fps']:.3g} frames/s "
          f"({r['fps'] / r['fps_old']:.2f}x baseline), {r['cpu_fps']:.3g} frames/CPU-s "
          f"({r['cpu_fps'] / r['cpu_fps_old']:.2f}x)", file=sys.stderr if args.wide else sys.stdout,
          flush=True)
  if args.wide:
    print(json.dumps(rows))
    return
  wide = wide_rows(args, repeats)
  write(rows, wide, args, run)


def wide_rows(args, repeats) -> list[dict]:
  """The first scene's settings again in a fresh process with `XLA_FLAGS` += `WIDE`."""
  env = dict(os.environ, XLA_FLAGS=(os.environ.get("XLA_FLAGS", "") + " " + WIDE).strip())
  command = [sys.executable, __file__, "--wide", "--repeats", str(repeats)]
  out = subprocess.run(command + (["--smoke"] if args.smoke else []), env=env, check=True,
                       stdout=subprocess.PIPE, text=True)
  return json.loads(out.stdout.strip().splitlines()[-1])


def _table(rows, plain=None) -> list[str]:
  """Markdown rows; with `plain` (the default-flag rows), whether each frame batch had
  the same pixels as without the flag."""
  head = ("| scene | H x W | B | passes | compile s | frames/s | baseline frames/s | ratio | "
          "frames / CPU-s | baseline | ratio | max diff |")
  rule = "|---|---|---|---|---|---|---|---|---|---|---|---|"
  if plain is not None:
    head, rule = head + " same pixels as without the flag |", rule + "---|"
    plain = {(r["scene"], tuple(r["size"]), r["batch"]): r["digest"] for r in plain}
  lines = [head, rule]
  for r in rows:
    line = (f"| {r['scene']} | {r['size'][0]} x {r['size'][1]} | {r['batch']} | {r['passes']} | "
            f"{r['compile_s']:.1f} | {r['fps']:.3g} | {r['fps_old']:.3g} | "
            f"{r['fps'] / r['fps_old']:.2f} | {r['cpu_fps']:.3g} | {r['cpu_fps_old']:.3g} | "
            f"{r['cpu_fps'] / r['cpu_fps_old']:.2f} | {r['max_diff']} |")
    if plain is not None:
      key = (r["scene"], tuple(r["size"]), r["batch"])
      line += f" {'yes' if plain.get(key) == r['digest'] else 'NO'} |"
    lines.append(line)
  return lines


def _avx512() -> bool:
  try:
    return "avx512f" in pathlib.Path("/proc/cpuinfo").read_text()
  except OSError:
    return False


def write(rows, wide, args, run: Run) -> None:
  flags = os.environ.get("XLA_FLAGS")
  lines = [
      "# Render throughput (`jc.render`)",
      "",
  ] + ([f"Run with `XLA_FLAGS='{flags}'`.", ""] if flags else []) + [
      "Timed: one jitted `jc.render(worlds, size, bounds, player=0)` on a batch of B worlds, "
      f"compiled with `drawing.CPU_OPTIONS` ({dict(drawing.CPU_OPTIONS)}: what a direct call "
      "uses); compile apart; median of interleaved calls, wall clock and CPU time of the "
      "process. Baseline: the previous renderer (a `lax.scan` over the bodies blending each "
      "into the whole image, vmapped), same layers, XLA's default options, timed in the same "
      "run; 'max diff' is the largest difference of a colour channel between the two (0: the "
      "same pixels).",
      "",
  ] + _table(rows) + [
      "",
      f"Both with 512-bit vectors: the first scene again, in a fresh process with "
      f"`XLA_FLAGS={WIDE}`, so that the baseline gets them too and the ratio is the "
      f"formulation's alone (XLA:CPU vectorises for 256-bit registers unless told; this "
      f"machine {'has' if _avx512() else 'does not have'} AVX-512). The pixels are checked "
      f"against the run without the flag.",
      "",
  ] + _table(wide, rows)
  lines += ["", "Frames / CPU-s: frames per second of CPU time summed over the process's "
            "threads, which moves much less with the machine's load than the wall clock does. "
            "On a quiet machine the wall-clock rate is about this figure times the number of "
            "cores a call keeps busy (1 to 2 here)."]
  write_result(out_dir(args), "render_throughput.md", lines, run)


if __name__ == "__main__":
  main()
