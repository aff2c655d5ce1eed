"""System identification: recover a box's mass and the floor's friction coefficient from a
recorded, noisy trajectory, by Gauss-Newton through a differentiable rollout.

A player of known mass 1 runs at 4 u/s into a box of unknown mass resting on a floor;
both slide on together and friction (one unknown coefficient shared by every body)
stops them. The recording is the x positions of player and box at every step, with
Gaussian noise. The model is the same scene with the parameters `(log mass, mu)`; the
fit minimises the squared residuals with Gauss-Newton steps (the Jacobian of the
residuals by `jax.jacfwd`: two parameters, two forward-mode passes), damped
Levenberg-Marquardt style, each accepted by a backtracking line search. Everything runs
in float32.

The guess starts at mass 1 and friction 0. `Config.for_world` would leave friction out
of a world whose coefficients are all 0 (its gradient would be 0); `keep=("friction",)`
keeps it compiled in. The mass enters through `World.with_mass`, so the gradient reaches
it directly.

    python examples/system_identification.py            # 90 steps (about 1.5 s of motion)
    python examples/system_identification.py --steps 30  # the small size the tests run
"""

from __future__ import annotations

import argparse

import jax
import jax.numpy as jnp
import numpy as np

import jaxchain as jc

INF = float("inf")
TRUE_MASS, TRUE_MU = 2.5, 0.3
NOISE = 2e-3  # Standard deviation of the recorded positions.


def scene(steps: int) -> tuple[jc.World, jc.Config]:
  """Player (body 0, mass 1, at 4 u/s) touching a box (body 1) on a floor (body 2); the
  masses and the coefficient are placeholders that `simulate` sets. The config is sized
  for the scene and keeps friction compiled in whatever the guess."""
  world = jc.World.create([[0.0, 0.5], [1.0, 0.5], [0.0, -0.5]],
                          [[0.5, 0.5], [0.5, 0.5], [50.0, 0.5]], [1.0, 1.0, INF],
                          vel=[[4.0, 0.0], [0.0, 0.0], [0.0, 0.0]], friction=0.0)
  del steps
  # A row on a floor: one link per body and direction (`links=1` compiles a smaller step).
  return world, jc.Config.for_world(world, keep=("friction",), links=1)


def simulate(theta: jax.Array, world: jc.World, config: jc.Config, steps: int) -> jax.Array:
  """`[steps, 2]`: the x positions of player and box at parameters `theta = (log mass,
  mu)`."""
  mass = jnp.stack([jnp.ones((), theta.dtype), jnp.exp(theta[0]), jnp.full((), jnp.inf)])
  world = world.with_mass(mass).replace(friction=jnp.full(3, theta[1]))
  _, traj = jc.rollout(world, config, steps)
  return traj.pos[:, :2, 0]


def _with_jacobian(theta, world, config, steps):
  flat = simulate(theta, world, config, steps).reshape(-1)
  return flat, flat


# `(d positions / d theta, positions)`, flattened (`[2 steps, 2]`, `[2 steps]`): the
# Jacobian by forward mode (two parameters, two tangents). One program, for the recording
# and every iteration of the fit.
positions_and_jacobian = jax.jit(jax.jacfwd(_with_jacobian, has_aux=True), static_argnums=(2, 3))


def record(steps: int, seed: int = 0) -> np.ndarray:
  """The measured trajectory (`[steps, 2]`): the true scene's positions plus noise."""
  world, config = scene(steps)
  theta = jnp.array([np.log(TRUE_MASS), TRUE_MU], jnp.float32)
  clean = np.asarray(positions_and_jacobian(theta, world, config, steps)[1]).reshape(steps, 2)
  rng = np.random.default_rng(seed)
  return clean + NOISE * rng.standard_normal(clean.shape).astype(np.float32)


def fit(observed: np.ndarray, theta0=(0.0, 0.0), iterations: int = 20,
        verbose: bool = False) -> tuple[np.ndarray, list[float]]:
  """Gauss-Newton (Levenberg-Marquardt damping) with a backtracking line search.

  Returns:
    `(theta, losses)`: the fitted `(log mass, mu)` and the loss after each iteration.
  """
  steps = observed.shape[0]
  world, config = scene(steps)
  observed = jnp.asarray(observed).reshape(-1)

  def jac_and_res(theta):
    jac, flat = positions_and_jacobian(theta, world, config, steps)
    return jac, flat - observed

  theta = jnp.asarray(theta0, jnp.float32)
  jac, res = jac_and_res(theta)
  loss = float(jnp.sum(res**2))
  losses, damping = [loss], 1e-3
  for k in range(iterations):
    jtj, jtr = jac.T @ jac, jac.T @ res
    step = -jnp.linalg.solve(jtj + damping * jnp.diag(jnp.diag(jtj)), jtr)
    scale, accepted = 1.0, False
    while scale > 1e-3:  # Backtracking: halve until the loss goes down.
      trial = theta + scale * step
      trial = trial.at[1].set(jnp.maximum(trial[1], 0.0))  # mu >= 0.
      trial_jac, trial_res = jac_and_res(trial)
      trial_loss = float(jnp.sum(trial_res**2))
      if trial_loss < loss:
        accepted = True
        break
      scale *= 0.5
    if not accepted:
      break  # No step lowers the loss: converged (to float32 resolution).
    theta, jac, res, loss = trial, trial_jac, trial_res, trial_loss
    damping = max(damping * 0.3, 1e-6) if scale == 1.0 else damping * 3.0
    losses.append(loss)
    if verbose:
      print(f"iteration {k:2d}: mass {float(jnp.exp(theta[0])):.4f}  mu {float(theta[1]):.4f}  "
            f"loss {loss:.4e}  (step x{scale:g})")
  return np.asarray(theta), losses


def identify(steps: int = 90, iterations: int = 20, seed: int = 0,
             verbose: bool = False) -> dict[str, float]:
  """Records a noisy trajectory, fits it, and returns the fitted values and relative
  errors."""
  observed = record(steps, seed)
  theta, losses = fit(observed, iterations=iterations, verbose=verbose)
  mass, mu = float(np.exp(theta[0])), float(theta[1])
  return dict(mass=mass, mu=mu, mass_error=abs(mass / TRUE_MASS - 1),
              mu_error=abs(mu / TRUE_MU - 1), loss=losses[-1], iterations=len(losses) - 1)


def main():
  parser = argparse.ArgumentParser(description=__doc__,
                                   formatter_class=argparse.RawDescriptionHelpFormatter)
  parser.add_argument("--steps", type=int, default=90, help="length of the recording")
  parser.add_argument("--iterations", type=int, default=20, help="most Gauss-Newton steps")
  parser.add_argument("--seed", type=int, default=0, help="seed of the noise")
  args = parser.parse_args()
  out = identify(args.steps, args.iterations, args.seed, verbose=True)
  print(f"mass {out['mass']:.4f} (true {TRUE_MASS}, error {100 * out['mass_error']:.2f}%), "
        f"mu {out['mu']:.4f} (true {TRUE_MU}, error {100 * out['mu_error']:.2f}%)")


if __name__ == "__main__":
  main()
