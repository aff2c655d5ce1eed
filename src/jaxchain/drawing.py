"""Pictures of worlds: `render` draws boxes into a uint8 image inside JAX, `save_gif`
writes frames to an animated GIF through Pillow.

`render` is pure and jitted (the image size, the edge mode, the aspect rule and the
palette are static), so it runs inside a compiled step and under `vmap`: a batch of
worlds becomes a batch of images in one call, and `render_trajectory` turns the
positions of a rollout into frames.

Colours by kind (`PALETTE`, a `Palette`; 8-bit sRGB, blended linearly in that
space). Each body gets the colour of the first kind in this list that it has:

================  ===============  =============================================
kind              colour           drawn
================  ===============  =============================================
inactive          (not drawn)      padding slots are left out
sensor            (90, 220, 120)   translucent fill (alpha 0.3) and a one-pixel
                                   opaque outline, on top of everything
sensor, sensed    (170, 255, 120)  brighter, fill alpha 0.55, same outline
crushed           (230, 50, 50)    opaque (`world.crushed`, the last step's flag)
player            (70, 170, 255)   opaque (the `player=` argument)
one-way           (175, 125, 230)  opaque (`world.one_way`)
immovable         (125, 133, 145)  opaque (`inv_mass == 0`: walls, platforms)
movable           (235, 160, 60)   opaque
background        (28, 30, 38)     wherever nothing is drawn
================  ===============  =============================================

Draw order: the bodies that are not sensors are composited in index order (a later
body covers an earlier one where they overlap), then the sensors, in index order,
translucent on top, so a body inside a sensor stays visible.

Edges: with `antialias=True` (the default) a body covers each pixel by the exact
fraction of the pixel's area inside the box (per axis the overlap of the pixel's
interval with the box's, divided by the pixel size, clipped to [0, 1]; the product
of the two axes), and it is composited with that coverage as alpha ("over"). With
`antialias=False` a pixel is covered, fully, when its centre lies in the box
(`lo <= c < hi`), so edges are crisp and every pixel has exactly one body's colour
or the background.

Geometry: y points up (row 0 of the image is the top of the view). The view is
`bounds = (xmin, ymin, xmax, ymax)` in world units; with `keep_aspect=True` (the
default) it is widened about its centre along one axis to the image's aspect ratio,
so that pixels are square and a square box looks square.

Cost: O(n H W) per image for `n` body slots (every slot is composited, masked if
inactive) and O(H W) memory: the per-axis coverages are `[n, H]` and `[n, W]`, and
a `lax.scan` over the bodies composites them into one `[H, W, 3]` float image (no
`[n, H, W]` array). Under `vmap` the scan carries one image per frame: `B` worlds x
`T` steps at `H x W` hold `B T H W 3` floats (64 x 100 frames at 64 x 96 are about
470 MB). `render_trajectory` therefore renders a clip in chunks of steps
(`lax.map`), about `CHUNK_PIXELS` pixels at a time, which bounds memory and is 2-3
times faster than one `vmap` over every frame.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import os
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from PIL import Image

from jaxchain.world import World

RGB = tuple[int, int, int]

# Default view margin: a fraction of the larger side of the bodies' extent.
MARGIN = 0.03

# `render_trajectory` composites about this many pixels at once (frames of all worlds
# times the steps of a chunk): a float image of 2**19 pixels is 6 MB, small enough to
# stay in cache while every body is composited into it (measured: 2-3 times faster
# than rendering every step at once at 64 x 100 frames of 64 x 96).
CHUNK_PIXELS = 2**19

# The fastest GIF that browsers play at its own speed: they treat delays below 2
# centiseconds as 10 centiseconds.
MAX_GIF_FPS = 50.0


class Palette(NamedTuple):
  """The colours of `render`, 8-bit RGB triples, and the sensors' fill opacity.

  A `NamedTuple` of Python values, so it is hashable and can be a static argument:
  `render(world, palette=PALETTE._replace(background=(255, 255, 255)))`.
  """

  background: RGB = (28, 30, 38)
  immovable: RGB = (125, 133, 145)
  movable: RGB = (235, 160, 60)
  player: RGB = (70, 170, 255)
  one_way: RGB = (175, 125, 230)
  crushed: RGB = (230, 50, 50)
  sensor: RGB = (90, 220, 120)
  sensed: RGB = (170, 255, 120)
  sensor_alpha: float = 0.3  # Fill opacity of a sensor; its one-pixel outline is opaque.
  sensed_alpha: float = 0.55  # Fill opacity of a sensor that senses something.


PALETTE = Palette()


@functools.partial(jax.jit, static_argnames=("margin",))
def bounds_of(world: World, pos: jax.Array | None = None, margin: float = MARGIN) -> jax.Array:
  """The view that holds every active body: `[4]` `(xmin, ymin, xmax, ymax)`.

  Reduces over every leading axis: for a batch of worlds (or, with `pos`, every step
  of a trajectory) it is one view that holds all of them, so frames share one
  camera. The box of the active bodies is grown on every side by `margin` times
  its larger side; with no active body it is `(-1, -1, 1, 1)`. Jitted (`margin`
  static).

  Args:
    world: a world, or a batch (`pos` `[..., n, 2]`).
    pos: optional positions to use instead of `world.pos`, `[..., t, n, 2]` with the
      world's leading axes first (a `Trajectory.pos` of `world`).
    margin: the margin, a fraction of the extent's larger side.

  Returns:
    `[4]` float array.

  Examples:
    >>> import jaxchain as jc
    >>> w = jc.World.create([[0.0, 0.0], [3.0, 1.0]], [0.5, 0.5], 1.0)
    >>> jc.drawing.bounds_of(w, margin=0.0).tolist()
    [-0.5, -0.5, 3.5, 1.5]
  """
  if pos is None:
    pos = world.pos
  lead = world.pos.shape[:-2]
  extra = pos.ndim - world.pos.ndim  # The trajectory's time axis, if any.
  if pos.shape[:len(lead)] != lead or pos.shape[-2:] != world.pos.shape[-2:] or extra < 0:
    raise ValueError(f"bounds_of: pos {pos.shape} does not extend the world's pos "
                     f"{world.pos.shape} (expected {lead} + (t,) + {world.pos.shape[-2:]})")
  expand = lambda x: x.reshape(lead + (1,) * extra + x.shape[len(lead):])
  half = jnp.broadcast_to(expand(world.half), pos.shape)
  active = jnp.broadcast_to(expand(world.active)[..., None], pos.shape)
  inf = jnp.asarray(jnp.inf, pos.dtype)
  axes = tuple(range(pos.ndim - 1))
  lo = jnp.min(jnp.where(active, pos - half, inf), axis=axes)
  hi = jnp.max(jnp.where(active, pos + half, -inf), axis=axes)
  any_active = jnp.any(world.active)
  lo = jnp.where(any_active, lo, -1.0)
  hi = jnp.where(any_active, hi, 1.0)
  pad = jnp.where(any_active, margin * jnp.max(hi - lo), 0.0)
  return jnp.concatenate([lo - pad, hi + pad])


def _check_size(size) -> tuple[int, int]:
  try:
    h, w = size
    ok = all(isinstance(s, (int, np.integer)) and not isinstance(s, bool) and s > 0
             for s in (h, w))
  except (TypeError, ValueError):
    ok = False
  if not ok:
    raise ValueError(f"render: size must be (H, W), two positive integers, got {size!r}")
  return int(h), int(w)


def _player_mask(player, n: int) -> jax.Array:
  """`[n]` bool from `None`, an index or a bool mask."""
  if player is None:
    return jnp.zeros(n, bool)
  player = jnp.asarray(player)
  if player.dtype == bool:
    if player.shape != (n,):
      raise ValueError(f"render: a player mask must have shape ({n},), got {player.shape}")
    return player
  if player.ndim != 0 or not jnp.issubdtype(player.dtype, jnp.integer):
    raise ValueError(f"render: player must be a body index (an integer) or a bool mask of "
                     f"shape ({n},), got {player.dtype} {player.shape}")
  return jnp.arange(n, dtype=player.dtype) == player


def _pixel_edges(bounds: jax.Array, h: int, w: int, keep_aspect: bool, dtype):
  """Edges of the pixel columns (`[W + 1]`, left to right) and rows (`[H + 1]`, top
  to bottom, decreasing y), and the pixel size along x and y."""
  bounds = jnp.asarray(bounds, dtype)
  if bounds.shape != (4,):
    raise ValueError(f"render: bounds must be (xmin, ymin, xmax, ymax), got shape {bounds.shape}")
  lo, hi = bounds[:2], bounds[2:]
  centre = (lo + hi) / 2
  span = jnp.abs(hi - lo)
  pixels = jnp.asarray([w, h], dtype)
  step = span / pixels
  if keep_aspect:
    step = jnp.broadcast_to(jnp.max(step), (2,))
  step = jnp.where(step > 0, step, jnp.ones((), dtype))  # A degenerate view: 1 unit a pixel.
  start = centre - step * pixels / 2
  xs = start[0] + step[0] * jnp.arange(w + 1, dtype=dtype)
  ys = (start[1] + step[1] * pixels[1]) - step[1] * jnp.arange(h + 1, dtype=dtype)
  return xs, ys, step


def _cover(lo: jax.Array, hi: jax.Array, a: jax.Array, b: jax.Array, step: jax.Array,
           antialias: bool) -> jax.Array:
  """`[n, p]` coverage of the pixel intervals `[a, b]` (`[p]`) by the body intervals
  `[lo, hi]` (`[n]`) along one axis."""
  if antialias:
    inside = jnp.minimum(b[None, :], hi[:, None]) - jnp.maximum(a[None, :], lo[:, None])
    return jnp.clip(inside / step, 0.0, 1.0)
  c = (a + b)[None, :] / 2
  return ((c >= lo[:, None]) & (c < hi[:, None])).astype(lo.dtype)


def _render_one(world: World, bounds, player, *, h: int, w: int, antialias: bool,
                keep_aspect: bool, palette: Palette) -> jax.Array:
  """`render` of one world (`pos` `[n, 2]`)."""
  n = world.num_bodies
  dtype = world.pos.dtype
  if bounds is None:
    bounds = bounds_of(world)
  xs, ys, step = _pixel_edges(bounds, h, w, keep_aspect, dtype)
  lo, hi = world.pos - world.half, world.pos + world.half
  # Per-axis coverage of each pixel column / row: [n, W], [n, H] (rows: y from ys[i+1]
  # up to ys[i]).
  cx = _cover(lo[:, 0], hi[:, 0], xs[:-1], xs[1:], step[0], antialias)
  cy = _cover(lo[:, 1], hi[:, 1], ys[1:], ys[:-1], step[1], antialias)
  # A sensor's outline: its coverage less that of the box one pixel smaller on every side.
  cx_in = _cover(lo[:, 0] + step[0], hi[:, 0] - step[0], xs[:-1], xs[1:], step[0], antialias)
  cy_in = _cover(lo[:, 1] + step[1], hi[:, 1] - step[1], ys[1:], ys[:-1], step[1], antialias)

  colour = lambda rgb: jnp.asarray(rgb, dtype)
  sensor = world.sensor & world.active
  kind = jnp.where(world.inv_mass > 0, 0, 1)  # Movable, immovable.
  kind = jnp.where(world.one_way, 2, kind)
  kind = jnp.where(_player_mask(player, n), 3, kind)
  kind = jnp.where(world.crushed, 4, kind)
  kind = jnp.where(sensor, jnp.where(world.sensed, 6, 5), kind)
  table = jnp.stack([colour(palette.movable), colour(palette.immovable), colour(palette.one_way),
                     colour(palette.player), colour(palette.crushed), colour(palette.sensor),
                     colour(palette.sensed)])
  rgb = table[kind]  # [n, 3]
  fill = jnp.where(world.sensed, palette.sensed_alpha, palette.sensor_alpha).astype(dtype)
  fill = jnp.where(sensor, fill, jnp.ones((), dtype))
  fill = jnp.where(world.active, fill, jnp.zeros((), dtype))
  outline = jnp.where(sensor, 1.0 - fill, jnp.zeros((), dtype))
  order = jnp.argsort(sensor, stable=True)  # Solid bodies in index order, then sensors.
  bodies = jax.tree.map(lambda x: x[order], (cx, cy, cx_in, cy_in, fill, outline, rgb))

  def composite(image, body):
    cx, cy, cx_in, cy_in, fill, outline, rgb = body
    cover = cy[:, None] * cx[None, :]
    ring = cover - cy_in[:, None] * cx_in[None, :]
    alpha = fill * cover + outline * ring
    return image + alpha[..., None] * (rgb[None, None, :] - image), None

  start = jnp.broadcast_to(colour(palette.background), (h, w, 3))
  image, _ = jax.lax.scan(composite, start, bodies)
  return jnp.round(jnp.clip(image, 0.0, 255.0)).astype(jnp.uint8)


def _mapped(x, single_ndim: int):
  """vmap axis for an optional argument: 0 if it has a batch axis, else None."""
  return None if x is None or jnp.ndim(x) <= single_ndim else 0


@functools.partial(jax.jit, static_argnames=("size", "antialias", "keep_aspect", "palette"))
def render(world: World, size: tuple[int, int] = (96, 160), bounds=None, *, antialias: bool = True,
           player=None, keep_aspect: bool = True, palette: Palette = PALETTE) -> jax.Array:
  """Draws a world (or a batch of worlds) into an RGB image, inside JAX.

  Pure and jitted: `size`, `antialias`, `keep_aspect` and `palette` are static (a
  new value compiles again), `world`, `bounds` and `player` are traced. It works
  under `jax.vmap` (over worlds, or over the steps of a trajectory: see
  `render_trajectory`), and leading batch axes of `world` are mapped for you. The
  colours, draw order and edge rule are in this module's docstring; the cost is
  O(n H W).

  Args:
    world: a world (`pos` `[n, 2]`), or a batch (`[..., n, 2]`: each world gets its
      own default bounds).
    size: `(H, W)` of the image in pixels (static).
    bounds: `(xmin, ymin, xmax, ymax)` of the view in world units (`[4]`, or `[...,
      4]` per world of a batch); default `bounds_of(world)`, the active bodies'
      extent with a small margin (traced).
    antialias: `True` for coverage-blended edges, `False` for crisp ones (pixel
      centre inside the box) (static).
    player: `None`, the index of the body to colour as the player (an integer), or
      a `[n]` bool mask of them (`[..., n]` per world of a batch).
    keep_aspect: widen the view along one axis to the image's aspect ratio, so
      pixels are square (static).
    palette: the colours, a `Palette` (static).

  Returns:
    `uint8[H, W, 3]` (`uint8[..., H, W, 3]` for a batch); row 0 is the top of the
    view (y points up).

  Raises:
    ValueError: for a size that is not two positive integers, bounds not of
      shape `[4]`, or a player that is neither an index nor a `[n]` bool mask.

  Examples:
    >>> import jaxchain as jc
    >>> inf = float("inf")
    >>> w = jc.World.create([[0.0, -0.5], [0.0, 0.5]], [[2.0, 0.5], [0.5, 0.5]], [inf, 1.0])
    >>> image = jc.render(w, (32, 48), bounds=(-2.0, -1.0, 2.0, 1.5), player=1)
    >>> image.shape, image.dtype
    ((32, 48, 3), dtype('uint8'))
    >>> image[28, 24].tolist(), image[12, 24].tolist(), image[2, 2].tolist()  # Wall, player, air.
    ([125, 133, 145], [70, 170, 255], [28, 30, 38])
  """
  h, w = _check_size(size)
  batch = world.pos.ndim - 2
  if batch < 0:
    raise ValueError(f"render: expected pos of shape (..., n, 2), got {world.pos.shape}")
  if bounds is not None:
    bounds = jnp.asarray(bounds, world.pos.dtype)
  fn = functools.partial(_render_one, h=h, w=w, antialias=antialias, keep_aspect=keep_aspect,
                         palette=palette)
  player_ndim = 1 if player is not None and jnp.asarray(player).dtype == bool else 0
  return _map_leading(fn, batch, player_ndim)(world, bounds, player)


def _map_leading(fn, depth: int, player_ndim: int):
  """`fn(world, bounds, player)` vmapped over `depth` leading axes of the world;
  `bounds` and `player` are mapped along with it where they have those axes."""
  if depth == 0:
    return fn
  inner = _map_leading(fn, depth - 1, player_ndim)
  return lambda world, bounds, player: jax.vmap(
      inner, in_axes=(0, _mapped(bounds, 1), _mapped(player, player_ndim)))(world, bounds, player)


@functools.partial(jax.jit, static_argnames=("size", "antialias", "keep_aspect", "palette",
                                             "batch_size"))
def render_trajectory(world: World, traj, size: tuple[int, int] = (96, 160), bounds=None, *,
                      antialias: bool = True, player=None, keep_aspect: bool = True,
                      palette: Palette = PALETTE, batch_size: int | None = None) -> jax.Array:
  """The frames of a rollout: `render` of `world` with the positions of each step.

  Frame `t` draws `world` with `pos = traj.pos[t]`, and with `crushed` and `sensed`
  from the trajectory where it recorded them (`jc.rollout(..., record=("crushed",
  "sensed"))`; else the world's own flags). Everything else (sizes, kinds, `active`)
  is the world's. One camera for the whole clip: the default bounds hold every
  active body at every step (`bounds_of(world, traj.pos)`), per world for a batch.

  Args:
    world: the world the rollout started from (`pos` `[n, 2]`), or a batch
      (`[b, n, 2]`, with `traj.pos` `[b, t, n, 2]` from a vmapped rollout).
    traj: a `jc.Trajectory` (or anything with `pos`, and optionally `crushed` and
      `sensed`, of shape `[..., t, n, ...]`).
    size, antialias, player, keep_aspect, palette: as in `render` (static but for
      `player`).
    bounds: `[4]` view shared by every frame (`[b, 4]`: one per world); default
      the extent of the whole trajectory.
    batch_size: how many steps to render at once (`lax.map` over chunks of
      steps, each chunk `vmap`ped; static). The default picks it so that about
      `CHUNK_PIXELS` (2**19) pixels, of all worlds of a batch, are composited at
      once: memory stays bounded on long clips, and it is faster than rendering
      every step at once (the image being composited stays in cache).

  Returns:
    `uint8[t, H, W, 3]`, or `uint8[b, t, H, W, 3]` for a batch.

  Examples:
    >>> import jaxchain as jc
    >>> import jax.numpy as jnp
    >>> w = jc.World.create([[0.0, 2.0], [0.0, -0.5]], [[0.5, 0.5], [3.0, 0.5]],
    ...                     [1.0, float("inf")])
    >>> # final, traj = jc.rollout(w, jc.Config.for_world(w), 30) makes one; by hand:
    >>> pos = jnp.broadcast_to(w.pos, (30, 2, 2)).at[:, 0, 1].add(jnp.linspace(0.0, -1.0, 30))
    >>> traj = jc.Trajectory(pos=pos, vel=jnp.zeros_like(pos))
    >>> frames = jc.render_trajectory(w, traj, (24, 32))
    >>> frames.shape, frames.dtype
    ((30, 24, 32, 3), dtype('uint8'))
  """
  h, w = _check_size(size)
  batch = world.pos.ndim - 2
  if batch not in (0, 1):
    raise ValueError(f"render_trajectory: expected one world (pos [n, 2]) or a batch "
                     f"(pos [b, n, 2]), got {world.pos.shape}")
  want = world.pos.shape[:-2] + (None,) + world.pos.shape[-2:]
  if traj.pos.ndim != len(want) or traj.pos.shape[:batch] != world.pos.shape[:batch] or (
      traj.pos.shape[-2:] != world.pos.shape[-2:]):
    raise ValueError(f"render_trajectory: traj.pos {traj.pos.shape} does not match the world "
                     f"(pos {world.pos.shape}): expected {want} with None the number of steps")
  if bounds is not None:
    bounds = jnp.asarray(bounds, world.pos.dtype)
  flags = {name: getattr(traj, name, None) for name in ("crushed", "sensed")}
  flags = {name: x for name, x in flags.items() if x is not None}
  player_ndim = 1 if player is not None and jnp.asarray(player).dtype == bool else 0
  frame = functools.partial(_render_one, h=h, w=w, antialias=antialias, keep_aspect=keep_aspect,
                            palette=palette)

  def clip(world, pos, flags, bounds, player):
    if bounds is None:
      bounds = bounds_of(world, pos)

    def one(xs):
      step_pos, step_flags = xs
      return frame(dataclasses.replace(world, pos=step_pos, **step_flags), bounds, player)

    steps = pos.shape[0]
    chunk = batch_size or max(1, CHUNK_PIXELS // (frames_per_step * h * w))
    if chunk >= steps:
      return jax.vmap(one)((pos, flags))
    return jax.lax.map(one, (pos, flags), batch_size=chunk)

  frames_per_step = world.pos.shape[0] if batch else 1
  if batch:
    clip = jax.vmap(clip, in_axes=(0, 0, 0, _mapped(bounds, 1), _mapped(player, player_ndim)))
  return clip(world, traj.pos, flags, bounds, player)


def gif_durations(n_frames: int, fps: float) -> list[int]:
  """Per-frame delays in milliseconds, each a whole number of centiseconds (what GIF
  stores), so that frame `k` starts at `round(k * 100 / fps)` centiseconds.

  Pillow takes GIF durations in milliseconds and truncates each to centiseconds
  (`int(ms / 10)`), so a plain `duration=1000 / fps` plays 30 fps as 33.3 fps. These
  durations keep the average rate exact: every frame gets the same delay when
  `100 / fps` is an integer (fps 50, 33.3.., 25, 20, 10, 5, 4, 2, 1, ...); otherwise
  (30 fps: 30, 40, 30 ms, ...) each frame is within 10 ms of `1000 / fps`.

  Examples:
    >>> import jaxchain as jc
    >>> jc.drawing.gif_durations(6, 30), jc.drawing.gif_durations(3, 25)
    ([30, 40, 30, 30, 40, 30], [40, 40, 40])
  """
  starts = [math.floor(k * 100 / fps + 0.5) for k in range(n_frames + 1)]
  return [10 * (b - a) for a, b in zip(starts[:-1], starts[1:])]


def save_gif(frames, path: str | os.PathLike, fps: float = 30, *, loop: int | None = 0) -> None:
  """Writes frames to an animated GIF through Pillow.

  Durations: `fps` frames per second on average, through whole-centisecond delays
  (`gif_durations`: Pillow's unit is the millisecond, GIF's the centisecond).
  `fps` must be at most 50 (`MAX_GIF_FPS`): browsers play delays below 2
  centiseconds as 10. Each frame is quantised to a palette of 256 colours by
  Pillow. Pillow merges a frame identical to the one before it into that one
  (adding its delay), so a GIF read back can have fewer frames than `frames`,
  never a different length in time.

  Args:
    frames: `uint8[T, H, W, 3]`, NumPy or JAX (`T >= 1`), e.g. from
      `render_trajectory`.
    path: the file to write (`.gif`).
    fps: frames per second, in `(0, 50]`.
    loop: how many times viewers repeat the clip, `0` for ever (the default), or
      `None` to play it once.

  Raises:
    ValueError: for frames that are not a non-empty `uint8[T, H, W, 3]` array, or a
      bad `fps` or `loop`.

  Examples:
    >>> import os, tempfile
    >>> import numpy as np
    >>> import jaxchain as jc
    >>> frames = np.zeros((3, 8, 8, 3), np.uint8)
    >>> frames[1, :4], frames[2, 4:] = 255, 128
    >>> path = os.path.join(tempfile.mkdtemp(), "clip.gif")
    >>> jc.save_gif(frames, path, fps=25)
    >>> from PIL import Image
    >>> with Image.open(path) as im:
    ...   im.n_frames, im.size, im.info["duration"]
    (3, (8, 8), 40)
  """
  array = np.asarray(frames)
  if array.dtype != np.uint8:
    raise ValueError(f"save_gif: frames must be uint8 (render's output), got {array.dtype}; "
                     "for floats in [0, 1] use (255 * x).round().astype(np.uint8)")
  if array.ndim != 4 or array.shape[-1] != 3:
    hint = "; for one image use frames[None]" if array.ndim == 3 else ""
    raise ValueError(f"save_gif: frames must have shape (T, H, W, 3), got {array.shape}{hint}")
  if 0 in array.shape:
    raise ValueError(f"save_gif: no pixels to write: frames of shape {array.shape}")
  if isinstance(fps, bool) or not isinstance(fps, (int, float, np.number)) or not (
      0 < fps <= MAX_GIF_FPS):
    raise ValueError(f"save_gif: fps must be a number in (0, {MAX_GIF_FPS:g}], got {fps!r} "
                     "(browsers play GIF delays under 20 ms as 100 ms)")
  if loop is not None and (isinstance(loop, bool) or not isinstance(loop, (int, np.integer))
                           or not 0 <= loop < 2**16):
    raise ValueError(f"save_gif: loop must be an integer in [0, 65535] (0: for ever) or None, "
                     f"got {loop!r}")
  images = [Image.fromarray(frame) for frame in array]
  extra = {} if loop is None else {"loop": int(loop)}
  images[0].save(path, format="GIF", save_all=True, append_images=images[1:],
                 duration=gif_durations(len(images), float(fps)), optimize=False, **extra)
