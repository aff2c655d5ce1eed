"""What the benchmark scripts share, in one place (issue 34).

- **Options**: `--smoke` and `--out` (`add_common_args`, `out_dir`).
- **Result files**: `Run` notes the commit, the time, the machine and the load when a
  script starts; `Run.header()` gives the lines every results file starts with and
  `write_result` writes a file with them. A result says which code it measured.
- **Timing**: `median_time`, `compile_and_time` (compile apart), `rounds` (settings
  interleaved round by round, the load average noted with each).
- **Scenes**: `Scene` (host arrays), `room` (the room of N falling boxes), `push_chain`,
  `room_world` and `demo_world` (as jaxchain worlds, optionally settled), `penetration`.
- **Peer engines**: the Python ones (Box2D 2.3, Box2D v3, pymunk) come from
  `_peer_worker.py`, which can also serve one from another interpreter (`PythonPeer`);
  `Jax2D`; `load_peers` says which import.
- **Plots and trees**: `loglog`, `export_src` (an earlier commit's `src`).

jaxchain itself is imported inside the functions that need it, so that a script can
import this module with an exported older `src` first on its path.
"""

from __future__ import annotations

import argparse
import dataclasses
import datetime
import importlib.metadata
import importlib.util
import json
import os
import pathlib
import platform
import shlex
import statistics
import subprocess
import sys
import time
from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np

import _peer_worker

# Where the scripts write their tables and plots unless given `--out`.
RESULTS = pathlib.Path(__file__).resolve().parent / "results"
ROOT = RESULTS.parents[1]  # The checkout.
HERE = RESULTS.parent  # benchmarks/

DT = 1 / 60
GRAVITY = -9.81
ROOM_FRICTION = 0.5  # The room of N boxes and the push chain, in every engine.
DEMO_FRICTION = 0.3  # `jaxchain demo`'s scene.
INF = np.inf


# --- Options ---------------------------------------------------------------------------


def add_common_args(parser: argparse.ArgumentParser) -> argparse.ArgumentParser:
  """Adds the options every benchmark script offers (`tests/test_benchmarks.py` runs
  each script with both, so a script without them fails the suite):

  - `--smoke`: tiny sizes, a few settings and steps, no waiting: seconds, not minutes.
    It runs the script's whole code path and writes its tables; the figures mean
    nothing.
  - `--out DIR`: the directory for the tables and plots (default `benchmarks/results`,
    the committed ones; the smoke test writes to a temporary directory).
  """
  parser.add_argument("--smoke", action="store_true",
                      help="tiny sizes, a few seconds: checks that the script runs and writes its "
                           "tables (the figures mean nothing)")
  parser.add_argument("--out", type=pathlib.Path, default=RESULTS, metavar="DIR",
                      help="directory to write the tables and plots to (default benchmarks/results)")
  return parser


def out_dir(args: argparse.Namespace) -> pathlib.Path:
  """`args.out`, created if missing."""
  args.out.mkdir(parents=True, exist_ok=True)
  return args.out


# --- Result files ----------------------------------------------------------------------


def load_average() -> float:
  """The 1-minute load average (nan where the OS has none)."""
  return os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")


def cpu_model() -> str:
  """The CPU's model name (`/proc/cpuinfo`), else what `platform` knows."""
  try:
    with open("/proc/cpuinfo") as f:
      for line in f:
        if line.startswith("model name"):
          return line.split(":", 1)[1].strip()
  except OSError:
    pass
  return platform.processor() or platform.machine()


def machine() -> str:
  """The machine in one line: CPU model and cores, jax, numpy and Python versions."""
  return (f"{cpu_model()}, {os.cpu_count()} cores, {platform.machine()}; jax {jax.__version__}, "
          f"numpy {np.__version__}, Python {platform.python_version()}")


def jaxchain_src() -> pathlib.Path | None:
  """The `src` folder `import jaxchain` finds first (without importing it), or None."""
  spec = importlib.util.find_spec("jaxchain")
  if spec is None or spec.origin is None:
    return None
  return pathlib.Path(spec.origin).resolve().parents[1]


def commit_line(src: pathlib.Path | None = None) -> str:
  """`commit <sha>` of the checkout that holds `src` (default: the jaxchain this
  interpreter imports), 12 or more hex digits, then ` dirty` when `git status
  --porcelain -- src` lists anything (uncommitted changes to the measured code), then
  where it is when that is not this checkout's `src`."""
  src = pathlib.Path(src).resolve() if src is not None else jaxchain_src()
  if src is None:
    return "commit unknown (jaxchain does not import here)"

  def git(*args) -> str | None:
    try:
      done = subprocess.run(["git", "-C", str(src), *args], capture_output=True, text=True,
                            timeout=30)
    except (OSError, subprocess.TimeoutExpired):
      return None
    return done.stdout.strip() if done.returncode == 0 else None

  sha = git("rev-parse", "--short=12", "HEAD")
  if not sha:
    return f"commit unknown (jaxchain from {src}, not a git checkout)"
  dirty = git("status", "--porcelain", "--", str(src))
  where = "" if src == (ROOT / "src").resolve() else f" (jaxchain from {src})"
  return f"commit {sha}{' dirty' if dirty else ''}{where}"


def command_line(argv: list[str] | None = None) -> str:
  """The command that ran this script, as typed from the checkout (without `--out`)."""
  argv = list(sys.argv if argv is None else argv)
  script = pathlib.Path(argv[0]).resolve()
  try:
    script = script.relative_to(ROOT)
  except ValueError:
    pass
  rest, skip = [], False
  for a in argv[1:]:
    if skip:
      skip = False
    elif a == "--out":
      skip = True
    elif not a.startswith("--out="):
      rest.append(a)
  return shlex.join(["python", str(script), *rest])


@dataclasses.dataclass(frozen=True)
class Run:
  """A benchmark run, noted when it starts: the commit it measures, the command, the
  time (UTC) and the load. `Run.start()` first thing in `main`; `header()` when writing.

  Attributes:
    commit: `commit_line(src)`.
    command: the command line (`command_line()`).
    started: when it started (UTC).
    t0: `time.perf_counter()` then.
    load0: the 1-minute load average then.
  """

  commit: str
  command: str
  started: datetime.datetime
  t0: float
  load0: float

  @classmethod
  def start(cls, src: pathlib.Path | None = None, command: str | None = None) -> Run:
    """A run starting now, measuring `src` (default: the jaxchain this interpreter imports)."""
    return cls(commit_line(src), command or command_line(), datetime.datetime.now(datetime.timezone.utc),
               time.perf_counter(), load_average())

  def header(self) -> list[str]:
    """The lines every results file starts with (a blank line last): the commit, the
    date, time and command, the machine, and the load at the start and now."""
    wall = time.perf_counter() - self.t0
    return [self.commit,
            f"measured {self.started:%Y-%m-%d %H:%M} UTC, {wall:.0f} s: `{self.command}`",
            f"machine: {machine()}",
            f"1-min load average: {self.load0:.2f} at the start, {load_average():.2f} at the end",
            ""]


def write_result(out: pathlib.Path, name: str, lines, run: Run | list[str],
                 echo: bool = True) -> pathlib.Path:
  """Writes `out/name`: `run.header()`, then `lines` (a list of lines or one text).
  `run` may also be header lines saved from the run that measured (a result redrawn
  later from saved data keeps the header of its measurement). Prints the text too
  unless `echo` is False. Returns the path."""
  body = lines if isinstance(lines, str) else "\n".join(lines)
  header = run.header() if isinstance(run, Run) else list(run)
  text = "\n".join(header) + "\n" + body.rstrip("\n") + "\n"
  out.mkdir(parents=True, exist_ok=True)
  path = out / name
  path.write_text(text)
  if echo:
    print(text)
  return path


# --- Timing ----------------------------------------------------------------------------


def median_time(fn, repeats: int, budget_s: float = float("inf")):
  """`(last result, median seconds)` of `fn()` over up to `repeats` calls; stops
  early once the calls so far took `budget_s` (one long call is enough)."""
  times, out = [], None
  for _ in range(repeats):
    t0 = time.perf_counter()
    out = fn()
    times.append(time.perf_counter() - t0)
    if sum(times) >= budget_s:
      break
  return out, statistics.median(times)


def compile_and_time(fn, *args, repeats: int = 5, budget_s: float = float("inf"),
                     warmup: bool = True):
  """`(result, median seconds per call, compile seconds)` of `jax.jit(fn)(*args)`.

  Compiles ahead of time (`lower(...).compile()`), so compile time is measured on
  its own and never counted in the run time. With `warmup`, one untimed call first.
  """
  t0 = time.perf_counter()
  compiled = jax.jit(fn).lower(*args).compile()
  compile_s = time.perf_counter() - t0
  if warmup:
    jax.block_until_ready(compiled(*args))
  out, sec = median_time(lambda: jax.block_until_ready(compiled(*args)), repeats, budget_s)
  return out, sec, compile_s


def wall(fn: Callable, *args) -> Callable[[], float]:
  """A measurement for `rounds`: the seconds of one `jax.block_until_ready(fn(*args))`."""
  def measure() -> float:
    t0 = time.perf_counter()
    jax.block_until_ready(fn(*args))
    return time.perf_counter() - t0
  return measure


@dataclasses.dataclass
class Rounds:
  """What `rounds` measured: `figures[name]`, one a round (what the measurement
  returned: seconds for `wall`), and `loads[name]`, the 1-minute load average just
  before each."""

  figures: dict[str, list[float]]
  loads: dict[str, list[float]]

  def median(self, name: str) -> float:
    return statistics.median(self.figures[name])


def rounds(measures: dict[str, Callable[[], float]], n: int, progress=None) -> Rounds:
  """Runs every measurement once per round, in order, for `n` rounds: so slow drift of
  a shared machine hits every setting alike, and ratios taken within a round compare
  like with like. Each measurement returns its own figure (seconds; see `wall`).
  `progress(round, name)` is called after each, if given."""
  figures = {k: [] for k in measures}
  loads = {k: [] for k in measures}
  for r in range(n):
    for name, measure in measures.items():
      loads[name].append(load_average())
      figures[name].append(measure())
      if progress is not None:
        progress(r, name)
  return Rounds(figures, loads)


# --- Scenes ----------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class Scene:
  """Host arrays of a scene: `pos [n, 2]`, `half [n, 2]`, `mass [n]` (inf = immovable).

  Immovable bodies come first (Jax2D wants its fixed polygons at the front).

  Attributes:
    player: index of the driven body, or None.
    last: index of the last box of the push chain, or None.
    wall_face: x of the wall's left face (push chain), or None.
  """

  pos: np.ndarray
  half: np.ndarray
  mass: np.ndarray
  player: int | None = None
  last: int | None = None
  wall_face: float | None = None

  def __post_init__(self):
    for k in ("pos", "half", "mass"):
      object.__setattr__(self, k, np.asarray(getattr(self, k), float))

  @property
  def n_static(self) -> int:
    return int(np.sum(np.isinf(self.mass)))

  @property
  def n_movable(self) -> int:
    return len(self.mass) - self.n_static

  def world(self, friction: float = ROOM_FRICTION):
    """The scene as a jaxchain `World` (friction on every body, g = GRAVITY)."""
    import jaxchain as jc
    return jc.World.create(self.pos, self.half, self.mass, friction=friction,
                           gravity=(0.0, GRAVITY))

  def peer(self, speed: float | None = None, friction: float = ROOM_FRICTION) -> dict:
    """The scene for a Python peer (`peer_scene`); the player driven at `speed` if given."""
    drive = None if speed is None or self.player is None else (self.player, speed)
    return peer_scene(self.pos, self.half, self.mass, friction=friction, drive=drive)


def peer_scene(pos, half, mass, vel=None, *, kinematic=(), gravity=(0.0, GRAVITY),
               friction: float = ROOM_FRICTION, dt: float = DT, drive=None) -> dict:
  """A scene as `_peer_worker` takes it: plain lists (JSON), see its docstring."""
  n = len(mass)
  return dict(pos=np.asarray(pos, float).tolist(), half=np.asarray(half, float).tolist(),
              mass=np.asarray(mass, float).tolist(),
              vel=np.zeros((n, 2)).tolist() if vel is None else np.asarray(vel, float).tolist(),
              kinematic=[int(k) for k in kinematic], gravity=[float(g) for g in gravity],
              friction=float(friction), dt=float(dt),
              drive=None if drive is None else [int(drive[0]), float(drive[1])])


def room(n: int, seed: int = 0) -> Scene:
  """The room of N boxes: `n` unit boxes (mass 1) on a lattice of pitch 1.5 (x jittered
  by up to 0.2) in a closed room of 4 immovable walls (`jaxchain.scenes.lattice_room`);
  they fall and settle in about 270 steps at dt = 1/60."""
  import jaxchain as jc
  s = jc.scenes.lattice_room(n, seed)
  return Scene(s.pos, s.half, s.mass)


PUSH_BOXES = 8
PUSH_GAP = 2.0


def push_chain(boxes: int = PUSH_BOXES, gap: float = PUSH_GAP) -> Scene:
  """Floor (top at y=0), a wall whose left face is right behind the last box, a player
  (unit box spanning x in [0, 1]) and `boxes` touching unit boxes starting `gap` further."""
  first = 1.0 + gap
  row = [[first + 0.5 + k, 0.5] for k in range(boxes)]
  wall_face = first + boxes
  pos = [[wall_face / 2, -0.5], [wall_face + 0.5, 2.0], [0.5, 0.5]] + row
  half = [[wall_face / 2 + 3, 0.5], [0.5, 2.0]] + [[0.5, 0.5]] * (boxes + 1)
  mass = [INF, INF] + [1.0] * (boxes + 1)
  return Scene(pos, half, mass, player=2, last=len(mass) - 1, wall_face=wall_face)


def settle(world, cfg, steps: int, controls=None):
  """`world` after `steps` steps of `jc.rollout` (the boxes fall and stack)."""
  import jaxchain as jc
  return jc.rollout(world, cfg, steps, controls)[0] if steps else world


def room_world(n: int = 64, settle_steps: int = 0, **overrides):
  """`(world, config)`: the room of N boxes as a jaxchain World (friction 0.5, g = -9.81),
  `Config.for_world(world, dt=1/60, **overrides)`, after `settle_steps` steps."""
  import jaxchain as jc
  world = room(n).world()
  cfg = jc.Config.for_world(world, dt=DT, **overrides)
  return settle(world, cfg, settle_steps), cfg


def demo_world(settle_steps: int = 0):
  """`(world, config)`: `jaxchain demo`'s platformer (14 bodies, friction 0.3,
  `Config.for_world`), after `settle_steps` steps with no push."""
  import jaxchain as jc
  world = jc.scenes.platformer().scene.world(friction=DEMO_FRICTION)
  cfg = jc.Config.for_world(world)
  controls = np.zeros((world.num_bodies, 2), np.float32)
  return settle(world, cfg, settle_steps, controls), cfg


def penetration(traj: np.ndarray, scene) -> np.ndarray:
  """`[t]` largest min(overlap_x, overlap_y) over pairs not both immovable, clipped at 0,
  of positions `traj [t, n, 2]` of a scene with `half` and `mass`."""
  d = np.abs(traj[:, :, None] - traj[:, None, :])  # [t, n, n, 2]
  ov = scene.half[:, None] + scene.half[None] - d
  pen = np.clip(np.min(ov, -1), 0.0, None)
  static = np.isinf(scene.mass)
  skip = np.eye(len(static), dtype=bool) | (static[:, None] & static[None])
  return np.max(np.where(skip, 0.0, pen), axis=(1, 2))


# --- Peer engines ----------------------------------------------------------------------

WORKER = HERE / "_peer_worker.py"


class PythonPeer:
  """A Python peer engine (`_peer_worker.ENGINES`: Box2D 2.3, Box2D v3, pymunk), in this
  process, or, with `python`, served by `_peer_worker.py` in that interpreter (JSON lines
  over a pipe; the worker times its own steps).

  Raises:
    ImportError: the engine does not import in this process.
    RuntimeError: the worker did not start or answer (its message says why).
  """

  def __init__(self, name: str, python: str | None = None):
    self.name, self.python, self.proc = name, python, None
    if python is None:
      self.engine = _peer_worker.ENGINES[name]()
      self.version = self.engine.version
      return
    try:
      self.proc = subprocess.Popen([python, str(WORKER), name], stdin=subprocess.PIPE,
                                   stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                   bufsize=1)
    except OSError as e:
      raise RuntimeError(f"could not start {python}: {e}") from None
    hello = self._call(dict(op="hello"))
    self.version = f"{hello['version']}, in Python {hello['python']} ({python})"

  def _call(self, req: dict) -> dict:
    try:
      self.proc.stdin.write(json.dumps(req) + "\n")
      self.proc.stdin.flush()
      line = self.proc.stdout.readline()
    except (BrokenPipeError, OSError):
      line = ""
    if not line:
      self.proc.kill()
      err = self.proc.stderr.read().strip()
      raise RuntimeError(f"the {self.name} worker ({self.python}) ended: {err[-1500:] or 'no output'}")
    reply = json.loads(line)
    if "error" in reply:
      raise RuntimeError(f"{self.name} worker ({self.python}): {reply['error']}")
    return reply

  def time(self, scene: dict, settle: int, steps: int, min_s: float = 0.0,
           max_reps: int = 1) -> dict:
    """`_peer_worker.time_windows`: `{"seconds", "reps", "pos"}`, `pos` as an array."""
    if self.proc is None:
      out = _peer_worker.time_windows(self.engine, scene, settle, steps, min_s, max_reps)
    else:
      out = self._call(dict(op="time", scene=scene, settle=settle, steps=steps, min_s=min_s,
                            max_reps=max_reps))
    return {**out, "pos": np.asarray(out["pos"], float)}

  def record(self, scene: dict, segments) -> tuple[np.ndarray, np.ndarray]:
    """`_peer_worker.record`: positions and velocities `[steps + 1, n, 2]`."""
    segments = [(int(s), {int(k): list(v) for k, v in c.items()}) for s, c in segments]
    if self.proc is None:
      out = _peer_worker.record(self.engine, scene, segments)
    else:
      out = self._call(dict(op="record", scene=scene,
                            segments=[[s, {str(k): v for k, v in c.items()}] for s, c in segments]))
    return np.asarray(out["pos"], float), np.asarray(out["vel"], float)

  def close(self) -> None:
    if self.proc is not None and self.proc.poll() is None:
      try:
        self.proc.stdin.write(json.dumps(dict(op="quit")) + "\n")
        self.proc.stdin.flush()
        self.proc.wait(timeout=10)
      except (OSError, subprocess.TimeoutExpired):
        self.proc.kill()
        self.proc.wait()


class Jax2D:
  """Jax2D (Matthews et al.; the engine behind Kinetix): all-pairs impulse solver in JAX.

  Polygons are rectangles of density `mass / area`; the immovable ones (first) are
  `fixated` and counted in `num_static_fixated_polys`. Jax2D needs at least one joint,
  one thruster and two circle slots (all left inactive). Friction is mixed as
  `sqrt((f_a b)^2 + (f_b b)^2)` with `base_friction b`: `b = 1` and `f = 0.5 / sqrt(2)`
  give 0.5. `clip_position` is raised so the room fits. Rotation is fixed (zero inverse
  inertia). Its `PhysicsEngine` builds all-pairs index lists in a Python loop at
  construction: keep N to a few dozen boxes.
  """

  name = "Jax2D"

  def __init__(self):
    from jax2d import engine, scene as j2scene, sim_state
    self.engine, self.scene, self.sim_state = engine, j2scene, sim_state
    self.version = f"jax2d {importlib.metadata.version('jax2d')}"

  def build(self, scene: Scene, speed: float | None = None, friction: float = ROOM_FRICTION):
    """`(state, step)`: Jax2D's state of `scene` and a pure `step(state) -> state` (the
    player, if any, driven at `speed` along x before each step)."""
    ss = self.sim_state
    n = len(scene.mass)
    static = ss.StaticSimParams(num_polygons=n, num_circles=2, num_joints=1, num_thrusters=1,
                                num_static_fixated_polys=scene.n_static)
    params = ss.SimParams(dt=DT, clip_position=1e4, base_friction=1.0)
    physics = self.engine.PhysicsEngine(static)
    state = self.engine.create_empty_sim(static, add_floor=False, add_walls_and_ceiling=False)
    state = state.replace(gravity=jnp.array([0.0, GRAVITY]))
    f = friction / np.sqrt(2)
    for p, h, m in zip(scene.pos, scene.half, scene.mass):
      fixated = bool(np.isinf(m))
      density = 1.0 if fixated else m / (4 * h[0] * h[1])
      state, _ = self.scene.add_rectangle_to_scene(state, static, jnp.asarray(p), jnp.asarray(2 * h),
                                                   density=density, friction=f, restitution=0.0,
                                                   fixated=fixated)
    state = state.replace(polygon=state.polygon.replace(inverse_inertia=jnp.zeros(n)))
    actions = jnp.zeros(static.num_joints + static.num_thrusters)
    player = scene.player if speed is not None else None

    def step(s):
      if player is not None:
        s = s.replace(polygon=s.polygon.replace(velocity=s.polygon.velocity.at[player, 0].set(speed)))
      return physics.step(s, params, actions)[0]
    return state, step

  @staticmethod
  def positions(state) -> jax.Array:
    return state.polygon.position


PEERS = ("Box2D", "Box2D v3", "pymunk", "Jax2D")
PEER_HINT = "`pip install -e .[peers]` installs it"


def load_peers(names=PEERS, v3_python: str | None = None) -> tuple[list, list[str]]:
  """The peer engines of `names` that can run, and one message per engine that cannot.

  Box2D v3 runs in this process when `box2d-python` imports here, else in a worker under
  `v3_python` (an interpreter with `box2d-python` and NumPy) when given.
  """
  peers, skipped = [], []
  for name in names:
    try:
      if name == "Jax2D":
        peers.append(Jax2D())
      elif name == "Box2D v3" and v3_python:
        peers.append(PythonPeer(name, python=v3_python))
      else:
        peers.append(PythonPeer(name))
    except RuntimeError as e:
      skipped.append(f"{name}: skipped, the worker failed ({e})")
    except Exception as e:  # noqa: BLE001 - any import failure means "not installed".
      hint = PEER_HINT
      if name == "Box2D v3":
        hint = (f"box2d-python ships wheels for Python 3.12 and later only (this is "
                f"{platform.python_version()}): pass `--v3-python PATH`, an interpreter with "
                "box2d-python and numpy (docs/performance.md)")
      skipped.append(f"{name}: skipped, import failed ({type(e).__name__}: {e}); {hint}")
  return peers, skipped


# --- Plots and trees -------------------------------------------------------------------


def loglog(path, series, *, xlabel: str, ylabel: str, title: str, xbase: int = 10) -> None:
  """Writes a log-log PNG of `series`: label -> `(xs, ys, matplotlib style)`."""
  import matplotlib
  matplotlib.use("Agg")
  import matplotlib.pyplot as plt
  fig, ax = plt.subplots(figsize=(7, 4.5))
  for label, (xs, ys, style) in series.items():
    ax.plot(xs, ys, style, label=label)
  ax.set_xscale("log", base=xbase)
  ax.set_yscale("log")
  ax.set_xlabel(xlabel)
  ax.set_ylabel(ylabel)
  ax.set_title(title)
  ax.grid(True, which="both", alpha=0.3)
  ax.legend()
  fig.tight_layout()
  fig.savefig(path, dpi=120)
  plt.close(fig)


def export_src(rev: str, into: pathlib.Path) -> pathlib.Path:
  """`git archive rev src` of this checkout into `into/rev`; returns its `src` folder
  (an earlier commit's jaxchain, to run beside the working tree's)."""
  dest = into / rev
  dest.mkdir(parents=True)
  archive = subprocess.run(["git", "-C", str(ROOT), "archive", rev, "src"], check=True,
                           capture_output=True).stdout
  subprocess.run(["tar", "-x", "-C", str(dest)], input=archive, check=True)
  return dest / "src"
