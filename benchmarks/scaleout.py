"""World-steps/s of one batch past one device: 1 device, 2 devices, 2 processes.

Two workloads at B = 1024 worlds (the `examples/multiprocess.py` ones): `demo`, the
`jaxchain demo` run (the platformer, box masses per world, friction 0.3, the player
pushed at 20, `Config.for_world(..., converge=True)`), and `room64`, the
`benchmarks/peers.py` room of 64 unit boxes (friction 0.5, `Config.for_world`). Every
setting runs in its own subprocess, all in one run:

- `1 device`: `JAX_NUM_CPU_DEVICES=1`, the whole batch on one XLA:CPU device;
- `1 device, 1 core`: the same pinned to one core (`taskset -c 0`), which shows how
  much of the machine one device already uses;
- `2 devices`: `JAX_NUM_CPU_DEVICES=2` in one process, the batch sharded over the
  mesh `jax.make_mesh((2,), ("worlds",))` (explicit axes);
- `2 devices, 1 core`: the same pinned to one core;
- `2 processes`: two processes of one device each on one JAX runtime (gloo
  collectives over localhost), each building its half (`examples/multiprocess.py`).

Timed: a jitted, vmapped rollout of `--steps` steps, compiled ahead and warmed up,
median of `--repeats` calls; world-steps/s = B * steps / seconds. "cores busy" is the
process's CPU time over the wall time of the timed calls (summed over processes).

    python benchmarks/scaleout.py             # about 12 minutes on 2 cores
    python benchmarks/scaleout.py --quick     # B = 256, fewer steps, one round
    python benchmarks/scaleout.py --smoke --out /tmp/x   # B = 4, 2 devices and 2 processes

Other programs on the machine only ever slow a run down, so every setting runs
`--rounds` times, interleaved with the others, and the best round is reported (with the
lowest beside it). `--variant LABEL=SRC` measures another jaxchain source tree in the same
run, interleaved (its workers get SRC first on PYTHONPATH). Writes `results/scaleout.md`.
"""

from __future__ import annotations

import argparse
import contextlib
import importlib.util
import json
import os
import pathlib
import shutil
import statistics
import subprocess
import sys
import time

HERE = pathlib.Path(__file__).resolve().parent
ROOT = HERE.parent
MODES = {"1dev": "1 device", "1dev1core": "1 device, 1 core", "2dev": "2 devices",
         "2dev1core": "2 devices, 1 core", "2proc": "2 processes"}
STEPS = {"demo": 20, "room64": 5}  # Per call: about a second of work on one device.


def _example():
  """`examples/multiprocess.py` as a module (its workloads and its process launcher)."""
  spec = importlib.util.spec_from_file_location("jaxchain_multiprocess_example",
                                                ROOT / "examples" / "multiprocess.py")
  module = importlib.util.module_from_spec(spec)
  spec.loader.exec_module(module)
  return module


# --- Worker: one setting in one process. ------------------------------------------------


def worker(scene: str, batch: int, steps: int, repeats: int) -> dict:
  """Times the rollout on every device this process has (1 or 2), batch sharded over them."""
  import jax
  import numpy as np
  from jax.sharding import NamedSharding, PartitionSpec as P

  import jaxchain as jc

  mp = _example()
  t0 = time.perf_counter()
  worlds = mp.build_worlds(scene, 0, batch)
  cfg = jc.Config.for_world(worlds, **mp.config_overrides(scene))
  setup_s = time.perf_counter() - t0
  devices = jax.device_count()
  mesh = jax.make_mesh((devices,), ("worlds",))  # Explicit axes: jax's default.
  with jax.set_mesh(mesh) if devices > 1 else contextlib.nullcontext():
    if devices == 1:
      worlds = jax.device_put(worlds, jax.devices()[0])
    else:
      worlds = jax.device_put(worlds, NamedSharding(mesh, P("worlds")))
    run = mp.make_rollout(scene, worlds.num_bodies, cfg, steps)
    t0 = time.perf_counter()
    compiled = run.lower(worlds).compile()
    compile_s = time.perf_counter() - t0
    jax.block_until_ready(compiled(worlds))  # Warm-up.
    times, cpu = [], []
    for _ in range(repeats):
      t0, c0 = time.perf_counter(), time.process_time()
      out = jax.block_until_ready(compiled(worlds))
      times.append(time.perf_counter() - t0)
      cpu.append(time.process_time() - c0)
  run_s = statistics.median(times)
  return dict(scene=scene, batch=batch, steps=steps, devices=devices, processes=1,
              setup_s=setup_s, compile_s=compile_s, run_s=run_s,
              world_steps_per_s=batch * steps / run_s, cores_busy=sum(cpu) / sum(times),
              depth=cfg.depth, links=cfg.links, converge=cfg.converge,
              status=int(np.bitwise_or.reduce(np.asarray(out.status).ravel())))


# --- Parent: every setting in a subprocess. ---------------------------------------------


def _env(devices: int, src: str | None) -> dict:
  env = {**os.environ, "JAX_PLATFORMS": "cpu", "JAX_NUM_CPU_DEVICES": str(devices)}
  if src:
    env["PYTHONPATH"] = os.pathsep.join([src, env.get("PYTHONPATH", "")]).rstrip(os.pathsep)
  return env


def run_setting(mode: str, scene: str, batch: int, steps: int, repeats: int, timeout: float,
                src: str | None) -> dict:
  """One setting in its own subprocess(es): its record, or one with an `error`."""
  base = dict(mode=mode, scene=scene, batch=batch, steps=steps)
  if mode == "2 processes":
    mp = _example()
    args = mp.parse_args(["--processes", "2", "--worlds", str(batch), "--steps", str(steps),
                          "--scene", scene, "--repeats", str(repeats), "--no-check",
                          "--timeout", str(timeout)])
    old = dict(os.environ)
    os.environ.update(_env(1, src))
    try:
      code, lines = mp.launch(args, echo=False)
    finally:
      os.environ.clear()
      os.environ.update(old)
    records = mp.results(lines)
    if code or len(records) != 2:
      return {**base, "error": f"exit {code}: " + " | ".join(lines[-3:])}
    slowest = max(r["run_s"] for r in records)
    return {**base, "devices": 2, "processes": 2, "setup_s": records[0]["setup_s"],
            "compile_s": max(r["compile_s"] for r in records), "run_s": slowest,
            "world_steps_per_s": batch * steps / slowest,
            "cores_busy": sum(r["cpu_per_s"] for r in records),
            "depth": records[0]["depth"], "links": records[0]["links"]}
  devices = 2 if mode.startswith("2 devices") else 1
  argv = [sys.executable, str(pathlib.Path(__file__).resolve()), "--worker", "--scene", scene,
          "--batch", str(batch), "--steps", str(steps), "--repeats", str(repeats)]
  if mode.endswith("1 core"):
    if shutil.which("taskset") is None:
      return {**base, "error": "taskset not found"}
    argv = ["taskset", "-c", "0"] + argv
  try:
    done = subprocess.run(argv, capture_output=True, text=True, env=_env(devices, src),
                          timeout=timeout)
  except subprocess.TimeoutExpired:
    return {**base, "error": f"timeout after {timeout:g} s"}
  line = next((l for l in done.stdout.splitlines() if l.startswith("RESULT ")), None)
  if done.returncode or line is None:
    return {**base, "error": f"exit {done.returncode}: {done.stderr.strip()[-300:]}"}
  return {**base, **json.loads(line[len("RESULT "):])}


def best(runs: list[dict]) -> dict:
  """The round with the most world-steps/s (other programs only ever slow a run down),
  with the spread over rounds; an error if every round failed."""
  ok = [r for r in runs if "error" not in r]
  if not ok:
    return runs[-1]
  top = max(ok, key=lambda r: r["world_steps_per_s"])
  return {**top, "spread": (min(r["world_steps_per_s"] for r in ok), top["world_steps_per_s"]),
          "rounds": len(ok)}


def table(rows: list[dict]) -> list[str]:
  out = ["| scene | setting | devices x processes | world-steps/s | vs 1 device | ms / step "
         "| cores busy | rounds: lowest | compile s | depth, links |",
         "|---|---|---|---|---|---|---|---|---|---|"]
  base = {r["scene"]: r["world_steps_per_s"] for r in rows
          if r["mode"] == "1 device" and "error" not in r}
  for r in rows:
    if "error" in r:
      error = " ".join(r["error"].split()).replace("|", "/")[:160]
      out.append(f"| {r['scene']} | {r['mode']} | - | - | - | - | - | - | - | {error} |")
      continue
    ratio = r["world_steps_per_s"] / base[r["scene"]] if r["scene"] in base else float("nan")
    out.append(f"| {r['scene']} | {r['mode']} | {r['devices'] // r['processes']} x {r['processes']} "
               f"| {r['world_steps_per_s']:.4g} | {ratio:.2f}x | {1e3 * r['run_s'] / r['steps']:.1f} "
               f"| {r['cores_busy']:.2f} | {r['rounds']}: {r['spread'][0]:.4g} | {r['compile_s']:.1f} "
               f"| {r['depth']}, {r['links']} |")
  return out


def main(argv=None) -> int:
  parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
  parser.add_argument("--batch", type=int, default=1024)
  parser.add_argument("--steps", type=int, default=None, help="steps per call (default per scene)")
  parser.add_argument("--repeats", type=int, default=3, help="timed calls per round (median)")
  parser.add_argument("--rounds", type=int, default=2,
                      help="rounds over every setting, interleaved; the best round is reported")
  parser.add_argument("--scenes", default="demo,room64")
  parser.add_argument("--modes", default=",".join(MODES), help=f"of {', '.join(MODES)}")
  parser.add_argument("--timeout", type=float, default=600.0, help="seconds per setting")
  parser.add_argument("--quick", action="store_true", help="B = 256, a quarter of the steps, 1 round")
  parser.add_argument("--variant", action="append", default=[], metavar="LABEL=SRC",
                      help="also measure the jaxchain source tree SRC (prepended to PYTHONPATH), "
                           "interleaved with the others; repeatable. Default: the importable one")
  parser.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
  parser.add_argument("--scene", default=None, help=argparse.SUPPRESS)
  sys.path.insert(0, str(HERE))
  from _bench import Run, add_common_args, out_dir, write_result  # Imports jax; starts no backend.

  args = add_common_args(parser).parse_args(argv)
  if args.worker:
    print("RESULT " + json.dumps(worker(args.scene, args.batch, args.steps, args.repeats)), flush=True)
    return 0

  batch = 256 if args.quick else args.batch
  rounds = 1 if args.quick else args.rounds
  if args.smoke:  # The worker (2 devices, a mesh) and the 2-process launcher, tiny.
    batch, rounds, args.repeats, args.steps = 4, 1, 1, 1
    args.scenes, args.modes = "demo", "2dev,2proc"
  variants = [tuple(v.split("=", 1)) for v in args.variant] or [("jaxchain as importable", None)]
  settings = [(scene, MODES[code.strip()]) for scene in args.scenes.split(",")
              for code in args.modes.split(",")]
  run = Run.start(src=variants[0][1] and pathlib.Path(variants[0][1]))
  runs = {(label, scene, mode): [] for label, _ in variants for scene, mode in settings}
  for k in range(rounds):
    for scene, mode in settings:
      steps = args.steps or max(1, STEPS[scene] // (4 if args.quick else 1))
      for label, src in variants:
        row = run_setting(mode, scene, batch, steps, args.repeats, args.timeout, src)
        runs[label, scene, mode].append(row)
        shown = row.get("error") or f"{row['world_steps_per_s']:.4g} world-steps/s"
        print(f"round {k + 1}/{rounds} {label[:24]:24s} {scene:7s} {mode:18s} {shown}", flush=True)
  body = [f"B = {batch}; {rounds} rounds over every setting (interleaved), best round shown; "
          f"each round the median of {args.repeats} calls.", ""]
  for label, src in variants:
    rows = [best(runs[label, scene, mode]) for scene, mode in settings]
    body += [f"## {label}", ""] + ([f"Workers on `{src}`.", ""] if src else []) + table(rows) + [""]
  intro = [
      "# Scale-out: one batch over devices and processes", "",
      __doc__.split("\n\n", 1)[1].split("\n\n    python")[0].strip(), ""]
  path = write_result(out_dir(args), "scaleout.md", intro + body, run, echo=False)
  print(f"wrote {path}")
  return 0


if __name__ == "__main__":
  sys.exit(main())
