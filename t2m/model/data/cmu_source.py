"""The captioned CMU trials (index.json + BVH on Reallusion's CC rig and/or DeepMimic humanoid3d frames) read into
SMPL-22 joints at 20 fps, not yet normalised (the builder cuts them by the sentences' timings first).

- CC-rig BVH: forward kinematics, `retarget.CC_RIG`, centimetres -> metres, 60 -> 20 fps. Some conversions start
  with a T-pose frame that the converter prepended (checked on the archive: the ten trials of subject 07, not the
  others, although the archive's README says every file does). Frame 0 is dropped when it is one: some joint jumps
  more than TPOSE_JUMP_M = 0.2 m to frame 1 (12 m/s at 60 fps; the body then teleports, on the real T-pose frames
  2.4-3.0 m) while frame 1 to 2 moves less than that. With the T-pose gone, frame counts equal the DeepMimic
  conversions of the same trials (to one frame at 20 fps).
- DeepMimic: `motion.deepmimic` forward kinematics, `motion.deepmimic_smpl` fills the joints humanoid3d lacks.
"""
from __future__ import annotations

import json
import logging
import os
import tarfile
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from t2m.motion.bvh import read_bvh
from t2m.motion.constants import FPS
from t2m.motion.deepmimic import HUMANOID3D, read_character, read_deepmimic
from t2m.motion.deepmimic_smpl import deepmimic_to_smpl22
from t2m.motion.retarget import CC_RIG, clean_fps, map_positions
from t2m.motion.transforms import resample

__all__ = ["ARCHIVE_TOP", "CaptionedSegment", "CmuTrial", "drop_tpose", "is_cmu_source", "open_cmu_source",
           "read_form", "read_index"]

log = logging.getLogger("t2m.data")

ARCHIVE_TOP = "cmu-captioned"
TPOSE_JUMP_M = 0.2
FORMS = ("bvh", "deepmimic")


@dataclass(frozen=True)
class CaptionedSegment:
    """One HumanML3D entry: a stretch of a trial (seconds from its start), people's sentences, HumanML3D's split."""

    humanml3d_id: int
    split: str
    start_s: float
    end_s: float
    sentences: tuple[str, ...]


@dataclass(frozen=True)
class CmuTrial:
    """A CMU trial `SS_TT`: its files by form ('bvh', 'deepmimic'), CMU's description, its captioned segments."""

    trial_id: str
    files: dict[str, str]
    description: str
    segments: tuple[CaptionedSegment, ...]


def _segment(raw: object, where: str) -> CaptionedSegment:
    try:
        assert isinstance(raw, dict)
        segment = CaptionedSegment(int(raw["humanml3d_id"]), str(raw["split"]), float(raw["start_s"]),
                                   float(raw["end_s"]), tuple(" ".join(str(s).split()) for s in raw["sentences"]))
    except (AssertionError, KeyError, TypeError, ValueError) as error:
        raise ValueError(f"{where}: expected {{humanml3d_id, split, start_s, end_s, sentences}} ({error!r})") from None
    if segment.split not in ("train", "test") or not 0 <= segment.start_s < segment.end_s \
            or not segment.sentences or not all(segment.sentences):
        raise ValueError(f"{where}: expected split train/test, 0 <= start_s < end_s and non-empty sentences")
    return segment


def read_index(path: str | os.PathLike) -> list[CmuTrial]:
    """index.json -> trials sorted by id (checked: known file forms, unique HumanML3D ids)."""
    try:
        document = json.loads(Path(path).read_text(encoding="utf-8"))
        assert isinstance(document, dict)
    except (OSError, ValueError, AssertionError) as error:
        raise ValueError(f"{path}: expected the CMU index JSON object {{\"SS_TT\": {{files, cmu, humanml3d}}}} "
                         f"({error})") from None
    trials, seen = [], set()
    for trial_id in sorted(document):
        entry = document[trial_id]
        where = f"{path}: trial {trial_id}"
        files: dict[str, str] = {}
        for name in entry.get("files", []) if isinstance(entry, dict) else []:
            form = "bvh" if str(name).endswith(".bvh") else "deepmimic" if str(name).startswith("deepmimic/") else None
            if form is None or form in files:
                raise ValueError(f"{where}: file {name!r} is neither the one .bvh nor the one deepmimic/ file")
            files[form] = str(name)
        if not files:
            raise ValueError(f"{where}: expected 'files' listing a .bvh and/or a deepmimic/ file")
        raws = entry.get("humanml3d") or []
        segments = tuple(_segment(raw, f"{where}: humanml3d[{k}]") for k, raw in enumerate(raws))
        for segment in segments:
            if segment.humanml3d_id in seen:
                raise ValueError(f"{where}: HumanML3D id {segment.humanml3d_id} appears twice in the index")
            seen.add(segment.humanml3d_id)
        trials.append(CmuTrial(trial_id, files, str((entry.get("cmu") or {}).get("description", "")), segments))
    return trials


def is_cmu_source(source: str | os.PathLike) -> bool:
    """Whether `source` is the CMU archive (first member under cmu-captioned/) or its extracted directory."""
    path = Path(source)
    if path.is_dir():
        return (path / ARCHIVE_TOP).is_dir() or (path.name == ARCHIVE_TOP)
    if path.is_file() and tarfile.is_tarfile(path):
        with tarfile.open(path, "r:*") as tar:
            first = tar.next()
        return first is not None and Path(first.name).parts[:1] == (ARCHIVE_TOP,)
    return False


def open_cmu_source(source: str | os.PathLike, workdir: str | os.PathLike | None = None) -> tuple[Path, Path | None]:
    """(the `cmu-captioned` directory, temporary directory to delete or None): the source or an extraction of it."""
    path = Path(source)
    if not path.exists():
        raise FileNotFoundError(2, "no such file or directory", str(path))
    if path.is_dir():
        root = path / ARCHIVE_TOP if (path / ARCHIVE_TOP).is_dir() else path
        return root, None
    temporary = Path(tempfile.mkdtemp(prefix="t2m-cmu-", dir=workdir))
    log.info("extracting %s into %s", path, temporary)
    with tarfile.open(path, "r:*") as tar:
        for member in tar:
            parts = Path(member.name).parts
            if member.isfile() and parts[:1] == (ARCHIVE_TOP,) and ".." not in parts:
                tar.extract(member, temporary, filter="data")
    return temporary / ARCHIVE_TOP, temporary


def drop_tpose(positions: np.ndarray) -> tuple[np.ndarray, bool]:
    """Positions without a leading T-pose frame (see the module docstring), and whether one was dropped."""
    if len(positions) < 3:
        return positions, False
    first_jump = float(np.abs(positions[1] - positions[0]).max())
    next_jump = float(np.abs(positions[2] - positions[1]).max())
    if first_jump > TPOSE_JUMP_M and next_jump < TPOSE_JUMP_M:
        return positions[1:], True
    return positions, False


def read_form(root: Path, trial: CmuTrial, form: str) -> tuple[np.ndarray, bool]:
    """SMPL-22 joints [T, 22, 3] in metres at 20 fps, not normalised, of one form; and whether a T-pose was dropped."""
    path = root / trial.files[form]
    if form == "bvh":
        bvh = read_bvh(path)
        if bvh.num_frames < 3:
            raise ValueError(f"{path}: expected a BVH with at least 3 frames, got {bvh.num_frames}")
        positions, dropped = drop_tpose(map_positions(bvh, CC_RIG))
        fps = clean_fps(bvh.fps)
        joints = positions if fps == FPS else resample(positions, fps, FPS)
        return joints.astype(np.float32), dropped
    character_file = root / "deepmimic" / "characters" / "humanoid3d.txt"
    character = read_character(character_file) if character_file.is_file() else HUMANOID3D
    if character.names != HUMANOID3D.names:
        raise ValueError(f"{character_file}: expected humanoid3d's joints {', '.join(HUMANOID3D.names)}")
    return deepmimic_to_smpl22(read_deepmimic(path, character), FPS, normalize=False), False
