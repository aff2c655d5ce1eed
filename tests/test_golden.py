"""Same answers: the benchmark scenes replayed against stored values (`tests/data/golden.npz`,
written by `tests/data/make_golden.py` from the physics issue's final commit)."""

import importlib.util
import json
import os
import pathlib
import subprocess
import sys
import textwrap

import numpy as np
import pytest

from tests.xla_flags import SUITE_XLA_FLAGS

DATA = pathlib.Path(__file__).parent / "data"
_spec = importlib.util.spec_from_file_location("make_golden", DATA / "make_golden.py")
make_golden = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(make_golden)
GOLDEN = np.load(DATA / "golden.npz")
CASES = make_golden.cases()


@pytest.mark.parametrize("name", sorted(CASES))
def test_same_answers_as_stored(name):
  world, kwargs, controls = CASES[name]
  final = make_golden.run(world, kwargs, controls)
  np.testing.assert_allclose(np.asarray(final.pos), GOLDEN[f"{name}/pos"], rtol=0, atol=1e-6)
  np.testing.assert_allclose(np.asarray(final.vel), GOLDEN[f"{name}/vel"], rtol=0, atol=1e-6)
  assert int(final.status) == int(GOLDEN[f"{name}/status"])


def test_stored_scenes_move():
  """The stored states are not the initial ones: the comparison above can fail."""
  for name, (world, _, _) in CASES.items():
    assert np.max(np.abs(GOLDEN[f"{name}/pos"] - np.asarray(world.pos))) > 1e-3, name


@pytest.fixture(scope="module")
def default_level():
  """One subprocess compiled with XLA's defaults (the suite compiles with faster
  codegen, see conftest.py), for the tests below: `{check: "OK" or its error}`."""
  suite_only = [flag.split("=")[0] for flag in SUITE_XLA_FLAGS]
  flags = " ".join(f for f in os.environ.get("XLA_FLAGS", "").split()
                   if f.split("=")[0] not in suite_only)
  code = textwrap.dedent(f"""
      import importlib.util, json, traceback
      import jax, numpy as np
      import jaxchain as jc
      spec = importlib.util.spec_from_file_location("make_golden", {str(DATA / "make_golden.py")!r})
      mg = importlib.util.module_from_spec(spec); spec.loader.exec_module(mg)
      golden = np.load({str(DATA / "golden.npz")!r})

      def golden_platformer():
        world, kwargs, controls = mg.cases()["platformer"]
        final = mg.run(world, kwargs, controls)
        for k in ("pos", "vel"):
          np.testing.assert_allclose(np.asarray(getattr(final, k)), golden["platformer/" + k],
                                     rtol=0, atol=1e-6)

      def one_world_as_batch():
        # A box in free fall: jc.step on one world and on a batch of two, in one program.
        solo = jc.World.create([[0.0, 2.0]], [[0.5, 0.5]], [1.0])
        cfg = jc.Config.for_world(solo, closing=0)
        both = jax.jit(lambda a, b: (jc.step(a, cfg), jc.step(b, cfg)))
        one, batch = solo, jc.stack([solo, solo])
        for t in range(14):
          one, batch = both(one, batch)
          for k in ("pos", "vel"):
            a, b = np.asarray(getattr(one, k)), np.asarray(getattr(batch, k))
            assert np.array_equal(a, b[0]) and np.array_equal(a, b[1]), (t, k, a, b)

      def cell_filling_up():
        # tests/test_broadphase.py's scene (issue 44 item 6): a cell of capacity 2 that a
        # third box drifts into; the step loop and the rollout, one answer and no bit.
        spec = jc.broadphase.GridSpec(origin=(0.0, 0.0), cell=1.0, shape=(6, 6), reach=0.1,
                                      cell_capacity=2, static_capacity=1, static_entries=4)
        cfg = jc.Config(gravity=False, friction=False, immovable=False, broadphase="grid",
                        grid=spec, neighbors=2, margin=0.2, depth=1, closing=0)
        w = jc.World.create([[2.3, 2.5], [2.7, 2.5], [3.05, 2.5]], [0.1, 0.1], 1.0,
                            vel=[[0.0, 0.0], [0.0, 0.0], [-1.5, 0.0]], gravity=(0.0, 0.0))
        final, traj = jc.rollout(w, cfg, 8, record=("status",))
        for t in range(8):
          w = jc.step(w, cfg)
          assert int(w.status) == int(traj.status[t]) == 0, (t, int(w.status), int(traj.status[t]))
          assert np.array_equal(np.asarray(w.pos), np.asarray(traj.pos[t])), t
        np.testing.assert_allclose(np.asarray(final.vel)[:, 0], [0.0, -0.75, -0.75], atol=1e-6)

      report = {{}}
      for check in (golden_platformer, one_world_as_batch, cell_filling_up):
        try:
          check()
          report[check.__name__] = "OK"
        except Exception:
          report[check.__name__] = traceback.format_exc()[-3000:]
      print("REPORT " + json.dumps(report))
  """)
  env = {**os.environ, "XLA_FLAGS": flags, "JAX_PLATFORMS": "cpu"}
  done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env,
                        timeout=600)
  line = next((l for l in done.stdout.splitlines() if l.startswith("REPORT ")), None)
  assert done.returncode == 0 and line is not None, done.stderr[-3000:]
  return json.loads(line[len("REPORT "):])


def test_same_answers_at_the_default_optimisation_level(default_level):
  """The demo's scene replayed at XLA's defaults: the bits users get match the stored
  ones."""
  assert default_level["golden_platformer"] == "OK", default_level["golden_platformer"]


def test_one_world_rounds_as_the_batch_at_the_default_optimisation_level(default_level):
  """Issue 44 item 2: `jc.step` on one world runs the kernel on a batch of two copies
  (`stepping.ONE_WORLD`), which were made with a broadcast; XLA saw through it and
  compiled another program, so at XLA's defaults a box falling freely differed from the
  same box in a batch (and under `vmap`, and in `jc.rollout`) by 1 ulp at step 12 (the
  y update contracted into a fused multiply-add: 1.752024531 against 1.752024651); the
  suite's -O0 codegen hides it. The copies are concatenated now: bit for bit, 14 steps."""
  assert default_level["one_world_as_batch"] == "OK", default_level["one_world_as_batch"]


def test_a_cell_filling_up_gives_one_answer_at_the_default_optimisation_level(default_level):
  """Issue 44 item 6 at XLA's defaults: `tests/test_broadphase.py`'s cell that fills up,
  stepped in a loop and rolled out, bit for bit and unflagged (before the grid's retry of
  a full cell, the step loop set CELL_OVERFLOW from step 2 and both lost the pair)."""
  assert default_level["cell_filling_up"] == "OK", default_level["cell_filling_up"]
