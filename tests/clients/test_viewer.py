"""The browser viewer in a real headless Chromium against a real `t2m serve` on loopback.

Types sentences, clicks Generate, waits for the page to report the frames (streamed: it starts playing with the
first frames message), checks that the skeleton is drawn and animates, that orbiting changes the view, that BVH and
glb downloads arrive, that a 422 names the field on the page, and that the console stays clean. Then edits a
generated motion from the timeline (POST /edit with the answer's handle) and checks the request, the frames kept
and the new timeline. The screenshots land in artifacts/viewer/ (env T2M_ARTIFACTS_DIR overrides).
"""
from __future__ import annotations

import io
import json
import os
import shutil
import time
from pathlib import Path
from typing import Any
from urllib.request import Request, urlopen

import numpy as np
import pytest
from chromium_cdp import HeadlessChromium, find_chromium

from t2m.testing.server_process import running_server

pytestmark = pytest.mark.clients

REPO = Path(__file__).resolve().parents[2]
RIGHT_BONE_RGB = np.array([0xF5, 0xA3, 0x5C])  # viewer/state.js SIDE_COLORS.right: only right-side bones use it


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
    from t2m.families.gpt.random_bundle import build_random_bundle

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


def _requests_to(browser, path: str) -> list[dict[str, Any]]:
    """The page's requests to `path` seen so far (CDP Network.requestWillBeSent: the request log), in order."""
    browser.page.drain()
    return [e["params"] for e in browser.page.events
            if e["method"] == "Network.requestWillBeSent" and e["params"]["request"]["url"].endswith(path)]


def _post_edit(server_url: str, body: dict[str, Any]) -> dict[str, Any]:
    """POST /edit from here: the same handle and edits give the same answer (docs/api.md), so this is what the page
    was answered (Network.getResponseBody is no witness: Chromium may log a stream the page read to its end as
    aborted, and then has no body to give)."""
    request = Request(server_url + "/edit", data=json.dumps(body).encode(),
                      headers={"Content-Type": "application/json"})
    with urlopen(request, timeout=120) as response:
        return dict(json.loads(response.read()))


def _timeline(browser) -> list[str]:
    return list(browser.evaluate("Array.from(document.querySelectorAll('#segment-strip span:not(.rest)'))"
                                 ".map(s => s.textContent)"))


def test_a_segment_is_edited_from_the_timeline(server, browser):
    """Generate three sentences, select the last on the timeline, change its text, regenerate: POST /edit gets the
    handle and that segment, the frames before the edit's reach are kept bit for bit, the timeline shows the new
    text; a re-roll sends the new handle and a seed; a 422 names the field; the console stays clean."""
    with urlopen(server.url + "/health", timeout=10) as response:
        model = json.loads(response.read())["model"]
    kinds, per_token = model["extra"]["edits"], model["frames_per_token"]
    browser.page.send("Network.enable")   # the request log: every request the page sends, with its body
    browser.navigate(server.url + "/")
    browser.wait_for("document.querySelectorAll('.segment-row').length === 2")
    browser.wait_for("document.getElementById('server-status').classList.contains('ready')", timeout_s=30)
    assert browser.evaluate("document.getElementById('edit-panel').hidden") is True   # nothing to edit yet

    # Durations in whole code steps (8 frames at 20 fps: multiples of 0.4 s), so no segment's time map changes.
    texts = ["a person walks forward", "a person turns around", "a person waves with the right hand"]
    seconds = [2.4, 2.0, 2.4]
    browser.click("#add-row")
    for row, (text, duration) in enumerate(zip(texts, seconds), start=1):
        browser.type_into(f".segment-row:nth-child({row}) .seg-text", text)
        browser.type_into(f".segment-row:nth-child({row}) .seg-duration", str(duration))
    browser.type_into("#seed", "7")
    browser.click("#generate")
    state = browser.wait_for("['ready', 'error'].includes(document.body.dataset.state)"
                             " && document.body.dataset.state", timeout_s=120)
    assert state == "ready", browser.evaluate("document.getElementById('message').textContent")
    handle = browser.evaluate("document.body.dataset.handle")   # the streamed answer's handle, kept by the page
    assert handle.startswith("t2m1.")
    generated = _post_edit(server.url, {"handle": handle, "edits": []})   # the handle's motion, bit for bit
    original = np.array(generated["frames"])
    assert int(browser.evaluate("document.body.dataset.frames")) == len(original)
    spans = [(s["start_frame"], s["end_frame"]) for s in generated["segments"]]
    assert [b - a for a, b in spans] == [round(d * 20) for d in seconds]

    # The timeline: one block per segment with its text, as wide as its frames; the playhead moves across it.
    assert _timeline(browser) == texts
    widths = browser.evaluate("(() => { const strip = document.getElementById('segment-strip');"
                              " const w = strip.getBoundingClientRect().width;"
                              " return Array.from(strip.children).map(s => s.getBoundingClientRect().width / w); })()")
    np.testing.assert_allclose(widths[:3], [(b - a) / len(original) for a, b in spans], atol=0.01)
    playhead = "document.getElementById('playhead').style.left"
    first = browser.evaluate(playhead)
    browser.page.drain(0.5)
    assert browser.evaluate(playhead) != first
    assert browser.evaluate("document.getElementById('edit-panel').hidden") is False
    assert browser.evaluate("document.getElementById('edit-regenerate').disabled") is True   # nothing selected

    # Select the last segment: its text in the edit bar; "upper body only" only where the model edits body parts.
    browser.click("#segment-strip span:nth-child(3)")
    browser.wait_for("document.body.dataset.selected === '2'")
    assert browser.evaluate("document.getElementById('edit-text').value") == texts[2]
    assert browser.evaluate("document.getElementById('edit-regenerate').disabled") is ("regenerate" not in kinds)
    assert browser.evaluate("document.getElementById('edit-upper').disabled") is ("body_part" not in kinds)
    assert browser.evaluate("document.body.dataset.editKinds") == ",".join(kinds)

    new_text = "a person sits down"
    browser.type_into("#edit-text", new_text)
    browser.click("#edit-regenerate")
    state = browser.wait_for("(document.body.dataset.edits === '1' || document.body.dataset.state === 'error')"
                             " && document.body.dataset.state", timeout_s=120)
    assert state == "ready", browser.evaluate("document.getElementById('message').textContent")

    # The request: the generation's handle, that segment and its new text, json; the answer replaces the motion
    # (and its handle is the one the page keeps: the same handle and edits give the same answer).
    edits = _requests_to(browser, "/edit")
    assert len(edits) == 1
    sent = json.loads(edits[0]["request"]["postData"])
    assert sent == {"handle": handle, "edits": [{"segment": 2, "text": new_text}], "format": "json"}
    answer = _post_edit(server.url, sent)
    assert [e["segment"] for e in answer["edited"]] == [2]
    assert browser.evaluate("document.body.dataset.handle") == answer["handle"] != handle
    edited = np.array(answer["frames"])
    assert int(browser.evaluate("document.body.dataset.frames")) == len(edited) == len(original)
    assert _timeline(browser) == [*texts[:2], new_text]
    assert browser.evaluate("document.body.dataset.selected") == "2"   # still selected, for the next edit
    assert browser.evaluate("document.getElementById('edit-text').value") == new_text
    # Frames before the edit, outside the decoder's reach of it, are the handle's motion's bit for bit (docs/api.md).
    first_step, rest = divmod(spans[2][0], per_token)
    assert rest == 0
    streaming = model["extra"].get("streaming", {})
    if streaming.get("lookahead_tokens") is not None:
        kept = (first_step - streaming["lookahead_tokens"]) * per_token
        assert kept > 0
        assert np.array_equal(edited[:kept], original[:kept])
    assert not np.array_equal(edited[spans[2][0]:], original[spans[2][0]:])   # the edit did change the segment
    browser.screenshot(_artifacts_dir() / "viewer-edit.png")
    # A download now is the edited motion: its handle with no edits, as BVH.
    browser.click("#download-bvh")
    browser.wait_for("(document.body.dataset.lastDownload || '').startsWith('motion.bvh')", timeout_s=120)
    download = json.loads(_requests_to(browser, "/edit")[-1]["request"]["postData"])
    assert download == {"handle": answer["handle"], "edits": [], "format": "bvh"}

    # A re-roll: the same segment again with a new random seed, sent with the edited motion's handle.
    browser.click("#edit-reroll")
    state = browser.wait_for("(document.body.dataset.edits === '2' || document.body.dataset.state === 'error')"
                             " && document.body.dataset.state", timeout_s=120)
    assert state == "ready", browser.evaluate("document.getElementById('message').textContent")
    second = json.loads(_requests_to(browser, "/edit")[2]["request"]["postData"])
    assert second["handle"] == answer["handle"]
    assert [set(e) for e in second["edits"]] == [{"segment", "seed"}] and second["edits"][0]["segment"] == 2
    assert _timeline(browser) == [*texts[:2], new_text]
    assert browser.console_errors() == []

    # A 422 names the field on the page and marks the edit bar's text (set past maxlength: the server's limit).
    browser.evaluate("document.getElementById('edit-text').value = 'a person waves '.repeat(30)")
    browser.click("#edit-regenerate")
    browser.wait_for("document.body.dataset.state === 'error'", timeout_s=30)
    message = browser.evaluate("document.getElementById('message').textContent")
    assert message.startswith("edits.0.") and ".text:" in message, message   # edits.0.regenerate.text: the union's tag
    assert browser.evaluate("document.getElementById('edit-text').classList.contains('invalid')")
    assert _timeline(browser) == [*texts[:2], new_text]   # the motion shown is kept
    assert [e for e in browser.console_errors() if "422" not in e] == []


def test_the_upper_body_is_regenerated_where_the_model_edits_body_parts(browser, tmp_path):
    """The masked model (body_part in /health `extra.edits`): "upper body only" is enabled, and a re-roll with it
    ticked sends a body_part edit of the selected segment; the edited motion replaces the shown one."""
    masked = REPO / "t2m" / "bundles" / "masked"
    if not (masked / "manifest.json").exists():
        pytest.skip("the masked model is not in t2m/bundles/masked")
    with running_server(masked, log_dir=tmp_path / "server") as live:
        browser.page.send("Network.enable")
        browser.navigate(live.url + "/")
        browser.wait_for("document.getElementById('server-status').classList.contains('ready')", timeout_s=60)
        browser.type_into("#seed", "3")
        browser.click("#generate")
        state = browser.wait_for("['ready', 'error'].includes(document.body.dataset.state)"
                                 " && document.body.dataset.state", timeout_s=120)
        assert state == "ready", browser.evaluate("document.getElementById('message').textContent")
        texts = _timeline(browser)
        assert len(texts) == 2
        assert "body_part" in browser.evaluate("document.body.dataset.editKinds").split(",")
        browser.click("#segment-strip span:nth-child(2)")
        browser.wait_for("document.body.dataset.selected === '1'")
        assert browser.evaluate("document.getElementById('edit-upper').disabled") is False
        browser.click("#edit-upper")
        assert browser.evaluate("document.getElementById('edit-upper').checked") is True
        frames_before = browser.evaluate("document.body.dataset.frames")
        browser.click("#edit-reroll")
        state = browser.wait_for("(document.body.dataset.edits === '1' || document.body.dataset.state === 'error')"
                                 " && document.body.dataset.state", timeout_s=120)
        assert state == "ready", browser.evaluate("document.getElementById('message').textContent")
        handle = browser.evaluate("document.body.dataset.handle")
        (request,) = _requests_to(browser, "/edit")
        edit = json.loads(request["request"]["postData"])
        assert edit["handle"] != handle   # the page keeps the edited motion's handle
        assert (_post_edit(live.url, edit)["frames"]
                != _post_edit(live.url, {"handle": edit["handle"], "edits": []})["frames"])   # the edit changed it
        assert [{k: v for k, v in e.items() if k != "seed"} for e in edit["edits"]] == [
            {"op": "body_part", "segment": 1, "part": "upper_body"}]
        assert isinstance(edit["edits"][0]["seed"], int)
        assert browser.evaluate("document.body.dataset.frames") == frames_before   # the same spans
        assert _timeline(browser) == texts
        assert "(upper body)" in browser.evaluate("document.getElementById('message').textContent")
        browser.screenshot(_artifacts_dir() / "viewer-edit-upper-body.png")
        assert browser.console_errors() == []
