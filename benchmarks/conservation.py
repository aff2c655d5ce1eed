"""Physics fidelity beside Box2D and pymunk: momentum, energy, riders, crushing.

Each scene is built once as host arrays (`Scene`) and fed to every engine: jaxchain,
Box2D (pybox2d, `fixedRotation` boxes, restitution 0) and pymunk (infinite moment,
elasticity 0). dt = 1/60, unit boxes (half-extent 0.5) unless a scene says
otherwise. A kinematic body (a moving platform, ceiling or elevator) is an
immovable body with a velocity: in jaxchain mass inf (it moves by its own velocity),
in Box2D a kinematic body, in pymunk a `KINEMATIC` body; a scene may set such
velocities between segments of its run (a platform that stops).

Per scene and engine: momentum error (relative, over the run), the largest
increase of energy in any step and its total change (energy = kinetic +
gravitational over the movable bodies: `sum 0.5 m |v|^2 - m g . p`), the largest
penetration between two bodies (not both immovable) in any step, whether the engine
reported a failure (jaxchain: its `world.status` bits, explained by `jc.check`, and
the bodies `world.crushed` marks; peers report none: "n/a"), and the scene's own
figures (final velocities, rider velocity errors, where a crushed box ends up).
Writes `results/conservation.md` and prints it.

Scenes (`SCENES`; each function's `about` text says what is expected): head_on,
free_chain, friction_contrast, edge_fall (and edge_fall_shallow, first contact less
deep than the horizontal overlap), random_room, rider (and rider_up), crush_ceiling,
crush_elevator; with one-way bodies (jaxchain only: the peer adapters have none; their
penetration is `jc.metrics.max_penetration`, which counts one-way pairs by the sink the
one-way rule resolves) crush_ceiling_one_way, crush_elevator_one_way, one_way_rise (a
box rising with its bottom in the one-way margin) and one_way_room.

    python benchmarks/conservation.py            # about 20 s on 2 cores
    python benchmarks/conservation.py --quick    # shorter room and chain runs
    python benchmarks/conservation.py --smoke --out /tmp/x   # head_on only: runs, writes
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
import inspect
import sys
from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np
from tqdm import tqdm

import jaxchain as jc
import _bench  # The Box2D / pymunk adapters, the penetration measure, the result header.
from _bench import add_common_args, out_dir

INF = np.inf
DT = 1 / 60
G = (0.0, -9.81)
NO_G = (0.0, 0.0)
ROOM_W, ROOM_H, ROOM_N = 8.0, 10.0, 24  # random_room: interior [0, W] x [0, H], N boxes.


# --- Scenes ----------------------------------------------------------------------------


@dataclasses.dataclass
class Scene:
  """Host arrays of one scene and how to run and judge it.

  Attributes:
    pos, half, vel: `[n, 2]`; mass: `[n]` (inf = immovable).
    gravity: `(gx, gy)`; friction: one coefficient for every contact.
    kinematic: indices of immovable bodies that move (or may be set moving).
    segments: `(steps, {body: (vx, vy)})` run in order, the velocities set first.
    momentum: "conserved" (error `max_t |P(t) - P(0)| / |P(0)|`), "no gain" (x
      momentum of the movable bodies may only fall: `max_t (Px(t) - Px(0)) / |Px(0)|`)
      or None (external forces: not reported).
    figures: `(scene, run) -> {column: text}`, the scene's own results.
    about: what is set up and what is expected.
  """

  name: str
  about: str
  pos: np.ndarray
  half: np.ndarray
  mass: np.ndarray
  vel: np.ndarray
  gravity: tuple[float, float]
  friction: float
  segments: list[tuple[int, dict]]
  figures: Callable
  kinematic: tuple[int, ...] = ()
  momentum: str | None = None
  one_way: tuple[int, ...] = ()  # One-way (jump-through) bodies: jaxchain only.

  @property
  def movable(self) -> np.ndarray:
    return np.isfinite(self.mass)

  @property
  def ends(self) -> list[int]:
    """Index (in a run's `[steps + 1]` record) of the last state of each segment."""
    return list(np.cumsum([s for s, _ in self.segments]))


def box(x, y, hx=0.5, hy=0.5, m=1.0, vx=0.0, vy=0.0):
  return (x, y), (hx, hy), m, (vx, vy)


def scene(name, about, bodies, **kw) -> Scene:
  pos, half, mass, vel = (np.array([b[i] for b in bodies], float) for i in range(4))
  return Scene(name, about, pos, half, mass, vel, **kw)


@dataclasses.dataclass
class Run:
  """A run's record: `pos`, `vel` `[steps + 1, n, 2]` (the start included) and the
  engine's failure report."""

  pos: np.ndarray
  vel: np.ndarray
  failure: str = "n/a"
  messages: tuple[str, ...] = ()


def f4(x) -> str:
  return f"{x:+.4f}"


def head_on(quick: bool) -> Scene:
  def figures(s, r):
    return {"v(m=1) end": f4(r.vel[-1, 0, 0]), "v(m=3) end": f4(r.vel[-1, 1, 0])}
  return scene(
      "head_on", "Box m=1 at vx=+1 and box m=3 at vx=-1, 0.2 apart, no gravity, no friction. "
      "Perfectly inelastic: both end at -0.5; kinetic energy falls from 2 to 0.5.",
      [box(0.0, 0.0, vx=1.0), box(1.2, 0.0, m=3.0, vx=-1.0)],
      gravity=NO_G, friction=0.0, segments=[(60, {})], momentum="conserved", figures=figures)


def free_chain(quick: bool) -> Scene:
  def figures(s, r):
    return {"player vx end": f4(r.vel[-1, 0, 0]), "last box vx end": f4(r.vel[-1, -1, 0]),
            "box vx spread end": f"{np.ptp(r.vel[-1, :, 0]):.2e}"}
  row = [box(1.5 + k, 0.0) for k in range(8)]
  return scene(
      "free_chain", "A player at vx=+4, 0.5 from a row of 8 touching unit boxes; no gravity, "
      "no friction. Perfectly inelastic: all 9 end at 4/9 = +0.4444 (or the row moves on "
      "ahead); energy never increases.",
      [box(0.0, 0.0, vx=4.0)] + row,
      gravity=NO_G, friction=0.0, segments=[(60 if quick else 120, {})], momentum="conserved",
      figures=figures)


def friction_contrast(quick: bool) -> Scene:
  def figures(s, r):
    return {"light vx end": f4(r.vel[-1, 1, 0]),
            "heavy max abs vx": f"{np.max(np.abs(r.vel[:, 2, 0])):.2e}",
            "x-momentum end": f4(np.sum(s.mass[1:] * r.vel[-1, 1:, 0]))}
  return scene(
      "friction_contrast", "A box (m=1, vx=+2) on a static floor slides under a box of mass 1e4 "
      "resting on it; friction 0.3 everywhere, gravity. The light box is held by friction on "
      "both faces and stops within a step; the heavy box can gain at most the light box's "
      "momentum (|vx| <= 2e-4). Energy never increases; the x-momentum of the two boxes "
      "(2 at the start) only falls.",
      [box(0.0, -0.5, hx=10.0, m=INF), box(0.0, 0.5, vx=2.0), box(0.0, 1.5, m=1e4)],
      gravity=G, friction=0.3, segments=[(120, {})], momentum="no gain", figures=figures)


def edge_fall(quick: bool, gap: float = 0.05) -> Scene:
  def figures(s, r):
    return {"top max abs vx": f"{np.max(np.abs(r.vel[:, 2, 0])):.2e}",
            "bottom max abs vx": f"{np.max(np.abs(r.vel[:, 1, 0])):.2e}",
            "top vx end": f4(r.vel[-1, 2, 0]), "bottom vx end": f4(r.vel[-1, 1, 0]),
            "top x end": f4(r.pos[-1, 2, 0]), "top y end": f4(r.pos[-1, 2, 1])}
  # The first step moves the top box 12 dt + g dt^2 = 0.203 down: `depth` deep into the other.
  depth = 12.0 * DT + 9.81 * DT ** 2 - gap
  return scene(
      "edge_fall" if gap < 0.1 else "edge_fall_shallow",
      f"A box starting at vy=-12, {gap:g} above a box resting on the floor and overlapping it "
      f"horizontally by 0.1 (top box x=0.9), gravity, no friction: the first step takes it "
      f"{depth:.3f} deep vertically, {'deeper' if depth > 0.1 else 'less deep'} than the "
      "horizontal overlap. It should land on the edge and stay (top y end +1.5, x +0.9): no "
      "sideways kick (all vx 0) and no energy gain in any step.",
      [box(0.0, -0.5, hx=5.0, m=INF), box(0.0, 0.5), box(0.9, 1.0 + 0.5 + gap, vy=-12.0)],
      gravity=G, friction=0.0, segments=[(90, {})], figures=figures)


def random_room(quick: bool, seed: int = 0) -> Scene:
  rng = np.random.default_rng(seed)
  boxes = []
  while len(boxes) < ROOM_N:  # Rejection sampling: no two boxes overlap or touch.
    c = rng.uniform([0.55, 0.55], [ROOM_W - 0.55, ROOM_H - 0.55])
    if all(np.max(np.abs(c - b)) >= 1.02 for b in boxes):
      boxes.append(c)
  w, h = ROOM_W, ROOM_H
  walls = [box(w / 2, -0.5, hx=w / 2 + 1, m=INF), box(w / 2, h + 0.5, hx=w / 2 + 1, m=INF),
           box(-0.5, h / 2, hy=h / 2, m=INF), box(w + 0.5, h / 2, hy=h / 2, m=INF)]

  def figures(s, r):
    p = r.pos[:, 4:]
    out = (p[..., 0] < 0) | (p[..., 0] > w) | (p[..., 1] < 0) | (p[..., 1] > h)
    return {"boxes that left the room": str(int(np.sum(np.any(out, axis=0)))),
            "penetration end": f"{_bench.penetration(r.pos[-1:], s)[0]:.2e}"}
  return scene(
      "random_room", f"{ROOM_N} unit boxes at random non-overlapping places (seed {seed}) fall "
      f"in a closed static room (interior {w:g} x {h:g}), gravity, friction 0.5. Energy should "
      "only fall; no box leaves the room.",
      walls + [box(*c) for c in boxes],
      gravity=G, friction=0.5, segments=[(120 if quick else 360, {})], figures=figures)


def rider(quick: bool, up: bool = False) -> Scene:
  axis = 1 if up else 0
  v_plat = (0.0, 1.0) if up else (1.0, 0.0)
  # The step after the stop: vertically the box flies on under gravity, horizontally it
  # slides on and friction takes mu g dt.
  expect = 1.0 - (9.81 if up else 0.5 * 9.81) * DT

  def figures(s, r):
    k = s.ends[0]
    return {"abs(v_box - v_plat) at 2 s": f"{np.linalg.norm(r.vel[k, 1] - r.vel[k, 0]):.2e}",
            f"box v{'xy'[axis]} after stop (expect {expect:.3f})": f4(r.vel[k + 1, 1, axis])}
  return scene(
      "rider_up" if up else "rider",
      f"A box at rest on a kinematic platform (half-extents 3 x 0.25) moving at "
      f"v{'xy'[axis]}=+1, friction 0.5, gravity. After 2 s the box should move with the "
      f"platform (error 0); then the platform stops and the box should keep about +1 the "
      f"step after ({expect:.3f}). The platform does work: energy rises.",
      [box(0.0, -0.25, hx=3.0, hy=0.25, m=INF, vx=v_plat[0], vy=v_plat[1]), box(0.0, 0.5)],
      gravity=G, friction=0.5, kinematic=(0,), segments=[(120, {}), (30, {0: (0.0, 0.0)})],
      figures=figures)


def squeeze_outcome(r: Run, s: Scene, b: int, below: int, above: int) -> str:
  """Where box `b` ended: held between bodies `below` and `above`, through one, or out."""
  x, y = r.pos[-1, b]
  if abs(x - r.pos[-1, below, 0]) >= s.half[below, 0] + s.half[b, 0]:
    return "squeezed out sideways"
  if y < r.pos[-1, below, 1] + s.half[below, 1]:
    return "through the " + ("floor" if below == 0 else "elevator")
  if y > r.pos[-1, above, 1] - s.half[above, 1]:
    return "through the ceiling"
  return "held between"


def sink(r: Run, s: Scene, b: int, below: int) -> float:
  """Largest depth of box `b`'s bottom face below the top face of body `below`."""
  d = r.pos[:, below, 1] + s.half[below, 1] - (r.pos[:, b, 1] - s.half[b, 1])
  return float(max(np.max(d), 0.0))


def crush_ceiling(quick: bool) -> Scene:
  def figures(s, r):
    return {"max sink into floor": f"{sink(r, s, 1, 0):.3f}", "box y end": f4(r.pos[-1, 1, 1]),
            "outcome": squeeze_outcome(r, s, 1, 0, 2)}
  return scene(
      "crush_ceiling", "A box on a static floor (top y=0); a kinematic ceiling (half-extents "
      "3 x 0.25), its bottom 0.25 above the box, descends at 1 u/s for 45 steps (its bottom "
      "ends at y=0.5, half the box's height) and then stops for 30 steps. No body can give: "
      "the box should stay between them (no sink into the floor would be ideal) and the "
      "squeeze be reported.",
      [box(0.0, -0.5, hx=3.0, m=INF), box(0.0, 0.5), box(0.0, 1.5, hx=3.0, hy=0.25, m=INF, vy=-1.0)],
      gravity=G, friction=0.5, kinematic=(2,), segments=[(45, {}), (30, {2: (0.0, 0.0)})],
      figures=figures)


def crush_elevator(quick: bool) -> Scene:
  def figures(s, r):
    return {"max sink into elevator": f"{sink(r, s, 1, 0):.3f}", "box y end": f4(r.pos[-1, 1, 1]),
            "outcome": squeeze_outcome(r, s, 1, 0, 2)}
  return scene(
      "crush_elevator", "A box on a kinematic elevator (half-extents 3 x 0.25, top y=1) rising "
      "at 1 u/s for 60 steps into a static ceiling (bottom y=2.5, 0.5 above the box); the "
      "elevator's top ends at y=2, half the box's height short of the ceiling, and stops for "
      "30 steps. The box should stay between them (not fall through the elevator or pass the "
      "ceiling) and the squeeze be reported.",
      [box(0.0, 0.75, hx=3.0, hy=0.25, m=INF, vy=1.0), box(0.0, 1.5),
       box(0.0, 2.75, hx=3.0, hy=0.25, m=INF)],
      gravity=G, friction=0.5, kinematic=(0,), segments=[(60, {}), (30, {0: (0.0, 0.0)})],
      figures=figures)


def crush_one_way(quick: bool, elevator: bool = False) -> Scene:
  """crush_ceiling and crush_elevator with the floor or the elevator one-way."""
  base = crush_elevator(quick) if elevator else crush_ceiling(quick)
  what = "elevator" if elevator else "floor"

  def figures(s, r):
    return {f"max sink into {what}": f"{sink(r, s, 1, 0):.3f}", "box y end": f4(r.pos[-1, 1, 1]),
            "outcome": squeeze_outcome(r, s, 1, 0, 2)}
  return dataclasses.replace(
      base, name=base.name + "_one_way", one_way=(0,), figures=figures,
      about=base.about.replace("static floor", "one-way (jump-through) static floor").replace(
          "kinematic elevator", "kinematic one-way (jump-through) elevator") + " One-way: "
      "the one-way body must hold the crushed box like a solid one (jaxchain only: the peer "
      "adapters have no one-way bodies).")


def one_way_rise(quick: bool) -> Scene:
  def figures(s, r):
    return {"box y after 1 step": f4(r.pos[1, 1, 1]), "box vy after 1 step": f4(r.vel[1, 1, 1]),
            "box y end": f4(r.pos[-1, 1, 1])}
  return scene(
      "one_way_rise", "A box of mass 80 rising at vy=+0.3 with its bottom 0.03 below the top of "
      "a one-way ledge (top y=0; 0.03 is the one-way margin), gravity, no friction. It is "
      "coming from below: the first step is free flight (y 0.4723, vy 0.1365, no energy "
      "gain). At its peak, 0.028 below the top and falling, the ledge catches it: that "
      "step lifts it onto the top, +m g (sink) (about 21 J), a start the penetration measure "
      "counts (a sink within the margin); it ends resting on the ledge (y end +0.5).",
      [box(0.0, -0.1, hx=3.0, hy=0.1, m=INF), box(0.0, 0.47, m=80.0, vy=0.3)],
      gravity=G, friction=0.0, segments=[(60, {})], figures=figures, one_way=(0,))


def one_way_room(quick: bool, seed: int = 0) -> Scene:
  """random_room with two one-way ledges across it and a third of the boxes one-way."""
  base = random_room(quick, seed)
  w, h = ROOM_W, ROOM_H
  ledges = [box(w / 4, h / 3, hx=w / 4, hy=0.05, m=INF), box(3 * w / 4, 2 * h / 3, hx=w / 4, hy=0.05, m=INF)]
  keep = [k for k in range(4, len(base.pos))  # Boxes clear of the ledges (no overlap at the start).
          if all(np.any(np.abs(base.pos[k] - np.array(l[0])) >= np.array(l[1]) + 0.5 + 0.02)
                 for l in ledges)]
  bodies = ([(tuple(base.pos[k]), tuple(base.half[k]), base.mass[k], tuple(base.vel[k]))
             for k in range(4)] + ledges
            + [(tuple(base.pos[k]), tuple(base.half[k]), base.mass[k], tuple(base.vel[k])) for k in keep])
  crates = tuple(6 + i for i in range(len(keep)) if i % 3 == 0)

  def figures(s, r):
    p = r.pos[:, 6:]
    out = (p[..., 0] < 0) | (p[..., 0] > w) | (p[..., 1] < 0) | (p[..., 1] > h)
    return {"boxes that left the room": str(int(np.sum(np.any(out, axis=0)))),
            "penetration end": f"{penetration(r.pos[-1:], s)[0]:.2e}"}
  return scene(
      "one_way_room", f"random_room (seed {seed}) with two one-way ledges (half-extents "
      f"{w / 4:g} x 0.05, at y = {h / 3:.2f} and {2 * h / 3:.2f}) and every third box a "
      f"one-way crate ({len(keep)} boxes, those clear of the ledges), gravity, friction 0.5. "
      "Energy should only fall; no box leaves the room (jaxchain only). Penetration counts "
      "one-way pairs too (a box resting on a ledge, a crate on a box).",
      bodies, gravity=G, friction=0.5, segments=base.segments, figures=figures,
      one_way=(4, 5) + crates)


SCENES = (head_on, free_chain, friction_contrast, edge_fall,
          functools.partial(edge_fall, gap=0.15), random_room, rider,
          functools.partial(rider, up=True), crush_ceiling, crush_elevator, crush_one_way,
          functools.partial(crush_one_way, elevator=True), one_way_rise, one_way_room)


# --- Engines ---------------------------------------------------------------------------
# Each engine: `name`, `version`, `run(scene) -> Run`.


class Peer:
  """A Python peer engine (`_bench.PythonPeer`: Box2D 2.3 or pymunk, the adapters of
  `_peer_worker.py`) run through a scene's segments, recording every step. Box2D:
  static, kinematic and fixed-rotation dynamic bodies, 8 velocity / 3 position
  iterations, friction mixed as sqrt(f_a f_b) (each fixture gets the scene's
  coefficient). pymunk: STATIC, KINEMATIC and dynamic bodies of infinite moment, 10
  iterations, collision slop 0.1, friction mixed as f_a f_b (each shape gets the square
  root of the scene's coefficient)."""

  def __init__(self, peer: _bench.PythonPeer):
    self.peer, self.name, self.version = peer, peer.name, peer.version

  def run(self, scene: Scene) -> Run:
    pos, vel = self.peer.record(
        _bench.peer_scene(scene.pos, scene.half, scene.mass, scene.vel, kinematic=scene.kinematic,
                          gravity=scene.gravity, friction=scene.friction, dt=DT),
        scene.segments)
    return Run(pos, vel)


# jaxchain is being moved from physics in the Config to physics in the World:
# `World.create(..., friction=, gravity=)` with `Config.gravity` / `Config.friction` as
# on/off switches that `for_world` derives. Until that lands, `Config(gravity=(gx, gy),
# friction=mu)`. Both are supported.
WORLD_PHYSICS = "friction" in inspect.signature(jc.World.create).parameters


def jaxchain_world(scene: Scene) -> tuple[jc.World, jc.Config]:
  """The scene as a jaxchain world and the config `Config.for_world` picks for it."""
  if WORLD_PHYSICS:
    one_way = {}
    if scene.one_way:  # Only worlds of a jaxchain with one-way bodies get the keyword.
      one_way = dict(one_way=np.isin(np.arange(len(scene.pos)), scene.one_way))
    world = jc.World.create(scene.pos, scene.half, scene.mass, scene.vel,
                            friction=scene.friction, gravity=scene.gravity, **one_way)
    cfg = jc.Config.for_world(world)
  else:
    world = jc.World.create(scene.pos, scene.half, scene.mass, scene.vel)
    cfg = jc.Config.for_world(world, gravity=scene.gravity, friction=scene.friction)
  assert cfg.dt == DT, cfg.dt
  return world, cfg


@functools.partial(jax.jit, static_argnames=("cfg", "steps"))
def _roll(world, cfg, steps):
  """`steps` of `jc.step`, recording positions, velocities and `crushed` (all False
  where the World has no `crushed` field) after every step."""
  def body(w, _):
    w = jc.step(w, cfg)
    crushed = getattr(w, "crushed", jnp.zeros(w.pos.shape[0], bool))
    return w, (w.pos, w.vel, crushed)
  return jax.lax.scan(body, world, None, length=steps)


def bit_names(code: int) -> list[str]:
  """Names of the `jc.status` bits set in `code` (whatever bits the installed version has)."""
  return [k for k, bit in vars(jc.status).items()
          if k.isupper() and isinstance(bit, int) and bit in jc.status.MESSAGES and code & bit]


class JaxChain:
  name = "jaxchain"

  def __init__(self):
    self.version = f"jaxchain {jc.__version__} (jax {jax.__version__})"

  def run(self, scene: Scene) -> Run:
    world, cfg = jaxchain_world(scene)
    has_crushed = hasattr(world, "crushed")
    pos, vel, crushed = [np.asarray(world.pos)[None]], [np.asarray(world.vel)[None]], []
    for steps, changes in scene.segments:
      for k, v in changes.items():
        world = world.replace(vel=world.vel.at[k].set(jnp.asarray(v, world.vel.dtype)))
      world, (p, v, c) = _roll(world, cfg, steps)
      pos.append(np.asarray(p))
      vel.append(np.asarray(v))
      crushed.append(np.asarray(c))
    crushed = np.concatenate(crushed)
    bits = bit_names(int(np.asarray(world.status)))
    if has_crushed:
      hit = np.flatnonzero(np.any(crushed, axis=0))
      bits.append(f"crushed {hit.tolist()} in {int(np.sum(np.any(crushed, axis=1)))} steps"
                  if hit.size else "crushed none")
    else:
      bits.append("no World.crushed")
    messages = tuple(jc.check(world))
    return Run(np.concatenate(pos).astype(float), np.concatenate(vel).astype(float),
               failure="; ".join(bits) if bits else "none", messages=messages)


def load_engines() -> tuple[list, list[str]]:
  engines, skipped = _bench.load_peers(("Box2D", "pymunk"))
  return [JaxChain()] + [Peer(e) for e in engines], skipped


# --- Measures --------------------------------------------------------------------------


def penetration(traj: np.ndarray, scene: Scene) -> np.ndarray:
  """`[t]` largest penetration per state: `_bench.penetration` (every pair not both
  immovable), or for a scene with one-way bodies (which bodies pass from below and the
  sides) `jc.metrics.max_penetration` (a one-way pair counts with a sink within the
  one-way margin, the overlap the one-way rule resolves)."""
  if not scene.one_way:
    return _bench.penetration(traj, scene)
  world, _ = jaxchain_world(scene)
  pos = jnp.asarray(traj, world.pos.dtype)
  return np.asarray(jax.vmap(lambda p: jc.metrics.max_penetration(world.replace(pos=p)))(pos))



def measures(scene: Scene, run: Run) -> dict[str, str]:
  """The columns every scene reports."""
  mov = scene.movable
  m, p, v = scene.mass[mov], run.pos[:, mov], run.vel[:, mov]
  energy = np.sum(0.5 * m * np.sum(v * v, -1) - m * (p @ np.asarray(scene.gravity)), axis=-1)
  d_energy = np.diff(energy)
  momentum = np.sum(m[:, None] * v, axis=1)  # [t, 2]
  if scene.momentum == "conserved":
    err = np.max(np.linalg.norm(momentum - momentum[0], axis=-1)) / np.linalg.norm(momentum[0])
    mom = f"{err:.2e}"
  elif scene.momentum == "no gain":
    mom = f"{max(np.max(momentum[:, 0] - momentum[0, 0]), 0.0) / abs(momentum[0, 0]):.2e} (gain)"
  else:
    mom = "-"
  return {"momentum error": mom, "max dE in a step": f"{np.max(d_energy):+.2e}",
          "total dE": f"{energy[-1] - energy[0]:+.3g}",
          "max penetration": f"{np.max(penetration(run.pos, scene)):.2e}",
          "failure reported": run.failure}


# --- Run and output --------------------------------------------------------------------


def main():
  parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
  parser.add_argument("--quick", action="store_true", help="shorter room and chain runs")
  args = add_common_args(parser).parse_args()
  run_ = _bench.Run.start()
  engines, skipped = load_engines()
  for line in skipped:
    print(line, file=sys.stderr)
  scenes = [make(args.quick or args.smoke) for make in (SCENES[:1] if args.smoke else SCENES)]
  rows = {s.name: [] for s in scenes}
  messages = []
  with tqdm(total=len(scenes) * len(engines), desc="scenes x engines", unit="run") as bar:
    for s in scenes:
      for e in engines:
        bar.set_postfix_str(f"{s.name} / {e.name}")
        if s.one_way and not isinstance(e, JaxChain):  # The peer adapters have no one-way bodies.
          bar.update()
          continue
        run = e.run(s)
        rows[s.name].append({"engine": e.name, **measures(s, run), **s.figures(s, run)})
        messages += [f"{s.name}: {m}" for m in run.messages]
        bar.update()
  write(run_, engines, skipped, scenes, rows, messages, out_dir(args))


def write(run_, engines, skipped, scenes, rows, messages, out) -> None:
  api = ("`World.create(..., friction=, gravity=)` + `Config.for_world(world)`" if WORLD_PHYSICS
         else "`Config.for_world(world, gravity=, friction=)` (the World.create of this commit "
              "takes no physics)")
  lines = [
      "# Physics fidelity: momentum, energy, riders, crushing",
      "",
      f"Run time in the header: compiles included. jaxchain built through {api}.",
      "",
      "Engines: " + "; ".join(e.version for e in engines) + ".",
      "",
  ]
  lines += [f"- {line}" for line in skipped] + ([""] if skipped else [])
  lines += [
      "Every engine gets the same host arrays (dt = 1/60, fixed rotation, restitution 0, "
      "no sleeping). Box2D: kinematic bodies for the moving platforms, 8 velocity / 3 "
      "position iterations, its 0.01 polygon skin. pymunk: `KINEMATIC` bodies, 10 "
      "iterations, collision slop 0.1 (its defaults). jaxchain: `Config.for_world`; a "
      "kinematic body is an immovable body (mass inf) with a velocity, stopped by "
      "`world.replace(vel=...)`.",
      "",
      "Columns: momentum error = `max_t |P(t) - P(0)| / |P(0)|` over the movable bodies "
      "(\"(gain)\": `max_t (Px(t) - Px(0)) / |Px(0)|`, where an external force may only take "
      "momentum away; `-` where gravity or platforms act). Energy E = sum over movable "
      "bodies of `0.5 m |v|^2 - m g . p`; max dE in a step is the largest change from one "
      "step to the next (positive = a gain), total dE = E(end) - E(start). Max penetration: "
      "largest min(overlap_x, overlap_y) of any pair not both immovable, over all steps. "
      "Failure reported: jaxchain's sticky `world.status` bits at the end and the bodies "
      "`world.crushed` marked in any step; the peers report nothing (n/a). jaxchain runs in "
      "float32: energy changes below `m |g| * spacing(y)` (about 1e-2 for the 1e4 box, 1e-6 "
      "for a unit box) are rounding.",
      "",
  ]
  for s in scenes:
    table = rows[s.name]
    cols = list(table[0])
    lines += [f"## {s.name}", "", s.about, "",
              "| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    lines += ["| " + " | ".join(r[c] for c in cols) + " |" for r in table]
    lines.append("")
  lines += ["## jaxchain `jc.check` messages", ""]
  lines += [f"- {m}" for m in messages] or ["- none"]
  _bench.write_result(out, "conservation.md", lines, run_)


if __name__ == "__main__":
  main()
