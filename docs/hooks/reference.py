"""MkDocs hook: the reference pages written from the code, and the repository's own READMEs, at build time.

Generated (never committed, so they cannot drift): ``reference/cli.md`` from
the argparse parser, ``reference/config.md`` and ``reference/driver-keys.md``
from the typed tables of the schema. Included as they are in the repository:
the driver folders' READMEs, ``PROTOCOL.md`` and ``driver.toml`` files, and
``bench/README.md``, at the same relative paths so their links between each
other hold; a link of theirs to anything else in the repository becomes the
file's path.
"""

from __future__ import annotations

import posixpath
import re
import sys
from pathlib import Path

from cli_page import cli_reference
from config_page import config_reference, driver_keys_reference

#: Files of the repository shown in the site at the same path, by glob.
INCLUDED_GLOBS = (
    "drivers/*/README.md",
    "drivers/*/PROTOCOL.md",
    "drivers/*/driver.toml",
    "drivers/*/firmware/README.md",
    "bench/README.md",
)

#: A Markdown inline link or image: ``[text](target)``.
LINK = re.compile(r"(!?)\[([^\]]*)\]\(([^)\s]+)\)")


def generated_pages() -> dict[str, str]:
    """Path in the site -> Markdown of every page written from the code."""
    from hilident.cli.main import build_parser

    return {
        "reference/cli.md": cli_reference(build_parser()),
        "reference/config.md": config_reference(),
        "reference/driver-keys.md": driver_keys_reference(),
    }


def included_files(root: Path) -> list[str]:
    """The repository paths of :data:`INCLUDED_GLOBS` under ``root``, sorted."""
    return sorted(str(path.relative_to(root).as_posix()) for pattern in INCLUDED_GLOBS for path in root.glob(pattern))


def on_config(config):
    """Put this checkout's ``src/`` first on the import path: the pages are written from the code being built."""
    source = str(repository_root(config) / "src")
    if source not in sys.path:
        sys.path.insert(0, source)
    return config


def on_files(files, config):
    """Add the generated pages and the included repository files to the site."""
    from mkdocs.structure.files import File

    root = repository_root(config)
    for uri, text in generated_pages().items():
        files.append(File.generated(config, uri, content=text))
    for uri in included_files(root):
        files.append(File.generated(config, uri, abs_src_path=str(root / uri)))
    return files


def on_page_markdown(markdown, page, config, files):
    """In an included README, a link to a repository file outside the site becomes that file's path."""
    uri = page.file.src_uri
    root = repository_root(config)
    if uri not in included_files(root):
        return markdown
    shown = set(included_files(root))
    return LINK.sub(lambda match: link_in_site(match, uri, shown), markdown)


def link_in_site(match: re.Match, page_uri: str, shown: set[str]) -> str:
    """A link of the included page ``page_uri`` as it works in the site."""
    image, text, target = match.groups()
    if image or re.match(r"[a-z]+:|#|/", target):
        return match.group(0)
    path, _, anchor = target.partition("#")
    repository_path = posixpath.normpath(posixpath.join(posixpath.dirname(page_uri), path))
    if repository_path in shown:
        return match.group(0)
    if repository_path.startswith("docs/"):
        relative = posixpath.relpath(repository_path.removeprefix("docs/"), posixpath.dirname(page_uri))
        return f"[{text}]({relative}{'#' + anchor if anchor else ''})"
    return f"{text} (`{repository_path}`)"


def repository_root(config) -> Path:
    """The folder holding ``mkdocs.yml``: the repository's root."""
    return Path(config.config_file_path).resolve().parent
