"""The Python peer engines (Box2D 2.3, Box2D v3, pymunk) on host arrays: NumPy only.

One adapter per engine, used two ways:

- in this process: `_bench` imports this module (so the benchmark scripts share one copy
  of each adapter) and calls `time_windows` and `record` directly;
- in another interpreter, as a worker: Box2D v3 (PyPI `box2d-python`) ships wheels for
  Python 3.12 and later only, so `benchmarks/peers.py --v3-python PATH` starts

      PATH benchmarks/_peer_worker.py "Box2D v3"

  which needs nothing but NumPy and the engine, and serves it over JSON lines: one
  request a line on stdin, one reply a line on stdout. The worker times its own steps,
  so the pipe is never inside a timed span.

Requests (a JSON object each, by `op`):

- `{"op": "hello"}` -> `{"name", "version"}`.
- `{"op": "time", "scene", "settle", "steps", "min_s", "max_reps"}` -> `{"seconds",
  "reps", "pos"}`: builds the scene, steps it `settle` steps (untimed), then times
  `steps` steps; again with a fresh world until `min_s` seconds are timed or `max_reps`
  windows ran. `seconds` is the timed total over the `reps` windows, `pos` the positions
  `[n, 2]` after the last one.
- `{"op": "record", "scene", "segments"}` -> `{"pos", "vel"}`: runs `segments`, a list of
  `[steps, {body: [vx, vy]}]` (the velocities set before the segment's steps), and
  returns positions and velocities `[steps + 1, n, 2]` (the start included).
- `{"op": "quit"}` ends the worker.

A request that fails gets `{"error": "..."}` (with the traceback's last line) and the
worker goes on.

A scene is a dict of plain lists: `pos`, `half` (`[n, 2]`), `mass` (`[n]`, `Infinity`
for an immovable body), `vel` (`[n, 2]`), `kinematic` (indices of immovable bodies that
move by their velocity), `gravity` (`[gx, gy]`), `friction` (one coefficient for every
contact), `dt`, and `drive`: `null` or `[body, speed]`, a body whose x velocity is set to
`speed` before every step (the push chain's player), and optionally `solver`: the
engine's accuracy setting, `{"iterations": [velocity, position]}` for Box2D 2.3,
`{"substeps": k}` for Box2D v3, `{"iterations": k}` for pymunk (default: each engine's
own, as below). Every engine gets fixed-rotation boxes, restitution 0 and no sleeping.
"""

from __future__ import annotations

import json
import math
import sys
import time
import traceback

import numpy as np

BOX2D_ITERATIONS = (8, 3)  # Box2D 2.3: velocity and position iterations a step.
BOX2D_V3_SUBSTEPS = 4  # Box2D v3: substeps a step (its soft-step solver's default).


def _bodies(scene: dict):
  """`(k, pos, half, mass, vel, kinematic)` for every body of `scene`."""
  kinematic = set(scene.get("kinematic", ()))
  vel = scene.get("vel") or [[0.0, 0.0]] * len(scene["mass"])
  for k, (p, h, m, v) in enumerate(zip(scene["pos"], scene["half"], scene["mass"], vel)):
    yield k, (float(p[0]), float(p[1])), (float(h[0]), float(h[1])), float(m), \
        (float(v[0]), float(v[1])), k in kinematic


def _density(m: float, h) -> float:
  return m / (4 * h[0] * h[1]) if math.isfinite(m) else 0.0


class Box2D:
  """pybox2d (Box2D 2.3): `b2World`, polygon boxes, 8 velocity / 3 position iterations.
  Friction mixes as sqrt(f_a f_b): each fixture gets the scene's coefficient."""

  name = "Box2D"

  def __init__(self):
    import Box2D as b2  # noqa: N813
    self.b2 = b2
    self.version = f"Box2D {b2.__version__} (pybox2d)"

  def world(self, scene: dict) -> "_Box2DWorld":
    return _Box2DWorld(self.b2, scene)


class _Box2DWorld:
  def __init__(self, b2, scene):
    self.world = b2.b2World(gravity=tuple(scene["gravity"]))
    self.world.SetAllowSleeping(False)  # The constructor's doSleep flag is ignored.
    self.dt, self.bodies = scene["dt"], []
    self.iterations = tuple((scene.get("solver") or {}).get("iterations", BOX2D_ITERATIONS))
    for _, p, h, m, v, kinematic in _bodies(scene):
      if kinematic:
        body = self.world.CreateKinematicBody(position=p, linearVelocity=v)
      elif math.isinf(m):
        body = self.world.CreateStaticBody(position=p)
      else:
        body = self.world.CreateDynamicBody(position=p, linearVelocity=v, fixedRotation=True)
      body.CreatePolygonFixture(box=h, density=_density(m, h), friction=scene["friction"],
                                restitution=0.0)
      self.bodies.append(body)

  def step(self):
    self.world.Step(self.dt, *self.iterations)

  def velocity(self, k):
    return tuple(self.bodies[k].linearVelocity)

  def set_velocity(self, k, v):
    self.bodies[k].linearVelocity = tuple(v)

  def state(self):
    return ([tuple(b.position) for b in self.bodies],
            [tuple(b.linearVelocity) for b in self.bodies])


class Box2DV3:
  """Box2D v3 through `box2d-python` (CFFI bindings): `box2d.World`, fixed-rotation boxes,
  4 substeps a step (its soft-step solver's default), no sleeping. Friction mixes as
  sqrt(f_a f_b), as in 2.3: each shape gets the scene's coefficient."""

  name = "Box2D v3"

  def __init__(self):
    import importlib.metadata
    import box2d  # PyPI box2d-python (not pybox2d's `Box2D`).
    self.b2 = box2d
    self.version = f"Box2D v3 (box2d-python {importlib.metadata.version('box2d-python')})"

  def world(self, scene: dict) -> "_Box2DV3World":
    return _Box2DV3World(self.b2, scene)


class _Box2DV3World:
  def __init__(self, b2, scene):
    self.world = b2.World(gravity=tuple(scene["gravity"]))
    self.world.enable_sleep = False
    self.dt, self.bodies = scene["dt"], []
    self.substeps = int((scene.get("solver") or {}).get("substeps", BOX2D_V3_SUBSTEPS))
    for _, p, h, m, v, kinematic in _bodies(scene):
      builder = self.world.new_body().position(*p)
      if kinematic:
        builder = builder.kinematic().linear_velocity(*v)
      elif math.isinf(m):
        builder = builder.static()
      else:
        builder = builder.dynamic().fixed_rotation().linear_velocity(*v)
      builder = builder.box(2 * h[0], 2 * h[1], density=_density(m, h),
                            friction=scene["friction"], restitution=0.0)
      self.bodies.append(builder.build())

  def step(self):
    self.world.step(self.dt, self.substeps)

  def velocity(self, k):
    v = self.bodies[k].linear_velocity
    return v.x, v.y

  def set_velocity(self, k, v):
    self.bodies[k].linear_velocity = tuple(v)

  def state(self):
    pos, vel = [], []
    for b in self.bodies:
      p, v = b.position, b.linear_velocity
      pos.append((p.x, p.y))
      vel.append((v.x, v.y))
    return pos, vel


class Pymunk:
  """pymunk (Chipmunk2D): `Space` with gravity, `Poly.create_box`, its default 10
  iterations and collision slop 0.1. Friction mixes as f_a f_b: each shape gets the
  square root of the scene's coefficient."""

  name = "pymunk"

  def __init__(self):
    import pymunk
    self.pm = pymunk
    self.version = f"pymunk {pymunk.version} (Chipmunk {pymunk.chipmunk_version.split('-')[0]})"

  def world(self, scene: dict) -> "_PymunkWorld":
    return _PymunkWorld(self.pm, scene)


class _PymunkWorld:
  def __init__(self, pm, scene):
    self.space = pm.Space()
    self.space.gravity = tuple(scene["gravity"])
    iterations = (scene.get("solver") or {}).get("iterations")
    if iterations is not None:
      self.space.iterations = int(iterations)
    self.dt, self.bodies = scene["dt"], []
    for _, p, h, m, v, kinematic in _bodies(scene):
      if kinematic:
        body = pm.Body(body_type=pm.Body.KINEMATIC)
      elif math.isinf(m):
        body = pm.Body(body_type=pm.Body.STATIC)
      else:
        body = pm.Body(mass=m, moment=float("inf"))  # Fixed rotation.
      body.position = p
      if body.body_type != pm.Body.STATIC:
        body.velocity = v
      shape = pm.Poly.create_box(body, (2 * h[0], 2 * h[1]))
      shape.friction, shape.elasticity = scene["friction"] ** 0.5, 0.0
      self.space.add(body, shape)
      self.bodies.append(body)

  def step(self):
    self.space.step(self.dt)

  def velocity(self, k):
    return tuple(self.bodies[k].velocity)

  def set_velocity(self, k, v):
    self.bodies[k].velocity = tuple(v)

  def state(self):
    return [tuple(b.position) for b in self.bodies], [tuple(b.velocity) for b in self.bodies]


ENGINES = {cls.name: cls for cls in (Box2D, Box2DV3, Pymunk)}


def run(world, steps: int, drive=None, states: list | None = None) -> float:
  """Steps `world` `steps` times (driving `drive = (body, speed)` along x before each
  step); appends `world.state()` after every step to `states` when given. Returns the
  seconds the loop took."""
  t0 = time.perf_counter()
  for _ in range(steps):
    if drive is not None:
      k, speed = drive
      world.set_velocity(k, (speed, world.velocity(k)[1]))
    world.step()
    if states is not None:
      states.append(world.state())
  return time.perf_counter() - t0


def time_windows(engine, scene: dict, settle: int, steps: int, min_s: float,
                 max_reps: int) -> dict:
  """The `time` request: windows of `steps` steps after `settle` untimed ones, a fresh
  world each, until `min_s` seconds are timed (at least one window, at most `max_reps`)."""
  seconds, reps, world = 0.0, 0, None
  while reps < max(max_reps, 1) and (reps == 0 or seconds < min_s):
    world = engine.world(scene)
    run(world, settle, scene.get("drive"))
    seconds += run(world, steps, scene.get("drive"))
    reps += 1
  return dict(seconds=seconds, reps=reps, pos=world.state()[0])


def record(engine, scene: dict, segments) -> dict:
  """The `record` request: positions and velocities after every step of `segments`."""
  world = engine.world(scene)
  states = [world.state()]
  for steps, changes in segments:
    for k, v in changes.items():
      world.set_velocity(int(k), v)
    run(world, steps, scene.get("drive"), states)
  return dict(pos=[s[0] for s in states], vel=[s[1] for s in states])


def serve(engine, stdin=sys.stdin, stdout=sys.stdout) -> None:
  """Answers requests (one JSON object a line) until `quit` or the end of `stdin`."""
  for line in stdin:
    if not line.strip():
      continue
    try:
      req = json.loads(line)
      op = req.get("op")
      if op == "quit":
        break
      if op == "hello":
        reply = dict(name=engine.name, version=engine.version, python=sys.version.split()[0],
                     numpy=np.__version__)
      elif op == "time":
        reply = time_windows(engine, req["scene"], req["settle"], req["steps"], req["min_s"],
                             req["max_reps"])
      elif op == "record":
        reply = record(engine, req["scene"], req["segments"])
      else:
        reply = dict(error=f"unknown op {op!r} (hello, time, record, quit)")
    except Exception as e:  # noqa: BLE001 - the caller gets the error, the worker goes on.
      reply = dict(error=f"{type(e).__name__}: {e}",
                   traceback=traceback.format_exc().strip().splitlines()[-3:])
    stdout.write(json.dumps(reply) + "\n")
    stdout.flush()


def main(argv: list[str]) -> int:
  if len(argv) != 1 or argv[0] not in ENGINES:
    print(f"usage: python _peer_worker.py ENGINE, ENGINE one of {', '.join(map(repr, ENGINES))}",
          file=sys.stderr)
    return 2
  try:
    engine = ENGINES[argv[0]]()
  except Exception as e:  # noqa: BLE001 - said on stdout too, where the caller reads.
    msg = (f"{argv[0]} does not import in Python {sys.version.split()[0]} ({sys.executable}): "
           f"{type(e).__name__}: {e}")
    print(json.dumps(dict(error=msg)), flush=True)
    return 1
  serve(engine)
  return 0


if __name__ == "__main__":
  sys.exit(main(sys.argv[1:]))
