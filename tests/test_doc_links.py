"""Every relative link in README.md and docs/ reaches a file that exists, and every #anchor a heading
in it: the docs are read on GitHub and in editors, where a dead link is the first thing a reader hits."""

import re
from functools import cache
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
LINK = re.compile(r"!?\[[^\[\]]*\]\(([^)\s]+)\)")  # link text may wrap lines, but holds no bracket
FENCED = re.compile(r"```.*?```", re.S)
CODE = re.compile(FENCED.pattern + r"|`[^`\n]*`", re.S)


def _slug(heading: str) -> str:
    """GitHub's anchor for a heading: lower case, punctuation dropped, spaces to hyphens."""
    s = heading.strip().lower()
    s = re.sub(r"[^\w\- ]", "", s)
    return s.replace(" ", "-")


@cache  # a page is linked from many others
def _anchors(page: Path) -> set[str]:
    text = FENCED.sub("", page.read_text(encoding="utf-8"))  # a heading's `code` is part of its anchor
    return {_slug(m.group(1)) for m in re.finditer(r"^#{1,6}\s+(.+?)\s*#*\s*$", text, re.M)}


def _links(page: Path):
    # code is blanked but keeps its newlines, so the line numbers below are the file's
    text = CODE.sub(lambda c: "\n" * c.group(0).count("\n"), page.read_text(encoding="utf-8"))
    for m in LINK.finditer(text):
        target = m.group(1)
        if re.match(r"[a-z][a-z0-9+.-]*:", target):  # http:, https:, mailto: ...
            continue
        line = text.count("\n", 0, m.start(1)) + 1  # the target's line
        yield line, target


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.relative_to(ROOT).as_posix())
def test_relative_links_resolve(page: Path) -> None:
    dead = []
    for line, target in _links(page):
        path, _, anchor = target.partition("#")
        dest = (page.parent / path).resolve() if path else page
        if not dest.exists():
            dead.append(f"{page.name}:{line}: {target} (no such file)")
        elif anchor and dest.suffix == ".md" and anchor not in _anchors(dest):
            dead.append(f"{page.name}:{line}: {target} (no heading '#{anchor}' in {dest.name})")
    assert not dead, "dead links:\n" + "\n".join(dead)


def test_the_checker_sees_links() -> None:
    # guards the regexes: the README links to docs pages and to its figures
    targets = [t for _, t in _links(ROOT / "README.md")]
    assert any(t.startswith("docs/") and ".md" in t for t in targets)
    assert any(t.endswith(".png") for t in targets)
