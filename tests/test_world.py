"""World.create validation and batching of worlds of different sizes."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxchain as jc

GOOD = dict(pos=[[0.0, 0.0], [2.0, 0.0]], half=[[0.5, 0.5], [0.5, 0.5]], mass=[1.0, np.inf])


def make(**changes):
  return jc.World.create(**{**GOOD, **changes})


def test_create_converts_mass_to_inverse_mass():
  w = make(vel=[[1.0, 0.0], [0.0, 0.0]])
  assert w.pos.shape == (2, 2) and w.vel.shape == (2, 2) and w.half.shape == (2, 2)
  np.testing.assert_array_equal(w.inv_mass, [1.0, 0.0])
  np.testing.assert_array_equal(w.active, [True, True])
  np.testing.assert_array_equal(w.movable, [True, False])


def test_shared_half_extents_and_scalar_mass_broadcast():
  w = jc.World.create(GOOD["pos"], [0.25, 1.0], 2.0)
  np.testing.assert_array_equal(w.half, [[0.25, 1.0], [0.25, 1.0]])
  np.testing.assert_array_equal(w.inv_mass, [0.5, 0.5])


@pytest.mark.parametrize("changes, match", [
    (dict(pos=[[0.0, np.nan], [2.0, 0.0]]), r"pos: NaN or inf for bodies \[0\]"),
    (dict(pos=[[0.0, 0.0], [np.inf, 0.0]]), r"pos: NaN or inf for bodies \[1\]"),
    (dict(vel=[[0.0, 0.0], [np.nan, 0.0]]), r"vel: NaN or inf"),
    (dict(vel=[[0.0, 0.0], [-np.inf, 0.0]]), r"vel: NaN or inf"),
    (dict(half=[[0.5, 0.0], [0.5, 0.5]]), r"half: half-extents must be > 0; bodies \[0\]"),
    (dict(half=[[0.5, 0.5], [-1.0, 0.5]]), r"half: .* bodies \[1\]"),
    (dict(half=[[0.5, np.inf], [0.5, 0.5]]), r"half: NaN or inf"),
    (dict(mass=[0.0, 1.0]), r"mass: masses must be > 0 .* bodies \[0\]"),
    (dict(mass=[1.0, -2.0]), r"mass: masses must be > 0"),
    (dict(mass=[np.nan, 1.0]), r"mass: NaN mass for bodies \[0\]"),
    (dict(pos=[0.0, 0.0]), r"pos: expected shape \(n, 2\)"),
    (dict(pos=[[0.0, 0.0, 0.0], [1.0, 1.0, 1.0]]), r"pos: expected shape \(n, 2\)"),
    (dict(half=[[0.5, 0.5]] * 3), r"half: expected shape \(2, 2\)"),
    (dict(mass=[1.0, 1.0, 1.0]), r"mass: expected shape \(2,\)"),
    (dict(vel=[[0.0, 0.0]]), r"vel: expected shape \(2, 2\)"),
    (dict(pos=[["a", "b"], ["c", "d"]]), r"pos: cannot convert"),
    (dict(active=[1, 1]), r"active: expected a bool array"),
])
def test_bad_input_raises_a_clear_error(changes, match):
  with pytest.raises(ValueError, match=match):
    make(**changes)


def test_stack_pads_with_inactive_immovable_slots():
  a = jc.World.create([[0.0, 0.0]], [0.5, 0.5], 1.0)
  b = jc.World.create([[0.0, 0.0], [3.0, 0.0], [6.0, 0.0]], [0.5, 0.5], 2.0)
  batch = jc.stack([a, b])
  assert batch.pos.shape == (2, 3, 2)
  np.testing.assert_array_equal(batch.active, [[True, False, False], [True, True, True]])
  np.testing.assert_array_equal(batch.inv_mass[0], [1.0, 0.0, 0.0])
  assert jc.stack([a], capacity=5).pos.shape == (1, 5, 2)


def test_pad_and_stack_errors():
  a = jc.World.create([[0.0, 0.0], [3.0, 0.0]], [0.5, 0.5], 1.0)
  with pytest.raises(ValueError, match="capacity 1 is smaller than the 2 bodies"):
    a.pad(1)
  with pytest.raises(ValueError, match="need at least one world"):
    jc.stack([])
  with pytest.raises(ValueError, match="expected a single world"):
    jc.stack([a, a]).pad(4)
  with pytest.raises(ValueError, match="capacity 1 is smaller than the 2 bodies of world 0"):
    jc.stack([a], capacity=1)
  with pytest.raises(ValueError, match="world 1 is not a single world"):
    jc.stack([a, jc.stack([a, a])])


def test_world_is_a_pytree():
  w = make()
  leaves = jax.tree.leaves(w)
  # pos, vel, half, inv_mass, active, friction, gravity, one_way, sensor, category, mask,
  # crushed, touching, sensed, status
  assert len(leaves) == 15
  doubled = jax.tree.map(lambda x: x * 2 if x.dtype != bool else x, w)
  np.testing.assert_array_equal(doubled.pos, 2 * np.asarray(w.pos))


# --- Physical parameters in the World --------------------------------------------------


def test_friction_and_gravity_are_stored_per_body_and_per_world():
  w = make(friction=0.3, gravity=(1.0, -2.0))
  np.testing.assert_allclose(w.friction, [0.3, 0.3])
  np.testing.assert_array_equal(w.gravity, [1.0, -2.0])
  np.testing.assert_array_equal(w.crushed, [False, False])
  assert w.friction.dtype == w.gravity.dtype == w.pos.dtype and w.crushed.dtype == bool
  np.testing.assert_allclose(make(friction=[0.1, 0.0]).friction, [0.1, 0.0])
  default = make()
  np.testing.assert_array_equal(default.friction, 0.0)
  np.testing.assert_allclose(default.gravity, [0.0, -9.81])


@pytest.mark.parametrize("changes, match", [
    (dict(friction=-0.1), r"friction: coefficients must be finite and >= 0; bodies \[0, 1\]"),
    (dict(friction=[0.2, np.nan]), r"friction: NaN friction for bodies \[1\]"),
    (dict(friction=[np.inf, 0.2]), r"friction: .* bodies \[0\] are not"),
    (dict(friction=[0.1, 0.2, 0.3]), r"friction: expected shape \(2,\) or a scalar"),
    (dict(gravity=(0.0, np.nan)), r"gravity: expected finite numbers"),
    (dict(gravity=(0.0, -9.81, 0.0)), r"gravity: expected shape \(2,\)"),
    (dict(gravity=[[0.0, -9.81]] * 2), r"gravity: expected shape \(2,\)"),
])
def test_bad_friction_or_gravity_raises_a_clear_error(changes, match):
  with pytest.raises(ValueError, match=match):
    make(**changes)


def test_pad_and_stack_carry_the_new_fields():
  a = jc.World.create([[0.0, 0.0]], [0.5, 0.5], 1.0, friction=0.4, gravity=(0.0, 0.0))
  b = jc.World.create([[0.0, 0.0], [3.0, 0.0]], [0.5, 0.5], 1.0, friction=[0.1, 0.2])
  padded = a.pad(3)
  np.testing.assert_allclose(padded.friction, [0.4, 0.0, 0.0])
  np.testing.assert_array_equal(padded.crushed, [False] * 3)
  np.testing.assert_array_equal(padded.gravity, [0.0, 0.0])  # Per world: not padded.
  batch = jc.stack([a, b])
  np.testing.assert_allclose(batch.friction, [[0.4, 0.0], [0.1, 0.2]])
  np.testing.assert_array_equal(batch.crushed, np.zeros((2, 2), bool))
  np.testing.assert_allclose(batch.gravity, [[0.0, 0.0], [0.0, -9.81]])
  assert batch.friction.dtype == batch.gravity.dtype == batch.pos.dtype


# --- Validation after the cast to float32 ----------------------------------------------


@pytest.mark.parametrize("changes, match", [
    (dict(pos=[[0.0, 0.0], [1e39, 0.0]]), r"pos: too large for float32 .* bodies \[1\]"),
    (dict(vel=[[0.0, -1e39], [0.0, 0.0]]), r"vel: too large for float32 .* bodies \[0\]"),
    (dict(mass=[1.0, 1e-38]), r"mass: masses of bodies \[1\] are below the smallest normal float32"),
    (dict(mass=[1e-39, 1.0]), r"mass: masses of bodies \[0\] are below the smallest normal"),
    (dict(mass=[1e-46, 1.0]), r"mass: masses of bodies \[0\] are below"),  # 0 in float32.
    (dict(mass=[1.0, 1e38]), r"mass: masses of bodies \[1\] are so large that 1/mass flushes to 0"),
    (dict(mass=[1e39, 1.0]), r"mass: masses of bodies \[0\] are so large"),  # inf in float32.
    (dict(half=[[0.5, 0.5], [1e-46, 0.5]]), r"half: half-extents of bodies \[1\] become 0 or inf"),
    (dict(half=[[1e-40, 0.5], [0.5, 0.5]]), r"half: half-extents of bodies \[0\] become 0"),
    (dict(half=[[0.5, 0.5], [0.5, 1e39]]), r"half: half-extents of bodies \[1\] become 0 or inf"),
    (dict(friction=[0.0, 1e39]), r"friction: too large for float32 .* bodies \[1\]"),
    (dict(gravity=(0.0, -1e39)), r"gravity: too large for float32"),
])
def test_values_float32_cannot_hold_are_rejected(changes, match):
  with pytest.raises(ValueError, match=match):
    make(**changes)


def test_extreme_but_representable_values_are_accepted():
  w = make(mass=[8e37, 1.2e-38], pos=[[3e38, 0.0], [-3e38, 0.0]], half=[[2e-38, 1e38]] * 2)
  assert np.all(np.asarray(w.inv_mass) > 0) and np.all(np.isfinite(np.asarray(w.inv_mass)))


# --- World.replace checks concrete values ------------------------------------------------


@pytest.mark.parametrize("changes, match", [
    (lambda w: dict(active=jnp.array([1, 1])), r"active: expected bool of shape \(2,\) .* got int32"),
    (lambda w: dict(active=np.ones(2)), r"active: expected bool .* got float64"),
    (lambda w: dict(active=[1, 0]), r"active: expected bool"),
    (lambda w: dict(crushed=jnp.zeros(2)), r"crushed: expected bool"),
    (lambda w: dict(pos=np.zeros((2, 2))), r"pos: expected float32 of shape \(2, 2\) .* got float64"),
    (lambda w: dict(pos=jnp.zeros((3, 2))), r"pos: expected float32 of shape \(2, 2\) .* \(3, 2\)"),
    (lambda w: dict(friction=jnp.zeros(3)), r"friction: expected float32 of shape \(2,\)"),
    (lambda w: dict(gravity=jnp.zeros(3)), r"gravity: expected float32 of shape \(2,\)"),
    (lambda w: dict(status=jnp.zeros(())), r"status: expected int32"),
    (lambda w: dict(half=w.half.at[1, 0].set(jnp.nan)), r"half: NaN or inf for bodies \[1\]"),
    (lambda w: dict(half=w.half.at[0, 1].set(0.0)), r"half: half-extents must be > 0; bodies \[0\]"),
    (lambda w: dict(half=w.half.at[1, 1].set(-1.0)), r"half: .* bodies \[1\] are not"),
    (lambda w: dict(pos=w.pos.at[1, 0].set(jnp.nan)), r"pos: NaN or inf for bodies \[1\]"),
    (lambda w: dict(pos=w.pos.at[0, 0].set(jnp.inf)), r"pos: NaN or inf for bodies \[0\]"),
    (lambda w: dict(vel=w.vel.at[0, 1].set(-jnp.inf)), r"vel: NaN or inf for bodies \[0\]"),
    (lambda w: dict(friction=jnp.array([0.1, -0.1])), r"friction: .* >= 0; bodies \[1\]"),
    (lambda w: dict(friction=jnp.array([jnp.nan, 0.1])), r"friction: NaN friction for bodies \[0\]"),
    (lambda w: dict(gravity=jnp.array([0.0, jnp.inf])), r"gravity: expected finite numbers"),
    (lambda w: dict(gravity=(jnp.nan, 0.0)), r"gravity: expected finite numbers"),
    (lambda w: dict(inv_mass=jnp.array([-1.0, 0.0])), r"inv_mass: .* >= 0 .* bodies \[0\]"),
    (lambda w: dict(inv_mass=jnp.array([1.0, jnp.nan])), r"inv_mass: .* bodies \[1\]"),
])
def test_replace_rejects_bad_concrete_values(changes, match):
  w = make()
  with pytest.raises(ValueError, match=match):
    w.replace(**changes(w))


def test_replace_accepts_good_values_and_converts_python_ones():
  w = make()
  out = w.replace(pos=w.pos + 1.0, friction=jnp.full(2, 0.5), gravity=(0, 0), status=3,
                  active=np.array([True, False]), half=[[1.0, 1.0], [0.5, 0.5]])
  np.testing.assert_array_equal(out.pos, np.asarray(w.pos) + 1.0)
  assert out.gravity.dtype == w.gravity.dtype and out.gravity.tolist() == [0.0, 0.0]
  assert out.status.dtype == np.int32 and int(out.status) == 3
  assert out.half.dtype == w.half.dtype
  np.testing.assert_array_equal(out.active, [True, False])
  with pytest.raises(TypeError, match="World has no field 'mass'"):
    w.replace(mass=jnp.ones(2))


def test_replace_on_a_batch_names_world_and_body():
  batch = jc.stack([make(), make()])
  with pytest.raises(ValueError, match=r"pos: NaN or inf for \(world, body\) \[\(1, 0\)\]"):
    batch.replace(pos=batch.pos.at[1, 0, 1].set(jnp.nan))
  with pytest.raises(ValueError, match=r"gravity: .* worlds \[1\]"):
    batch.replace(gravity=batch.gravity.at[1, 0].set(jnp.inf))
  assert batch.replace(friction=jnp.ones((2, 2))).friction.shape == (2, 2)


def test_replace_skips_checks_on_traced_values():
  w = make()
  nan_pos = jax.jit(lambda w: w.replace(pos=w.pos * jnp.nan).pos)(w)  # Traced: not checked.
  assert np.all(np.isnan(np.asarray(nan_pos)))
  bumped = jax.vmap(lambda w: w.replace(friction=w.friction - 1.0).friction)(jc.stack([w, w]))
  np.testing.assert_allclose(bumped, -1.0)
  grad = jax.grad(lambda x: jnp.sum(w.replace(half=w.half * x).half))(1.0)
  assert float(grad) == 2.0  # The sum of the half-extents.


# --- Platformer fields (issue 12) ---------------------------------------------------------


def test_create_takes_one_way_sensor_and_layers_per_body_or_for_all():
  w = jc.World.create([[0.0, 0.0], [2.0, 0.0]], [0.5, 0.5], 1.0, one_way=[False, True],
                      sensor=True, category=[1, 2**31], mask=3)
  assert w.one_way.tolist() == [False, True] and w.sensor.tolist() == [True, True]
  assert w.category.dtype == np.uint32 and w.category.tolist() == [1, 2**31]
  assert w.mask.tolist() == [3, 3]
  assert w.touching.shape == (2, 4) and not w.touching.any() and not w.sensed.any()
  d = jc.World.create([[0.0, 0.0]], [0.5, 0.5], 1.0)
  assert (d.one_way.tolist(), d.sensor.tolist(), d.category.tolist(), d.mask.tolist()) == (
      [False], [False], [1], [0xFFFFFFFF])


@pytest.mark.parametrize("kwargs, message", [
    (dict(one_way=1), "one_way: expected bools"),
    (dict(sensor=[True]), r"sensor: expected shape \(2,\)"),
    (dict(category=-1), r"category: layer bits must lie in \[0, 2\*\*32\) \(uint32\); got -1"),
    (dict(mask=[0, 2**32]), r"mask: layer bits .* bodies \[1\] are not"),
    (dict(category=1.5), "category: expected integers"),
    (dict(mask=True), "mask: expected integers"),
])
def test_create_rejects_bad_platformer_fields(kwargs, message):
  with pytest.raises(ValueError, match=message):
    jc.World.create([[0.0, 0.0], [2.0, 0.0]], [0.5, 0.5], 1.0, **kwargs)


def test_replace_and_stack_keep_layer_bits():
  w = jc.World.create([[0.0, 0.0], [2.0, 0.0]], [0.5, 0.5], 1.0, category=[2, 4])
  assert w.replace(mask=[1, 2]).mask.tolist() == [1, 2]
  with pytest.raises(ValueError, match="layer bits"):
    w.replace(mask=[-1, 2])
  b = jc.stack([w, jc.World.create([[0.0, 0.0]], [0.5, 0.5], 1.0)])
  assert b.category.tolist() == [[2, 4], [1, 1]] and b.touching.shape == (2, 2, 4)


def test_from_arrays_equals_create_and_runs_under_jit_and_vmap():
  args = ([[0.0, 0.0], [1.0, 0.0]], [0.5, 0.5], [1.0, float("inf")])
  kw = dict(friction=0.2, category=[1, 2], one_way=[False, True], gravity=(0.0, -3.0))
  a, b = jc.World.create(*args, **kw), jc.World.from_arrays(*args, **kw)
  for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b)):
    assert x.dtype == y.dtype and np.array_equal(x, y)
  build = jax.jit(jax.vmap(lambda y: jc.World.from_arrays(
      jnp.zeros((2, 2)).at[1, 1].set(y), [0.5, 0.5], jnp.array([jnp.inf, 1.0]))))
  w = build(jnp.array([1.0, 2.0, 3.0]))
  assert w.pos.shape == (3, 2, 2) and w.inv_mass.tolist() == [[0.0, 1.0]] * 3
  assert w.pos[:, 1, 1].tolist() == [1.0, 2.0, 3.0]
