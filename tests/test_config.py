"""Config: frozen, hashable, validated; for_world leaves out what a scene does not use."""

import dataclasses

import jax
import numpy as np
import pytest

import jaxchain as jc
from jaxchain import scenes


def test_frozen_and_hashable_by_value():
  a, b = jc.Config(depth=3, gravity=np.bool_(False)), jc.Config(depth=3, gravity=False)
  assert a == b and hash(a) == hash(b)
  assert a != jc.Config(depth=4, gravity=False)
  with pytest.raises(dataclasses.FrozenInstanceError):
    a.depth = 5


@pytest.mark.parametrize("kwargs, match", [
    (dict(dt=0.0), "Config.dt: must be > 0"),
    (dict(dt=float("nan")), "Config.dt: expected a finite number"),
    (dict(depth=-1), "Config.depth: expected an integer >= 0"),
    (dict(depth=2.5), "Config.depth: expected an integer"),
    (dict(iterations=0), "Config.iterations: expected an integer >= 1"),
    (dict(substeps=0), "Config.substeps"),
    (dict(friction=-0.1), "Config.friction is now an on/off switch"),
    (dict(friction=0.3), r"friction values live in the World: World.create\(..., friction=0.3\)"),
    (dict(friction=0), "Config.friction is now an on/off switch"),
    (dict(gravity=(0.0,)), "Config.gravity is now an on/off switch"),
    (dict(gravity=(0.0, -9.81)), r"World.create\(..., gravity=\(0.0, -9.81\)\)"),
    (dict(gravity=(0.0, float("inf"))), "Config.gravity"),
    (dict(broadphase="octree"), "Config.broadphase: expected one of"),
    (dict(skin=-1.0), "Config.skin: must be >= 0"),
    (dict(immovable=1), "Config.immovable: expected a bool"),
])
def test_bad_config_raises_a_clear_error(kwargs, match):
  with pytest.raises(ValueError, match=match):
    jc.Config(**kwargs)


def test_for_world_switches_off_unused_features():
  free = scenes.push_chain(3, wall=False).world(gravity=(0.0, 0.0))
  cfg = jc.Config.for_world(free)
  assert cfg.immovable is False and cfg.depth == 4 and not cfg.has_gravity
  assert not cfg.has_friction
  walled = scenes.push_chain(20, wall=True).world(friction=0.5)
  cfg = jc.Config.for_world(walled)
  assert cfg.immovable is True and cfg.depth == 21 and cfg.has_friction  # The whole chain.
  loose = scenes.random_boxes(np.random.default_rng(0), 30, extent=40.0).world()
  assert jc.Config.for_world(loose).depth == jc.Config.depth  # Nothing long: the default.
  assert jc.Config.for_world(walled, depth=32).depth == 32  # Overrides win.


def test_for_world_on_a_padded_batch_looks_at_active_bodies_only():
  small = scenes.push_chain(1, wall=False).world()
  big = scenes.push_chain(5, wall=False).world()
  cfg = jc.Config.for_world(jc.stack([small, big]))
  assert cfg.immovable is False  # Padding is immovable but inactive.
  assert cfg.depth == 6


def _jaxpr_lines(config, world):
  return str(jax.make_jaxpr(lambda w: jc.step(w, config))(world)).count("\n")


@pytest.mark.parametrize("feature", [
    dict(gravity=True), dict(friction=True), dict(immovable=True), dict(substeps=2),
])
def test_switched_off_features_are_not_traced(feature):
  world = scenes.push_chain(3, wall=False).world(gravity=(0.0, 0.0))
  lean = jc.Config.for_world(world)
  assert (lean.has_gravity, lean.has_friction, lean.immovable, lean.substeps) == (
      False, False, False, 1)
  assert _jaxpr_lines(lean, world) < _jaxpr_lines(lean.replace(**feature), world)


def test_lean_config_gives_the_same_answer_on_scenes_it_fits():
  scene = scenes.push_chain(5, overlap=0.3, wall=False, overlaps=[0.1, 0.0, 0.2, 0.05])
  world = scene.world(gravity=(0.0, 0.0))
  lean = jc.Config.for_world(world)
  assert lean.immovable is False
  full = lean.replace(immovable=True, depth=8)
  np.testing.assert_allclose(jc.resolve(world, lean).pos, jc.resolve(world, full).pos, atol=1e-6)


def test_grid_is_not_traced_for_small_worlds():
  world = scenes.push_chain(3, wall=True).world()
  lean = jc.Config.for_world(world)
  assert lean.broadphase == "dense"
  grid = lean.replace(broadphase="grid", grid=jc.broadphase.allocate(world))
  text = lambda cfg: str(jax.make_jaxpr(lambda w: jc.step(w, cfg))(world))
  sorts = lambda cfg: text(cfg).count(" sort[")
  assert sorts(lean) == 0 and sorts(grid) > 0
