"""MkDocs hook: pages may link to repository files outside docs/ (`../benchmarks/...`).

The pages use links relative to docs/ so that they also work on GitHub. MkDocs only knows
the files inside docs/, and `mkdocs build --strict` fails on a link it cannot resolve. This
hook adds every repository file that some page links to with `../` to the site, copied as
is under `repo/` (a results table is served as its Markdown text, a plot as an image). A
link to a file that does not exist stays unresolved, so `--strict` still fails on it.
"""

import pathlib
import posixpath
import re

from mkdocs.structure.files import File, InclusionLevel

_LINK = re.compile(r"\]\((\.\./[^)\s#]+)")


class _RepoFile(File):
  """A repository file outside docs/, copied verbatim (never rendered as a page)."""

  def is_documentation_page(self) -> bool:
    return False

  def is_static_page(self) -> bool:
    return False


def on_files(files, config):
  docs = pathlib.Path(config.docs_dir).resolve()
  repo = docs.parent
  for page in docs.rglob("*.md"):
    rel_dir = page.parent.relative_to(docs).as_posix()
    for target in _LINK.findall(page.read_text(encoding="utf-8")):
      src_uri = posixpath.normpath(posixpath.join(rel_dir, target))
      path = (docs / src_uri).resolve()
      if not src_uri.startswith("../") or not path.is_file() or src_uri in files:
        continue
      if repo not in path.parents or ".git" in path.relative_to(repo).parts:
        continue
      files.append(_RepoFile(src_uri, str(docs), config.site_dir, config.use_directory_urls,
                             dest_uri="repo/" + path.relative_to(repo).as_posix(),
                             inclusion=InclusionLevel.INCLUDED))
  return files
