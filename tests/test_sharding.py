"""A batch of worlds sharded over devices (`jax.sharding`) and over processes.

Every sharded run happens in a subprocess with `JAX_NUM_CPU_DEVICES=2`, so this pytest
process keeps its one device; here each result is compared with the same batch stepped
unsharded on that one device, and must be bit-identical (`np.array_equal`).

The mesh is the one `jax.make_mesh((2,), ("worlds",))` builds by default (explicit axes,
`AxisType.Explicit`), under `jax.set_mesh` and without it (the batch's type carries the
mesh), and one with `AxisType.Auto`. Under explicit axes JAX's batching
rules for `select_n`, for gathers whose operand is not batched and for loop carries that
start unbatched reject the sharded batch axis: the step runs its body in
`sharding.in_auto_axes`, and `Config` is a pytree without leaves, so
`jax.vmap(jc.step, in_axes=(0, None, 0))` accepts it.
"""

import doctest
import functools
import json
import os
import pathlib
import subprocess
import sys
import textwrap

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax import lax

import jaxchain
from jaxchain import sharding
from jaxchain.core.layout import lane_index, take

ROOT = pathlib.Path(__file__).resolve().parents[1]
SRC = pathlib.Path(jaxchain.__file__).resolve().parents[1]  # The jaxchain under test.
TIMEOUT_S = 240

# The cases, built the same way here (one device) and in the subprocess (two).
CASES = textwrap.dedent("""
    import jax, jax.numpy as jnp, numpy as np
    import jaxchain as jc

    B, STEPS = 4, 3

    def cases():
      plat = jc.stack([jc.scenes.platformer(np.random.default_rng(s)).scene.world(friction=0.3)
                       for s in range(B)])
      cfg = jc.Config.for_world(plat)
      n = plat.num_bodies
      push = np.zeros((B, STEPS, n, 2), np.float32)
      push[:, :, jc.scenes.platformer().player, 0] = 20.0 + np.arange(B)[:, None]  # Per world.
      push = jnp.asarray(push)
      room = jc.stack([jc.scenes.box_room(np.random.default_rng(s), 40).world()  # Lighter.
                       for s in range(B)])
      grid = jc.Config.for_world(room, broadphase="grid")
      assert grid.uses_grid(room.num_bodies)
      return {
          "rollout": (lambda w, u: jax.jit(jax.vmap(
              lambda w, u: jc.rollout(w, cfg, STEPS, u)[0]))(w, u), plat, push),
          "step_in_axes": (lambda w, u: jax.vmap(jc.step, in_axes=(0, None, 0))(w, cfg, u[:, 0]),
                           plat, push),
          "grid_rollout": (lambda w, u: jax.jit(jax.vmap(
              lambda w: jc.rollout(w, grid, STEPS)[0]))(w), room, push),
      }

    def leaves(world):
      return {k: np.asarray(getattr(world, k)) for k in ("pos", "vel", "status", "crushed")}
""")

SHARDED = CASES + textwrap.dedent("""
    import json, sys
    from jax.sharding import AxisType, NamedSharding, PartitionSpec as P
    jax.config.update("jax_numpy_rank_promotion", "raise")
    jax.config.update("jax_numpy_dtype_promotion", "strict")
    import contextlib
    run_kinds, out_path = sys.argv[1].split(","), sys.argv[2]
    KINDS = json.loads(sys.argv[3])
    assert jax.device_count() == 2, jax.devices()
    report, arrays = {}, {}
    for kind in run_kinds:
      # "unset": the explicit mesh make_mesh builds, but no jax.set_mesh around the call
      # (the batch's type alone carries the mesh).
      types = (AxisType.Auto,) if kind == "auto" else (AxisType.Explicit,)
      mesh = jax.make_mesh((2,), ("worlds",), axis_types=None if kind != "auto" else types)
      assert mesh.axis_types == types, mesh.axis_types  # make_mesh's default is explicit.
      context = contextlib.nullcontext() if kind == "unset" else jax.set_mesh(mesh)
      with context:
        for name, (fn, worlds, push) in cases().items():
          if name not in KINDS[kind]:
            continue
          put = lambda x: jax.device_put(x, NamedSharding(mesh, P("worlds")))
          try:
            out = fn(jax.tree.map(put, worlds), put(push))
            shards = out.pos.addressable_shards
            report[f"{kind}/{name}"] = dict(ok=True, devices=len(out.pos.sharding.device_set),
                                            rows=[s.data.shape[0] for s in shards])
            arrays.update({f"{kind}/{name}/{k}": v for k, v in leaves(out).items()})
          except Exception as e:  # Reported to the test, which shows it.
            report[f"{kind}/{name}"] = dict(ok=False, error=f"{type(e).__name__}: {str(e)[:400]}")
    np.savez(out_path, **arrays)
    print("REPORT " + json.dumps(report))
""")

def _env(devices: int) -> dict:
  path = os.pathsep.join([str(SRC), os.environ.get("PYTHONPATH", "")]).rstrip(os.pathsep)
  return {**os.environ, "JAX_PLATFORMS": "cpu", "JAX_NUM_CPU_DEVICES": str(devices),
          "PYTHONPATH": path}


@pytest.fixture(scope="module")
def sharded(tmp_path_factory):
  """Every case on 2 devices under each mesh kind: `{kind: (report, arrays)}`, or
  `{kind: error text}` if that subprocess failed as a whole.

  Both subprocesses start at once and this process computes its one-device references
  while they compile (`_reference`), so the module costs about one subprocess of time.
  """
  tmp = tmp_path_factory.mktemp("sharding")
  runs = {kinds: (subprocess.Popen([sys.executable, "-c", SHARDED, kinds, str(tmp / f"{i}.npz"),
                                    json.dumps(KINDS)],
                                   stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                   env=_env(2)), tmp / f"{i}.npz")
          for i, kinds in enumerate(PROCESSES)}
  for name in NAMES:
    _reference(name)
  out = {}
  for kinds, (proc, path) in runs.items():
    try:
      stdout, stderr = proc.communicate(timeout=TIMEOUT_S)
    except subprocess.TimeoutExpired:
      for p, _ in runs.values():
        p.kill()
      raise
    line = next((l for l in stdout.splitlines() if l.startswith("REPORT ")), None)
    for kind in kinds.split(","):
      if proc.returncode or line is None:
        out[kind] = f"exit {proc.returncode}: {stderr[-3000:]}"
      else:
        out[kind] = json.loads(line[len("REPORT "):]), dict(np.load(path))
  return out


@functools.lru_cache(maxsize=None)
def _cases() -> dict:
  namespace = {}
  exec(CASES, namespace)  # noqa: S102 - the test's own case table.
  return namespace


@functools.lru_cache(maxsize=None)
def _reference(name: str) -> dict:
  """The same case stepped unsharded on this process's one device."""
  fn, worlds, push = _cases()["cases"]()[name]
  return _cases()["leaves"](fn(worlds, push))


# Three programs per process (compile dominates): a rollout with controls (the scan), a
# plain `jc.step` vmapped with the config unmapped, and the grid broadphase (argsort,
# searchsorted, scatter). `make_step` and `resolve` run the same stages.
NAMES = ["rollout", "step_in_axes", "grid_rollout"]
# The cases each mesh kind runs: all under explicit axes (what `jax.make_mesh` builds,
# and where JAX type-checks the batch); under Auto axes the scan and the grid (the
# `in_axes=None` config is an explicit-mode check). Fewer compiles, same coverage.
# "unset" is the explicit mesh with no `jax.set_mesh` around the call (issue 19): the
# batch's type carries the mesh, and the rollout must still give the one-device bits.
KINDS = {"explicit": NAMES, "auto": ["rollout", "grid_rollout"], "unset": ["rollout"]}
PROCESSES = ("explicit", "auto,unset")  # Two subprocesses at once, about equally long.
CASES_RUN = [(name, kind) for kind, names in KINDS.items() for name in names]


@pytest.mark.parametrize("name, kind", CASES_RUN)
def test_sharded_batch_matches_one_device(name, kind, sharded):
  assert jax.device_count() == 1  # This process keeps one device.
  assert not isinstance(sharded[kind], str), sharded[kind]
  report, arrays = sharded[kind]
  got = report[f"{kind}/{name}"]
  assert got["ok"], got["error"]
  assert got["devices"] == 2 and got["rows"] == [2, 2], got  # Two worlds on each device.
  want = _reference(name)
  for k, v in want.items():
    assert np.array_equal(arrays[f"{kind}/{name}/{k}"], v), f"{name}: {k} differs from one device"


def _multiprocess(*flags: str) -> subprocess.CompletedProcess:
  argv = [sys.executable, str(ROOT / "examples" / "multiprocess.py"), "--processes", "2",
          "--worlds", "4", "--steps", "2", "--timeout", "150", *flags]
  return subprocess.run(argv, capture_output=True, text=True, env=_env(1), timeout=TIMEOUT_S)


def test_multiprocess_example_matches_one_process():
  """Two processes on one runtime (the explicit mesh `jax.make_mesh` builds), 2 worlds each."""
  done = _multiprocess()
  assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-2000:]
  assert "[0] PASS" in done.stdout and "bit-identical" in done.stdout, done.stdout[-2000:]


# --- jaxchain.sharding: the batched gather and the Auto-axes wrapper -------------------

HELPERS = textwrap.dedent("""
    import contextlib, json, re, sys
    import jax, jax.numpy as jnp, numpy as np
    from jax import lax
    from jax.sharding import AxisType, NamedSharding, PartitionSpec as P
    from jaxchain.core.layout import lane_index, lanes_split, take
    from jaxchain.sharding import in_auto_axes
    jax.config.update("jax_numpy_rank_promotion", "raise")

    def per_world(x, idx, table):
      # The patterns JAX 0.10.1 rejects under an explicit batch axis:
      code = jnp.where(jnp.sum(x) > 0, 4, 0)                       # select_n of constants
      total = lax.fori_loop(0, 2, lambda i, c: c + jnp.sum(x), 0.0)  # unbatched scalar carry
      rows = table[jnp.argsort(x)]                                 # gather, unbatched operand
      return code, total, rows

    def batch(x, idx):
      # The core's gathers, batch minor: table [6, B], rows [5, B] (and a stack of two).
      xm, im = x.T, idx.T
      both = jnp.stack([xm, 2.0 * xm])
      shifted = lane_index(im)[None] + jnp.asarray([0, 6], jnp.int32)[:, None, None] * (
          1 if lanes_split() else x.shape[0])
      return take(xm, lane_index(im)).T, jnp.moveaxis(take(both, shifted), -1, 0)

    rng = np.random.default_rng(0)
    x = jnp.asarray(rng.normal(size=(8, 6)).astype(np.float32))
    idx = jnp.asarray(rng.integers(0, 6, (8, 5)).astype(np.int32))
    table = jnp.asarray(rng.normal(size=6).astype(np.float32))
    fn = jax.jit(jax.vmap(lambda x, i: in_auto_axes(per_world, x, i, table)))
    core = jax.jit(lambda x, i: in_auto_axes(batch, x, i, batched=True))
    want = [np.asarray(a) for a in fn(x, idx)]
    want_core = [np.asarray(x)[np.arange(8)[:, None], np.asarray(idx)],
                 np.stack([1.0, 2.0])[None, :, None] * np.asarray(x)[np.arange(8)[:, None], np.asarray(idx)][:, None]]
    report = {}
    for kind in ("explicit", "auto", "unset"):
      mesh = jax.make_mesh((2,), ("worlds",), axis_types=(
          AxisType.Auto if kind == "auto" else AxisType.Explicit,))
      put = lambda a: jax.device_put(a, NamedSharding(mesh, P("worlds")))
      for f, w, label in ((fn, want, kind), (core, want_core, f"{kind}/core")):
        with jax.set_mesh(mesh) if kind != "unset" else contextlib.nullcontext():
          compiled = f.lower(put(x), put(idx)).compile()
          got = compiled(put(x), put(idx))
        hlo = compiled.as_text()
        report[label] = dict(
            same=all(np.array_equal(np.asarray(g), v) for g, v in zip(got, w)),
            collectives=len(re.findall(r"all-gather|all-reduce|collective-permute|all-to-all", hlo)),
            sharded=[len(g.sharding.device_set) for g in got])
    print("REPORT " + json.dumps(report))
""")


def test_helpers_under_both_meshes_without_collectives():
  """`in_auto_axes` around code JAX 0.10.1 rejects under explicit axes (per world, under
  vmap), and around the core's batch-minor gathers (`core.layout.take`, the batch as a
  whole): the same bits as one device under both meshes and under an explicit mesh that
  is only in the batch's type (no `jax.set_mesh`), the outputs sharded over both
  devices, and no collective in the program (with the batch spread over devices each
  gather indexes its own world's lane: `core.layout.lanes_split`)."""
  done = subprocess.run([sys.executable, "-c", HELPERS], capture_output=True, text=True,
                        env=_env(2), timeout=TIMEOUT_S)
  assert done.returncode == 0, done.stderr[-3000:]
  report = json.loads(next(l for l in done.stdout.splitlines() if l.startswith("REPORT "))[7:])
  for kind in ("explicit", "auto", "unset"):
    assert report[kind] == dict(same=True, collectives=0, sharded=[2] * 3), (kind, report)
    assert report[f"{kind}/core"] == dict(same=True, collectives=0, sharded=[2] * 2), (kind, report)


def test_take_is_one_flat_gather_and_matches_the_split_lanes(monkeypatch):
  """`core.layout.take` on one device: one flat gather over `[R, B]` (the rows at
  `lane_index`), and with the lanes split (several devices) a gather per lane; the same
  values and gradients either way, and inside a loop (the chain's hops)."""
  rng = np.random.default_rng(1)
  x = jnp.asarray(rng.normal(size=(3, 5, 4)).astype(np.float32))  # [k, n, B]
  rows = jnp.asarray(rng.integers(0, 15, (2, 7, 4)).astype(np.int32))  # Rows of [15, B].
  want = np.asarray(x).reshape(15, 4)[np.asarray(rows), np.arange(4)]

  def run():
    got = take(x, lane_index(rows))
    loss = lambda a: jnp.sum(jnp.sin(take(a, lane_index(rows))) * jnp.arange(1.0, 8.0)[None, :, None])
    hop = lax.fori_loop(0, 2, lambda _, c: c + take(x + c[0, 0, 0], lane_index(rows)),
                        jnp.zeros(rows.shape, x.dtype))
    return got, jax.grad(loss)(x), hop

  flat = jax.jit(run)()
  text = jax.jit(run).lower().as_text()
  assert np.array_equal(flat[0], want)
  monkeypatch.setattr(jax, "device_count", lambda: 2)  # Two devices: the lanes split.
  split = run()
  for a, b in zip(flat, split):
    np.testing.assert_allclose(a, b, rtol=1e-6, atol=1e-6)
  assert text.count("gather(") <= 3  # The flat formulation: no per-lane batching dims.


def test_sharding_docstring_examples():
  result = doctest.testmod(sharding, optionflags=doctest.ELLIPSIS)
  assert result.attempted > 0 and result.failed == 0


def test_step_rollout_and_resolve_run_inside_shard_map():
  """Issue 44 item 7: inside `jax.shard_map` (its `check_vma` on, the default) `jc.step`,
  `jc.rollout` and `jc.resolve` raised a TypeError: the core's loops (passes, closing
  stage, chain hops, friction rounds, substeps, the rollout's scan and neighbour table)
  start from constants, which vary over no mesh axis, and end with values computed
  from the worlds, which vary over the axis the batch is split over;
  `core.layout.vary` casts those initial carries. On this process's one device (a mesh
  of one, explicit axes as `jax.make_mesh` builds it), one program (one compile): the
  exact answers, and the step's equal to the rollout's first step."""
  from jax.sharding import NamedSharding, PartitionSpec as P

  import jaxchain as jc
  # Two boxes meeting head-on (world 0: overlapping by 0.1, closing at 1 u/s), and the
  # same 0.1 apart (world 1): the smallest step with loops (the closing stage's, the
  # chain's hops, the impulses' refinement; friction's rounds and the substeps' carry
  # the same `vary`).
  world = jc.World.create([[0.0, 0.0], [0.9, 0.0]], [0.5, 0.5], 1.0,
                          vel=[[1.0, 0.0], [0.0, 0.0]], gravity=(0.0, 0.0))
  batch = jc.stack([world, world.replace(pos=world.pos.at[0, 0].set(-0.2))])
  cfg = jc.Config.for_world(batch)
  run = lambda w: (jc.step(w, cfg), jc.resolve(w, cfg), jc.rollout(w, cfg, 2))
  mesh = jax.make_mesh((1,), ("worlds",))
  sharded = jax.device_put(batch, NamedSharding(mesh, P("worlds")))
  stepped, resolved, (final, traj) = jax.jit(jax.shard_map(
      run, mesh=mesh, in_specs=P("worlds"), out_specs=P("worlds")))(sharded)
  dt = cfg.dt
  # World 0: the overlap (0.1 + dt) split in half, both at the common velocity 0.5 (the
  # overlap already there adds none); world 1 moves freely.
  x0 = dt - (0.1 + dt) / 2
  np.testing.assert_allclose(stepped.pos[:, :, 0], [[x0, 0.9 + dt - x0], [-0.2 + dt, 0.9]],
                             atol=1e-6)
  np.testing.assert_allclose(stepped.vel[:, :, 0], [[0.5, 0.5], [1.0, 0.0]], atol=1e-6)
  np.testing.assert_allclose(resolved.pos[:, :, 0], [[-0.05, 0.95], [-0.2, 0.9]], atol=1e-6)
  np.testing.assert_allclose(final.pos[:, :, 0], [[x0 + dt / 2, 0.9 + dt - x0 + dt / 2],
                                                  [-0.2 + 2 * dt, 0.9]], atol=1e-6)
  for name in ("pos", "vel"):
    assert np.array_equal(getattr(traj, name)[:, 0], getattr(stepped, name))
  assert not np.asarray(stepped.status).any() and not np.asarray(final.status).any()
