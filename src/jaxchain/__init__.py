"""jaxchain: batched, differentiable 2D box collisions with collision chaining."""

from jaxchain import (broadphase, core, drawing, env, levels, metrics, queries, reference, scenes, sizing,
                      status)
from jaxchain.broadphase import GridSpec
from jaxchain.config import Config
from jaxchain.drawing import render, render_trajectory, save_gif
from jaxchain.flags import blocked, grounded
from jaxchain.queries import (RayHit, SlideInfo, drive_platforms, drop_through, move_and_slide,
                              query_aabb, query_point, raycast, touching_bodies)
from jaxchain.status import check
from jaxchain.stepping import Trajectory, make_step, resolve, rollout, step
from jaxchain.world import World, stack

__all__ = [
    "Config", "GridSpec", "RayHit", "SlideInfo", "Trajectory", "World", "blocked", "broadphase", "check",
    "core", "drawing", "drive_platforms", "drop_through", "env", "grounded", "levels", "make_step", "metrics", "move_and_slide",
    "queries", "query_aabb", "query_point", "raycast", "reference", "render", "render_trajectory", "resolve", "rollout",
    "save_gif", "scenes", "sizing", "stack", "status", "step", "touching_bodies",
]
__version__ = "0.1.0"
