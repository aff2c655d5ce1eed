"""Where a step's time goes: stage-by-stage costs, measured by taking stages away.

Each row times one jitted function of the batch-minor core over a batch of settled worlds (compile
excluded, median of repeats): the broadphase and contacts alone, then with the link
table, then the resolver passes at depth 0 with positions only and with the contact
impulses, at full depth, with friction, and the full step. Differences between rows are
the stages' costs. Scenes: the peers room (N unit boxes settled in a closed room,
friction 0.5 on every body, `Config.for_world`, as in `peers.py`) and the demo platformer.

Below the stages, the XLA operations of the full step by their share of its run time,
from a `jax.profiler` trace of XLA:CPU's thunks (each a fused loop, a gather or a
matrix product), named by the jax operation XLA fused the others into. Shares of one
trace do not depend on how busy the machine is, unlike the stage rows. Writes
`results/profile.md`.

    python benchmarks/profile_step.py            # about 2 minutes on 2 cores
    python benchmarks/profile_step.py --batch 256
    python benchmarks/profile_step.py --smoke --out /tmp/x   # room of 8, B=2: runs, writes
"""

from __future__ import annotations

import argparse
import collections
import glob
import pathlib
import re
import tempfile
import time

import jax
import jax.numpy as jnp
from tqdm import tqdm

import jaxchain as jc
from jaxchain import core
import _bench
from _bench import add_common_args, demo_world, out_dir, room_world



def stages(cfg: jc.Config) -> dict:
  """Name -> function of a batch (`[B, n, ...]` World), each a superset of the one before;
  the core's stages on its batch-minor layout (one transpose in, as a step has)."""
  shallow = cfg.replace(depth=0)

  def pair_stage(w, table=False):
    state, bodies = core.from_world(w)
    cand, _ = core.pairs.candidates(state.pos, bodies, cfg)
    c = core.contacts.contacts(state.pos, bodies.half, cand, cfg.skin, start=state.pos,
                               surface=bodies.fixed if cfg.immovable else None)
    if not table:
      return c.code, c.overlap  # What the link table reads.
    f = core.contacts.link_table(c, cand, cfg.links, rows=bodies.movable)[0]
    return jnp.sum(f.overlap), jnp.sum(f.mask)

  quiet = cfg.replace(friction=False)

  def passes(config, with_vel):
    def fn(w):
      state, bodies = core.from_world(w)
      pos, vel = core.step.passes(bodies, state.pos, config, start=state.pos,
                                  vel=state.vel if with_vel else None)[:2]
      return pos if vel is None else (pos, vel)  # Return what a stage makes: no dead code.
    return fn

  return {
      "broadphase + contacts": pair_stage,
      "+ link table": lambda w: pair_stage(w, table=True),
      "resolver, depth 0, positions only": passes(shallow.replace(friction=False), False),
      "resolver, depth 0, with contact impulses": passes(shallow.replace(friction=False), True),
      f"resolver, depth {cfg.depth}, with contact impulses": passes(quiet, True),
      f"+ friction (depth {cfg.depth})": passes(cfg, True),
      "step (integration, status)": lambda w: jc.step(w, cfg),
  }


def scene_worlds(name: str, batch: int, settle: int = 120) -> tuple[jc.World, jc.Config]:
  """`batch` copies of a settled scene: `room<N>` (the room of N boxes) or the demo."""
  if name.startswith("room"):
    world, cfg = room_world(int(name[4:]), settle)  # Settled: the boxes fall and stack.
  else:
    world, cfg = demo_world(60)
  return jc.stack([world] * batch), cfg


def op_shares(compiled, worlds, top: int = 12, calls: int = 3) -> tuple[float, list]:
  """The XLA:CPU operations of the compiled call `compiled(worlds)` by run time, from
  a profiler trace.

  Returns:
    `(total_s, rows)`: op time per call summed over threads, and `(name, jax op, share)`
    for the `top` largest.
  """
  from jax._src import profiler as jax_profiler  # ProfileData reads the trace; no public path.

  jax.block_until_ready(compiled(worlds))
  with tempfile.TemporaryDirectory() as tmp:
    with jax.profiler.trace(tmp):
      for _ in range(calls):
        jax.block_until_ready(compiled(worlds))
    trace = glob.glob(f"{tmp}/**/*.xplane.pb", recursive=True)[0]
    data = jax_profiler.ProfileData.from_serialized_xspace(pathlib.Path(trace).read_bytes())
  ns = collections.Counter()
  for plane in data.planes:
    for line in plane.lines:
      if not line.name.startswith("tf_XLA"):
        continue
      for ev in line.events:  # Thunks; the executor's and loops' own spans contain them.
        if not ev.name.startswith(("ThunkExecutor", "while", "conditional", "call")):
          ns[ev.name] += ev.duration_ns
  hlo = compiled.as_text()

  def jax_op(name):
    m = re.search(r"\n\s*%?" + re.escape(name) + r" = [^\n]*op_name=\"([^\"]+)\"", hlo)
    return m.group(1).rsplit("/", 1)[-1] if m else "-"

  total = sum(ns.values())
  return total / calls * 1e-9, [(k, jax_op(k), v / total) for k, v in ns.most_common(top)]


def main():
  parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
  parser.add_argument("--batch", type=int, default=1024, help="worlds per batch")
  parser.add_argument("--repeats", type=int, default=7)
  args = add_common_args(parser).parse_args()
  scenes_ = ["room64", "platformer"]
  if args.smoke:  # One small room, unsettled; every stage and the trace still run.
    args.batch, args.repeats, scenes_ = 2, 1, ["room8"]
  run = _bench.Run.start()
  tables = {}
  for name in tqdm(scenes_, desc="scenes", unit="scene"):
    worlds, cfg = scene_worlds(name, args.batch, settle=0 if args.smoke else 120)
    compiled = {}
    for stage, fn in stages(cfg).items():
      t0 = time.perf_counter()
      compiled[stage] = jax.jit(fn).lower(worlds).compile()
      compiled_s = time.perf_counter() - t0
      jax.block_until_ready(compiled[stage](worlds))  # Warm-up.
      compiled[stage] = (compiled[stage], compiled_s)
    # Rounds interleave the stages, so slow drift in the machine hits them all alike.
    times = _bench.rounds({stage: _bench.wall(fn, worlds) for stage, (fn, _) in compiled.items()},
                          args.repeats)
    rows = [(stage, times.median(stage), compiled[stage][1]) for stage in compiled]
    full = compiled[list(compiled)[-1]][0]  # The full step, as compiled for its row.
    tables[name] = (cfg, int(worlds.pos.shape[1]), rows,
                    op_shares(full, worlds, calls=1 if args.smoke else 3))
  write(tables, args, run)


def write(tables, args, run) -> None:
  lines = [
      "# Where a step's time goes",
      "",
      f"Each row: one jitted call of the batch-minor core over {args.batch} identical settled worlds, "
      f"median of {args.repeats} rounds that time every stage once in turn, compile excluded. Each row adds stages to the one before, "
      "so the difference is what a stage costs.",
  ]
  for name, (cfg, n, rows, ops) in tables.items():
    step_s = rows[-1][1]
    lines += [
        "",
        f"## {name}: {n} bodies, {args.batch} worlds",
        "",
        f"Config (`for_world`): depth {cfg.depth}, links {cfg.links}, {cfg.broadphase}, "
        f"iterations {cfg.iterations}, substeps {cfg.substeps}, friction {'on' if cfg.friction else 'off'}. "
        f"Full step: {step_s * 1e3:.1f} ms, {args.batch * n / step_s:.3g} body-steps/s.",
        "",
        "| stage | ms per step | added by this stage | share of the step | compile s |",
        "|---|---|---|---|---|",
    ]
    before = 0.0
    for stage, sec, compile_s in rows:
      added = sec - before
      lines.append(f"| {stage} | {sec * 1e3:.2f} | {added * 1e3:+.2f} | {added / step_s:.0%} | "
                   f"{compile_s:.2f} |")
      before = sec
    total_s, top = ops
    lines += ["", f"XLA operations of the full step (trace: {total_s * 1e3:.1f} ms of op time per "
              f"call, summed over threads; the largest {len(top)}):", "",
              "| XLA op | jax op it computes | share |", "|---|---|---|"]
    lines += [f"| `{op}` | `{jax_name}` | {share:.1%} |" for op, jax_name, share in top]
  lines += [
      "",
      "Reading the rows: the link table is the compaction of contacts into `[links, 4, n, B]`;",
      "the contact impulses are the velocity channel of the push hops plus the K hops that",
      "turn it into link impulses and friction units; `depth K` adds the hops beyond depth 0",
      "(backing K, push K + 1 with two channels, impulses K); friction adds its K transport",
      "hops on the same link table (no second contacts stage); the step adds integration and",
      "the status bits.",
      "Differences smaller than the run-to-run noise (a few percent) can come out negative.",
  ]
  _bench.write_result(out_dir(args), "profile.md", lines, run)


if __name__ == "__main__":
  main()
