"""Docs that cannot drift: the lists the documentation keeps of things the code defines are the code's lists.

- the model families: docs/architecture.md's family table has one row per family, docs/contracts.md's family list
  names each once and its manifest examples (`"family": "..."`) name no other;
- the `t2m train` kinds: every `t2m train a|b|...` list in README.md and docs/ names every trainer once;
- docs/README.md indexes every page under docs/.
"""
from __future__ import annotations

import re
from collections import Counter
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
README = REPO / "README.md"
CONTRACTS = REPO / "docs" / "contracts.md"
ARCHITECTURE = REPO / "docs" / "architecture.md"
DOCS_INDEX = REPO / "docs" / "README.md"


def family_names() -> list[str]:
    """The model families the code knows. The one place that asks the code: switch it here when the families
    become a registry."""
    from t2m.bundle import family_names
    return list(family_names())


def training_kinds() -> list[str]:
    from t2m.cli.commands.train import trainers
    return list(trainers())


def section(text: str, heading: str) -> str:
    """The text of a `## heading` section, up to the next heading of the same level."""
    match = re.search(rf"^## {re.escape(heading)}\s*$(.*?)(?=^## |\Z)", text, re.MULTILINE | re.DOTALL)
    assert match, f"no '## {heading}' section"
    return match.group(1)


def table(text: str, first_header: str) -> list[list[str]]:
    """The rows (cells, stripped) of the Markdown table whose header row starts with `| first_header |`."""
    lines = text.splitlines()
    start = next((i for i, line in enumerate(lines) if line.startswith(f"| {first_header} |")), None)
    assert start is not None, f"no table with a '{first_header}' column"
    rows = []
    for line in lines[start + 2:]:
        if not line.startswith("|"):
            break
        rows.append([cell.strip() for cell in line.strip().strip("|").split("|")])
    return rows


def test_the_architecture_table_has_one_row_per_family():
    rows = table(section(ARCHITECTURE.read_text(encoding="utf-8"), "The families"), "family")
    families = [match.group(1) if (match := re.match(r"`([\w-]+)`", row[0])) else row[0] for row in rows]
    assert Counter(families) == Counter(family_names()), (
        f"docs/architecture.md's family table has rows for {families}; the code's families are {family_names()}")


def test_the_contracts_list_every_family_once_and_no_other():
    text = CONTRACTS.read_text(encoding="utf-8")
    listed = re.search(r"^Families \(`family`, one of `t2m\.bundle\.family_names\(\)`\): ([^.]*)\.", text, re.MULTILINE)
    assert listed, "docs/contracts.md lacks its 'Families (`family`, one of `t2m.bundle.family_names()`): ...' line"
    assert Counter(re.findall(r"`(\w+)`", listed.group(1))) == Counter(family_names())
    assert set(re.findall(r'"family": "(\w+)"', text)) == set(family_names())
    assert "admits only" not in text


def test_every_list_of_training_kinds_is_complete():
    pages = [README, *sorted((REPO / "docs").rglob("*.md"))]
    lists = [(page, found) for page in pages
             for found in re.findall(r"t2m train ((?:[\w-]+\\?\|)+[\w-]+)", page.read_text(encoding="utf-8"))]
    assert {page.name for page, _ in lists} >= {"cli.md", "contracts.md"}
    for page, found in lists:
        kinds = re.split(r"\\?\|", found)
        assert Counter(kinds) == Counter(training_kinds()), (
            f"{page.relative_to(REPO)} lists `t2m train {found}`; the trainers are {'|'.join(training_kinds())}")


def test_the_docs_index_lists_every_page():
    index = DOCS_INDEX.read_text(encoding="utf-8")
    linked = set(re.findall(r"\]\(([^)#\s]+)\)", index))
    pages = {p.relative_to(DOCS_INDEX.parent).as_posix() for p in DOCS_INDEX.parent.rglob("*.md")} - {"README.md"}
    assert pages <= linked, f"docs/README.md does not list {sorted(pages - linked)}"
