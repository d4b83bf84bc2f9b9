"""The viewer's files are served by the app and reach nothing outside it (no CDN, works offline)."""
from __future__ import annotations

import re
from pathlib import Path

from fastapi.testclient import TestClient

from t2m.service.app import create_app
from t2m.service.settings import Settings

STATIC = Path(__file__).resolve().parents[2] / "t2m" / "service" / "static"


def _client() -> TestClient:
    # No `with`: the lifespan (model loading) does not run; the page needs no model.
    return TestClient(create_app(Settings(bundle_path=Path("no-model-needed"))))


def test_root_serves_the_page_and_its_assets():
    client = _client()
    page = client.get("/")
    assert page.status_code == 200 and page.headers["content-type"].startswith("text/html")
    assets = re.findall(r'(?:src|href)="(static/[^"]+)"', page.text)
    assert sorted(assets) == ["static/viewer.css", "static/viewer/main.js"]
    assert '<script type="module" src="static/viewer/main.js">' in page.text
    modules = sorted(path.name for path in (STATIC / "viewer").glob("*.js"))
    for asset in ["static/viewer.css", *(f"static/viewer/{name}" for name in modules)]:
        answer = client.get("/" + asset)
        assert answer.status_code == 200 and answer.content == (STATIC / asset.split("/", 1)[1]).read_bytes()
    for name in modules:
        assert client.get(f"/static/viewer/{name}").headers["content-type"].split(";")[0] in (
            "text/javascript", "application/javascript")


def test_the_viewer_modules_import_only_each_other():
    """main.js reaches every module through relative static imports, and each import names a module that exists."""
    folder = STATIC / "viewer"
    reached, todo = set(), ["main.js"]
    while todo:
        name = todo.pop()
        if name in reached:
            continue
        assert (folder / name).is_file(), f"{name} is imported but missing"
        reached.add(name)
        todo += re.findall(r"^import \{[^}]*\} from '\./([\w]+\.js)';$", (folder / name).read_text(), re.M)
    assert reached == {path.name for path in folder.glob("*.js")}


def test_viewer_files_reference_nothing_external():
    for path in [*STATIC.glob("*.*"), *(STATIC / "viewer").glob("*.js")]:
        text = path.read_text()
        external = re.search(r"(https?:)?//[a-z0-9.-]+\.[a-z]{2,}", text, re.I)
        assert not external, f"{path.name} references an external URL"
        assert "@import" not in text and "import(" not in text, path.name


def test_page_calls_only_the_documented_endpoints():
    script = "\n".join(path.read_text() for path in sorted((STATIC / "viewer").glob("*.js")))
    # fetch('health'); postJson('generate' | 'edit', body): relative paths, so a proxy's path prefix is kept
    assert set(re.findall(r"(?:fetch|postJson)\('([^']+)'", script)) == {"generate", "edit", "health"}
    assert "fetch(path," in script and "fetch('/" not in script
