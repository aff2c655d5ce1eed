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

from __future__ import annotations

import dataclasses
import functools
import warnings
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from jaxchain import env as env_lib

__all__ = ["GymnaxEnv", "GymnaxState", "GymnasiumEnv", "GymnasiumVectorEnv", "SB3VecEnv",
           "GYMNAX_IDS", "GYMNASIUM_IDS", "register_gymnax", "register_gymnasium"]

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

    def render(self, state, params=None):
      """The frame of `state` (`uint8[H, W, 3]`; a batch gives a batch): what
      gymnax's `GymnaxToGymWrapper.render` shows."""
      del params
      return self.env.render(state.env_state)

    def __repr__(self) -> str:
      return f"GymnaxEnv({self.env!r})"

  return _public(GymnaxEnv)


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
  """jax info arrays as (writable) NumPy arrays."""
  return {k: np.array(v) for k, v in info.items()}


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


def _check_render_mode(render_mode):
  if render_mode not in (None, "rgb_array"):
    raise ValueError(f"render_mode: None or 'rgb_array', got {render_mode!r}")


def _same(a, b) -> bool:
  """`a` and `b` are the same value: one object, or pytrees with equal leaves."""
  if a is b:
    return True
  leaves_a, tree_a = jax.tree.flatten(a)
  leaves_b, tree_b = jax.tree.flatten(b)
  return tree_a == tree_b and all(np.array_equal(np.asarray(x), np.asarray(y))
                                  for x, y in zip(leaves_a, leaves_b))


def _seed_list(seed, num_envs: int) -> list:
  """Gymnasium's vector seeding: None (every env goes on from its own key), an int `s`
  (env i from `s + i`), or a list of `num_envs` ints or Nones."""
  if seed is None:
    return [None] * num_envs
  if isinstance(seed, (int, np.integer)) and not isinstance(seed, bool):
    return [int(seed) + i for i in range(num_envs)]
  seeds = list(seed)
  if len(seeds) != num_envs:
    raise ValueError(f"seed: a list of {num_envs} seeds (one per env, None to go on), got "
                     f"{len(seeds)}")
  for s in seeds:
    if s is not None and not (isinstance(s, (int, np.integer)) and not isinstance(s, bool)):
      raise TypeError(f"seed: ints or None, got {s!r}")
  return [None if s is None else int(s) for s in seeds]


# The per-env metadata of the batched adapters (a `GymnasiumEnv`'s).
_SINGLE_METADATA = {"render_modes": ["rgb_array"], "render_fps": 60}


class _Batched:
  """The host side shared by `GymnasiumVectorEnv` and `SB3VecEnv`: `num_envs` worlds
  stepped by one jitted, vmapped `env.step` (auto-reset inside), one JAX key per env.

  Env i seeded with `s` draws what a `GymnasiumEnv` seeded with `s` draws (its reset
  key and each step's key are split from `jax.random.key(s)` the same way), so a
  batch is the single envs side by side. The jitted functions are rebuilt after
  unpickling (pickle and `copy.deepcopy` carry the env, params, keys and state).
  """

  _JITTED = ("_reset_fn", "_step_fn", "_render_fn")
  # Per-env attributes the adapter holds itself (the rest come from the jaxchain env);
  # and those `set_attr` may change (for every env at once: they share one step).
  _OWN = ("env", "params", "render_mode")
  _SETTABLE = ("params", "render_mode")

  def _setup(self, env, num_envs, params, render_mode, make_kwargs):
    if not isinstance(num_envs, (int, np.integer)) or num_envs < 1:
      raise ValueError(f"num_envs must be an int >= 1, got {num_envs!r}")
    self.env, self.params = _make(env, params, make_kwargs)
    _check_render_mode(render_mode)
    self.render_mode = render_mode
    self.num_envs = int(num_envs)
    self._space = self.env.action_space(self.params)
    self.single_action_space = _gym_space(self._space)
    self.single_observation_space = _gym_space(self.env.observation_space(self.params))
    self._keys = None  # [num_envs] JAX keys, after the first reset.
    self._state = None
    self._obs = None
    self._build()

  def _build(self):
    env = self.env

    def reset(keys, params):
      pair = jax.vmap(jax.random.split)(keys)
      obs, state = jax.vmap(env.reset, in_axes=(0, None))(pair[:, 1], params)
      return pair[:, 0], obs, state

    def step(keys, state, action, params):
      pair = jax.vmap(jax.random.split)(keys)
      obs, state, reward, done, info = jax.vmap(env.step, in_axes=(0, 0, 0, None))(
          pair[:, 1], state, action, params)
      return pair[:, 0], obs, state, reward, done, info

    self._reset_fn = jax.jit(reset)
    self._step_fn = jax.jit(step)
    self._render_fn = jax.jit(env.render)

  def __getstate__(self) -> dict:
    return {k: v for k, v in self.__dict__.items() if k not in self._JITTED}

  def __setstate__(self, state: dict) -> None:
    self.__dict__.update(state)
    self._build()

  def _start_keys(self, seeds: list, rng) -> jax.Array:
    """`[num_envs]` keys a reset starts from: env i's seed if given, else its own key
    (after a first reset), else a seed drawn from `rng`."""
    if self._keys is not None and all(s is None for s in seeds):
      return self._keys
    keys = [jax.random.key(s) if s is not None else
            self._keys[i] if self._keys is not None else jax.random.key(int(rng.integers(2**31)))
            for i, s in enumerate(seeds)]
    return jnp.stack(keys)

  def _host_reset(self, seeds: list, rng, mask=None) -> np.ndarray:
    """Resets the envs where `mask` (default: all); the others keep their state."""
    keys, obs, state = self._reset_fn(self._start_keys(seeds, rng), self.params)
    obs = np.array(obs)
    if mask is not None and not mask.all():
      if self._state is None:
        raise ValueError("reset_mask: the first reset must reset every env")
      m = jnp.asarray(mask)
      pick = lambda new, old: jnp.where(m.reshape(m.shape + (1,) * (new.ndim - 1)), new, old)
      state = jax.tree.map(pick, state, self._state)
      keys = jax.random.wrap_key_data(pick(jax.random.key_data(keys),
                                           jax.random.key_data(self._keys)))
      obs = np.where(mask.reshape(mask.shape + (1,) * (obs.ndim - 1)), obs, self._obs)
    self._keys, self._state, self._obs = keys, state, obs
    return obs.copy()

  def _host_step(self, actions):
    """One jitted step of every env: `(obs, reward, done, info)` as NumPy."""
    if self._state is None:
      raise RuntimeError("step before reset: call reset() first")
    self._keys, obs, self._state, reward, done, info = self._step_fn(
        self._keys, self._state, _as_action(self._space, actions, (self.num_envs,)), self.params)
    # Writable copies (a view of a jax array is read-only; torch warns on those).
    self._obs = np.array(obs)
    return self._obs.copy(), np.array(reward), np.array(done), _host_info(info)

  def _frames(self):
    """`uint8[num_envs, H, W, 3]`, or None without `render_mode="rgb_array"` or state."""
    if self.render_mode is None or self._state is None:
      return None
    return np.asarray(self._render_fn(self._state))

  def _env_attr(self, name: str):
    """What each env of the batch has as `name`: its spaces (the single ones), its
    metadata, the adapter's `env`, `params`, `render_mode`, else the jaxchain env's."""
    if name in ("action_space", "observation_space"):
      return getattr(self, "single_" + name)
    if name == "metadata":
      return dict(_SINGLE_METADATA)
    if name in self._OWN:
      return getattr(self, name)
    try:
      return getattr(self.env, name)
    except AttributeError:
      raise AttributeError(
          f"{type(self).__name__}: the envs have no attribute {name!r} (neither one of "
          f"{', '.join(self._OWN + ('action_space', 'observation_space', 'metadata'))} nor "
          f"the jaxchain env's)") from None

  def _call(self, name: str, indices, args=(), kwargs=None, call: bool = True) -> list:
    """`name` of each env in `indices`: called with `args` if callable and `call`.
    `render` gives each env's own frame."""
    indices = list(indices)
    for i in indices:
      if not 0 <= i < self.num_envs:
        raise IndexError(f"env index {i} out of range for {self.num_envs} envs")
    if name == "render" and call:
      frames = self._frames()
      return [None if frames is None else frames[i] for i in indices]
    value = self._env_attr(name)
    if call and callable(value):
      return [value(*args, **(kwargs or {})) for _ in indices]
    return [value for _ in indices]

  def _set(self, name: str, values: list, all_envs: bool) -> None:
    """Sets `name` for every env; refuses what the shared step cannot hold."""
    if name not in self._SETTABLE:
      raise AttributeError(f"{type(self).__name__}: cannot set {name!r}: the {self.num_envs} "
                           f"envs share one env and one jitted step; settable: "
                           f"{', '.join(self._SETTABLE)}")
    if not all_envs or any(not _same(values[0], v) for v in values[1:]):
      raise ValueError(f"{type(self).__name__}: {name} is one value for all {self.num_envs} "
                       f"envs (they share one jitted step); set it for every env alike")
    value = values[0]
    if name == "render_mode":
      _check_render_mode(value)
    elif jax.tree.structure(value) != jax.tree.structure(self.params):
      raise ValueError(f"{type(self).__name__}: params must have the structure of the env's "
                       f"params ({type(self.params).__name__})")
    setattr(self, name, value)


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
    episode ends, call `reset` (Gymnasium's contract). Picklable and deep-copyable
    (the jitted functions are rebuilt).

    Args:
      env: a task name, a `jaxchain.env.Task`, or a built env.
      params: the params of a built env.
      render_mode: None or "rgb_array" (`render()` gives `uint8[H, W, 3]`).
      **make_kwargs: keywords of `jaxchain.env.make`, with a task name.
    """

    metadata = dict(_SINGLE_METADATA)
    _JITTED = ("_reset", "_step", "_render")

    def __init__(self, env, params=None, render_mode: str | None = None, **make_kwargs):
      self.env, self.params = _make(env, params, make_kwargs)
      _check_render_mode(render_mode)
      self.render_mode = render_mode
      self._space = self.env.action_space(self.params)
      self.action_space = _gym_space(self._space)
      self.observation_space = _gym_space(self.env.observation_space(self.params))
      self._key = None
      self._state = None
      self._build()

    def _build(self):
      self._reset = jax.jit(self.env.reset)
      self._step = jax.jit(self.env.step_env)
      self._render = jax.jit(self.env.render)

    def __getstate__(self) -> dict:
      return {k: v for k, v in self.__dict__.items() if k not in self._JITTED}

    def __setstate__(self, state: dict) -> None:
      self.__dict__.update(state)
      self._build()

    def reset(self, *, seed: int | None = None, options: dict | None = None):
      super().reset(seed=seed)
      if options:
        raise ValueError(f"reset: this env takes no options, got {sorted(options)}")
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

  class GymnasiumVectorEnv(_Batched, VectorEnv):
    """`num_envs` jaxchain worlds as a `gymnasium.vector.VectorEnv`, NumPy in and out.

    One jitted `jax.vmap(env.step)` steps the batch; worlds whose episode ended are
    reset in the same step (`metadata["autoreset_mode"]` is `SAME_STEP`): the
    returned observation starts the next episode, `info["final_obs"]` (an object
    array, as `SyncVectorEnv` gives it) holds the last one where `info["_final_obs"]`,
    and `info["final_info"]` that step's info. The other info keys are the env's
    (`success`, `invalid_action`, `episode_return`, `episode_length`, `status`),
    each `[num_envs]` with an all-True `_key` mask. Rewards are float64, as
    `SyncVectorEnv` gives them.

    Like `SyncVectorEnv`: `reset(seed=s)` seeds env i with `s + i`,
    `reset(seed=[s0, s1, ...])` each env with its own (None: it goes on from its
    key), and env i seeded with `s` is a `GymnasiumEnv` seeded with `s` (until its
    first auto-reset); `reset(options={"reset_mask": mask})` resets only those envs.
    `call(name, ...)`, `get_attr(name)` and `set_attr(name, values)` reach each
    env's attributes: its single spaces and metadata, `params` and `render_mode`,
    else the jaxchain env's (`level_names`, `action_space(params)`, ...);
    `call("render")` gives each env's frame. `set_attr` sets `params` or
    `render_mode` for all envs alike (they share one jitted step) and refuses
    anything else. Picklable and deep-copyable (the jitted functions are rebuilt).

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
      self._setup(env, num_envs, params, render_mode, make_kwargs)
      self.action_space = batch_space(self.single_action_space, self.num_envs)
      self.observation_space = batch_space(self.single_observation_space, self.num_envs)

    def reset(self, *, seed: int | list | None = None, options: dict | None = None):
      seeds = _seed_list(seed, self.num_envs)
      if seed is not None and not isinstance(seed, list | tuple):
        super().reset(seed=int(seed))  # Seeds np_random, as VectorEnv.reset does.
      options = dict(options or {})
      mask = options.pop("reset_mask", None)
      if options:
        raise ValueError(f"reset: unknown options {sorted(options)} (only reset_mask)")
      if mask is not None:
        mask = np.asarray(mask)
        if mask.shape != (self.num_envs,) or mask.dtype != np.bool_ or not mask.any():
          raise ValueError(f"reset_mask: a bool array of shape ({self.num_envs},) with a True, "
                           f"got {mask.dtype} {mask.shape}")
      return self._host_reset(seeds, self.np_random, mask), {}

    def step(self, actions):
      obs, reward, done, info = self._host_step(actions)
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
      return obs, reward.astype(np.float64), terminated, truncated, out

    def call(self, name: str, *args, **kwargs) -> tuple:
      """`name` of each env, called with `args` and `kwargs` if callable (a tuple)."""
      return tuple(self._call(name, range(self.num_envs), args, kwargs))

    def get_attr(self, name: str) -> tuple:
      """`name` of each env (a tuple; as `SyncVectorEnv`, a method is called)."""
      return self.call(name)

    def set_attr(self, name: str, values) -> None:
      """Sets `name` (`params` or `render_mode`) for every env; `values`: one value, or
      one per env (all the same)."""
      if not isinstance(values, list | tuple):
        values = [values] * self.num_envs
      if len(values) != self.num_envs:
        raise ValueError(f"set_attr: {len(values)} values for {self.num_envs} envs")
      self._set(name, list(values), True)

    def render(self):
      return self._frames()

    def __repr__(self) -> str:
      return f"GymnasiumVectorEnv({self.env!r}, num_envs={self.num_envs})"

  return _public(GymnasiumEnv), _public(GymnasiumVectorEnv)


def _public(cls):
  """`cls` (built lazily inside a function) under its public name in this module, so
  pickle finds it as `jaxchain.bridges.<name>` (the module's `__getattr__`)."""
  cls.__module__ = __name__
  cls.__qualname__ = cls.__name__
  return cls


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


# Stable-Baselines3.


@functools.cache
def _sb3_class():
  try:
    from stable_baselines3.common.vec_env import VecEnv
  except ImportError as e:
    raise _missing("stable_baselines3", e, extra="sb3") from e
  _gymnasium_classes()  # Gymnasium's spaces; SB3 needs gymnasium too.

  class SB3VecEnv(_Batched, VecEnv):
    """`num_envs` jaxchain worlds as a Stable-Baselines3 `VecEnv` (one jitted step for
    all of them), for `PPO("MlpPolicy", SB3VecEnv("push_box_easy", 16))` and the rest
    of SB3.

    What SB3's `DummyVecEnv` gives, without a Python loop over envs: `step_wait`
    returns `(obs, rewards, dones, infos)` with float32 rewards (DummyVecEnv's
    buffer dtype), bool dones and one info dict per env: the env's info (`success`,
    `invalid_action`, `episode_return`, `episode_length`, `status`) as Python
    scalars, `is_success` (SB3 logs `rollout/success_rate` from it),
    `TimeLimit.truncated` (truncated and not terminated) and, where the episode
    ended, `terminal_observation`; the returned observation already starts the
    next episode (jaxchain's auto-reset). `seed(s)` gives env i the seed `s + i`
    at the next `reset()` and returns the list; env i seeded with `s` draws what a
    `GymnasiumEnv` seeded with `s` draws. `get_attr`, `set_attr`, `env_method`
    reach each env's attributes as `GymnasiumVectorEnv.call` does (`set_attr`
    takes `params` or `render_mode`, for every env alike); `env_is_wrapped` is
    False (no Gymnasium wrapper sits around the worlds; `VecMonitor` gives SB3's
    episode statistics). Picklable and deep-copyable.

    Args:
      env: a task name, a `jaxchain.env.Task`, or a built env.
      num_envs: worlds in the batch.
      params: the params of a built env.
      render_mode: None or "rgb_array" (`get_images()` gives each env's frame).
      **make_kwargs: keywords of `jaxchain.env.make`, with a task name.

    Examples:
      >>> from stable_baselines3 import PPO
      >>> from stable_baselines3.common.vec_env import VecMonitor
      >>> from jaxchain import bridges
      >>> venv = VecMonitor(bridges.SB3VecEnv("push_box_easy", num_envs=4, max_steps=50))
      >>> model = PPO("MlpPolicy", venv, n_steps=16, batch_size=32, seed=0)
      >>> model = model.learn(total_timesteps=64)
      >>> venv.seed(0)
      [0, 1, 2, 3]
    """

    def __init__(self, env, num_envs: int = 1, params=None, render_mode: str | None = None,
                 **make_kwargs):
      self._setup(env, num_envs, params, render_mode, make_kwargs)
      self._actions = None
      self._rng = np.random.default_rng()
      VecEnv.__init__(self, self.num_envs, self.single_observation_space,
                      self.single_action_space)

    def reset(self):
      if any(self._options):
        raise ValueError(f"SB3VecEnv: reset options are not supported, got {self._options}")
      obs = self._host_reset(list(self._seeds), self._rng)
      self._reset_seeds()
      self._reset_options()
      self.reset_infos = [{} for _ in range(self.num_envs)]
      return obs

    def step_async(self, actions) -> None:
      self._actions = actions

    def step_wait(self):
      if self._actions is None:
        raise RuntimeError("step_wait before step_async")
      actions, self._actions = self._actions, None
      obs, reward, done, info = self._host_step(actions)
      terminated, truncated = info.pop("terminated"), info.pop("truncated")
      final = info.pop("final_obs")
      columns = {k: v.tolist() for k, v in info.items()}
      cut = (truncated & ~terminated).tolist()
      infos = []
      for i in range(self.num_envs):
        d = {k: v[i] for k, v in columns.items()}
        d["is_success"] = d.get("success", False)
        d["TimeLimit.truncated"] = cut[i]
        if done[i]:
          d["terminal_observation"] = final[i]
        infos.append(d)
      return obs, reward.astype(np.float32), done, infos

    def close(self) -> None:
      pass

    def get_images(self):
      if self.render_mode != "rgb_array":
        warnings.warn(f"The render mode is {self.render_mode}, but get_images needs "
                      f"'rgb_array'; make the env with render_mode='rgb_array'")
        return [None] * self.num_envs
      frames = self._frames()
      return [None] * self.num_envs if frames is None else list(frames)

    def get_attr(self, attr_name: str, indices=None) -> list:
      return self._call(attr_name, self._get_indices(indices), call=False)

    def set_attr(self, attr_name: str, value, indices=None) -> None:
      indices = list(self._get_indices(indices))
      self._set(attr_name, [value] * max(len(indices), 1),
                sorted(set(indices)) == list(range(self.num_envs)))

    def env_method(self, method_name: str, *method_args, indices=None, **method_kwargs) -> list:
      return self._call(method_name, self._get_indices(indices), method_args, method_kwargs)

    def env_is_wrapped(self, wrapper_class, indices=None) -> list[bool]:
      del wrapper_class
      return [False for _ in self._get_indices(indices)]

    def __repr__(self) -> str:
      return f"SB3VecEnv({self.env!r}, num_envs={self.num_envs})"

  return _public(SB3VecEnv)


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
