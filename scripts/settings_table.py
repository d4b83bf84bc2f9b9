"""Write docs/service.md's settings table from the code (t2m/service/settings.py), or check that it is current.

Why: the table is what an operator reads, the pydantic-settings class is what the service obeys; generating one
from the other means they cannot disagree. Each field gives one row: its environment variable(s), its default, its
type and range, and its description. tests/service/test_settings_table.py fails when the committed table differs.
Usage: python scripts/settings_table.py            (rewrite the table between the markers in docs/service.md)
       python scripts/settings_table.py --check    (exit 1 and say so when the committed table is not current)
"""
from __future__ import annotations

import sys
import types
import typing
from pathlib import Path

import annotated_types
from pydantic import AliasChoices, SecretStr
from pydantic.fields import FieldInfo
from pydantic_core import PydanticUndefined

import t2m
from t2m.service.settings import Settings

PAGE = Path(__file__).resolve().parent.parent / "docs" / "service.md"
BEGIN = ("<!-- settings table: generated from t2m/service/settings.py by scripts/settings_table.py "
         "(edit the descriptions there, then run it) -->")
END = "<!-- end of the generated settings table -->"
PREFIX = Settings.model_config.get("env_prefix", "")


def env_names(name: str, field: FieldInfo) -> list[str]:
    """The variables that set a field: its aliases that carry the prefix, else PREFIX + NAME."""
    alias = field.validation_alias
    if isinstance(alias, AliasChoices):
        names = [choice for choice in alias.choices if isinstance(choice, str) and choice.startswith(PREFIX)]
        if names:
            return names
    return [f"{PREFIX}{name.upper()}"]


def default_text(field: FieldInfo) -> str:
    """The default as an operator would write it (in backticks), or `unset` / `none` for no value."""
    value = field.get_default(call_default_factory=True)
    if value is None or value is PydanticUndefined:
        return "unset"
    if isinstance(value, list) and not value:
        return "none"
    if isinstance(value, bool):
        text = str(value).lower()
    elif isinstance(value, float):
        text = format(value, "g")
    elif isinstance(value, Path):  # the embedded bundle: where it sits in the package, not on this machine
        package_root = Path(t2m.__file__).resolve().parent.parent
        text = (value.resolve().relative_to(package_root).as_posix()
                if value.resolve().is_relative_to(package_root) else value.as_posix())
    elif isinstance(value, list):
        text = ",".join(str(item) for item in value)
    else:
        text = str(value)
    return f"`{cell(text)}`"


def type_text(field: FieldInfo) -> str:
    """The type an operator writes, with the range the field accepts."""
    annotation = field.annotation
    args = [a for a in typing.get_args(annotation) if a is not type(None)]
    if typing.get_origin(annotation) is typing.Literal:
        kind = " or ".join(f"`{a}`" for a in typing.get_args(annotation))
    elif typing.get_origin(annotation) in (typing.Union, types.UnionType) and args == [SecretStr]:
        kind = "secret string"
    elif typing.get_origin(annotation) is list:
        kind = "comma-separated " + ("directories" if args == [Path] else "list")
    else:
        names: dict[object, str] = {bool: "true/false", int: "integer", float: "number", Path: "directory",
                                    str: "string"}
        kind = names.get(annotation) or str(getattr(annotation, "__name__", annotation))
    bound = {attribute: getattr(item, attribute) for item in field.metadata
             if isinstance(item, annotated_types.BaseMetadata)
             for attribute in ("ge", "gt", "le", "lt") if getattr(item, attribute, None) is not None}
    if "ge" in bound and "le" in bound:
        return f"{kind}, {bound['ge']} to {bound['le']}"
    words = {"ge": "at least", "gt": "above", "le": "at most", "lt": "below"}
    return ", ".join([kind, *(f"{words[attribute]} {value}" for attribute, value in bound.items())])


def cell(text: str) -> str:
    """Markdown table cell: a pipe would split it, an angle bracket would be taken for HTML."""
    return " ".join(text.split()).replace("|", "\\|").replace("<", "&lt;")


def render() -> str:
    rows = ["| variable | default | type | meaning |", "| --- | --- | --- | --- |"]
    for name, field in Settings.model_fields.items():
        variables = " / ".join(f"`{env}`" for env in env_names(name, field))
        rows.append(f"| {variables} | {default_text(field)} | {cell(type_text(field))} | "
                    f"{cell(field.description or '')} |")
    return "\n".join([BEGIN, "", *rows, "", END])


def with_table(page_text: str) -> str:
    """The page with its table replaced by the generated one (ValueError when the markers are missing)."""
    start, end = page_text.find(BEGIN), page_text.find(END)
    if start < 0 or end < start:
        raise ValueError(f"{PAGE.name}: the markers of the generated settings table are missing")
    return page_text[:start] + render() + page_text[end + len(END):]


def main(argv: list[str]) -> int:
    text = PAGE.read_text(encoding="utf-8")
    updated = with_table(text)
    if "--check" in argv:
        if updated != text:
            print(f"{PAGE}: the settings table is not current; run python scripts/settings_table.py",
                  file=sys.stderr)
            return 1
        return 0
    if updated != text:
        PAGE.write_text(updated, encoding="utf-8")
    print(f"{PAGE}: settings table {'rewritten' if updated != text else 'already current'}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
