"""MkDocs hook: pages may link to repository files outside docs/ (`../benchmarks/...`).

The pages use links relative to docs/ so that they also work on GitHub. MkDocs only knows
the files inside docs/, and `mkdocs build --strict` fails on a link it cannot resolve. This
hook adds every repository file that a page links to with a `../` path to the site, under
`repo/`: a Markdown file (a results table) becomes a page of its own, outside the
navigation, and its own links are followed the same way; any other file (a plot) is
copied as is. A link to a file that does not exist is left alone, so `--strict` still
fails on it.
"""

import pathlib
import posixpath
import re

from mkdocs.structure.files import File, InclusionLevel

_LINK = re.compile(r"\]\(([^)\s#:]+)")


class _RepoFile(File):
  """A repository file outside docs/ that is copied verbatim."""

  def is_documentation_page(self) -> bool:
    return False

  def is_static_page(self) -> bool:
    return False


def on_files(files, config):
  docs = pathlib.Path(config.docs_dir).resolve()
  repo = docs.parent
  todo = [(page.relative_to(docs).as_posix(), page) for page in docs.rglob("*.md")]
  while todo:
    src_uri, page = todo.pop()
    for target in _LINK.findall(page.read_text(encoding="utf-8")):
      uri = posixpath.normpath(posixpath.join(posixpath.dirname(src_uri), target))
      path = (docs / uri).resolve()
      if not uri.startswith("../") or uri in files or not path.is_file():
        continue
      if repo not in path.parents or ".git" in path.relative_to(repo).parts:
        continue
      dest = "repo/" + path.relative_to(repo).as_posix()
      if path.suffix == ".md":
        dest = dest[:-len(".md")] + ("/index.html" if config.use_directory_urls else ".html")
        files.append(File(uri, str(docs), config.site_dir, config.use_directory_urls,
                          dest_uri=dest, inclusion=InclusionLevel.NOT_IN_NAV))
        todo.append((uri, path))
      else:
        files.append(_RepoFile(uri, str(docs), config.site_dir, config.use_directory_urls,
                               dest_uri=dest, inclusion=InclusionLevel.INCLUDED))
  return files
