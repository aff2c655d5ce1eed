"""A task of your own, from parts: a room with two boxes and two goals, discrete moves
(each held for 4 physics steps), and a reward of your own: +1 per box newly on a goal
(-1 per box pushed off), +2 when both are home, 0.2 per unit the boxes get closer to
the goals (the sum of each box's Manhattan distance to its nearest goal), -0.001 per
physics step. An episode ends when both goals hold a box (or the player is crushed),
or after 200 moves (a scripted path home for both boxes takes about 110).

`make_env()` returns `(env, params)`; `examples/ppo.py --env two_box` trains it.

    python examples/two_box_task.py   # plays one episode at random and prints its return
"""

import jax
import jax.numpy as jnp

import jaxchain as jc

ROOM = """
#########
#       #
#  $  . #
# @     #
#  $  . #
#       #
#########
"""


def reward(env, old, action, new, params):  # Your own: goals filled, progress, time.
  on = lambda state: jnp.sum(jc.env.goals_filled(env, state.world)).astype(jnp.float32)
  closer = jc.env.box_goal_distance(env, old.world) - jc.env.box_goal_distance(env, new.world)
  home = jc.env.all_goals_filled(env, new.world)
  return on(new) - on(old) + jnp.where(home, 2.0, 0.0) + 0.2 * closer - 0.001


TASK = jc.env.Task(name="two_box", levels=[jc.env.load_level(ROOM, name="two_box")],
                   actions=jc.env.Moves(repeat=4), reward=reward, terminate=jc.env.push_terminate,
                   forces=jc.env.drag, slots=(("box", 2), ("goal", 2)),
                   params=jc.env.PushBoxParams(max_steps=200))


def make_env(**overrides):  # (env, params); overrides as jc.env.make's.
  return jc.env.make(TASK, **overrides)


if __name__ == "__main__":
  env, params = make_env()
  key = jax.random.key(0)
  obs, state = env.reset(key, params)
  step = jax.jit(env.step)
  for k in jax.random.split(key, params.max_steps):
    obs, state, r, done, info = step(k, state, env.action_space(params).sample(k), params)
    if done:
      break
  print(f"{env}: return {float(info['episode_return']):.3f} after "
        f"{int(info['episode_length'])} steps, success {bool(info['success'])}")
