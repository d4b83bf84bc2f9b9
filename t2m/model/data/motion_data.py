"""Numpy reader of a dataset in HumanML3D's layout: ours (Bandai-Namco build), a user's real HumanML3D, or KIT-ML.

    root/new_joint_vecs/<id>.npy  [N, D] features      (D = 263 for SMPL-22, 251 for KIT-21)
    root/new_joints/<id>.npy      [N, J, 3] joints     (optional for training; used by evaluation/visualisation)
    root/texts/<id>.txt           "caption#tokens#start#end" lines
    root/Mean.npy, root/Std.npy   [D]
    root/<split>.txt              one id a line

The PyTorch datasets wrap this; it has no torch so the tooling and tests can read data without it. Ids listed in a
split whose feature file or text file is missing are dropped with a count (HumanML3D's own split files list a few
ids that its processing never produced), but a layout with nothing usable raises a ValueError naming the path.
"""
from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from t2m.model.data.captions import parse_caption_line

__all__ = ["SKELETON_BY_DIM", "SPLITS", "Caption", "MotionDirectory"]

SKELETON_BY_DIM = {263: "smpl22", 251: "kit21"}
SPLITS = ("train", "val", "test", "all")


@dataclass(frozen=True)
class Caption:
    """One text line: the sentence, its tokens ('word/POS') and the covered time span in seconds (0, 0 = all)."""

    text: str
    tokens: tuple[str, ...]
    start: float
    end: float


def _parse_line(line: str, path: Path, number: int) -> Caption:
    parts = line.split("#")
    text = parts[0].strip()
    if not text:
        raise ValueError(f"{path}: line {number}: empty caption")
    tokens = tuple(parts[1].split()) if len(parts) > 1 else ()
    try:
        start = float(parts[2]) if len(parts) > 2 and parts[2].strip() else 0.0
        end = float(parts[3]) if len(parts) > 3 and parts[3].strip() else 0.0
    except ValueError:
        raise ValueError(f"{path}: line {number}: expected 'caption#tokens#start#end' with numeric start/end, "
                         f"got {line!r}") from None
    if start != start or end != end:  # NaN: HumanML3D writes 'nan' for some spans; treat as the whole clip
        start, end = 0.0, 0.0
    return Caption(text, tokens, start, end)


class MotionDirectory:
    """One split of a HumanML3D-layout directory.

    `ids` are the split's usable ids (features and texts present), in file order. `skeleton` is inferred from the
    feature dimension of Mean.npy (263 -> smpl22, 251 -> kit21).
    """

    def __init__(self, root: str | os.PathLike, split: str = "train") -> None:
        self.root = Path(root)
        self.split = split
        if not self.root.is_dir():
            raise ValueError(f"dataset directory {self.root} does not exist")
        for sub in ("new_joint_vecs", "texts"):
            if not (self.root / sub).is_dir():
                raise ValueError(f"{self.root} is not in HumanML3D layout: {sub}/ is missing")
        split_file = self.root / f"{split}.txt"
        if not split_file.is_file():
            known = [s for s in SPLITS if (self.root / f"{s}.txt").is_file()]
            raise ValueError(f"{split_file} is missing (split {split!r}); splits present: {', '.join(known) or 'none'}")
        self.mean = self._load_stat("Mean.npy")
        self.std = self._load_stat("Std.npy")
        if self.mean.shape != self.std.shape:
            raise ValueError(f"{self.root}: Mean.npy {self.mean.shape} and Std.npy {self.std.shape} differ in shape")
        dim = int(self.mean.shape[0])
        if dim not in SKELETON_BY_DIM:
            raise ValueError(f"{self.root / 'Mean.npy'}: feature dim {dim}; expected one of "
                             f"{', '.join(map(str, SKELETON_BY_DIM))} (HumanML3D / KIT-ML)")
        if np.any(self.std <= 0):
            raise ValueError(f"{self.root / 'Std.npy'}: has zero or negative entries; cannot normalise with it")
        self.feature_dim = dim
        self.skeleton = SKELETON_BY_DIM[dim]

        listed = [line.strip() for line in split_file.read_text(encoding="utf-8").splitlines() if line.strip()]
        self.ids = [i for i in listed if (self.root / "new_joint_vecs" / f"{i}.npy").is_file()
                    and (self.root / "texts" / f"{i}.txt").is_file()]
        self.missing = len(listed) - len(self.ids)
        if not self.ids:
            raise ValueError(f"{split_file}: none of its {len(listed)} ids has both new_joint_vecs/<id>.npy and "
                             f"texts/<id>.txt")

    def _load_stat(self, name: str) -> np.ndarray:
        path = self.root / name
        if not path.is_file():
            raise ValueError(f"{path} is missing (dataset statistics)")
        array = np.load(path).astype(np.float32)
        if array.ndim != 1:
            raise ValueError(f"{path}: expected a vector [D], got shape {array.shape}")
        return array

    def __len__(self) -> int:
        return len(self.ids)

    def __repr__(self) -> str:
        return f"MotionDirectory({str(self.root)!r}, split={self.split!r}, items={len(self)}, skeleton={self.skeleton})"

    def features(self, item_id: str) -> np.ndarray:
        """Raw (not normalised) features [N, D] float32."""
        path = self.root / "new_joint_vecs" / f"{item_id}.npy"
        if not path.is_file():
            raise ValueError(f"{path} is missing")
        array = np.load(path)
        if array.ndim != 2 or array.shape[1] != self.feature_dim:
            raise ValueError(f"{path}: expected [frames, {self.feature_dim}], got shape {array.shape}")
        return array.astype(np.float32, copy=False)

    def normalized_features(self, item_id: str) -> np.ndarray:
        return (self.features(item_id) - self.mean) / self.std

    def joints(self, item_id: str) -> np.ndarray:
        """Joint positions [N, J, 3] float32 from new_joints/ (HumanML3D's recovered joints)."""
        path = self.root / "new_joints" / f"{item_id}.npy"
        if not path.is_file():
            raise ValueError(f"{path} is missing")
        array = np.load(path)
        joints = {"smpl22": 22, "kit21": 21}[self.skeleton]
        if array.ndim != 3 or array.shape[1:] != (joints, 3):
            raise ValueError(f"{path}: expected [frames, {joints}, 3], got shape {array.shape}")
        return array.astype(np.float32, copy=False)

    def caption_lines(self, item_id: str) -> list[Caption]:
        path = self.root / "texts" / f"{item_id}.txt"
        if not path.is_file():
            raise ValueError(f"{path} is missing")
        lines = path.read_text(encoding="utf-8").splitlines()
        captions = [_parse_line(line, path, n) for n, line in enumerate(lines, start=1) if line.strip()]
        if not captions:
            raise ValueError(f"{path} has no captions")
        return captions

    def captions(self, item_id: str) -> list[str]:
        return [parse_caption_line(c.text) for c in self.caption_lines(item_id)]

    def num_frames(self, item_id: str) -> int:
        """Feature rows without loading the file (reads the .npy header)."""
        path = self.root / "new_joint_vecs" / f"{item_id}.npy"
        if not path.is_file():
            raise ValueError(f"{path} is missing")
        return int(np.load(path, mmap_mode="r").shape[0])
