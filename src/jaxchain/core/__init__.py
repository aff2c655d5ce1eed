"""The stepping core, batch minor: every array is `[..., n, B]`, the batch of worlds last.

One pass is one call per stage: `pairs` (candidates: dense, neighbour table, grid),
`contacts` (contacts, seams, one-way bodies, layers, sensors; the link table), `chain`
(backing, split, push, impulses, crushing), `friction`, `flags`. `step` puts them
together (`step.passes`, `step.substep`, `step.step`, `step.resolve`, `step.rollout`);
`layout` holds the `State` / `Bodies` pytrees and the transposes from and to a `World`.
`jaxchain.stepping` is the public entry (`jc.step`, `jc.rollout`, `jc.resolve`).
"""

from jaxchain.core import chain, contacts, flags, friction, layout, pairs, step
from jaxchain.core.layout import Bodies, State, from_world, to_world

__all__ = ["Bodies", "State", "chain", "contacts", "flags", "friction", "from_world", "layout",
           "pairs", "step", "to_world"]
