"""The docs site builds with `mkdocs build --strict`: a broken link, a missing anchor or a bad
mkdocstrings reference (`::: jaxchain.name` that does not resolve) fails the suite."""

import os
import pathlib
import subprocess
import sys

ROOT = pathlib.Path(__file__).resolve().parents[1]


def test_mkdocs_build_strict(tmp_path):
  env = dict(os.environ, NO_MKDOCS_2_WARNING="1")
  out = subprocess.run(
      [sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(tmp_path / "site")],
      cwd=ROOT, capture_output=True, text=True, timeout=300, env=env)
  assert out.returncode == 0, out.stdout + out.stderr
  site = tmp_path / "site"
  for page in ("index.html", "physics/index.html", "api/index.html"):
    assert (site / page).is_file(), page
  api = (site / "api" / "index.html").read_text()
  assert "jaxchain.World" in api and "jaxchain.rollout" in api  # mkdocstrings rendered them
  # docs/hooks.py: repository files the pages link to with `../` are in the site too.
  assert (site / "repo" / "benchmarks" / "results" / "scaling.png").is_file()
  assert (site / "repo" / "benchmarks" / "results" / "scaling" / "index.html").is_file()
