"""One batch of worlds stepped by several processes on JAX's own runtime.

Starts `--processes` local processes (each runs this script with `--process-id i`) that
join one JAX runtime through a coordinator on localhost (`jax.distributed.initialize`,
CPU collectives over gloo). Each process builds only its own share of the worlds and
hands it to `jax.make_array_from_process_local_data`, so the batch exists as one global
array sharded over every process's devices; all processes step it together, gather the
result (`multihost_utils.process_allgather`), and process 0 checks it against a
one-process run of the whole batch (computed in process 0 alone, on one device): the
results must be bit-identical. Prints PASS or FAIL with timings; exits nonzero on
failure or if anything takes longer than `--timeout` seconds.

    python examples/multiprocess.py                       # 2 processes, 8 worlds
    python examples/multiprocess.py --processes 2 --worlds 1024 --steps 50 --scene room64

Across machines the same script runs once per host with `--process-id`, the same
`--coordinator host:port` (process 0's address) and `--processes`; see docs/scaleout.md.

The mesh is `jax.make_mesh((devices,), ("worlds",))`, explicit axes by default
(`--axis-type auto` for `AxisType.Auto`); the plain `jax.vmap` of `jc.rollout` runs
under both (jaxchain runs each world's step with the mesh's axes Auto, see
`jaxchain.sharding`).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import socket
import subprocess
import sys
import threading
import time
import zlib

def parse_args(argv=None) -> argparse.Namespace:
  parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
  parser.add_argument("--processes", type=int, default=2, help="number of processes (default 2)")
  parser.add_argument("--worlds", type=int, default=8,
                      help="worlds in the global batch, a multiple of the device count (default 8)")
  parser.add_argument("--steps", type=int, default=10, help="time steps (default 10)")
  parser.add_argument("--scene", choices=SCENES, default="demo",
                      help="demo: the `jaxchain demo` workload; room64: 64 boxes in a room")
  parser.add_argument("--devices-per-process", type=int, default=1,
                      help="CPU devices each process exposes (JAX_NUM_CPU_DEVICES, default 1)")
  parser.add_argument("--axis-type", choices=("explicit", "auto"), default="explicit",
                      help="mesh axis type (default explicit, what jax.make_mesh builds)")
  parser.add_argument("--no-check", action="store_true",
                      help="skip the one-process reference run (timing only)")
  parser.add_argument("--repeats", type=int, default=1,
                      help="timed calls of the compiled rollout; the median is reported")
  parser.add_argument("--timeout", type=float, default=300.0,
                      help="seconds before every process is killed (default 300)")
  parser.add_argument("--process-id", type=int, default=None, help=argparse.SUPPRESS)
  parser.add_argument("--coordinator", default=None,
                      help="host:port of process 0 (default: a free port on localhost)")
  args = parser.parse_args(argv)
  if args.processes < 1 or args.worlds < 1 or args.steps < 1 or args.devices_per_process < 1:
    parser.error("--processes, --worlds, --steps and --devices-per-process must be >= 1")
  devices = args.processes * args.devices_per_process
  if args.worlds % devices:
    parser.error(f"--worlds ({args.worlds}) must be a multiple of the {devices} devices")
  return args


# --- The workload: every process builds the worlds it owns, and only those. ------------

SCENES = ("demo", "room64")


def build_worlds(scene: str, first: int, stop: int):
  """Worlds `first .. stop - 1` of the global batch, stacked (host-side, per process).

  World `b` depends on `b` alone, so any process can build any slice and the
  one-process reference builds them all. `demo`: the `jaxchain demo` scene (the
  platformer room, box masses drawn with seed `b`, friction 0.3). `room64`: the
  `benchmarks/peers.py` room of 64 unit boxes (lattice jitter drawn with seed `b`),
  friction 0.5.
  """
  import numpy as np

  import jaxchain as jc

  if scene == "demo":
    worlds = [jc.scenes.platformer(np.random.default_rng(b)).scene.world(friction=0.3)
              for b in range(first, stop)]
  else:
    worlds = [jc.scenes.lattice_room(64, seed=b).world(friction=0.5) for b in range(first, stop)]
  return jc.stack(worlds)


def config_overrides(scene: str) -> dict:
  """`Config.for_world` keywords of the workload: the demo's (forward-only hop loops)."""
  return dict(converge=True) if scene == "demo" else {}


def make_rollout(scene: str, num_bodies: int, config, steps: int):
  """`jax.jit` of the batched rollout (final worlds only). The demo pushes its player
  at 20 along +x every step, as `jaxchain demo` does (the same push in every world: a
  constant, not sharded)."""
  import jax
  import numpy as np

  import jaxchain as jc

  push = None
  if scene == "demo":
    push = np.zeros((num_bodies, 2), np.float32)
    push[jc.scenes.platformer().player, 0] = 20.0
  batched = jax.vmap(lambda w: jc.rollout(w, config, steps, push)[0])
  return jax.jit(batched)


def agreed_config(local_worlds, overrides: dict):
  """`Config.for_world` of this process's worlds, made the same in every process.

  The config is measured from data (chain depth, link table size, substeps), and every
  process must compile the same program: each measures its own worlds, then all take
  the largest depth and links and substeps over the processes.
  """
  import numpy as np
  from jax.experimental import multihost_utils

  import jaxchain as jc

  cfg = jc.Config.for_world(local_worlds, **overrides)
  mine = np.array([cfg.depth, -1 if cfg.links is None else cfg.links, cfg.substeps], np.int32)
  every = np.asarray(multihost_utils.process_allgather(mine)).reshape(-1, 3)
  links = None if np.any(every[:, 1] < 0) else int(every[:, 1].max())
  cfg = cfg.replace(depth=int(every[:, 0].max()), links=links, substeps=int(every[:, 2].max()))
  if cfg.grid is not None:
    raise SystemExit("multiprocess.py: grid configs are measured per process; not supported here")
  digest = np.array([zlib.crc32(repr(cfg).encode())], np.uint32)
  if len(set(np.asarray(multihost_utils.process_allgather(digest)).ravel().tolist())) != 1:
    raise SystemExit(f"multiprocess.py: processes derived different configs ({cfg})")
  return cfg


def global_batch(local_worlds, sharding, batch: int):
  """The global batch from each process's share: one sharded `jax.Array` per leaf."""
  import jax

  def leaf(x):
    return jax.make_array_from_process_local_data(sharding(x.ndim), x, (batch,) + x.shape[1:])

  return jax.tree.map(leaf, local_worlds)


def local_rows(mesh, batch: int) -> tuple[int, int]:
  """The rows of a batch sharded over `mesh` that this process's devices hold."""
  import jax
  from jax.sharding import NamedSharding, PartitionSpec as P

  index = NamedSharding(mesh, P("worlds")).addressable_devices_indices_map((batch,))
  spans = sorted((s[0].start or 0, batch if s[0].stop is None else s[0].stop) for s in index.values())
  first, stop = spans[0][0], spans[-1][1]
  if sum(b - a for a, b in spans) != stop - first:
    raise SystemExit(f"process {jax.process_index()}: its rows {spans} are not contiguous")
  return first, stop


def worker(args: argparse.Namespace) -> int:
  """One process of the group: joins the runtime, steps its share, checks (process 0)."""
  import jax

  jax.config.update("jax_cpu_collectives_implementation", "gloo")
  t0 = time.perf_counter()
  jax.distributed.initialize(coordinator_address=args.coordinator, num_processes=args.processes,
                             process_id=args.process_id,
                             initialization_timeout=max(10, int(args.timeout)))
  import numpy as np
  from jax.experimental import multihost_utils
  from jax.sharding import AxisType, NamedSharding, PartitionSpec as P

  me = jax.process_index()
  axis_type = AxisType.Explicit if args.axis_type == "explicit" else AxisType.Auto
  mesh = jax.make_mesh((jax.device_count(),), ("worlds",), axis_types=(axis_type,))

  def sharding(ndim):
    return NamedSharding(mesh, P("worlds", *([None] * (ndim - 1))))

  first, stop = local_rows(mesh, args.worlds)
  local = build_worlds(args.scene, first, stop)
  cfg = agreed_config(local, config_overrides(args.scene))
  setup_s = time.perf_counter() - t0

  with jax.set_mesh(mesh):
    worlds = global_batch(local, sharding, args.worlds)
    run = make_rollout(args.scene, local.num_bodies, cfg, args.steps)
    t0 = time.perf_counter()
    compiled = run.lower(worlds).compile()
    compile_s = time.perf_counter() - t0
    times, cpu = [], []
    for _ in range(max(1, args.repeats)):
      t0, c0 = time.perf_counter(), time.process_time()
      final = jax.block_until_ready(compiled(worlds))
      times.append(time.perf_counter() - t0)
      cpu.append(time.process_time() - c0)
    run_s = float(np.median(times))
    cpu_per_s = float(np.sum(cpu) / np.sum(times))  # CPU seconds per wall second: cores busy.
    got = {k: np.asarray(multihost_utils.process_allgather(getattr(final, k), tiled=True))
           for k in ("pos", "vel", "status")}
  result = dict(process=me, processes=jax.process_count(), devices=jax.device_count(),
                worlds=args.worlds, steps=args.steps, scene=args.scene, rows=[first, stop],
                axis_type=args.axis_type, setup_s=setup_s, compile_s=compile_s,
                run_s=run_s, cpu_per_s=cpu_per_s, world_steps_per_s=args.worlds * args.steps / run_s,
                depth=cfg.depth, links=cfg.links)
  ok = True
  if me == 0 and not args.no_check:
    # The reference: the whole batch in this process alone, on one device, no mesh.
    device = jax.local_devices()[0]
    full = jax.device_put(build_worlds(args.scene, 0, args.worlds), device)
    t0 = time.perf_counter()
    reference = make_rollout(args.scene, full.num_bodies, cfg, args.steps)
    want = jax.block_until_ready(reference(full))
    result["reference_s"] = time.perf_counter() - t0
    bad = [k for k in got if not np.array_equal(got[k], np.asarray(getattr(want, k)))]
    ok = not bad
    result["mismatch"] = bad
  multihost_utils.sync_global_devices("multiprocess.py done")
  print("RESULT " + json.dumps(result), flush=True)
  if me == 0:
    verdict = "PASS" if ok else "FAIL"
    check = ("not checked (--no-check)" if args.no_check else
             "bit-identical to the one-process run" if ok else
             f"differs from the one-process run in {', '.join(result['mismatch'])}")
    print(f"{verdict}: {args.worlds} worlds ({args.scene}) x {args.steps} steps on "
          f"{jax.process_count()} processes, {jax.device_count()} devices, {args.axis_type} axes: "
          f"{check}; setup {setup_s:.2f} s, compile {compile_s:.2f} s, run {run_s:.3f} s "
          f"({result['world_steps_per_s']:.4g} world-steps/s)", flush=True)
  return 0 if ok else 1


# --- The parent: starts the processes, streams their output, enforces the timeout. -----


def free_port() -> int:
  with contextlib.closing(socket.socket(socket.AF_INET, socket.SOCK_STREAM)) as s:
    s.bind(("127.0.0.1", 0))
    return s.getsockname()[1]


def child_argv(args: argparse.Namespace, process_id: int, coordinator: str) -> list[str]:
  argv = [sys.executable, os.path.abspath(__file__), "--processes", str(args.processes),
          "--worlds", str(args.worlds), "--steps", str(args.steps), "--scene", args.scene,
          "--devices-per-process", str(args.devices_per_process), "--axis-type", args.axis_type,
          "--repeats", str(args.repeats), "--timeout", str(args.timeout),
          "--process-id", str(process_id), "--coordinator", coordinator]
  return argv + (["--no-check"] if args.no_check else [])


def launch(args: argparse.Namespace, echo: bool = True) -> tuple[int, list[str]]:
  """Runs the process group; returns (exit code, every output line, prefixed by process).

  The exit code is 0 only if every process exits 0 within `args.timeout` seconds; on a
  timeout every process is killed and the code is 124.
  """
  coordinator = args.coordinator or f"127.0.0.1:{free_port()}"
  env = {**os.environ, "JAX_PLATFORMS": "cpu", "JAX_NUM_CPU_DEVICES": str(args.devices_per_process)}
  procs = [subprocess.Popen(child_argv(args, i, coordinator), env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True, bufsize=1)
           for i in range(args.processes)]
  lines: list[str] = []
  lock = threading.Lock()

  def pump(i, stream):
    for line in stream:
      with lock:
        lines.append(f"[{i}] {line.rstrip()}")
        if echo:
          print(lines[-1], flush=True)

  pumps = [threading.Thread(target=pump, args=(i, p.stdout), daemon=True) for i, p in enumerate(procs)]
  for t in pumps:
    t.start()
  deadline = time.monotonic() + args.timeout
  code = 0
  for p in procs:
    try:
      p.wait(timeout=max(0.1, deadline - time.monotonic()))
    except subprocess.TimeoutExpired:
      code = 124
      break
  if code == 124:
    for p in procs:
      p.kill()
    for p in procs:
      p.wait()
    lines.append(f"FAIL: timeout after {args.timeout:g} s; every process killed")
    if echo:
      print(lines[-1], flush=True)
  for t in pumps:
    t.join(timeout=5)
  if code == 0:
    codes = [p.returncode for p in procs]
    code = next((c for c in codes if c != 0), 0)
    if code:
      lines.append(f"FAIL: process exit codes {codes}")
      if echo:
        print(lines[-1], flush=True)
  return code, lines


def results(lines: list[str]) -> list[dict]:
  """The `RESULT` records the processes printed, by process index."""
  out = [json.loads(l.split("RESULT ", 1)[1]) for l in lines if "RESULT " in l]
  return sorted(out, key=lambda r: r["process"])


def main(argv=None) -> int:
  args = parse_args(argv)
  if args.process_id is not None:
    return worker(args)
  t0 = time.perf_counter()
  code, lines = launch(args)
  passed = any(l.split("] ", 1)[-1].startswith("PASS") for l in lines)
  if code == 0 and not passed:
    code = 1
    print("FAIL: process 0 reported no PASS", flush=True)
  print(f"multiprocess.py: {'ok' if code == 0 else 'failed'} in {time.perf_counter() - t0:.1f} s "
        f"(exit {code})", flush=True)
  return code


if __name__ == "__main__":
  sys.exit(main())
