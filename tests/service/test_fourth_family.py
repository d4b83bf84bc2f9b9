"""The proof of the family seam: a fourth family defined in tests/service/tiny_family.py (nothing under t2m/
edited or naming it) is registered, exported with `t2m export --family fourth`, loaded and served over HTTP: a
3-sentence stream, whole and streamed, with the same seeds giving the same motion."""
from __future__ import annotations

import json
from pathlib import Path

import pytest
import tiny_family
from served_stream import check_whole_and_streamed

REPO = Path(__file__).resolve().parents[2]
STREAM = [{"text": "a person walks forward", "duration": 3.0},
          {"text": "a person waves with the right hand", "duration": 2.0},
          {"text": "a person bows", "duration": 2.0}]


@pytest.fixture(scope="module")
def tiny_bundle(tmp_path_factory: pytest.TempPathFactory):
    """The family registered for this module only, and a bundle exported through the `t2m export` CLI."""
    import torch

    from t2m.bundle import register_family, unregister_family
    from t2m.cli.main import main

    torch.set_num_threads(1)
    register_family(tiny_family.FAMILY)
    out = tmp_path_factory.mktemp("fourth") / "bundle"
    try:
        assert main(["export", "--family", "fourth", "--fourth-seed", "3", "-o", str(out)]) == 0
        yield out
    finally:
        unregister_family("fourth")


def test_no_file_under_t2m_names_the_fourth_family():
    """The seam held: the family exists only in the test suite."""
    hits = [path for path in (REPO / "t2m").rglob("*.py") if "tiny_family" in path.read_text(encoding="utf-8")
            or '"fourth"' in path.read_text(encoding="utf-8")]
    assert hits == []


def test_the_export_cli_offers_the_family_and_refuses_its_options_elsewhere(tiny_bundle, capsys):
    from t2m.cli.main import main

    manifest = json.loads((tiny_bundle / "manifest.json").read_text())
    assert manifest["family"] == "fourth" and "fourth_codes.onnx" in manifest["files"]
    capsys.readouterr()
    code = main(["export", "--family", "gpt", "--vq", "x", "--gpt", "y", "--fourth-seed", "1", "-o", "z"])
    assert code == 2 and "--fourth-seed: only with --family fourth" in capsys.readouterr().err


def test_the_fourth_family_is_served_over_http_with_streams(tiny_bundle, make_client):
    from t2m.service.settings import Settings

    client = make_client(Settings(bundle_path=tiny_bundle, intra_op_threads=1))
    health = client.get("/health").json()
    assert health["model"]["extra"]["family"] == "fourth"
    assert health["model"]["extra"]["streaming"]["early_frames"] is False
    body = {"segments": STREAM, "seed": 11, "guidance": 2.0}
    check_whole_and_streamed(client, body, [(0, 60), (60, 100), (100, 140)])

    for fmt in ("bvh", "glb"):
        assert client.post("/generate", json={**body, "format": fmt}).status_code == 200
    refused = client.post("/generate", json={"segments": [{"text": "walk", "duration": None}]})
    assert refused.status_code == 422 and "segments.0.duration" in refused.text


def test_a_manifest_of_an_unregistered_family_is_refused_naming_the_field(tiny_bundle, tmp_path):
    from t2m.bundle import BundleError, read_manifest, unregister_family

    unregister_family("fourth")
    try:
        with pytest.raises(BundleError, match=r"field 'family' must be one of .*got 'fourth'"):
            read_manifest(tiny_bundle)
    finally:
        from t2m.bundle import register_family

        register_family(tiny_family.FAMILY)
