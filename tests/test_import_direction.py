"""The arrows of docs/contracts.md, checked on the source: every import statement (top level or inside a function)
of every .py file under t2m/ is read with `ast`.

Packages: our packages are the sub-packages of `t2m`; an import of `t2m.X...` counts as an import of package X.
Families: a family is a folder, t2m/families/<name>/, whose modules play one of three roles, by file name:
- its declaration (`__init__.py`, `family.py`) imports only the bundle contract and its own folder at its top
  level (its hooks import the rest inside the function), so looking a family up never imports torch or onnxruntime;
- its served modules (`loop.py`, `served.py`, `edits.py`) are what the service runs: torch-free, importing neither
  the training nor the export code, nor the family's offline modules;
- every other module of the folder is offline (networks, training, export, importers, evaluation: torch allowed),
  and nothing served imports it.
No module outside t2m/families/ imports a family (the registry in t2m.bundle.family finds them by module name), but
for the packages that measure or drive named models (FAMILY_AWARE: the CLI's importers, `t2m bench`, `t2m eval
SUBJECT`, the shared test helpers); never the serving path, the shared machinery or the offline code the families
share."""
from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
ROOT = REPO / "t2m"
OURS = {"motion", "model", "export", "service", "client", "cli", "bundle", "bundles", "decoding", "families", "runtime",
        "api", "bench", "quality", "testing"}
STDLIB = set(sys.stdlib_module_names) | {"__future__"}

# which of our packages each package may import (itself included)
ALLOWED_OURS = {
    "motion": {"motion"},
    "bundle": {"bundle"},
    "decoding": {"decoding"},
    "client": {"client"},
    "api": {"api", "runtime"},
    "runtime": {"runtime", "api", "motion", "bundle", "bundles", "decoding"},
    # the service plugs `t2m serve` into the CLI (its errors are the CLI's)
    "service": {"service", "runtime", "api", "motion", "bundle", "bundles", "cli"},
    "model": {"model", "motion", "bundle", "decoding"},
    # the exporter computes a bundle's caption index with the runtime's own text path (same features)
    "export": {"export", "model", "motion", "bundle", "decoding", "bundles", "runtime", "api"},
    "families": {"families", "bundle", "runtime", "api", "export", "model", "decoding", "motion", "bundles", "bench",
                 "quality", "testing"},
    # the CLI runs the runtime and the offline code; `t2m serve` is plugged in by the service (t2m_commands)
    "cli": {"cli", "runtime", "api", "export", "model", "motion", "bundle", "bundles", "decoding", "bench", "quality"},
    # the measurements (`t2m bench`, `t2m eval SUBJECT`) and the helpers tests and benchmarks share
    "bench": {"bench", "runtime", "api", "export", "model", "motion", "bundle", "bundles", "decoding", "testing"},
    "quality": {"quality", "runtime", "api", "export", "model", "motion", "bundle", "bundles", "decoding"},
    "testing": {"testing", "runtime", "api", "export", "model", "motion", "bundle", "bundles", "decoding"},
}
# packages that measure or drive named models and so may name a family: the CLI's importers, `t2m bench`,
# `t2m eval SUBJECT`, the random releases the tests and benchmarks share; never the serving path
FAMILY_AWARE = {"cli", "bench", "quality", "testing"}
# no HTTP framework below the service: the runtime, the API's models and the families' served code run without one
HTTP_FRAMEWORKS = {"fastapi", "starlette", "uvicorn"}
DECLARATION = {"__init__", "family"}
SERVED = {"loop", "served", "edits"}
# what a family's declaration may import at its top level (the rest only inside its hooks)
DECLARATION_TOP_LEVEL = {"families", "bundle"}
DECLARATION_TOP_LEVEL_THIRD_PARTY = {"numpy"}
# what a family's served modules may import of ours
SERVED_OURS = {"families", "bundle", "runtime", "api", "decoding", "motion"}
NEVER = {"torch"}  # for the torch-free packages, and for a family's declaration and served modules
TORCH_FREE = {"motion", "bundle", "bundles", "decoding", "client", "api", "runtime", "service", "families"}
MOTION_THIRD_PARTY = {"numpy"}
GLTF_THIRD_PARTY = {"numpy", "pygltflib", "trimesh"}


def imports_of(path: Path, top_level_only: bool = False) -> list[tuple[int, str]]:
    """(line, module) for every import in the file (or only the module's own top-level statements); a relative
    import counts as the file's own package, `t2m.X` (no module) as that package."""
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    own = "t2m." + path.relative_to(ROOT).parts[0]
    found: list[tuple[int, str]] = []
    for node in (tree.body if top_level_only else ast.walk(tree)):
        if isinstance(node, ast.Import):
            found += [(node.lineno, alias.name) for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            module = own if node.level else (node.module or "")
            if module in ("t2m", "t2m.families"):  # `from t2m.families import gpt`: the names are modules
                found += [(node.lineno, f"{module}.{alias.name}") for alias in node.names]
            else:
                found.append((node.lineno, module))
    return found


def imported_top_names(path: Path, top_level_only: bool = False) -> list[tuple[int, str]]:
    """(line, package) for every import in the file: the sub-package for `t2m.X...`, else the top-level module."""
    return [(line, _package_of(module)) for line, module in imports_of(path, top_level_only)]


def _package_of(module: str) -> str:
    parts = module.split(".")
    return parts[1] if parts[0] == "t2m" and len(parts) > 1 else parts[0]


def family_role(module: str) -> str | None:
    """`declaration`, `served` or `offline` for a module t2m.families.<name>.<stem>, None for any other."""
    parts = module.split(".")
    if parts[:2] != ["t2m", "families"] or len(parts) < 3:
        return None
    stem = parts[3] if len(parts) > 3 else "__init__"
    return "declaration" if stem in DECLARATION else "served" if stem in SERVED else "offline"


def module_name(path: Path) -> str:
    return ".".join(("t2m", *path.relative_to(ROOT).with_suffix("").parts))


def sources(package: str) -> list[Path]:
    return sorted((ROOT / package).rglob("*.py"))


def violations(package: str) -> list[str]:
    found = []
    for path in sources(package):
        where = path.relative_to(ROOT)
        role = family_role(module_name(path)) if package == "families" else None
        for line, module in imports_of(path):
            name = _package_of(module)
            if name in OURS and name != "families" and name not in ALLOWED_OURS[package]:
                found.append(f"{where}:{line} imports {name}")
            if package in TORCH_FREE and role != "offline" and name in NEVER:
                found.append(f"{where}:{line} imports {name}")
            if package != "families" and package not in FAMILY_AWARE and name == "families":
                found.append(f"{where}:{line} imports {module} (only the registry finds a family, by module name)")
            if package != "service" and name in HTTP_FRAMEWORKS:
                found.append(f"{where}:{line} imports {name} (HTTP lives in t2m/service/ alone)")
            if role == "served" and ((name not in SERVED_OURS and name in OURS) or family_role(module) == "offline"):
                found.append(f"{where}:{line} imports {module} (a served module imports no offline code)")
            if package == "motion" and name not in STDLIB and name not in OURS:
                allowed = GLTF_THIRD_PARTY if path.name == "gltf.py" else MOTION_THIRD_PARTY
                if name not in allowed:
                    found.append(f"{where}:{line} imports {name} (motion/ is numpy-only)")
        if role == "declaration":
            for line, name in imported_top_names(path, top_level_only=True):
                if (name in OURS and name not in DECLARATION_TOP_LEVEL) or (
                        name not in OURS and name not in STDLIB and name not in DECLARATION_TOP_LEVEL_THIRD_PARTY):
                    found.append(f"{where}:{line} imports {name} at its top level (only inside a hook)")
    return found


@pytest.mark.parametrize("package", sorted(ALLOWED_OURS))
def test_import_direction(package):
    assert sources(package), f"{package}/ has no Python files"
    assert violations(package) == []


def test_the_runtime_runs_without_fastapi():
    """Every module of the runtime, the API's models and the families' served code imported in a fresh interpreter
    loads no HTTP framework (the import rule above reads the source; this catches what a dependency pulls in)."""
    served = [module_name(path) for path in sources("families") if family_role(module_name(path)) != "offline"]
    modules = [module_name(path) for package in ("runtime", "api") for path in sources(package)] + served
    code = ("import importlib, sys\n"
            f"for name in {modules!r}: importlib.import_module(name.removesuffix('.__init__'))\n"
            f"print(sorted(m for m in {sorted(HTTP_FRAMEWORKS)!r} if m in sys.modules))")
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=REPO, check=True)
    assert result.stdout.strip() == "[]"


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
    family = tmp_path / "families" / "bad"
    family.mkdir(parents=True)
    (family / "family.py").write_text(
        "import onnxruntime\nfrom t2m.runtime.engine import OnnxEngine\n"
        "def serve():\n    from t2m.families.bad.served import Codes\n")
    (family / "served.py").write_text("import torch\nfrom t2m.families.bad.network import Net\n")
    (family / "network.py").write_text("import torch\nfrom t2m.model.networks.quantizers import Q\n")
    assert violations("families") == [
        "families/bad/family.py:1 imports onnxruntime at its top level (only inside a hook)",
        "families/bad/family.py:2 imports runtime at its top level (only inside a hook)",
        "families/bad/served.py:1 imports torch",
        "families/bad/served.py:2 imports t2m.families.bad.network (a served module imports no offline code)",
    ]
    (tmp_path / "service" / "engine" / "bad.py").write_text("from t2m.families import bad\n")
    assert violations("service") == [
        "service/engine/bad.py:1 imports t2m.families.bad (only the registry finds a family, by module name)"]


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
