"""Environments: gymnax-style reinforcement-learning tasks on jaxchain levels.

    env, params = jc.env.make("push_box")
    obs, state = env.reset(key, params)
    obs, state, reward, done, info = env.step(key, state, action, params)

Everything is pure and jittable, and vmappable over keys, states and actions
(PureJaxRL style: `jax.vmap(env.step, in_axes=(0, 0, 0, None))`). `step` resets
by itself: when an episode ends, the returned `obs` and `state` are those of a
fresh `reset`, and `info["final_obs"]` holds the observation the episode ended on.

Tasks are compositions (`Task`): the levels; an action map (`Accelerate`,
`Moves`, `RunJump`, or your own `ActionMap`, with action repeat); reward,
termination and observation hooks, pure and jittable; optional forces (drag), a
`before` hook (kinematic platforms) and a `randomize` hook. `make(task)` turns a
`Task` (or a name of `TASKS`) into an `Environment`, which keeps the loop:
reset, auto-reset, `final_obs`, truncation at `max_steps` and the info dict.

    task = jc.env.Task(name="mine", levels=[ascii_map], actions=jc.env.Moves(repeat=4),
                       reward=my_reward, terminate=my_terminate,
                       slots=(("box", 2), ("goal", 2)))
    env, params = jc.env.make(task)

Levels are fixed-capacity. At `make` time (on the host) every level is loaded
(`load_level`), its bodies rearranged into fixed slots (the player in slot 0, then
each slot group of the task, walls last, every group padded with inactive slots
to one count) and stacked as arrays held by the env (`env.level_data`); `reset`
picks a level with `jax.random` and builds its world with `World.from_arrays` plus
start jitter, so it runs inside `jit`. One static `jaxchain.Config` per env comes
from `Config.for_world` on the stacked levels (`converge=False`, so `jax.grad`
works through `step`).

Shipped tasks (`TASKS`; their params classes hold the scales):

* `"push_box"`: Sokoban from above (gravity 0) on `sokoban1`-`sokoban3`. A
  continuous player (`Accelerate`): the action is a 2-D acceleration in
  `[-1, 1]^2` (clipped), times `PushBoxParams.accel`; the player feels linear
  drag `drag` and boxes `box_drag` (`drag`: from above there is no floor to rub
  on, so drag stands in for friction). It pushes boxes onto goal sensors (a
  goal's mask admits boxes only). Reward (`push_reward`): `goal_reward` for each
  box newly on a goal (minus as much for each box pushed off one),
  `success_reward` once all goals are filled, `shaping` times the decrease of
  the box-goal distance (the sum over boxes of the Manhattan distance to the
  nearest goal), minus `step_cost` every step and `crush_penalty` if the player
  is crushed. Ends (terminated) when every goal is filled or the player is
  crushed; truncated at `max_steps`.
* `"push_box_discrete"`: the same with `Moves`: `Discrete(5)` (noop, left,
  right, down, up), each an acceleration `accel` along its direction.
* `"push_box_easy"`: push_box's rules on four small rooms (`LEVELS`: `push_east`,
  `push_west`, `push_north`, `push_south`), one box in line between the player
  and the goal: the task of the training example.
* `"reach_flag"`: a platformer (gravity from the level) on `platformer1` and
  `platformer2`: one-way platforms, pushable boxes, a flag sensor, hazards.
  Discrete actions (`RunJump`, `ACTIONS`): 0 noop, 1 left, 2 right, 3 jump, 4
  left+jump, 5 right+jump. Horizontal control steers the player's velocity
  toward `-run_speed`, 0 or `+run_speed` with gain `run_gain` (per second; on the
  ground and in the air). A jump is an upward acceleration `jump` (420: about
  7 u/s, 2.5 cells high) for one step, applied only when the player was grounded
  (`jc.grounded`) after the previous step. Boxes feel horizontal drag `box_drag`.
  Kinematic platforms patrol: each turns back every `patrol` steps (so it never
  drifts out of the level). Reward: `success_reward` on reaching the flag (the
  flag sensor senses the player), minus `hazard_penalty` on touching a hazard
  and `crush_penalty` on being crushed, plus `shaping` times the decrease of the
  player-flag Manhattan distance (0 by default), minus `step_cost`. Ends on the
  flag, a hazard or crushing (terminated), or at `max_steps` (truncated).

Params: `EnvParams` holds what every task reads (`max_steps`, `jitter`, and the
physics overrides `gravity` and `friction`); `PushBoxParams` and
`ReachFlagParams` add each task family's scales. A custom task may subclass
either (register it with `jax.tree_util.register_dataclass`).

Physics and randomisation: `make(name, friction=True)` traces friction (the
levels' own coefficients), `make(name, friction=0.5)` also sets
`params.friction`, and `gravity=` likewise (`gravity=(0, -9.81)`); other `Config`
fields are keywords of `make` too (`depth=4`), or pass `config=`. Every reset puts
`params.gravity`/`params.friction` (when not None) into the world, then applies
the task's `randomize(key, world, params)` hook (`uniform_physics` draws gravity,
friction, masses and sizes), so auto-reset keeps them. A params value or hook the
Config would ignore raises instead (at `make`, or at trace time for params set
later): physics is never dropped silently.

Actions: `step` checks the action at trace time: a wrong shape or kind of dtype
raises, naming `action` and the expected shape and dtype (a scalar is never
broadcast to a 2-D action). A discrete action out of range or a non-finite
continuous one is invalid: `info["invalid_action"]` is set, the action acts as the
noop, and the episode ends as `truncated` (not `terminated`: the state is not a
real terminal state). `make(..., check_actions="raise")` also raises on a concrete
invalid action (an eager call), for debugging. Finite continuous actions outside
`[-1, 1]` are clipped.

Observations (`make(..., obs=...)`; `observation_space(params)` matches):

* `"vector"` (default): one flat float32 vector,

  | index | content |
  | --- | --- |
  | 0-1 | player centre relative to the level's bounds, `(p - lo) / (hi - lo)` (0..1 inside) |
  | 2-3 | player velocity (units/s) |
  | 4-7 | player contact flags `touching` (+x, -x, +y, -y) as 0/1 (7 is grounded) |
  | 8 | `t / max_steps`, the fraction of the episode's step budget used |
  | 9 + 8k ... 16 + 8k | slot k: present, dx, dy, vx, vy, hx, hy, flag |

  A slot describes one body: `present` is 1 for a body and 0 for a padding slot
  (whose eight numbers are all 0); `dx, dy` its centre minus the player's; `vx,
  vy` its velocity; `hx, hy` its half-extents; `flag` is, for a sensor, whether it
  senses something now (a goal holds a box); for a box, whether it lies on a
  goal; for a platform, 1 if one-way (0 for a solid kinematic platform); 0 for a
  wall. Slots, in order (`env.slots`): push_box 4 boxes, 4 goals, 11 walls (obs
  size 161); push_box_easy 4 boxes, 4 goals, 4 walls (105); reach_flag 1 flag, 4
  boxes, 4 hazards, 6 platforms, 4 walls (161). Walls (static solids, merged into
  rectangles by the level loader) are observed, so a policy can read the layout.
* `"grid"`: `[H, W, C]` float32 occupancy in one-unit cells over the largest
  level (`env.grid_shape`), one channel per kind (`env.grid_channels`: player,
  then the slot groups, walls included): see `observations.grid`.
* `"pixels"`: `uint8[H, W, 3]`, `jaxchain.render` of the level at `pixel_size`
  (default 64x64), sensors drawn at least 0.3 units large so goals show.

`info` (every step): `final_obs` (the observation the step produced, before any
reset), `terminated`, `truncated`, `success`, `invalid_action` (bools),
`episode_return` and `episode_length` (of the episode so far, final where
`done`), `status` (the world's status bits after the step).

Dtypes: obs float32 (uint8 for pixels), reward and `episode_return` float32,
actions float32 / int32, also under `JAX_ENABLE_X64` (the world itself is then
float64).

Every task also ends (terminated, reward 0) when the world goes non-finite
(`status.NON_FINITE`), so one broken world resets instead of poisoning a batch.

Cost: a step is one `jaxchain.step` on the env's 9-20 body slots (dense pairs)
per action repeat, plus the reset it may need; on 2 CPU cores that is about
1e4-2e4 env-steps/s, with little gain from batching (CPU-bound per world;
`benchmarks/results/env_throughput.md`).
"""

from jaxchain.env.actions import ACTIONS, MOVES, Accelerate, ActionMap, Moves, RunJump
from jaxchain.env.core import (CHECK_ACTIONS, LEVELS, OBS_MODES, Environment, EnvParams,
                                   EnvState, PushBoxParams, ReachFlagParams, Task, load_level)
from jaxchain.env.observations import PLAYER_FEATURES, SLOT_FIELDS, senses
from jaxchain.env.spaces import Box, Discrete
from jaxchain.env.sokoban import (LURD, SokobanMoves, make_replay, sokoban_actions,
                                     sokoban_terminate)
from jaxchain.env.tasks import (TASK_DEFS, TASK_LEVELS, TASKS, all_goals_filled,
                                    box_drag_x, box_goal_distance, drag, goals_filled, make,
                                    patrol, push_reward, push_terminate, reach_reward,
                                    reach_terminate, UniformPhysics,
                                    uniform_physics)

__all__ = [
    "ACTIONS", "CHECK_ACTIONS", "LEVELS", "MOVES", "OBS_MODES", "PLAYER_FEATURES", "SLOT_FIELDS",
    "TASKS", "TASK_DEFS", "TASK_LEVELS", "Accelerate", "ActionMap", "Box", "Discrete",
    "EnvParams", "EnvState", "Environment", "Moves", "PushBoxParams", "ReachFlagParams",
    "RunJump", "Task", "UniformPhysics", "all_goals_filled", "box_drag_x", "box_goal_distance", "drag",
    "goals_filled", "load_level", "make", "patrol", "push_reward", "push_terminate",
    "reach_reward", "reach_terminate", "senses", "uniform_physics",
    "SokobanMoves", "sokoban_terminate", "LURD", "make_replay", "sokoban_actions",
]
