"""Bridges: jaxchain environments as gymnax and Gymnasium environments.

Three adapters around an env from `jaxchain.env.make` (or any env with its API):

* `GymnaxEnv`: a subclass of gymnax's `Environment` (`gymnax.environments.
  environment.Environment`, gymnax >= 1.0): `step_env`, `reset_env`, `get_obs`,
  `is_terminal`, `action_space`, `observation_space` (gymnax spaces),
  `default_params`, `name`, `num_actions`. gymnax's own `step` does the auto-reset
  and returns `(obs, state, reward, terminated, truncated, info)` with
  `info["final_observation"]`. `register_gymnax()` registers the shipped tasks
  with `gymnax.register`, so `gymnax.make("PushBoxEasy-jaxchain")` works.
* `GymnasiumVectorEnv`: a `gymnasium.vector.VectorEnv` of `num_envs` worlds, NumPy in
  and out (for SB3 / CleanRL-style host loops). One jitted, vmapped step for the
  whole batch; it resets finished worlds in the same step (`AutoresetMode.SAME_STEP`,
  `info["final_obs"]` and `info["final_info"]` with their `_final_obs` masks, as
  Gymnasium's `SyncVectorEnv` gives them in that mode).
* `GymnasiumEnv`: one world as a `gymnasium.Env` (it passes
  `gymnasium.utils.env_checker.check_env`). `register_gymnasium()` registers the
  shipped tasks, so `gymnasium.make("jaxchain/PushBoxEasy-v0")` and
  `gymnasium.make_vec("jaxchain/PushBoxEasy-v0", num_envs=64,
  vectorization_mode="vector_entry_point")` work.

gymnax and Gymnasium are optional (`pip install "jaxchain[rl]"`) and imported
only when an adapter is first used: `import jaxchain` and `import
jaxchain.bridges` need neither.

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

from __future__ import annotations

import dataclasses
import functools
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from jaxchain import env as env_lib

__all__ = ["GymnaxEnv", "GymnaxState", "GymnasiumEnv", "GymnasiumVectorEnv", "GYMNAX_IDS",
           "GYMNASIUM_IDS", "register_gymnax", "register_gymnasium"]

# Registered names of the shipped tasks (gymnax's "Name-suite" and Gymnasium's
# "namespace/Name-vN" conventions).
_CAMEL = {"push_box": "PushBox", "push_box_easy": "PushBoxEasy",
          "push_box_discrete": "PushBoxDiscrete", "reach_flag": "ReachFlag"}
GYMNAX_IDS = {task: f"{camel}-jaxchain" for task, camel in _CAMEL.items()}
GYMNASIUM_IDS = {task: f"jaxchain/{camel}-v0" for task, camel in _CAMEL.items()}


def _make(env, params, kwargs):
  """`(env, params)` from a task name or `Task` (with `make` keywords), or a built env."""
  if isinstance(env, str) or isinstance(env, env_lib.Task):
    if params is not None:
      raise TypeError("pass params only with a built env, not with a task name")
    return env_lib.make(env, **kwargs)
  if kwargs:
    raise TypeError(f"make keywords {sorted(kwargs)} need a task name, not a built env")
  return env, (env.default_params if params is None else params)


# Distributions of modules whose pip name differs from their import name.
_DISTRIBUTIONS = {"absl": "absl-py", "yaml": "pyyaml", "stable_baselines3": "stable-baselines3"}


def _missing(package: str, error: ImportError, extra: str = "rl") -> ImportError:
  """The ImportError to raise when importing `package` failed with `error`.

  It names the module that is really missing (`error.name`): `package` itself (not
  installed: install the extra), or a module that `package` imports (installed, but
  a dependency it needs is not: install that one)."""
  missing = getattr(error, "name", None)
  top = (missing or "").split(".")[0]
  if top == package.split(".")[0]:
    return ImportError(f"jaxchain.bridges needs {package}, which is not installed: "
                       f"pip install \"jaxchain[{extra}]\"")
  if missing:
    dist = _DISTRIBUTIONS.get(top, top)
    return ImportError(f"jaxchain.bridges: {package} is installed but importing it failed: "
                       f"it imports the module {missing!r}, which is not installed ({error}). "
                       f"pip install {dist}")
  return ImportError(f"jaxchain.bridges: importing {package} failed: {error} (a version that "
                     f"does not match? pip install -U \"jaxchain[{extra}]\")")


# gymnax.


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class GymnaxState:
  """`GymnaxEnv`'s state: the jaxchain `EnvState` and the outcome of its last step.

  Attributes:
    env_state: the wrapped env's `EnvState`.
    time: `[]` int32, steps in this episode (gymnax's `EnvState.time`).
    terminated: `[]` bool, the last step ended the episode in a terminal state.
    truncated: `[]` bool, the last step cut the episode (`max_steps`, or an invalid
      action).
  """

  env_state: Any
  time: jax.Array
  terminated: jax.Array
  truncated: jax.Array

  def replace(self, **changes) -> GymnaxState:
    """A copy with some fields changed."""
    return dataclasses.replace(self, **changes)


@functools.cache
def _gymnax_class():
  try:
    from gymnax.environments import environment, spaces
  except ImportError as e:
    raise _missing("gymnax", e) from e

  class GymnaxEnv(environment.Environment):
    """A jaxchain env under gymnax's `Environment` interface.

    gymnax's `step` (inherited, jitted with `self` static) calls `step_env`, asks
    `is_truncated`, and resets with `reset_env` where the episode ended. The
    adapter's state is a `GymnaxState`; its params are the wrapped env's params.
    Like gymnax's own envs, transitions stop gradients unless
    `with_transition_gradients()` is called (jaxchain's steps are differentiable).

    Args:
      env: a task name of `jaxchain.env.TASKS`, a `jaxchain.env.Task`, or an env
        built by `jaxchain.env.make`.
      params: the params of a built env (default: its `default_params`).
      **make_kwargs: keywords of `jaxchain.env.make`, with a task name.

    Examples:
      >>> import jax
      >>> from jaxchain import bridges
      >>> env = bridges.GymnaxEnv("push_box_easy")
      >>> params = env.default_params
      >>> obs, state = env.reset(jax.random.key(0), params)
      >>> action = env.action_space(params).sample(jax.random.key(1))
      >>> obs, state, reward, terminated, truncated, info = env.step(
      ...     jax.random.key(2), state, action, params)
    """

    _supports_transition_gradients = True

    def __init__(self, env, params=None, **make_kwargs):
      super().__init__()
      self.env, self._params = _make(env, params, make_kwargs)

    @property
    def default_params(self):
      return self._params

    def reset_env(self, key, params):
      obs, state = self.env.reset(key, params)
      false = jnp.zeros((), bool)
      state = GymnaxState(state, jnp.zeros((), jnp.int32), false, false)
      return self._apply_transition_gradient_policy(obs, state)

    def step_env(self, key, state, action, params):
      obs, inner, reward, done, info = self.env.step_env(key, state.env_state, action, params)
      del done
      state = GymnaxState(inner, state.time + 1, info["terminated"], info["truncated"])
      obs, state = self._apply_transition_gradient_policy(obs, state)
      info = {k: v for k, v in info.items() if k not in ("terminated", "truncated")}
      return obs, state, reward, state.terminated, info

    def get_obs(self, state, params=None, key=None):
      del key
      return self.env.get_obs(state.env_state, self._params if params is None else params)

    def is_truncated(self, state, params):
      del params
      return state.truncated

    def is_terminated(self, state, params):
      del params
      return state.terminated

    def is_terminal(self, state, params):
      """gymnax's legacy done test: terminated or truncated."""
      return self.is_terminated(state, params) | self.is_truncated(state, params)

    @property
    def name(self) -> str:
      return GYMNAX_IDS.get(self.env.name, f"{self.env.name}-jaxchain")

    @property
    def num_actions(self) -> int:
      return self.env.num_actions

    def action_space(self, params=None):
      space = self.env.action_space(params)
      if hasattr(space, "n"):
        return spaces.Discrete(int(space.n))
      return spaces.Box(space.low, space.high, tuple(space.shape), jnp.dtype(space.dtype))

    def observation_space(self, params=None):
      space = self.env.observation_space(params)
      return spaces.Box(space.low, space.high, tuple(space.shape), jnp.dtype(space.dtype))

    def __repr__(self) -> str:
      return f"GymnaxEnv({self.env!r})"

  return GymnaxEnv


def register_gymnax() -> list[str]:
  """Registers the shipped tasks with `gymnax.register` (once; later calls do nothing).

  Returns:
    The ids (`GYMNAX_IDS`), e.g. "PushBoxEasy-jaxchain": `gymnax.make(id, **kwargs)`
    returns `(GymnaxEnv(task, **kwargs), params)`.
  """
  try:
    import gymnax
  except ImportError as e:
    raise _missing("gymnax", e) from e
  cls = _gymnax_class()
  for task, env_id in GYMNAX_IDS.items():
    if task in env_lib.TASKS and env_id not in gymnax.registered_envs:
      gymnax.register(env_id, functools.partial(cls, task))
  return [GYMNAX_IDS[t] for t in GYMNAX_IDS if t in env_lib.TASKS]


# Gymnasium.


def _gym_space(space):
  """A Gymnasium space for a jaxchain `Discrete` or `Box`."""
  from gymnasium import spaces
  if hasattr(space, "n"):
    return spaces.Discrete(int(space.n))
  dtype = np.dtype(space.dtype)
  cast = int if np.issubdtype(dtype, np.integer) else float
  return spaces.Box(cast(space.low), cast(space.high), tuple(space.shape), dtype)


def _as_action(space, action, batch: tuple[int, ...]) -> jax.Array:
  """A host action as the jax array the env expects (its dtype; shape checked there)."""
  action = np.asarray(action)
  want = batch + tuple(space.shape)
  if action.shape != want:
    raise ValueError(f"action: expected shape {want}, got {action.shape}")
  return jnp.asarray(action.astype(np.dtype(space.dtype), copy=False))


def _host_info(info: dict) -> dict:
  """jax info arrays as NumPy."""
  return {k: np.asarray(v) for k, v in info.items()}


def _reset_key(env, seed: int | None) -> jax.Array:
  """The key a Gymnasium `reset` uses: from `seed`, else split from the env's own key
  (after a first reset), else from the env's `np_random` (seeded by Gymnasium)."""
  if seed is None and env._key is not None:
    env._key, key = jax.random.split(env._key)
  else:
    env._key, key = jax.random.split(jax.random.key(
        seed if seed is not None else int(env.np_random.integers(2**31))))
  return key


def _step_key(env) -> jax.Array:
  """The key a Gymnasium `step` uses, split from the env's key; raises before a reset."""
  if env._state is None:
    raise RuntimeError("step before reset: call reset() first")
  env._key, key = jax.random.split(env._key)
  return key


@functools.cache
def _gymnasium_classes():
  try:
    import gymnasium
    from gymnasium.vector import AutoresetMode, VectorEnv
    from gymnasium.vector.utils import batch_space
  except ImportError as e:
    raise _missing("gymnasium", e) from e

  class GymnasiumEnv(gymnasium.Env):
    """One jaxchain world as a `gymnasium.Env` (NumPy in and out, no auto-reset).

    `reset(seed=s)` seeds a JAX key (with no seed: drawn from `np_random`), each
    `step` splits it; `reset` and `step` are jitted once per env. After an
    episode ends, call `reset` (Gymnasium's contract).

    Args:
      env: a task name, a `jaxchain.env.Task`, or a built env.
      params: the params of a built env.
      render_mode: None or "rgb_array" (`render()` gives `uint8[H, W, 3]`).
      **make_kwargs: keywords of `jaxchain.env.make`, with a task name.
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 60}

    def __init__(self, env, params=None, render_mode: str | None = None, **make_kwargs):
      self.env, self.params = _make(env, params, make_kwargs)
      if render_mode not in (None, "rgb_array"):
        raise ValueError(f"render_mode: None or 'rgb_array', got {render_mode!r}")
      self.render_mode = render_mode
      self._space = self.env.action_space(self.params)
      self.action_space = _gym_space(self._space)
      self.observation_space = _gym_space(self.env.observation_space(self.params))
      self._reset = jax.jit(self.env.reset)
      self._step = jax.jit(self.env.step_env)
      self._render = jax.jit(self.env.render)
      self._key = None
      self._state = None

    def reset(self, *, seed: int | None = None, options: dict | None = None):
      super().reset(seed=seed)
      del options
      obs, self._state = self._reset(_reset_key(self, seed), self.params)
      return np.asarray(obs), {}

    def step(self, action):
      obs, self._state, reward, _, info = self._step(
          _step_key(self), self._state, _as_action(self._space, action, ()), self.params)
      info = _host_info(info)
      return (np.asarray(obs), float(reward), bool(info.pop("terminated")),
              bool(info.pop("truncated")), info)

    def render(self):
      if self.render_mode is None or self._state is None:
        return None
      return np.asarray(self._render(self._state))

    def __repr__(self) -> str:
      return f"GymnasiumEnv({self.env!r})"

  class GymnasiumVectorEnv(VectorEnv):
    """`num_envs` jaxchain worlds as a `gymnasium.vector.VectorEnv`, NumPy in and out.

    One jitted `jax.vmap(env.step)` steps the batch; worlds whose episode ended are
    reset in the same step (`metadata["autoreset_mode"]` is `SAME_STEP`): the
    returned observation starts the next episode, `info["final_obs"]` (an object
    array, as `SyncVectorEnv` gives it) holds the last one where `info["_final_obs"]`,
    and `info["final_info"]` that step's info. The other info keys are the env's
    (`success`, `invalid_action`, `episode_return`, `episode_length`, `status`),
    each `[num_envs]` with an all-True `_key` mask.

    Args:
      env: a task name, a `jaxchain.env.Task`, or a built env.
      num_envs: worlds in the batch.
      params: the params of a built env.
      render_mode: None or "rgb_array" (`render()` gives `uint8[num_envs, H, W, 3]`).
      **make_kwargs: keywords of `jaxchain.env.make`, with a task name.
    """

    metadata = {"render_modes": ["rgb_array"], "autoreset_mode": AutoresetMode.SAME_STEP}

    def __init__(self, env, num_envs: int = 1, params=None, render_mode: str | None = None,
                 **make_kwargs):
      if num_envs < 1:
        raise ValueError(f"num_envs must be >= 1, got {num_envs}")
      self.env, self.params = _make(env, params, make_kwargs)
      if render_mode not in (None, "rgb_array"):
        raise ValueError(f"render_mode: None or 'rgb_array', got {render_mode!r}")
      self.render_mode = render_mode
      self.num_envs = num_envs
      self._space = self.env.action_space(self.params)
      self.single_action_space = _gym_space(self._space)
      self.single_observation_space = _gym_space(self.env.observation_space(self.params))
      self.action_space = batch_space(self.single_action_space, num_envs)
      self.observation_space = batch_space(self.single_observation_space, num_envs)
      env_ = self.env
      n = num_envs

      def reset(key, params):
        return jax.vmap(env_.reset, in_axes=(0, None))(jax.random.split(key, n), params)

      def step(key, state, action, params):
        return jax.vmap(env_.step, in_axes=(0, 0, 0, None))(jax.random.split(key, n), state,
                                                             action, params)

      self._reset = jax.jit(reset)
      self._step = jax.jit(step)
      self._render = jax.jit(self.env.render)
      self._key = None
      self._state = None

    def reset(self, *, seed: int | None = None, options: dict | None = None):
      super().reset(seed=seed)
      del options
      obs, self._state = self._reset(_reset_key(self, seed), self.params)
      return np.asarray(obs), {}

    def step(self, actions):
      obs, self._state, reward, done, info = self._step(
          _step_key(self), self._state, _as_action(self._space, actions, (self.num_envs,)), self.params)
      info = _host_info(info)
      done = np.asarray(done)
      terminated, truncated = info.pop("terminated"), info.pop("truncated")
      final = info.pop("final_obs")
      out = {}
      for k, v in info.items():
        out[k], out[f"_{k}"] = v, np.ones(self.num_envs, bool)
      if done.any():
        final_obs = np.full(self.num_envs, None, dtype=object)
        final_info = {}
        for i in np.flatnonzero(done):
          final_obs[i] = final[i]
        for k, v in info.items():
          final_info[k], final_info[f"_{k}"] = np.where(done, v, np.zeros_like(v)), done.copy()
        out.update(final_obs=final_obs, _final_obs=done.copy(), final_info=final_info,
                   _final_info=done.copy())
      return np.asarray(obs), np.asarray(reward), terminated, truncated, out

    def render(self):
      if self.render_mode is None or self._state is None:
        return None
      return np.asarray(self._render(self._state))

    def __repr__(self) -> str:
      return f"GymnasiumVectorEnv({self.env!r}, num_envs={self.num_envs})"

  return GymnasiumEnv, GymnasiumVectorEnv


def register_gymnasium() -> list[str]:
  """Registers the shipped tasks with `gymnasium.register` (once).

  Returns:
    The ids (`GYMNASIUM_IDS`), e.g. "jaxchain/PushBoxEasy-v0":
    `gymnasium.make(id, **make_kwargs)` gives a `GymnasiumEnv` (inside Gymnasium's
    usual checker wrappers), `gymnasium.make_vec(id, num_envs=B,
    vectorization_mode="vector_entry_point")` a `GymnasiumVectorEnv`.
  """
  try:
    import gymnasium
  except ImportError as e:
    raise _missing("gymnasium", e) from e
  ids = []
  for task, env_id in GYMNASIUM_IDS.items():
    if task not in env_lib.TASKS:
      continue
    ids.append(env_id)
    if env_id not in gymnasium.registry:
      gymnasium.register(env_id, entry_point=functools.partial(_single, task),
                         vector_entry_point=functools.partial(_vector, task),
                         disable_env_checker=False)
  return ids


def _single(task, **kwargs):
  return _gymnasium_classes()[0](task, **kwargs)


def _vector(task, num_envs: int = 1, **kwargs):
  return _gymnasium_classes()[1](task, num_envs=num_envs, **kwargs)


def __getattr__(name: str):
  """The adapter classes, built on first use (so gymnax and gymnasium load lazily)."""
  if name == "GymnaxEnv":
    return _gymnax_class()
  if name == "GymnasiumEnv":
    return _gymnasium_classes()[0]
  if name == "GymnasiumVectorEnv":
    return _gymnasium_classes()[1]
  raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
