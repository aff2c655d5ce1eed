"""A pytest plugin for `benchmarks/suite_time.py`: where the suite's time goes.

Loaded with `-p _suite_plugin` (this folder on `PYTHONPATH`) when `JAXCHAIN_SUITE_TIMING`
names a directory; on every pytest-xdist worker (they inherit both) it writes one JSON
line per test phase and per fixture set-up into `DIR/<pid>.jsonl`:

- a test's set-up, call and teardown: CPU seconds of this process
  (`time.process_time`), CPU seconds of the subprocesses it waited for
  (`RUSAGE_CHILDREN`), wall seconds, the XLA compiles it started (the count and
  seconds of `jax.monitoring`'s backend-compile event, which also times a program
  loaded from the persistent compilation cache: the loads are counted apart, as
  `cache_hits`, and not as compiles);
- a fixture's set-up (module- and session-scoped ones are paid once, by the first test
  that asks): the same figures, by fixture name and scope.

`DIR/sitecustomize.py` (written by suite_time.py, on the subprocesses' path) counts the
compiles of the tests' own Python subprocesses the same way, named by the test that
started them (`JAXCHAIN_SUITE_TEST`, set here while each test runs).
"""

from __future__ import annotations

import json
import os
import resource
import threading
import time

import pytest

BACKEND_COMPILE = "/jax/core/compile/backend_compile_duration"
CACHE_HIT = "/jax/compilation_cache/cache_hits"  # The suite's run cache (tests/conftest.py).
DIR = os.environ.get("JAXCHAIN_SUITE_TIMING")
_lock = threading.Lock()
_compiles = [0, 0.0, 0]  # Count and seconds, persistent-cache hits, this process, so far.


def _listen(event, duration, **kwargs):
  del kwargs
  if event == BACKEND_COMPILE:
    with _lock:
      _compiles[0] += 1
      _compiles[1] += duration


def _listen_event(event, **kwargs):
  del kwargs
  if event == CACHE_HIT:
    with _lock:
      _compiles[2] += 1


def _now():
  child = resource.getrusage(resource.RUSAGE_CHILDREN)
  return (time.process_time(), child.ru_utime + child.ru_stime, time.perf_counter(),
          _compiles[0], _compiles[1], _compiles[2])


def _delta(t0):
  t1 = _now()
  return dict(cpu=t1[0] - t0[0], child_cpu=t1[1] - t0[1], wall=t1[2] - t0[2],
              compiles=(t1[3] - t0[3]) - (t1[5] - t0[5]), compile_s=t1[4] - t0[4],
              cache_hits=t1[5] - t0[5])


_out = None


def _write(record):
  global _out
  if _out is None:
    _out = open(os.path.join(DIR, f"{os.getpid()}.jsonl"), "a", buffering=1)
  _out.write(json.dumps(record) + "\n")


def pytest_configure(config):
  del config
  if DIR:
    import jax
    jax.monitoring.register_event_duration_secs_listener(_listen)
    jax.monitoring.register_event_listener(_listen_event)


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_protocol(item, nextitem):
  del nextitem
  if not DIR:
    yield
    return
  os.environ["JAXCHAIN_SUITE_TEST"] = item.nodeid
  yield
  os.environ.pop("JAXCHAIN_SUITE_TEST", None)


def _phase(item, when):
  t0 = _now()
  outcome = yield
  if DIR:
    record = dict(kind="phase", when=when, nodeid=item.nodeid, module=item.path.name,
                  worker=os.environ.get("PYTEST_XDIST_WORKER", "main"),
                  failed=outcome.excinfo is not None, **_delta(t0))
    _write(record)


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_setup(item):
  yield from _phase(item, "setup")


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_call(item):
  yield from _phase(item, "call")


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_teardown(item, nextitem):
  del nextitem
  yield from _phase(item, "teardown")


@pytest.hookimpl(hookwrapper=True)
def pytest_fixture_setup(fixturedef, request):
  t0 = _now()
  yield
  if DIR:
    node = request.node
    path = getattr(node, "path", None)
    _write(dict(kind="fixture", name=fixturedef.argname, scope=fixturedef.scope,
                module=path.name if path is not None else "", nodeid=node.nodeid,
                **_delta(t0)))
