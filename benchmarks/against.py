"""The demo's speed beside earlier commits, built side by side and run in turn.

Each revision is exported with `git archive` into a temporary folder and runs the
same command, `jaxchain demo --batch B --steps S --no-progress` (the demo scene: 14
bodies, friction 0.3, `Config.for_world`), in a fresh interpreter whose only
jaxchain is that tree. Rounds alternate the trees, so slow drift of a shared machine
hits all alike; the table gives each tree's median world-steps/s and compile time,
and the speedup of the working tree over each revision. The working tree runs twice:
as the demo runs it (`--converge`, the default) and with `--no-converge` (the
fixed-depth hop loops a gradient needs). Writes `results/against.md`.

    python benchmarks/against.py                       # against b26b41f and bafbcc8
    python benchmarks/against.py --against b26b41f --rounds 5 --batch 1024
    python benchmarks/against.py --smoke --out /tmp/x   # HEAD exported, a 2-step demo: runs, writes
"""

from __future__ import annotations

import argparse
import os
import pathlib
import re
import statistics
import subprocess
import sys
import tempfile

from tqdm import tqdm

from _bench import ROOT, Run, add_common_args, export_src, out_dir, write_result

# `--smoke`: the cheapest demo to compile (no chain hops, no friction, no converging loops).
SMOKE_DEMO = ["--depth", "0", "--no-converge", "--friction", "0"]
FIGURES = {"compile": r"compile time\s+([\d.]+) s", "world_steps": r"world-steps/s\s+([\d.e+]+)"}


def run_demo(src: pathlib.Path, args: list[str]) -> dict:
  """One `jaxchain demo` run with `src` first on the path; its printed figures."""
  code = f"import sys; from jaxchain.cli import main; sys.exit(main({args!r}))"
  env = dict(os.environ, PYTHONPATH=str(src))
  out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True,
                       cwd=tempfile.gettempdir(), timeout=1800)
  if out.returncode:
    raise RuntimeError(f"demo failed in {src}:\n{out.stdout}\n{out.stderr}")
  found = {k: re.search(p, out.stdout) for k, p in FIGURES.items()}
  missing = [k for k, m in found.items() if m is None]
  if missing:
    raise RuntimeError(f"demo output in {src} lacks {missing}:\n{out.stdout}")
  return {k: float(m.group(1)) for k, m in found.items()}


def main():
  parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
  parser.add_argument("--against", nargs="+", default=["b26b41f", "bafbcc8"],
                      help="git revisions to build beside the working tree")
  parser.add_argument("--batch", type=int, default=1024)
  parser.add_argument("--steps", type=int, default=300)
  parser.add_argument("--rounds", type=int, default=3)
  args = add_common_args(parser).parse_args()
  if args.smoke:  # The working tree and HEAD (exported by `git archive`), once each, tiny.
    args.against, args.batch, args.steps, args.rounds = ["HEAD"], 2, 2, 1
  run = Run.start(src=ROOT / "src")
  demo = ["demo", "--batch", str(args.batch), "--steps", str(args.steps), "--no-progress"]
  if args.smoke:
    demo += SMOKE_DEMO
  with tempfile.TemporaryDirectory() as tmp:
    trees = {"working tree": (ROOT / "src", demo)}
    if not args.smoke:
      trees["working tree, --no-converge"] = (ROOT / "src", demo + ["--no-converge"])
    for rev in args.against:
      trees[rev] = (export_src(rev, pathlib.Path(tmp)), demo)
    runs = {name: [] for name in trees}
    plan = [(r, name) for r in range(args.rounds) for name in trees]
    for _, name in tqdm(plan, desc="demo runs", unit="run"):
      runs[name].append(run_demo(*trees[name]))
  write(runs, args, run)


def write(runs, args, run: Run) -> None:
  med = {name: {k: statistics.median(r[k] for r in rs) for k in FIGURES} for name, rs in runs.items()}
  base = {rev: med[rev]["world_steps"] for rev in args.against}
  lines = [
      "# The demo beside earlier commits",
      "",
      f"Against {' '.join(args.against)}, batch {args.batch}, {args.steps} steps, {args.rounds} "
      f"rounds. Each tree runs `jaxchain demo --batch {args.batch} --steps {args.steps} --no-progress` in a fresh "
      "interpreter, rounds alternating the trees; medians over rounds.",
      "",
      "| tree | world-steps/s | us per world-step | compile s | "
      + " | ".join(f"speedup over {rev}" for rev in args.against) + " |",
      "|---|---|---|---|" + "---|" * len(args.against),
  ]
  for name, m in med.items():
    ratios = " | ".join(f"{m['world_steps'] / b:.2f}x" for b in base.values())
    lines.append(f"| {name} | {m['world_steps']:.4g} | {1e6 / m['world_steps']:.1f} | "
                 f"{m['compile']:.2f} | {ratios} |")
  write_result(out_dir(args), "against.md", lines, run)


if __name__ == "__main__":
  main()
