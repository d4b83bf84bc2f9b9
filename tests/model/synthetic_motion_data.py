"""A tiny dataset directory in the contracts' HumanML3D layout, for the model tests.

The motion is real: crops of HumanML3D's sample clip 012314 (committed in tests/fixtures/humanml3d-sample) with
HumanML3D's own Mean/Std; the captions are made up. There is no synthetic stand-in: the sample is always there.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from tests.shared_data import HUMANML3D_SAMPLE as SAMPLE

CAPTIONS = (
    "a person walks forward",
    "someone waves with the right hand",
    "a man jumps in place",
    "the person turns around slowly",
)


def _source_motion() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(features [170, 263], mean, std) of the real HumanML3D sample."""
    features = np.load(SAMPLE / "new_joint_vecs_012314.npy").astype(np.float32)
    return features, np.load(SAMPLE / "Mean.npy").astype(np.float32), np.load(SAMPLE / "Std.npy").astype(np.float32)


def make_dataset(root: Path, train_clips: int = 8, val_clips: int = 3) -> Path:
    """Write root/{new_joint_vecs,new_joints,texts}, Mean/Std, train/val/test.txt; return root."""
    features, mean, std = _source_motion()
    rng = np.random.default_rng(0)
    for sub in ("new_joint_vecs", "new_joints", "texts"):
        (root / sub).mkdir(parents=True, exist_ok=True)
    splits: dict[str, list[str]] = {"train": [], "val": [], "test": []}
    # lengths: most clips long enough for a 64-frame window, one shorter (left out of VQ windows), one full clip.
    layout = [("train", i) for i in range(train_clips)] + [("val", i) for i in range(val_clips)] + [("test", 0)]
    for index, (split, number) in enumerate(layout):
        clip_id = f"{split}{number:03d}"
        if split == "train" and number == 0:
            length = 40
        elif split == "train" and number == 1:
            length = len(features)
        else:
            length = int(rng.integers(64, len(features) + 1))
        start = int(rng.integers(0, len(features) - length + 1))
        clip = features[start : start + length]
        np.save(root / "new_joint_vecs" / f"{clip_id}.npy", clip)
        np.save(root / "new_joints" / f"{clip_id}.npy", rng.normal(size=(length + 1, 22, 3)).astype(np.float32))
        captions = [CAPTIONS[(index + k) % len(CAPTIONS)] for k in range(2)]
        (root / "texts" / f"{clip_id}.txt").write_text(
            "".join(f"{c}#{' '.join(w + '/NOUN' for w in c.split())}#0.0#0.0\n" for c in captions)
        )
        splits[split].append(clip_id)
    for split, ids in splits.items():
        (root / f"{split}.txt").write_text("\n".join(ids) + "\n")
    np.save(root / "Mean.npy", mean)
    np.save(root / "Std.npy", std)
    return root
