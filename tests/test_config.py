"""Config: frozen, hashable, validated; for_world leaves out what a scene does not use."""

import dataclasses

import jax
import jax.extend.core
import jax.numpy as jnp
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


def test_for_world_keeps_what_a_fit_starts_at_zero():
  # Issue 43 item 2: a guess of friction 0 or gravity 0 switched the feature off, and its
  # gradient was silently 0. keep= leaves the named switches on (and nothing else changes).
  world = jc.World.create([[0.0, 0.5], [0.0, -0.5]], [[0.5, 0.5], [20.0, 0.5]], [1.0, np.inf],
                          vel=[[2.0, 0.0], [0.0, 0.0]], gravity=(0.0, 0.0))
  lean = jc.Config.for_world(world)
  assert not lean.has_friction and not lean.has_gravity
  kept = jc.Config.for_world(world, keep=("friction", "gravity"))
  assert kept.has_friction and kept.has_gravity
  assert kept == jc.Config.for_world(world, friction=True, gravity=True)
  assert jc.Config.for_world(world, keep="friction") == lean.replace(friction=True)
  free = scenes.push_chain(2, wall=False).world(gravity=(0.0, 0.0))
  assert jc.Config.for_world(free, keep=("immovable",)).immovable
  with pytest.raises(ValueError, match=r"keep= takes names from .*'frictoin'"):
    jc.Config.for_world(world, keep=("frictoin",))


def test_for_world_on_a_padded_batch_looks_at_active_bodies_only():
  small = scenes.push_chain(1, wall=False).world()
  big = scenes.push_chain(5, wall=False).world()
  cfg = jc.Config.for_world(jc.stack([small, big]))
  assert cfg.immovable is False  # Padding is immovable but inactive.
  assert cfg.depth == 6


def _step_ops(config, world) -> int:
  """Equations of the step (in every sub-jaxpr) apart from its O(n) check of the features
  the world uses that the config leaves out (`flags.switched_off`, which a lean config
  traces and a full one does not)."""
  def count(jaxpr) -> int:
    total = 0
    for eqn in jaxpr.eqns:
      total += "switched_off" not in str(eqn.source_info.name_stack)
      for sub in jax.extend.core.jaxprs_in_params(eqn.params):
        total += count(sub)
    return total

  return count(jax.make_jaxpr(lambda w: jc.step(w, config))(world).jaxpr)


def _pair_ops(config, world) -> int:
  """Equations of the step (in every sub-jaxpr) with a per-pair output: `[n, n]` pairs of
  one world, `[..., n, n, B]` in the core's batch-minor layout (one world runs as a batch
  of `stepping.ONE_WORLD`)."""
  n = world.num_bodies
  pair = (n, n, jc.stepping.ONE_WORLD)

  def count(jaxpr) -> int:
    total = 0
    for eqn in jaxpr.eqns:
      total += sum(tuple(getattr(v.aval, "shape", ()))[-3:] == pair
                   or getattr(v.aval, "shape", None) == (n, n) for v in eqn.outvars)
      for sub in jax.extend.core.jaxprs_in_params(eqn.params):
        total += count(sub)
    return total

  return count(jax.make_jaxpr(lambda w: jc.step(w, config))(world).jaxpr)


@pytest.mark.parametrize("feature", [
    dict(gravity=True), dict(friction=True), dict(immovable=True), dict(substeps=2),
    dict(one_way=True), dict(layers=True), dict(sensors=True),
])
def test_switched_off_features_are_not_traced(feature):
  world = scenes.push_chain(3, wall=False).world(gravity=(0.0, 0.0))
  lean = jc.Config.for_world(world)
  assert (lean.has_gravity, lean.has_friction, lean.immovable, lean.substeps, lean.one_way,
          lean.layers, lean.sensors) == (False, False, False, 1, False, False, False)
  if set(feature) & {"one_way", "layers", "sensors"}:
    # Left out, they cost no per-pair work at all (only an O(n) SWITCHED_OFF check).
    assert _pair_ops(lean, world) < _pair_ops(lean.replace(**feature), world)
  else:
    assert _step_ops(lean, world) < _step_ops(lean.replace(**feature), world)


@pytest.mark.parametrize("change, switch", [
    (dict(one_way=[False, True, False, False]), "one_way"),
    (dict(sensor=[False, False, True, False]), "sensors"),
    (dict(mask=[0xFFFFFFFF, 1, 0xFFFFFFFF, 0xFFFFFFFF], category=[1, 1, 2, 1]), "layers"),
    (dict(category=[1, 0, 1, 1]), "layers"),  # Category 0 collides with nothing.
])
def test_for_world_switches_on_what_the_world_uses_and_flags_what_a_config_leaves_out(
    change, switch):
  world = scenes.push_chain(3, wall=False).world(gravity=(0.0, 0.0))
  assert not getattr(jc.Config.for_world(world), switch)
  used = world.replace(**{k: np.asarray(v, world.__dict__[k].dtype) for k, v in change.items()})
  cfg = jc.Config.for_world(used)
  assert getattr(cfg, switch)
  assert int(jc.step(used, cfg).status) == 0
  off = jc.step(used, cfg.replace(**{switch: False}))
  assert int(off.status) & jc.status.SWITCHED_OFF


def test_layers_that_every_mask_covers_are_left_out():
  # Every body in layer 2, every mask all bits: every pair interacts, nothing to trace.
  world = scenes.push_chain(3, wall=False).world(gravity=(0.0, 0.0))
  world = world.replace(category=np.full(4, 2, np.uint32))
  cfg = jc.Config.for_world(world)
  assert not cfg.layers
  assert int(jc.step(world, cfg).status) == 0  # And not flagged as switched off.


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


# --- Physical switches: values live in the World ---------------------------------------


def test_switches_accept_bools_and_numpy_bools_only():
  assert jc.Config(gravity=np.bool_(False), friction=np.bool_(True)) == jc.Config(
      gravity=False, friction=True)
  assert jc.Config().has_gravity and jc.Config().has_friction  # Both traced by default.
  cfg = jc.Config(gravity=False, friction=False)
  assert (cfg.has_gravity, cfg.has_friction) == (False, False)
  with pytest.raises(ValueError, match=r"World.create\(..., friction=0.3\)"):
    jc.Config(friction=0.3)
  with pytest.raises(ValueError, match="Config.gravity is now an on/off switch"):
    jc.Config().replace(gravity=(0.0, 0.0))


def test_for_world_switches_on_what_the_world_sets():
  free = lambda **kw: scenes.push_chain(2, wall=False).world(**kw)
  assert jc.Config.for_world(free()).has_gravity  # Default gravity, movable bodies.
  assert not jc.Config.for_world(free()).has_friction  # Default friction 0.
  assert jc.Config.for_world(free(friction=0.2)).has_friction
  one = free().replace(friction=jnp.array([0.0, 0.0, 0.1]))
  assert jc.Config.for_world(one).has_friction  # Any active body.
  inactive = jc.World.create([[0.0, 0.0], [2.0, 0.0]], [0.5, 0.5], 1.0, friction=[0.0, 0.5],
                             active=np.array([True, False]))
  assert not jc.Config.for_world(inactive).has_friction
  assert not jc.Config.for_world(free(gravity=(0.0, 0.0))).has_gravity
  assert jc.Config.for_world(free(gravity=(0.5, 0.0))).has_gravity  # Sideways counts.
  walls = jc.World.create([[0.0, 0.0]], [0.5, 0.5], np.inf)  # Nothing gravity could move.
  assert not jc.Config.for_world(walls).has_gravity
  assert not jc.Config.for_world(free(friction=0.2), friction=False).has_friction  # Overrides.
  assert jc.Config.for_world(free(gravity=(0.0, 0.0)), gravity=True).has_gravity


def test_for_world_on_a_batch_looks_at_each_worlds_gravity():
  still = jc.World.create([[0.0, 5.0]], [0.5, 0.5], 1.0, gravity=(0.0, 0.0))
  heavy = still.replace(gravity=jnp.array([0.0, -6000.0]))  # 100 per step: 3 substeps.
  walls = jc.World.create([[0.0, 0.0]], [0.5, 0.5], np.inf, gravity=(0.0, -6000.0))
  assert not jc.Config.for_world(jc.stack([still, walls])).has_gravity  # No movable body feels it.
  cfg = jc.Config.for_world(jc.stack([still, heavy]))
  assert cfg.has_gravity and cfg.substeps == 3
  assert jc.Config.for_world(jc.stack([still, still])).substeps == 1
  assert jc.Config.for_world(heavy, gravity=False).substeps == 1  # Off: not counted.


def test_for_world_refuses_scenes_that_need_too_many_substeps():
  tiny = jc.World.create([[0.0, 0.0]], [1e-9, 1e-9], 1.0)  # Would need 1.7 million.
  with pytest.raises(ValueError, match=r"body 0 would need \d+ substeps, more than "
                                       r"MAX_SUBSTEPS = 64") as err:
    jc.Config.for_world(tiny)
  for part in ("moves at 0.164 along y", "half-extent 1e-09", "larger bodies", "smaller dt",
               "substeps="):
    assert part in str(err.value)
  assert jc.Config.for_world(tiny, substeps=4).substeps == 4  # An explicit choice is kept.
  slow = jc.World.create([[0.0, 0.0], [3.0, 0.0]], [0.5, 0.5], 1.0)
  fast = slow.replace(vel=jnp.array([[0.0, 0.0], [1e4, 0.0]]))
  with pytest.raises(ValueError, match=r"body 1 of world 1 would need .* moves at 1e\+04 along x"):
    jc.Config.for_world(jc.stack([slow, fast]))
  limit = jc.config.MAX_SUBSTEPS  # Just at the limit is fine.
  edge = slow.replace(vel=jnp.array([[0.0, 0.0], [limit * 60 / 1.25 * 0.99, 0.0]]),
                      gravity=jnp.zeros(2))
  assert jc.Config.for_world(edge).substeps == limit


@pytest.mark.parametrize("kwargs", [
    dict(dt=np.float32(0.01)), dict(dt=np.float64(0.02)), dict(skin=np.float32(1e-3)),
    dict(depth=np.int64(3)), dict(iterations=np.int32(2)), dict(substeps=np.int16(2)),
    dict(links=np.int64(4)), dict(immovable=np.bool_(False)), dict(broadphase=np.str_("dense")),
    dict(dt=np.int64(1)),
])
def test_numpy_scalars_are_accepted(kwargs):
  cfg = jc.Config(**kwargs)
  for name, value in kwargs.items():
    got = getattr(cfg, name)
    assert got == value and type(got) in (int, float, bool, str)  # Stored as Python values.
  assert hash(cfg) == hash(jc.Config(**{k: v.item() for k, v in kwargs.items()}))


@pytest.mark.parametrize("kwargs, match", [
    (dict(depth=True), "Config.depth: expected an integer"),
    (dict(depth=np.bool_(True)), "Config.depth: expected an integer"),
    (dict(iterations=np.float64(2.0)), "Config.iterations: expected an integer"),
    (dict(links=np.bool_(True)), "Config.links: expected None or an integer"),
    (dict(dt=np.bool_(True)), "Config.dt: expected a finite number"),
    (dict(dt=np.float32("nan")), "Config.dt: expected a finite number"),
    (dict(immovable=np.int64(1)), "Config.immovable: expected a bool"),
])
def test_numpy_scalars_of_the_wrong_kind_are_rejected(kwargs, match):
  with pytest.raises(ValueError, match=match):
    jc.Config(**kwargs)


@pytest.mark.parametrize("kwargs, match", [
    (dict(neighbors=0), "Config.neighbors: expected None or an integer >= 1"),
    (dict(neighbors=2.5), "Config.neighbors: expected None or an integer >= 1"),
    (dict(neighbors=True), "Config.neighbors: expected None or an integer >= 1"),
    (dict(margin=-0.1), "Config.margin: must be >= 0"),
    (dict(margin=float("nan")), "Config.margin: expected a finite number"),
    (dict(margin=np.bool_(True)), "Config.margin: expected a finite number"),
])
def test_bad_neighbor_table_fields_raise_a_clear_error(kwargs, match):
  with pytest.raises(ValueError, match=match):
    jc.Config(**kwargs)


def test_neighbor_table_fields_are_stored_as_python_values():
  cfg = jc.Config(neighbors=np.int64(10), margin=np.float32(0.25))
  assert cfg.neighbors == 10 and type(cfg.neighbors) is int
  assert cfg.margin == 0.25 and type(cfg.margin) is float
  assert cfg == jc.Config(neighbors=10, margin=0.25) and hash(cfg) == hash(cfg.replace())


def test_for_world_foresees_the_stacks_gravity_builds():
  # Issue 42 item 3: the rooms of falling boxes touch nothing at the start, so depth 8
  # (from the chains now) was cut short once they settled into columns of 16, 32 and 64
  # (DEPTH_EXHAUSTED, IMPULSES_SCALED, OVERLAP_LEFT). Under gravity the tallest column
  # sizes the depth.
  for n, column in ((256, 16), (1024, 32), (4096, 64)):
    world = jc.World.create(*(getattr(scenes.lattice_room(n), k) for k in ("pos", "half", "mass")))
    assert jc.sizing.stack_bound(world, (0.0, -9.81)) == column
    assert jc.Config.for_world(world).depth == column
  # Two columns of 12 boxes, 0.5 apart, touching sideways only at their edges (no stack).
  pos = [[0.0, 0.5 + 1.5 * k] for k in range(12)] + [[1.0, 0.5 + 1.5 * k] for k in range(12)]
  world = jc.World.create(pos, [0.5, 0.5], 1.0)
  assert jc.sizing.stack_bound(world, (0.0, -9.81)) == 12
  assert jc.sizing.stack_bound(world, (-9.81, 0.0)) == 2  # Gravity along x: rows of 2.
  assert jc.sizing.stack_bound(world, (0.0, 0.0)) == 0
  assert jc.Config.for_world(world.replace(gravity=jnp.zeros(2))).depth == 8  # No stacks.
  batch = jc.stack([world, world.replace(gravity=jnp.array([-9.81, 0.0]))])
  assert jc.sizing.stack_bound(batch, batch.gravity) == 12  # Each world's own gravity.
