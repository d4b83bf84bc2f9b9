"""The arrows of docs/contracts.md, checked on the source: every import statement (top level or inside a function)
of every .py file under t2m/motion/, t2m/bundle/, t2m/service/, t2m/client/, t2m/model/ and t2m/families/ is read
with `ast`. A family module (t2m/families/) imports only the bundle contract at its top level: its hooks import the
service, export or model code inside the function, so looking a family up never imports torch or onnxruntime; and
no package imports t2m/families/ (the registry in t2m.bundle.family finds the built-in families by module name).

Our packages are the sub-packages of `t2m`; an import of `t2m.X...` counts as an import of package X."""
from __future__ import annotations

import ast
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
ROOT = REPO / "t2m"
OURS = {"motion", "model", "export", "service", "client", "cli", "bundle", "bundles", "decoding", "families"}
STDLIB = set(sys.stdlib_module_names) | {"__future__"}

# which of our packages each package may import (itself included)
ALLOWED_OURS = {
    "motion": {"motion"},
    "bundle": {"bundle"},
    "service": {"service", "motion", "bundle", "bundles", "decoding"},
    "client": {"client"},
    "decoding": {"decoding"},
    "model": {"model", "motion", "bundle", "decoding"},
    # the exporter computes a bundle's caption index with the service's own text path (same features)
    "export": {"export", "model", "motion", "bundle", "decoding", "bundles", "service"},
    "families": {"families", "bundle", "service", "export", "model", "decoding", "motion"},
}
# what a family module may import at its top level (the rest only inside its hooks)
FAMILIES_TOP_LEVEL = {"families", "bundle"}
FAMILIES_TOP_LEVEL_THIRD_PARTY = {"numpy"}
NEVER = {"torch"}  # for every package but model and export
MOTION_THIRD_PARTY = {"numpy"}
GLTF_THIRD_PARTY = {"numpy", "pygltflib", "trimesh"}


def imported_top_names(path: Path, top_level_only: bool = False) -> list[tuple[int, str]]:
    """(line, package) for every import in the file (or only the module's own top-level statements): the
    sub-package for `t2m.X...`, else the top-level module; relative imports count as the file's own package."""
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    package = path.relative_to(ROOT).parts[0]
    names: list[tuple[int, str]] = []
    for node in (tree.body if top_level_only else ast.walk(tree)):
        if isinstance(node, ast.Import):
            names += [(node.lineno, _package_of(alias.name)) for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            names.append((node.lineno, package if node.level else _package_of(node.module or "")))
    return names


def _package_of(module: str) -> str:
    parts = module.split(".")
    return parts[1] if parts[0] == "t2m" and len(parts) > 1 else parts[0]


def sources(package: str) -> list[Path]:
    return sorted((ROOT / package).rglob("*.py"))


def violations(package: str) -> list[str]:
    found = []
    for path in sources(package):
        where = path.relative_to(ROOT)
        for line, name in imported_top_names(path):
            if name in OURS and name not in ALLOWED_OURS[package]:
                found.append(f"{where}:{line} imports {name}")
            if package not in ("model", "export") and name in NEVER:
                found.append(f"{where}:{line} imports {name}")
            if package != "families" and name == "families":
                found.append(f"{where}:{line} imports families (only the registry finds them, by module name)")
            if package == "motion" and name not in STDLIB and name not in OURS:
                allowed = GLTF_THIRD_PARTY if path.name == "gltf.py" else MOTION_THIRD_PARTY
                if name not in allowed:
                    found.append(f"{where}:{line} imports {name} (motion/ is numpy-only)")
        if package == "families":
            for line, name in imported_top_names(path, top_level_only=True):
                if (name in OURS and name not in FAMILIES_TOP_LEVEL) or (
                        name not in OURS and name not in STDLIB and name not in FAMILIES_TOP_LEVEL_THIRD_PARTY):
                    found.append(f"{where}:{line} imports {name} at its top level (only inside a hook)")
    return found


@pytest.mark.parametrize("package", sorted(ALLOWED_OURS))
def test_import_direction(package):
    assert sources(package), f"{package}/ has no Python files"
    assert violations(package) == []


def test_the_checker_sees_nested_and_relative_imports(tmp_path, monkeypatch):
    """The rule must be able to fail: a nested torch import and a relative import are both reported."""
    fake = tmp_path / "service" / "engine"
    fake.mkdir(parents=True)
    (fake / "bad.py").write_text(
        "def f():\n    import torch\n    from t2m.model.networks.gpt import GPT\nfrom . import x\n"
    )
    monkeypatch.setattr(sys.modules[__name__], "ROOT", tmp_path)
    assert violations("service") == [
        "service/engine/bad.py:2 imports torch",
        "service/engine/bad.py:3 imports model",
    ]
    (tmp_path / "motion").mkdir()
    (tmp_path / "motion" / "features.py").write_text("import numpy\nimport scipy.ndimage\n")
    assert violations("motion") == ["motion/features.py:2 imports scipy (motion/ is numpy-only)"]
    (tmp_path / "families").mkdir()
    (tmp_path / "families" / "bad.py").write_text(
        "import onnxruntime\nfrom t2m.service.engine.engine import OnnxEngine\n"
        "def serve():\n    from t2m.service.engine.gpt_codes import GptCodes\n")
    assert violations("families") == ["families/bad.py:1 imports onnxruntime at its top level (only inside a hook)",
                                      "families/bad.py:2 imports service at its top level (only inside a hook)"]


def module_imports() -> dict[str, set[str]]:
    """module -> the t2m modules it imports (at any depth of the file), by `ast`."""
    graph: dict[str, set[str]] = {}
    for path in sorted(ROOT.rglob("*.py")):
        parts = path.relative_to(ROOT.parent).with_suffix("").parts
        name = ".".join(parts[:-1] if parts[-1] == "__init__" else parts)
        found: set[str] = set()
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.Import):
                found |= {alias.name for alias in node.names if alias.name.startswith("t2m.")}
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and (node.module or "").startswith("t2m."):
                found.add(node.module or "")
        graph[name] = found
    return graph


def find_cycle(graph: dict[str, set[str]]) -> list[str]:
    """One import cycle between modules (a module importing a package counts as importing its __init__), or []."""
    state: dict[str, int] = {}
    stack: list[str] = []

    def visit(module: str) -> list[str]:
        state[module] = 1
        stack.append(module)
        for target in sorted(graph.get(module, ())):
            if target not in graph or target == module:
                continue
            if state.get(target) == 1:
                return [*stack[stack.index(target):], target]
            if target not in state and (cycle := visit(target)):
                return cycle
        state[module] = 2
        stack.pop()
        return []

    for module in sorted(graph):
        if module not in state and (cycle := visit(module)):
            return cycle
    return []


def test_no_import_cycles():
    assert find_cycle(module_imports()) == []


def test_the_cycle_finder_can_fail():
    assert find_cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]
