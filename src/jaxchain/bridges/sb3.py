"""The Stable-Baselines3 client: `SB3VecEnv` (an SB3 `VecEnv`).
"""

from __future__ import annotations

import functools
import warnings

import numpy as np

from jaxchain.bridges.common import _Batched, _check_seed, _missing, _public
from jaxchain.bridges.gymnasium import _gymnasium_classes


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
    at the next `reset()` and returns the list (`s` an int >= 0 of any size); env i
    seeded with `s` draws what a `GymnasiumEnv` seeded with `s` draws, episode after
    episode, so it gives what `DummyVecEnv` over `GymnasiumEnv`s gives, except that
    observations agree to 1e-6 rather than bit for bit (the vmapped step rounds
    `t / max_steps` one ulp apart on some steps). `get_attr`, `set_attr`, `env_method`
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

    def seed(self, seed: int | None = None) -> list:
      """SB3's rule (env i gets `seed + i` at the next `reset()`; None draws one), with
      the seed checked as every adapter checks it (an int >= 0 of any size)."""
      return super().seed(_check_seed(seed))

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
