"""Writes tests/data/golden.npz: fixed benchmark scenes and their states after a rollout.

`tests/test_golden.py` replays every scene and requires the same positions and
velocities to 1e-6, so a faster formulation of the step cannot change its answers
unnoticed. Regenerate (`python tests/data/make_golden.py`) only when the physics is
meant to change, and say so in the commit message.

Stored from commit bafbcc8 (the physics issue's final commit).
"""

from __future__ import annotations

import pathlib

import numpy as np

import jaxchain as jc
from jaxchain import scenes

STEPS = 30
DT = 1 / 60


def cases() -> dict[str, tuple[jc.World, dict, np.ndarray | None]]:
  """`{name: (world, config kwargs, controls [n, 2] or None)}`."""
  out = {}
  w = scenes.lattice_room(64).world(friction=0.5)
  out["room64"] = (w, dict(depth=8, links=4), None)
  demo = scenes.platformer(np.random.default_rng(0))
  w = demo.scene.world(friction=0.5)
  u = np.zeros((w.num_bodies, 2), np.float32)
  u[demo.player, 0] = 30.0
  out["platformer"] = (w, dict(depth=10, links=4), u)
  chain = scenes.push_chain(16, overlap=0.2)
  vel = np.zeros((16 + 2, 2))
  vel[0, 0] = 3.0
  out["chain16"] = (chain.world(vel, friction=0.3, gravity=(0.0, 0.0)), dict(depth=17, links=4), None)
  out["stack10"] = (scenes.stack(10).world(friction=0.5), dict(depth=11, links=4), None)
  rng = np.random.default_rng(1)
  w = scenes.box_room(rng, 64).world(friction=0.4)
  out["box_room_grid"] = (w, dict(depth=8, links=4, broadphase="grid",
                                  grid=jc.broadphase.allocate(w)), None)
  return out


def run(world: jc.World, kwargs: dict, controls) -> jc.World:
  cfg = jc.Config(dt=DT, **kwargs)
  final, _ = jc.rollout(world, cfg, STEPS, None if controls is None else np.asarray(controls))
  return final


def main() -> None:
  arrays = {}
  for name, (world, kwargs, controls) in cases().items():
    final = run(world, kwargs, controls)
    arrays[f"{name}/pos"] = np.asarray(final.pos)
    arrays[f"{name}/vel"] = np.asarray(final.vel)
    arrays[f"{name}/status"] = np.asarray(final.status)
    print(name, jc.check(final))
  np.savez_compressed(pathlib.Path(__file__).with_name("golden.npz"), **arrays)


if __name__ == "__main__":
  main()
