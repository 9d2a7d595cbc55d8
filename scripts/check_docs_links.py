"""Check that every internal link of the built documentation resolves.

Usage: ``python scripts/check_docs_links.py docs/_build/html``

Every ``href`` and ``src`` of every HTML page that is not an external URL
(``http:``, ``https:``, ``mailto:``, ...) must name an existing file of the
build, and a ``#fragment`` must name an ``id`` of the page it points to.
Prints one line per broken link and exits 1 when there is any.
"""

from __future__ import annotations

import sys
from html.parser import HTMLParser
from pathlib import Path
from urllib.parse import unquote, urlsplit


class _Links(HTMLParser):
    """The links (``href``, ``src``) and the ``id`` values of one page."""

    def __init__(self) -> None:
        super().__init__()
        self.links: list[str] = []
        self.ids: set[str] = set()

    def handle_starttag(self, tag, attrs):
        for name, value in attrs:
            if value is None:
                continue
            if name in ("href", "src"):
                self.links.append(value)
            elif name == "id" or (name == "name" and tag == "a"):
                self.ids.add(value)


def _parsed(path: Path, cache: dict) -> _Links:
    if path not in cache:
        parser = _Links()
        parser.feed(path.read_text(encoding="utf-8", errors="replace"))
        cache[path] = parser
    return cache[path]


def broken_links(root: Path) -> list[str]:
    """``"page: link"`` of every internal link under ``root`` that does not resolve."""
    cache: dict = {}
    broken = []
    for page in sorted(root.rglob("*.html")):
        if "_static" in page.relative_to(root).parts:
            continue  # the theme's template fragments, not pages
        for link in _parsed(page, cache).links:
            parts = urlsplit(link)
            if parts.scheme or parts.netloc or link.startswith(("javascript:", "data:")):
                continue  # external, not this check's
            target = page if not parts.path else (page.parent / unquote(parts.path)).resolve()
            if target.is_dir():
                target = target / "index.html"
            if not target.is_file():
                broken.append(f"{page.relative_to(root)}: {link} (no such file)")
            elif parts.fragment and target.suffix == ".html" and unquote(parts.fragment) not in _parsed(target, cache).ids:
                broken.append(f"{page.relative_to(root)}: {link} (no such anchor)")
    return broken


def main(argv: list[str]) -> int:
    root = Path(argv[0] if argv else "docs/_build/html")
    if not (root / "index.html").is_file():
        print(f"{root}: no index.html; build the documentation first (bash scripts/docs.sh)", file=sys.stderr)
        return 2
    broken = broken_links(root)
    for line in broken:
        print(line)
    pages = sum(1 for page in root.rglob("*.html") if "_static" not in page.relative_to(root).parts)
    print(f"links: {len(broken)} broken internal links in {pages} pages")
    return 1 if broken else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
