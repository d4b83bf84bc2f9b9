"""The browser viewer in a real headless Chromium against a real `t2m serve` on loopback.

Types sentences, clicks Generate, waits for the page to report the frames (streamed: it starts playing with the
first frames message), checks that the skeleton is drawn and animates, that orbiting changes the view, that BVH and
glb downloads arrive, that a 422 names the field on the page, and that the console stays clean. The screenshot lands
in artifacts/viewer/ (env T2M_ARTIFACTS_DIR overrides).
"""
from __future__ import annotations

import io
import json
import os
import shutil
import time
from pathlib import Path

import numpy as np
import pytest
from chromium_cdp import HeadlessChromium, find_chromium

from benchmarks.server_process import running_server

pytestmark = pytest.mark.clients

REPO = Path(__file__).resolve().parents[2]
RIGHT_BONE_RGB = np.array([0xF5, 0xA3, 0x5C])  # viewer.js SIDE_COLORS.right: only right-side bones use it


def _artifacts_dir() -> Path:
    path = Path(os.environ.get("T2M_ARTIFACTS_DIR", REPO / "artifacts")) / "viewer"
    path.mkdir(parents=True, exist_ok=True)
    return path


@pytest.fixture(scope="module")
def bundle_dir(tmp_path_factory) -> Path:
    """T2M_TEST_BUNDLE, else the default model if it is there, else a tiny random bundle."""
    if os.environ.get("T2M_TEST_BUNDLE"):
        return Path(os.environ["T2M_TEST_BUNDLE"])
    default = REPO / "t2m" / "bundles" / "default"
    if (default / "manifest.json").exists():
        return default
    torch = pytest.importorskip("torch")
    torch.set_num_threads(1)
    from t2m.export.families.gpt_random import build_random_bundle

    return build_random_bundle(tmp_path_factory.mktemp("bundle") / "tiny")


@pytest.fixture(scope="module")
def server(bundle_dir, tmp_path_factory):
    with running_server(bundle_dir, log_dir=tmp_path_factory.mktemp("server")) as live:
        yield live


@pytest.fixture(scope="module")
def renamed_copy(bundle_dir, tmp_path_factory) -> Path:
    """The same bundle under another manifest name (the manifest is not hashed), to serve two models."""
    copy = tmp_path_factory.mktemp("bundle") / "copy"
    shutil.copytree(bundle_dir, copy)
    manifest = json.loads((copy / "manifest.json").read_text())
    manifest["name"] += "-copy"
    (copy / "manifest.json").write_text(json.dumps(manifest))
    return copy


@pytest.fixture
def browser(tmp_path):
    if not find_chromium():
        pytest.skip("chromium is not installed (scripts/install_clients.sh)")
    profile = tmp_path / "profile"
    profile.mkdir()
    chromium = HeadlessChromium(profile, tmp_path / "downloads")
    yield chromium
    chromium.close()


def _pixels(png: bytes) -> np.ndarray:
    from PIL import Image

    return np.asarray(Image.open(io.BytesIO(png)).convert("RGB")).astype(np.int16)


def _right_bone_pixels(pixels: np.ndarray) -> int:
    return int((np.abs(pixels - RIGHT_BONE_RGB).max(axis=-1) < 24).sum())


def test_generate_animates_and_downloads(server, browser, bundle_dir):
    browser.navigate(server.url + "/")
    browser.wait_for("document.querySelectorAll('.segment-row').length === 2")
    browser.wait_for("document.getElementById('server-status').classList.contains('ready')", timeout_s=30)
    assert browser.evaluate("document.getElementById('model-field').hidden") is True   # one model: no choice shown
    before = _pixels(browser.canvas_png("#view"))
    assert _right_bone_pixels(before) == 0, "a skeleton is drawn before anything was generated"

    # Edit the form as a user would: replace the first sentence, remove the second row, add a new one.
    browser.type_into(".segment-row:nth-child(1) .seg-text", "a person walks forward slowly")
    browser.click(".segment-row:nth-child(2) .remove-row")
    browser.wait_for("document.querySelectorAll('.segment-row').length === 1")
    browser.click("#add-row")
    browser.type_into(".segment-row:nth-child(2) .seg-text", "a person jumps")
    browser.type_into(".segment-row:nth-child(2) .seg-duration", "2")
    browser.type_into("#seed", "123")
    browser.click("#generate")

    state = browser.wait_for("['ready', 'error'].includes(document.body.dataset.state)"
                             " && document.body.dataset.state", timeout_s=120)
    message = browser.evaluate("document.getElementById('message').textContent")
    assert state == "ready", f"page reports {state}: {message}"
    frames = int(browser.evaluate("document.body.dataset.frames"))
    assert frames == sum(round(seconds * 20) for seconds in (3, 2))   # exact durations: round(d * fps) per segment
    # The answer was streamed: playback began with the first frames message, before the rest had arrived.
    assert 0 < int(browser.evaluate("document.body.dataset.framesAtStart")) < frames
    assert "seed 123" in message
    # The model's warnings are shown: the default model has a caption index and never saw anyone jump.
    warnings = browser.evaluate("Array.from(document.querySelectorAll('#warnings li')).map(li => li.textContent)")
    if (bundle_dir / "caption_index.npz").exists():
        assert browser.evaluate("document.getElementById('warnings').hidden") is False
        assert [w.split(":")[0] for w in warnings] == ["segments.1.text"], warnings
    else:
        assert warnings == []
    strip = browser.evaluate("Array.from(document.querySelectorAll('#segment-strip span')).map(s => s.textContent)")
    assert strip[:2] == ["a person walks forward slowly", "a person jumps"]

    # It animates: the frame counter and the canvas move on by themselves.
    first_frame = int(browser.evaluate("document.body.dataset.frame"))
    first = _pixels(browser.canvas_png("#view"))
    browser.page.drain(0.6)
    second = _pixels(browser.canvas_png("#view"))
    assert int(browser.evaluate("document.body.dataset.frame")) != first_frame
    assert np.abs(first - second).mean() > 0.01
    assert first.std() > 10.0, "the canvas is (nearly) uniform"
    assert _right_bone_pixels(first) > 30, "no right-side bone pixels: the skeleton is not drawn"
    caption = browser.evaluate("document.getElementById('caption').textContent")
    assert caption in strip

    screenshot = browser.screenshot(_artifacts_dir() / "viewer.png")
    assert screenshot.stat().st_size > 10_000

    # Paused, the picture holds still; a drag on the canvas orbits the camera; the slider moves the frame.
    browser.click("#play")
    assert browser.evaluate("document.getElementById('play').textContent") == "Play"
    browser.page.drain(2.0)  # the camera's follow settles
    still_a = _pixels(browser.canvas_png("#view"))
    browser.page.drain(0.3)
    still_b = _pixels(browser.canvas_png("#view"))
    assert np.abs(still_a - still_b).max() == 0
    browser.drag((700, 400), (900, 430), steps=8)
    browser.page.drain(0.2)
    orbited = _pixels(browser.canvas_png("#view"))
    assert np.abs(orbited - still_b).mean() > 0.5
    browser.evaluate("(() => { const s = document.getElementById('frame-slider'); s.value = '0';"
                     " s.dispatchEvent(new Event('input')); })()")
    assert browser.evaluate("document.body.dataset.frame") == "0"

    # Downloads: the same request again as BVH and glb, saved by the browser.
    browser.click("#download-bvh")
    browser.wait_for("(document.body.dataset.lastDownload || '').startsWith('motion.bvh')", timeout_s=120)
    browser.click("#download-glb")
    browser.wait_for("(document.body.dataset.lastDownload || '').startsWith('motion.glb')", timeout_s=120)
    deadline = time.monotonic() + 10
    while len(browser.completed_downloads()) < 2 and time.monotonic() < deadline:
        time.sleep(0.1)
    saved = browser.completed_downloads()
    assert saved["motion.bvh"].read_bytes().startswith(b"HIERARCHY")
    assert saved["motion.glb"].read_bytes()[:4] == b"glTF"

    assert browser.console_errors() == []


def test_bad_input_is_explained_on_the_page(server, browser):
    browser.navigate(server.url + "/")
    browser.wait_for("document.querySelectorAll('.segment-row').length === 2")

    # Caught in the page: an empty sentence is named before anything is sent.
    browser.type_into(".segment-row:nth-child(2) .seg-text", "   ")
    browser.click("#generate")
    message = browser.evaluate("document.getElementById('message').textContent")
    assert "sentence 2" in message and "empty" in message
    assert browser.evaluate("document.querySelector('.segment-row:nth-child(2) .seg-text')"
                            ".classList.contains('invalid')")

    # Caught by the server: a 422 whose field is named on the page and marked in the form.
    browser.type_into(".segment-row:nth-child(2) .seg-text", "a person jumps")
    browser.type_into(".segment-row:nth-child(2) .seg-duration", "99")
    browser.click("#generate")
    browser.wait_for("document.body.dataset.state === 'error'", timeout_s=30)
    message = browser.evaluate("document.getElementById('message').textContent")
    assert "segments.1.duration" in message
    assert browser.evaluate("document.querySelector('.segment-row:nth-child(2) .seg-duration')"
                            ".classList.contains('invalid')")
    # The only console error allowed is the browser's own note about the 422 response.
    unexpected = [e for e in browser.console_errors() if "422" not in e]
    assert unexpected == []


def test_the_model_choice_picks_a_served_model(bundle_dir, renamed_copy, browser, tmp_path):
    """Two bundles served: the page lists both (the default first and selected), and the chosen one answers."""
    default = json.loads((bundle_dir / "manifest.json").read_text())["name"]
    other = default + "-copy"
    with running_server(bundle_dir, extra_models=[renamed_copy], log_dir=tmp_path / "server") as live:
        browser.navigate(live.url + "/")
        browser.wait_for("!document.getElementById('model-field').hidden", timeout_s=30)
        options = browser.evaluate("Array.from(document.querySelectorAll('#model option')).map(o => o.value)")
        assert options == [default, other]
        assert browser.evaluate("document.getElementById('model').value") == default
        assert "2 models" in browser.evaluate("document.getElementById('server-status').textContent")
        browser.evaluate(f"(() => {{ const s = document.getElementById('model'); s.value = {json.dumps(other)};"
                         " s.dispatchEvent(new Event('change')); })()")
        browser.type_into("#seed", "5")
        browser.click("#generate")
        state = browser.wait_for("['ready', 'error'].includes(document.body.dataset.state)"
                                 " && document.body.dataset.state", timeout_s=120)
        assert state == "ready", browser.evaluate("document.getElementById('message').textContent")
        assert other in browser.evaluate("document.getElementById('model-info').textContent")
        assert browser.console_errors() == []
