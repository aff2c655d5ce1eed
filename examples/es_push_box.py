"""Evolution strategies on `push_box_easy`: a linear policy learns to push the box home.

OpenAI-ES (Salimans et al. 2017) in pure JAX: each iteration perturbs the policy's
parameters with `population / 2` antithetic pairs of Gaussian noise, scores every
perturbed policy by its episode returns in the environment (`jc.env.make`, all
episodes of a population in one jitted, vmapped `lax.scan` of `env.step`), turns
the returns into centred ranks and moves the parameters along the rank-weighted
noise with Adam. The policy is linear: `action = tanh(obs[:k] @ W + b)`, a 2-D
acceleration, from zero (the player stands still: return 0). It reads the first `k`
numbers of the observation: the player's, the box's and the goal's (not the wall
slots at the end).

Every member of a population plays the same episodes (one per level of the task,
with the same start jitter: common random numbers), and "return" below is the mean
return of the current parameters over `eval_episodes` episodes, equally many on
each level, with start jitter from a fixed evaluation key.

    python examples/es_push_box.py [--iterations 40] [--population 32] [--seed 0]

Prints the mean return before and after training, the share of episodes solved,
and the wall time.
"""

from __future__ import annotations

import argparse
import time

import jax
import jax.numpy as jnp
import numpy as np

import jaxchain as jc

TASK = "push_box_easy"


def features(env) -> int:
  """How many leading numbers of the observation the policy reads: the player's and
  the box and goal slots, not the walls (the last slots: they only tell the four
  rooms apart, which the box and goal slots already do)."""
  return jc.env.PLAYER_FEATURES + len(jc.env.SLOT_FIELDS) * int(env.slots_of("wall")[0] - 1)


def policy(theta: jax.Array, obs: jax.Array, obs_size: int) -> jax.Array:
  """`tanh(obs[:obs_size] @ W + b)`, with `theta` the flat `[obs_size * 2 + 2]`
  parameters."""
  w = theta[: obs_size * 2].reshape(obs_size, 2)
  return jnp.tanh(obs[:obs_size] @ w + theta[obs_size * 2:])


def make_fitness(env, params, steps: int):
  """`fitness(thetas [p, d], keys [p, e], levels [e]) -> (returns [p, e], solved [p, e])`:
  parameter vector i plays the episodes (level, start-jitter key `keys[i]`) for up to
  `steps` steps; the return counts the rewards up to the end of the first episode."""
  obs_size = features(env)

  def episode(theta, key, level):
    state = env.reset_level(key, params, level)
    obs = env.get_obs(state, params)

    def body(carry, k):
      obs, state, alive, ret, solved = carry
      # `step_env` (no auto-reset): only the first episode counts, and a finished
      # world may run on harmlessly; it compiles faster than `step`.
      obs, state, reward, done, info = env.step_env(k, state, policy(theta, obs, obs_size),
                                                    params)
      ret = ret + jnp.where(alive, reward, 0.0)
      solved = solved | (alive & info["success"])
      return (obs, state, alive & ~done, ret, solved), None

    init = (obs, state, jnp.array(True), jnp.zeros((), obs.dtype), jnp.array(False))
    (_, _, _, ret, solved), _ = jax.lax.scan(body, init, jax.random.split(key, steps))
    return ret, solved

  batch = jax.vmap(episode)  # One flat batch of (member, episode) pairs: vmap once.

  @jax.jit
  def fitness(thetas, keys, levels):
    p, e = keys.shape
    flat = batch(jnp.repeat(thetas, e, axis=0), keys.reshape(p * e),
                 jnp.tile(levels, p))
    return jax.tree.map(lambda x: x.reshape(p, e), flat)

  return fitness


def centred_ranks(x: jax.Array) -> jax.Array:
  """Ranks of `x` scaled to `[-0.5, 0.5]` (OpenAI-ES fitness shaping)."""
  ranks = jnp.argsort(jnp.argsort(x)).astype(x.dtype)
  return ranks / (x.size - 1) - 0.5


def train(iterations: int = 40, population: int = 32, seed: int = 0, *, sigma: float = 0.1,
          learning_rate: float = 0.05, steps: int = 150, eval_episodes: int | None = None,
          verbose: bool = False) -> tuple[float, float]:
  """Trains the linear policy; returns `(return_before, return_after)`.

  Args:
    iterations: ES updates.
    population: perturbed policies per update (even: antithetic pairs).
    seed: seeds the noise, the episodes' start jitter and the evaluation.
    sigma: noise scale of the perturbations.
    learning_rate: Adam's step size.
    steps: steps per episode (the env's `max_steps`).
    eval_episodes: episodes of the before/after evaluation, rounded up to a
      multiple of `population` times the number of levels (the default: one round).
    verbose: print progress.

  Returns:
    The mean evaluation return of the initial (zero) and the final parameters.
  """
  if population % 2:
    raise ValueError(f"population must be even (antithetic pairs), got {population}")
  env, params = jc.env.make(TASK, max_steps=steps)
  n_levels = env.num_levels
  fitness = make_fitness(env, params, steps)
  dim = features(env) * 2 + 2
  theta = jnp.zeros(dim)
  key = jax.random.key(seed)
  key, eval_key = jax.random.split(key)
  # One episode per level per member; the evaluation plays `population` copies of one
  # parameter vector on distinct keys, so it reuses the compiled `fitness` (same shapes).
  episodes = n_levels
  levels = jnp.arange(n_levels, dtype=jnp.int32)
  eval_rounds = max(1, -(-(eval_episodes or population * episodes) // (population * episodes)))

  def evaluate(theta):
    rets, solved = [], []
    for r in range(eval_rounds):
      keys = jax.random.split(jax.random.fold_in(eval_key, r), (population, episodes))
      ret, ok = fitness(jnp.broadcast_to(theta, (population, dim)), keys, levels)
      rets.append(np.asarray(ret))
      solved.append(np.asarray(ok))
    return float(np.mean(rets)), float(np.mean(solved))

  m = jnp.zeros(dim)
  v = jnp.zeros(dim)
  b1, b2, eps = 0.9, 0.999, 1e-8
  before, solved_before = evaluate(theta)
  if verbose:
    print(f"{TASK}: levels {', '.join(env.level_names)}; policy tanh(obs[:{features(env)}] @ W "
          f"+ b), {dim} parameters; population {population}, sigma {sigma}, {steps} steps per "
          f"episode")
    print(f"before: mean return {before:.3f}, solved {solved_before:.0%}")
  for it in range(iterations):
    key, k_noise, k_ep = jax.random.split(key, 3)
    half = jax.random.normal(k_noise, (population // 2, dim))
    noise = jnp.concatenate([half, -half])
    # Common random numbers: every member plays the same episodes.
    ep_keys = jnp.broadcast_to(jax.random.split(k_ep, episodes), (population, episodes))
    ret, _ = fitness(theta[None] + sigma * noise, ep_keys, levels)
    score = centred_ranks(ret.mean(axis=1))
    grad = -(noise.T @ score) / (population * sigma)  # Ascent on the return.
    m = b1 * m + (1 - b1) * grad
    v = b2 * v + (1 - b2) * grad**2
    theta = theta - learning_rate * (m / (1 - b1 ** (it + 1))) / (
        jnp.sqrt(v / (1 - b2 ** (it + 1))) + eps)
    if verbose and (it % 5 == 4 or it == iterations - 1):
      print(f"iteration {it + 1:3d}: population mean return {float(ret.mean()):.3f}, "
            f"best {float(ret.mean(axis=1).max()):.3f}")
  after, solved_after = evaluate(theta)
  if verbose:
    print(f"after:  mean return {after:.3f}, solved {solved_after:.0%}")
  return before, after


def main(argv=None) -> int:
  parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
  parser.add_argument("--iterations", type=int, default=40)
  parser.add_argument("--population", type=int, default=32)
  parser.add_argument("--steps", type=int, default=150)
  parser.add_argument("--seed", type=int, default=0)
  args = parser.parse_args(argv)
  t0 = time.perf_counter()
  before, after = train(args.iterations, args.population, args.seed, steps=args.steps,
                        verbose=True)
  print(f"return {before:.3f} -> {after:.3f} in {time.perf_counter() - t0:.0f} s "
        f"(compile included)")
  return 0


if __name__ == "__main__":
  raise SystemExit(main())
