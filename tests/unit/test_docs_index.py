"""Every page in docs/ is linked from the docs index, docs/README.md (figures may be shown by the page
that uses them instead)."""

from __future__ import annotations

import re

from tests.conftest import REPO

DOCS = REPO / "docs"


def test_every_page_in_docs_is_linked_from_the_index():
    linked = set(re.findall(r"\]\(([^)#/]+)(?:#[^)]*)?\)", (DOCS / "README.md").read_text()))
    pages = {p.name for p in DOCS.glob("*.md") if p.name != "README.md"}
    assert sorted(pages - linked) == []
