"""Merge built HumanML3D-layout datasets (Bandai-Namco, CMU, ...) into one directory for training on all of them.

Each source's ids get its prefix (`bn-`, `cmu-`, ...) so that ids cannot collide; a mirror keeps HumanML3D's `M` in
front (`M<prefix><id>`), so the rest of t2m still tells mirrors from originals. Splits are kept as each source made
them; Mean/Std are recomputed over the merged train split (the sources' own statistics differ). Files are copied.
summary.json lists the sources' summaries, their licences (the strictest, CC BY-NC 4.0 for Bandai-Namco, binds a
model trained on the merge) and the merged counts per split.
"""
from __future__ import annotations

import json
import os
import shutil
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from t2m.model.data.dataset_builder import LAYOUT_ITEMS, feature_statistics, prepare_output
from t2m.motion.constants import FPS

__all__ = ["SPLITS", "merge_datasets", "merged_id"]

SPLITS = ("train", "val", "test")


def merged_id(prefix: str, item_id: str) -> str:
    """`M<prefix><id>` for a mirror `M<id>`, else `<prefix><id>`."""
    return f"M{prefix}{item_id[1:]}" if item_id.startswith("M") else f"{prefix}{item_id}"


def _ids(root: Path, split: str) -> list[str]:
    path = root / f"{split}.txt"
    if not path.is_file():
        raise ValueError(f"{path}: missing; expected a built dataset with train.txt, val.txt and test.txt")
    return path.read_text(encoding="utf-8").split()


def merge_datasets(sources: Sequence[tuple[str, str | os.PathLike]], out: str | os.PathLike,
                   overwrite: bool = False) -> dict:
    """Merge [(prefix, dataset directory), ...] into `out`; return the summary (also out/summary.json)."""
    prefixes = [prefix for prefix, _ in sources]
    if len(sources) < 2 or len(set(prefixes)) != len(prefixes) or not all(p and p[-1] in "-_" for p in prefixes):
        raise ValueError(f"expected two or more datasets with distinct prefixes ending in '-' or '_', got {prefixes}")
    if any(prefix.startswith("M") for prefix in prefixes):
        raise ValueError(f"a prefix must not start with 'M' (HumanML3D's mirror mark), got {prefixes}")
    out = Path(out)
    prepare_output(out, overwrite)
    splits: dict[str, list[str]] = {split: [] for split in SPLITS}
    summaries = []
    for prefix, directory in sources:
        root = Path(directory)
        for split in SPLITS:
            for item in _ids(root, split):
                target = merged_id(prefix, item)
                for sub, suffix in (("new_joint_vecs", ".npy"), ("new_joints", ".npy"), ("texts", ".txt")):
                    source_file = root / sub / f"{item}{suffix}"
                    if not source_file.is_file():
                        raise ValueError(f"{source_file}: missing (listed in {root / f'{split}.txt'})")
                    shutil.copyfile(source_file, out / sub / f"{target}{suffix}")
                splits[split].append(target)
        summary_file = root / "summary.json"
        summary = json.loads(summary_file.read_text(encoding="utf-8")) if summary_file.is_file() else {}
        summaries.append({"prefix": prefix, "directory": str(root), "name": summary.get("name"),
                          "license": summary.get("license"), "attribution": summary.get("attribution")})
    for split, ids in splits.items():
        (out / f"{split}.txt").write_text("".join(f"{i}\n" for i in sorted(ids)), encoding="utf-8")
    every = sorted(i for ids in splits.values() for i in ids)
    (out / "all.txt").write_text("".join(f"{i}\n" for i in every), encoding="utf-8")
    mean, std = feature_statistics(np.load(out / "new_joint_vecs" / f"{i}.npy") for i in sorted(splits["train"]))
    np.save(out / "Mean.npy", mean)
    np.save(out / "Std.npy", std)
    per_split = {}
    for split, ids in splits.items():
        frames = sum(len(np.load(out / "new_joint_vecs" / f"{i}.npy", mmap_mode="r")) for i in ids)
        per_split[split] = {"items": len(ids), "frames": frames, "hours": round(frames / FPS / 3600, 3),
                            **{f"items_{p.rstrip('-_')}": sum(1 for i in ids if i.lstrip("M").startswith(p))
                               for p in prefixes}}
    merged = {"name": "+".join(str(s["name"]) for s in summaries), "sources": summaries,
              "license": "CC BY-NC 4.0" if any(s["license"] == "CC BY-NC 4.0" for s in summaries)
              else "; ".join(str(s["license"]) for s in summaries),
              "fps": FPS, "feature_dim": int(mean.shape[0]), "splits": per_split,
              "items": sum(s["items"] for s in per_split.values()),
              "mean_std": "recomputed over the merged train split (with mirrors)",
              "layout": [name for name in LAYOUT_ITEMS if name != "build.log"]}
    (out / "summary.json").write_text(json.dumps(merged, indent=2) + "\n", encoding="utf-8")
    return merged
