"""Rendering inside JAX (`jc.render`, `jc.render_trajectory`) and GIFs (`jc.save_gif`).

Every image here is 32 x 48 pixels of the view (0, 0)-(48, 32): one world unit per
pixel, so the pixel in row i and column j covers x in [j, j + 1] and y in
[31 - i, 32 - i] (y up). One world of 8 bodies for the whole module, so the renders
share a few compiled functions.
"""

import dataclasses
import doctest

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from PIL import Image

import jaxchain as jc
from jaxchain import drawing

INF = float("inf")
SIZE = (32, 48)
BOUNDS = (0.0, 0.0, 48.0, 32.0)
P = drawing.PALETTE
FLOOR, BOX, PLAYER, LEDGE, SENSOR, INSIDE, GONE, CRUSHED = range(8)


def _world() -> jc.World:
  pos = [[24.0, 2.0],    # FLOOR: a wall, y in [0, 4]: rows 28-31.
         [6.0, 28.0],    # BOX: movable at the top, x in [4, 8], y in [26, 30]: rows 2-5.
         [14.0, 8.0],    # PLAYER: x in [12, 16], y in [6, 10]: rows 22-25.
         [24.0, 16.0],   # LEDGE: one-way, x in [20, 28], y in [15.5, 16.5]: half of rows 15, 16.
         [40.0, 10.0],   # SENSOR: x in [36, 44], y in [6, 14]: rows 18-25, outline 1 px.
         [40.0, 10.0],   # INSIDE: movable inside the sensor, x in [39, 41], y in [9, 11].
         [30.0, 26.0],   # GONE: inactive, never drawn.
         [20.0, 26.0]]   # CRUSHED: x in [18.5, 21.5], y in [24.5, 27.5].
  half = [[24.0, 2.0], [2.0, 2.0], [2.0, 2.0], [4.0, 0.5], [4.0, 4.0], [1.0, 1.0], [2.0, 2.0],
          [1.5, 1.5]]
  mass = [INF, 1.0, 1.0, INF, INF, 1.0, 1.0, 1.0]
  flag = lambda *i: np.isin(np.arange(8), i)
  world = jc.World.create(pos, half, mass, active=~flag(GONE), one_way=flag(LEDGE),
                          sensor=flag(SENSOR))
  return world.replace(crushed=flag(CRUSHED))


WORLD = _world()


def blend(rgb, alpha, under=P.background):
  return np.asarray(under, np.float64) + alpha * (np.asarray(rgb, np.float64) - under)


@pytest.fixture(scope="module")
def image():
  return np.asarray(jc.render(WORLD, SIZE, BOUNDS, player=PLAYER))


@pytest.fixture(scope="module")
def crisp():
  return np.asarray(jc.render(WORLD, SIZE, BOUNDS, player=PLAYER, antialias=False))


def test_colours_by_kind_at_known_pixels(image, crisp):
  assert image.shape == (32, 48, 3) and image.dtype == np.uint8
  for im in (image, crisp):
    np.testing.assert_array_equal(im[30, 10], P.immovable)  # The floor, bottom rows.
    np.testing.assert_array_equal(im[3, 5], P.movable)  # A box at the top of the world...
    np.testing.assert_array_equal(im[31 - 3, 5], P.immovable)  # ...is in the top rows (y up).
    np.testing.assert_array_equal(im[23, 13], P.player)
    np.testing.assert_array_equal(im[5, 20], P.crushed)
    np.testing.assert_array_equal(im[5, 29], P.background)  # The inactive body: not drawn.
    np.testing.assert_array_equal(im[10, 10], P.background)  # Empty space.
  np.testing.assert_array_equal(crisp[16, 24], P.one_way)  # Crisp: centre y = 15.5 is in.
  np.testing.assert_array_equal(crisp[15, 24], P.background)  # Centre 16.5 is not (hi open).


def test_top_rows_hold_the_top_of_the_world(image):
  rows = np.flatnonzero(np.all(image[:, 5] == P.movable, axis=-1))
  np.testing.assert_array_equal(rows, [2, 3, 4, 5])  # y in [26, 30] of a view 32 high.
  floor = np.flatnonzero(np.all(image[:, 5] == P.immovable, axis=-1))
  np.testing.assert_array_equal(floor, [28, 29, 30, 31])


def test_antialiased_edges_blend_by_the_covered_area(image):
  half_row = blend(P.one_way, 0.5)  # The ledge covers half of rows 15 and 16.
  np.testing.assert_allclose(image[15, 24], half_row, atol=0.51)
  np.testing.assert_allclose(image[16, 24], half_row, atol=0.51)
  assert not np.array_equal(image[15, 24], P.one_way)
  np.testing.assert_allclose(image[4, 18], blend(P.crushed, 0.25), atol=0.51)  # A corner: 1/2 x 1/2.
  np.testing.assert_allclose(image[4, 19], blend(P.crushed, 0.5), atol=0.51)  # An edge.


def test_a_sensor_is_translucent_with_an_outline_and_drawn_on_top(image):
  np.testing.assert_allclose(image[19, 38], blend(P.sensor, P.sensor_alpha), atol=0.51)
  np.testing.assert_array_equal(image[20, 36], P.sensor)  # The one-pixel outline.
  np.testing.assert_array_equal(image[18, 40], P.sensor)
  # The body inside stays visible, tinted by the sensor on top of it.
  np.testing.assert_allclose(image[21, 39], blend(P.sensor, P.sensor_alpha, P.movable), atol=0.51)


def test_a_sensed_sensor_is_brighter():
  sensed = WORLD.replace(sensed=np.arange(8) == SENSOR)
  im = np.asarray(jc.render(sensed, SIZE, BOUNDS, player=PLAYER))
  np.testing.assert_allclose(im[19, 38], blend(P.sensed, P.sensed_alpha), atol=0.51)
  np.testing.assert_array_equal(im[20, 36], P.sensed)


def test_player_as_a_mask_equals_player_as_an_index(image):
  mask = np.arange(8) == PLAYER
  np.testing.assert_array_equal(jc.render(WORLD, SIZE, BOUNDS, player=mask), image)
  no_player = np.asarray(jc.render(WORLD, SIZE, BOUNDS, player=np.zeros(8, bool)))
  np.testing.assert_array_equal(no_player[23, 13], P.movable)


def test_default_bounds_hold_every_active_body_with_a_margin():
  lo, hi = np.asarray(drawing.bounds_of(WORLD)).reshape(2, 2)
  np.testing.assert_allclose(lo, [0.0 - 0.03 * 48, 0.0 - 0.03 * 48], atol=1e-5)
  np.testing.assert_allclose(hi, [48.0 + 0.03 * 48, 30.0 + 0.03 * 48], atol=1e-5)
  empty = WORLD.replace(active=np.zeros(8, bool))
  np.testing.assert_array_equal(drawing.bounds_of(empty), [-1, -1, 1, 1])


def _batch(k=3):
  """`k` copies of WORLD, copy b shifted right by 4 b (built on the host: eager ops would
  each compile)."""
  batch = jax.tree.map(lambda x: np.stack([np.asarray(x)] * k), WORLD)
  pos = batch.pos.copy()
  pos[..., 0] += 4.0 * np.arange(k, dtype=np.float32)[:, None]
  return dataclasses.replace(batch, pos=pos)


def _take(tree, b):
  return jax.tree.map(lambda x: x[b], tree)


def test_a_batch_of_worlds_is_a_batch_of_images(image):
  batch = _batch()
  images = np.asarray(jc.render(batch, SIZE, BOUNDS, player=PLAYER))  # Leading axes mapped.
  assert images.shape == (3, 32, 48, 3)
  np.testing.assert_array_equal(images[0], image)
  for b in range(1, 3):
    one = _take(batch, b)
    np.testing.assert_array_equal(images[b], jc.render(one, SIZE, BOUNDS, player=PLAYER))
  # Default bounds are per world: every shifted copy looks the same in its own view.
  own = np.asarray(jc.render(batch, SIZE, player=PLAYER)).astype(int)
  assert np.abs(own - own[0]).max() <= 1
  # Bounds per world: each copy's view shifted with it.
  views = np.asarray([[4.0 * b, 0.0, 48.0 + 4.0 * b, 32.0] for b in range(3)], np.float32)
  shifted = np.asarray(jc.render(batch, SIZE, views, player=PLAYER)).astype(int)
  assert np.abs(shifted - image.astype(int)).max() <= 1


def _trajectory(batch, steps=4, record=True):
  """The box falls by 1 a step; CRUSHED is flagged only at step 2 (host arrays)."""
  pos = np.stack([batch.pos] * steps, axis=1)
  pos[:, :, BOX, 1] -= np.arange(steps, dtype=np.float32)
  crushed = np.zeros(pos.shape[:-1], bool)
  crushed[:, 2, CRUSHED] = True
  return jc.Trajectory(pos=pos, vel=np.zeros_like(pos), crushed=crushed if record else None)


def test_a_batch_of_rollouts_is_a_batch_of_clips():
  batch = _batch()
  traj = _trajectory(batch)
  frames = jc.render_trajectory(batch, traj, SIZE, BOUNDS, player=PLAYER)
  assert frames.shape == (3, 4, 32, 48, 3)
  by_hand = jax.vmap(jax.vmap(lambda w, pos, crushed: jc.render(
      dataclasses.replace(w, pos=pos, crushed=crushed), SIZE, BOUNDS, player=PLAYER),
      in_axes=(None, 0, 0)))(batch, traj.pos, traj.crushed)
  np.testing.assert_array_equal(frames, by_hand)
  frames = np.asarray(frames)
  np.testing.assert_array_equal(frames[0, 0, 2, 5], P.movable)  # The box falls a row a step.
  np.testing.assert_array_equal(frames[0, 3, 2, 5], P.background)
  np.testing.assert_array_equal(frames[0, 3, 5 + 3, 5], P.movable)
  np.testing.assert_array_equal(frames[1, 2, 5, 20 + 4], P.crushed)  # Recorded flags per step.
  np.testing.assert_array_equal(frames[1, 1, 5, 20 + 4], P.movable)
  chunked = jc.render_trajectory(batch, traj, SIZE, BOUNDS, player=PLAYER, batch_size=3)
  np.testing.assert_array_equal(chunked, frames)  # lax.map in chunks of 3 steps (and a rest).


def test_a_clip_has_one_camera_holding_every_step():
  batch = _batch()
  traj = _trajectory(batch, record=False)
  one, steps = _take((batch, traj), 0)
  view = np.asarray(drawing.bounds_of(one, steps.pos))
  np.testing.assert_allclose(view, [-1.44, -1.44, 49.44, 31.44], atol=1e-5)  # The floor to
  frames = jc.render_trajectory(one, steps, SIZE, player=PLAYER)            # the box at t=0.
  assert frames.shape == (4, 32, 48, 3)
  last = jc.render(one.replace(pos=steps.pos[-1]), SIZE, tuple(map(float, view)), player=PLAYER)
  np.testing.assert_array_equal(frames[-1], last)


def test_inside_a_callers_jit_the_same_pixels(image):
  # A direct call compiles with drawing.CPU_OPTIONS (on an AVX-512 CPU); inside a jit
  # (traced inputs, or constants only) JAX takes no compile options: the plain one.
  np.testing.assert_array_equal(jax.jit(lambda w: jc.render(w, SIZE, BOUNDS, player=PLAYER))(
      WORLD), image)
  np.testing.assert_array_equal(jax.jit(lambda: jc.render(WORLD, SIZE, BOUNDS, player=PLAYER))(),
                                image)
  assert set(drawing.CPU_OPTIONS) <= {"xla_cpu_prefer_vector_width"}


def test_second_call_does_not_compile():
  jc.render(WORLD, SIZE, BOUNDS, player=PLAYER)
  moved = WORLD.replace(pos=WORLD.pos + 0.5)  # New values (eager ops compile too: not inside).
  events = []
  listener = lambda name, *args, **kwargs: events.append(name)
  jax.monitoring.register_event_duration_secs_listener(listener)
  try:
    jc.render(moved, SIZE, (1.0, 2.0, 40.0, 30.0), player=BOX).block_until_ready()
  finally:
    jax.monitoring.unregister_event_duration_listener(listener)
  assert not [e for e in events if "compile" in e], events


@pytest.mark.parametrize("kwargs, message", [
    (dict(size=(0, 4)), "size must be"),
    (dict(size=(4.0, 4)), "size must be"),
    (dict(size=(4, 4), bounds=(0.0, 1.0)), "bounds must be"),
    (dict(size=(4, 4), player=np.ones(3, bool)), "player mask must have shape"),
    (dict(size=(4, 4), player=1.5), "player must be a body index"),
])
def test_bad_arguments_are_clear_errors(kwargs, message):
  with pytest.raises(ValueError, match=message):
    jc.render(WORLD, **kwargs)


def _reference(world, size, bounds, player=None, antialias=True):
  """The documented rule in float64 NumPy, one body after another ("over", solid
  bodies in index order, then sensors): the slow twin of `render`."""
  h, w = size
  x0, y0, x1, y1 = np.asarray(bounds, np.float64)
  step = max((x1 - x0) / w, (y1 - y0) / h)  # keep_aspect
  cx, cy = (x0 + x1) / 2, (y0 + y1) / 2
  xs = cx + step * (np.arange(w + 1) - w / 2)
  ys = cy + step * (h / 2 - np.arange(h + 1))
  pos, half = np.asarray(world.pos, np.float64), np.asarray(world.half, np.float64)
  active, sensor = np.asarray(world.active), np.asarray(world.sensor) & np.asarray(world.active)
  sensed, crushed = np.asarray(world.sensed), np.asarray(world.crushed)
  kinds = [P.movable, P.immovable, P.one_way, P.player, P.crushed, P.sensor, P.sensed]

  def cover(lo, hi, a, b):
    if antialias:
      return np.clip((np.minimum(b, hi) - np.maximum(a, lo)) / step, 0, 1)
    c = (a + b) / 2
    return ((c >= lo) & (c < hi)).astype(float)

  image = np.broadcast_to(np.asarray(P.background, float), (h, w, 3)).copy()
  for i in sorted(range(len(pos)), key=lambda i: sensor[i]):
    if not active[i]:
      continue
    lo, hi = pos[i] - half[i], pos[i] + half[i]
    box = np.outer(cover(lo[1], hi[1], ys[1:], ys[:-1]), cover(lo[0], hi[0], xs[:-1], xs[1:]))
    inner = np.outer(cover(lo[1] + step, hi[1] - step, ys[1:], ys[:-1]),
                     cover(lo[0] + step, hi[0] - step, xs[:-1], xs[1:]))
    kind = 1 if np.asarray(world.inv_mass)[i] == 0 else 0
    kind = 2 if np.asarray(world.one_way)[i] else kind
    kind = 3 if player is not None and i == player else kind
    kind = 4 if crushed[i] else kind
    fill = 1.0
    if sensor[i]:
      kind, fill = (6, P.sensed_alpha) if sensed[i] else (5, P.sensor_alpha)
    alpha = fill * box + (1 - fill) * (box - inner) if sensor[i] else box
    image += alpha[..., None] * (np.asarray(kinds[kind], float) - image)
  return np.round(np.clip(image, 0, 255)).astype(np.uint8)


def test_one_pass_equals_the_rule_body_after_body(image, crisp):
  np.testing.assert_array_equal(image, _reference(WORLD, SIZE, BOUNDS, player=PLAYER))
  np.testing.assert_array_equal(crisp, _reference(WORLD, SIZE, BOUNDS, PLAYER, antialias=False))


def _crowd(k=4, n=45, seed=0):
  """`k` worlds of `n` overlapping boxes (more than `drawing.GROUP`: several passes),
  some immovable, one-way, sensors, sensed, crushed or inactive (host arrays)."""
  rng = np.random.default_rng(seed)
  pick = lambda p: rng.random((k, n)) < p
  mass = np.where(pick(0.3), INF, 1.0)
  worlds = [jc.World.create(rng.uniform(0, 10, (n, 2)), rng.uniform(0.05, 2.0, (n, 2)), mass[b],
                            active=~pick(0.1)[b], one_way=pick(0.1)[b], sensor=pick(0.15)[b])
            for b in range(k)]
  batch = jax.tree.map(lambda *x: np.stack([np.asarray(v) for v in x]), *worlds)
  return dataclasses.replace(batch, sensed=pick(0.5), crushed=pick(0.1))


@pytest.mark.parametrize("antialias", [True, False])
def test_several_passes_equal_the_rule_body_after_body(antialias):
  crowd = _crowd()
  assert crowd.num_bodies > drawing.GROUP
  size, bounds = (40, 40), (0.0, 0.0, 10.0, 10.0)
  images = np.asarray(jc.render(crowd, size, bounds, player=3, antialias=antialias))
  for b in range(len(images)):
    want = _reference(_take(crowd, b), size, bounds, player=3, antialias=antialias)
    assert np.abs(images[b].astype(int) - want).max() <= 1  # float32 against float64.
    assert np.mean(images[b] != want) < 0.01


def test_a_batch_in_chunks_equals_each_world_alone():
  crowd = _crowd(k=6)
  size = (128, 128)  # drawing.CHUNK_PIXELS // (128 * 128) = 4 frames a chunk: 4 + 2.
  assert drawing.CHUNK_PIXELS // (size[0] * size[1]) < 6
  images = np.asarray(jc.render(crowd, size, player=np.arange(6)))
  for b in (0, 5):
    np.testing.assert_array_equal(images[b], jc.render(_take(crowd, b), size, player=b))


def test_a_clip_of_a_large_world_equals_its_frames():
  crowd = _crowd(k=2)
  pos = np.stack([np.asarray(crowd.pos) + 0.3 * t for t in range(3)], axis=1)  # [2, 3, n, 2]
  traj = jc.Trajectory(pos=pos, vel=np.zeros_like(pos))
  size, bounds = (24, 24), (0.0, 0.0, 12.0, 12.0)
  frames = np.asarray(jc.render_trajectory(crowd, traj, size, bounds, batch_size=2))
  for b, t in ((0, 0), (1, 2)):
    one = dataclasses.replace(_take(crowd, b), pos=pos[b, t])
    np.testing.assert_array_equal(frames[b, t], jc.render(one, size, bounds))


# What is not finite (issue 18): never an all-black frame, never a silent wrong answer.


def _with_nan_box():
  pos = np.array(WORLD.pos)
  pos[BOX] = np.nan
  return dataclasses.replace(WORLD, pos=pos)  # As a blown-up step leaves it (replace checks).


def test_a_non_finite_body_is_left_out_and_the_rest_is_drawn(image):
  nan_box = _with_nan_box()
  im = np.asarray(jc.render(nan_box, SIZE, BOUNDS, player=PLAYER))
  np.testing.assert_array_equal(im[3, 5], P.background)  # The NaN box is not drawn...
  keep = np.ones(im.shape[:2], bool)
  keep[:8, :10] = False  # ...and everything away from where it was is as before.
  np.testing.assert_array_equal(im[keep], image[keep])
  # Default bounds: those of the finite bodies (the NaN one is left out, like an inactive one).
  gone = WORLD.replace(active=np.asarray(WORLD.active) & (np.arange(8) != BOX))
  np.testing.assert_array_equal(drawing.bounds_of(nan_box), drawing.bounds_of(gone))
  assert np.isfinite(np.asarray(drawing.bounds_of(nan_box))).all()
  np.testing.assert_array_equal(jc.render(nan_box, SIZE, player=PLAYER),
                                jc.render(gone, SIZE, player=PLAYER))


def test_bounds_as_wide_as_the_float_range_do_not_overflow():
  # The span (6e38) overflows float32; every body is far below a pixel: all background.
  im = np.asarray(jc.render(WORLD, (4, 4), (-3e38, -3e38, 3e38, 3e38)))
  np.testing.assert_array_equal(im, np.broadcast_to(P.background, (4, 4, 3)))
  # A body as large as the float range fills the view around it.
  huge = jc.World.create([[0.0, 0.0]], [[1.5e38, 1.5e38]], INF)
  im = np.asarray(jc.render(huge, (4, 4)))
  np.testing.assert_array_equal(im[1:3, 1:3], np.broadcast_to(P.immovable, (2, 2, 3)))
  assert np.isfinite(np.asarray(drawing.bounds_of(huge))).all()


@pytest.mark.parametrize("bounds", [(0.0, 0.0, INF, 32.0), (float("nan"), 0.0, 48.0, 32.0),
                                    (0.0, 0.0, 1e39, 32.0)])  # 1e39 is inf in float32.
def test_concrete_bounds_that_are_not_finite_raise(bounds):
  with pytest.raises(ValueError, match=r"bounds must be finite in float32"):
    jc.render(WORLD, SIZE, bounds)
  with pytest.raises(ValueError, match=r"render_trajectory: bounds must be finite"):
    jc.render_trajectory(WORLD, jc.Trajectory(
        pos=np.asarray(WORLD.pos)[None], vel=np.zeros((1, 8, 2), np.float32)), SIZE, bounds)


def test_traced_bounds_that_are_not_finite_fall_back_to_the_default_view():
  draw = jax.jit(lambda b: jc.render(WORLD, SIZE, b, player=PLAYER))
  fallback = np.asarray(draw(jnp.asarray([0.0, 0.0, jnp.nan, 32.0])))
  np.testing.assert_array_equal(fallback, jc.render(WORLD, SIZE, player=PLAYER))


@pytest.mark.parametrize("player", [8, -1, 100, np.int32(8), np.array([0, 9, 1])])
def test_a_concrete_player_index_out_of_range_raises(player):
  world = _batch() if np.ndim(player) else WORLD
  with pytest.raises(ValueError, match=r"player index .* out of range for a world of 8 bodies"):
    jc.render(world, SIZE, BOUNDS, player=player)


def test_a_traced_player_index_out_of_range_colours_no_body():
  draw = jax.jit(lambda p: jc.render(WORLD, SIZE, BOUNDS, player=p))
  np.testing.assert_array_equal(draw(jnp.int32(8)), jc.render(WORLD, SIZE, BOUNDS))


@pytest.mark.parametrize("kwargs", [dict(bounds=np.zeros((2, 4), np.float32)),
                                    dict(player=np.zeros(2, np.int32)),
                                    dict(player=np.zeros((2, 8), bool))])
def test_per_world_arguments_must_match_the_batch(kwargs):
  with pytest.raises(ValueError, match=r"does not match the world's batch axes \(3,\)"):
    jc.render(_batch(), (4, 4), **kwargs)


def _frames(t=5):
  """`t` distinct 8 x 12 frames: frame k has its first k + 1 columns white."""
  frames = np.zeros((t, 8, 12, 3), np.uint8)
  for k in range(t):
    frames[k, :, :k + 1] = 255
  return frames


@pytest.mark.parametrize("fps, durations", [(25, [40] * 5), (30, [30, 40, 30, 30, 40]),
                                            (50, [20] * 5), (10, [100] * 5)])
def test_gif_read_back_has_every_frame_and_the_right_duration(tmp_path, fps, durations):
  path = tmp_path / "clip.gif"
  jc.save_gif(jnp.asarray(_frames()), path, fps=fps)  # JAX arrays work too.
  with Image.open(path) as im:
    assert im.n_frames == 5 and im.size == (12, 8) and im.info["loop"] == 0
    got = []
    for k in range(im.n_frames):
      im.seek(k)
      got.append(im.info["duration"])
      np.testing.assert_array_equal(np.asarray(im.convert("RGB")), _frames()[k])
  assert got == durations
  assert abs(sum(durations) - 5 * 1000 / fps) <= 10  # The average rate is exact.


def test_gif_of_rendered_frames_keeps_the_colours(tmp_path, image):
  path = tmp_path / "still.gif"
  frames = np.stack([image, image[::-1]])  # Two frames: upright and upside down.
  jc.save_gif(frames, path, loop=None)
  with Image.open(path) as im:
    assert im.n_frames == 2 and "loop" not in im.info
    rgb = np.asarray(im.convert("RGB")).astype(int)
  assert np.abs(rgb - image.astype(int)).max() <= 8  # Quantised to 256 colours by Pillow.
  np.testing.assert_array_equal(rgb[23, 13], P.player)


def test_gif_durations_keep_the_average_rate():
  for fps in (30, 24, 7, 50, 1):
    d = drawing.gif_durations(300, fps)
    assert all(x % 10 == 0 and x >= 20 for x in d)
    assert abs(sum(d) - 300 * 1000 / fps) <= 5
    assert max(d) - min(d) <= 10


@pytest.mark.parametrize("frames, kwargs, message", [
    (np.zeros((2, 4, 4, 3), np.float32), {}, "must be uint8"),
    (np.zeros((4, 4, 3), np.uint8), {}, r"shape \(T, H, W, 3\).*frames\[None\]"),
    (np.zeros((2, 4, 4, 4), np.uint8), {}, r"shape \(T, H, W, 3\)"),
    (np.zeros((0, 4, 4, 3), np.uint8), {}, "no pixels"),
    (np.zeros((2, 0, 4, 3), np.uint8), {}, "no pixels"),
    (np.zeros((2, 4, 4, 3), np.uint8), dict(fps=60), r"fps must be a number in \(0, 50\]"),
    (np.zeros((2, 4, 4, 3), np.uint8), dict(fps=0), "fps must be"),
    (np.zeros((2, 4, 4, 3), np.uint8), dict(fps=float("nan")), "fps must be"),
    (np.zeros((2, 4, 4, 3), np.uint8), dict(loop=-1), "loop must be"),
])
def test_save_gif_errors(tmp_path, frames, kwargs, message):
  with pytest.raises(ValueError, match=message):
    jc.save_gif(frames, tmp_path / "bad.gif", **kwargs)
  assert not (tmp_path / "bad.gif").exists()


def test_docstring_examples():
  result = doctest.testmod(drawing, extraglobs={"jc": jc}, optionflags=doctest.ELLIPSIS)
  assert result.attempted > 0 and result.failed == 0
