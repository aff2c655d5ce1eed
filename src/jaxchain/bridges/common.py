"""What the adapters share: the registered ids, building the env, the ImportError of a
missing client, host-side actions, seeds and info, and `_Batched` (the host side of
the vector adapters: one jitted, vmapped step for every env).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from jaxchain import env as env_lib

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


def _gym_space(space):
  """A Gymnasium space for a jaxchain `Discrete` or `Box`."""
  from gymnasium import spaces
  if hasattr(space, "n"):
    return spaces.Discrete(int(space.n))
  dtype = np.dtype(space.dtype)
  cast = int if np.issubdtype(dtype, np.integer) else float
  return spaces.Box(cast(space.low), cast(space.high), tuple(space.shape), dtype)


def _as_action(space, action, batch: tuple[int, ...]) -> jax.Array:
  """A host action as the jax array the env expects, never cast silently: a discrete
  action must be integers (an int32 cannot hold is out of range, -1: the env flags it
  invalid), a continuous one real numbers (ints exactly, floats as float32)."""
  action = np.asarray(action)
  discrete = hasattr(space, "n")
  if discrete and action.dtype.kind not in "iu":
    raise TypeError(f"action: Discrete({space.n}) takes integer actions, got {action.dtype} "
                    f"{action.tolist()!r} (floats, strings and bools are not cast: give ints)")
  if not discrete and action.dtype.kind not in "iuf":
    raise TypeError(f"action: Box({space.low}, {space.high}, {tuple(space.shape)}) takes real "
                    f"numbers, got {action.dtype} {action.tolist()!r}")
  want = batch + tuple(space.shape)
  if action.shape != want:
    raise ValueError(f"action: expected shape {want}, got {action.shape}")
  if discrete:
    inside = (action >= 0) & (action < space.n)
    action = np.where(inside, action.astype(np.int64, casting="unsafe"), -1)
  return jnp.asarray(action.astype(np.dtype(space.dtype), copy=False))


def _host_info(info: dict) -> dict:
  """jax info arrays as (writable) NumPy arrays."""
  return {k: np.array(v) for k, v in info.items()}


def _check_seed(seed) -> int | None:
  """A seed as every adapter takes it: None, or an int >= 0 of any size (Gymnasium's
  rule; a Python or NumPy int, not a bool); anything else is a ValueError."""
  if seed is None:
    return None
  if isinstance(seed, (int, np.integer)) and not isinstance(seed, (bool, np.bool_)) and seed >= 0:
    return int(seed)
  raise ValueError(f"seed: expected an int >= 0 (any size) or None, got {seed!r}")


def _seed_key(seed: int) -> jax.Array:
  """The JAX key of a seed `>= 0`: `jax.random.key(seed)` below 2**32 (as always); above,
  the low 32 bits' key with each further 32 bits folded in, so every bit counts
  (`jax.random.key` alone takes an int64, and without x64 keeps 32 bits)."""
  key = jax.random.key(seed & 0xFFFFFFFF)
  seed >>= 32
  while seed:
    key = jax.random.fold_in(key, seed & 0xFFFFFFFF)
    seed >>= 32
  return key


def _reset_key(env, seed: int | None) -> jax.Array:
  """The key a Gymnasium `reset` uses: from `seed`; else, right after a step ended the
  episode, the key that step drew for the next episode (what `env.step`'s auto-reset,
  gymnax's and the vector adapters' use); else split from the env's own key (after a
  first reset), else from the env's `np_random` (seeded by Gymnasium)."""
  pending, env._next_reset = env._next_reset, None
  if seed is None and pending is not None:
    return pending
  if seed is None and env._key is not None:
    env._key, key = jax.random.split(env._key)
  else:
    env._key, key = jax.random.split(_seed_key(
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
  if not isinstance(seed, (list, tuple)):
    seed = _check_seed(seed)
    return [seed + i for i in range(num_envs)]
  seeds = list(seed)
  if len(seeds) != num_envs:
    raise ValueError(f"seed: a list of {num_envs} seeds (one per env, None to go on), got "
                     f"{len(seeds)}")
  return [_check_seed(s) for s in seeds]


# The per-env metadata of the batched adapters (a `GymnasiumEnv`'s).
_SINGLE_METADATA = {"render_modes": ["rgb_array"], "render_fps": 60}


class _Batched:
  """The host side shared by `GymnasiumVectorEnv` and `SB3VecEnv`: `num_envs` worlds
  stepped by one jitted, vmapped `env.step` (auto-reset inside), one JAX key per env.

  Env i seeded with `s` draws what a `GymnasiumEnv` seeded with `s` draws, across
  episodes too: its reset key and each step's key are split from the seed's key the
  same way, and the auto-reset starts the next episode from the key the step drew for
  it, as a `GymnasiumEnv` `reset()` after its episode ended does (so SB3's
  `DummyVecEnv` and Gymnasium's `SyncVectorEnv` over single envs give the same
  episodes; observations agree to an ulp of `t / max_steps`, which the vmapped step
  rounds differently on some steps). Seeds are `_check_seed`'s: ints >= 0 of any size.
  The jitted functions are rebuilt after unpickling (pickle and `copy.deepcopy` carry
  the env, params, keys and state).
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
    keys = [_seed_key(s) if s is not None else
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


def _public(cls):
  """`cls` (built lazily inside a function) under its public name in this module, so
  pickle finds it as `jaxchain.bridges.<name>` (the module's `__getattr__`)."""
  cls.__module__ = "jaxchain.bridges"
  cls.__qualname__ = cls.__name__
  return cls
