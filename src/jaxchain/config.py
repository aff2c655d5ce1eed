"""Static configuration: a frozen, hashable value that selects what gets traced."""

from __future__ import annotations

import dataclasses
import math
from typing import NamedTuple

import numpy as np

from jaxchain.broadphase import GridSpec

BROADPHASES = ("auto", "dense", "grid")

# Worlds with at most this many body slots use dense all-pairs candidates in
# `for_world` and "auto". Measured with compact link tables
# (benchmarks/results/scaling.md): dense is faster at N=128 and the grid at N=256,
# for one world and for batches of 16; between the two it is not measured.
DENSE_MAX_BODIES = 192

# `for_world` keeps at least this many links per body and direction (two unit boxes
# side by side under a third is 2; an overlapping crowd may have 3).
MIN_LINKS = 4

# `for_world` refuses a scene that would need more substeps than this to keep every
# body under the tunnelling limit (a box of half-extent 1e-9 falling under gravity
# would get 1.7 million): a tiny or very fast body is nearly always a units mistake.
# Pass `substeps=` to `for_world` explicitly to run such a scene anyway.
MAX_SUBSTEPS = 64

_REALS = (int, float, np.integer, np.floating)


@dataclasses.dataclass(frozen=True)
class Config:
  """Everything that shapes the compiled step. Frozen and hashable: pass it as a
  static argument; two equal configs share one compiled function.

  Attributes:
    dt: time step in seconds.
    gravity: whether gravity is traced: `True` applies each world's
      `World.gravity` to its movable bodies, `False` leaves gravity out of the
      compiled step (the values in the World are then ignored).
    depth: chain depth K, how many links beyond the direct contact a push (and the
      mass behind it) travels in one pass. `0` is plain pairwise Jacobi; a chain of
      L boxes is resolved exactly in one pass when `depth >= L`.
    iterations: resolution passes per (sub)step.
    friction: whether friction is traced: `True` applies Coulomb friction with
      the per-body coefficients in `World.friction`, `False` leaves it out of the
      compiled step (the values in the World are then ignored).
    broadphase: `"dense"` (all pairs, O(n^2)), `"grid"` (uniform grid, O(n); needs
      `grid`) or `"auto"` (grid when `grid` is set and the world has more than
      `DENSE_MAX_BODIES` bodies, else dense).
    substeps: sub-steps of `dt / substeps` per step.
    skin: bodies closer than this along the contact axis are chain links: a push
      travels through a row of touching boxes in the same pass.
    immovable: whether the scene may hold immovable bodies (inverse mass 0). With
      `False` the "leans on something immovable" flag is not traced at all; only
      set it when no active body has infinite mass.
    grid: the grid layout (`GridSpec`), from `broadphase.allocate` or `for_world`.
    links: most links kept per body and direction, or None for all candidates.
      Chain hops walk a `[4, n, links]` table instead of the `[4, n, m]` candidate
      table, so a small value makes each hop much cheaper; a body with more links
      in one direction (a wide box on many small ones) sets `status.LINK_OVERFLOW`
      and the extra links (the last by candidate order) are ignored, in the
      resolution and in friction, which reads the same table. `for_world` sizes it
      from the scene.
  """

  dt: float = 1 / 60
  gravity: bool = True
  depth: int = 8
  iterations: int = 1
  friction: bool = True
  broadphase: str = "auto"
  substeps: int = 1
  skin: float = 1e-4
  immovable: bool = True
  grid: GridSpec | None = None
  links: int | None = None

  def __post_init__(self):
    for name, example in (("gravity", "gravity=(0.0, -9.81)"), ("friction", "friction=0.3")):
      v = getattr(self, name)
      if not isinstance(v, (bool, np.bool_)):
        raise ValueError(
            f"Config.{name} is now an on/off switch (a bool), got {v!r}; {name} values live "
            f"in the World: World.create(..., {example}) or world.replace({name}=...), with "
            f"Config({name}=True) (the default)")
      object.__setattr__(self, name, bool(v))
    for name in ("dt", "skin"):
      v = getattr(self, name)
      if isinstance(v, bool) or not isinstance(v, _REALS) or not math.isfinite(v):
        raise ValueError(f"Config.{name}: expected a finite number, got {v!r}")
      object.__setattr__(self, name, float(v))
    if self.dt <= 0:
      raise ValueError(f"Config.dt: must be > 0, got {self.dt}")
    if self.skin < 0:
      raise ValueError(f"Config.skin: must be >= 0, got {self.skin}")
    for name, lo in (("depth", 0), ("iterations", 1), ("substeps", 1)):
      v = getattr(self, name)
      if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < lo:
        raise ValueError(f"Config.{name}: expected an integer >= {lo}, got {v!r}")
      object.__setattr__(self, name, int(v))
    if self.links is not None and (isinstance(self.links, bool) or
                                   not isinstance(self.links, (int, np.integer)) or self.links < 1):
      raise ValueError(f"Config.links: expected None or an integer >= 1, got {self.links!r}")
    if self.links is not None:
      object.__setattr__(self, "links", int(self.links))
    if not isinstance(self.broadphase, str) or self.broadphase not in BROADPHASES:
      raise ValueError(f"Config.broadphase: expected one of {BROADPHASES}, got {self.broadphase!r}")
    object.__setattr__(self, "broadphase", str(self.broadphase))
    if not isinstance(self.immovable, (bool, np.bool_)):
      raise ValueError(f"Config.immovable: expected a bool, got {self.immovable!r}")
    object.__setattr__(self, "immovable", bool(self.immovable))
    if self.grid is not None and not isinstance(self.grid, GridSpec):
      raise ValueError(f"Config.grid: expected a GridSpec or None, got {type(self.grid).__name__}")
    if self.broadphase == "grid" and self.grid is None:
      raise ValueError("Config.broadphase: 'grid' needs Config.grid (a GridSpec); build one "
                       "with jaxchain.broadphase.allocate(world) or use Config.for_world")

  def uses_grid(self, num_bodies: int) -> bool:
    """Whether a world of `num_bodies` slots is resolved with the grid."""
    if self.broadphase == "auto":
      return self.grid is not None and num_bodies > DENSE_MAX_BODIES
    return self.broadphase == "grid"

  @property
  def has_gravity(self) -> bool:
    """Whether gravity (`World.gravity`) is traced."""
    return self.gravity

  @property
  def has_friction(self) -> bool:
    """Whether friction (`World.friction`) is traced."""
    return self.friction

  def replace(self, **changes) -> Config:
    """A copy with some fields changed (validated again)."""
    return dataclasses.replace(self, **changes)

  @classmethod
  def for_world(cls, world, **overrides) -> Config:
    """A config that leaves out what `world` does not use.

    Looks at the (host) world, or a padded batch of worlds, and switches off:
    immovable-body handling when no active body is immovable; chain depth beyond
    what the scene can use: `min(movable bodies, max(8, 2 * longest chain))`, where
    the longest chain is measured over the bodies touching now (a stack of 20 gets
    20, a room of loose boxes 8, two boxes 2); and substeps
    beyond what the current speeds need to keep every body from moving, in one
    substep, its own half-extent plus the thinnest body's (the tunnelling limit;
    see `status.FAST_BODY`; later speed-ups are not foreseen), with each world's
    own gravity; gravity when no world with an active movable body has nonzero
    `World.gravity`; friction when no active body has `World.friction > 0`.
    Switched-off features are not traced. The broadphase is
    dense pairs up to `DENSE_MAX_BODIES` body slots, else the grid, sized by
    `broadphase.allocate` from this world, unless the scene is so crowded that a
    grid row would hold over a quarter of the bodies (then dense is cheaper).
    The link table keeps `max(MIN_LINKS, 2 * most links any movable body has in
    one direction now)` per body and direction (None when that is not below the
    candidate row: nothing to save). Explicit `overrides` always win.

    Raises:
      ValueError: when a body would need more than `MAX_SUBSTEPS` substeps (a tiny
        or very fast body: the message names it, its speed and half-extent); pass
        `substeps=` explicitly to skip that check. And for invalid overrides.

    Examples:
      >>> import jaxchain as jc
      >>> w = jc.World.create([[0.0, 0.0], [0.9, 0.0]], [0.5, 0.5], 1.0, gravity=(0.0, 0.0))
      >>> cfg = jc.Config.for_world(w)
      >>> cfg.immovable, cfg.depth, cfg.has_gravity, cfg.has_friction
      (False, 2, False, False)
    """
    from jaxchain import broadphase as bp  # Import here: broadphase imports config.
    active = np.asarray(world.active)
    inv_mass = np.asarray(world.inv_mass)
    n = int(world.pos.shape[-2])
    movable = active & (inv_mass > 0)
    n_movable = int(np.max(np.sum(movable, axis=-1), initial=0))
    gravity = np.asarray(world.gravity, np.float64)  # [2] or [b, 2].
    switches = dict(
        gravity=bool(np.any(np.any(movable, axis=-1) & np.any(gravity != 0, axis=-1))),
        friction=bool(np.any(active & (np.asarray(world.friction) > 0))))
    switches.update({k: v for k, v in overrides.items() if k in switches})
    derived_keys = ("depth", "immovable", "broadphase", "grid", "substeps", "links")
    base = cls(**{**{k: v for k, v in overrides.items() if k not in derived_keys}, **switches})
    derived = dict(immovable=bool(np.any(active & (inv_mass == 0))))
    if "substeps" not in overrides:
      need = _substep_need(world, base.dt, gravity if base.gravity else 0.0)
      if need.substeps > MAX_SUBSTEPS:
        raise ValueError(need.message(base.dt))
      derived["substeps"] = need.substeps
    broadphase = overrides.get("broadphase", "auto")
    if broadphase in ("auto", "grid") and "grid" not in overrides:
      if broadphase == "grid" or n > DENSE_MAX_BODIES:
        spec = bp.allocate(world, base.skin)
        crowded = spec.row_size > n / 4
        derived.update(grid=spec, broadphase="dense" if crowded and broadphase == "auto" else "grid")
      else:
        derived.update(broadphase="dense")
    chosen = base.replace(**{**derived, **{k: v for k, v in overrides.items() if k in derived_keys}})
    uses_grid = chosen.uses_grid(n)
    cap = max(n_movable, 1)
    if not ("depth" in overrides and "links" in overrides):  # Else nothing to measure.
      movable = world.active & (world.inv_mass > 0)
      chain_found, links_found = bp.measure(world.pos, world.half, world.active, movable,
                                            np.int32(cap), spec=chosen.grid if uses_grid else None,
                                            skin=base.skin)
      derived["depth"] = min(cap, max(Config.depth, 2 * int(np.max(chain_found, initial=0))))
      row = chosen.grid.row_size if uses_grid else n
      links = max(MIN_LINKS, 2 * int(np.max(links_found, initial=0)))
      derived["links"] = links if links < row else None
    derived.update({k: v for k, v in overrides.items() if k in derived_keys})
    return base.replace(**derived)


class _SubstepNeed(NamedTuple):
  """How many substeps a world needs, and the body that needs the most."""

  substeps: int
  body: tuple[int, ...]  # (body,) or (world, body).
  axis: int
  speed: float  # Along `axis`, with one step of gravity.
  half: float
  thinnest: float  # The thinnest active body's half-extent along `axis`.
  safety: float

  def message(self, dt: float) -> str:
    where = (f"body {self.body[0]}" if len(self.body) == 1
             else f"body {self.body[-1]} of world {self.body[0]}")
    return (
        f"Config.for_world: {where} would need {self.substeps} substeps, more than "
        f"MAX_SUBSTEPS = {MAX_SUBSTEPS}: it moves at {self.speed:.3g} along {'xy'[self.axis]} "
        f"(its velocity plus one step of gravity) and has half-extent {self.half:.3g} there "
        f"(the thinnest body {self.thinnest:.3g}), so one step of dt = {dt:.3g} carries it "
        f"{self.speed * dt:.3g}, and without tunnelling it may move only "
        f"{(self.half + self.thinnest) / self.safety:.3g} per substep ((its half-extent + the "
        f"thinnest) / {self.safety:g}). Use larger bodies (or other length units) or a smaller "
        f"dt; or pass substeps= explicitly to run it anyway (status.FAST_BODY then reports "
        f"what moves too far)")


def _substep_need(world, dt: float, gravity=0.0, safety: float = 1.25) -> _SubstepNeed:
  """Fewest substeps with `|v| dt / substeps < (half + thinnest half) / safety` for
  every active body and axis, at the world's current velocities plus one step of
  gravity, and the body that sets it.

  Args:
    world: a world or a padded batch.
    dt: the step.
    gravity: `[2]` (one world) or `[b, 2]` (a batch, one per world), or a scalar;
      normally `world.gravity`, or 0 when gravity is switched off.
    safety: margin on the tunnelling limit.
  """
  active = np.asarray(world.active)
  if not active.any():
    return _SubstepNeed(1, (0,) * active.ndim, 0, 0.0, 0.0, 0.0, safety)
  half = np.asarray(world.half, np.float64)
  gravity = np.asarray(gravity, np.float64)
  if gravity.ndim >= 1:
    gravity = gravity[..., None, :]  # Per world, broadcast over its bodies.
  speed = np.broadcast_to(np.abs(np.asarray(world.vel, np.float64)) + np.abs(gravity) * dt,
                          half.shape)
  thinnest = np.min(half[active], axis=0)
  ratio = np.where(active[..., None], speed * dt * safety / (half + thinnest), 0.0)
  worst = np.unravel_index(int(np.argmax(ratio)), ratio.shape)
  return _SubstepNeed(max(1, int(np.ceil(ratio[worst]))), tuple(int(i) for i in worst[:-1]),
                      int(worst[-1]), float(speed[worst]), float(half[worst]),
                      float(thinnest[worst[-1]]), safety)

