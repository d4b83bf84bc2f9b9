"""scripts/render_motions.py draws real motion: a contact sheet PNG and an animated GIF, small and readable."""
from __future__ import annotations

import numpy as np
import pytest
from PIL import Image

from scripts.render_motions import Camera, SheetRow, _pick_frames, contact_sheet, stream_gif
from t2m.motion.bvh import read_bvh
from t2m.motion.retarget import bvh_to_smpl22
from t2m.motion.skeleton import SMPL22


@pytest.fixture(scope="module")
def walk_and_wave(bandai_clip) -> tuple[np.ndarray, np.ndarray]:
    walk = bvh_to_smpl22(read_bvh(bandai_clip("dataset-1_walk_normal_001")))[:60]
    wave = bvh_to_smpl22(read_bvh(bandai_clip("dataset-2_wave-left-hand_youthful_007")))[:40]
    wave[..., [0, 2]] += walk[-1, 0, [0, 2]] - wave[0, 0, [0, 2]]      # continue where the walk ends
    return walk, wave


def test_camera_sees_the_front_left():
    """Facing +Z, seen from the front-left: the body's left (+X) is on the screen's right, up is up, the front near."""
    camera = Camera(np.array([0.0, 0.0, 1.0]))
    left, right = SMPL22.joint_names.index("left_shoulder"), SMPL22.joint_names.index("right_shoulder")
    points = np.zeros((22, 3))
    points[left], points[right] = [0.2, 1.4, 0.0], [-0.2, 1.4, 0.0]
    screen, depth = camera.project(points, np.zeros(3))
    assert screen[left, 0] > screen[right, 0] and screen[left, 1] > 1.2 and depth[left] > depth[right]
    ahead, _ = camera.project(np.array([[0.0, 0.0, 1.0]]), np.zeros(3))
    assert ahead[0, 0] < 0 and ahead[0, 1] < 0   # walking forward heads to the screen's left, towards the viewer


def test_frames_include_every_join():
    assert _pick_frames(140, 8, [60, 100]) == sorted(set(_pick_frames(140, 8, [60, 100])))
    assert {60, 100} <= set(_pick_frames(140, 8, [60, 100]))


def test_contact_sheet_and_gif(walk_and_wave, tmp_path):
    walk, wave = walk_and_wave
    stream = np.concatenate([walk, wave])
    sheet = contact_sheet([SheetRow(walk, "a real walk"), SheetRow(stream, "walk then wave", (60,))],
                          tmp_path / "sheet.png", frames_per_row=4)
    with Image.open(sheet) as image:
        width, height = image.size
        pixels = np.asarray(image.convert("RGB"))
    assert width > 400 and height > 300 and sheet.stat().st_size < 1.5e6
    assert (np.abs(pixels.astype(int) - [214, 39, 40]).sum(-1) < 60).any(), "no right-side (red) bone drawn"
    assert (np.abs(pixels.astype(int) - [31, 95, 191]).sum(-1) < 60).any(), "no left-side (blue) bone drawn"

    gif = stream_gif(stream, ["a real walk", "a real wave"], [0, 60], tmp_path / "stream.gif", every=10)
    with Image.open(gif) as image:
        assert image.n_frames == 10 and image.info["duration"] == 500
    with pytest.raises(ValueError, match="sentences"):
        stream_gif(stream, ["one"], [0, 60], tmp_path / "bad.gif")


def test_the_edit_picture_is_drawn_and_a_bad_bundle_is_one_line(tmp_path, capsys):
    """scripts/render_edit.py: the README's edit picture (two rows, a PNG), and a missing bundle refused in one line."""
    from PIL import Image

    from scripts.render_edit import main as render_edit

    out = tmp_path / "edit.png"
    assert render_edit(["--out", str(out)]) == 0
    assert "bit-identical" in capsys.readouterr().out
    with Image.open(out) as image:
        assert image.format == "PNG" and image.height > 200 and image.width > 600
    assert render_edit(["--bundle", str(tmp_path / "nowhere"), "--out", str(tmp_path / "x.png")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error:") and len(err.strip().splitlines()) == 1
