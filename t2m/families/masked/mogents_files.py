"""Where MoGenTS's released files are and reading them (../shared/docs/masked-models.md §2.6-2.7).

The release unpacks to ``logs/humanml3d/`` (KIT-ML: ``logs/kit/``, transformers suffixed ``_kit``); the length
estimator comes with the evaluators' ``checkpoints.zip`` beside ``logs/``:

    logs/humanml3d/pretrain_vq/model/net_best_fid.tar        {'vq_model' | 'net', 'ep', 'value'}
    logs/humanml3d/pretrain_vq/meta/mean.npy, std.npy         the de-normalisation (std / 5 on root + feet)
    logs/humanml3d/pretrain_mtrans/model/net_best_fid.tar    {'t2m_transformer_aux', 't2m_transformer_ts', ...}
                                            (latest.tar:     {'mask_transformer_aux', 'mask_transformer_ts', ...})
    logs/humanml3d/pretrain_rtrans/model/net_best_fid.tar    {'res_transformer_aux', 'res_transformer_ts', ...}
    checkpoints/humanml3d/length_estimator/model/finest.tar  {'estimator', 'epoch', 'niter'}

MoGenTS's demo reads the best-FID files of both transformer runs; latest.tar is taken when a run has no best-FID
copy, and any file can be named by option. The VQ folder is the mask run's ``vq_name`` (its opt.txt) when that
file says so, else ``pretrain_vq``. Only the models' state dicts are read.
"""
from __future__ import annotations

import re
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from t2m.export.importers.kit import load_checkpoint_entries
from t2m.families.masked.length_estimator import LengthEstimator
from t2m.families.masked.masked_transformer import MaskedTransformer
from t2m.families.masked.momask_files import MomaskFiles, release_files
from t2m.families.masked.residual_transformer import ResidualTransformer
from t2m.model.networks.fused_vqvae import FusedVQVAE

VQ_DIR = "pretrain_vq"
MASKED_DIR = "pretrain_mtrans"
RESIDUAL_DIR = "pretrain_rtrans"
KIT_SUFFIX = "_kit"
DEMO_STEPS = 18              # the --time_steps default MoGenTS's demo runs with (its evaluation: 10)
# top-level keys, per model of each file, in the order they are tried (best-FID file first, then latest.tar)
ENTRY_KEYS = {
    "vq": (("vq_model", "net"),),
    "masked": (("t2m_transformer_ts", "mask_transformer_ts"), ("t2m_transformer_aux", "mask_transformer_aux")),
    "residual": (("res_transformer_ts",), ("res_transformer_aux",)),
}
ROLES = {"vq": "the VQ-VAE", "masked": "the mask transformers", "residual": "the residual transformers",
         "length": "the length estimator", "mean": "the VQ's meta mean", "std": "the VQ's meta std"}


def _run_file(folder: Path) -> Path:
    """A transformer run's file as MoGenTS's demo reads it: net_best_fid.tar, else latest.tar."""
    best, latest = folder / "model" / "net_best_fid.tar", folder / "model" / "latest.tar"
    return latest if not best.is_file() and latest.is_file() else best


def _vq_name(masked_run: Path) -> str:
    """The VQ run the mask run was trained on (opt.txt's ``vq_name``), else the README's ``pretrain_vq``."""
    options = masked_run / "opt.txt"
    if options.is_file():
        match = re.search(r"^vq_name:\s*(\S+)\s*$", options.read_text(encoding="utf-8", errors="replace"), re.M)
        if match:
            return match.group(1)
    return VQ_DIR


def locate_release(logs_dir: str | Path | None, overrides: Mapping[str, str | Path | None]) -> MomaskFiles:
    """The release's files under ``logs_dir`` (MoGenTS's ``logs/humanml3d`` or ``logs/kit``), each replaceable by
    an explicit path in ``overrides`` (vq, mean, std, masked, residual, length). Missing files are refused naming
    the file and what it is for, except the length estimator of the folder lookup (None: no free length)."""
    given = {role: Path(path) for role, path in overrides.items() if path is not None}
    dataset, looked_for = "HumanML3D", None
    found: dict[str, Path | None] = {}
    if logs_dir is not None:
        root = Path(logs_dir)
        if not root.is_dir():
            raise ValueError(f"{root}: no such folder (expected MoGenTS's logs/humanml3d with {VQ_DIR}/, "
                             f"{MASKED_DIR}/ and {RESIDUAL_DIR}/)")
        kit = root.name == "kit" or (root / (MASKED_DIR + KIT_SUFFIX)).is_dir()
        dataset, suffix = ("KIT-ML", KIT_SUFFIX) if kit else ("HumanML3D", "")
        masked_run = root / (MASKED_DIR + suffix)
        vq_folder = root / _vq_name(masked_run)
        found = {"vq": vq_folder / "model" / "net_best_fid.tar", "mean": vq_folder / "meta" / "mean.npy",
                 "std": vq_folder / "meta" / "std.npy", "masked": _run_file(masked_run),
                 "residual": _run_file(root / (RESIDUAL_DIR + suffix))}
        looked_for = root.parent.parent / "checkpoints" / root.name / "length_estimator" / "model" / "finest.tar"
        found["length"] = looked_for if looked_for.is_file() else None
    return release_files({**found, **given}, "length" in given, ROLES, "LOGS_DIR", dataset, looked_for)


def read_states(path: Path, role: str, allow_pickle: bool = False) -> list[tuple[str, dict[str, torch.Tensor]]]:
    """The state dicts of one release file (the VQ; or the ts then the aux transformer), each as (the top-level
    key found, its tensors in float32 without ``clip_model.*``)."""
    return [(key, {k: v for k, v in state.items() if not k.startswith("clip_model.")})
            for key, state in load_checkpoint_entries(path, ENTRY_KEYS[role], allow_pickle)]


@dataclass
class ImportedMogents:
    """The release as our modules (eval mode), the de-normalisation and the top-level keys read."""

    files: MomaskFiles
    vq: FusedVQVAE
    masked: MaskedTransformer         # ts (2D)
    residual: ResidualTransformer     # ts (2D)
    masked_aux: MaskedTransformer     # aux (1D)
    residual_aux: ResidualTransformer
    length: LengthEstimator | None
    mean: np.ndarray
    std: np.ndarray
    keys: dict[str, str]
