"""The Gymnasium clients: `GymnasiumEnv` (one world, a `gymnasium.Env`),
`GymnasiumVectorEnv` (a `gymnasium.vector.VectorEnv`) and `register_gymnasium`.
"""

from __future__ import annotations

import functools

import jax
import numpy as np

from jaxchain import env as env_lib
from jaxchain.bridges.common import (GYMNASIUM_IDS, _SINGLE_METADATA, _as_action, _Batched,
                                     _check_render_mode, _check_seed, _gym_space, _host_info,
                                     _make, _missing, _public, _reset_key, _seed_list,
                                     _step_key)


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

    `reset(seed=s)` seeds a JAX key (`s` an int >= 0 of any size, or None: drawn from
    `np_random`), each `step` splits it; `reset` and `step` are jitted once per env.
    After an episode ends, call `reset` (Gymnasium's contract): without a seed it
    starts the next episode from the key the last step drew for it, the start
    jaxchain's `env.step` auto-reset (and so the vector adapters and gymnax) would
    give. Actions are never cast: a discrete one must be integers, a continuous one
    real numbers (a `TypeError` otherwise). Picklable and deep-copyable (the jitted
    functions are rebuilt).

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
      self._next_reset = None  # After a step that ended the episode: its reset key.
      self._state = None
      self._build()

    def _build(self):
      self._reset = jax.jit(self.env.reset)
      self._step = jax.jit(self.env.step_env)
      self._render = jax.jit(self.env.render)

    def __getstate__(self) -> dict:
      return {k: v for k, v in self.__dict__.items() if k not in self._JITTED}

    def __setstate__(self, state: dict) -> None:
      self.__dict__.update({"_next_reset": None, **state})
      self._build()

    def reset(self, *, seed: int | None = None, options: dict | None = None):
      seed = _check_seed(seed)
      super().reset(seed=seed)
      if options:
        raise ValueError(f"reset: this env takes no options, got {sorted(options)}")
      obs, self._state = self._reset(_reset_key(self, seed), self.params)
      return np.asarray(obs), {}

    def step(self, action):
      action = _as_action(self._space, action, ())
      key = _step_key(self)
      obs, self._state, reward, _, info = self._step(key, self._state, action, self.params)
      info = _host_info(info)
      terminated, truncated = bool(info.pop("terminated")), bool(info.pop("truncated"))
      # The next episode's key, as `env.step` would draw it: for a reset() that follows.
      self._next_reset = jax.random.split(key)[1] if terminated or truncated else None
      return np.asarray(obs), float(reward), terminated, truncated, info

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
    key), and env i seeded with `s` is a `GymnasiumEnv` seeded with `s`, episode
    after episode (`SyncVectorEnv` over them, same-step autoreset, gives the same
    episodes; observations to an ulp); `reset(options={"reset_mask": mask})` resets
    only those envs. Seeds are ints >= 0 of any size (else a ValueError).
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
