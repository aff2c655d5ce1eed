"""PPO on jaxchain tasks: one file, pure JAX + optax, the whole training loop under one jit.

PureJaxRL style (Lu et al. 2022): `num_envs` environments stepped with
`jax.vmap(env.step)` (which resets finished episodes itself), `num_steps` steps
per rollout in a `lax.scan`, generalised advantage estimation (GAE) in a reverse
`lax.scan`, then `update_epochs` epochs of the clipped PPO objective over
shuffled minibatches, all of it scanned over the updates and compiled once.
The actor and the critic are two small MLPs written in plain `jax.numpy`
(orthogonal initialisation, tanh). The head follows the action space: a
categorical over `n` logits for a `Discrete` space, a diagonal Gaussian with a
learned, state-independent log standard deviation for a `Box` (the sample is
clipped to the box before it reaches the env; the log-probability is that of
the unclipped sample, as in CleanRL).

Truncation is not termination: where an episode is cut at `max_steps`
(`info["truncated"]`) the return is bootstrapped with the critic's value of
`info["final_obs"]`; only `info["terminated"]` zeroes the value of what follows.

    python examples/ppo.py --env push_box_easy --timesteps 1000000
    python examples/ppo.py --env reach_flag --level platformer1 --param shaping=0.1
    python examples/ppo.py --env two_box        # examples/two_box_task.py's make_env()
    python examples/ppo.py --env my_task.py     # any file with make_env() -> (env, params)

Prints one line per `--log-every` updates (timesteps, mean return and success
rate of the episodes that ended, losses), then the wall time (compile included)
and a final evaluation: the success rate and mean return of the trained policy
(its mode: argmax or the Gaussian mean) over 256 evaluation episodes, each from
a fresh reset. `--out PREFIX` writes the learning curve as `PREFIX.csv` and
`PREFIX.png`; `--plot A.csv B.csv --out PREFIX` only draws saved curves together.
Results on 2 cores: `benchmarks/results/ppo.md`.
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import importlib.util
import math
import pathlib
import sys
import time
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import optax

import jaxchain as jc

HERE = pathlib.Path(__file__).resolve().parent

# Learning-curve columns: one row per update (episodes that ended in that update's rollout).
CURVE_FIELDS = ("update", "timesteps", "episodes", "return", "success", "length", "value_loss",
                "actor_loss", "entropy", "approx_kl")


@dataclasses.dataclass(frozen=True)
class PPOConfig:
  """PPO's hyperparameters (static: they fix the shapes of the compiled loop).

  Attributes:
    num_envs: environments stepped in parallel (one vmap).
    num_steps: steps per environment per rollout; a batch is
      `num_envs * num_steps` transitions.
    total_timesteps: environment steps in all; the number of updates is
      `total_timesteps // (num_envs * num_steps)` (at least 1).
    update_epochs: passes over each batch.
    num_minibatches: minibatches per pass (must divide the batch).
    gamma: discount.
    gae_lambda: GAE's lambda.
    clip_eps: the ratio clip of the policy loss (and of the value loss).
    ent_coef: weight of the entropy bonus (None: 0.01 for a categorical head, 0.005
      for a Gaussian one, which keeps its spread long enough to find every room of
      push_box_easy).
    vf_coef: weight of the value loss.
    max_grad_norm: global gradient-norm clip.
    lr: Adam's learning rate (annealed linearly to 0 when `anneal_lr`).
    anneal_lr: anneal the learning rate over the updates.
    hidden: width of the two hidden layers of each MLP.
    init_log_std: the Gaussian head's initial log standard deviation.
    normalize_obs: feed the networks observations standardised by running
      statistics (mean and variance over every observation seen so far, updated
      after each rollout; clipped to +-10), as PureJaxRL's continuous-control
      wrapper does.
    squash: a Gaussian sample reaches the box through tanh instead of a clip.
    obs_features: feed the networks only the first this many entries of the
      (flattened) observation (None: all). With the vector observation, 9 + 8 * k
      keeps the player and the first k slots: `--obs-features 73` on push_box_easy
      keeps the player, box and goal features and leaves out the wall slots (as
      `examples/es_push_box.py` does). "auto" (the default): that cut for an env with
      the vector observation whose wall slots come last (every shipped task: the
      walls of a level do not move, and their inputs slowed learning on
      push_box_easy, `benchmarks/results/ppo.md`), else all (`auto_features`).
  """

  # The defaults learn push_box_easy (the CLI's default env) within 100k env steps
  # (benchmarks/results/ppo.md); the earlier ones (128 envs x 64 steps, 4 epochs, 8
  # minibatches, standardised inputs, all 105 of them) stayed at 0% there. Small
  # batches make many updates out of few steps.
  num_envs: int = 16
  num_steps: int = 128
  total_timesteps: int = 1_000_000
  update_epochs: int = 8
  num_minibatches: int = 4
  gamma: float = 0.99
  gae_lambda: float = 0.95
  clip_eps: float = 0.2
  ent_coef: float | None = None
  vf_coef: float = 0.5
  max_grad_norm: float = 0.5
  lr: float = 1e-3
  anneal_lr: bool = True
  hidden: int = 64
  init_log_std: float = 0.0
  normalize_obs: bool = False
  squash: bool = False
  obs_features: int | str | None = "auto"

  @property
  def batch_size(self) -> int:
    return self.num_envs * self.num_steps

  @property
  def num_updates(self) -> int:
    return max(1, self.total_timesteps // self.batch_size)


# The policy: two MLPs in plain jax.numpy.


def init_mlp(key: jax.Array, sizes: tuple[int, ...], last_scale: float) -> list[dict]:
  """Parameters of an MLP with layer widths `sizes`: a list of `{"w": [i, o], "b": [o]}`,
  orthogonal weights (scale sqrt 2 for hidden layers, `last_scale` for the output), zero biases."""
  layers = []
  keys = jax.random.split(key, len(sizes) - 1)
  for k, (i, o) in enumerate(zip(sizes[:-1], sizes[1:])):
    scale = last_scale if k == len(sizes) - 2 else math.sqrt(2.0)
    w = jax.nn.initializers.orthogonal(scale)(keys[k], (i, o), jnp.float32)
    layers.append({"w": w, "b": jnp.zeros((o,), jnp.float32)})
  return layers


def _lead(v: jax.Array, x: jax.Array) -> jax.Array:
  """`v` `[n]` shaped to broadcast against `x` `[..., n]` (explicit ranks)."""
  return jnp.reshape(v, (1,) * (x.ndim - 1) + v.shape)


def mlp(layers: list[dict], x: jax.Array) -> jax.Array:
  """`x` `[..., i]` through the MLP (tanh between layers) -> `[..., o]` float32."""
  x = x.astype(jnp.float32)
  for layer in layers:
    y = x @ layer["w"]
    x = y + _lead(layer["b"], y)
    if layer is not layers[-1]:
      x = jnp.tanh(x)
  return x


class Head(NamedTuple):
  """The action distribution's shape: `discrete` (categorical over `n` actions) or a
  Gaussian over a `shape` box clipped to `[low, high]`."""

  discrete: bool
  n: int  # Logits (discrete) or action dimension (continuous).
  shape: tuple[int, ...]
  low: Any
  high: Any
  dtype: Any
  squash: bool = False  # Gaussian: tanh-squash the sample into the box (else clip it).


def head_of(space, squash: bool = False) -> Head:
  """The head for an action space with a `Discrete` (`.n`) or `Box` (`.low/.high/.shape`)
  API; `squash`: a Gaussian sample reaches the box through tanh (else it is clipped)."""
  if hasattr(space, "n"):
    return Head(True, int(space.n), (), None, None, np.dtype(space.dtype))
  shape = tuple(space.shape)
  return Head(False, int(np.prod(shape)), shape, np.asarray(space.low, np.float32),
              np.asarray(space.high, np.float32), np.dtype(space.dtype), squash)


def init_policy(key: jax.Array, obs_size: int, head: Head, config: PPOConfig) -> dict:
  """`{"actor": mlp, "critic": mlp, "log_std": [n]}` (log_std unused by a discrete head)."""
  k_actor, k_critic = jax.random.split(key)
  h = config.hidden
  return {"actor": init_mlp(k_actor, (obs_size, h, h, head.n), 0.01),
          "critic": init_mlp(k_critic, (obs_size, h, h, 1), 1.0),
          "log_std": jnp.full((head.n,), config.init_log_std, jnp.float32)}


def value_fn(theta: dict, obs: jax.Array) -> jax.Array:
  """The critic: `[..., obs]` -> `[...]`."""
  return mlp(theta["critic"], obs)[..., 0]


def log_prob(theta: dict, head: Head, out: jax.Array, action: jax.Array) -> jax.Array:
  """The log-probability of `action` (`[...]` ints, or `[..., n]` raw Gaussian samples)
  under the actor output `out` `[..., n]`."""
  if head.discrete:
    logp = jax.nn.log_softmax(out)
    return jnp.take_along_axis(logp, action[..., None].astype(jnp.int32), axis=-1)[..., 0]
  log_std = _lead(theta["log_std"], out)
  z = (action - out) / jnp.exp(log_std)
  return jnp.sum(-0.5 * z * z - log_std - 0.5 * math.log(2.0 * math.pi), axis=-1)


def entropy(theta: dict, head: Head, out: jax.Array) -> jax.Array:
  """The entropy of the action distribution, `[...]`."""
  if head.discrete:
    logp = jax.nn.log_softmax(out)
    return -jnp.sum(jnp.exp(logp) * logp, axis=-1)
  per_dim = theta["log_std"] + 0.5 * (1.0 + math.log(2.0 * math.pi))
  return jnp.broadcast_to(jnp.sum(per_dim), out.shape[:-1])


def sample(theta: dict, head: Head, out: jax.Array, key: jax.Array) -> jax.Array:
  """A raw sample from the distribution: `[...]` int32 or `[..., n]` float32."""
  if head.discrete:
    return jax.random.categorical(key, out).astype(jnp.int32)
  std = jnp.exp(_lead(theta["log_std"], out))
  return out + std * jax.random.normal(key, out.shape, out.dtype)


def mode(head: Head, out: jax.Array) -> jax.Array:
  """The distribution's mode (argmax, or the Gaussian mean), as a raw sample."""
  if head.discrete:
    return jnp.argmax(out, axis=-1).astype(jnp.int32)
  return out


def to_env(head: Head, raw: jax.Array) -> jax.Array:
  """A raw sample as the env's action: the int as is; a Gaussian sample clipped to the
  box (or, with `head.squash`, mapped into it by tanh) and shaped like it (`[..., n]` ->
  `[..., *shape]`). PPO's ratio is the same either way (the squash's Jacobian cancels)."""
  if head.discrete:
    return raw.astype(head.dtype)
  low, high = jnp.asarray(head.low.reshape(-1)), jnp.asarray(head.high.reshape(-1))
  low, high = _lead(low, raw), _lead(high, raw)
  if head.squash:
    a = low + (jnp.tanh(raw) + 1.0) * 0.5 * (high - low)
  else:
    a = jnp.clip(raw, low, high)
  return a.reshape(raw.shape[:-1] + head.shape).astype(head.dtype)


# Observations.


def auto_features(env) -> int | None:
  """`obs_features="auto"` for `env`: the player's and every non-wall slot's features
  of the vector observation (`PLAYER_FEATURES + len(SLOT_FIELDS) * slots`) when the
  wall slots come last; None (all) otherwise (other observations, other envs)."""
  slots = getattr(env, "slots", None)
  if getattr(env, "obs_mode", None) != "vector" or not slots or slots[-1][0] != "wall":
    return None
  if any(kind == "wall" for kind, _ in slots[:-1]):
    return None
  kept = sum(count for kind, count in slots[:-1])
  return jc.env.PLAYER_FEATURES + len(jc.env.SLOT_FIELDS) * kept


def resolve_features(config: PPOConfig, env) -> PPOConfig:
  """`config` with `obs_features="auto"` replaced by `auto_features(env)`."""
  if config.obs_features == "auto":
    return dataclasses.replace(config, obs_features=auto_features(env))
  if isinstance(config.obs_features, str):
    raise ValueError(f"obs_features: an int, None or 'auto', got {config.obs_features!r}")
  return config


def features(config: PPOConfig | None, obs: jax.Array) -> jax.Array:
  """A batch of observations `[B, ...]` as the networks' input `[B, k]`: flattened, and
  cut to the first `config.obs_features` entries if that is set (resolved: no "auto")."""
  flat = obs.reshape(obs.shape[0], -1)
  if config is not None and config.obs_features is not None:
    flat = flat[:, :config.obs_features]
  return flat




def init_norm(obs_size: int) -> dict:
  """Running mean and variance of observations: `{"mean", "var": [obs], "count": []}`."""
  return {"mean": jnp.zeros((obs_size,), jnp.float32), "var": jnp.ones((obs_size,), jnp.float32),
          "count": jnp.asarray(1e-4, jnp.float32)}


def update_norm(norm: dict, obs: jax.Array) -> dict:
  """`norm` after also seeing the observations `obs` `[k, obs]` (Chan et al.'s merge)."""
  obs = obs.astype(jnp.float32)
  n = jnp.asarray(obs.shape[0], jnp.float32)
  mean, var = jnp.mean(obs, axis=0), jnp.var(obs, axis=0)
  total = norm["count"] + n
  delta = mean - norm["mean"]
  m2 = norm["var"] * norm["count"] + var * n + delta * delta * norm["count"] * n / total
  return {"mean": norm["mean"] + delta * n / total, "var": m2 / total, "count": total}


def normalize(norm: dict | None, obs: jax.Array) -> jax.Array:
  """`obs` `[..., obs]` standardised by `norm` and clipped to +-10 (as is if `norm` is None)."""
  obs = obs.astype(jnp.float32)
  if norm is None:
    return obs
  mean, var = _lead(norm["mean"], obs), _lead(norm["var"], obs)
  return jnp.clip((obs - mean) / jnp.sqrt(var + 1e-8), -10.0, 10.0)


# Training.


class Transition(NamedTuple):
  obs: jax.Array  # [B, obs], normalised.
  action: jax.Array  # [B] or [B, n], raw.
  logp: jax.Array  # [B]
  value: jax.Array  # [B]
  reward: jax.Array  # [B], plus gamma V(final_obs) where truncated.
  terminated: jax.Array  # [B] bool: no bootstrap past here.
  done: jax.Array  # [B] bool: the episode ended (the next obs starts another).
  ep_return: jax.Array  # [B]
  ep_length: jax.Array  # [B]
  success: jax.Array  # [B] bool


def gae_fn(config: PPOConfig):
  """`gae(traj, last_value) -> (advantages, targets)`, each `[T, B]`: generalised
  advantage estimation over a rollout `traj` (a `Transition` of `[T, B]` leaves), in
  a reverse scan; `last_value` `[B]` is the critic's value of the observation after
  the rollout.

  Past an end (`done`) the next step belongs to another episode: neither its value
  nor its advantage runs back. A truncated step's bootstrap, `gamma V(final_obs)`,
  is in its reward already (added while collecting); a terminated step's is 0.
  """
  gamma, lam = config.gamma, config.gae_lambda

  def gae(traj: Transition, last_value):
    def body(carry, t: Transition):
      next_adv, next_value = carry
      cont = 1.0 - t.done.astype(jnp.float32)
      delta = t.reward + gamma * next_value * cont - t.value
      adv = delta + gamma * lam * cont * next_adv
      return (adv, t.value), adv

    _, adv = jax.lax.scan(body, (jnp.zeros_like(last_value), last_value), traj, reverse=True)
    return adv, adv + traj.value

  return gae


def make_train(env, env_params, config: PPOConfig, *, verbose: bool = False, log_every: int = 1):
  """`train(key) -> (policy, curve)`: the whole PPO run as one pure function (jit it).

  Args:
    env: an environment with the gymnax API of `jaxchain.env` (`reset`, `step` with
      auto-reset and `info["final_obs"]`, `["terminated"]`, `["truncated"]`,
      `["success"]`, `["episode_return"]`, `["episode_length"]`; `action_space`,
      `observation_space`).
    env_params: its params.
    config: the `PPOConfig`.
    verbose: print a progress line every `log_every` updates (from inside the
      compiled loop, through `jax.debug.callback`).
    log_every: see `verbose`.

  Returns:
    `train`: `key -> (policy, curve)`: `policy` is `{"theta": parameters, "norm":
    observation statistics or None}` (what `act` and `make_evaluate` take) and
    `curve` a dict of `[num_updates]` arrays keyed by `CURVE_FIELDS`.
  """
  config = resolve_features(config, env)
  head = head_of(env.action_space(env_params), config.squash)
  obs_size = int(np.prod(env.observation_space(env_params).shape))
  if config.obs_features is not None:
    obs_size = min(obs_size, config.obs_features)
  keep = lambda o: features(config, o)
  if config.batch_size % config.num_minibatches:
    raise ValueError(f"num_minibatches ({config.num_minibatches}) must divide num_envs * "
                     f"num_steps ({config.batch_size})")
  n_updates = config.num_updates
  steps_per_update = config.num_minibatches * config.update_epochs
  lr = (optax.linear_schedule(config.lr, 0.0, n_updates * steps_per_update)
        if config.anneal_lr else config.lr)
  tx = optax.chain(optax.clip_by_global_norm(config.max_grad_norm), optax.adam(lr, eps=1e-5))
  v_reset = jax.vmap(env.reset, in_axes=(0, None))
  v_step = jax.vmap(env.step, in_axes=(0, 0, 0, None))
  gamma = config.gamma

  ent_coef = config.ent_coef if config.ent_coef is not None else (0.01 if head.discrete else 0.005)

  def loss_fn(theta, batch: Transition, adv, target):
    out = mlp(theta["actor"], batch.obs)
    logp = log_prob(theta, head, out, batch.action)
    value = value_fn(theta, batch.obs)
    v_clipped = batch.value + jnp.clip(value - batch.value, -config.clip_eps, config.clip_eps)
    value_loss = 0.5 * jnp.mean(jnp.maximum(jnp.square(value - target),
                                            jnp.square(v_clipped - target)))
    log_ratio = logp - batch.logp
    ratio = jnp.exp(log_ratio)
    adv = (adv - adv.mean()) / (adv.std() + 1e-8)
    actor_loss = -jnp.mean(jnp.minimum(
        ratio * adv, jnp.clip(ratio, 1.0 - config.clip_eps, 1.0 + config.clip_eps) * adv))
    ent = jnp.mean(entropy(theta, head, out))
    approx_kl = jnp.mean((ratio - 1.0) - log_ratio)
    total = actor_loss + config.vf_coef * value_loss - ent_coef * ent
    return total, (value_loss, actor_loss, ent, approx_kl)

  gae = gae_fn(config)

  def update(carry, update_index):
    theta, opt_state, norm, env_state, obs, key = carry
    use_norm = norm if config.normalize_obs else None

    def env_step(c, _):
      env_state, raw_obs, key = c
      key, k_act, k_env = jax.random.split(key, 3)
      obs = normalize(use_norm, raw_obs)
      out = mlp(theta["actor"], obs)
      raw = sample(theta, head, out, k_act)
      logp = log_prob(theta, head, out, raw)
      value = value_fn(theta, obs)
      next_obs, env_state, reward, done, info = v_step(
          jax.random.split(k_env, config.num_envs), env_state, to_env(head, raw), env_params)
      truncated = info["truncated"] & ~info["terminated"]
      final_value = value_fn(
          theta, normalize(use_norm, keep(info["final_obs"])))
      reward = reward.astype(jnp.float32) + jnp.where(truncated, gamma * final_value, 0.0)
      t = Transition(obs, raw, logp, value, reward, info["terminated"], done,
                     info["episode_return"].astype(jnp.float32),
                     info["episode_length"].astype(jnp.float32), info["success"])
      return (env_state, keep(next_obs), key), (t, raw_obs)

    (env_state, obs, key), (traj, raw) = jax.lax.scan(env_step, (env_state, obs, key), None,
                                                      config.num_steps)
    adv, target = gae(traj, value_fn(theta, normalize(use_norm, obs)))
    if config.normalize_obs:  # The statistics move after the rollout, not inside the batch.
      norm = update_norm(norm, raw.reshape(config.batch_size, -1))

    def epoch(c, _):
      theta, opt_state, key = c
      key, k_perm = jax.random.split(key)
      perm = jax.random.permutation(k_perm, config.batch_size)
      flat = jax.tree.map(lambda x: x.reshape((config.batch_size,) + x.shape[2:]),
                          (traj, adv, target))
      mini = jax.tree.map(
          lambda x: x[perm].reshape((config.num_minibatches, -1) + x.shape[1:]), flat)

      def minibatch(c, b):
        theta, opt_state = c
        grads, aux = jax.grad(loss_fn, has_aux=True)(theta, *b)
        # optax's Adam raises a Python float to an int32 step count (bias correction),
        # which strict dtype promotion refuses: allow standard promotion for it alone.
        with jax.numpy_dtype_promotion("standard"):
          updates, opt_state = tx.update(grads, opt_state, theta)
        return (optax.apply_updates(theta, updates), opt_state), aux

      (theta, opt_state), aux = jax.lax.scan(minibatch, (theta, opt_state), mini)
      return (theta, opt_state, key), aux

    (theta, opt_state, key), aux = jax.lax.scan(epoch, (theta, opt_state, key), None,
                                                config.update_epochs)
    ended = traj.done
    n = jnp.sum(ended)
    denom = jnp.maximum(n, 1).astype(jnp.float32)
    mean_over_ended = lambda x: jnp.sum(jnp.where(ended, x, 0.0)) / denom
    value_loss, actor_loss, ent, kl = (jnp.mean(a) for a in aux)
    row = {"update": update_index + 1,
           "timesteps": (update_index + 1) * config.batch_size,
           "episodes": n,
           "return": mean_over_ended(traj.ep_return),
           "success": mean_over_ended(traj.success.astype(jnp.float32)),
           "length": mean_over_ended(traj.ep_length),
           "value_loss": value_loss, "actor_loss": actor_loss, "entropy": ent,
           "approx_kl": kl}
    if verbose:
      jax.lax.cond((update_index + 1) % log_every == 0,
                   lambda r: jax.debug.callback(_print_row, r, n_updates), lambda r: None, row)
    return (theta, opt_state, norm, env_state, obs, key), row

  def train(key: jax.Array):
    k_init, k_reset, key = jax.random.split(key, 3)
    theta = init_policy(k_init, obs_size, head, config)
    opt_state = tx.init(theta)
    obs, env_state = v_reset(jax.random.split(k_reset, config.num_envs), env_params)
    obs = keep(obs)
    norm = init_norm(obs_size)
    (theta, _, norm, *_), curve = jax.lax.scan(
        update, (theta, opt_state, norm, env_state, obs, key), jnp.arange(n_updates))
    return {"theta": theta, "norm": norm if config.normalize_obs else None}, curve

  return train


def _print_row(row, n_updates):
  r = {k: np.asarray(v).item() for k, v in row.items()}
  print(f"update {r['update']:4d}/{n_updates}  steps {r['timesteps']:>9d}  episodes "
        f"{r['episodes']:5d}  return {r['return']:7.3f}  success {r['success']:6.1%}  length "
        f"{r['length']:6.1f}  v_loss {r['value_loss']:.4f}  entropy {r['entropy']:.3f}  "
        f"kl {r['approx_kl']:.4f}", flush=True)


# Evaluation.


def make_evaluate(env, env_params, head: Head, max_steps: int, episodes: int = 256,
                  deterministic: bool = True, config: PPOConfig | None = None):
  """`evaluate(policy, key) -> (success, return, level)`, each `[episodes]`: each episode
  from its own reset, played by the policy (its mode when `deterministic`) for up to
  `max_steps` steps (the policy reads `features(config, obs)`, as in training); only
  the first episode of each env counts. `level` is the
  episode's level index (`state.level`; -1 for an env whose state has none)."""
  if config is not None:
    config = resolve_features(config, env)
  v_reset = jax.vmap(env.reset, in_axes=(0, None))
  v_step = jax.vmap(env.step, in_axes=(0, 0, 0, None))

  def evaluate(policy, key):
    theta = policy["theta"]
    k_reset, key = jax.random.split(key)
    obs, state = v_reset(jax.random.split(k_reset, episodes), env_params)
    level = getattr(state, "level", jnp.full((episodes,), -1, jnp.int32))

    def body(c, k):
      obs, state, alive, ret, solved = c
      k_act, k_env = jax.random.split(k)
      out = mlp(theta["actor"], normalize(policy["norm"], features(config, obs)))
      raw = mode(head, out) if deterministic else sample(theta, head, out, k_act)
      obs, state, reward, done, info = v_step(jax.random.split(k_env, episodes), state,
                                              to_env(head, raw), env_params)
      ret = ret + jnp.where(alive, reward.astype(jnp.float32), 0.0)
      solved = solved | (alive & info["success"])
      return (obs, state, alive & ~done, ret, solved), None

    init = (obs, state, jnp.ones(episodes, bool), jnp.zeros(episodes, jnp.float32),
            jnp.zeros(episodes, bool))
    (_, _, _, ret, solved), _ = jax.lax.scan(body, init, jax.random.split(key, max_steps))
    return solved, ret, level

  return evaluate


# Environments and the command line.


def load_env(name: str, level: str | None = None, **overrides):
  """`(env, params)` for `--env`: a task of `jaxchain.env.TASKS` (on `level` alone if
  given, with `EnvParams` overrides), `two_box` (`examples/two_box_task.py`), or a path
  to a Python file with `make_env() -> (env, params)`."""
  if name in jc.env.TASKS:
    return jc.env.make(name, **({} if level is None else {"levels": [level]}), **overrides)
  path = pathlib.Path(name)
  if name == "two_box":
    path = HERE / "two_box_task.py"
  if path.suffix != ".py" or not path.exists():
    raise SystemExit(f"--env: expected one of {', '.join(jc.env.TASKS)}, two_box, or a .py "
                     f"file with make_env(); got {name!r}")
  if level is not None:
    raise SystemExit(f"--level applies to the library's tasks, not to {path.name}")
  spec = importlib.util.spec_from_file_location(path.stem, path)
  module = importlib.util.module_from_spec(spec)
  sys.modules[spec.name] = module  # Dataclasses look their module up while being built.
  spec.loader.exec_module(module)
  env, params = module.make_env()
  if overrides:
    params = params.replace(**overrides)
  return env, params


def episode_limit(env, params) -> int:
  """The env's step limit per episode (`max_steps`), read on the host."""
  for field in ("max_steps", "max_steps_in_episode"):
    if hasattr(params, field):
      return int(getattr(params, field))
  raise SystemExit("the env's params have no max_steps: pass --eval-steps")


def write_curve(prefix: str, curve: dict, title: str) -> tuple[pathlib.Path, pathlib.Path]:
  """`PREFIX.csv` (columns `CURVE_FIELDS`) and `PREFIX.png` (return and success against
  timesteps)."""
  prefix = pathlib.Path(prefix)
  if prefix.suffix in (".csv", ".png"):
    prefix = prefix.with_suffix("")
  prefix.parent.mkdir(parents=True, exist_ok=True)
  rows = {k: np.asarray(curve[k]) for k in CURVE_FIELDS}
  csv_path, png_path = prefix.with_suffix(".csv"), prefix.with_suffix(".png")
  with open(csv_path, "w", newline="") as f:
    w = csv.writer(f)
    w.writerow(CURVE_FIELDS)
    for i in range(len(rows["update"])):
      w.writerow([_fmt(rows[k][i]) for k in CURVE_FIELDS])
  plot_curves([csv_path], png_path, title=title)
  return csv_path, png_path


def _fmt(x) -> str:
  return str(int(x)) if np.issubdtype(np.asarray(x).dtype, np.integer) else f"{float(x):.6g}"


def read_curve(path) -> dict[str, np.ndarray]:
  """A learning-curve CSV (as `write_curve` writes it) as `{column: array}`."""
  with open(path, newline="") as f:
    rows = list(csv.DictReader(f))
  return {k: np.asarray([float(r[k]) for r in rows]) for k in rows[0]} if rows else {}


def plot_curves(csv_paths, png_path, title: str | None = None, labels=None) -> None:
  """Return and success rate against env steps, one line per CSV written by `write_curve`."""
  import matplotlib
  matplotlib.use("Agg")
  import matplotlib.pyplot as plt
  fig, (ax_r, ax_s) = plt.subplots(1, 2, figsize=(10, 3.6))
  for i, path in enumerate(csv_paths):
    data = read_curve(path)
    label = labels[i] if labels else pathlib.Path(path).stem
    for ax, key in ((ax_r, "return"), (ax_s, "success")):
      # Raw per update (faint) and a running mean over 10 updates (weighted by episodes).
      x, y, w = data["timesteps"], data[key], data["episodes"]
      k = np.ones(10)
      smooth = np.convolve(y * w, k, "full")[:len(y)] / np.maximum(
          np.convolve(w, k, "full")[:len(y)], 1)
      line, = ax.plot(x, smooth, label=label)
      ax.plot(x, y, color=line.get_color(), alpha=0.2, linewidth=0.8)
  ax_r.set(xlabel="env steps", ylabel="mean episode return",
           title="return of the episodes ended (10-update mean)")
  ax_s.set(xlabel="env steps", ylabel="success rate",
           title="success of the episodes ended (10-update mean)",
           ylim=(-0.02, 1.02))
  for ax in (ax_r, ax_s):
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
  if title:
    fig.suptitle(title, fontsize=10)
  fig.tight_layout()
  fig.savefig(png_path, dpi=110)
  plt.close(fig)


def _parse_param(text: str):
  key, sep, value = text.partition("=")
  if not sep:
    raise argparse.ArgumentTypeError(f"--param: expected KEY=VALUE, got {text!r}")
  try:
    return key, int(value)
  except ValueError:
    try:
      return key, float(value)
    except ValueError:
      raise argparse.ArgumentTypeError(f"--param {key}: not a number: {value!r}") from None


def _parse_features(text: str):
  if text in ("all", "auto"):
    return None if text == "all" else "auto"
  try:
    return int(text)
  except ValueError:
    raise argparse.ArgumentTypeError(f"--obs-features: an int, all or auto, got {text!r}") from None


def main(argv=None) -> int:
  defaults = PPOConfig()
  parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
  parser.add_argument("--env", default="push_box_easy",
                      help=f"{' | '.join(jc.env.TASKS)} | two_box | path/to/task.py")
  parser.add_argument("--level", default=None, help="train on this level alone (e.g. platformer1)")
  parser.add_argument("--param", type=_parse_param, action="append", default=[],
                      metavar="KEY=VALUE", help="EnvParams override (repeatable), e.g. shaping=0.1")
  parser.add_argument("--timesteps", type=int, default=defaults.total_timesteps)
  parser.add_argument("--num-envs", type=int, default=defaults.num_envs)
  parser.add_argument("--num-steps", type=int, default=defaults.num_steps)
  parser.add_argument("--epochs", type=int, default=defaults.update_epochs)
  parser.add_argument("--minibatches", type=int, default=defaults.num_minibatches)
  parser.add_argument("--lr", type=float, default=defaults.lr)
  parser.add_argument("--gamma", type=float, default=defaults.gamma)
  parser.add_argument("--ent-coef", type=float, default=defaults.ent_coef)
  parser.add_argument("--hidden", type=int, default=defaults.hidden)
  parser.add_argument("--init-log-std", type=float, default=defaults.init_log_std)
  parser.add_argument("--squash", action="store_true", help="tanh-squash Gaussian samples")
  parser.add_argument("--obs-features", type=_parse_features, default=defaults.obs_features,
                      metavar="K|all|auto",
                      help="the policy reads only the first K observation entries; all; or "
                           "auto (default: all but the wall slots of the vector observation)")
  parser.add_argument("--normalize-obs", action=argparse.BooleanOptionalAction,
                      default=defaults.normalize_obs,
                      help="standardise observations by running statistics (default: "
                           f"{'on' if defaults.normalize_obs else 'off'})")
  parser.add_argument("--seed", type=int, default=0)
  parser.add_argument("--eval-episodes", type=int, default=256)
  parser.add_argument("--eval-steps", type=int, default=None,
                      help="steps per evaluation episode (default: the env's max_steps)")
  parser.add_argument("--log-every", type=int, default=1, help="print every N updates")
  parser.add_argument("--out", default=None, metavar="PREFIX",
                      help="write the learning curve to PREFIX.csv and PREFIX.png")
  parser.add_argument("--quiet", action="store_true", help="no per-update lines")
  parser.add_argument("--save", default=None, metavar="PATH.npz",
                      help="write the trained policy's arrays (keyed by pytree path)")
  parser.add_argument("--plot", nargs="+", default=None, metavar="CSV",
                      help="only plot these learning-curve CSVs into --out PREFIX.png (no training)")
  args = parser.parse_args(argv)
  if args.plot:
    if not args.out:
      parser.error("--plot needs --out PREFIX")
    png = pathlib.Path(args.out).with_suffix(".png")
    plot_curves(args.plot, png, title="PPO (examples/ppo.py) on 2 CPU cores")
    print(f"wrote {png}")
    return 0

  env, env_params = load_env(args.env, args.level, **dict(args.param))
  config = PPOConfig(num_envs=args.num_envs, num_steps=args.num_steps,
                     total_timesteps=args.timesteps, update_epochs=args.epochs,
                     num_minibatches=args.minibatches, lr=args.lr, gamma=args.gamma,
                     ent_coef=args.ent_coef, hidden=args.hidden,
                     init_log_std=args.init_log_std, squash=args.squash,
                     obs_features=args.obs_features,
                     normalize_obs=args.normalize_obs)
  head = head_of(env.action_space(env_params), config.squash)
  label = args.env + (f" ({args.level})" if args.level else "")
  print(f"PPO on {label}: {env!r}; {'categorical' if head.discrete else 'Gaussian'} head over "
        f"{head.n}; {config.num_updates} updates of {config.num_envs} envs x {config.num_steps} "
        f"steps ({config.num_updates * config.batch_size} env steps); jax {jax.__version__} on "
        f"{jax.devices()[0].platform}", flush=True)
  key = jax.random.key(args.seed)
  t0 = time.perf_counter()
  train = jax.jit(make_train(env, env_params, config, verbose=not args.quiet,
                             log_every=args.log_every)).lower(key).compile()
  compile_s = time.perf_counter() - t0
  print(f"compiled in {compile_s:.1f} s", flush=True)
  t0 = time.perf_counter()
  policy, curve = jax.block_until_ready(train(key))
  run_s = time.perf_counter() - t0
  train_s = compile_s + run_s
  print(f"trained in {run_s:.1f} s + {compile_s:.1f} s compile = {train_s / 60:.2f} min: "
        f"{config.num_updates * config.batch_size / run_s:.3g} env-steps/s", flush=True)

  steps = args.eval_steps or episode_limit(env, env_params)
  evaluate = jax.jit(make_evaluate(env, env_params, head, steps, args.eval_episodes,
                                   config=config))
  t0 = time.perf_counter()
  solved, ret, level = jax.block_until_ready(evaluate(policy, jax.random.key(args.seed + 10_000)))
  eval_s = time.perf_counter() - t0
  solved, ret, level = np.asarray(solved), np.asarray(ret), np.asarray(level)
  print(f"evaluation ({args.eval_episodes} episodes, policy mode, up to {steps} steps, "
        f"{eval_s:.1f} s): success {solved.mean():.1%}, mean return {ret.mean():.3f}", flush=True)
  names = getattr(env, "level_names", ())
  if len(names) > 1 and level.min() >= 0:
    print("  per level: " + ", ".join(f"{names[i]} {solved[level == i].mean():.0%} of "
                                      f"{int(np.sum(level == i))}" for i in range(len(names))
                                      if np.any(level == i)))
  if args.save:
    leaves = jax.tree_util.tree_leaves_with_path(policy)
    np.savez(args.save, **{jax.tree_util.keystr(k): np.asarray(v) for k, v in leaves})
    print(f"wrote {args.save}")
  if args.out:
    csv_path, png_path = write_curve(
        args.out, curve, f"PPO on {label}: eval success {solved.mean():.1%} "
        f"({args.eval_episodes} episodes), {train_s / 60:.1f} min")
    print(f"wrote {csv_path} and {png_path}")
  return 0


if __name__ == "__main__":
  sys.exit(main())
