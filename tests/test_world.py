"""World.create validation and batching of worlds of different sizes."""

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
  import jax
  w = make()
  leaves = jax.tree.leaves(w)
  assert len(leaves) == 9  # pos, vel, half, inv_mass, active, friction, gravity, crushed, status
  doubled = jax.tree.map(lambda x: x * 2 if x.dtype != bool else x, w)
  np.testing.assert_array_equal(doubled.pos, 2 * np.asarray(w.pos))
