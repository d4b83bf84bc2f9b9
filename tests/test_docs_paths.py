"""Docs that cannot drift: every repository path and `t2m.` module the documentation names exists.

Checked: every Markdown page of the repository (README.md, CONTRIBUTING.md, docs/, benchmarks/, deploy/, the
bundles' model cards, ...) and every string of the embedded bundles' manifest.json files. CHANGELOG.md and
docs/speed-history.md are not checked: they are history, and their entries name the paths and commands as they were
when each was written.

What counts as a path (the rule, kept small so that it neither misses a moved file nor cries wolf):
- a Markdown link or image target `[...](target)` that is not a URL: relative to the page, with its `#anchor`
  checked against the target page's headings (GitHub's slugs);
- a token that starts with one of the repository's top-level folders (`t2m/`, `tests/`, `docs/`, `scripts/`,
  `benchmarks/`, `deploy/`, `tools/`, `.ci/`), anywhere in the text (prose, inline code, code blocks): relative
  to the repository root. A token ends at the first character that cannot be in a path, so a placeholder or glob
  (`t2m/decoding/<family>.py`, `t2m/bundles/{default,gpt}`, `*.whl`) leaves the folder before it to check;
- any other token with a slash that ends in a source or document suffix and whose first folder has the name of
  one of the repository's folders (`model/captions.py`, `engine/reach.py`: shortened or stale paths of ours; a
  released checkpoint's `meta/mean.npy` or a placeholder's `DIR/Mean.npy` are not ours): relative to the
  repository root or to the page;
- a dotted module path `t2m.a.b[.Name]`: the longest importable prefix is found on disk (a .py file or a package
  folder) and the next name, if any, must be a sub-module or defined at that module's top level. A token followed
  by `(` is a call on an object that happens to be named `t2m` (the SDK examples' client), one followed by `..` a
  placeholder (`t2m.X...`): neither is checked.
A path outside the repository (a link to `../shared/...`, or a `../shared/` token) is checked only when that
folder exists (the shared data and docs folder of a development machine: $T2M_SHARED, else `../shared` beside
the repository, as tests/conftest.py finds it). Folders the repository ignores (`data/`, `runs/`: rebuilt by
commands) are not roots, so they are never checked.
"""
from __future__ import annotations

import ast
import json
import re
import shutil
import subprocess
from functools import cache
from pathlib import Path

import pytest

from tests.shared_data import shared_dir

REPO = Path(__file__).resolve().parents[1]

ROOT_FOLDERS = ("t2m", "tests", "docs", "scripts", "benchmarks", "deploy", "tools", ".ci")
MARKDOWN_ROOTS = ("docs", "benchmarks", "deploy", "t2m", "tests", "scripts", "tools")
SKIPPED_FOLDERS = {"node_modules", "__pycache__"}  # installed third-party files (tools/gltf-validator), caches
NOT_CHECKED = {"CHANGELOG.md", "speed-history.md"}  # history: paths (and commands) as they were
SUFFIXES = ("py", "md", "sh", "json", "toml", "yml", "yaml", "onnx", "npz", "npy", "log", "png", "gif", "txt", "conf")

LINK = re.compile(r"!?\[[^\]]*\]\(\s*<?([^)\s>]+)>?(?:\s+\"[^\"]*\")?\s*\)")
PATH_CHARS = r"[\w.\-/]"
ROOTED = re.compile(rf"(?<![\w.\-/$~])((?:{'|'.join(re.escape(f) for f in ROOT_FOLDERS)})/{PATH_CHARS}*)")
SUFFIXED = re.compile(rf"(?<![\w.\-/$~:<])((?:\.\./)*[\w.\-]+/{PATH_CHARS}*\.(?:{'|'.join(SUFFIXES)}))(?![\w/<])")
MODULE = re.compile(r"(?<![\w./\-])(t2m(?:\.[A-Za-z_]\w*)+)(?!\w|\(|\.\.)")
SHARED = re.compile(r"(?<![\w.\-/])\.\./shared/([\w.\-/]*[\w\-/])")
HEADING = re.compile(r"^#{1,6}\s+(.*?)\s*#*\s*$")


@cache
def ignored_roots(repo: Path = REPO) -> frozenset[str]:
    """Top-level folders .gitignore names (`/data/`, `/runs/`, ...): rebuilt by commands, never committed."""
    lines = (repo / ".gitignore").read_text(encoding="utf-8").splitlines() if (repo / ".gitignore").is_file() else []
    return frozenset(m.group(1) for line in lines if (m := re.fullmatch(r"/?([\w.\-]+)/", line.strip())))


@cache
def folder_names(repo: Path = REPO) -> frozenset[str]:
    """The names of the repository's source folders, at any depth (what a shortened path of ours starts with)."""
    names: set[str] = set()
    for root in ROOT_FOLDERS:
        for path in (repo / root).rglob("*"):
            parts = path.relative_to(repo).parts
            if path.is_dir() and not any(part.startswith((".", "__")) for part in parts[1:]) and \
                    parts[:2] != ("tests", "fixtures"):    # data laid out as its source has it, not our code
                names.add(path.name)
    return frozenset(names - ignored_roots(repo))


def documentation_files(repo: Path = REPO) -> list[Path]:
    """The Markdown pages checked: the top level's and every one under the source folders, the history aside."""
    pages = [p for p in sorted(repo.glob("*.md")) if p.name not in NOT_CHECKED]
    for root in MARKDOWN_ROOTS:
        pages += sorted(p for p in (repo / root).rglob("*.md") if p.name not in NOT_CHECKED and not any(
            part.startswith(".") or part in SKIPPED_FOLDERS for part in p.relative_to(repo).parts))
    return pages


def manifest_files(repo: Path = REPO) -> list[Path]:
    return sorted((repo / "t2m" / "bundles").glob("*/manifest.json"))


def slug(heading: str) -> str:
    """GitHub's anchor for a heading: markup dropped, lower case, punctuation removed, spaces to hyphens."""
    text = re.sub(r"\[([^\]]*)\]\([^)]*\)", r"\1", heading).replace("`", "").strip().lower()
    return re.sub(r"[^\w\- ]", "", text).replace(" ", "-")


@cache
def anchors(page: Path) -> frozenset[str]:
    found: set[str] = set()
    in_code = False
    for line in page.read_text(encoding="utf-8").splitlines():
        if line.lstrip().startswith("```"):
            in_code = not in_code
            continue
        match = None if in_code else HEADING.match(line)
        if match:
            base = slug(match.group(1))
            name, n = base, 1
            while name in found:
                name, n = f"{base}-{n}", n + 1
            found.add(name)
    return frozenset(found)


def _outside_and_absent(path: Path, page: Path, repo: Path) -> bool:
    """A page of the repository pointing outside it, to a folder beside it that does not exist here (the shared
    folder of a development machine)."""
    resolved = path.resolve()
    if resolved.is_relative_to(repo.resolve()) or not page.resolve().is_relative_to(repo.resolve()):
        return False
    parent = repo.resolve().parent
    if not resolved.is_relative_to(parent):
        return True
    first = resolved.relative_to(parent).parts[:1]
    return not first or not (parent / first[0]).exists()


@cache
def top_level_names(module_file: Path) -> frozenset[str]:
    """Names a module defines or imports at its top level (and its `__all__`)."""
    tree = ast.parse(module_file.read_text(encoding="utf-8"))
    names: set[str] = set()
    for node in tree.body:
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            names.add(node.name)
        elif isinstance(node, (ast.Assign, ast.AnnAssign, ast.AugAssign)):
            targets = node.targets if isinstance(node, ast.Assign) else [node.target]
            for target in targets:
                names.update(n.id for n in ast.walk(target) if isinstance(n, ast.Name))
        elif isinstance(node, (ast.Import, ast.ImportFrom)):
            names.update((alias.asname or alias.name).split(".")[0] for alias in node.names)
        elif isinstance(node, (ast.If, ast.Try)):
            for child in ast.walk(node):
                if isinstance(child, (ast.FunctionDef, ast.ClassDef)):
                    names.add(child.name)
                elif isinstance(child, (ast.Import, ast.ImportFrom)):
                    names.update((alias.asname or alias.name).split(".")[0] for alias in child.names)
    return frozenset(names)


def module_problem(dotted: str, repo: Path = REPO) -> str | None:
    """None when `t2m.a.b[.Name[...]]` names a module on disk and, after it, a name that module defines."""
    parts = dotted.split(".")
    found = None
    for end in range(len(parts), 0, -1):
        base = repo.joinpath(*parts[:end])
        if base.with_suffix(".py").is_file():
            found = (end, base.with_suffix(".py"))
            break
        if (base / "__init__.py").is_file():
            found = (end, base / "__init__.py")
            break
    if found is None:
        return "no such module"
    end, module_file = found
    if end == len(parts):
        return None
    name = parts[end]
    if name in top_level_names(module_file):
        return None
    return f"{'.'.join(parts[:end])} has no {name!r}"


def problems_in_text(text: str, page: Path, repo: Path = REPO) -> list[str]:
    """Every path in `text` (the content of `page`) that does not exist, as 'what: why' lines."""
    problems: list[str] = []

    for target in LINK.findall(text):
        if re.match(r"^[a-z][\w+.-]*:", target, re.IGNORECASE):      # http:, https:, mailto:
            continue
        file_part, _, anchor = target.partition("#")
        destination = (page.parent / file_part) if file_part else page
        if _outside_and_absent(destination, page, repo):
            continue
        if not destination.exists():
            problems.append(f"link ({target}): no such file")
        elif anchor and destination.suffix == ".md" and anchor not in anchors(destination.resolve()):
            problems.append(f"link ({target}): no heading #{anchor} in {destination.name}")

    rooted = set()
    for match in ROOTED.finditer(text):
        token = match.group(1).rstrip(".")
        rooted.add(token)
        following = text[match.end():match.end() + 1]
        if following and following in "<{*" and "/" in token:
            token = token.rsplit("/", 1)[0]   # cut inside a name by a placeholder: its folder must exist
        if not (repo / token).exists():
            problems.append(f"path {token}: no such file or folder")

    for token in SUFFIXED.findall(text):
        first = token.split("/")[0]
        if token in rooted or first in ROOT_FOLDERS or first not in folder_names(repo):
            continue
        candidates = [repo / token, page.parent / token]
        if any(c.exists() for c in candidates) or all(_outside_and_absent(c, page, repo) for c in candidates):
            continue
        problems.append(f"path {token}: no such file (from the repository root or {page.parent.name}/)")

    shared = shared_dir() if repo == REPO else repo / ".." / "shared"
    if shared.is_dir():
        for token in SHARED.findall(text):
            if not (shared / token).exists():
                problems.append(f"path ../shared/{token}: not in the shared folder {shared}")

    for dotted in MODULE.findall(text):
        problem = module_problem(dotted.rstrip("."), repo)
        if problem:
            problems.append(f"module {dotted}: {problem}")
    return problems


def strings_of(value: object) -> list[str]:
    if isinstance(value, str):
        return [value]
    if isinstance(value, dict):
        return [s for v in value.values() for s in strings_of(v)]
    if isinstance(value, list):
        return [s for v in value for s in strings_of(v)]
    return []


def test_the_pages_and_cards_are_found():
    pages = {p.relative_to(REPO).as_posix() for p in documentation_files()}
    assert {"README.md", "CONTRIBUTING.md", "docs/contracts.md", "docs/service.md",
            "t2m/bundles/default/MODEL_CARD.md", "t2m/bundles/gpt/MODEL_CARD.md"} <= pages
    assert "CHANGELOG.md" not in pages
    assert {p.parent.name for p in manifest_files()} >= {"default", "gpt", "masked"}


@pytest.mark.parametrize("page", documentation_files(), ids=lambda p: p.relative_to(REPO).as_posix())
def test_every_path_a_page_names_exists(page: Path):
    problems = problems_in_text(page.read_text(encoding="utf-8"), page)
    assert not problems, f"{page.relative_to(REPO)} names paths that do not exist:\n  " + "\n  ".join(problems)


@pytest.mark.parametrize("manifest", manifest_files(), ids=lambda p: p.parent.name)
def test_every_path_a_manifest_names_exists(manifest: Path):
    strings = strings_of(json.loads(manifest.read_text(encoding="utf-8")))
    problems = [p for s in strings for p in problems_in_text(s, manifest)]
    assert not problems, f"{manifest.relative_to(REPO)} names paths that do not exist:\n  " + "\n  ".join(problems)


MACHINE_FOLDER = re.compile(r"(?<![\w.~\-])/(?:work|root|home)/")
BINARY_SUFFIXES = {".onnx", ".npz", ".npy", ".png", ".gif", ".gz", ".pt", ".safetensors"}


def tracked_text_files(repo: Path = REPO) -> list[Path]:
    if shutil.which("git") is None or not (repo / ".git").exists():
        pytest.skip("not a git checkout: the tracked files are unknown")
    names = subprocess.run(["git", "ls-files", "-z"], cwd=repo, capture_output=True, check=True).stdout
    return [repo / name for name in names.decode().split("\0")
            if name and Path(name).suffix not in BINARY_SUFFIXES and name != ".gitignore"]


def test_no_file_names_a_folder_of_one_machine():
    """/work/..., /root/..., /home/...: a folder of the machine a change was made on, meaningless in a clone (a
    shared tool is named by its command, a data set by its archive or an option). .gitignore's `/work/` is a
    pattern of the repository, not such a path, and this file names them to find them."""
    found = []
    for path in tracked_text_files():
        if not path.is_file() or path.resolve() == Path(__file__).resolve():
            continue
        for number, line in enumerate(path.read_text(encoding="utf-8", errors="replace").splitlines(), 1):
            if MACHINE_FOLDER.search(line):
                found.append(f"{path.relative_to(REPO)}:{number}: {line.strip()[:100]}")
    assert not found, "paths of one machine:\n  " + "\n  ".join(found)


def test_control_a_broken_path_is_reported_and_a_good_one_is_not(tmp_path):
    """The checker itself: a page with deliberately broken references and good ones beside them."""
    (tmp_path / "other.md").write_text("# Other page\n\n## A section\n", encoding="utf-8")
    page = tmp_path / "page.md"
    page.write_text(
        "# Page\n\n"
        "Good: [other](other.md), [section](other.md#a-section), [here](#page), [site](https://example.org/x.md),\n"
        "`t2m/service/settings.py`, t2m/bundles/<name>/MODEL_CARD.md, `t2m.service.settings.Settings`,\n"
        "`t2m.bundle`, `t2m.X...`, t2m.generate([(\"a person walks\", 3.0)]), meta/mean.npy, DIR/Mean.npy,\n"
        "[the contracts](" + str(REPO / "docs" / "contracts.md") + ").\n\n"
        "Broken: [gone](missing.md), [no section](other.md#no-such-section), `t2m/service/no_such.py`,\n"
        "model/captions.py, `t2m.service.no_such_module`, `t2m.service.settings.NoSuchName`.\n",
        encoding="utf-8")
    problems = problems_in_text(page.read_text(encoding="utf-8"), page)
    assert problems == [
        "link (missing.md): no such file",
        "link (other.md#no-such-section): no heading #no-such-section in other.md",
        "path t2m/service/no_such.py: no such file or folder",
        f"path model/captions.py: no such file (from the repository root or {tmp_path.name}/)",
        "module t2m.service.no_such_module: t2m.service has no 'no_such_module'",
        "module t2m.service.settings.NoSuchName: t2m.service.settings has no 'NoSuchName'",
    ]
