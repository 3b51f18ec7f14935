"""Every page and figure in docs/ is linked from the docs index, docs/README.md."""

from __future__ import annotations

import re

from .conftest import REPO

DOCS = REPO / "docs"


def test_every_page_in_docs_is_linked_from_the_index():
    linked = set(re.findall(r"\]\(([^)#/]+)(?:#[^)]*)?\)", (DOCS / "README.md").read_text()))
    pages = {p.name for p in DOCS.iterdir() if p.is_file() and p.name != "README.md"}
    assert sorted(pages - linked) == []
