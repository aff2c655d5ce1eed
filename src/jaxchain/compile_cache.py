"""Compile once per machine: the command line's programs, kept on disk between runs.

A jaxchain program costs seconds before its first step: tracing the step into a JAX
program (about 2 s for the demo) and XLA compiling it (about 5-10 s). `jaxchain demo`
keeps both on disk, in a cache directory of the user's:

* XLA's executables in JAX's persistent compilation cache (`DIR/xla`, unless the user
  set `JAX_COMPILATION_CACHE_DIR`, which is then used as it is);
* the traced program, exported (`jax.export`) and pickled under a key naming
  everything it was traced from (`DIR/programs`): jaxchain's source, JAX's version, the
  platform, `XLA_FLAGS`, the arguments' shapes and dtypes, and the caller's `key` (the
  static configuration and every constant the program closes over).

So a second run on the same machine skips both and starts in well under a second. The
directory is `$JAXCHAIN_CACHE_DIR`, else `$XDG_CACHE_HOME/jaxchain`, else
`~/.cache/jaxchain`; `JAXCHAIN_CACHE=off` (or `jaxchain demo --no-cache`) turns the cache
off, and deleting the directory empties it. A cached program that cannot be read (a
damaged file, another JAX) is traced and compiled again, and replaced.

This is the command line's: the library itself never touches JAX's configuration.
`persistent` sets JAX's cache directory only for the duration of a `with` block.
"""

from __future__ import annotations

import contextlib
import dataclasses
import hashlib
import json
import os
import pathlib
import pickle
import tempfile
import time
from collections.abc import Callable, Hashable, Iterator

import jax
import jaxlib
from jax.experimental.compilation_cache import compilation_cache

_PACKAGE = pathlib.Path(__file__).resolve().parent
# Bump when what a cached program file holds changes.
_FORMAT = "jaxchain-program-1"


def directory() -> pathlib.Path | None:
  """The cache directory the environment names, or None when `JAXCHAIN_CACHE` is
  `off`, `0`, `no` or `false`."""
  if os.environ.get("JAXCHAIN_CACHE", "").strip().lower() in ("off", "0", "no", "false"):
    return None
  if os.environ.get("JAXCHAIN_CACHE_DIR"):
    return pathlib.Path(os.environ["JAXCHAIN_CACHE_DIR"]).expanduser()
  base = os.environ.get("XDG_CACHE_HOME") or pathlib.Path.home() / ".cache"
  return pathlib.Path(base) / "jaxchain"


@contextlib.contextmanager
def persistent(path: pathlib.Path | str | None) -> Iterator[None]:
  """JAX's persistent compilation cache in `path / "xla"` inside the block (every
  program, however short its compile), then JAX's settings as they were. Does nothing
  when `path` is None or the user set a cache directory of their own."""
  if path is None or jax.config.jax_compilation_cache_dir:
    yield
    return
  min_time = jax.config.jax_persistent_cache_min_compile_time_secs
  xla = pathlib.Path(path) / "xla"
  xla.mkdir(parents=True, exist_ok=True)
  compilation_cache.reset_cache()
  jax.config.update("jax_compilation_cache_dir", str(xla))
  jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
  try:
    yield
  finally:
    jax.config.update("jax_compilation_cache_dir", None)
    jax.config.update("jax_persistent_cache_min_compile_time_secs", min_time)
    compilation_cache.reset_cache()


@dataclasses.dataclass(frozen=True)
class Compiled:
  """A compiled program and where it came from.

  Attributes:
    fn: calls the program with the arguments' pytrees, returns its outputs' pytree.
    seconds: this run's time to have it (trace and compile, or load).
    source: "compiled" (traced and compiled, and saved when a cache is on), "cache"
      (loaded from the cache) or "off" (no cache).
    first_s: seconds the first trace and compile took on this machine (this run's when
      it compiled).
    note: why a cached program was not used, when one was found and could not be.
  """

  fn: Callable
  seconds: float
  source: str
  first_s: float
  note: str = ""


def _source_digest() -> str:
  """A digest of jaxchain's Python source: a cached program is only good for it."""
  h = hashlib.sha256()
  for file in sorted(_PACKAGE.rglob("*.py")):
    h.update(str(file.relative_to(_PACKAGE)).encode())
    h.update(file.read_bytes())
  return h.hexdigest()


def _program_key(key: Hashable, in_tree, avals) -> str:
  device = jax.devices()[0]
  parts = (_FORMAT, _source_digest(), jax.__version__, jaxlib.__version__, device.platform,
           device.device_kind, os.environ.get("XLA_FLAGS", ""), bool(jax.config.jax_enable_x64),
           repr(key), str(in_tree), [str(a) for a in avals])
  return hashlib.sha256(repr(parts).encode()).hexdigest()


def compile(fn: Callable, args: tuple, key: Hashable, path: pathlib.Path | str | None) -> Compiled:  # noqa: A001
  """`jax.jit(fn)` compiled for `args`, through the cache in `path` (None: no cache).

  Args:
    fn: the program, a function of the pytrees `args`.
    args: example arguments (their shapes and dtypes are part of the key).
    key: everything else the program is traced from: the static configuration and every
      constant `fn` closes over (a repr that names them all). Two programs with the same
      key, source and argument shapes must be the same program.
    path: the cache directory, or None.
  """
  t0 = time.perf_counter()
  flat, in_tree = jax.tree.flatten(args)
  if path is None:
    compiled = (fn if hasattr(fn, "lower") else jax.jit(fn)).lower(*args).compile()
    seconds = time.perf_counter() - t0
    return Compiled(compiled, seconds, "off", seconds)
  avals = [jax.typeof(x) for x in flat]
  file = pathlib.Path(path) / "programs" / f"{_program_key(key, in_tree, avals)}.pkl"
  note = ""
  if file.exists():
    try:
      with open(file, "rb") as f:
        saved = pickle.load(f)
      run = jax.jit(saved["exported"].call).lower(*flat).compile()
      out_tree = saved["out_tree"]
      return Compiled(lambda *a: jax.tree.unflatten(out_tree, run(*jax.tree.leaves(a))),
                      time.perf_counter() - t0, "cache", saved["first_s"])
    except Exception as e:  # noqa: BLE001 - any failure to load means: compile again.
      note = f"the cached program could not be used ({type(e).__name__}: {e}); compiled again"
  trees = []

  def flat_fn(*leaves):
    out, out_tree = jax.tree.flatten(fn(*jax.tree.unflatten(in_tree, leaves)))
    trees.append(out_tree)
    return out

  exported = jax.export.export(jax.jit(flat_fn))(*flat)
  run = jax.jit(exported.call).lower(*flat).compile()
  seconds = time.perf_counter() - t0
  out_tree = trees[0]
  # `_get_vjp` is a closure (not picklable) that only reverse-mode differentiation of the
  # exported function needs; the command line never differentiates it.
  saved = dict(exported=dataclasses.replace(exported, _get_vjp=None), out_tree=out_tree,
               first_s=seconds)
  file.parent.mkdir(parents=True, exist_ok=True)
  with tempfile.NamedTemporaryFile(dir=file.parent, delete=False, suffix=".tmp") as f:
    pickle.dump(saved, f)
  os.replace(f.name, file)  # Atomic: a concurrent run reads the old file or the new one.
  (file.parent / f"{file.stem}.json").write_text(json.dumps(
      dict(first_s=seconds, key=repr(key), created=time.strftime("%Y-%m-%d %H:%M:%S"))))
  return Compiled(lambda *a: jax.tree.unflatten(out_tree, run(*jax.tree.leaves(a))), seconds,
                  "compiled", seconds, note)
