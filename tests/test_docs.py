"""The user docs: every relative link and anchor resolves, the README stays short, and the docs and the
package say what is true now (no session or issue journal; nothing in the package points into the dated
history)."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
HISTORY = ROOT / "docs" / "history"
USER_DOCS = sorted(
    [ROOT / "README.md", ROOT / "benchmarks" / "README.md", *(ROOT / "docs").rglob("*.md")],
    key=str,
)
USER_DOCS = [p for p in USER_DOCS if HISTORY not in p.parents]
LINK = re.compile(r"!?\[[^\]]*\]\(([^)\s]+)\)")
FENCE = re.compile(r"^```.*?^```", re.MULTILINE | re.DOTALL)


def slug(heading: str) -> str:
    """GitHub's anchor for a heading: lower case, punctuation dropped, spaces to hyphens."""
    text = re.sub(r"[`*_]", "", heading.strip().lower())
    text = re.sub(r"[^\w\- ]", "", text)
    return text.replace(" ", "-")


def anchors(path: Path) -> set[str]:
    text = FENCE.sub("", path.read_text(encoding="utf-8"))
    return {slug(m.group(1)) for m in re.finditer(r"^#+\s+(.+)$", text, re.MULTILINE)}


def links(path: Path) -> list[str]:
    text = FENCE.sub("", path.read_text(encoding="utf-8"))
    text = re.sub(r"<!--.*?-->", "", text, flags=re.DOTALL)
    return LINK.findall(text)


@pytest.mark.parametrize("doc", USER_DOCS, ids=lambda p: str(p.relative_to(ROOT)))
def test_relative_links_resolve(doc: Path) -> None:
    broken = []
    for target in links(doc):
        if re.match(r"^[a-z]+:", target):  # http:, https:, mailto:
            continue
        file_part, _, anchor = target.partition("#")
        resolved = (doc.parent / file_part).resolve() if file_part else doc
        if not resolved.exists():
            broken.append(f"{target}: no such file")
        elif anchor and resolved.suffix == ".md" and anchor not in anchors(resolved):
            broken.append(f"{target}: no heading #{anchor}")
    assert not broken, f"{doc.relative_to(ROOT)}: {broken}"


def test_the_checker_finds_a_broken_link_and_a_broken_anchor(tmp_path: Path) -> None:
    (tmp_path / "a.md").write_text(
        "# Title\n\n## A section\n\n[ok](#a-section) [bad](b.md) [anchor](#nope)\n"
        "```\n[in code](ignored.md)\n```\n"
    )
    found = links(tmp_path / "a.md")
    assert found == ["#a-section", "b.md", "#nope"]
    assert anchors(tmp_path / "a.md") == {"title", "a-section"}


def test_the_readme_is_short() -> None:
    assert len((ROOT / "README.md").read_text(encoding="utf-8").splitlines()) <= 200


def test_docs_and_package_hold_no_journal() -> None:
    journal = re.compile(r"session [0-9]+|issue [0-9]+", re.IGNORECASE)
    for doc in USER_DOCS:
        hits = journal.findall(doc.read_text(encoding="utf-8"))
        assert not hits, f"{doc.relative_to(ROOT)}: {hits}"
    for path in (ROOT / "dyndlo_vision").rglob("*"):
        if path.suffix in (".py", ".json", ".yaml", ".yml") and "docs/history" in path.read_text("utf-8"):
            raise AssertionError(f"{path.relative_to(ROOT)} points into docs/history")
