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
    assert sorted(assets) == ["static/viewer.css", "static/viewer.js"]
    for asset in assets:
        answer = client.get("/" + asset)
        assert answer.status_code == 200 and answer.content == (STATIC / asset.split("/", 1)[1]).read_bytes()
    assert client.get("/static/viewer.js").headers["content-type"].split(";")[0] in (
        "text/javascript", "application/javascript")


def test_viewer_files_reference_nothing_external():
    for path in STATIC.iterdir():
        text = path.read_text()
        external = re.search(r"(https?:)?//[a-z0-9.-]+\.[a-z]{2,}", text, re.I)
        assert not external, f"{path.name} references an external URL"
        assert "@import" not in text and "import(" not in text, path.name


def test_page_calls_only_the_documented_endpoints():
    script = (STATIC / "viewer.js").read_text()
    # fetch('health'); postJson('generate' | 'edit', body): relative paths, so a proxy's path prefix is kept
    assert set(re.findall(r"(?:fetch|postJson)\('([^']+)'", script)) == {"generate", "edit", "health"}
    assert "fetch(path," in script and "fetch('/" not in script
