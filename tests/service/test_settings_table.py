"""docs/service.md's settings table is generated from t2m/service/settings.py (scripts/settings_table.py): the
committed table is the generated one, so every setting the service reads is documented, with its default and
description, and the table has no row the code lacks."""
from __future__ import annotations

import re
from pathlib import Path

import pytest

from scripts import settings_table
from t2m.service.settings import Settings

REPO = Path(__file__).resolve().parents[2]


def committed_table() -> str:
    text = settings_table.PAGE.read_text(encoding="utf-8")
    start, end = text.find(settings_table.BEGIN), text.find(settings_table.END)
    assert start >= 0 and end > start, "docs/service.md lacks the generated settings table's markers"
    return text[start:end + len(settings_table.END)]


def test_the_committed_table_is_the_generated_one():
    assert committed_table() == settings_table.render(), (
        "docs/service.md's settings table differs from t2m/service/settings.py: run python scripts/settings_table.py")


def test_one_row_per_setting_with_its_variable_default_and_description():
    rows = [line for line in committed_table().splitlines() if line.startswith("| `T2M_")]
    assert len(rows) == len(Settings.model_fields)
    for row, (name, field) in zip(rows, Settings.model_fields.items()):
        assert f"`T2M_{name.upper()}`" in row
        assert " ".join(field.description.split()).replace("<", "&lt;") in row
    bundle_row = rows[list(Settings.model_fields).index("bundle_path")]
    assert bundle_row.startswith("| `T2M_BUNDLE_PATH` / `T2M_MODEL_DIR` | `t2m/bundles/default` |")
    assert re.search(r"\| `T2M_MAX_QUEUE` \| `16` \| integer, at least 1 \|", committed_table())


def test_check_mode_reports_a_stale_table(tmp_path, monkeypatch, capsys):
    page = tmp_path / "service.md"
    page.write_text(f"# x\n\n{settings_table.BEGIN}\n| a stale row |\n{settings_table.END}\n", encoding="utf-8")
    monkeypatch.setattr(settings_table, "PAGE", page)
    assert settings_table.main(["--check"]) == 1
    assert "not current" in capsys.readouterr().err
    assert settings_table.main([]) == 0
    assert settings_table.main(["--check"]) == 0
    assert page.read_text(encoding="utf-8").startswith("# x\n\n") and "T2M_UNKNOWN_TEXT" in page.read_text()
    page.write_text("no markers\n", encoding="utf-8")
    with pytest.raises(ValueError, match="markers"):
        settings_table.main(["--check"])
