"""Build a HumanML3D-layout dataset from the Bandai-Namco Research Motion Dataset (BVH clips + content/style labels).

    source (.tar.xz or extracted dir) -> BVH -> SMPL-22 joints (20 fps, normalised) -> 263-dim features
                                      -> templated captions -> train/val/test -> Mean/Std -> summary.json

Choices (also written into summary.json):
- clips shorter than MIN_FRAMES = 20 frames at 20 fps (1 s) are skipped: too short to be a motion. (HumanML3D's
  trainers use 40, but here that would drop ~445 of the 10 `raise-up-*` gesture clips, which are 1-2 s long.)
- clips longer than MAX_FRAMES = 196 frames (HumanML3D's cap, 9.8 s) are cut into ceil(T / 196) equal consecutive
  pieces, each normalised again (starts at the origin facing +Z); piece ids end in `_p<k>`.
- splits are per source clip, stratified by content x style: clips are ordered by (content, style, hash of id) and
  dealt in that order onto a fixed 10-slot pattern (8 train, 1 val, 1 test), so every label pair that has 10 clips
  gets ~80/10/10 and the global ratio is exact. Pieces and mirrors of a clip share its split.
- left/right labels are checked against the motion (`observed_side`): a clip whose motion clearly goes the other
  way (a few `walk-turn-*` clips turn the opposite way) is captioned with the mirrored label and listed under
  `relabelled` in summary.json; splits still use the file's labels. One-handed gestures (bye, guide, respond,
  call) get captions naming the hand that moved, when one clearly did.
- mirrored copies (HumanML3D's augmentation) have ids `M<id>`, joints reflected with left/right swapped, and captions
  with 'left'/'right' swapped.
- Mean/Std: over the train split's feature rows (originals and mirrors), then, as HumanML3D does, each channel group's
  std is replaced by the group's mean std (root rotation velocity, root linear velocity, root height, ric positions,
  rotations, local velocities, foot contacts) so that no single near-constant channel blows up; finally std is
  floored at STD_FLOOR = 1e-3 so a group that never varies cannot divide by ~0.
Output is identical for any number of workers (results are collected in clip order; nothing depends on timing).
"""
from __future__ import annotations

import hashlib
import json
import logging
import math
import multiprocessing
import os
import shutil
import tarfile
import tempfile
import time
from collections.abc import Iterable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import asdict, dataclass, field
from itertools import pairwise
from pathlib import Path
from typing import Any

import numpy as np

from t2m.model.data.captions import format_caption_line, make_captions, mirror_caption, mirror_label
from t2m.motion.bvh import read_bvh
from t2m.motion.constants import FPS
from t2m.motion.features import feature_dim, features_to_joints, joints_to_features, normalize_joints
from t2m.motion.retarget import BANDAI_NAMCO, bvh_to_smpl22
from t2m.motion.skeleton import SMPL22
from t2m.motion.transforms import mirror_joints

__all__ = [
    "BuildOptions",
    "ClipSource",
    "assign_splits",
    "build_dataset",
    "feature_statistics",
    "find_clips",
    "open_source",
    "prepare_output",
    "write_clip",
    "write_texts_and_splits",
]

log = logging.getLogger("t2m.data")

MIN_FRAMES = 20
MAX_FRAMES = 196
STD_FLOOR = 1e-3
SPLIT_PATTERN = ("train", "train", "train", "train", "val", "train", "train", "train", "train", "test")
LICENSE = "CC BY-NC 4.0"
ATTRIBUTION = ('Kobayashi et al., "Motion Capture Dataset for Practical Use of AI-based Motion Editing and '
               'Stylization", arXiv 2306.08861, Bandai Namco Research Inc.')
LAYOUT_ITEMS = ("new_joints", "new_joint_vecs", "texts", "Mean.npy", "Std.npy", "train.txt", "val.txt", "test.txt",
                "all.txt", "summary.json", "build.log")


@dataclass(frozen=True)
class ClipSource:
    """One BVH clip with its labels (from the JSON sidecar, checked against the file name)."""

    clip_id: str
    bvh_path: str
    content: str
    style: str


@dataclass
class BuildOptions:
    workers: int = 2
    mirror: bool = True
    limit: int | None = None
    min_frames: int = MIN_FRAMES
    max_frames: int = MAX_FRAMES
    captions_per_clip: int = 8
    overwrite: bool = False
    progress: bool = True


@dataclass
class ClipResult:
    """What a worker made of one clip: the items it wrote (id, frames) or why it was skipped."""

    clip: ClipSource
    items: list[tuple[str, int]] = field(default_factory=list)   # (item id, feature rows), originals then mirrors
    captions: dict[str, list[str]] = field(default_factory=dict)
    skipped: str | None = None
    relabelled: str | None = None   # the content label used instead of the file's, when the motion contradicts it
    source_frames: int = 0


# --- source -------------------------------------------------------------------------------------------------------
def _tar_members_needed(tar: tarfile.TarFile) -> Iterable[tarfile.TarInfo]:
    for member in tar:
        parts = Path(member.name).parts
        if not member.isfile() or ".." in parts or member.name.startswith("/"):
            continue
        in_data_or_cfg = len(parts) >= 2 and parts[-2] in ("data", "cfg")
        if (in_data_or_cfg and Path(member.name).suffix in (".bvh", ".json", ".txt")) \
                or parts[-1] in ("LICENSE", "README.md"):
            yield member


def open_source(source: str | os.PathLike, workdir: str | os.PathLike | None = None) -> tuple[Path, Path | None]:
    """The directory holding the dataset: `source` itself, or a fresh extraction of the tarball `source`.

    Returns (root, temporary directory to delete afterwards or None). Only BVH/JSON/label files are extracted.
    """
    path = Path(source)
    if not path.exists():
        raise FileNotFoundError(2, "no such file or directory", str(path))
    if path.is_dir():
        return path, None
    if not tarfile.is_tarfile(path):
        raise ValueError(f"--source {path}: neither a directory nor a tar archive")
    temporary = Path(tempfile.mkdtemp(prefix="t2m-bandai-", dir=workdir))
    log.info("extracting %s into %s", path, temporary)
    with tarfile.open(path, "r:*") as tar:
        for member in _tar_members_needed(tar):
            tar.extract(member, temporary, filter="data")
    return temporary, temporary


def _labels(cfg_file: Path) -> list[str]:
    """Label names of cfg/*_label.txt, whose lines look like `dataset-1_walk`."""
    names = []
    for number, line in enumerate(cfg_file.read_text(encoding="utf-8").splitlines(), start=1):
        line = line.strip()
        if not line:
            continue
        prefix, sep, name = line.partition("_")
        if not sep or not prefix.startswith("dataset-"):
            raise ValueError(f"{cfg_file}: line {number}: expected 'dataset-N_label', got {line!r}")
        names.append(name)
    return names


def find_clips(root: str | os.PathLike) -> list[ClipSource]:
    """Every `<dataset>/data/*.bvh` under root with its content/style label, sorted by id."""
    root = Path(root)
    clips: list[ClipSource] = []
    data_dirs = sorted(p for p in root.rglob("data") if p.is_dir() and (p.parent / "cfg").is_dir())
    if not data_dirs:
        raise ValueError(
            f"{root}: no Bandai-Namco dataset found (expected <dataset>/data/*.bvh next to <dataset>/cfg/)"
        )
    for data_dir in data_dirs:
        cfg = data_dir.parent / "cfg"
        contents = _labels(cfg / "content_label.txt")
        styles = _labels(cfg / "style_label.txt")
        for bvh_path in sorted(data_dir.glob("*.bvh")):
            sidecar = bvh_path.with_suffix(".json")
            if not sidecar.is_file():
                raise ValueError(f"{bvh_path}: label file {sidecar.name} is missing")
            try:
                label = json.loads(sidecar.read_text(encoding="utf-8"))
                content, style = contents[int(label["content"])], styles[int(label["style"])]
            except (ValueError, KeyError, IndexError, TypeError) as error:
                raise ValueError(f"{sidecar}: expected {{\"content\": i, \"style\": j}} indexing cfg labels "
                                 f"({error})") from None
            stem_parts = bvh_path.stem.split("_")
            if len(stem_parts) >= 3 and (stem_parts[1], stem_parts[2]) != (content, style):
                raise ValueError(f"{sidecar}: labels {content}/{style} disagree with the file name {bvh_path.name}")
            clips.append(ClipSource(bvh_path.stem, str(bvh_path), content, style))
    clips.sort(key=lambda c: c.clip_id)
    ids = [c.clip_id for c in clips]
    if len(set(ids)) != len(ids):
        raise ValueError(f"{root}: duplicate clip ids")
    return clips


def _limited(clips: Sequence[ClipSource], limit: int | None) -> list[ClipSource]:
    """`limit` clips spread evenly over the sorted list (so a quick build still sees both datasets, many labels)."""
    if limit is None or limit >= len(clips):
        return list(clips)
    if limit <= 0:
        raise ValueError(f"--limit must be positive, got {limit}")
    picks = np.linspace(0, len(clips) - 1, limit).round().astype(int)
    return [clips[i] for i in sorted(set(picks.tolist()))]


# --- splits --------------------------------------------------------------------------------------------------------
def _stable_hash(text: str) -> str:
    return hashlib.sha256(text.encode("utf-8")).hexdigest()


def assign_splits(clips: Sequence[ClipSource]) -> dict[str, str]:
    """clip id -> 'train' | 'val' | 'test', stratified by content x style (see the module docstring)."""
    ordered = sorted(clips, key=lambda c: (c.content, c.style, _stable_hash(c.clip_id)))
    return {clip.clip_id: SPLIT_PATTERN[i % len(SPLIT_PATTERN)] for i, clip in enumerate(ordered)}


# --- per clip work (runs in the worker processes) -------------------------------------------------------------------
def _pieces(num_frames: int, max_frames: int) -> list[tuple[int, int]]:
    count = math.ceil(num_frames / max_frames)
    bounds = np.linspace(0, num_frames, count + 1).round().astype(int)
    return [(int(a), int(b)) for a, b in pairwise(bounds)]


def write_clip(out: Path, item_id: str, joints: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Save a normalised clip's features and the joints recovered from them (HumanML3D's new_joints); return both."""
    features = joints_to_features(joints, SMPL22).astype(np.float32)
    recovered = features_to_joints(features, SMPL22).astype(np.float32)
    np.save(out / "new_joint_vecs" / f"{item_id}.npy", features)
    np.save(out / "new_joints" / f"{item_id}.npy", recovered)
    return features, recovered


def _save_item(out: Path, item_id: str, joints: np.ndarray) -> int:
    return int(write_clip(out, item_id, joints)[0].shape[0])


# --- checking left/right against the motion ------------------------------------------------------------------------
L_WRIST, R_WRIST = 20, 21
LATERAL_CONTENTS = ("walk-left", "walk-right", "walk-turn-left", "walk-turn-right", "wave-left-hand",
                    "wave-right-hand", "raise-up-left-hand", "raise-up-right-hand")
ONE_HAND_GESTURES = ("bye", "guide", "respond", "call")


def _wrist_travel(joints: np.ndarray, wrist: int) -> float:
    return float(np.linalg.norm(np.diff(joints[:, wrist], axis=0), axis=-1).sum())


def observed_side(content: str, joints: np.ndarray) -> str | None:
    """'left' / 'right' as seen in normalised joints (facing +Z at frame 0, the body's left = +x), or None when the
    motion does not say clearly. Used to catch mislabelled clips and to name the hand of one-handed gestures.

    - walking sideways / turning: the side (x) of the root at its farthest point from the start, at least 1 m
      (0.5 m for walk-left/right) away, and for turns a heading there of more than 45 degrees the same way;
    - hands: the wrist that travels more than twice as far (waves, gestures) or rises 0.2 m higher (raise-up).
    """
    from t2m.motion.transforms import facing_angle

    if content.startswith("walk-"):
        root = joints[:, 0]
        far = int(np.argmax(np.linalg.norm(root[:, [0, 2]] - root[0, [0, 2]], axis=-1)))
        x = float(root[far, 0] - root[0, 0])
        limit = 1.0 if content.startswith("walk-turn") else 0.5
        side = "left" if x > limit else "right" if x < -limit else None
        if side and content.startswith("walk-turn"):
            heading = np.degrees(np.unwrap(facing_angle(joints, SMPL22)))[far]
            if not (heading > 45 if side == "left" else heading < -45):
                return None
        return side
    if content.startswith("raise-up-"):
        lift = joints[:, [L_WRIST, R_WRIST], 1].max(0) - joints[0, [L_WRIST, R_WRIST], 1]
        return "left" if lift[0] > lift[1] + 0.2 else "right" if lift[1] > lift[0] + 0.2 else None
    left, right = _wrist_travel(joints, L_WRIST), _wrist_travel(joints, R_WRIST)
    return "left" if left > 2 * right else "right" if right > 2 * left else None


def labelled_side(content: str) -> str | None:
    parts = content.split("-")
    return "left" if "left" in parts else "right" if "right" in parts else None


def process_clip(clip: ClipSource, out: Path, options: BuildOptions) -> ClipResult:
    result = ClipResult(clip=clip)
    try:
        bvh = read_bvh(clip.bvh_path)
        result.source_frames = bvh.num_frames
        joints = bvh_to_smpl22(bvh, BANDAI_NAMCO, target_fps=FPS)
    except ValueError as error:
        result.skipped = f"unreadable: {error}"
        return result
    if len(joints) < options.min_frames:
        result.skipped = f"too short: {len(joints)} frames at {FPS} fps < {options.min_frames}"
        return result
    content, side = clip.content, None
    if content in LATERAL_CONTENTS:
        seen = observed_side(content, joints)
        if seen is not None and seen != labelled_side(content):  # the motion clearly contradicts the label
            content = mirror_label(content)
            result.relabelled = content
    elif content in ONE_HAND_GESTURES:
        side = observed_side(content, joints)
    pieces = _pieces(len(joints), options.max_frames)
    originals: list[tuple[str, np.ndarray]] = []
    for k, (start, stop) in enumerate(pieces):
        piece_id = clip.clip_id if len(pieces) == 1 else f"{clip.clip_id}_p{k}"
        piece = joints if len(pieces) == 1 else normalize_joints(joints[start:stop], SMPL22)
        originals.append((piece_id, piece))
    for piece_id, piece in originals:
        result.items.append((piece_id, _save_item(out, piece_id, piece)))
        result.captions[piece_id] = make_captions(content, clip.style, piece_id, options.captions_per_clip, side)
    if options.mirror:
        for piece_id, piece in originals:
            mirror_id = f"M{piece_id}"
            result.items.append((mirror_id, _save_item(out, mirror_id, mirror_joints(piece, SMPL22))))
            result.captions[mirror_id] = [mirror_caption(c) for c in result.captions[piece_id]]
    return result


def _work(job: tuple[ClipSource, str, BuildOptions]) -> ClipResult:
    clip, out, options = job
    return process_clip(clip, Path(out), options)


# --- statistics ----------------------------------------------------------------------------------------------------
def feature_statistics(features: Iterable[np.ndarray], num_joints: int = 22) -> tuple[np.ndarray, np.ndarray]:
    """HumanML3D-style Mean/Std [D] of feature rows: per channel-group std averaging, then a floor (STD_FLOOR)."""
    total: np.ndarray | None = None
    total_sq: np.ndarray | None = None
    count = 0
    for rows in features:
        rows64 = rows.astype(np.float64)
        total = rows64.sum(0) if total is None else total + rows64.sum(0)
        total_sq = (rows64**2).sum(0) if total_sq is None else total_sq + (rows64**2).sum(0)
        count += len(rows64)
    if total is None or total_sq is None or not count:
        raise ValueError("no training feature rows to compute Mean/Std from (is the train split empty?)")
    mean = total / count
    std = np.sqrt(np.maximum(total_sq / count - mean**2, 0.0))
    j = num_joints
    groups = [(0, 1), (1, 3), (3, 4), (4, 4 + (j - 1) * 3), (4 + (j - 1) * 3, 4 + (j - 1) * 9),
              (4 + (j - 1) * 9, 4 + (j - 1) * 9 + j * 3), (4 + (j - 1) * 9 + j * 3, len(std))]
    for start, stop in groups:
        std[start:stop] = std[start:stop].mean()
    return mean.astype(np.float32), np.maximum(std, STD_FLOOR).astype(np.float32)


# --- the build -----------------------------------------------------------------------------------------------------
def prepare_output(out: Path, overwrite: bool) -> None:
    """Refuse to overwrite a dataset unless asked; make the layout's folders."""
    existing = [name for name in LAYOUT_ITEMS if (out / name).exists()]
    if existing and not overwrite:
        raise ValueError(f"--out {out} already holds a dataset ({', '.join(existing[:3])}...); "
                         f"pass --overwrite to replace it")
    for name in existing:
        target = out / name
        shutil.rmtree(target) if target.is_dir() else target.unlink()
    for sub in ("new_joints", "new_joint_vecs", "texts"):
        (out / sub).mkdir(parents=True, exist_ok=True)


def write_texts_and_splits(out: Path, captions: dict[str, list[str]], splits: dict[str, list[str]]) -> None:
    """texts/<id>.txt (HumanML3D's caption lines), <split>.txt and all.txt, then Mean/Std over the train split."""
    for item_id, lines in sorted(captions.items()):
        text = "\n".join(format_caption_line(c) for c in lines) + "\n"
        (out / "texts" / f"{item_id}.txt").write_text(text, encoding="utf-8")
    for split, ids in splits.items():
        (out / f"{split}.txt").write_text("".join(f"{i}\n" for i in sorted(ids)), encoding="utf-8")
    (out / "all.txt").write_text("".join(f"{i}\n" for i in sorted(captions)), encoding="utf-8")
    mean, std = feature_statistics(np.load(out / "new_joint_vecs" / f"{i}.npy") for i in sorted(splits["train"]))
    np.save(out / "Mean.npy", mean)
    np.save(out / "Std.npy", std)


def _split_summary(items: dict[str, list[tuple[str, int]]], captions: dict[str, list[str]],
                   clips: dict[str, int]) -> dict[str, dict[str, float]]:
    summary = {}
    for split, rows in items.items():
        frames = sum(n for _, n in rows)
        summary[split] = {"source_clips": clips.get(split, 0), "items": len(rows),
                          "mirrored_items": sum(1 for i, _ in rows if i.startswith("M")),
                          "frames": frames, "hours": round(frames / FPS / 3600, 3),
                          "captions": sum(len(captions[i]) for i, _ in rows)}
    return summary


def build_dataset(source: str | os.PathLike, out: str | os.PathLike, options: BuildOptions | None = None) -> dict:
    """Build the dataset into `out` and return the summary (also written to out/summary.json)."""
    options = options or BuildOptions()
    if options.workers < 1:
        raise ValueError(f"--workers must be at least 1, got {options.workers}")
    out = Path(out)
    started = time.time()
    prepare_output(out, options.overwrite)
    with build_log(out):
        root, temporary = open_source(source, workdir=out)
        try:
            summary = _build(root, out, options, str(source))
        finally:
            if temporary is not None:
                shutil.rmtree(temporary, ignore_errors=True)
        log.info("built %s in %.1f s", out, time.time() - started)
        return summary


@contextmanager
def build_log(out: Path) -> Iterator[None]:
    """Every builder's log lines also go to out/build.log while it builds (kept beside the data it describes)."""
    handler = logging.FileHandler(out / "build.log", mode="w", encoding="utf-8")
    handler.setFormatter(logging.Formatter("%(asctime)s %(levelname)s %(message)s"))
    log.addHandler(handler)
    log.setLevel(logging.INFO)
    try:
        yield
    finally:
        log.removeHandler(handler)
        handler.close()


def _build(root: Path, out: Path, options: BuildOptions, source_name: str) -> dict:
    from tqdm import tqdm

    all_clips = find_clips(root)
    clips = _limited(all_clips, options.limit)
    log.info("%d clips found, building %d (workers=%d, mirror=%s)", len(all_clips), len(clips), options.workers,
             options.mirror)
    jobs = [(clip, str(out), options) for clip in clips]
    bar: dict[str, Any] = {"total": len(jobs), "desc": "clips", "unit": "clip", "disable": not options.progress}
    if options.workers == 1:
        results = [_work(job) for job in tqdm(jobs, **bar)]
    else:
        context = multiprocessing.get_context("spawn" if os.name == "nt" else "fork")
        with context.Pool(options.workers) as pool:
            results = list(tqdm(pool.imap(_work, jobs, chunksize=4), **bar))

    splits = assign_splits([r.clip for r in results if not r.skipped])
    items: dict[str, list[tuple[str, int]]] = {"train": [], "val": [], "test": []}
    captions: dict[str, list[str]] = {}
    clips_per_split: dict[str, int] = {}
    skipped = []
    for result in results:
        if result.relabelled:
            log.warning("relabelled %s: %s -> %s (the motion goes the other way)", result.clip.clip_id,
                        result.clip.content, result.relabelled)
        if result.skipped:
            skipped.append({"clip": result.clip.clip_id, "reason": result.skipped})
            log.warning("skipped %s: %s", result.clip.clip_id, result.skipped)
            continue
        split = splits[result.clip.clip_id]
        clips_per_split[split] = clips_per_split.get(split, 0) + 1
        items[split].extend(result.items)
        captions.update(result.captions)
    if not captions:
        raise ValueError(f"no usable clips in {source_name} ({len(skipped)} skipped)")

    write_texts_and_splits(out, captions, {split: [i for i, _ in rows] for split, rows in items.items()})

    per_split = _split_summary(items, captions, clips_per_split)
    total_frames = sum(s["frames"] for s in per_split.values())
    summary = {
        "name": "bandai-namco-smpl22",
        "source": Path(source_name).name,
        "license": LICENSE,
        "attribution": ATTRIBUTION,
        "captions": "templated from the content and style labels (t2m/model/data/captions.py), not written by people",
        "skeleton": "smpl22", "fps": FPS, "feature_dim": feature_dim(SMPL22),
        "clips_found": len(all_clips), "clips_used": len(clips) - len(skipped), "clips_skipped": len(skipped),
        "items": sum(s["items"] for s in per_split.values()),
        "frames": total_frames, "hours": round(total_frames / FPS / 3600, 3),
        "splits": per_split,
        "options": {k: v for k, v in asdict(options).items() if k not in ("workers", "progress", "overwrite")},
        "choices": {"min_frames": options.min_frames, "max_frames": options.max_frames, "std_floor": STD_FLOOR,
                    "split_pattern": "8 train / 1 val / 1 test per 10 clips ordered by content, style, hash(id)",
                    "mean_std": "train split only (with mirrors), HumanML3D per-group std averaging"},
        "labels": _label_counts(results),
        "skipped": skipped,
        "relabelled": [{"clip": r.clip.clip_id, "label": r.clip.content, "used": r.relabelled}
                       for r in results if r.relabelled and not r.skipped],
    }
    (out / "summary.json").write_text(json.dumps(summary, indent=2) + "\n", encoding="utf-8")
    return summary


def _label_counts(results: Sequence[ClipResult]) -> dict[str, int]:
    counts: dict[str, int] = {}
    for result in results:
        if not result.skipped:
            counts[result.clip.content] = counts.get(result.clip.content, 0) + 1
    return dict(sorted(counts.items()))


def format_summary(summary: dict) -> str:
    """A few human lines for the terminal."""
    lines = [f"{summary['name']}: {summary['clips_used']} clips used of {summary['clips_found']} found "
             f"({summary['clips_skipped']} skipped), {summary['items']} items, {summary['frames']} frames, "
             f"{summary['hours']} h at {summary['fps']} fps"]
    for split, s in summary["splits"].items():
        lines.append(f"  {split:5s} {s['source_clips']:5d} clips {s['items']:6d} items "
                     f"({s['mirrored_items']} mirrored) {s['frames']:8d} frames {s['hours']:6.2f} h "
                     f"{s['captions']:6d} captions")
    lines.append(f"  licence {summary['license']}: {summary['attribution']}")
    return "\n".join(lines)
