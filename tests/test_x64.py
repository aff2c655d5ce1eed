"""float64 end to end, in a subprocess so the rest of the suite stays float32."""

import os
import subprocess
import sys
import textwrap

SCRIPT = textwrap.dedent("""
    import jax, jax.numpy as jnp, numpy as np
    import jaxchain as jc
    from jaxchain import reference, scenes
    assert jax.config.jax_enable_x64
    scene = scenes.push_chain(6, overlap=0.3, wall=False, masses=[1, 2, 3, 0.5, 1, 2, 1e3],
                              overlaps=[0.1, 0.0, 0.2, 0.05, 0.0])
    world = scene.world()
    assert world.pos.dtype == jnp.float64, world.pos.dtype
    out = jc.resolve(world, jc.Config(depth=8, gravity=False))
    want = reference.resolve(scene.pos, scene.half, scene.mass)
    err = float(np.max(np.abs(np.asarray(out.pos) - want)))
    assert err < 1e-12, err
    room = scenes.platformer().scene.world(friction=0.3)
    cfg = jc.Config.for_world(room)
    final, traj = jc.rollout(room, cfg, 60)
    assert traj.pos.dtype == jnp.float64 and int(final.status) == 0
    g = jax.grad(lambda v: jc.rollout(room.replace(vel=room.vel.at[4, 0].set(v)), cfg, 30)[0].pos[4, 0])(3.0)
    assert np.isfinite(g) and g > 0, g
    print("x64 ok", err)
""")


def test_float64_end_to_end():
  env = {**os.environ, "JAX_ENABLE_X64": "1", "JAX_PLATFORMS": "cpu"}
  done = subprocess.run([sys.executable, "-c", SCRIPT], capture_output=True, text=True, env=env,
                        timeout=300)
  assert done.returncode == 0, done.stderr[-3000:]
  assert "x64 ok" in done.stdout
