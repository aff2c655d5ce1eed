"""jaxchain.queries: touching_bodies, query_aabb/query_point, raycast, move_and_slide,
drive_platforms, drop_through. Exact answers on small scenes, under jit and vmap.

Every world here is padded to `CAP` bodies, so each query compiles once for the module.
"""

import doctest
import importlib.util
import pathlib

import chex
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxchain as jc
from jaxchain import core, queries

INF = float("inf")
CAP = 10
DT = 1 / 60
EXACT = dict(atol=2e-6, rtol=0.0)  # Closed-form answers on O(1) coordinates (helpers.TOL).


def make(pos, half, mass, **kw):
  return jc.World.create(pos, half, mass, **kw).pad(CAP)


def test_docstring_examples():
  result = doctest.testmod(queries, extraglobs={"jc": jc}, optionflags=doctest.ELLIPSIS)
  assert result.attempted > 0 and result.failed == 0


# --- touching_bodies -----------------------------------------------------------------------

def _scene():
  """A floor (0), a wall (1) at x in [3, 4], boxes A (2) and B (3) stacked against it, a
  one-way ledge (4) with a box (5) on it and a box (6) rising through it, a sensor (7)
  overlapping B, and a box (8) beside A in a layer it does not share."""
  return make(
      pos=[[0.0, -0.5], [3.5, 2.0], [2.5, 0.5], [2.5, 1.5], [-3.0, 2.0], [-4.0, 2.6],
           [-2.0, 1.7], [2.5, 2.3], [1.5, 0.5]],
      half=[[5.0, 0.5], [0.5, 2.0], [0.5, 0.5], [0.5, 0.5], [2.0, 0.1], [0.5, 0.5],
            [0.5, 0.5], [0.5, 0.5], [0.5, 0.5]],
      mass=[INF, INF, 1.0, 1.0, INF, 1.0, 1.0, INF, 1.0],
      vel=[[0.0, 0.0]] * 6 + [[0.0, 3.0]] + [[0.0, 0.0]] * 2,
      one_way=[False] * 4 + [True] + [False] * 4, sensor=[False] * 7 + [True, False],
      category=[1] * 8 + [2], mask=[0xFFFFFFFF] * 8 + [2])


def test_touching_bodies_known_scene():
  index, overflow = jc.touching_bodies(_scene(), k=2)
  no = [-1, -1]
  expected = [
      [no, no, [1, 2], no],            # The floor holds the wall and A (not box 8: layers).
      [no, [2, 3], no, [0, -1]],       # The wall: A and B on its left, stands on the floor.
      [[1, -1], no, [3, -1], [0, -1]],  # A: wall, B above, floor below (8 is filtered).
      [[1, -1], no, no, [2, -1]],      # B: wall, on A; the sensor above does not count.
      [no, no, [5, -1], no],           # The one-way ledge holds box 5, not the riser 6.
      [no, no, no, [4, -1]],           # Box 5 stands on the one-way ledge.
      [no, no, no, no],                # Box 6 rises through the ledge: no contact.
      [no, no, no, no],                # The sensor touches nothing.
      [no, no, no, no],                # Box 8 shares no layer with anything here.
  ] + [[no] * 4] * (CAP - 9)
  assert index.tolist() == expected
  assert index.dtype == jnp.int32 and not overflow.any()
  assert index[:, 3, 0].tolist()[:6] == [-1, 0, 0, 2, -1, 4]  # What each stands on.


def test_touching_bodies_agree_with_the_step_flags():
  w = _scene()
  stepped = jc.step(w, jc.Config.for_world(w))
  index, _ = jc.touching_bodies(stepped)
  flags = np.asarray(index[..., 0] >= 0)
  movable = np.asarray(stepped.movable)
  np.testing.assert_array_equal(flags[movable], np.asarray(stepped.touching)[movable])
  assert np.asarray(stepped.touching)[[2, 3, 5]].any(-1).all()  # The scene is not trivial.


def test_touching_bodies_no_side_contact_at_a_seam():
  # A box whose edge is on the seam between two floor tiles, a rounding error inside
  # both: it stands on the tiles and touches no tile's side (the step's seam rule).
  for eps in (0.0, 1e-7, 1e-6, -1e-6):
    w = make([[-0.5, -0.5], [0.5, -0.5], [-0.5 + eps, 0.5 - abs(eps)]], [0.5, 0.5],
             [INF, INF, 1.0])
    index = np.asarray(jc.touching_bodies(w)[0][2])
    assert (index[:3] == -1).all() and index[3, 0] == 0, (eps, index)


def test_touching_bodies_overflow_lists_the_first_k():
  # A wide box on three small ones: with k = 2 its -y row is full and overflows.
  w = make([[0.0, 1.5], [-1.0, 0.5], [0.0, 0.5], [1.0, 0.5]], [[1.5, 0.5], [0.4, 0.5],
           [0.4, 0.5], [0.4, 0.5]], [1.0, INF, INF, INF])
  index, overflow = jc.touching_bodies(w, k=2)
  assert index[0, 3].tolist() == [1, 2] and overflow.tolist() == [True] + [False] * (CAP - 1)
  index, overflow = jc.touching_bodies(w, k=3)
  assert index[0, 3].tolist() == [1, 2, 3] and not overflow.any()


def test_touching_bodies_under_vmap_and_jit():
  a = _scene()
  b = a.replace(pos=a.pos.at[5, 1].set(4.0))  # Box 5 lifted off the ledge.
  batch = jc.stack([a, b])
  index, overflow = jax.jit(jax.vmap(lambda w: jc.touching_bodies(w, k=2)))(batch)
  single, _ = jc.touching_bodies(a, k=2)
  np.testing.assert_array_equal(index[0], single)
  assert index[1, 5, 3, 0] == -1 and index[1, 4, 2, 0] == -1 and not overflow.any()


def test_touching_bodies_rejects_bad_arguments():
  w = _scene()
  with pytest.raises(ValueError, match="k must be an integer >= 1"):
    jc.touching_bodies(w, k=0)
  with pytest.raises(ValueError, match="single world"):
    jc.touching_bodies(jc.stack([w, w]))


# --- query_aabb, query_point ---------------------------------------------------------------

def _row():
  """Three unit boxes at x = 0, 2, 4 (categories 1, 2, 4), the middle one a sensor."""
  return make([[0.0, 0.0], [2.0, 0.0], [4.0, 0.0]], [0.5, 0.5], 1.0, category=[1, 2, 4],
              sensor=[False, True, False])


def test_query_aabb_and_point_are_closed_and_filter_by_layer():
  w = _row()
  pick = lambda x: np.flatnonzero(np.asarray(x)).tolist()
  assert pick(jc.query_aabb(w, [0.5, -2.0], [1.5, 2.0])) == [0, 1]  # Touches both faces.
  assert pick(jc.query_aabb(w, [0.51, -2.0], [1.49, 2.0])) == []
  assert pick(jc.query_aabb(w, [-9.0, 0.5], [9.0, 0.6])) == [0, 1, 2]  # Top faces.
  assert pick(jc.query_aabb(w, [-9.0, -1.0], [9.0, 1.0], mask=4 | 1)) == [0, 2]
  assert pick(jc.query_point(w, [4.5, -0.5])) == [2]  # A corner.
  assert pick(jc.query_point(w, [1.0, 0.0])) == []
  assert pick(jc.query_point(w, [2.0, 0.0], mask=1)) == []
  # Inactive padding (unit boxes at the origin) is never found.
  assert pick(jc.query_point(w, [0.0, 0.0])) == [0]


def test_queries_vmap_over_points_and_worlds():
  w = _row()
  xs = jnp.linspace(-1.0, 5.0, 13)
  found = jax.jit(jax.vmap(lambda x: jc.query_point(w, jnp.stack([x, 0.0]))))(xs)
  expected = [[abs(x - c) <= 0.5 for c in (0.0, 2.0, 4.0)] for x in np.linspace(-1.0, 5.0, 13)]
  np.testing.assert_array_equal(np.asarray(found)[:, :3], expected)
  batch = jc.stack([w, w.replace(pos=w.pos + jnp.array([[1.0, 0.0]]))])
  hits = jax.vmap(lambda v: jc.query_aabb(v, jnp.array([0.0, 0.0]), jnp.array([0.1, 0.1])))(batch)
  assert np.flatnonzero(hits[0]).tolist() == [0] and np.flatnonzero(hits[1]).tolist() == []
  # An inverted box under jit finds nothing (even inside a body that spans it).
  inverted = jax.jit(jc.query_aabb)(w, jnp.array([0.2, 0.0]), jnp.array([-0.2, 0.1]))
  assert not inverted.any()


def test_queries_reject_bad_host_input():
  w = _row()
  with pytest.raises(ValueError, match="lo must be <= hi"):
    jc.query_aabb(w, [1.0, 0.0], [0.0, 1.0])
  with pytest.raises(ValueError, match=r"shape \(2,\)"):
    jc.query_point(w, [1.0, 0.0, 0.0])
  with pytest.raises(ValueError, match="finite"):
    jc.query_point(w, [np.nan, 0.0])
  with pytest.raises(ValueError, match="mask must be one integer"):
    jc.query_point(w, [0.0, 0.0], mask=-1)


# --- raycast -------------------------------------------------------------------------------

def _boxes():
  """A floor (0, top at y = 0), a wall (1, left face x = 3), a box (2) at (1, 0.5), and a
  sensor (3) between the origin and the box."""
  return make([[0.0, -0.5], [3.5, 1.0], [1.0, 0.5], [0.5, 0.5]],
              [[5.0, 0.5], [0.5, 1.0], [0.25, 0.25], [0.1, 0.1]], [INF, INF, 1.0, INF],
              sensor=[False, False, False, True], category=[1, 1, 2, 1])


def _hit(r):
  return bool(r.hit), int(r.body), float(r.distance), r.point.tolist(), r.normal.tolist()


def test_raycast_exact_hits_in_every_direction():
  w = _boxes()
  assert _hit(jc.raycast(w, [0.0, 0.5], [3.0, 0.0])) == (True, 2, 0.75, [0.75, 0.5], [-1.0, 0.0])
  assert _hit(jc.raycast(w, [0.0, 1.0], [1.0, 0.0])) == (True, 1, 3.0, [3.0, 1.0], [-1.0, 0.0])
  assert _hit(jc.raycast(w, [1.0, 2.0], [0.0, -5.0])) == (True, 2, 1.25, [1.0, 0.75], [0.0, 1.0])
  assert _hit(jc.raycast(w, [2.0, 2.0], [0.0, -1.0])) == (True, 0, 2.0, [2.0, 0.0], [0.0, 1.0])
  assert _hit(jc.raycast(w, [1.0, -3.0], [0.0, 1.0])) == (True, 0, 2.0, [1.0, -1.0], [0.0, -1.0])
  assert _hit(jc.raycast(w, [5.0, 1.0], [-1.0, 0.0])) == (True, 1, 1.0, [4.0, 1.0], [1.0, 0.0])
  # Diagonal: through the sensor, grazing the box's corner (0.75, 0.25), onto the floor.
  r = jc.raycast(w, [-1.0, 2.0], [1.0, -1.0])
  assert _hit(r)[:2] == (True, 0) and r.normal.tolist() == [0.0, 1.0]
  np.testing.assert_allclose(r.distance, 2.0 * np.sqrt(2.0), rtol=1e-6)
  np.testing.assert_allclose(r.point, [1.0, 0.0], **EXACT)


def test_raycast_rules_inside_graze_reach_mask_ignore():
  w = _boxes()
  # From inside the wall: the wall is ignored; the ray leaves it and hits nothing.
  assert _hit(jc.raycast(w, [3.5, 1.0], [1.0, 0.0])) == (False, -1, INF, [3.5, 1.0], [0.0, 0.0])
  # From inside the floor, straight down: nothing; up, out of the floor: the box above.
  assert jc.raycast(w, [1.0, -0.5], [0.0, 1.0]).body == 2
  # Along the floor's top face: grazing is no hit, where nothing stands on it (left), and
  # the base of the wall that stands on it (right: there the ray is between the two).
  assert not jc.raycast(w, [-4.0, 0.0], [-1.0, 0.0]).hit
  assert not jc.raycast(w, [3.5, 2.0], [1.0, 0.0]).hit  # Along the wall's top face.
  assert _hit(jc.raycast(w, [-4.0, 0.0], [1.0, 0.0])) == (True, 1, 7.0, [3.0, 0.0], [-1.0, 0.0])
  assert jc.raycast(w, [-4.0, 1e-3], [1.0, 0.0]).body == 1  # Just above it: the wall.
  # Starting on a face, pointing in: distance 0; pointing out: nothing.
  assert _hit(jc.raycast(w, [3.0, 1.0], [1.0, 0.0]))[:3] == (True, 1, 0.0)
  assert not jc.raycast(w, [3.0, 1.0], [-1.0, 0.0]).hit
  # max_distance: not reached, and reached exactly.
  short = jc.raycast(w, [0.0, 1.0], [1.0, 0.0], 2.5)
  assert _hit(short) == (False, -1, 2.5, [0.0, 1.0], [0.0, 0.0])
  assert jc.raycast(w, [0.0, 1.0], [1.0, 0.0], 3.0).body == 1
  # Layers and ignore skip the box; the sensor is never hit.
  assert jc.raycast(w, [0.0, 0.5], [1.0, 0.0], mask=1).body == 1
  assert jc.raycast(w, [0.0, 0.5], [1.0, 0.0], ignore=2).body == 1
  skip = jnp.zeros(CAP, bool).at[jnp.array([1, 2])].set(True)
  assert not jc.raycast(w, [0.0, 0.5], [1.0, 0.0], ignore=skip).hit


def test_raycast_hits_a_tiled_floor_along_its_seams():
  """Along a seam (the ray on the faces between two bodies), the ray enters where both
  sides are solid, as it would the one merged body: a ground check at an integer x finds
  the floor the step and move_and_slide see as one surface."""
  tiles = make([[-1.0, -0.5], [1.0, -0.5], [3.0, -0.25]], [[1.0, 0.5], [1.0, 0.5], [1.0, 0.25]],
               [INF, INF, INF])  # Tiles [-2, 0], [0, 2], [2, 4], tops at y = 0.
  merged = make([[0.0, -0.5]], [[2.0, 0.5]], [INF])
  cast = jax.jit(jc.raycast)  # One compile for the rays below.
  down = jnp.array([0.0, -1.0])
  assert _hit(cast(merged, jnp.array([0.0, 2.0]), down)) == (True, 0, 2.0, [0.0, 0.0],
                                                             [0.0, 1.0])
  for x, body in ((0.0, 0), (2.0, 1), (-0.5, 0), (0.5, 1)):  # Seams, and inside one tile.
    assert _hit(cast(tiles, jnp.array([x, 2.0]), down)) == (True, body, 2.0, [x, 0.0],
                                                            [0.0, 1.0]), x
  # The outer edges are faces of one tile only: grazing, no hit.
  assert not cast(tiles, jnp.array([-2.0, 2.0]), down).hit
  assert not cast(tiles, jnp.array([4.0, 2.0]), down).hit
  # A step: at x = 2 the tile on the right is lower; the ray runs down the left tile's
  # side and enters where both sides are solid: the right tile's top, y = -0.5.
  steps = tiles.replace(pos=tiles.pos.at[2, 1].set(-0.75))  # Its top at y = -0.5.
  assert _hit(cast(steps, jnp.array([2.0, 2.0]), down)) == (True, 2, 2.5, [2.0, -0.5],
                                                            [0.0, 1.0])
  # A wall of stacked tiles, a ray along the seam at y = 1 from the left; and a vmapped
  # batch of rays over both kinds of seam.
  wall = make([[3.5, 0.5], [3.5, 1.5]], [[0.5, 0.5], [0.5, 0.5]], [INF, INF])
  assert _hit(cast(wall, jnp.array([0.0, 1.0]), jnp.array([1.0, 0.0]))) == (
      True, 0, 3.0, [3.0, 1.0], [-1.0, 0.0])
  xs = jnp.array([-2.0, -1.0, 0.0, 1.0, 2.0, 3.0, 4.0])
  r = jax.vmap(lambda x: jc.raycast(tiles, jnp.stack([x, 2.0]), down))(xs)
  assert r.hit.tolist() == [False] + [True] * 5 + [False]
  np.testing.assert_array_equal(r.distance[1:6], [2.0] * 5)
  # A tiny direction is a direction: (1e-30, -1e-30) is normalised, not taken for zero.
  r = cast(tiles, jnp.array([-1.5, 0.5]), jnp.array([1e-30, -1e-30]))
  assert _hit(r)[:2] == (True, 0) and r.normal.tolist() == [0.0, 1.0]
  np.testing.assert_allclose(r.distance, 0.5 * np.sqrt(2.0), rtol=1e-6)
  with pytest.raises(ValueError, match="direction must be nonzero"):
    jc.raycast(tiles, [0.0, 1.0], [1e-40, 0.0])  # Below float32's normals: flushed to 0.
  # The seam rule keeps the gradient of the distance.
  g = jax.grad(lambda o: jc.raycast(tiles, o, down).distance)(jnp.array([0.0, 2.0]))
  np.testing.assert_allclose(g, [0.0, 1.0], **EXACT)


def test_raycast_zero_direction():
  w = _boxes()
  with pytest.raises(ValueError, match="direction must be nonzero"):
    jc.raycast(w, [0.0, 0.5], [0.0, 0.0])
  with pytest.raises(ValueError, match="max_distance"):
    jc.raycast(w, [0.0, 0.5], [1.0, 0.0], -1.0)
  with pytest.raises(ValueError, match="ignore"):
    jc.raycast(w, [0.0, 0.5], [1.0, 0.0], ignore=CAP)
  r = jax.jit(lambda d: jc.raycast(w, jnp.array([0.0, 0.5]), d))(jnp.zeros(2))
  assert not r.hit and r.body == -1


def test_raycast_gradients_are_finite_for_axis_aligned_rays():
  w = _boxes()
  dist = lambda o, d: jc.raycast(w, o, d).distance
  g = jax.grad(dist)(jnp.array([0.0, 0.5]), jnp.array([1.0, 0.0]))
  np.testing.assert_allclose(g, [-1.0, 0.0], **EXACT)
  g = jax.grad(dist, argnums=(0, 1))(jnp.array([1.0, 2.0]), jnp.array([0.0, -1.0]))
  assert all(np.isfinite(x).all() for x in g)
  np.testing.assert_allclose(g[0], [0.0, 1.0], **EXACT)
  np.testing.assert_allclose(g[1], [0.0, 0.0], **EXACT)  # The length of d does not matter.
  # Diagonal: distance to the floor from (x, y) along (1, -1)/sqrt(2) is sqrt(2) y.
  g = jax.grad(dist)(jnp.array([-1.0, 2.0]), jnp.array([1.0, -1.0]))
  np.testing.assert_allclose(g, [0.0, np.sqrt(2.0)], rtol=1e-6)
  # A zero direction under grad: no hit, no NaN.
  g = jax.grad(lambda d: jnp.where(jc.raycast(w, jnp.zeros(2), d, 5.0).hit, 1.0, 0.0) +
               jc.raycast(w, jnp.zeros(2), d, 5.0).distance)(jnp.zeros(2))
  assert np.isfinite(g).all()


def test_raycast_gradients_are_finite_for_tiny_directions():
  # Issue 44 item 9: a tiny direction (1e-30, -1e-30) hit as (1, -1) does, but every
  # gradient of the cast was NaN: JAX's rules for the normalisation and for 1 / u go
  # through scale ** -2 and u ** -2 (1e60: inf in float32), and 0 * inf is NaN, also
  # along the axis a ray (1, -1e-30) nearly runs along. The distance does not depend on
  # the direction's length, so its gradient at s d is that at d over s.
  w = _boxes()
  grad = jax.jit(jax.grad(lambda o, d: jc.raycast(w, o, d).distance, argnums=(0, 1)))
  origin = jnp.array([-1.0, 2.0])  # Along (1, -1): the floor at distance sqrt(2) * 2.
  g_origin, g_dir = grad(origin, jnp.array([1.0, -1.0]))
  for scale in (1e-30, 1e-20, 1e-12):
    got = grad(origin, scale * jnp.array([1.0, -1.0]))
    assert all(np.isfinite(x).all() for x in got), scale
    np.testing.assert_allclose(got[0], g_origin, rtol=1e-6)
    np.testing.assert_allclose(got[1] * scale, g_dir, rtol=1e-5)
  # Nearly axis-aligned: from (0, 0.5) along (1, -1e-30) into the wall at x = 3.
  got = grad(jnp.array([0.0, 1.5]), jnp.array([1.0, -1e-30]))
  assert all(np.isfinite(x).all() for x in got)
  np.testing.assert_allclose(got[0], [-1.0, 0.0], **EXACT)
  np.testing.assert_allclose(got[1], [0.0, 0.0], atol=1e-6)  # 3 sqrt(1 + dy^2): 3 dy.


def test_raycast_vmap_over_rays_and_worlds():
  w = _boxes()
  ys = jnp.array([0.3, 0.5, 0.74, 1.0, 2.5])
  cast = jax.jit(jax.vmap(lambda y: jc.raycast(w, jnp.stack([0.0, y]), jnp.array([1.0, 0.0]))))
  r = cast(ys)
  assert r.body.tolist() == [2, 2, 2, 1, -1]
  np.testing.assert_allclose(r.distance[:4], [0.75, 0.75, 0.75, 3.0], **EXACT)
  batch = jc.stack([w, w.replace(pos=w.pos.at[2, 0].set(2.0))])
  r = jax.vmap(lambda v: jc.raycast(v, jnp.array([0.0, 0.5]), jnp.array([1.0, 0.0])))(batch)
  np.testing.assert_allclose(r.distance, [0.75, 1.75], **EXACT)


# --- move_and_slide ------------------------------------------------------------------------

def _level():
  """A floor of two tiles (0, 1; top y = 0), a wall (2, left face x = 4), a ceiling (3,
  bottom y = 3), a one-way ledge (4, top y = 1.5, x in [-3, -1]), a movable crate (5),
  and the player (6), a unit box on the floor."""
  return make([[-2.5, -0.5], [2.5, -0.5], [4.5, 2.0], [0.0, 3.5], [-2.0, 1.4],
               [-4.0, 0.5], [0.0, 0.5]],
              [[2.5, 0.5], [2.5, 0.5], [0.5, 3.0], [5.0, 0.5], [1.0, 0.1], [0.5, 0.5],
               [0.5, 0.5]],
              [INF, INF, INF, INF, INF, 1.0, 1.0], one_way=[False] * 4 + [True] + [False] * 2)


PLAYER = 6
slide = jax.jit(jc.move_and_slide)  # One compile for every move below.


def _slide(w, pos, vel, steps=1, gravity=0.0):
  w = w.replace(pos=w.pos.at[PLAYER].set(jnp.asarray(pos, jnp.float32)))
  v = jnp.asarray(vel, jnp.float32)
  info = None
  for _ in range(steps):
    w, info = slide(w, PLAYER, v + jnp.array([0.0, gravity * DT]), DT)
    v = w.vel[PLAYER]
  return w, info


def test_move_and_slide_stops_flush_at_a_wall_and_slides_along_the_floor():
  w, info = _slide(_level(), [0.0, 0.5], [60.0, 0.0], steps=4)  # 1 unit a step.
  assert w.pos[PLAYER].tolist() == [3.5, 0.5] and w.vel[PLAYER].tolist() == [0.0, 0.0]
  assert bool(info.on_wall) and int(info.hit_x) == 2 and int(info.hit_y) == -1
  # Sliding over the seam between the floor tiles, pressed down: x speed kept.
  w, info = _slide(_level(), [-0.7, 0.5], [6.0, 0.0], steps=20, gravity=-9.81)
  np.testing.assert_allclose(w.pos[PLAYER], [1.3, 0.5], atol=1e-5)
  assert float(w.vel[PLAYER, 0]) == 6.0 and bool(info.on_floor) and not info.on_wall


def test_move_and_slide_lands_and_bumps_the_ceiling():
  w, info = _slide(_level(), [0.0, 1.0], [0.0, -60.0])  # Falls 1 unit, the gap is 0.5.
  assert w.pos[PLAYER].tolist() == [0.0, 0.5] and bool(info.on_floor)
  assert int(info.hit_y) in (0, 1) and w.vel[PLAYER].tolist() == [0.0, 0.0]
  assert info.floor_velocity.tolist() == [0.0, 0.0]
  moving = _level().replace(vel=_level().vel.at[0].set(jnp.array([2.0, 0.0])))  # Tile 0 moves.
  w, info = _slide(moving, [-0.5, 1.0], [0.0, -60.0])
  assert int(info.hit_y) == 0 and info.floor_velocity.tolist() == [2.0, 0.0]
  w, info = _slide(_level(), [1.0, 2.0], [3.0, 60.0])  # Up 1 unit, the ceiling is 0.5 away.
  np.testing.assert_allclose(w.pos[PLAYER], [1.05, 2.5], **EXACT)
  assert w.pos[PLAYER, 1] == 2.5 and w.vel[PLAYER].tolist() == [3.0, 0.0]
  assert bool(info.on_ceiling) and not info.on_floor and int(info.hit_y) == 3


def test_move_and_slide_one_way_from_below_and_from_above():
  # Jumping up through the ledge (x = -2): passes it.
  w, info = _slide(_level(), [-2.0, 0.5], [0.0, 90.0])
  assert w.pos[PLAYER].tolist() == [-2.0, 2.0] and not info.on_ceiling
  # Falling from above: lands flush on its top (y = 1.5 + 0.5).
  w, info = _slide(_level(), [-2.0, 2.5], [0.0, -60.0])
  assert w.pos[PLAYER].tolist() == [-2.0, 2.0] and bool(info.on_floor) and int(info.hit_y) == 4
  # Running sideways through it: no wall.
  w, info = _slide(_level(), [0.0, 1.4], [-60.0, 0.0])
  assert w.pos[PLAYER, 0] == -1.0 and not info.on_wall
  # The crate is an obstacle, never pushed.
  w, info = _slide(_level(), [-2.0, 0.5], [-120.0, 0.0])
  assert w.pos[PLAYER].tolist() == [-3.0, 0.5] and int(info.hit_x) == 5
  assert w.pos[5].tolist() == [-4.0, 0.5]


def test_move_and_slide_never_goes_deeper_into_what_it_overlaps():
  """Sunk into a floor or a wall, the body may leave the overlap but not go deeper: along
  the pair's contact axis (the one of smaller overlap, as in the step), a move toward
  the obstacle's centre stops where it is; other moves are free."""
  base = _level()
  # Sunk 0.01 into the floor, falling (it fell through: y 0.39 -> -0.61).
  w, info = _slide(base, [0.0, 0.49], [0.0, -60.0])
  np.testing.assert_array_equal(w.pos[PLAYER], np.float32([0.0, 0.49]))  # Where it was.
  assert w.vel[PLAYER].tolist() == [0.0, 0.0]
  assert bool(info.on_floor) and int(info.hit_y) in (0, 1)
  # Sliding along it, pressed down: x is free (the contact axis is y), y stays.
  w, info = _slide(base, [0.0, 0.49], [30.0, -30.0])
  np.testing.assert_allclose(w.pos[PLAYER], [0.5, 0.49], **EXACT)
  assert not info.on_wall and bool(info.on_floor)
  # Jumping out of it: free.
  w, info = _slide(base, [0.0, 0.49], [0.0, 30.0])
  np.testing.assert_allclose(w.pos[PLAYER], [0.0, 0.99], **EXACT)
  assert not info.on_floor and not info.on_ceiling
  # 0.1 inside the wall (left face x = 4) and moving into it (it came out the far side).
  w, info = _slide(base, [3.6, 1.5], [120.0, 0.0])
  np.testing.assert_array_equal(w.pos[PLAYER], np.float32([3.6, 1.5]))
  assert bool(info.on_wall) and int(info.hit_x) == 2
  assert w.vel[PLAYER].tolist() == [0.0, 0.0]
  w, info = _slide(base, [3.6, 1.5], [-30.0, 0.0])  # Leaving it: free.
  np.testing.assert_allclose(w.pos[PLAYER], [3.1, 1.5], **EXACT)
  assert not info.on_wall
  # A one-way ledge still lets a body below its margin pass (drop_through relies on it).
  w, info = _slide(base, [-2.0, 1.95], [0.0, -60.0])
  np.testing.assert_allclose(w.pos[PLAYER], [-2.0, 0.95], **EXACT)
  assert not info.on_floor


def test_move_and_slide_vmap_and_no_recompile():
  base = _level()
  batch = jc.stack([base, base.replace(pos=base.pos.at[2, 0].set(2.5))])  # A closer wall.
  chex.clear_trace_counter()

  @jax.jit
  @chex.assert_max_traces(n=1)
  def run(b, v):
    return jax.vmap(lambda w: jc.move_and_slide(w, PLAYER, v, DT))(b)

  w, info = run(batch, jnp.array([120.0, 0.0]))
  assert w.pos[:, PLAYER, 0].tolist() == [2.0, 1.5] and info.on_wall.tolist() == [False, True]
  w, info = run(w, jnp.array([120.0, 0.0]))  # New values, the same trace.
  assert w.pos[:, PLAYER, 0].tolist() == [3.5, 1.5]


def test_move_and_slide_gradients():
  base = _level()

  def x_after(v, wall_x):  # Where the player ends along x.
    w = base.replace(pos=base.pos.at[2, 0].set(wall_x))
    return jc.move_and_slide(w, PLAYER, v, DT)[0].pos[PLAYER, 0]

  grad = jax.jit(jax.grad(x_after, argnums=(0, 1)))
  g_v, g_wall = grad(jnp.array([6.0, -1.0]), 4.5)  # Free: moves by v dt.
  np.testing.assert_allclose(g_v, [DT, 0.0], **EXACT)
  assert g_wall == 0.0
  g_v, g_wall = grad(jnp.array([600.0, -1.0]), 4.5)  # Stopped flush: follows the wall.
  assert g_v.tolist() == [0.0, 0.0] and g_wall == 1.0


def test_empty_world():
  e = jc.World.create(np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0))
  assert jc.touching_bodies(e)[0].shape == (0, 4, 4) and jc.query_point(e, [0.0, 0.0]).shape == (0,)
  assert not jc.raycast(e, [0.0, 0.0], [1.0, 0.0]).hit
  assert jc.drive_platforms(e, np.zeros(0, bool), [1.0, 0.0]).vel.shape == (0, 2)


def test_move_and_slide_rejects_bad_host_input():
  w = _level()
  with pytest.raises(ValueError, match="body 10 is not in"):
    jc.move_and_slide(w, 10, [1.0, 0.0], DT)
  with pytest.raises(ValueError, match="inactive"):
    jc.move_and_slide(w, 8, [1.0, 0.0], DT)
  with pytest.raises(ValueError, match="dt must be"):
    jc.move_and_slide(w, PLAYER, [1.0, 0.0], 0.0)
  with pytest.raises(ValueError, match="velocity must be finite"):
    jc.move_and_slide(w, PLAYER, [INF, 0.0], DT)


# --- drive_platforms -----------------------------------------------------------------------

def _platform_scene():
  """A kinematic platform (0, top y = 0), a frictionless box on it (1) and one on that (2),
  a floor (3, top y = -2) and a box standing on the floor beside the platform (4)."""
  return make([[0.0, -0.25], [0.0, 0.5], [0.0, 1.5], [0.0, -2.5], [4.0, -1.5]],
              [[2.0, 0.25], [0.5, 0.5], [0.5, 0.5], [10.0, 0.5], [0.5, 0.5]],
              [INF, 1.0, 1.0, INF, 1.0])


def test_drive_platforms_carries_a_frictionless_stack():
  w = _platform_scene()
  cfg = jc.Config.for_world(w)
  driven = jc.drive_platforms(w, 0, [2.0, 0.0])
  assert driven.vel[:5, 0].tolist() == [2.0, 2.0, 2.0, 0.0, 0.0]
  final, _ = jc.rollout(driven, cfg, 60)
  np.testing.assert_allclose(final.pos[:3, 0], [2.0, 2.0, 2.0], atol=1e-5)
  np.testing.assert_allclose(final.pos[1:3, 0] - final.pos[0, 0], [0.0, 0.0], atol=1e-6)
  np.testing.assert_allclose(final.pos[:3, 1], [-0.25, 0.5, 1.5], atol=1e-5)
  assert final.pos[4].tolist() == [4.0, -1.5]  # Not on the platform: not carried.
  # Without the helper a frictionless rider stays behind.
  alone, _ = jc.rollout(w.replace(vel=w.vel.at[0].set(jnp.array([2.0, 0.0]))), cfg, 60)
  np.testing.assert_allclose(alone.pos[1, 0], 0.0, atol=1e-6)
  # Stopping it stops the riders (relative velocity kept).
  stopped = jc.drive_platforms(final, 0, [0.0, 0.0])
  np.testing.assert_allclose(stopped.vel[:3], np.zeros((3, 2)), atol=1e-5)


def test_drive_platforms_depth_mask_and_vmap():
  w = _platform_scene()
  one = jc.drive_platforms(w, jnp.arange(CAP) == 0, [1.0, -1.0], depth=1)
  assert one.vel[:3].tolist() == [[1.0, -1.0], [1.0, -1.0], [0.0, 0.0]]  # Only one high.
  batch = jc.stack([w, w.replace(pos=w.pos.at[1, 0].set(3.0))])  # Box 1 off the platform.
  out = jax.jit(jax.vmap(lambda v: jc.drive_platforms(v, 0, jnp.array([2.0, 0.0]))))(batch)
  assert out.vel[0, :3, 0].tolist() == [2.0, 2.0, 2.0]
  assert out.vel[1, :3, 0].tolist() == [2.0, 0.0, 0.0]
  with pytest.raises(ValueError, match="must be immovable"):
    jc.drive_platforms(w, 1, [1.0, 0.0])
  with pytest.raises(ValueError, match="velocity must be finite"):
    jc.drive_platforms(w, 0, [1.0, 0.0, 0.0])


def test_drive_platforms_carries_a_stack_of_any_height_and_reports_what_depth_leaves():
  # A platform (0) and a stack of 12 frictionless boxes on it, at rest.
  w = jc.World.create([[0.0, 0.0]] + [[0.0, float(k)] for k in range(1, 13)],
                      [[2.0, 0.5]] + [[0.5, 0.5]] * 12, [INF] + [1.0] * 12, gravity=(0.0, 0.0))
  assert jc.drive_platforms(w, 0, [2.0, 0.0]).vel[:, 0].tolist() == [2.0] * 13  # Default.
  out, left = jc.drive_platforms(w, 0, [2.0, 0.0], depth=8, left_behind=True)
  assert out.vel[:, 0].tolist() == [2.0] * 9 + [0.0] * 4  # Eight boxes high.
  assert left.tolist() == [False] * 9 + [True] * 4  # The top four: reported.
  out, left = jc.drive_platforms(w, 0, [2.0, 0.0], left_behind=True)
  assert out.vel[:, 0].tolist() == [2.0] * 13 and not left.any()
  with pytest.raises(ValueError, match="depth must be None or an integer >= 0"):
    jc.drive_platforms(w, 0, [1.0, 0.0], depth=-1)


def test_a_traced_body_index_out_of_range_moves_nothing():
  """The host refuses body -1 (or n); under jit it is no body: nothing moves (it used to
  move the last body, as NumPy indexing wraps -1)."""
  unpad = lambda w, n: jax.tree.map(lambda x: x[:n] if x.ndim and x.shape[0] == CAP else x, w)
  w, ledge = unpad(_level(), PLAYER + 1), unpad(_ledge_scene(), 3)  # Each last: the mover.
  assert w.num_bodies == PLAYER + 1 and ledge.num_bodies == 3
  slide_at = jax.jit(lambda w, b: jc.move_and_slide(w, b, jnp.array([60.0, -60.0]), DT))
  drop_at = jax.jit(jc.drop_through)
  for body in (-1, -7, PLAYER + 1, 100):
    out, info = slide_at(w, body)
    np.testing.assert_array_equal(out.pos, w.pos)
    np.testing.assert_array_equal(out.vel, w.vel)
    assert (int(info.hit_x), int(info.hit_y), bool(info.on_floor)) == (-1, -1, False)
    out, dropped = drop_at(ledge, body)
    assert not dropped and out.pos.tolist() == ledge.pos.tolist()
  out, info = slide_at(w, PLAYER)  # A valid index, the same trace: it moves.
  assert out.pos[PLAYER].tolist() == [1.0, 0.5]
  assert bool(drop_at(ledge, 2)[1])
  driven = jax.jit(lambda w, b: jc.drive_platforms(w, b, jnp.array([2.0, 0.0])))
  np.testing.assert_array_equal(driven(_platform_scene(), -1).vel, _platform_scene().vel)


def test_one_way_platform_side_and_below_touch_nothing_and_ride_nothing():
  # A one-way platform (0), a box at its right side (1), one just under it (2), one on it (3).
  w = make([[0.0, 0.0], [1.5, 0.0], [0.0, -0.6], [0.0, 0.6]], [[1.0, 0.1]] + [[0.5, 0.5]] * 3,
           [INF, 1.0, 1.0, 1.0], one_way=[True, False, False, False], gravity=(0.0, 0.0))
  index, _ = jc.touching_bodies(w)
  assert index[:4, :, 0].tolist() == [[-1, -1, 3, -1], [-1] * 4, [-1] * 4, [-1, -1, -1, 0]]
  driven = jc.drive_platforms(w, 0, [2.0, 0.0])
  assert driven.vel[:4].tolist() == [[2.0, 0.0], [0.0, 0.0], [0.0, 0.0], [2.0, 0.0]]


# --- drop_through --------------------------------------------------------------------------

def _ledge_scene(one_way=True):
  """A floor (0, top y = 0), a ledge (1, top y = 2, one-way or not), a player (2) on it."""
  return make([[0.0, -0.5], [0.0, 1.9], [0.0, 2.5]], [[5.0, 0.5], [1.5, 0.1], [0.5, 0.5]],
              [INF, INF, 1.0], one_way=[False, one_way, False])


def test_drop_through_falls_to_the_floor_below():
  w = _ledge_scene()
  cfg = jc.Config.for_world(w)
  rest, _ = jc.rollout(w, cfg, 5)  # Resting on the ledge: the step holds it.
  np.testing.assert_allclose(rest.pos[2], [0.0, 2.5], atol=1e-5)
  dropped_world, dropped = jc.drop_through(rest, 2)
  expected = 2.0 - (core.contacts.ONE_WAY_MARGIN + queries.DROP_EXTRA) * 0.6 + 0.5
  assert bool(dropped)
  np.testing.assert_allclose(dropped_world.pos[2, 1], expected, **EXACT)
  final, _ = jc.rollout(dropped_world, cfg, 60)
  np.testing.assert_allclose(final.pos[2], [0.0, 0.5], atol=1e-4)
  assert bool(jc.grounded(final)[2])
  assert jc.touching_bodies(final)[0][2, 3, 0] == 0  # It stands on the floor now.


def test_drop_through_keeps_a_body_on_solid_ground():
  solid = _ledge_scene(one_way=False)
  out, dropped = jc.drop_through(solid, 2)
  assert not dropped and out.pos.tolist() == solid.pos.tolist()
  # Half on a one-way ledge, half on a solid block: it stays.
  mixed = make([[-1.0, 1.9], [1.0, 1.9], [0.0, 2.5]], [[1.0, 0.1], [1.0, 0.1], [0.5, 0.5]],
               [INF, INF, 1.0], one_way=[True, False, False])
  out, dropped = jc.drop_through(mixed, 2)
  assert not dropped and out.pos.tolist() == mixed.pos.tolist()
  # In the air: nothing to drop through.
  air = _ledge_scene().replace(pos=_ledge_scene().pos.at[2, 1].set(4.0))
  assert not jc.drop_through(air, 2)[1]
  # Batched.
  out, dropped = jax.vmap(lambda v: jc.drop_through(v, 2))(jc.stack([_ledge_scene(), solid]))
  assert dropped.tolist() == [True, False]
  # The player then passes the ledge with move_and_slide too.
  w, info = jc.move_and_slide(jc.drop_through(_ledge_scene(), 2)[0], 2, [0.0, -60.0], DT)
  assert not info.on_floor and float(w.pos[2, 1]) < 2.0


# --- examples/controller.py ----------------------------------------------------------------

def test_controller_example():
  path = pathlib.Path(__file__).resolve().parents[1] / "examples" / "controller.py"
  spec = importlib.util.spec_from_file_location("controller_example", path)
  ex = importlib.util.module_from_spec(spec)
  spec.loader.exec_module(ex)
  runs = np.array([2.0, 4.0])
  final, trace = ex.run_worlds(runs, 360)
  pos, on_floor, jumps, floor = (np.asarray(x) for x in trace)
  player = pos[:, :, ex.PLAYER]
  # Dropped through the ledge (top y = 2.5) and reached the floor within a second.
  assert (np.abs(player[:, :60, 1] - 0.5) < 1e-4).any(axis=1).all()
  assert (player[:, 0, 1] < 3.0).all()
  # Never inside the floor, the walls or the box (a kinematic helper never enters).
  for j in (ex.FLOOR, ex.LEFT, ex.RIGHT, ex.BOX):
    over = (np.asarray(final.half[:, j])[:, None] + np.asarray(final.half[:, ex.PLAYER])[:, None]
            - np.abs(pos[:, :, j] - player))
    assert np.min(over, axis=-1).max() < 1e-4, j
  # The frictionless crate rides the patrolling platform, reversals included.
  rel = pos[:, :, ex.CRATE] - pos[:, :, ex.PLATFORM]
  np.testing.assert_allclose(rel, np.broadcast_to([0.0, 0.75], rel.shape), atol=1e-4)
  assert np.ptp(pos[:, :, ex.PLATFORM, 0], axis=1).min() > 1.5  # It did patrol.
  assert jumps.sum(axis=1).min() >= 1 and bool(np.any(floor[1] == ex.PLATFORM))
  lines = ex.report(runs, final, trace)
  assert lines[-1] == "status: ok" and "rode the platform: True" in lines[1]
