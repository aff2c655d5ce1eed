"""Bridges: jaxchain environments as gymnax, Gymnasium and Stable-Baselines3 environments.

Four adapters around an env from `jaxchain.env.make` (or any env with its API):

* `GymnaxEnv`: a subclass of gymnax's `Environment` (`gymnax.environments.
  environment.Environment`, gymnax >= 1.0): `step_env`, `reset_env`, `get_obs`,
  `is_terminal`, `action_space`, `observation_space` (gymnax spaces),
  `default_params`, `name`, `num_actions`, `render`. gymnax's own `step` does the
  auto-reset and returns `(obs, state, reward, terminated, truncated, info)` with
  `info["final_observation"]`. `register_gymnax()` registers the shipped tasks
  with `gymnax.register`, so `gymnax.make("PushBoxEasy-jaxchain")` works.
* `GymnasiumVectorEnv`: a `gymnasium.vector.VectorEnv` of `num_envs` worlds, NumPy in
  and out (for CleanRL-style host loops). One jitted, vmapped step for the whole
  batch; it resets finished worlds in the same step (`AutoresetMode.SAME_STEP`,
  `info["final_obs"]` and `info["final_info"]` with their `_final_obs` masks, as
  Gymnasium's `SyncVectorEnv` gives them in that mode); float64 rewards and
  per-env seeds as `SyncVectorEnv`.
* `SB3VecEnv`: the same batch as a Stable-Baselines3 `VecEnv` (SB3 refuses
  Gymnasium's `VectorEnv`), giving what SB3's `DummyVecEnv` gives.
* `GymnasiumEnv`: one world as a `gymnasium.Env` (it passes
  `gymnasium.utils.env_checker.check_env`). `register_gymnasium()` registers the
  shipped tasks, so `gymnasium.make("jaxchain/PushBoxEasy-v0")` and
  `gymnasium.make_vec("jaxchain/PushBoxEasy-v0", num_envs=64,
  vectorization_mode="vector_entry_point")` work.

gymnax and Gymnasium are optional (`pip install "jaxchain[rl]"`), Stable-Baselines3
too (`pip install "jaxchain[sb3]"`), and imported only when an adapter is first
used: `import jaxchain` and `import jaxchain.bridges` need none of them. Every
adapter pickles and deep-copies (the copy rebuilds its jitted functions).

Examples:
  >>> import numpy as np
  >>> from jaxchain import bridges
  >>> envs = bridges.GymnasiumVectorEnv("push_box_easy", num_envs=4)
  >>> obs, info = envs.reset(seed=0)
  >>> obs.shape, obs.dtype
  ((4, 105), dtype('float32'))
  >>> obs, reward, terminated, truncated, info = envs.step(envs.action_space.sample())
  >>> reward.shape, terminated.dtype, sorted(info)[:2]
  ((4,), dtype('bool'), ['_episode_length', '_episode_return'])
"""

from jaxchain.bridges.common import GYMNASIUM_IDS, GYMNAX_IDS
from jaxchain.bridges.gymnasium import _gymnasium_classes, register_gymnasium
from jaxchain.bridges.gymnax import GymnaxState, _gymnax_class, register_gymnax
from jaxchain.bridges.sb3 import _sb3_class

__all__ = ["GymnaxEnv", "GymnaxState", "GymnasiumEnv", "GymnasiumVectorEnv", "SB3VecEnv",
           "GYMNAX_IDS", "GYMNASIUM_IDS", "register_gymnax", "register_gymnasium"]


def __getattr__(name: str):
  """The adapter classes, built on first use (so gymnax and gymnasium load lazily)."""
  if name == "GymnaxEnv":
    return _gymnax_class()
  if name == "GymnasiumEnv":
    return _gymnasium_classes()[0]
  if name == "GymnasiumVectorEnv":
    return _gymnasium_classes()[1]
  if name == "SB3VecEnv":
    return _sb3_class()
  raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
