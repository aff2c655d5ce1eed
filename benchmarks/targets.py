"""Issue 27's speed targets that no other script measures, beside an earlier commit.

Each revision is exported with `git archive` (as `against.py` does) and measured in a
fresh interpreter whose only jaxchain is that tree; rounds alternate the trees, so slow
drift of a shared machine hits them alike, and each figure is the median over rounds of
the best of a few calls (compile apart). The working tree is `HEAD` plus uncommitted
changes (`--against` names the others; default `6272a46`, the last commit before the
batch-minor core). Figures:

- **env**: env-steps/s of `jax.jit(jax.vmap(env.step))` on platformer1
  (`jc.env.make("reach_flag", levels=["platformer1"])`, 13 bodies), B = 1024 envs, a
  jitted `lax.scan` of 20 steps with random actions (auto-reset included);
- **one world**: microseconds per call of `jc.make_step(cfg)` on one platformer1 world
  (the game loop: B = 1), each call waited for;
- **B=1024 / B=1**: the room of 64 (68 bodies, friction 0.5, `Config.for_world`), 30-step
  rollouts, body-steps/s at B = 1024 over B = 1 (`jax.vmap(rollout)`, which every
  version takes).

    python benchmarks/targets.py                          # HEAD beside 6272a46, 3 rounds
    python benchmarks/targets.py --against b26b41f --rounds 5
    python benchmarks/targets.py --smoke --out /tmp/x     # tiny sizes, HEAD only: runs, writes
"""

from __future__ import annotations

import argparse
import json
import os
import pathlib
import statistics
import subprocess
import sys
import tempfile

from _bench import ROOT, Run, add_common_args, export_src, out_dir, write_result


CHILD = r"""
import json, sys, time
import jax, jax.numpy as jnp, numpy as np
import jaxchain as jc

envs, steps, one_calls, batch = (int(x) for x in sys.argv[1:5])

def best(fn, repeats=3):
  jax.block_until_ready(fn())
  times = []
  for _ in range(repeats):
    t0 = time.perf_counter(); jax.block_until_ready(fn()); times.append(time.perf_counter() - t0)
  return min(times)

out = {}
# env-steps/s: a scan of `steps` steps of the vmapped env step, random actions.
env, params = jc.env.make("reach_flag", levels=["platformer1"])
keys = jax.random.split(jax.random.key(0), envs)
_, state = jax.jit(jax.vmap(env.reset, in_axes=(0, None)))(keys, params)
space = env.action_space(params)
vstep = jax.vmap(env.step, in_axes=(0, 0, 0, None))

@jax.jit
def run(state, key):
  def body(carry, k):
    state = carry
    acts = jax.vmap(space.sample)(jax.random.split(k, envs))
    _, state, reward, _, _ = vstep(jax.random.split(k, envs), state, acts, params)
    return state, reward
  return jax.lax.scan(body, state, jax.random.split(key, steps))

out["env_steps_per_s"] = envs * steps / best(lambda: run(state, jax.random.key(1)))

# One world, one step (the game loop).
world = jc.levels.load("platformer1").world(friction=0.3)
cfg = jc.Config.for_world(world)
step_fn = jc.make_step(cfg)
w = jax.block_until_ready(step_fn(world))
def calls():
  x = world
  for _ in range(one_calls):
    x = jax.block_until_ready(step_fn(x))
  return x
out["one_world_us"] = best(calls) / one_calls * 1e6

# The room of 64 at B = batch and B = 1.
s = jc.scenes.lattice_room(64, 0)
room = jc.World.create(s.pos, s.half, s.mass, friction=0.5)
rcfg = jc.Config.for_world(room)
roll = jax.jit(jax.vmap(lambda w: jc.rollout(w, rcfg, 30)[0].pos))
for b in (batch, 1):
  ws = jc.stack([room] * b)
  out[f"room_B{b}"] = b * 64 * 30 / best(lambda: roll(ws))
print("RESULT " + json.dumps(out))
"""


def measure(src: pathlib.Path, sizes: list[int]) -> dict:
  env = dict(os.environ, PYTHONPATH=str(src))
  done = subprocess.run([sys.executable, "-c", CHILD, *map(str, sizes)], env=env,
                        capture_output=True, text=True, cwd=tempfile.gettempdir(), timeout=1800)
  if done.returncode:
    raise RuntimeError(f"targets failed in {src}:\n{done.stdout[-2000:]}\n{done.stderr[-3000:]}")
  line = next(l for l in done.stdout.splitlines() if l.startswith("RESULT "))
  return json.loads(line[7:])


def main() -> None:
  parser = add_common_args(argparse.ArgumentParser(description=__doc__.split("\n")[0]))
  parser.add_argument("--against", nargs="*", default=["6272a46"], metavar="COMMIT")
  parser.add_argument("--rounds", type=int, default=3)
  args = parser.parse_args()
  sizes = [1024, 20, 200, 1024]  # envs, scan steps, one-world calls, room batch
  if args.smoke:
    args.against, args.rounds, sizes = [], 1, [4, 2, 5, 1]  # B = 1 twice: one room program.
  run = Run.start(src=ROOT / "src")
  trees = {"HEAD": ROOT / "src"}
  with tempfile.TemporaryDirectory() as tmp:
    for rev in args.against:
      trees[rev] = export_src(rev, pathlib.Path(tmp))
    runs = {name: [] for name in trees}
    for r in range(args.rounds):
      for name, src in trees.items():
        runs[name].append(measure(src, sizes))
        print(f"round {r} {name}: {runs[name][-1]}", flush=True)
  med = {name: {k: statistics.median(run[k] for run in rs) for k in rs[0]} for name, rs in runs.items()}
  batch = sizes[3]
  lines = ["# Issue 27 targets beside an earlier commit", "",
           f"Median over {args.rounds} alternating rounds of the best of 3 calls per figure, "
           "compile apart; each tree in a fresh interpreter.", "",
           "| figure | " + " | ".join(trees) + " | HEAD over each |", "|---|" + "---|" * (len(trees) + 1)]
  rows = [("env-steps/s, platformer1, B=1024, `jax.jit(jax.vmap(env.step))`", "env_steps_per_s", "{:,.0f}", False),
          ("one world (B=1), one `make_step` call, platformer1 (13 bodies), us", "one_world_us", "{:.0f}", True),
          (f"room of 64, body-steps/s at B={batch}", f"room_B{batch}", "{:,.0f}", False),
          ("room of 64, body-steps/s at B=1", "room_B1", "{:,.0f}", False)]
  for label, key, fmt, lower_better in rows:
    vals = [med[name][key] for name in trees]
    ratios = [(med[name][key] / med["HEAD"][key] if lower_better else med["HEAD"][key] / med[name][key])
              for name in trees if name != "HEAD"]
    lines.append(f"| {label} | " + " | ".join(fmt.format(v) for v in vals) + " | " +
                 (", ".join(f"{x:.2f}x" for x in ratios) or "-") + " |")
  scale = {name: med[name][f"room_B{batch}"] / med[name]["room_B1"] for name in trees}
  lines.append(f"| room of 64, B={batch} over B=1 throughput | " +
               " | ".join(f"{scale[n]:.1f}x" for n in trees) + " | - |")
  write_result(out_dir(args), "targets.md", lines, run)


if __name__ == "__main__":
  main()
