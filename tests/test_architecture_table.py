"""docs/architecture.md's table of the family folders is the tree: every family folder is a row, every .py file of a
folder is listed under its role (declaration, served, offline: the roles the import-direction test enforces), and
every listed file exists. A newcomer reads the table; this keeps it true."""
from __future__ import annotations

import re
from pathlib import Path

from tests.test_import_direction import family_role

REPO = Path(__file__).resolve().parents[1]
PAGE = REPO / "docs" / "architecture.md"
ROLES = ("declaration", "served", "offline")
ROW = re.compile(r"^\| `(\w+)`[^|]*\| `t2m/families/(\w+)/` \|([^|]*)\|([^|]*)\|([^|]*)\|\s*$")


def table_rows(text: str) -> dict[str, dict[str, set[str]]]:
    """{folder: {role: {file, ...}}} from the page's rows `| `name` ... | `t2m/families/name/` | files... |`."""
    rows: dict[str, dict[str, set[str]]] = {}
    for line in text.splitlines():
        match = ROW.match(line)
        if match:
            cells = match.groups()[2:]
            rows[match.group(2)] = {role: set(re.findall(r"`([\w.]+\.py)`", cell)) for role, cell in zip(ROLES, cells)}
    return rows


def tree_rows(root: Path) -> dict[str, dict[str, set[str]]]:
    """The same from the tree under root/t2m/families/."""
    rows: dict[str, dict[str, set[str]]] = {}
    for folder in sorted(p for p in (root / "t2m" / "families").iterdir() if (p / "__init__.py").is_file()):
        files: dict[str, set[str]] = {role: set() for role in ROLES}
        for path in folder.glob("*.py"):
            files[family_role(f"t2m.families.{folder.name}.{path.stem}") or "offline"].add(path.name)
        rows[folder.name] = files
    return rows


def differences(page: dict[str, dict[str, set[str]]], tree: dict[str, dict[str, set[str]]]) -> list[str]:
    found = [f"family folder t2m/families/{name}/ has no row" for name in sorted(tree.keys() - page.keys())]
    found += [f"row {name}: no folder t2m/families/{name}/" for name in sorted(page.keys() - tree.keys())]
    for name in sorted(page.keys() & tree.keys()):
        for role in ROLES:
            found += [f"{name}: {file} ({role}) is not in the table" for file in sorted(tree[name][role] -
                                                                                          page[name][role])]
            found += [f"{name}: the table lists {file} as {role}, the tree has no such {role} file"
                      for file in sorted(page[name][role] - tree[name][role])]
    return found


def test_the_architecture_table_is_the_tree():
    page = table_rows(PAGE.read_text(encoding="utf-8"))
    assert page, "docs/architecture.md has no family table"
    assert differences(page, tree_rows(REPO)) == []


def test_a_file_missing_from_the_table_or_the_tree_is_named(tmp_path):
    """Control: the check fails on a deliberate break, both ways."""
    folder = tmp_path / "t2m" / "families" / "tiny"
    folder.mkdir(parents=True)
    for name in ("__init__.py", "family.py", "loop.py", "served.py", "network.py"):
        (folder / name).write_text("")
    row = ("| `tiny` | `t2m/families/tiny/` | `__init__.py`, `family.py` | `loop.py`, `served.py` | "
           "`network.py` |")
    assert differences(table_rows(row), tree_rows(tmp_path)) == []
    (folder / "training.py").write_text("")
    assert differences(table_rows(row), tree_rows(tmp_path)) == ["tiny: training.py (offline) is not in the table"]
    (folder / "training.py").unlink()
    (folder / "served.py").unlink()
    assert differences(table_rows(row), tree_rows(tmp_path)) == [
        "tiny: the table lists served.py as served, the tree has no such served file"]
    assert differences({}, tree_rows(tmp_path)) == ["family folder t2m/families/tiny/ has no row"]
