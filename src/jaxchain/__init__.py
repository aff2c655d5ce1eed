"""jaxchain: batched, differentiable 2D box collisions with collision chaining."""

from jaxchain import metrics, reference, scenes
from jaxchain.broadphase import Candidates
from jaxchain.config import Config
from jaxchain.step import Trajectory, make_step, resolve, rollout, step
from jaxchain.world import World, stack

__all__ = [
    "Candidates", "Config", "Trajectory", "World", "make_step", "metrics", "reference", "resolve",
    "rollout", "scenes", "stack", "step",
]
__version__ = "0.1.0"
