"""Failures as values: per-world status bits, sticky across steps.

A step never raises under `jit`; it ORs bits into `World.status` (an int32 per
world, so under `vmap` one bad world does not take down the batch). `check`
turns them into readable messages on the host.
"""

from __future__ import annotations

import enum

import numpy as np


class Status(enum.IntFlag):
  """The status bits of `World.status`; each member's `message` says what went
  wrong and what to do about it (`MESSAGES`).

  An `IntFlag`, so members are ints: `jnp.where(bad, Status.FAST_BODY, 0)` traces
  as a weakly typed int, exactly like the plain int it replaced, and bits combine
  with `|` and test with `&`. The module-level names (`status.FAST_BODY`, ...) are
  the same members.
  """

  OK = 0
  CELL_OVERFLOW = 1 << 0
  STATIC_OVERFLOW = 1 << 1
  BODY_TOO_LARGE = 1 << 2
  NON_FINITE = 1 << 3
  DEPTH_EXHAUSTED = 1 << 4
  FAST_BODY = 1 << 5
  LINK_OVERFLOW = 1 << 6
  SWITCHED_OFF = 1 << 7
  CRUSHED = 1 << 8
  IMPULSES_SCALED = 1 << 9
  NEIGHBOR_OVERFLOW = 1 << 10
  NEIGHBOR_MARGIN = 1 << 11
  PRECISION_LOST = 1 << 12
  FRICTION_OFF = 1 << 13
  GRAVITY_OFF = 1 << 14
  IMMOVABLE_OFF = 1 << 15
  ONE_WAY_OFF = 1 << 16
  SENSORS_OFF = 1 << 17
  LAYERS_OFF = 1 << 18
  OVERLAP_LEFT = 1 << 19
  SKIN_TOO_WIDE = 1 << 20

  @property
  def message(self) -> str:
    """The readable message of a bit (of each bit set, joined by "; "; "" for `OK`)."""
    return "; ".join(MESSAGES[bit] for bit in self)


OK = Status.OK
CELL_OVERFLOW = Status.CELL_OVERFLOW
STATIC_OVERFLOW = Status.STATIC_OVERFLOW
BODY_TOO_LARGE = Status.BODY_TOO_LARGE
NON_FINITE = Status.NON_FINITE
DEPTH_EXHAUSTED = Status.DEPTH_EXHAUSTED
FAST_BODY = Status.FAST_BODY
LINK_OVERFLOW = Status.LINK_OVERFLOW
SWITCHED_OFF = Status.SWITCHED_OFF
CRUSHED = Status.CRUSHED
IMPULSES_SCALED = Status.IMPULSES_SCALED
NEIGHBOR_OVERFLOW = Status.NEIGHBOR_OVERFLOW
NEIGHBOR_MARGIN = Status.NEIGHBOR_MARGIN
PRECISION_LOST = Status.PRECISION_LOST
FRICTION_OFF = Status.FRICTION_OFF
GRAVITY_OFF = Status.GRAVITY_OFF
IMMOVABLE_OFF = Status.IMMOVABLE_OFF
ONE_WAY_OFF = Status.ONE_WAY_OFF
SENSORS_OFF = Status.SENSORS_OFF
LAYERS_OFF = Status.LAYERS_OFF
OVERLAP_LEFT = Status.OVERLAP_LEFT
SKIN_TOO_WIDE = Status.SKIN_TOO_WIDE

# `Config.skin` may be at most the thinnest active body's half-extent over this
# (`SKIN_TOO_WIDE`): gaps within the skin are contacts, so bodies rest and stop up to the
# skin apart, and the contact rules read faces within the skin as level. A power of two:
# `half / SKIN_HALF_RATIO` is exact, so the limit has no rounding of its own.
SKIN_HALF_RATIO = 8

# Every bit's message, in bit order (the order `check` reports them in).
MESSAGES = {
    CELL_OVERFLOW: "a grid cell held more movable bodies than Config.grid.cell_capacity; "
                   "contacts were missed (re-run Config.for_world on the current world, or "
                   "raise cell_capacity)",
    STATIC_OVERFLOW: "the grid's table of immovable bodies overflowed (static_capacity per cell "
                     "or static_entries in all); contacts with walls were missed (re-run "
                     "Config.for_world, or raise those capacities)",
    BODY_TOO_LARGE: "a movable body is larger than Config.grid.reach allows; its contacts may "
                    "be missed (re-run Config.for_world on this world)",
    NON_FINITE: "the state went NaN or inf, or a parameter left its domain (NaN or "
                "non-positive half-extent, NaN or negative inverse mass or friction, NaN "
                "gravity); check inputs: accelerations, dt, coordinates far beyond float "
                "precision, values set inside traced code",
    DEPTH_EXHAUSTED: "a chain was longer than Config.depth could resolve in some pass of a "
                     "step; penetration may be left, or a push, impact or friction not carried "
                     "through the whole chain (positions or velocities differ from a full-depth "
                     "step): raise depth",
    FAST_BODY: "a body moved farther in one substep than it and the thinnest body are thick, "
               "so it may have passed through something (raise Config.substeps)",
    LINK_OVERFLOW: "a body had more links in one direction than Config.links keeps; the "
                   "extra ones were ignored in that pass or in friction (raise links, set it to None, or "
                   "re-run Config.for_world on the current world)",
    SWITCHED_OFF: "the World uses a feature the Config switched off (the *_OFF bit beside "
                  "this one names it); use Config.for_world on this world or switch it on",
    CRUSHED: "a movable body was squeezed between units that lean on immovable bodies on "
             "opposite sides (world.crushed says which); its overlap was split in half and "
             "it took the mean velocity of what crushes it",
    IMPULSES_SCALED: "a pass's contact impulses or friction would have added energy (bodies "
                     "pushing one body together, a fan) and were scaled down for the whole "
                     "world: velocities were damped, momentum kept; the next pass or step meets "
                     "those contacts again",
    NEIGHBOR_OVERFLOW: "a body had more partners within Config.margin than the neighbour table "
                       "holds (Config.neighbors); contacts may have been missed (re-run "
                       "Config.for_world on the current world, or raise neighbors)",
    NEIGHBOR_MARGIN: "a body moved more than Config.margin / 2 along an axis between the "
                     "neighbour table's build and a pass or the sensors that read it; contacts "
                     "may have been missed (re-run Config.for_world on the current world, or "
                     "raise margin or substeps)",
    PRECISION_LOST: "a body moving faster than 1e-3 units/s moved less in a substep than 8 "
                    "float spacings of its coordinate (far from the origin: at x = 1e5 float32 "
                    "steps by 0.0078), so up to 1/16 of its motion or all of it was rounded "
                    "away; recentre the world near the origin, or use float64 "
                    "(jax_enable_x64)",
    FRICTION_OFF: "the World sets friction coefficients > 0 but Config.friction is off: they "
                  "were ignored (use Config.for_world, or friction=True)",
    GRAVITY_OFF: "the World sets gravity on movable bodies but Config.gravity is off: it was "
                 "ignored (use Config.for_world, or gravity=True)",
    IMMOVABLE_OFF: "the World holds immovable bodies (mass inf) but Config.immovable is off: "
                   "they were treated as movable in the chains (use Config.for_world, or "
                   "immovable=True)",
    ONE_WAY_OFF: "the World has one-way bodies (World.one_way) but Config.one_way is off: they "
                 "blocked from every side (use Config.for_world, or one_way=True)",
    SENSORS_OFF: "the World has sensors (World.sensor) but Config.sensors is off: they acted "
                 "as solid bodies and sensed nothing (use Config.for_world, or sensors=True)",
    LAYERS_OFF: "the World's collision layers keep some bodies apart (category/mask) but "
                "Config.layers is off: every pair collided (use Config.for_world, or "
                "layers=True)",
    OVERLAP_LEFT: "a pair the step pushed into each other still overlapped by more than the "
                  "skin after the step's passes and Config.closing closing passes (not "
                  "crushed, not one-way); the next step lifts it out by position, which can "
                  "add potential energy (raise closing, iterations or substeps)",
    SKIN_TOO_WIDE: "Config.skin is wider than 1/8 of the thinnest active body's half-extent "
                   "(status.SKIN_HALF_RATIO): gaps within the skin count as contact, so "
                   "bodies rest and stop up to the skin apart (lower skin; the default 1e-4 "
                   "suits bodies of half-extent 8e-4 and up)",
}


def check(world) -> list[str]:
  """Readable messages for every status bit set, one per (world, problem).

  Args:
    world: a `World`, single or batched (status of shape `[]` or `[b]`).

  Returns:
    An empty list when every world is fine, else lines like
    `"world 3: a grid cell held more movable bodies ..."`.

  Examples:
    >>> import jaxchain as jc
    >>> jc.check(jc.World.create([[0.0, 0.0]], [0.5, 0.5], 1.0))
    []
  """
  codes = np.atleast_1d(np.asarray(world.status))
  out = []
  for b, code in enumerate(codes):
    for bit, text in MESSAGES.items():
      if code & bit:
        out.append(f"world {b}: {text}")
    unknown = int(code) & ~sum(MESSAGES)
    if unknown:
      out.append(f"world {b}: unknown status bits {unknown:#x}")
  return out
