"""Static configuration: a frozen, hashable value that selects what gets traced."""

from __future__ import annotations

import dataclasses
import math

import jax
import numpy as np

from jaxchain import sizing
from jaxchain.broadphase import GridSpec  # Re-exported: jaxchain.config.GridSpec.
# Re-exported: the sizing limits are documented as jaxchain.config.MAX_SUBSTEPS etc.
from jaxchain.sizing import DENSE_MAX_BODIES, MAX_SUBSTEPS, MIN_LINKS

BROADPHASES = ("auto", "dense", "grid")

_REALS = (int, float, np.integer, np.floating)


@jax.tree_util.register_static
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
      travels through a row of touching boxes in the same pass. A rounding tolerance:
      at most the thinnest active body's half-extent / `status.SKIN_HALF_RATIO` (8),
      else every step sets `status.SKIN_TOO_WIDE` (bodies rest up to the skin apart).
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
    one_way: whether one-way (jump-through) bodies are traced (`World.one_way`);
      `False` treats every body as solid.
    layers: whether collision layers are traced (`World.category`, `World.mask`);
      `False` lets every pair interact.
    sensors: whether sensors are traced (`World.sensor`, output `World.sensed`);
      `False` treats sensors as solid bodies and leaves `sensed` False.
      `for_world` switches each of these three off when no world of the batch uses
      it, and a world that uses one its config leaves out sets
      `status.SWITCHED_OFF` and the bit naming it (`ONE_WAY_OFF`, `LAYERS_OFF`,
      `SENSORS_OFF`).
    converge: forward-only mode: every hop loop is a `while_loop` that stops after
      its second hop when that hop changed nothing (in the whole batch), else runs its
      `depth` hops; the same answer as `depth` hops, bit for bit. Faster where
      nothing is carried (free fall), as fast on a settled room; not
      reverse-differentiable: `jax.grad` through `rollout`, `step` or `resolve` raises
      a `ValueError` naming `converge=False`, so leave it off for gradients.
    neighbors: width of the neighbour table, or None to read the coarse candidates
      (dense pairs or grid rows, by `broadphase`) in every pass. When set, the
      coarse table is filtered into the partners of each movable body within
      `margin` (`broadphase.build`), this many per body at most, and every pass and
      the sensors read that narrow table: the pair stages cost `n * neighbors`
      instead of `n * n`. `step` builds it every substep; `rollout` keeps it from
      step to step while every body stays within `margin / 2` of where it was built
      (the same answers). Exact: a row with more partners sets
      `status.NEIGHBOR_OVERFLOW`, and a body that moves more than `margin / 2` along
      an axis between the build and a use sets `status.NEIGHBOR_MARGIN`; neither is
      ever a silent miss. `for_world` sizes it from the scene.
    closing: the closing stage's budget: after the `iterations` passes, a world that
      still has a pair overlapping by more than `skin` (pushed into each other by the
      step: a support still sinking under a box) runs more passes from the positions
      reached, at most this many, so the step ends without that overlap; a world with
      none left keeps its state bit for bit, and a batch with none skips them. When the
      budget runs out, `status.OVERLAP_LEFT`; with 0 the overlap is reported, not
      closed. Positions-only `resolve` has no closing stage.
    margin: how far apart (gap along each axis, beyond `skin`) bodies may be and still
      enter the neighbour table: the motion it allows between its build and its last
      use in a substep (the resolution passes and the sensors), `margin / 2` per
      body and axis. `for_world` sizes it from the bodies' sizes and speeds.
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
  one_way: bool = True
  layers: bool = True
  sensors: bool = True
  converge: bool = False
  neighbors: int | None = None
  margin: float = 0.0
  closing: int = 2

  def __post_init__(self):
    for name, example in (("gravity", "gravity=(0.0, -9.81)"), ("friction", "friction=0.3")):
      v = getattr(self, name)
      if not isinstance(v, (bool, np.bool_)):
        raise ValueError(
            f"Config.{name} is now an on/off switch (a bool), got {v!r}; {name} values live "
            f"in the World: World.create(..., {example}) or world.replace({name}=...), with "
            f"Config({name}=True) (the default)")
      object.__setattr__(self, name, bool(v))
    for name in ("dt", "skin", "margin"):
      v = getattr(self, name)
      if isinstance(v, bool) or not isinstance(v, _REALS) or not math.isfinite(v):
        raise ValueError(f"Config.{name}: expected a finite number, got {v!r}")
      object.__setattr__(self, name, float(v))
    if self.dt <= 0:
      raise ValueError(f"Config.dt: must be > 0, got {self.dt}")
    if self.skin < 0:
      raise ValueError(f"Config.skin: must be >= 0, got {self.skin}")
    for name, lo in (("depth", 0), ("iterations", 1), ("substeps", 1), ("closing", 0)):
      v = getattr(self, name)
      if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < lo:
        raise ValueError(f"Config.{name}: expected an integer >= {lo}, got {v!r}")
      object.__setattr__(self, name, int(v))
    if self.links is not None and (isinstance(self.links, bool) or
                                   not isinstance(self.links, (int, np.integer)) or self.links < 1):
      raise ValueError(f"Config.links: expected None or an integer >= 1, got {self.links!r}")
    if self.links is not None:
      object.__setattr__(self, "links", int(self.links))
    if self.neighbors is not None and (isinstance(self.neighbors, bool) or
                                       not isinstance(self.neighbors, (int, np.integer))
                                       or self.neighbors < 1):
      raise ValueError(f"Config.neighbors: expected None or an integer >= 1, got "
                       f"{self.neighbors!r}")
    if self.neighbors is not None:
      object.__setattr__(self, "neighbors", int(self.neighbors))
    if self.margin < 0:
      raise ValueError(f"Config.margin: must be >= 0, got {self.margin}")
    if not isinstance(self.broadphase, str) or self.broadphase not in BROADPHASES:
      raise ValueError(f"Config.broadphase: expected one of {BROADPHASES}, got {self.broadphase!r}")
    object.__setattr__(self, "broadphase", str(self.broadphase))
    for name in ("immovable", "one_way", "layers", "sensors", "converge"):
      v = getattr(self, name)
      if not isinstance(v, (bool, np.bool_)):
        raise ValueError(f"Config.{name}: expected a bool, got {v!r}")
      object.__setattr__(self, name, bool(v))
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

    Implemented by `jaxchain.sizing.for_world` (all host-side sizing lives there);
    this classmethod is the public entry point and delegates to it.

    Looks at the (host) world, or a padded batch of worlds, and switches off:
    immovable-body handling when no active body is immovable; chain depth beyond
    what the scene can use: `min(movable bodies, max(8, 2 * longest chain, tallest
    stack))`, where the longest chain is measured over the bodies touching now (a
    stack of 20 gets 20, a room of loose boxes 8, two boxes 2) and, under gravity, the
    tallest stack is the most movable bodies in one column along gravity
    (`sizing.stack_bound`: boxes falling into columns of 16 get 16 though nothing
    touches yet); and substeps
    beyond what the current speeds need to keep every body from moving, in one
    substep, its own half-extent plus the thinnest body's (the tunnelling limit;
    see `status.FAST_BODY`; later speed-ups are not foreseen), with each world's
    own gravity; gravity when no world with an active movable body has nonzero
    `World.gravity`; friction when no active body has `World.friction > 0`.
    Switched-off features are not traced. The broadphase is
    dense pairs up to `DENSE_MAX_BODIES` body slots, else the grid, sized by
    `broadphase.allocate` from this world, unless the scene is so crowded that a
    grid row would hold over a quarter of the bodies (then dense is cheaper).
    The link table keeps as many links per body and direction as non-overlapping
    bodies of this scene's sizes can make (`sizing.link_bound`: 2 for boxes of one
    size), or the most any movable body has now if that is more (None when that is
    not below the candidate row: nothing to save); an overlapping crowd that needs
    more raises `LINK_OVERFLOW`. The neighbour table (`neighbors`, `margin`;
    `sizing.neighbor_sizing`) gets a margin of half the thinnest movable body, or
    more for fast bodies and deep overlaps, and a width of `max(MIN_NEIGHBORS,
    1.5 * most partners within the margin now)`; it is left out (None) when that is
    more than half the coarse row (small worlds). Explicit `overrides` always win.

    `keep`: switches to leave on whatever the world holds now, any of `("friction",
    "gravity", "immovable", "one_way", "sensors", "layers")`. For fitting: a guess of
    friction 0 or gravity 0 would otherwise switch the feature off, and its gradient
    would be 0 silently (the feature is not in the compiled step). `keep=("friction",)`
    is `friction=True` that reads better beside other kept features.

    Raises:
      ValueError: when a body would need more than `MAX_SUBSTEPS` substeps (a tiny
        or very fast body: the message names it, its speed and half-extent); pass
        `substeps=` explicitly to skip that check. And for invalid overrides or an
        unknown `keep` name.

    Examples:
      >>> import jaxchain as jc
      >>> w = jc.World.create([[0.0, 0.0], [0.9, 0.0]], [0.5, 0.5], 1.0, gravity=(0.0, 0.0))
      >>> cfg = jc.Config.for_world(w)
      >>> cfg.immovable, cfg.depth, cfg.has_gravity, cfg.has_friction
      (False, 2, False, False)
      >>> jc.Config.for_world(w, keep=("friction", "gravity")).has_friction
      True
    """
    return sizing.for_world(cls, world, **overrides)
