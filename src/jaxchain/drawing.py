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

Cost: O(n H W) per image for `n` body slots (every slot is composited; inactive
and non-finite ones with zero alpha). Each body's coverage is separable: a row
coverage `[H]` and a column coverage `[W]`, whose outer product is its alpha, so the
per-body setup is O(n (H + W)) and the [H, W] work is one blend per body and pixel.
The blends are fused: up to `GROUP` (20) bodies are composited in one pass over the
pixels, each pixel kept in registers through the whole chain of "over" operations
(painter's order, exactly as one body after another), and a world of more bodies
takes `ceil(n / GROUP)` passes, its frames in cache-sized chunks (`CHUNK_PIXELS`).
Nothing `[n, H, W]` is ever built. On an AVX-512 CPU, `render` and
`render_trajectory` compile their own functions with 512-bit vectors
(`CPU_OPTIONS`), twice as fast again. Throughput on 2 CPU cores
(benchmarks/results/render_throughput.md): at 64 x 64 and 20 body slots, a batch
renders at several times the frames per CPU-second of the earlier renderer (a
`lax.scan` over bodies, writing the whole image once per body). `render_trajectory`
renders a clip in chunks of steps when a frame takes several passes, which bounds
memory too.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import os
import types
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from PIL import Image

from jaxchain.world import World

RGB = tuple[int, int, int]

# Default view margin: a fraction of the larger side of the bodies' extent.
MARGIN = 0.03

# `render` composites this many layers (bodies) in one fused pass over the pixels;
# a world of more bodies takes ceil(n / GROUP) passes. Measured on XLA:CPU (2 cores,
# benchmarks/render_throughput.py): a pass of up to ~20 layers keeps each pixel in
# registers; one pass of 36 or 68 layers ran 2-3 times slower than passes of 12-23.
GROUP = 20

# When a frame takes several passes, frames are composited in chunks of about this
# many pixels (`lax.map` over chunks, each `vmap`ped): a float image of 2**16 pixels
# is 0.8 MB, so it stays in cache from one pass to the next (measured: 1.5-2 times
# faster than one `vmap` over B = 1024 frames of 64 x 64 at 36-68 bodies).
CHUNK_PIXELS = 2**16



def _avx512() -> bool:
  """Whether this (Linux) machine's CPU has AVX-512."""
  try:
    with open("/proc/cpuinfo", encoding="ascii", errors="replace") as f:
      return "avx512f" in f.read()
  except OSError:
    return False


# XLA:CPU vectorises for 256-bit registers unless told. On a CPU with AVX-512 the
# fused passes run twice as fast with 512-bit ones, with the same pixels
# (benchmarks/results/render_throughput.md), so `render` and `render_trajectory`
# compile their own functions with this option when they run on the CPU. It applies
# to those compiled functions only (jaxchain never sets a process-wide flag); called
# inside a caller's `jit`, the caller's compile options apply, and the caller may pass
# these: `jax.jit(f, compiler_options=jc.drawing.CPU_OPTIONS)`.
CPU_OPTIONS = types.MappingProxyType(
    {"xla_cpu_prefer_vector_width": 512} if _avx512() else {})


def _jit(fn, static: tuple[str, ...]):
  """`fn` jitted twice: plainly, and with `CPU_OPTIONS`, used for a top-level call on
  the CPU backend (JAX takes compile options only at the top level: inside a trace,
  the plain one)."""
  plain = jax.jit(fn, static_argnames=static)
  if not CPU_OPTIONS:
    return plain
  cpu = jax.jit(fn, static_argnames=static, compiler_options=dict(CPU_OPTIONS))

  def call(*args, **kwargs):
    traced = any(isinstance(x, jax.core.Tracer) for x in jax.tree.leaves((args, kwargs)))
    if traced or jax.default_backend() != "cpu":
      return plain(*args, **kwargs)
    try:
      return cpu(*args, **kwargs)
    except ValueError as e:  # Inside a trace all the same (constant inputs).
      if "compiler_options" not in str(e):
        raise
      return plain(*args, **kwargs)

  return call


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


def _drawable(world: World) -> jax.Array:
  """`[..., n]` bool: active bodies whose centre and half-extents are finite (the
  others, a NaN body for one, are left out of the picture and of `bounds_of`)."""
  finite = jnp.all(jnp.isfinite(world.pos) & jnp.isfinite(world.half), axis=-1)
  return world.active & finite


@functools.partial(jax.jit, static_argnames=("margin",))
def bounds_of(world: World, pos: jax.Array | None = None, margin: float = MARGIN) -> jax.Array:
  """The view that holds every active body: `[4]` `(xmin, ymin, xmax, ymax)`.

  Reduces over every leading axis: for a batch of worlds (or, with `pos`, every step
  of a trajectory) it is one view that holds all of them, so frames share one
  camera. The box of the active bodies is grown on every side by `margin` times
  its larger side; with no active body it is `(-1, -1, 1, 1)`. Bodies whose
  position or half-extents are not finite (a NaN body, at some step) are left
  out, and the result is always finite: an extent beyond the float range is
  clipped to it. Jitted (`margin` static).

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
  finite = jnp.all(jnp.isfinite(pos) & jnp.isfinite(half), axis=-1)
  keep = (jnp.broadcast_to(expand(world.active), pos.shape[:-1]) & finite)[..., None]
  big = jnp.asarray(jnp.finfo(pos.dtype).max, pos.dtype)
  axes = tuple(range(pos.ndim - 1))
  lo = jnp.clip(jnp.min(jnp.where(keep, pos - half, big), axis=axes), -big, big)
  hi = jnp.clip(jnp.max(jnp.where(keep, pos + half, -big), axis=axes), -big, big)
  any_kept = jnp.any(keep)
  lo = jnp.where(any_kept, lo, -1.0)
  hi = jnp.where(any_kept, hi, 1.0)
  pad = jnp.where(any_kept, margin * 2 * jnp.max(hi / 2 - lo / 2), 0.0)  # No overflow.
  return jnp.clip(jnp.concatenate([lo - pad, hi + pad]), -big, big)


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


def _concrete(x) -> np.ndarray | None:
  """`x` as a NumPy array if its value is known on the host (not a tracer)."""
  if any(isinstance(leaf, jax.core.Tracer) for leaf in jax.tree.leaves(x)):
    return None
  return np.asarray(x)


def _check_bounds(bounds, dtype, name: str = "render"):
  """Shape check, and on concrete input a finiteness check in the world's dtype."""
  if bounds is None:
    return None
  if np.shape(bounds)[-1:] != (4,):
    raise ValueError(f"{name}: bounds must be (xmin, ymin, xmax, ymax), got shape "
                     f"{np.shape(bounds)}")
  value = _concrete(bounds)
  if value is not None:
    with np.errstate(over="ignore", invalid="ignore"):
      cast = value.astype(dtype)
    if not np.all(np.isfinite(cast)):
      raise ValueError(f"{name}: bounds must be finite in {np.dtype(dtype).name}, got "
                       f"{value.tolist()} (omit bounds for the view that holds every finite "
                       f"body)")
  return jnp.asarray(bounds, dtype)


def _check_player(player, n: int) -> None:
  """Shape and dtype checks; on a concrete index, a range check."""
  if player is None:
    return
  shape, dtype = np.shape(player), jnp.result_type(player)
  if dtype == bool:
    if shape[-1:] != (n,):
      raise ValueError(f"render: a player mask must have shape ({n},), got {shape}")
    return
  if not jnp.issubdtype(dtype, jnp.integer):
    raise ValueError(f"render: player must be a body index (an integer) or a bool mask of "
                     f"shape ({n},), got {dtype} {shape}")
  value = _concrete(player)
  if value is not None and np.any((value < 0) | (value >= n)):
    raise ValueError(f"render: player index {value.tolist()} is out of range for a world of "
                     f"{n} bodies (expected 0 <= player < {n})")


def _player_mask(player, n: int) -> jax.Array:
  """`[n]` bool from `None`, an index or a bool mask (an index outside [0, n): none)."""
  if player is None:
    return jnp.zeros(n, bool)
  player = jnp.asarray(player)
  if player.dtype == bool:
    return player
  return jnp.arange(n, dtype=player.dtype) == player


def _pixel_edges(bounds: jax.Array, h: int, w: int, keep_aspect: bool, dtype):
  """Edges of the pixel columns (`[W + 1]`, left to right) and rows (`[H + 1]`, top
  to bottom, decreasing y), and the pixel size along x and y.

  Free of overflow for any finite bounds: the centre and half-span are formed from
  halves, and each edge is the centre plus one product, so a view as wide as the
  float range has finite edges (at worst the outermost edges round to +-inf, which
  the coverage rule clips) and never NaN ones.
  """
  lo, hi = bounds[:2], bounds[2:]
  centre = lo / 2 + hi / 2
  half_span = jnp.abs(hi / 2 - lo / 2)
  pixels = jnp.asarray([w, h], dtype)
  big = jnp.asarray(jnp.finfo(dtype).max, dtype)
  step = jnp.minimum(half_span * (2 / pixels), big)
  if keep_aspect:
    step = jnp.broadcast_to(jnp.max(step), (2,))
  step = jnp.where(step > 0, step, jnp.ones((), dtype))  # A degenerate view: 1 unit a pixel.
  xs = centre[0] + step[0] * (jnp.arange(w + 1, dtype=dtype) - w / 2)
  ys = centre[1] + step[1] * (h / 2 - jnp.arange(h + 1, dtype=dtype))
  return xs, ys, step


def _cover(lo: jax.Array, hi: jax.Array, a: jax.Array, b: jax.Array, step: jax.Array,
           antialias: bool) -> jax.Array:
  """`[n, p]` coverage of the pixel intervals `[a, b]` (`[p]`) by the body intervals
  `[lo, hi]` (`[n]`) along one axis."""
  if antialias:
    inside = jnp.minimum(b[None, :], hi[:, None]) - jnp.maximum(a[None, :], lo[:, None])
    return jnp.clip(inside / step, 0.0, 1.0)
  c = a / 2 + b / 2
  return ((c[None, :] >= lo[:, None]) & (c[None, :] < hi[:, None])).astype(lo.dtype)


def _layers(world: World, bounds, player, *, h: int, w: int, antialias: bool,
            keep_aspect: bool, palette: Palette):
  """The layers of one world's picture, in draw order (solid bodies by index, then
  sensors): per layer the alpha's two separable terms and the colour.

  A layer's alpha at pixel (row r, column c) is `pa[r] * cx[c] - pb[r] * cb[c]`:
  `fill * cover + outline * ring` with `cover = cy (x) cx` (the box's per-axis
  coverages) and `ring = cover - cy_in (x) cx_in` (a sensor's outline, the box less
  the box one pixel smaller on every side), so `pa = (fill + outline) cy` and
  `pb = outline cy_in`. Bodies left out (inactive, non-finite) have zero alpha.

  Returns:
    `(pa [n, H], pb [n, H], cx [n, W], cb [n, W], rgb [n, 3])`.
  """
  n = world.num_bodies
  dtype = world.pos.dtype
  drawable = _drawable(world)
  if bounds is None:
    bounds = bounds_of(world)
  else:  # Traced bounds that are not finite (concrete ones raise): the default view.
    bounds = jnp.where(jnp.all(jnp.isfinite(bounds)), bounds, bounds_of(world))
  xs, ys, step = _pixel_edges(bounds, h, w, keep_aspect, dtype)
  zero = jnp.zeros((), dtype)
  colour = lambda rgb: jnp.asarray(rgb, dtype)
  sensor = world.sensor & drawable
  kind = jnp.where(world.inv_mass > 0, 0, 1)  # Movable, immovable.
  kind = jnp.where(world.one_way, 2, kind)
  kind = jnp.where(_player_mask(player, n), 3, kind)
  kind = jnp.where(world.crushed, 4, kind)
  kind = jnp.where(sensor, jnp.where(world.sensed, 6, 5), kind)
  table = jnp.stack([colour(palette.movable), colour(palette.immovable), colour(palette.one_way),
                     colour(palette.player), colour(palette.crushed), colour(palette.sensor),
                     colour(palette.sensed)])
  fill = jnp.where(world.sensed, palette.sensed_alpha, palette.sensor_alpha).astype(dtype)
  fill = jnp.where(sensor, fill, jnp.ones((), dtype))
  fill = jnp.where(drawable, fill, zero)
  outline = jnp.where(sensor, 1.0 - fill, zero)
  lo = jnp.where(drawable[:, None], world.pos - world.half, zero)
  hi = jnp.where(drawable[:, None], world.pos + world.half, zero)
  # Draw order first, on the [n] values (gathers of [n, H] tables cost more than the rest).
  order = jnp.argsort(sensor, stable=True)  # Solid bodies in index order, then sensors.
  lo, hi, kind, fill, outline = (x[order] for x in (lo, hi, kind, fill, outline))
  # Per-axis coverage of each pixel column / row: [n, W], [n, H] (rows: y from ys[i+1]
  # up to ys[i]).
  cx = _cover(lo[:, 0], hi[:, 0], xs[:-1], xs[1:], step[0], antialias)
  cy = _cover(lo[:, 1], hi[:, 1], ys[1:], ys[:-1], step[1], antialias)
  cx_in = _cover(lo[:, 0] + step[0], hi[:, 0] - step[0], xs[:-1], xs[1:], step[0], antialias)
  cy_in = _cover(lo[:, 1] + step[1], hi[:, 1] - step[1], ys[1:], ys[:-1], step[1], antialias)
  pa = (fill + outline)[:, None] * cy
  pb = outline[:, None] * cy_in
  return pa, pb, cx, cx_in, table[kind]


def _groups(n: int) -> tuple[int, int]:
  """`(groups, size)`: `n` layers composited in `groups` passes of `size` (`<= GROUP`)."""
  groups = -(-n // GROUP) if n else 1
  return groups, -(-n // groups) if n else 0


def _over(image: jax.Array, group) -> jax.Array:
  """Composites one group of layers ("over", in order) onto `image` (`[H, W, 3]`).

  The loop runs over the `<= GROUP` slots of one group, a static size fixed by
  `GROUP`, not by the scene: XLA:CPU fuses the whole chain into one pass over the
  pixels, each pixel kept in registers while the group's layers are blended into
  it (a `lax` loop per layer writes the whole image once per layer instead: 4-5
  times slower, measured in benchmarks/render_throughput.py's docstring).
  """
  pa, pb, cx, cb, rgb = group
  for k in range(pa.shape[0]):
    alpha = pa[k][:, None] * cx[k][None, :] - pb[k][:, None] * cb[k][None, :]
    image = image + alpha[..., None] * (rgb[k][None, None, :] - image)
  return image


def _composite(layers, h: int, w: int, palette: Palette, dtype) -> jax.Array:
  """`uint8[H, W, 3]` of the layers over the background."""
  n = layers[0].shape[0]
  image = jnp.broadcast_to(jnp.asarray(palette.background, dtype), (h, w, 3))
  groups, size = _groups(n)
  if groups == 1:
    image = _over(image, layers)
  else:
    pad = groups * size - n  # Zero layers: alpha 0 leaves the image as it is, exactly.
    tables = jax.tree.map(lambda x: jnp.pad(x, [(0, pad)] + [(0, 0)] * (x.ndim - 1)).reshape(
        (groups, size) + x.shape[1:]), layers)

    def one_group(_, carry):
      # The group is read with a static index and the tables rolled by one group: a
      # dynamic index inside the fused pass (scan's) makes it several times slower.
      image, tables = carry
      image = _over(image, jax.tree.map(lambda x: x[0], tables))
      return image, jax.tree.map(lambda x: jnp.roll(x, -1, axis=0), tables)

    image, _ = jax.lax.fori_loop(0, groups, one_group, (image, tables))
  return jnp.round(jnp.clip(image, 0.0, 255.0)).astype(jnp.uint8)


def _frame(world: World, bounds, player, *, h: int, w: int, antialias: bool, keep_aspect: bool,
           palette: Palette) -> jax.Array:
  """`render` of one world (`pos` `[n, 2]`)."""
  layers = _layers(world, bounds, player, h=h, w=w, antialias=antialias,
                   keep_aspect=keep_aspect, palette=palette)
  return _composite(layers, h, w, palette, world.pos.dtype)


def _frames(frame, args, pixels: int, groups: int):
  """`frame` mapped over the leading axis of `args`: one `vmap` when each frame is
  one fused pass, else in chunks of about `CHUNK_PIXELS` pixels (`lax.map`), so the
  images being composited stay in cache between the passes."""
  count = jax.tree.leaves(args)[0].shape[0]
  chunk = max(1, CHUNK_PIXELS // pixels)
  if groups == 1 or chunk >= count:
    return jax.vmap(frame)(args)
  return jax.lax.map(frame, args, batch_size=chunk)


def _mapped(x, single_ndim: int):
  """vmap axis for an optional argument: 0 if it has a batch axis, else None."""
  return None if x is None or jnp.ndim(x) <= single_ndim else 0


def _lead(x, lead: tuple[int, ...], core: int):
  """`x` (`[*prefix of lead, *core]`) broadcast to `[*lead, *core]` and flattened
  to `[prod(lead), *core]`."""
  if x is None:
    return None
  x = jnp.asarray(x)
  prefix = x.ndim - core
  x = x.reshape(x.shape[:prefix] + (1,) * (len(lead) - prefix) + x.shape[prefix:])
  x = jnp.broadcast_to(x, lead + x.shape[len(lead):])
  return x.reshape((math.prod(lead),) + x.shape[len(lead):])


def render(world: World, size: tuple[int, int] = (96, 160), bounds=None, *, antialias: bool = True,
           player=None, keep_aspect: bool = True, palette: Palette = PALETTE) -> jax.Array:
  """Draws a world (or a batch of worlds) into an RGB image, inside JAX.

  Pure, and jitted inside (`size`, `antialias`, `keep_aspect` and `palette` are
  static: a new value compiles again; `world`, `bounds` and `player` are traced).
  It works under `jax.jit` and `jax.vmap` (over worlds, or over the steps of a
  trajectory: see `render_trajectory`), and leading batch axes of `world` are
  mapped for you: pass a batch rather than vmapping `render` over a large world
  (more than `GROUP` bodies) and its frames are composited in cache-sized chunks.
  The colours, draw order, edge rule and cost are in this module's docstring.

  What is not finite: a body whose position or half-extents are not finite (NaN,
  inf) is not drawn and does not count for the default bounds; every other body
  is drawn as usual. Bounds must be finite: concrete ones that are not raise, and
  traced ones that are not (under `jit`/`vmap`) fall back to the default bounds.
  Any finite bounds work, up to the float range (no overflow).

  Args:
    world: a world (`pos` `[n, 2]`), or a batch (`[..., n, 2]`: each world gets its
      own default bounds).
    size: `(H, W)` of the image in pixels (static).
    bounds: `(xmin, ymin, xmax, ymax)` of the view in world units (`[4]`, or `[...,
      4]` per world of a batch); default `bounds_of(world)`, the drawn bodies'
      extent with a small margin (traced).
    antialias: `True` for coverage-blended edges, `False` for crisp ones (pixel
      centre inside the box) (static).
    player: `None`, the index of the body to colour as the player (an integer in
      `[0, n)`), or a `[n]` bool mask of them (`[..., n]` per world of a batch). A
      traced index outside `[0, n)` colours no body.
    keep_aspect: widen the view along one axis to the image's aspect ratio, so
      pixels are square (static).
    palette: the colours, a `Palette` (static).

  Returns:
    `uint8[H, W, 3]` (`uint8[..., H, W, 3]` for a batch); row 0 is the top of the
    view (y points up).

  Raises:
    ValueError: for a size that is not two positive integers, bounds not of
      shape `[4]` or (when concrete) not finite in the world's dtype, or a player
      that is neither an index nor a `[n]` bool mask, or (when concrete) an index
      outside `[0, n)`.

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
  if world.pos.ndim < 2:
    raise ValueError(f"render: expected pos of shape (..., n, 2), got {world.pos.shape}")
  bounds = _check_bounds(bounds, world.pos.dtype)
  _check_player(player, world.pos.shape[-2])
  lead = world.pos.shape[:-2]
  for name, x, core in (("bounds", bounds, 1), ("player", player, None)):
    if x is None:
      continue
    core = core if core is not None else int(jnp.result_type(x) == bool)
    axes = np.shape(x)[:len(np.shape(x)) - core]
    if axes != lead[:len(axes)]:
      raise ValueError(f"render: {name} of shape {np.shape(x)} does not match the world's "
                       f"batch axes {lead} (give one for all worlds, or one per world)")
  return _render(world, (h, w), bounds, player, antialias=antialias, keep_aspect=keep_aspect,
                 palette=palette)


def _render_impl(world: World, size, bounds, player, *, antialias, keep_aspect, palette):
  h, w = size
  frame = functools.partial(_frame, h=h, w=w, antialias=antialias, keep_aspect=keep_aspect,
                            palette=palette)
  lead = world.pos.shape[:-2]
  if not lead:
    return frame(world, bounds, player)
  player_core = 1 if player is not None and jnp.asarray(player).dtype == bool else 0
  flat = jax.tree.map(lambda x: x.reshape((math.prod(lead),) + x.shape[len(lead):]), world)
  args = (flat, _lead(bounds, lead, 1), _lead(player, lead, player_core))
  images = _frames(lambda a: frame(*a), args, h * w, _groups(world.num_bodies)[0])
  return images.reshape(lead + images.shape[1:])


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
      steps, each chunk `vmap`ped; static). The default renders every step at
      once when a frame is one fused pass (at most `GROUP` bodies: no float image
      is kept), else about `CHUNK_PIXELS` (2**16) pixels, of all worlds of a
      batch, at a time, so the images being composited stay in cache.

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
  _check_size(size)
  bounds = _check_bounds(bounds, world.pos.dtype, "render_trajectory")
  _check_player(player, world.pos.shape[-2])
  return _render_trajectory(world, traj, tuple(size), bounds, antialias=antialias, player=player,
                            keep_aspect=keep_aspect, palette=palette, batch_size=batch_size)


def _render_trajectory_impl(world: World, traj, size, bounds, *, antialias, player,
                            keep_aspect, palette, batch_size):
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
  flags = {name: getattr(traj, name, None) for name in ("crushed", "sensed")}
  flags = {name: x for name, x in flags.items() if x is not None}
  player_ndim = 1 if player is not None and jnp.asarray(player).dtype == bool else 0
  frame = functools.partial(_frame, h=h, w=w, antialias=antialias, keep_aspect=keep_aspect,
                            palette=palette)
  groups = _groups(world.num_bodies)[0]

  def clip(world, pos, flags, bounds, player):
    if bounds is None:
      bounds = bounds_of(world, pos)

    def one(xs):
      step_pos, step_flags = xs
      return frame(dataclasses.replace(world, pos=step_pos, **step_flags), bounds, player)

    steps = pos.shape[0]
    if batch_size is None and groups == 1:  # One fused pass a frame: nothing to keep in cache.
      chunk = steps
    else:
      chunk = batch_size or max(1, CHUNK_PIXELS // (frames_per_step * h * w))
    if chunk >= steps:
      return jax.vmap(one)((pos, flags))
    return jax.lax.map(one, (pos, flags), batch_size=chunk)

  frames_per_step = world.pos.shape[0] if batch else 1
  if batch:
    clip = jax.vmap(clip, in_axes=(0, 0, 0, _mapped(bounds, 1), _mapped(player, player_ndim)))
  return clip(world, traj.pos, flags, bounds, player)


_render = _jit(_render_impl, ("size", "antialias", "keep_aspect", "palette"))
_render_trajectory = _jit(_render_trajectory_impl,
                          ("size", "antialias", "keep_aspect", "palette", "batch_size"))


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
