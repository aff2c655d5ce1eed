"""Compile time: the trace, lower and compile split of the demo's step and the env step.

Programs (each in a fresh state: `jax.clear_caches()` first, after one tiny warm-up
compile so that the first row does not pay for XLA's start-up):

- `demo`: the program `jaxchain demo` compiles (`jaxchain.cli.demo`): the platformer
  scene of `scenes.platformer` in B = 1024 worlds (seed 0, friction 0.3,
  `Config.for_world(worlds, iterations=1, converge=True)`), `cli.chunk_program` of
  `jax.vmap(make_step(config))`: the vmapped step (which reaches the batch-minor core)
  in a 50-step `lax.scan` whose steps past a bound are masked. An older jaxchain
  without `chunk_program` compiles `jax.jit(jax.vmap(lambda w, u: rollout(w, config,
  50, u)[0]))`, the program its demo compiled.
- `env`: `jax.jit(jax.vmap(env.step, in_axes=(0, 0, 0, None)))` of `jc.env.make(task)`
  for push_box and reach_flag at B = 1, 64, 1024, 4096 (auto-reset included).

Each is timed as `jax.jit(f).trace(*args)` (Python tracing to a jaxpr), `.lower()`
(to StableHLO) and `.compile()` (XLA: HLO passes and LLVM). Beside the times, the
program's size: jaxpr equations (each loop body counted once: the static program XLA
compiles), StableHLO ops, and instructions and `while` loops of the optimised HLO.
With `--where` (on by default for the demo), the jaxpr equations of the demo's step
are attributed to the pipeline stage that made them (the line of `core/step.py` that
called into it) and to the source lines that made the most (a Python loop unrolled
shows up as one line with many equations). Writes `results/compile_time.md`.

    python benchmarks/compile_time.py                 # demo + both tasks x 4 sizes: ~3 min
    python benchmarks/compile_time.py --batches 1 1024 --tasks push_box
    python benchmarks/compile_time.py --smoke --out /tmp/x   # tiny B, one task: runs, writes

Compile times depend on machine load far more than run times do (XLA compiles on one
thread, and shares the cores): the machine line gives the load average, and only
ratios measured in one run mean much on a busy machine.
"""

from __future__ import annotations

import argparse
import collections
import contextlib
import functools
import os
import pathlib
import re
import time

import jax
import jax.extend
import jax.numpy as jnp
import numpy as np

import jaxchain as jc
from jaxchain import scenes

from _bench import Run, add_common_args, out_dir, write_result

TASKS = ("push_box", "reach_flag")
BATCHES = (1, 64, 1024, 4096)
DEMO_BATCH, DEMO_CHUNK = 1024, 50  # `jaxchain demo`'s defaults (--batch, --chunk).


# --- the programs --------------------------------------------------------------------

def demo_program(batch: int, chunk: int):
  """`(fn, args, one, one_args, None)`: the chunk `jaxchain demo` compiles (built as
  `cli.demo` builds it), and its per-world function with the first world's arguments."""
  rng = np.random.default_rng(0)
  layouts = [scenes.platformer(rng) for _ in range(batch)]
  try:
    worlds = jc.stack([p.scene.world(friction=0.3) for p in layouts])
    config = jc.Config.for_world(worlds, iterations=1, converge=True)
  except TypeError:  # An older jaxchain (b26b41f, to compare): friction in the Config.
    worlds = jc.stack([p.scene.world() for p in layouts])
    config = jc.Config.for_world(worlds, iterations=1, friction=0.3)
  controls = np.zeros((batch, worlds.num_bodies, 2), np.float32)
  controls[:, layouts[0].player, 0] = 20.0
  one = lambda w, u: jc.rollout(w, config, chunk, u)[0]
  args = (worlds, jnp.asarray(controls))
  one_args = jax.tree.map(lambda x: x[0], args)
  from jaxchain import cli
  chunk_program = getattr(cli, "chunk_program", None)
  if chunk_program is None:  # An older jaxchain: the demo compiled a vmapped rollout.
    return jax.vmap(one), args, one, one_args, None
  # As `cli.demo`: the vmapped step scanned over the chunk, steps past `stop` masked.
  step = jax.vmap(jc.make_step(config))
  run = chunk_program(lambda w, t, u: step(w, u), chunk)
  fn = lambda w, u, start, stop: run(w, start, stop, u)[0]
  return fn, args + (np.int32(0), np.int32(chunk)), one, one_args, None


def env_program(task: str, batch: int):
  """`(fn, args, one, one_args, env class)`: the vmapped env step of `task` at `batch`
  envs (auto-reset included), and the env step of one env with its arguments."""
  env, params = jc.env.make(task)
  keys = jax.random.split(jax.random.key(0), batch)
  _, state = jax.jit(jax.vmap(env.reset, in_axes=(0, None)))(keys, params)
  actions = jax.vmap(env.action_space(params).sample)(keys)
  fn = jax.vmap(env.step, in_axes=(0, 0, 0, None))
  first = jax.tree.map(lambda x: x[0], (keys, state, actions))
  return fn, (keys, state, actions, params), env.step, first + (params,), type(env)


# --- timing and size -----------------------------------------------------------------

def split(fn, args) -> dict:
  """Trace, lower and compile seconds of `jax.jit(fn)` on `args`, from a cold cache,
  and the program's size at each level."""
  jax.clear_caches()
  t0, c0 = time.perf_counter(), time.process_time()
  traced = jax.jit(fn).trace(*args)
  t1, c1 = time.perf_counter(), time.process_time()
  lowered = traced.lower()
  t2, c2 = time.perf_counter(), time.process_time()
  compiled = lowered.compile()
  t3, c3 = time.perf_counter(), time.process_time()
  hlo = compiled.as_text()
  return dict(trace_s=t1 - t0, lower_s=t2 - t1, compile_s=t3 - t2, total_s=t3 - t0,
              trace_cpu=c1 - c0, lower_cpu=c2 - c1, compile_cpu=c3 - c2, total_cpu=c3 - c0,
              fusions=len(re.findall(r"^\s+(?:ROOT )?%?[\w.\-]+ = \S+ fusion\(", hlo, re.M)),
              eqns=sum(_eqn_counts(traced.jaxpr.jaxpr).values()),
              stablehlo=_stablehlo_ops(lowered.as_text()),
              hlo=len(re.findall(r"^\s+(?:ROOT )?%?[\w.\-]+ = ", hlo, re.M)),
              whiles=len(re.findall(r" while\(", hlo)))


def _stablehlo_ops(text: str) -> int:
  return len(re.findall(r"^\s*(?:%[\w#:, %]+ = )?\"?(?:stablehlo|chlo)\.", text, re.M))


def _sub_jaxprs(eqn):
  for v in eqn.params.values():
    for j in (v if isinstance(v, (tuple, list)) else (v,)):
      if isinstance(j, jax.extend.core.ClosedJaxpr):
        yield j.jaxpr
      elif isinstance(j, jax.extend.core.Jaxpr):
        yield j


def _eqn_counts(jaxpr, key=lambda frames: None, counts=None, outer=()) -> collections.Counter:
  """Equations of `jaxpr` and every sub-jaxpr (loop and branch bodies once), by
  `key(frames)`: the jaxchain frames of the equation's traceback and then of the
  equations it sits inside, innermost first (an equation inside a cached inner jit,
  e.g. `jnp.where`'s, or a custom rule has only the frames of that trace)."""
  counts = collections.Counter() if counts is None else counts
  for eqn in jaxpr.eqns:
    frames = _frames(eqn) + list(outer)
    subs = list(_sub_jaxprs(eqn))
    if subs:
      for sub in subs:
        _eqn_counts(sub, key, counts, frames)
    else:
      counts[key(frames)] += 1
  return counts


def _frames(eqn):
  """The jaxchain frames of an equation's traceback, innermost first."""
  tb = eqn.source_info.traceback
  if tb is None:
    return []
  return [f for f in tb.frames if f"{os.sep}jaxchain{os.sep}" in f.file_name]


def _stage(frames) -> str:
  """The `core/step.py` line that led here (the pipeline stage), else the module."""
  for f in frames:
    if f.file_name.endswith(os.path.join("core", "step.py")):
      return f"core/step.py:{f.line_num} {_source(f.file_name, f.line_num)}"
  return os.path.basename(frames[0].file_name) if frames else "(outside jaxchain)"


def _line(frames) -> str:
  """The innermost jaxchain line that led here."""
  if not frames:
    return "(outside jaxchain)"
  f = frames[0]
  return f"{os.path.basename(f.file_name)}:{f.line_num} {f.function_name}: " \
         f"{_source(f.file_name, f.line_num)}"


_SOURCES: dict = {}


def _source(path: str, line: int) -> str:
  if path not in _SOURCES:
    try:
      _SOURCES[path] = pathlib.Path(path).read_text().splitlines()
    except OSError:
      _SOURCES[path] = []
  lines = _SOURCES[path]
  text = lines[line - 1].strip() if 0 < line <= len(lines) else ""
  return text if len(text) <= 70 else text[:67] + "..."


def where(one, one_args, top: int) -> tuple[int, list, list]:
  """The jaxpr equations of `one` (the per-world function, not vmapped: batching rules
  trace without the caller's stack), by pipeline stage and by source line:
  `(total, stages, lines)`."""
  jaxpr = jax.make_jaxpr(one)(*one_args).jaxpr
  return (sum(_eqn_counts(jaxpr).values()), _eqn_counts(jaxpr, _stage).most_common(top),
          _eqn_counts(jaxpr, _line).most_common(top))


# The functions whose compiled code `kernels` counts apart: during one extra compile
# each runs inside a `jax.named_scope`, which XLA keeps in every instruction's
# `op_name` (so the optimised HLO says which function made each fusion). Names a
# version of jaxchain lacks are skipped.
SCOPED = {
    "core.step": ("passes", "sensors", "substep"),
    "core.pairs": ("candidates", "build", "pack", "peel"),
    "core.contacts": ("admit", "contacts", "seam_axis", "link_table"),
    "core.flags": ("sensed", "finite", "switched_off", "too_fast", "motion_lost"),
    "core.chain": ("displacement", "backing", "link_impulses", "energy_scale", "repeat", "crush"),
    "core.friction": ("friction",),
}
LINKS_METHODS = ("front", "back", "bodies")
ENV_METHODS = ("reset", "step_env", "get_obs")
# Jitted helpers of jax.random, named in op_name by their jit.
RANDOM = re.compile(r"jit\((_randint|_uniform|_threefry_split|_threefry_fold_in|_bits|"
                    r"_random_bits|_normal|_choice)\)")


@contextlib.contextmanager
def _scoped(env_cls=None):
  """Wraps `SCOPED` (and an env class's methods) in named scopes `jc:<name>`, for the
  duration of the block."""
  import importlib

  def wrap(f, name):
    @functools.wraps(f)
    def g(*a, **k):
      with jax.named_scope(f"jc:{name}"):
        return f(*a, **k)
    return g

  undo = []
  targets = [(importlib.import_module(f"jaxchain.{m}"), names) for m, names in SCOPED.items()]
  from jaxchain.core import contacts
  targets.append((contacts.Links, LINKS_METHODS))
  for cls in (env_cls.__mro__ if env_cls is not None else ()):
    targets.append((cls, [n for n in ENV_METHODS if n in cls.__dict__]))
  for owner, names in targets:
    for n in names:
      f = owner.__dict__.get(n) if isinstance(owner, type) else getattr(owner, n, None)
      if f is None or not callable(f):
        continue
      undo.append((owner, n, f))
      setattr(owner, n, wrap(f, n))
  try:
    yield
  finally:
    for owner, n, f in reversed(undo):
      setattr(owner, n, f)


def kernels(fn, args, env_cls=None, top: int = 12) -> tuple[int, int, list]:
  """Compiles `jax.jit(fn)` once more with `_scoped` on and counts the optimised HLO's
  instructions and kernels (fusions, and gathers, scatters, dots and sorts left
  unfused: what XLA:CPU emits code for) by the chain of jaxchain functions that made
  them (`a/b/c`: c called inside b inside a; `jax.random` for its helpers).

  Returns:
    `(instructions, kernels, [(path, instructions, kernels)])`, the `top` paths with
    the most kernels.
  """
  jax.clear_caches()
  with _scoped(env_cls):
    hlo = jax.jit(fn).lower(*args).compile().as_text()
  ins, ker = collections.Counter(), collections.Counter()
  for line in hlo.splitlines():
    m = re.match(r"^\s+(?:ROOT )?%?[\w.\-]+ = \S+ ([\w\-]+)\(", line)
    if not m:
      continue
    name = re.search(r'op_name="([^"]*)"', line)
    path = "/".join(dict.fromkeys(re.findall(r"jc:(\w+)", name.group(1)))) if name else ""
    if name and RANDOM.search(name.group(1)):
      path = (path + "/" if path else "") + "jax.random"
    path = path or ("(parameters, tuples)" if m.group(1) in ("parameter", "tuple",
                                                            "get-tuple-element") else "(other)")
    ins[path] += 1
    ker[path] += m.group(1) in ("fusion", "gather", "scatter", "dot", "sort")
  rows = sorted(ins, key=lambda k: (-ker[k], -ins[k]))[:top]
  return sum(ins.values()), sum(ker.values()), [(k, ins[k], ker[k]) for k in rows]


# --- the run -------------------------------------------------------------------------

def _warm_up() -> None:
  jax.jit(lambda x: jnp.sin(x) @ x).lower(jnp.ones((4, 4))).compile()


# Per-compile XLA options (`jax.jit(f, compiler_options=...)`) that trade code quality
# for compile time, measured with `--options`: LLVM at -O1 (default -O3), and XLA:CPU's
# older loop emitters instead of its MLIR fusion emitters.
OPTIONS = {
    "default": {},
    "O1": {"xla_backend_optimization_level": 1},
    "O1, no fusion emitters": {"xla_backend_optimization_level": 1,
                               "xla_cpu_use_fusion_emitters": False},
}


def options(fn, args, repeats: int, names=tuple(OPTIONS)) -> list[dict]:
  """Compile CPU seconds, run CPU seconds per call (best of `repeats`) and whether the
  answer is bit-identical to the first's (the default), for each of `OPTIONS[names]`."""
  rows, ref = [], None
  for name in names:
    opts = OPTIONS[name]
    jax.clear_caches()
    lowered = jax.jit(fn).lower(*args)
    c0 = time.process_time()
    compiled = lowered.compile(compiler_options=opts) if opts else lowered.compile()
    compile_cpu = time.process_time() - c0
    out = [np.asarray(x) for x in jax.tree.leaves(jax.block_until_ready(compiled(*args)))]
    runs = []
    for _ in range(repeats):
      c0 = time.process_time()
      jax.block_until_ready(compiled(*args))
      runs.append(time.process_time() - c0)
    ref = out if ref is None else ref
    same = all(np.array_equal(a, b, equal_nan=True) for a, b in zip(out, ref))
    hlo = compiled.as_text()
    rows.append(dict(name=name, compile_cpu=compile_cpu, run_cpu=min(runs), same=same,
                     fusions=len(re.findall(r"= \S+ fusion\(", hlo))))
  return rows


def main():
  parser = argparse.ArgumentParser(description=__doc__,
                                   formatter_class=argparse.RawDescriptionHelpFormatter)
  parser.add_argument("--tasks", nargs="*", default=list(TASKS),
                      help=f"env tasks (default {' '.join(TASKS)}; none: the demo only)")
  parser.add_argument("--batches", type=int, nargs="+", default=list(BATCHES))
  parser.add_argument("--demo-batch", type=int, default=DEMO_BATCH)
  parser.add_argument("--no-demo", dest="demo", action="store_false")
  parser.add_argument("--no-where", dest="where", action="store_false",
                      help="skip the where-it-goes tables (one compile more per program)")
  parser.add_argument("--no-options", dest="options", action="store_false",
                      help="skip the XLA options table (three compiles more per program)")
  parser.add_argument("--top", type=int, default=12, help="rows of the where-it-goes tables")
  args = add_common_args(parser).parse_args()
  chunk, repeats = DEMO_CHUNK, 3
  option_names = list(OPTIONS)
  if args.smoke:  # The whole path once, small: the demo at 2 worlds (split only), one
    # task at B=2 with its tables, one of the options (the last: compiled with options).
    args.tasks, args.batches, args.demo_batch = args.tasks[:1], [2], 2
    chunk, repeats, args.top, option_names = 2, 1, 5, option_names[-1:]
  run = Run.start()
  _warm_up()
  plan = ([("demo", args.demo_batch)] if args.demo else []) + [
      (task, batch) for task in args.tasks for batch in args.batches]
  rows, tables, opts = [], {}, {}
  for name, batch in plan:
    if name == "demo":
      fn, fargs, one, one_args, env_cls = demo_program(batch, chunk)
    else:
      fn, fargs, one, one_args, env_cls = env_program(name, batch)
    rows.append(dict(program=name, batch=batch, **split(fn, fargs)))
    print(_row(rows[-1]), flush=True)
    # The analyses at the demo's batch, and at each task's largest B up to 1024.
    at = args.demo_batch if name == "demo" else max(
        [b for b in args.batches if b <= 1024] or args.batches[:1])
    analyse = batch == at and not (args.smoke and name == "demo")
    if analyse and args.where:
      tables[name, batch] = where(one, one_args, args.top), kernels(fn, fargs, env_cls, args.top)
    if analyse and args.options and (name == "demo" or name == args.tasks[0]):
      opts[name, batch] = options(fn, fargs, repeats, option_names)
  write(rows, tables, opts, args, run)


def _row(r: dict) -> str:
  return (f"| {r['program']} | {r['batch']} | {r['trace_s']:.2f} | {r['lower_s']:.2f} | "
          f"{r['compile_s']:.2f} | {r['total_s']:.2f} | {r['trace_cpu']:.2f} | "
          f"{r['lower_cpu']:.2f} | {r['compile_cpu']:.2f} | {r['total_cpu']:.2f} | {r['eqns']} | "
          f"{r['stablehlo']} | {r['hlo']} | {r['fusions']} | {r['whiles']} |")


def write(rows, tables, opts, args, run: Run) -> None:
  lines = [
      "# Compile time",
      "",
      "Each program from a cold cache (`jax.clear_caches()`): `jax.jit(f).trace(*args)`, "
      "`.lower()`, `.compile()`, in wall seconds and in CPU seconds of this process (all "
      "threads: on a busy machine the wall time is the CPU time stretched by the load, so "
      "compare CPU seconds). Size: jaxpr equations (loop bodies once), StableHLO ops, "
      "instructions, fusions and `while` loops of the optimised HLO. `demo`: the "
      f"{DEMO_CHUNK}-step chunk `jaxchain demo` compiles; the tasks: "
      "`jax.jit(jax.vmap(env.step))` (auto-reset included).",
      "",
      "| program | B | trace s | lower s | compile s | total s | trace CPU s | lower CPU s | "
      "compile CPU s | total CPU s | jaxpr eqns | StableHLO ops | HLO instructions | "
      "HLO fusions | HLO whiles |",
      "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
  ] + [_row(r) for r in rows]
  for task in dict.fromkeys(r["program"] for r in rows if r["program"] != "demo"):
    one = [r for r in rows if r["program"] == task]
    if len(one) > 1:
      lines.append(f"\n- {task}: total CPU {one[-1]['total_cpu']:.2f} s at B={one[-1]['batch']} "
                   f"against {one[0]['total_cpu']:.2f} s at B={one[0]['batch']} "
                   f"({one[-1]['total_cpu'] / one[0]['total_cpu']:.2f}x); HLO fusions "
                   f"{' -> '.join(str(r['fusions']) for r in one)} over B = "
                   f"{', '.join(str(r['batch']) for r in one)}")
  for (name, batch), rs in opts.items():
    base = rs[0]
    lines += ["", f"## XLA options: `{name}` at B={batch}", "",
              "Per-compile options (`jax.jit(f, compiler_options=...)`); CPU seconds, run: "
              "best of the timed calls after one untimed call.", "",
              "| options | compile CPU s | x default | run CPU s / call | x default | "
              "fusions | bit-identical |", "|---|---|---|---|---|---|---|"]
    lines += [f"| {r['name']} | {r['compile_cpu']:.2f} | {r['compile_cpu'] / base['compile_cpu']:.2f} "
              f"| {r['run_cpu']:.3f} | {r['run_cpu'] / base['run_cpu']:.2f} | {r['fusions']} | "
              f"{'yes' if r['same'] else 'no'} |" for r in rs]
  for (name, batch), ((total, stages, source), (ins, ker, paths)) in tables.items():
    lines += ["", f"## Where `{name}` (B={batch}) goes", "",
              f"Optimised HLO: {ins} instructions, {ker} kernels (fusions, and gathers, "
              "scatters, dots and sorts left alone: what XLA:CPU emits code for, most of the "
              "compile time), by the jaxchain functions that made them (`a/b`: b inside a).", "",
              "| functions | kernels | instructions |", "|---|---|---|"]
    lines += [f"| `{k}` | {kn} | {n} |" for k, n, kn in paths]
    lines += ["", f"Jaxpr equations of one world ({total} in all) by pipeline stage:", "",
              "| pipeline stage (the `core/step.py` line, else the module) | eqns | share |",
              "|---|---|---|"]
    lines += [f"| `{k}` | {n} | {n / total:.0%} |" for k, n in stages]
    lines += ["", "| source line (innermost jaxchain frame; a loop unrolled in Python shows "
              "as one line with many) | eqns |", "|---|---|"]
    lines += [f"| `{k}` | {n} |" for k, n in source]
  write_result(out_dir(args), "compile_time.md", lines, run)


if __name__ == "__main__":
  main()
