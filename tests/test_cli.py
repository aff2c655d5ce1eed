"""The demo: it runs, reports its figures, and the row ends against the wall."""

import collections
import contextlib
import doctest
import importlib
import os
import re
import subprocess
import sys

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxchain
from jaxchain import cli, compile_cache, status


def test_demo_figures():
  # 420 steps in chunks of 160: two calls of 160, then one of the same program, masked to 100.
  figures = cli.demo(batch=3, steps=420, chunk=160, seed=1, depth=None, iterations=1,
                     friction=0.3, push=20.0, progress=False)
  assert figures["chunks"] == [160, 160, 100]
  # The same answers as one rollout of 420 steps, to the bit.
  whole = cli.demo(batch=3, steps=420, chunk=420, seed=1, depth=None, iterations=1,
                   friction=0.3, push=20.0, progress=False)
  assert whole["chunks"] == [420]
  for name in ("pos", "vel", "status", "crushed", "touching"):
    np.testing.assert_array_equal(getattr(figures["final_world"], name),
                                  getattr(whole["final_world"], name), err_msg=name)
  assert figures["finite"]
  assert figures["worlds_at_wall"] == 3
  assert figures["wall_intrusion"] < 1e-4
  assert figures["max_penetration"] < 1e-4
  np.testing.assert_allclose(figures["row_moved_mean"], 2.0, atol=1e-3)  # Gap to the wall.
  assert figures["world_steps_per_s"] > 0 and figures["compile_s"] > 0
  assert figures["status_messages"] == {}


# jax.monitoring's event for one XLA compile; its `fun_name` is "jit(<function name>)".
BACKEND_COMPILE = "/jax/core/compile/backend_compile_duration"


@contextlib.contextmanager
def compiles():
  """Counts the XLA compiles inside the block by function name: `{"jit(name)": count}`."""
  names = collections.Counter()

  def listen(event, duration, **kwargs):
    del duration
    if event == BACKEND_COMPILE:
      names[kwargs.get("fun_name")] += 1

  jax.monitoring.register_event_duration_secs_listener(listen)
  try:
    yield names
  finally:
    jax.monitoring.unregister_event_duration_listener(listen)


def _steppers(names) -> list[str]:
  """The compiled functions that could hold a step: the demo's chunk, a rollout, a step, a
  lambda (before issue 31 the demo compiled `jax.jit(jax.vmap(lambda ...: rollout(...)))`)."""
  return sorted(n for n in names if any(w in n for w in ("chunk", "rollout", "step", "<lambda>")))


def test_demo_compiles_one_program_for_any_steps(capsys):
  """Issue 31: 20 steps in chunks of 8 ran two programs (8 and 4 steps); now one, whose last
  call masks 4 steps, with the answers of 20 steps taken one by one."""
  # The smallest step to compile (depth 0, no converging loops, no friction), 2 worlds.
  with compiles() as names:
    figures = cli.demo(batch=2, steps=20, chunk=8, seed=1, depth=0, iterations=1,
                       friction=0.0, push=20.0, progress=False, converge=False)
  assert figures["chunks"] == [8, 8, 4]
  assert names["jit(demo_chunk)"] == 1 and _steppers(names) == ["jit(demo_chunk)"], names
  assert "s (one program: 3 calls of 8 steps, the last masked to 4)\n" in capsys.readouterr().out
  # The same batch stepped 20 times, one jitted step a call (as `cli.demo` builds it).
  rng = np.random.default_rng(1)
  layouts = [jaxchain.scenes.platformer(rng) for _ in range(2)]
  worlds = jaxchain.stack([p.scene.world(friction=0.0) for p in layouts])
  config = jaxchain.Config.for_world(worlds, iterations=1, converge=False, depth=0)
  push = jnp.zeros(worlds.pos.shape).at[:, layouts[0].player, 0].set(20.0)
  step = jax.jit(jax.vmap(jaxchain.make_step(config)))
  for _ in range(20):
    worlds = step(worlds, push)
  final = figures["final_world"]
  for name in ("pos", "vel", "status", "crushed", "touching", "sensed", "active"):
    np.testing.assert_array_equal(getattr(final, name), getattr(worlds, name), err_msg=name)
  assert not np.array_equal(final.pos, step(worlds, push).pos)  # A 21st step would show.


def test_console_script_runs_and_rejects_bad_flags():
  env = {**os.environ, "JAX_PLATFORMS": "cpu"}
  # The smallest step to compile (the physics of the default demo is test_demo_figures').
  ok = subprocess.run([sys.executable, "-m", "jaxchain.cli", "demo", "--batch", "2", "--steps",
                       "20", "--chunk", "10", "--no-progress", "--depth", "0", "--no-converge",
                       "--friction", "0"], capture_output=True, text=True, env=env, timeout=300)
  assert ok.returncode == 0, ok.stderr
  for line in ("compile time", "world-steps/s", "body-steps/s", "final max penetration",
               "row intrusion into wall"):
    assert line in ok.stdout
  bad = subprocess.run([sys.executable, "-m", "jaxchain.cli", "demo", "--batch", "0"],
                       capture_output=True, text=True, env=env, timeout=300)
  assert bad.returncode == 2 and "must be a positive integer" in bad.stderr


@pytest.mark.parametrize("name", ["world", "config", "stepping", "status", "reference", "cli"])
def test_docstring_examples(name):
  module = importlib.import_module(f"jaxchain.{name}")
  result = doctest.testmod(module, extraglobs={"jc": jaxchain}, optionflags=doctest.ELLIPSIS)
  assert result.attempted > 0 and result.failed == 0


# How `jaxchain demo --help` states each flag's default (issue 31: --iterations did not).
HELP_DEFAULTS = {
    "--batch": "1024", "--steps": "600", "--chunk": "50", "--seed": "0",
    "--depth": "from the scene", "--iterations": "1", "--friction": "0.3", "--push": "20",
    "--converge": "on", "--level": "none", "--gif": "none", "--gif-worlds": "4",
    "--gif-size": "96x160", "--gif-every": "2", "--gif-fps": "30", "--no-progress": "off",
    "--no-cache": "off",
}


def test_help_states_every_default(capsys):
  with pytest.raises(SystemExit) as exit_info:
    cli.main(["demo", "--help"])
  assert exit_info.value.code == 0
  options = capsys.readouterr().out.split("\noptions:\n")[1]
  # One entry per flag: its line and the indented lines below, whitespace collapsed.
  entries = {}
  for entry in re.split(r"\n(?=  -)", options.strip("\n")):
    flag = entry.split()[0].rstrip(",")
    entries[flag] = " ".join(entry.split())
  assert set(entries) == set(HELP_DEFAULTS) | {"-h"}  # Every flag is in the table.
  for flag, shown in HELP_DEFAULTS.items():
    assert re.search(rf"\(default: {re.escape(shown)}\b", entries[flag]), entries[flag]
  # What the help says is the default is the default.
  defaults = cli.build_parser()[0].parse_args(["demo"])
  for flag, shown in HELP_DEFAULTS.items():
    value = getattr(defaults, flag[2:].replace("-", "_"))
    if isinstance(value, bool):
      assert shown == ("on" if value else "off"), flag
    elif isinstance(value, (int, float)):
      assert float(shown) == value, flag
    elif isinstance(value, tuple):
      assert shown == "x".join(map(str, value)), flag
    else:
      assert value is None and flag in ("--depth", "--level", "--gif"), flag


@pytest.mark.parametrize("flags, message", [
    (["--depth", "-1"], "argument --depth: must be an integer >= 0, got -1"),
    (["--depth", "two"], "argument --depth: expected an integer, got 'two'"),
    (["--friction", "nan"], "argument --friction: must be a finite number, got nan"),
    (["--friction", "-1"], "argument --friction: must be >= 0, got -1"),
    (["--friction", "inf"], "argument --friction: must be a finite number"),
    (["--push", "nan"], "argument --push: must be a finite number, got nan"),
    (["--push", "inf"], "argument --push: must be a finite number, got inf"),
    (["--push=-1e999"], "argument --push: must be a finite number, got -1e999"),
    (["--batch", "0"], "argument --batch: must be a positive integer, got 0"),
    (["--steps", "-3"], "argument --steps: must be a positive integer, got -3"),
    (["--iterations", "0"], "argument --iterations: must be a positive integer"),
    (["--seed", "-1"], "argument --seed: must be an integer >= 0, got -1"),
    (["--steps", "0"], "argument --steps: must be a positive integer, got 0"),
    (["--chunk", "0"], "argument --chunk: must be a positive integer, got 0"),
])
def test_bad_flags_are_argparse_errors(flags, message, capsys):
  with pytest.raises(SystemExit) as exit_info:
    cli.main(["demo", "--no-progress", *flags])
  assert exit_info.value.code == 2
  err = capsys.readouterr().err
  assert message in err and "Traceback" not in err


def test_demo_reports_every_status_bit_and_never_claims_all_is_well(capsys):
  # A push of 1e30 moves the player across the room in one step: FAST_BODY in both worlds.
  figures = cli.demo(batch=2, steps=4, chunk=2, seed=0, depth=None, iterations=1,
                     friction=0.3, push=1e30, progress=False)
  out = capsys.readouterr().out
  fast = status.MESSAGES[status.FAST_BODY]
  assert figures["status_messages"].get(fast) == 2
  assert f"status FAST_BODY in 2/2 worlds: {fast}" in out
  assert out.count(fast) == 1  # Each message once, with its count of worlds.
  for text in figures["status_messages"]:
    assert text in out
  assert "status: ok" not in out and "all states finite     True" not in out
  if status.MESSAGES[status.NON_FINITE] in figures["status_messages"]:
    assert not figures["finite"] and "all states finite     False" in out


@pytest.mark.parametrize("steps, chunk, lengths", [
    (600, 50, [50] * 12), (60, 50, [50, 10]), (1, 50, [1]), (7, 7, [7]), (7, 1, [1] * 7),
    (10, 4, [4, 4, 2]), (49, 50, [49]), (101, 50, [50, 50, 1]),
])
def test_chunk_lengths_cover_any_step_count(steps, chunk, lengths):
  assert cli.chunk_lengths(steps, chunk) == lengths


@pytest.mark.parametrize("steps, chunk", [(0, 50), (-1, 50), (10, 0)])
def test_chunk_lengths_reject_nonpositive(steps, chunk):
  with pytest.raises(ValueError, match="must be at least 1"):
    cli.chunk_lengths(steps, chunk)
  with pytest.raises(ValueError, match="must be at least 1"):  # Before anything compiles.
    cli.demo(batch=1, steps=steps, chunk=chunk, seed=0, depth=None, iterations=1,
             friction=0.3, push=20.0, progress=False)


def test_status_summary_counts_worlds_per_message():
  world = jaxchain.World.create([[0.0, 0.0]], [0.5, 0.5], 1.0)
  batch = jaxchain.stack([world] * 3)
  codes = np.array([status.FAST_BODY, status.FAST_BODY | status.NON_FINITE, 0], np.int32)
  summary = cli.status_summary(batch.replace(status=codes))
  assert summary == {status.MESSAGES[status.NON_FINITE]: 1, status.MESSAGES[status.FAST_BODY]: 2}
  assert cli.status_summary(batch) == {}


# --- `jaxchain demo --gif` -----------------------------------------------------------------


def _gif_frames(path):
  from PIL import Image
  with Image.open(path) as im:
    frames, durations = [], []
    for k in range(im.n_frames):
      im.seek(k)
      frames.append(np.asarray(im.convert("RGB")))
      durations.append(im.info["duration"])
  return np.stack(frames), durations


def _has_colour(frame, rgb, tol=8):
  return bool(np.any(np.all(np.abs(frame.astype(int) - rgb) <= tol, axis=-1)))


def test_demo_gif_tiles_the_first_worlds(tmp_path, capsys, monkeypatch):
  path = tmp_path / "demo.gif"
  # A cache directory named, and --no-cache: nothing is kept there.
  monkeypatch.delenv("JAXCHAIN_CACHE", raising=False)
  monkeypatch.setenv("JAXCHAIN_CACHE_DIR", str(tmp_path / "cache"))
  # Depth 0, no converging loops, no friction: the smallest compile (the GIF is tested here).
  assert cli.main(["demo", "--batch", "3", "--steps", "20", "--chunk", "10", "--no-progress",
                   "--depth", "0", "--no-converge", "--friction", "0", "--gif", str(path),
                   "--gif-worlds", "2", "--gif-size", "48x80", "--gif-every", "5",
                   "--no-cache"]) == 0
  out = capsys.readouterr().out
  assert "compile cache         off\n" in out and not (tmp_path / "cache").exists()
  assert "row pushed" in out and f"gif                   {path}: 2 worlds, 5 frames" in out
  frames, durations = _gif_frames(path)
  assert frames.shape == (5, 48, 2 * 80 + cli.GIF_BORDER, 3)  # The start and steps 5 to 20.
  assert durations == [30, 40, 30, 30, 40]  # 30 fps in whole centiseconds.
  palette = jaxchain.drawing.PALETTE
  for tile in (frames[:, :, :80], frames[:, :, -80:]):
    assert _has_colour(tile[0], palette.player) and _has_colour(tile[0], palette.immovable)
    assert _has_colour(tile[0], palette.movable)
  assert np.all(frames[:, :, 80:80 + cli.GIF_BORDER] == 0)  # The border between tiles.
  assert not np.array_equal(frames[0], frames[-1])  # The player moved.


def test_level_demo_gif(tmp_path, capsys):
  path = tmp_path / "level.gif"
  # Chunks of 4, 4 and 2 steps, one program: the masked last call records its 2 frames.
  with compiles() as names:
    assert cli.main(["demo", "--level", "sokoban1", "--batch", "1", "--steps", "10", "--chunk",
                     "4", "--no-progress", "--depth", "0", "--no-converge", "--friction", "0",
                     "--gif", str(path), "--gif-every", "4", "--gif-size", "32x32",
                     "--gif-fps", "25"]) == 0
  assert _steppers(names) == ["jit(demo_chunk)"] and names["jit(demo_chunk)"] == 1, names
  assert "gif " in capsys.readouterr().out
  frames, durations = _gif_frames(path)
  assert frames.shape[1:] == (32, 32, 3) and len(frames) <= 4  # Steps 0, 4, 8, 10.
  assert sum(durations) == 4 * 40  # Frames merged by Pillow keep their time.
  palette = jaxchain.drawing.PALETTE
  assert _has_colour(frames[0], palette.player) and _has_colour(frames[0], palette.movable)


@pytest.mark.parametrize("flags, message", [
    (["--gif-size", "0x10"], "argument --gif-size: both sides must be positive, got '0x10'"),
    (["--gif-size", "big"], "argument --gif-size: expected HxW such as 96x160, got 'big'"),
    (["--gif-fps", "60"], "argument --gif-fps: must be in (0, 50], got 60"),
    (["--gif-worlds", "0"], "argument --gif-worlds: must be a positive integer, got 0"),
    (["--gif", "no/such/dir/x.gif"], "--gif: no such directory: 'no/such/dir'"),
])
def test_bad_gif_flags_are_argparse_errors(flags, message, capsys):
  with pytest.raises(SystemExit) as exit_info:
    cli.main(["demo", "--no-progress", *flags])
  assert exit_info.value.code == 2
  err = capsys.readouterr().err
  assert message in err and "Traceback" not in err


def test_tile_lays_clips_out_in_a_grid():
  clips = np.stack([np.full((2, 3, 4, 3), 10 * (i + 1), np.uint8) for i in range(3)])
  grid = cli.tile(clips, border=1)
  assert grid.shape == (2, 2 * 3 + 1, 2 * 4 + 1, 3)  # 2 columns, 2 rows, the last cell empty.
  assert grid[0, 0, 0, 0] == 10 and grid[0, 0, -1, 0] == 20 and grid[0, -1, 0, 0] == 30
  assert grid[0, -1, -1, 0] == 0 and grid[0, 3, 0, 0] == 0


# --- Compile once per machine (issue 41 item 2) -------------------------------------------
# The suite runs with `JAXCHAIN_CACHE=off` (tests/conftest.py); these tests name a cache of
# their own. The smallest step to compile, as above.
SMALL = dict(batch=2, steps=12, chunk=6, seed=1, depth=0, iterations=1, friction=0.0,
             push=20.0, progress=False, converge=False)


def _same_worlds(a, b):
  for name in ("pos", "vel", "status", "crushed", "touching", "sensed"):
    np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)


@pytest.fixture
def no_xla_cache_of_the_suite():
  """JAX as a user has it who set no cache directory: the suite's run sets one for every
  process (tests/conftest.py), and `compile_cache.persistent` leaves a user's alone."""
  from jax.experimental.compilation_cache import compilation_cache
  saved = jax.config.jax_compilation_cache_dir
  jax.config.update("jax_compilation_cache_dir", None)
  compilation_cache.reset_cache()
  yield
  jax.config.update("jax_compilation_cache_dir", saved)
  compilation_cache.reset_cache()


def test_a_second_run_loads_the_program_from_the_cache(tmp_path, capsys, no_xla_cache_of_the_suite):
  plain = cli.demo(**SMALL)
  assert plain["compile_source"] == "off"
  with compile_cache.persistent(tmp_path):
    first = cli.demo(**SMALL, cache=tmp_path)
    second = cli.demo(**SMALL, cache=tmp_path)
    # Another program (the push is data, the depth is not): compiled, not loaded.
    other = cli.demo(**{**SMALL, "depth": 1}, cache=tmp_path)
  assert jax.config.jax_compilation_cache_dir is None  # JAX's settings as they were.
  assert [first["compile_source"], second["compile_source"], other["compile_source"]] == [
      "compiled", "cache", "compiled"]
  assert second["first_compile_s"] == first["compile_s"]
  for figures in (first, second):  # The cached program gives the same answers, to the bit.
    _same_worlds(figures["final_world"], plain["final_world"])
  assert not np.array_equal(other["final_world"].pos, plain["final_world"].pos)
  assert len(list((tmp_path / "programs").glob("*.pkl"))) == 2
  assert any((tmp_path / "xla").iterdir())  # XLA's executables, in JAX's cache.
  out = capsys.readouterr().out
  assert f"compile cache         saved to {tmp_path}: the next run loads it" in out
  assert (f"compile cache         loaded from {tmp_path}; the first compile on this machine "
          f"took {first['compile_s']:.2f} s") in out


def test_the_level_demo_keys_its_program_by_what_the_policy_closes_over(tmp_path):
  # The push and the player are constants of the level demo's policy, not data: a run with
  # another push must not load the program of the first.
  level = dict(SMALL, batch=1, level="sokoban1")
  first = cli.demo(**level, cache=tmp_path)
  pushed = cli.demo(**{**level, "push": 5.0}, cache=tmp_path)
  again = cli.demo(**{**level, "push": 5.0}, cache=tmp_path)
  assert [first["compile_source"], pushed["compile_source"], again["compile_source"]] == [
      "compiled", "compiled", "cache"]
  _same_worlds(again["final_world"], pushed["final_world"])
  assert not np.array_equal(first["final_world"].pos, pushed["final_world"].pos)


def test_a_damaged_cached_program_is_compiled_again(tmp_path, capsys):
  cli.demo(**SMALL, cache=tmp_path)
  (saved,) = (tmp_path / "programs").glob("*.pkl")
  saved.write_bytes(b"not a pickle")
  again = cli.demo(**SMALL, cache=tmp_path)
  assert again["compile_source"] == "compiled"
  assert "compile cache note    the cached program could not be used" in capsys.readouterr().out
  assert cli.demo(**SMALL, cache=tmp_path)["compile_source"] == "cache"  # Replaced.


@pytest.mark.parametrize("env, wanted", [
    ({"JAXCHAIN_CACHE_DIR": "/x/y"}, "/x/y"),
    ({"XDG_CACHE_HOME": "/c"}, "/c/jaxchain"),
    ({"HOME": "/h"}, "/h/.cache/jaxchain"),
    ({"JAXCHAIN_CACHE": "off", "JAXCHAIN_CACHE_DIR": "/x/y"}, None),
    ({"JAXCHAIN_CACHE": "0"}, None),
])
def test_the_cache_directory_comes_from_the_environment(env, wanted, monkeypatch):
  for name in ("JAXCHAIN_CACHE", "JAXCHAIN_CACHE_DIR", "XDG_CACHE_HOME"):
    monkeypatch.delenv(name, raising=False)
  for name, value in env.items():
    monkeypatch.setenv(name, value)
  got = compile_cache.directory()
  assert (None if got is None else str(got)) == wanted


def test_the_console_script_compiles_once_per_machine(tmp_path):
  # As a user runs it, twice: the second process loads the program and says so.
  env = {**os.environ, "JAX_PLATFORMS": "cpu", "JAXCHAIN_CACHE_DIR": str(tmp_path)}
  for name in ("JAXCHAIN_CACHE", "JAX_COMPILATION_CACHE_DIR",  # The suite's (conftest).
               "JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS"):
    env.pop(name, None)
  argv = [sys.executable, "-m", "jaxchain.cli", "demo", "--batch", "2", "--steps", "6",
          "--chunk", "6", "--no-progress", "--depth", "0", "--no-converge", "--friction", "0"]
  runs = [subprocess.run(argv, capture_output=True, text=True, env=env, timeout=300)
          for _ in range(2)]
  assert all(r.returncode == 0 for r in runs), runs[-1].stderr
  assert "compile cache         saved to" in runs[0].stdout
  assert "compile cache         loaded from" in runs[1].stdout
  # Everything after the timings is the same in both runs.
  tail = lambda r: r.stdout.split("final max penetration")[1]
  assert tail(runs[0]) == tail(runs[1])
