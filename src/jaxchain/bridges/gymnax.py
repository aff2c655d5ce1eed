"""The gymnax client: `GymnaxEnv` (a gymnax `Environment`), `GymnaxState` and
`register_gymnax`.
"""

from __future__ import annotations

import dataclasses
import functools
from typing import Any

import jax
import jax.numpy as jnp

from jaxchain import env as env_lib
from jaxchain.bridges.common import GYMNAX_IDS, _make, _missing, _public


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
