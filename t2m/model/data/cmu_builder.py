"""Build a HumanML3D-layout dataset from the captioned CMU trials: one clip per HumanML3D entry, people's sentences.

    archive (or its directory) + index.json -> per trial: SMPL-22 joints at 20 fps (BVH and/or DeepMimic form)
        -> cut at each entry's [start_s, end_s) -> normalised clip -> 263-dim features -> checks
        -> texts (the entry's sentences) -> HumanML3D's split (+ val) -> Mean/Std -> summary.json

Choices (also written into summary.json):
- a clip is frames [round(start_s * 20), round(end_s * 20)) of the trial (HumanML3D's own cut), normalised on its
  own (starts at the origin facing +Z, feet on the floor); ids are `<trial>_<HumanML3D id, 6 digits>`. A cut that
  ends past the motion is shortened and listed under `short_cuts`; a clip under MIN_FRAMES = 20 frames is skipped.
  Clips are at most 10 s (200 frames; HumanML3D's trainers crop to 196), so none is split.
- splits: HumanML3D's own train/test; val = the train entries of every tenth trial that has train entries, trials
  ordered by the sha256 of their id (deterministic, no trial in both train and val). Mirrors share their split.
- a trial in both forms is read in both; they are compared (per-joint error after both are normalised the same way)
  and the form whose clips fail fewer checks (`clip_checks`) is kept, the BVH on a tie: it measures every SMPL-22
  joint, where DeepMimic's humanoid has seven of them filled in.
- mirrored copies `M<id>` (HumanML3D's augmentation), 'left'/'right' swapped in their sentences.
- Mean/Std as the Bandai-Namco builder (train split with mirrors, per-group std, floor).
The build is single-process and deterministic; summary.json's `build_key` (sha256 of the archive, the index, the
options and BUILD_VERSION) lets a second identical build return at once.
"""
from __future__ import annotations

import hashlib
import json
import logging
import os
import shutil
import time
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from t2m.model.data.captions import mirror_caption
from t2m.model.data.clip_checks import CHECK_LIMITS, ClipChecks, check_clip
from t2m.model.data.cmu_source import CaptionedSegment, CmuTrial, open_cmu_source, read_form, read_index
from t2m.model.data.dataset_builder import STD_FLOOR, build_log, prepare_output, write_clip, write_texts_and_splits
from t2m.motion.constants import FPS
from t2m.motion.features import feature_dim, features_to_joints, joints_to_features, normalize_joints
from t2m.motion.skeleton import SMPL22
from t2m.motion.transforms import mirror_joints

__all__ = ["BUILD_VERSION", "CmuBuildOptions", "build_cmu_dataset", "compare_forms", "cut_frames", "format_cmu_summary",
           "val_trials"]

log = logging.getLogger("t2m.data")

BUILD_VERSION = 1
MIN_FRAMES = 20
VAL_EVERY = 10
MAX_SHIFT = 10  # frames searched when aligning two forms of a trial in time
LICENSE = ("motions: CMU Graphics Lab Motion Capture Database terms (free for all uses, no resale of the data); "
           "sentences: HumanML3D, MIT")
ATTRIBUTION = ("The data used in this project was obtained from mocap.cs.cmu.edu. The database was created with "
               "funding from NSF EIA-0196217. Sentences: HumanML3D (Guo et al., CVPR 2022).")


@dataclass
class CmuBuildOptions:
    index: str | None = None          # index.json; default: beside the archive (or inside the directory)
    mirror: bool = True
    limit: int | None = None          # only the first N trials with sentences (quick runs)
    min_frames: int = MIN_FRAMES
    overwrite: bool = False
    progress: bool = True


@dataclass
class TrialResult:
    trial: CmuTrial
    form: str | None = None
    clips: dict[str, tuple[np.ndarray, ClipChecks]] = field(default_factory=dict)
    comparison: dict | None = None
    tpose_dropped: bool = False
    short_cuts: list[dict] = field(default_factory=list)
    skipped: list[dict] = field(default_factory=list)


# --- pieces ---------------------------------------------------------------------------------------------------------
def cut_frames(segment: CaptionedSegment, num_frames: int, fps: float = FPS) -> tuple[int, int]:
    """[start, stop) frame indices of a segment in a motion of num_frames frames (stop clipped to the motion)."""
    return round(segment.start_s * fps), min(round(segment.end_s * fps), num_frames)


def val_trials(trials: Sequence[CmuTrial]) -> set[str]:
    """Every VAL_EVERY-th trial with train entries, ordered by the sha256 of its id."""
    with_train = [t.trial_id for t in trials if any(s.split == "train" for s in t.segments)]
    ordered = sorted(with_train, key=lambda i: hashlib.sha256(i.encode("utf-8")).hexdigest())
    return {trial_id for k, trial_id in enumerate(ordered) if k % VAL_EVERY == VAL_EVERY // 2}


def compare_forms(first: np.ndarray, second: np.ndarray) -> dict[str, float | int | list[int]]:
    """Mean per-joint distance between two conversions of a trial (both normalised, metres).

    Aligned in time by the shift (within MAX_SHIFT frames) that minimises the root-relative error; `mpjpe_m` is the
    plain error after that shift (both start at the origin facing +Z), `root_relative_mpjpe_m` ignores the path.
    """
    a, b = normalize_joints(first, SMPL22), normalize_joints(second, SMPL22)
    best: tuple[float, int, int] | None = None
    for shift in range(-MAX_SHIFT, MAX_SHIFT + 1):
        x, y = a[max(shift, 0):], b[max(-shift, 0):]
        n = min(len(x), len(y))
        if n < len(a) // 2:
            continue
        error = float(np.linalg.norm((x[:n] - x[:n, :1]) - (y[:n] - y[:n, :1]), axis=-1).mean())
        if best is None or error < best[0]:
            best = (error, shift, n)
    if best is None:
        raise ValueError("the two forms differ too much in length to compare")
    error, shift, n = best
    x, y = a[max(shift, 0):][:n], b[max(-shift, 0):][:n]
    return {"root_relative_mpjpe_m": round(error, 4), "mpjpe_m": round(float(np.linalg.norm(x - y, axis=-1).mean()), 4),
            "shift_frames": shift, "frames_compared": n, "frames": [len(a), len(b)]}


def _clips_of(trial: CmuTrial, joints: np.ndarray, min_frames: int, result: TrialResult) -> dict:
    """clip id -> (normalised joints, checks) for every captioned segment of one form."""
    clips = {}
    for segment in trial.segments:
        clip_id = f"{trial.trial_id}_{segment.humanml3d_id:06d}"
        start, stop = cut_frames(segment, len(joints))
        if stop - start < min_frames:
            result.skipped.append({"clip": clip_id, "reason": f"too short: {max(stop - start, 0)} frames at {FPS} fps "
                                   f"< {min_frames} (motion has {len(joints)} frames, cut {segment.start_s}-"
                                   f"{segment.end_s} s)"})
            continue
        normalised = normalize_joints(joints[start:stop], SMPL22)
        features = joints_to_features(normalised, SMPL22)
        checks = check_clip(joints[start:stop], features, features_to_joints(features, SMPL22))
        clips[clip_id] = (normalised, checks)
    return clips


def process_trial(root: Path, trial: CmuTrial, options: CmuBuildOptions) -> TrialResult:
    """Read every form of a trial, compare them when there are two, keep one, cut its clips."""
    result = TrialResult(trial)
    forms: dict[str, np.ndarray] = {}
    for form in ("bvh", "deepmimic"):
        if form in trial.files:
            try:
                forms[form], dropped = read_form(root, trial, form)
                result.tpose_dropped |= dropped
            except (ValueError, OSError) as error:
                log.warning("%s: %s form unreadable: %s", trial.trial_id, form, error)
                result.skipped.append({"clip": trial.trial_id, "reason": f"{form} unreadable: {error}"})
    if not forms:
        return result
    notes = {form: TrialResult(trial) for form in forms}
    candidates = {form: _clips_of(trial, joints, options.min_frames, notes[form]) for form, joints in forms.items()}
    failures = {form: sum(len(c.failed) for _, c in clips.values()) for form, clips in candidates.items()}
    result.form = min(forms, key=lambda form: (failures[form], form != "bvh"))
    if len(forms) == 2:
        result.comparison = {"trial": trial.trial_id, **compare_forms(forms["bvh"], forms["deepmimic"]),
                             "failed_checks": failures, "kept": result.form}
    joints = forms[result.form]
    result.clips = candidates[result.form]
    result.skipped.extend(notes[result.form].skipped)
    for segment in trial.segments:
        missing = segment.end_s - len(joints) / FPS
        if missing > 0.5 / FPS:
            result.short_cuts.append({"clip": f"{trial.trial_id}_{segment.humanml3d_id:06d}",
                                      "end_s": segment.end_s, "motion_s": round(len(joints) / FPS, 3)})
    return result


# --- caching --------------------------------------------------------------------------------------------------------
def _sha256(path: Path) -> str:
    digest = hashlib.sha256()
    if path.is_dir():
        for file in sorted(p for p in path.rglob("*") if p.is_file()):
            digest.update(str(file.relative_to(path)).encode("utf-8"))
            digest.update(file.read_bytes())
        return digest.hexdigest()
    with path.open("rb") as handle:
        for block in iter(lambda: handle.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def build_key(source: Path, index: Path, options: CmuBuildOptions) -> str:
    settings = {k: v for k, v in asdict(options).items() if k not in ("index", "overwrite", "progress")}
    text = json.dumps({"version": BUILD_VERSION, "source": _sha256(source), "index": _sha256(index),
                       "options": settings}, sort_keys=True)
    return hashlib.sha256(text.encode("utf-8")).hexdigest()


def _existing_summary(out: Path) -> dict | None:
    try:
        return json.loads((out / "summary.json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None


def find_index(source: Path, index: str | None) -> Path:
    """The index given, else index.json beside the archive (or inside / beside the directory)."""
    if index is not None:
        candidates = [Path(index)]
    elif source.is_dir():
        candidates = [source / "index.json", source.parent / "index.json"]
    else:
        candidates = [source.parent / "index.json"]
    for candidate in candidates:
        if candidate.is_file():
            return candidate
    raise ValueError(f"no CMU index found (looked for {', '.join(map(str, candidates))}); pass --index")


# --- the build ------------------------------------------------------------------------------------------------------
def build_cmu_dataset(source: str | os.PathLike, out: str | os.PathLike,
                      options: CmuBuildOptions | None = None) -> dict:
    """Build (or find already built) the CMU dataset in `out`; return the summary (also out/summary.json)."""
    options = options or CmuBuildOptions()
    source, out = Path(source), Path(out)
    if not source.exists():
        raise FileNotFoundError(2, "no such file or directory", str(source))
    index = find_index(source, options.index)
    key = build_key(source, index, options)
    existing = _existing_summary(out)
    if existing is not None and existing.get("build_key") == key and not options.overwrite:
        log.info("%s is up to date (build_key %s)", out, key[:12])
        return {**existing, "cached": True}
    started = time.time()
    prepare_output(out, options.overwrite)
    with build_log(out):
        root, temporary = open_cmu_source(source, workdir=out)
        try:
            summary = _build(root, read_index(index), out, options)
        finally:
            if temporary is not None:
                shutil.rmtree(temporary, ignore_errors=True)
        summary.update({"source": source.name, "index": index.name, "build_key": key})
        (out / "summary.json").write_text(json.dumps(summary, indent=2) + "\n", encoding="utf-8")
        log.info("built %s in %.1f s", out, time.time() - started)
        return summary


def _build(root: Path, trials: list[CmuTrial], out: Path, options: CmuBuildOptions) -> dict:
    from tqdm import tqdm

    captioned = [t for t in trials if t.segments]
    if options.limit is not None:
        if options.limit < 1:
            raise ValueError(f"--limit must be positive, got {options.limit}")
        captioned = captioned[:options.limit]
    for trial in captioned:
        for form, name in trial.files.items():
            if not (root / name).is_file():
                raise ValueError(f"{root / name}: listed in the index for {trial.trial_id} ({form}) but missing")
    log.info("%d trials in the index, %d with sentences, building %d", len(trials),
             sum(1 for t in trials if t.segments), len(captioned))
    val = val_trials(captioned)
    results = [process_trial(root, trial, options)
               for trial in tqdm(captioned, desc="trials", unit="trial", disable=not options.progress)]

    splits: dict[str, list[str]] = {"train": [], "val": [], "test": []}
    captions: dict[str, list[str]] = {}
    frames: dict[str, int] = {}
    sentences: dict[str, int] = {}
    split_of_trial: dict[str, set[str]] = {}
    failed = []
    for result in results:
        segments = {f"{result.trial.trial_id}_{s.humanml3d_id:06d}": s for s in result.trial.segments}
        for clip_id, (joints, checks) in result.clips.items():
            segment = segments[clip_id]
            split = "val" if segment.split == "train" and result.trial.trial_id in val else segment.split
            split_of_trial.setdefault(result.trial.trial_id, set()).add(split)
            if checks.failed:
                failed.append({"clip": clip_id, "failed": checks.failed, **checks.as_dict()})
                log.warning("%s fails checks %s: %s", clip_id, checks.failed, checks.as_dict())
            items = [(clip_id, joints, list(segment.sentences))]
            if options.mirror:
                mirrored = [mirror_caption(c) for c in segment.sentences]
                items.append((f"M{clip_id}", mirror_joints(joints, SMPL22), mirrored))
            for item_id, item_joints, lines in items:
                frames[item_id] = int(write_clip(out, item_id, item_joints)[0].shape[0])
                captions[item_id] = lines
                splits[split].append(item_id)
            sentences[clip_id] = len(segment.sentences)
    if not captions:
        raise ValueError("no usable clips: every segment was skipped (see build.log)")
    write_texts_and_splits(out, captions, splits)
    return _summary(trials, results, splits, frames, sentences, failed, split_of_trial, options)


def _summary(trials: list[CmuTrial], results: list[TrialResult], splits: dict[str, list[str]], frames: dict[str, int],
             sentences: dict[str, int], failed: list[dict], split_of_trial: dict[str, set[str]],
             options: CmuBuildOptions) -> dict:
    per_split = {}
    for split, ids in splits.items():
        originals = [i for i in ids if not i.startswith("M")]
        count = sum(frames[i] for i in ids)
        per_split[split] = {
            "trials": sum(1 for s in split_of_trial.values() if split in s), "clips": len(originals),
            "items": len(ids), "mirrored_items": len(ids) - len(originals),
            "seconds": round(sum(frames[i] + 1 for i in originals) / FPS, 2),
            "frames": count, "sentences": sum(sentences[i] for i in originals),
            "captions": sum(sentences[i.removeprefix("M")] for i in ids)}
    used = [r for r in results if r.clips]
    seconds = sum(s["seconds"] for s in per_split.values())
    return {
        "name": "cmu-captioned-smpl22",
        "license": LICENSE, "attribution": ATTRIBUTION,
        "captions": "HumanML3D's sentences, written by people, timed to the trials",
        "skeleton": "smpl22", "fps": FPS, "feature_dim": feature_dim(SMPL22),
        "trials": {"in_index": len(trials), "bvh": sum("bvh" in t.files for t in trials),
                   "deepmimic": sum("deepmimic" in t.files for t in trials),
                   "both_forms": sum(len(t.files) == 2 for t in trials),
                   "with_sentences": sum(1 for t in trials if t.segments), "built": len(results), "used": len(used),
                   "form_used": {f: sum(r.form == f for r in used) for f in ("bvh", "deepmimic")}},
        "clips": sum(s["clips"] for s in per_split.values()), "items": sum(s["items"] for s in per_split.values()),
        "seconds": round(seconds, 2), "hours": round(seconds / 3600, 3),
        "sentences": sum(s["sentences"] for s in per_split.values()),
        "splits": per_split,
        "both_forms": [r.comparison for r in results if r.comparison],
        "tpose_dropped": [r.trial.trial_id for r in results if r.tpose_dropped],
        "checks": {"limits": {k: list(v) for k, v in CHECK_LIMITS.items()}, "failed": failed},
        "short_cuts": [c for r in results for c in r.short_cuts],
        "skipped": [s for r in results for s in r.skipped],
        "trials_in_two_splits": sorted(t for t, s in split_of_trial.items() if len(s) > 1),
        "options": {k: v for k, v in asdict(options).items() if k not in ("index", "overwrite", "progress")},
        "choices": {"min_frames": options.min_frames, "std_floor": STD_FLOOR,
                    "split": f"HumanML3D's train/test; val = train entries of every {VAL_EVERY}th trial by sha256(id)",
                    "both_forms_rule": "fewer failed clip checks, BVH on a tie",
                    "mean_std": "train split only (with mirrors), HumanML3D per-group std averaging"},
    }


def format_cmu_summary(summary: dict) -> str:
    """A few human lines for the terminal."""
    t = summary["trials"]
    lines = [f"{summary['name']}{' (cached)' if summary.get('cached') else ''}: {t['used']} trials used of "
             f"{t['with_sentences']} with sentences ({t['in_index']} in the index: {t['bvh']} BVH, {t['deepmimic']} "
             f"DeepMimic, {t['both_forms']} both; kept {t['form_used']['bvh']} BVH, {t['form_used']['deepmimic']} "
             f"DeepMimic), {summary['clips']} clips, {summary['items']} items, {summary['seconds']} s, "
             f"{summary['sentences']} sentences"]
    for split, s in summary["splits"].items():
        lines.append(f"  {split:5s} {s['trials']:4d} trials {s['clips']:4d} clips {s['items']:5d} items "
                     f"{s['seconds']:8.1f} s {s['sentences']:4d} sentences")
    for c in summary["both_forms"]:
        lines.append(f"  both forms {c['trial']}: MPJPE {c['mpjpe_m'] * 100:.1f} cm, root-relative "
                     f"{c['root_relative_mpjpe_m'] * 100:.1f} cm, shift {c['shift_frames']}, kept {c['kept']}")
    lines.append(f"  T-pose frame dropped: {', '.join(summary['tpose_dropped']) or 'none'}; "
                 f"{len(summary['checks']['failed'])} clips fail a check, {len(summary['skipped'])} skipped")
    lines.append(f"  licence: {summary['license']}")
    return "\n".join(lines)
