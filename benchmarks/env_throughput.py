"""Environment throughput: env-steps/s of the `jaxchain.env` tasks under a random policy.

For each task (push_box, reach_flag) and batch size B (1, 64, 1024, 4096): a jitted
`lax.scan` of T steps of `jax.vmap(env.step)` (auto-reset included: every step also
builds the reset it may need), the actions drawn inside the scan from
`env.action_space(params).sample`, the envs' default params. Compile time is
measured apart (ahead-of-time `lower().compile()`), run time is the median of
repeated calls after a warm-up call. Also counted: episodes ended and solved (the
random policy's successes). Writes `results/env_throughput.md`.

    python benchmarks/env_throughput.py            # about 4 minutes on 2 cores
    python benchmarks/env_throughput.py --quick    # shorter calls, fewer repeats
    python benchmarks/env_throughput.py --smoke --out /tmp/x   # one task, B=2: runs, writes
"""

from __future__ import annotations

import argparse

import jax
import jax.numpy as jnp
import numpy as np
from tqdm import tqdm

import jaxchain as jc
from _bench import Run, add_common_args, compile_and_time, out_dir, write_result

TASKS = ("push_box", "reach_flag")
BATCHES = (1, 64, 1024, 4096)


def setting(task: str, batch: int, env_steps: int, repeats: int, min_steps: int = 10) -> dict:
  env, params = jc.env.make(task)
  space = env.action_space(params)
  steps = int(np.clip(env_steps // batch, min_steps, 1000))
  vstep = jax.vmap(env.step, in_axes=(0, 0, 0, None))
  obs, state = jax.vmap(env.reset, in_axes=(0, None))(
      jax.random.split(jax.random.key(0), batch), params)

  def run(key, obs, state):
    def body(carry, key):
      obs, state, ended, solved = carry
      k_act, k_step = jax.random.split(key)
      actions = jax.vmap(space.sample)(jax.random.split(k_act, batch))
      obs, state, _, done, info = vstep(jax.random.split(k_step, batch), state, actions, params)
      return (obs, state, ended + jnp.sum(done), solved + jnp.sum(info["success"])), None

    zero = jnp.zeros((), jnp.int32)
    (obs, state, ended, solved), _ = jax.lax.scan(body, (obs, state, zero, zero),
                                                  jax.random.split(key, steps))
    return obs, state, ended, solved

  (_, final, ended, solved), sec, compile_s = compile_and_time(
      run, jax.random.key(1), obs, state, repeats=repeats, budget_s=20.0)
  return dict(task=task, batch=batch, steps=steps, bodies=env.num_bodies, obs=env.obs_size,
              compile_s=compile_s, call_s=sec, env_steps=batch * steps / sec,
              ended=int(ended), solved=int(solved),
              status=int(np.bitwise_or.reduce(np.asarray(final.world.status).ravel())))


def main():
  parser = argparse.ArgumentParser(description=__doc__,
                                   formatter_class=argparse.RawDescriptionHelpFormatter)
  parser.add_argument("--quick", action="store_true",
                      help="about 4e4 env-steps per timed call (else 2e5), 2 repeats (else 3)")
  parser.add_argument("--tasks", nargs="+", default=list(TASKS), choices=jc.env.TASKS)
  parser.add_argument("--batches", type=int, nargs="+", default=list(BATCHES))
  args = add_common_args(parser).parse_args()
  env_steps, repeats = (40_000, 2) if args.quick else (200_000, 3)
  if args.smoke:
    # One task (the first asked for), 2 envs, 4 steps a call: the env's whole path, once.
    args.tasks, args.batches, env_steps, repeats = args.tasks[:1], [2], 8, 1
  run = Run.start()
  rows = []
  plan = [(t, b) for t in args.tasks for b in args.batches]
  with tqdm(plan, desc="env throughput", unit="setting") as bar:
    for task, batch in bar:
      bar.set_postfix(task=task, B=batch)
      rows.append(setting(task, batch, env_steps, repeats, min_steps=4 if args.smoke else 10))
  write(rows, args, run)


def write(rows, args, run: Run) -> None:
  lines = [
      "# Environment throughput (random policy)",
      "",
      "Timed: a jitted `lax.scan` of T steps of `jax.vmap(env.step)` over B envs (auto-reset "
      "included), random actions from `env.action_space(params).sample` drawn inside the scan, "
      "default params; median of repeated calls after a warm-up call, compile apart. "
      "Episodes ended / solved: counted over one call (the random policy's successes).",
      "",
      "| task | B | bodies | obs | T | compile s | s / call | env-steps/s | episodes ended | "
      "solved | status |",
      "|---|---|---|---|---|---|---|---|---|---|---|",
  ]
  for r in rows:
    lines.append(f"| {r['task']} | {r['batch']} | {r['bodies']} | {r['obs']} | {r['steps']} | "
                 f"{r['compile_s']:.1f} | {r['call_s']:.3f} | {r['env_steps']:.3g} | "
                 f"{r['ended']} | {r['solved']} | {r['status']} |")
  lines += ["", "Status: the OR of every world's status bits after the timed call (0: no failure "
            "bit; `jc.check` explains them)."]
  for task in dict.fromkeys(r["task"] for r in rows):
    one = [r for r in rows if r["task"] == task]
    best = max(one, key=lambda r: r["env_steps"])
    lines.append(f"- {task}: highest {best['env_steps']:.3g} env-steps/s at B={best['batch']}, "
                 f"{best['env_steps'] / one[0]['env_steps']:.1f}x the rate at B={one[0]['batch']}")
  write_result(out_dir(args), "env_throughput.md", lines, run)


if __name__ == "__main__":
  main()
