"""Stable-Baselines3's PPO on `jaxchain.bridges.SB3VecEnv`: env steps/s and success.

Measures, on one task:
1. Env throughput with random actions: `SB3VecEnv` (one jitted, vmapped step for the
   batch) against SB3's `DummyVecEnv` over `num_envs` `GymnasiumEnv`s (a jitted step
   per env, a Python loop), after a first reset and step (compile time reported apart).
2. PPO training (`PPO("MlpPolicy", VecMonitor(SB3VecEnv(...)))`): wall time, env-steps/s
   with the networks and updates included, and the learning curve (SB3's
   `rollout/ep_rew_mean` and `rollout/success_rate`, from the adapter's `is_success`).
3. A final evaluation of the trained policy on `--eval-episodes` fresh episodes, with
   the argmax action and with sampled actions; success = the episode ended with
   `is_success`.

    python benchmarks/ppo_sb3.py          # reach_flag on platformer1, shaping 0.1, 1M steps

Writes `ppo_sb3.md` (the table), `ppo_sb3_curve.csv` (one row per rollout) and
`ppo_sb3_curve.png` into `--out DIR` (default `benchmarks/results`). `--smoke`: 4 envs,
episodes of 64 steps, 2048 PPO steps. Needs the sb3 extra (`pip install -e ".[sb3]"`).
"""

from __future__ import annotations

import argparse
import csv
import time

import numpy as np
import stable_baselines3
import torch
from stable_baselines3 import PPO
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.vec_env import DummyVecEnv, VecMonitor

import _bench
import jaxchain as jc
from jaxchain import bridges


def _param(text: str):
  key, _, value = text.partition("=")
  try:
    return key, int(value)
  except ValueError:
    return key, float(value)


def throughput(venv, steps: int, seed: int = 0) -> tuple[float, float]:
  """`(first_step_s, steps_per_s)`: the first reset + step (compiles), then `steps`
  batched steps with random actions."""
  venv.seed(seed)
  rng = np.random.default_rng(seed)
  space = venv.action_space
  sample = lambda: np.stack([space.sample() for _ in range(venv.num_envs)])
  t0 = time.perf_counter()
  venv.reset()
  venv.step(sample())
  first = time.perf_counter() - t0
  actions = [sample() for _ in range(16)]
  t0 = time.perf_counter()
  for t in range(steps):
    venv.step(actions[t % 16])
  del rng
  return first, steps * venv.num_envs / (time.perf_counter() - t0)


class Curve(BaseCallback):
  """One row per rollout: timesteps, SB3's episode-return and success means (the last
  100 episodes), wall time."""

  FIELDS = ("timesteps", "return", "success", "episodes", "seconds")

  def __init__(self):
    super().__init__()
    self.rows, self.t0 = [], time.perf_counter()

  def _on_step(self) -> bool:
    return True

  def _on_rollout_end(self) -> None:
    eps = list(self.model.ep_info_buffer)
    succ = list(self.model.ep_success_buffer)
    self.rows.append({"timesteps": self.num_timesteps,
                      "return": float(np.mean([e["r"] for e in eps])) if eps else float("nan"),
                      "success": float(np.mean(succ)) if succ else float("nan"),
                      "episodes": len(eps), "seconds": time.perf_counter() - self.t0})


def evaluate(model, venv, seed: int, deterministic: bool = True) -> tuple[float, float]:
  """`(success_rate, mean_return)` of the policy (its mode when `deterministic`, else
  sampled) over the first episode of each env of `venv`."""
  episodes = venv.num_envs
  venv.seed(seed)
  obs = venv.reset()
  alive = np.ones(episodes, bool)
  ret = np.zeros(episodes)
  success = np.zeros(episodes, bool)
  while alive.any():
    action, _ = model.predict(obs, deterministic=deterministic)
    obs, reward, done, infos = venv.step(action)
    ret += np.where(alive, reward, 0.0)
    success |= alive & done & np.array([i["is_success"] for i in infos])
    alive &= ~done
  return float(success.mean()), float(ret.mean())


def main(argv=None) -> int:
  parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
  parser.add_argument("--env", default="reach_flag", choices=jc.env.TASKS)
  parser.add_argument("--level", default="platformer1")
  parser.add_argument("--param", type=_param, action="append", default=None, metavar="KEY=VALUE",
                      help="EnvParams override (default: shaping=0.1)")
  parser.add_argument("--num-envs", type=int, default=16)
  parser.add_argument("--n-steps", type=int, default=128)
  parser.add_argument("--timesteps", type=int, default=1_000_000)
  parser.add_argument("--lr", type=float, default=3e-4)
  parser.add_argument("--ent-coef", type=float, default=0.01,
                      help="PPO's entropy coefficient (SB3's default is 0)")
  parser.add_argument("--n-epochs", type=int, default=10)
  parser.add_argument("--throughput-steps", type=int, default=300)
  parser.add_argument("--eval-episodes", type=int, default=64)
  parser.add_argument("--seed", type=int, default=0)
  _bench.add_common_args(parser)
  args = parser.parse_args(argv)
  params_kw = dict(args.param if args.param is not None else [("shaping", 0.1)])
  if args.smoke:
    args.num_envs, args.n_steps, args.timesteps = 4, 64, 2048
    args.throughput_steps, args.eval_episodes = 10, 4
    params_kw["max_steps"] = 64
  run = _bench.Run.start()
  out = _bench.out_dir(args)
  torch.set_num_threads(1)  # The jitted env keeps the other core.
  kwargs = dict(params_kw)
  if args.level:
    kwargs["levels"] = [args.level]
  env, params = jc.env.make(args.env, **kwargs)
  machine = f"torch {torch.__version__}, stable-baselines3 {stable_baselines3.__version__}"
  print(f"{machine}; {env!r}", flush=True)

  n = args.num_envs
  batched = bridges.SB3VecEnv(env, n, params)  # Measured, then trained on (compiled once).
  first_b, sps_b = throughput(batched, args.throughput_steps)
  dummy = DummyVecEnv([lambda: bridges.GymnasiumEnv(env, params) for _ in range(n)])
  first_d, sps_d = throughput(dummy, max(args.throughput_steps // 4, 10))
  print(f"env only, random actions, {n} envs: SB3VecEnv {sps_b:.3g} env-steps/s (first step "
        f"{first_b:.1f} s), DummyVecEnv of GymnasiumEnv {sps_d:.3g} env-steps/s (first step "
        f"{first_d:.1f} s): {sps_b / sps_d:.1f}x", flush=True)

  venv = VecMonitor(batched)
  model = PPO("MlpPolicy", venv, n_steps=args.n_steps, batch_size=n * args.n_steps // 4,
              learning_rate=args.lr, ent_coef=args.ent_coef, n_epochs=args.n_epochs,
              seed=args.seed, device="cpu", verbose=0)
  compile_s = first_b  # The batch's reset and step compiled in the throughput run.
  curve = Curve()
  t0 = time.perf_counter()
  model.learn(args.timesteps, callback=curve)
  train_s = time.perf_counter() - t0
  sps = args.timesteps / train_s
  print(f"PPO: {args.timesteps} env steps in {train_s / 60:.1f} min (+ {compile_s:.1f} s "
        f"compile): {sps:.3g} env-steps/s (networks and updates included)", flush=True)
  rows = [r for r in curve.rows if r["episodes"]]
  for row in rows[:: max(len(rows) // 10, 1)] + rows[-1:]:
    print(f"  {row['timesteps']:>8d} steps: return {row['return']:.3f}, success "
          f"{row['success']:.1%}", flush=True)
  evaluation = bridges.SB3VecEnv(env, args.eval_episodes, params)
  success, ret = evaluate(model, evaluation, args.seed + 10_000)
  sampled, sampled_ret = evaluate(model, evaluation, args.seed + 10_000, deterministic=False)
  print(f"evaluation ({args.eval_episodes} episodes): argmax action: success {success:.1%}, "
        f"mean return {ret:.3f}; sampled actions (as in training): success {sampled:.1%}, "
        f"mean return {sampled_ret:.3f}", flush=True)

  label = f"{args.env}" + (f" on {args.level}" if args.level else "") + "".join(
      f", {k}={v}" for k, v in params_kw.items())
  last = rows[-1] if rows else {"success": float("nan"), "return": float("nan")}
  table = "\n".join([
      "# Stable-Baselines3 PPO on `SB3VecEnv` (`benchmarks/ppo_sb3.py`)", "",
      f"{machine}.{' SMOKE RUN: the figures mean nothing.' if args.smoke else ''}", "",
      f"Task: {label}; {n} envs; PPO(\"MlpPolicy\", n_steps={args.n_steps}, "
      f"batch_size={n * args.n_steps // 4}, learning_rate={args.lr}, ent_coef={args.ent_coef}, "
      f"n_epochs={args.n_epochs}, seed={args.seed}), SB3's other defaults; torch on 1 thread.",
      "",
      "| what | figure |", "|---|---|",
      f"| env only, random actions: `SB3VecEnv` ({n} envs, one jitted step) | "
      f"{sps_b:.3g} env-steps/s (first reset + step {first_b:.1f} s) |",
      f"| env only: SB3's `DummyVecEnv` of {n} `GymnasiumEnv`s | {sps_d:.3g} env-steps/s "
      f"(first reset + step {first_d:.1f} s); `SB3VecEnv` is {sps_b / sps_d:.1f}x |",
      f"| PPO training, {args.timesteps} env steps | {train_s / 60:.1f} min + {compile_s:.1f} s "
      f"compile: **{sps:.3g} env-steps/s** (networks and updates included) |",
      f"| training episodes, last 100 (sampled actions) | success {last['success']:.0%}, mean "
      f"return {last['return']:.2f} |",
      f"| evaluation, {args.eval_episodes} fresh episodes, argmax action | success "
      f"**{success:.0%}**, mean return {ret:.2f} |",
      f"| evaluation, {args.eval_episodes} fresh episodes, sampled actions | success "
      f"**{sampled:.0%}**, mean return {sampled_ret:.2f} |", "",
      "The learning curve: `ppo_sb3_curve.csv` (one row per rollout: SB3's means over the "
      "last 100 episodes) and `ppo_sb3_curve.png`.", ""])
  _bench.write_result(out, "ppo_sb3.md", table, run, echo=False)
  with open(out / "ppo_sb3_curve.csv", "w", newline="") as f:
    w = csv.DictWriter(f, fieldnames=list(Curve.FIELDS))
    w.writeheader()
    w.writerows(curve.rows)
  import matplotlib
  matplotlib.use("Agg")
  import matplotlib.pyplot as plt
  fig, (ax_r, ax_s) = plt.subplots(1, 2, figsize=(10, 3.6))
  x = [r["timesteps"] for r in rows]
  ax_r.plot(x, [r["return"] for r in rows])
  ax_s.plot(x, [r["success"] for r in rows])
  ax_r.set(xlabel="env steps", ylabel="mean episode return (last 100)")
  ax_s.set(xlabel="env steps", ylabel="success rate (last 100)", ylim=(-0.02, 1.02))
  for ax in (ax_r, ax_s):
    ax.grid(alpha=0.3)
  fig.suptitle(f"SB3 PPO on SB3VecEnv({label}), {n} envs: eval success {success:.0%} argmax, "
               f"{sampled:.0%} sampled; {sps:.3g} env-steps/s", fontsize=9)
  fig.tight_layout()
  fig.savefig(out / "ppo_sb3_curve.png", dpi=110)
  plt.close(fig)
  print(f"wrote {out / 'ppo_sb3.md'}, ppo_sb3_curve.csv and ppo_sb3_curve.png", flush=True)
  return 0


if __name__ == "__main__":
  raise SystemExit(main())
