"""Where MoMask's released files are, reading them, and what an import read from them (../shared/docs/masked-models.md
§1.5).

The release unpacks to ``checkpoints/t2m/`` (HumanML3D; KIT-ML: ``checkpoints/kit/`` with the folder names suffixed
``_k``):

    rvq_nq6_dc512_nc512_noshare_qdp0.2/model/net_best_fid.tar     {'vq_model' | 'net', 'ep'}
    rvq_nq6_dc512_nc512_noshare_qdp0.2/meta/mean.npy, std.npy      the de-normalisation (std / 5 on root + feet)
    t2m_nlayer8_nhead6_ld384_ff1024_cdp0.1_rvq6ns/model/latest.tar {'t2m_transformer' | 'trans', optimiser, ...}
    tres_nlayer8_ld384_ff1024_rvq6ns_cdp0.2_sw/model/net_best_fid.tar {'res_transformer', 'ep'}
    length_estimator/model/finest.tar                              {'estimator', 'epoch', 'niter'}

MoMask's own generation script reads these very paths (the mask transformer's latest.tar, not a best-FID copy); a
user who holds another file of a run (net_best_fid.tar of the mask transformer, latest.tar of another) names it
with an option, and the other top-level key names of §1.5 are accepted. Only the model's state dict is read; the
optimiser and scheduler entries are ignored; ``clip_model.*`` tensors (deleted by the release) are dropped if a
file still has them.
"""
from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from t2m.export.importers.kit import load_checkpoint_entry
from t2m.families.masked.length_estimator import LengthEstimator
from t2m.families.masked.masked_transformer import MaskedTransformer
from t2m.families.masked.residual_transformer import ResidualTransformer
from t2m.model.networks.vqvae import MotionVQVAE

VQ_DIR = "rvq_nq6_dc512_nc512_noshare_qdp0.2"
MASKED_DIR = "t2m_nlayer8_nhead6_ld384_ff1024_cdp0.1_rvq6ns"
RESIDUAL_DIR = "tres_nlayer8_ld384_ff1024_rvq6ns_cdp0.2_sw"
LENGTH_DIR = "length_estimator"
KIT_SUFFIX = "_k"
# top-level keys of each file, in the order MoMask's loaders try them
STATE_KEYS = {"vq": ("vq_model", "net"), "masked": ("t2m_transformer", "trans"), "residual": ("res_transformer",),
              "length": ("estimator",)}
ROLES = {"vq": "the RVQ-VAE", "masked": "the masked transformer", "residual": "the residual transformer",
         "length": "the length estimator", "mean": "the VQ's meta mean", "std": "the VQ's meta std"}


@dataclass(frozen=True)
class MomaskFiles:
    """The files of one import (MoMask's or MoGenTS's); ``length`` None: no length estimator (the bundle then needs
    durations)."""

    vq: Path
    mean: Path
    std: Path
    masked: Path
    residual: Path
    length: Path | None
    dataset: str = "HumanML3D"
    length_looked_for: Path | None = None  # where the folder lookup expected the length estimator

    def missing_length_note(self) -> str | None:
        """One line naming the missing length estimator and what it is needed for (None: it is there)."""
        if self.length is not None:
            return None
        where = f"{self.length_looked_for}: missing file" if self.length_looked_for else "no --length file"
        return (f"{where}: the length estimator, needed for free length (a segment without a duration); imported "
                "without it, so every segment needs a duration")


def _dataset(root: Path) -> tuple[str, str]:
    """(dataset name, folder suffix): KIT's folders end in ``_k``."""
    if not (root / VQ_DIR).exists() and (root / (VQ_DIR + KIT_SUFFIX)).exists():
        return "KIT-ML", KIT_SUFFIX
    return "HumanML3D", ""


def _transformer_file(folder: Path) -> Path:
    """The mask transformer's file as MoMask's generation reads it: latest.tar, else a best-FID copy."""
    latest = folder / "model" / "latest.tar"
    best = folder / "model" / "net_best_fid.tar"
    return best if not latest.is_file() and best.is_file() else latest


def locate_release(checkpoints_dir: str | Path | None, overrides: Mapping[str, str | Path | None]) -> MomaskFiles:
    """The release's files under ``checkpoints_dir`` (MoMask's ``checkpoints/t2m``), each replaceable by an explicit
    path in ``overrides`` (keys vq, mean, std, masked, residual, length). Missing files are refused naming the file
    and what it is for, except the length estimator of the folder lookup (None: imported without free length)."""
    given = {role: Path(path) for role, path in overrides.items() if path is not None}
    dataset, looked_for = "HumanML3D", None
    found: dict[str, Path | None] = {}
    if checkpoints_dir is not None:
        root = Path(checkpoints_dir)
        if not root.is_dir():
            raise ValueError(f"{root}: no such folder (expected MoMask's checkpoints/t2m with {VQ_DIR}/, "
                             f"{MASKED_DIR}/, {RESIDUAL_DIR}/ and {LENGTH_DIR}/)")
        dataset, suffix = _dataset(root)
        vq_folder = root / (VQ_DIR + suffix)
        found = {"vq": vq_folder / "model" / "net_best_fid.tar", "mean": vq_folder / "meta" / "mean.npy",
                 "std": vq_folder / "meta" / "std.npy", "masked": _transformer_file(root / (MASKED_DIR + suffix)),
                 "residual": root / (RESIDUAL_DIR + suffix) / "model" / "net_best_fid.tar"}
        candidates = [root / name / "model" / "finest.tar" for name in dict.fromkeys((LENGTH_DIR, LENGTH_DIR + suffix))]
        found["length"] = next((path for path in candidates if path.is_file()), None)
        looked_for = candidates[0]
    return release_files({**found, **given}, "length" in given, ROLES, "CHECKPOINTS_DIR", dataset, looked_for)


def release_files(paths: Mapping[str, Path | None], length_given: bool, roles: Mapping[str, str], folder_arg: str,
                  dataset: str, looked_for: Path | None) -> MomaskFiles:
    """The located files of a release (both importers): each required one present, else one line naming it and
    what it is for; the length estimator optional unless named by option."""

    def required(role: str) -> Path:
        path = paths.get(role)
        if path is None:
            raise ValueError(f"no file for {roles[role]}: pass {folder_arg} or --{role} FILE")
        if not path.is_file():
            needed = " (needed for de-normalisation)" if role in ("mean", "std") else ""
            raise ValueError(f"{path}: missing file: {roles[role]}{needed}")
        return path

    length = paths.get("length")
    if length is not None and length_given:
        length = required("length")
    return MomaskFiles(vq=required("vq"), mean=required("mean"), std=required("std"), masked=required("masked"),
                       residual=required("residual"), length=length, dataset=dataset,
                       length_looked_for=None if length_given else looked_for)


def kit_fps_note(dataset: str) -> str | None:
    """KIT-ML's motion is 12.5 fps; a bundle's fps is an integer and the service's is 20 (None for HumanML3D)."""
    if dataset != "KIT-ML":
        return None
    return ("KIT-ML motion is 12.5 fps but the bundle records 20 fps (manifest format 1): durations map to 20 / 12.5 "
            "times more token rows than in MoMask, and the served motion plays 1.6 times too fast")


@dataclass
class ImportedMomask:
    """The release as our modules (eval mode), the de-normalisation and what was read from where."""

    files: MomaskFiles
    vq: MotionVQVAE
    masked: MaskedTransformer
    residual: ResidualTransformer
    length: LengthEstimator | None
    mean: np.ndarray
    std: np.ndarray
    keys: dict[str, str]


def read_state(path: Path, role: str, allow_pickle: bool = False) -> tuple[str, dict[str, torch.Tensor]]:
    """(the top-level key found, its state dict in float32 without ``clip_model.*``) of one release file."""
    key, state = load_checkpoint_entry(path, STATE_KEYS[role], allow_pickle)
    return key, {k: v for k, v in state.items() if not k.startswith("clip_model.")}


