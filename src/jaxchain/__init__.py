"""jaxchain: batched, differentiable 2D box collisions with collision chaining."""

from jaxchain import broadphase, drawing, env, levels, metrics, reference, scenes, sizing, status
from jaxchain.broadphase import GridSpec
from jaxchain.config import Config
from jaxchain.drawing import render, render_trajectory, save_gif
from jaxchain.flags import blocked, grounded
from jaxchain.geometry import Candidates
from jaxchain.status import check
from jaxchain.stepping import Trajectory, make_step, resolve, rollout, step
from jaxchain.world import World, stack

__all__ = [
    "Candidates", "Config", "GridSpec", "Trajectory", "World", "blocked", "broadphase", "check", "drawing", "env",
    "grounded", "levels", "make_step", "metrics", "reference", "render", "render_trajectory", "resolve", "rollout", "save_gif", "scenes", "sizing", "stack", "status", "step",
]
__version__ = "0.1.0"
