"""The work meter: how much one step computes, counted, not timed (issue 23).

Walks the jaxpr of one step of a batch of worlds (`BATCH` copies of a scene: the core is
batched by hand, batch minor) and counts, for every primitive, the elements
it produces and, for gathers, the elements it gathers; the body of a `scan` (every
static-trip `fori_loop` is one) counts `length` times, a `while_loop` (`converge`) once
per iteration of its static bound (its upper limit; the meter runs the fixed-depth
step). Divided by bodies x worlds, that is elements per body-step, split by stage (the
jaxchain function that made the equation: broadphase, contacts, link table, chain
hops, impulses, friction, ...). It does not depend on the machine or its load: the
figure to watch while changing the step, and what `tests/test_work_meter.py` holds
under a budget. On XLA:CPU a gathered element costs about 0.65-1.06 ns and a fused
arithmetic element 0.015-0.07 ns (issue 23), so gathers and materialised buffers are
the budget; elements produced over-count what XLA fuses, which is why both are shown.

Scenes (`SCENES`): the room of 64 (`benchmarks/peers.py`: 68 bodies, friction 0.5,
`Config.for_world`), the demo platformer (`jaxchain demo`'s scene, fixed depth), and a
shipped platformer level (platformer1, one-way platforms and sensors).

    python benchmarks/work_meter.py              # all scenes; writes results/work_meter.md
    python benchmarks/work_meter.py --against b26b41f   # also a commit, in a fresh interpreter
    python benchmarks/work_meter.py --smoke --out /tmp/x
"""

from __future__ import annotations

import argparse
import collections
import dataclasses
import json
import pathlib
import subprocess
import sys
import tempfile

import jax
import jax.numpy as jnp
import numpy as np

import _bench
from _bench import add_common_args, out_dir

CLOSING_GATE = "closing_gate"  # jaxchain.core.step.CLOSING_GATE (older commits lack it).

# Stage of an equation: the innermost jaxchain frame that is not a shared helper, by
# (file, function prefix); first match wins. Helpers (gathers, reductions over link
# slots, safe division, loops) count toward the stage that called them. The files are
# the core's (`jaxchain/core/`), plus the public entry points (`stepping.py`: the
# transposes into and out of the batch-minor layout) and the sharding wrapper.
HELPERS = {
    ("layout.py", ""), ("sharding.py", ""), ("contacts.py", "Links."),
    ("pairs.py", "Candidates."), ("pairs.py", "first_set"), ("chain.py", "repeat"),
    ("flags.py", "bit"),
}
STAGES = [
    ("pairs.py", "", "broadphase"),
    ("contacts.py", "link_table", "link table"),
    ("contacts.py", "touching", "flags, sensors"),
    ("contacts.py", "", "contacts"),
    ("chain.py", "backing", "chain: backing"),
    ("chain.py", "displacement.<locals>.push_hop", "chain: push"),
    ("chain.py", "displacement.<locals>.refine", "chain: refine"),
    ("chain.py", "displacement.<locals>.velocity_change", "chain: refine"),
    ("chain.py", "link_impulses", "chain: impulses"),
    ("chain.py", "apply_impulses", "chain: refine"),
    ("chain.py", "crush", "crush"),
    ("chain.py", "", "chain: split"),
    ("friction.py", "", "friction"),
    ("flags.py", "", "flags, sensors"),
    ("step.py", "", "integrate, step"),
    ("stepping.py", "", "layout (transposes)"),
]
ORDER = list(dict.fromkeys(s for _, _, s in STAGES)) + ["other"]


def _stage(eqn) -> str:
  tb = eqn.source_info.traceback
  frames = [] if tb is None else tb.frames  # Innermost first.
  for fr in frames:
    path = fr.file_name.replace("\\", "/")
    if "/jaxchain/" not in path:
      continue
    file, fn = path.rsplit("/", 1)[-1], fr.function_name
    if any(file == f and fn.startswith(p) for f, p in HELPERS):
      continue
    for f, p, stage in STAGES:
      if file == f and fn.startswith(p):
        return stage
  return "other"


def _size(aval) -> int:
  shape = getattr(aval, "shape", None)
  return 0 if shape is None else int(np.prod(shape, dtype=np.int64))


@dataclasses.dataclass
class Count:
  """Elements produced and gathered, in total and by stage (per call of the function)."""

  elements: collections.Counter = dataclasses.field(default_factory=collections.Counter)
  gathered: collections.Counter = dataclasses.field(default_factory=collections.Counter)
  primitives: collections.Counter = dataclasses.field(default_factory=collections.Counter)
  while_loops: int = 0

  def add(self, eqn, times: int, stage: str) -> None:
    out = sum(_size(v.aval) for v in eqn.outvars) * times
    self.elements[stage] += out
    self.primitives[eqn.primitive.name] += out
    if eqn.primitive.name == "gather":
      self.gathered[stage] += out


def _sub_jaxprs(eqn, times: int):
  """The jaxprs inside `eqn` with how often each runs, or [] for a plain equation."""
  p, name = eqn.params, eqn.primitive.name
  if name == "scan":
    return [(p["jaxpr"].jaxpr, times * p["length"])]
  if name == "while":
    return None  # Handled by the caller (needs the bound).
  if name == "cond":
    return "cond"  # Handled by the caller (one branch runs).
  subs = []
  for value in p.values():
    inner = getattr(value, "jaxpr", value)
    if hasattr(inner, "eqns"):
      subs.append((inner, times))
  return subs


def walk(jaxpr, times: float, count: Count, while_trips: int, outer: str = "other",
         branch: str = "common", gate: float = 1.0) -> None:
  """Counts `jaxpr`'s equations into `count`, `times` each. An equation whose traceback
  names no jaxchain stage takes the stage of the equation it is inside (`outer`): JAX
  caches the jaxprs of its own jitted helpers (`jnp.where`, ...) and of custom rules,
  so their equations carry the traceback of their first trace.

  A `cond` runs one branch: `branch="common"` counts its cheapest (the core's conds skip
  work a batch does not need: the seam rule without corner contacts, the second link
  slot where no body has a second link), `"worst"` its most expensive. The closing
  stage's gate (`core.step.CLOSING_GATE`: one loop runs the passes, then the closing
  passes only for a batch with overlap left) runs its pass on the main passes, a
  fraction `gate` of the loop's trips, and skips the rest on the common path."""
  for eqn in jaxpr.eqns:
    stage = _stage(eqn)
    stage = outer if stage == "other" else stage
    subs = _sub_jaxprs(eqn, times)
    if subs == "cond":
      options = []
      for b in eqn.params["branches"]:
        c = Count()
        walk(b.jaxpr, times, c, while_trips, stage, branch, gate)
        options.append(c)
      size = lambda c: sum(c.elements.values())
      pick = (min if branch == "common" else max)(options, key=size)
      if branch == "common" and CLOSING_GATE in str(eqn.source_info.name_stack):
        pick = Count()
        for c, share in zip(sorted(options, key=size), (1 - gate, gate)):
          for mine, theirs in ((pick.elements, c.elements), (pick.gathered, c.gathered),
                               (pick.primitives, c.primitives)):
            mine.update({k: v * share for k, v in theirs.items()})
          pick.while_loops += c.while_loops
      count.elements.update(pick.elements)
      count.gathered.update(pick.gathered)
      count.primitives.update(pick.primitives)
      count.while_loops += pick.while_loops
      continue
    if subs is None:  # A while loop: counted at `while_trips` iterations.
      count.while_loops += 1
      subs = [(eqn.params["body_jaxpr"].jaxpr, times * while_trips),
              (eqn.params["cond_jaxpr"].jaxpr, times * while_trips)]
    if subs:
      for sub, t in subs:
        walk(sub, t, count, while_trips, stage, branch, gate)
    else:
      count.add(eqn, times, stage)


def meter(fn, *args, while_trips: int = 1, branch: str = "common", config=None) -> Count:
  """The `Count` of one call of `fn(*args)` (traced, never run); `branch`: which branch
  of a `cond` counts (`walk`); `config`, the step's, says how many of the passes' loop
  trips are main passes (the rest are the closing stage's, skipped on the common path)."""
  count = Count()
  gate = 1.0 if config is None else config.iterations / (config.iterations + config.closing)
  walk(jax.make_jaxpr(fn)(*args).jaxpr, 1, count, while_trips, branch=branch, gate=gate)
  return count


# --- Scenes ----------------------------------------------------------------------------


def room64(n: int = 64):
  """The room of N boxes (`_bench.room_world`, as `benchmarks/peers.py` times it): `n`
  unit boxes falling in a closed room, friction 0.5, g = -9.81, dt = 1/60,
  `Config.for_world`."""
  return _bench.room_world(n)


def demo():
  """`jaxchain demo`'s scene (one world of it), at fixed depth (the demo converges)."""
  import jaxchain as jc
  p = jc.scenes.platformer(np.random.default_rng(0))
  world = p.scene.world(friction=0.5)
  return world, jc.Config.for_world(world)


def platformer_level():
  """The shipped level platformer1 (one-way platforms, sensors), `Config.for_world`."""
  import jaxchain as jc
  level = jc.levels.load("platformer1")
  world = level.world(friction=0.5)
  return world, jc.Config.for_world(world)


SCENES = {"room of 64": room64, "demo": demo, "platformer1": platformer_level}


# Worlds per metered step: the core runs a batch of worlds at once (batch minor), so the
# meter counts one step of this many copies of the scene and divides by bodies x worlds
# (the counts per body-step hardly depend on it; a batch shows the per-step overheads
# at their real, amortised size).
BATCH = 8


def scene_counts(smoke: bool = False) -> dict[str, dict]:
  """`{scene: {"bodies", "config", "elements", "gathered", "stages"}}`, per body-step."""
  import jaxchain as jc
  out = {}
  for name, make in SCENES.items():
    world, config = make(8) if (smoke and name == "room of 64") else make()
    n = world.num_bodies
    batch = jax.tree.map(lambda x: jnp.broadcast_to(x, (BATCH,) + x.shape), world)
    count = meter(lambda w: jc.step(w, config), batch, config=config)
    worst = meter(lambda w: jc.step(w, config), batch, branch="worst", config=config)
    per = n * BATCH
    count_per = lambda c, s: c[s] / per
    stages = {s: [count_per(count.elements, s), count_per(count.gathered, s)] for s in ORDER
              if count.elements[s]}
    out[name] = dict(bodies=n, config=_config_line(config),
                     elements=sum(count.elements.values()) / per,
                     gathered=sum(count.gathered.values()) / per, stages=stages,
                     worst=[sum(worst.elements.values()) / per, sum(worst.gathered.values()) / per],
                     while_loops=count.while_loops)
    rolled = _rollout_step(batch, config, per)
    if rolled is not None:
      out[f"{name}, rollout step"] = dict(out[name], **rolled)
  return out


def _rollout_step(batch, config, per: int) -> dict | None:
  """A rollout's step in steady state: the neighbour table carried from the step before
  and kept (`core.step.advance`; `pairs.refresh`'s keep branch is the common path), as a
  settled room runs it. None without a table (or on commits before the carried table)."""
  from jaxchain import core
  if config.neighbors is None or not hasattr(core.step, "advance"):
    return None
  state, bodies = core.from_world(batch)
  table = core.pairs.build(state.pos, bodies, config, state.pos)
  fn = lambda s, t: core.step.advance(s, t, bodies, config)
  count = meter(fn, state, table, config=config)
  worst = meter(fn, state, table, branch="worst", config=config)
  return dict(elements=sum(count.elements.values()) / per,
              gathered=sum(count.gathered.values()) / per,
              stages={s: [count.elements[s] / per, count.gathered[s] / per] for s in ORDER
                      if count.elements[s]},
              worst=[sum(worst.elements.values()) / per, sum(worst.gathered.values()) / per])


def _config_line(config) -> str:
  keys = ("depth", "iterations", "links", "neighbors", "friction", "one_way", "sensors",
          "layers", "converge")
  return ", ".join(f"{k}={getattr(config, k)}" for k in keys if hasattr(config, k))


def _against(commit: str, smoke: bool) -> dict:
  """The same counts for `commit`, exported with `git archive` and metered by this script
  in a fresh interpreter with that tree's `src` first on the path."""
  with tempfile.TemporaryDirectory() as tmp:
    src = _bench.export_src(commit, pathlib.Path(tmp))
    code = (f"import sys, json; sys.path[:0] = [{str(src)!r}, "
            f"{str(pathlib.Path(__file__).parent)!r}]; import work_meter as m; "
            f"print(json.dumps(m.scene_counts({smoke})))")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          cwd=tmp)
    if done.returncode:
      print(f"--against {commit}: could not meter it:\n{done.stderr[-2000:]}", file=sys.stderr)
      return {}
    return json.loads(done.stdout.strip().splitlines()[-1])


def table(results: dict[str, dict], against: dict[str, dict] | None = None) -> list[str]:
  lines = ["| scene | bodies | elements / body-step | gathered / body-step | worst branch: "
           "elements / gathered | config |", "|---|---|---|---|---|---|"]
  for label, res in [("", results)] + [(f" at {c}", r) for c, r in (against or {}).items()]:
    for name, r in res.items():
      worst = r.get("worst")
      worst = "-" if worst is None else f"{worst[0]:,.0f} / {worst[1]:,.0f}"
      lines.append(f"| {name}{label} | {r['bodies']} | {r['elements']:,.0f} | "
                   f"{r['gathered']:,.0f} | {worst} | {r['config']} |")
  return lines


def stage_table(name: str, r: dict) -> list[str]:
  lines = [f"### {name}: by stage", "", "| stage | elements / body-step | gathered / body-step |",
           "|---|---|---|"]
  for stage, (e, g) in r["stages"].items():
    lines.append(f"| {stage} | {e:,.0f} | {g:,.0f} |")
  lines.append(f"| **total** | **{r['elements']:,.0f}** | **{r['gathered']:,.0f}** |")
  return lines + [""]


def main(argv=None) -> None:
  parser = add_common_args(argparse.ArgumentParser(description=__doc__.split("\n")[0]))
  parser.add_argument("--against", nargs="*", default=[], metavar="COMMIT",
                      help="also meter these commits (git archive, fresh interpreter)")
  args = parser.parse_args(argv)
  run = _bench.Run.start()
  results = scene_counts(args.smoke)
  against = {c: _against(c, args.smoke) for c in args.against}
  lines = ["# Work meter: elements per body-step", "",
           "Counted from the jaxpr of one step of a batch of `BATCH` copies of each scene: every equation's output elements, gathers' "
           "elements apart, loop bodies times their trip counts; per body and world. Deterministic: "
           "it does not depend on the machine or its load. Where the step branches "
           "(`lax.cond` over the batch: the seam rule only with a corner contact, the "
           "second link slot only where a body has a second link, the closing stage's "
           "passes only where overlap is left) the main columns count "
           "the cheaper branch, the common case; the worst-branch column the dearer (every "
           "closing pass run). A scene with a neighbour table also has its rollout step: "
           "the table carried from the step before and kept, as a settled room runs it. "
           "Issue 27's budget for the room of 64: must <= 6,000 / <= 500, goal <= 3,000 / "
           "<= 250.", ""]
  lines += table(results, against) + [""]
  for name, r in results.items():
    lines += stage_table(name, r)
  for commit, res in against.items():
    for name, r in res.items():
      lines += stage_table(f"{name} at {commit}", r)
  _bench.write_result(out_dir(args), "work_meter.md", lines, run)


if __name__ == "__main__":
  main()
