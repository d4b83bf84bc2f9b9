"""Train the motion VQ-VAE on random 64-frame windows (T2M-GPT's recipe, sized for a CPU).

loss = smooth-L1(recon, x)
     + vel_weight    * smooth-L1 of the frame-to-frame differences of the root-relative joint positions
                       (channels 4 : 4 + 3 (J-1) of the normalised features; T2M-GPT applies its "velocity"
                       loss to those channels themselves, we use their true temporal differences, which
                       penalises jitter)
     + bone_weight   * L1 of the bone lengths (metres, t2m.model.training.bone_lengths) against the input's: the
                       decoder predicts joint positions freely, and without this term generated bones stretch by
                       centimetres
     + commit_weight * the quantiser's loss: commitment for ema_reset/residual (weight 0.02, T2M-GPT);
                       codebook + 0.25 commitment for plain (weight 1, the original VQ-VAE)

Validation on the val split (deterministic windows): reconstruction loss, codebook perplexity,
the mean per-joint position error in millimetres after de-normalising and recovering joints, and how much the
reconstructed bones change length within a window (bone_std_mm).
The run directory also gets mean.npy / std.npy: the normalisation the decoder must undo.
"""
from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from t2m.model.data.balancing import BALANCE_POWER_HELP

if TYPE_CHECKING:  # torch is imported inside the functions: `t2m --help` must not pay for it
    import torch

    from t2m.model.networks.joint_vqvae import JointVQVAE
    from t2m.model.networks.vqvae import MotionVQVAE
    from t2m.model.training.bone_lengths import BoneLengths

# = t2m.model.networks.vqvae.QUANTIZERS (kept here so argparse needs no torch)
QUANTIZERS = ("ema_reset", "plain", "residual")


def joints_from_feature_dim(feat_dim: int) -> int:
    """263 -> 22 joints (HumanML3D), 251 -> 21 (KIT-ML): D = 12 J - 1."""
    if (feat_dim + 1) % 12:
        raise ValueError(f"feature dimension {feat_dim} is not a HumanML3D-style layout (12 J - 1)")
    return (feat_dim + 1) // 12


def vq_loss(
    model: MotionVQVAE | JointVQVAE, x: torch.Tensor, vel_weight: float = 0.5, commit_weight: float = 0.02,
    bones: BoneLengths | None = None, bone_weight: float = 0.0,
) -> tuple[torch.Tensor, dict[str, float]]:
    """The training loss and its parts for a batch of normalised windows [B, T, D]."""
    import torch
    import torch.nn.functional as F

    recon, parts = model(x)
    reconstruction = F.smooth_l1_loss(recon, x)
    joints = joints_from_feature_dim(x.shape[-1])
    positions = slice(4, 4 + 3 * (joints - 1))
    velocity = F.smooth_l1_loss(torch.diff(recon[..., positions], dim=1), torch.diff(x[..., positions], dim=1))
    loss = reconstruction + vel_weight * velocity + commit_weight * parts["commit"]
    metrics = {
        "recon": float(reconstruction.detach()),
        "vel": float(velocity.detach()),
        "commit": float(parts["commit"].detach()),
        "perplexity": float(parts["perplexity"]),
    }
    if bones is not None and bone_weight > 0:
        bone = F.l1_loss(bones(recon), bones(x))
        loss = loss + bone_weight * bone
        metrics["bone_m"] = float(bone.detach())
    return loss, metrics


def validate_vq(
    model: MotionVQVAE | JointVQVAE, windows: torch.Tensor, mean: np.ndarray, std: np.ndarray, batch_size: int = 64,
    max_joint_windows: int = 64,
) -> dict[str, float]:
    """Reconstruction loss, perplexity over all windows' codes, and MPJPE (mm) on the first windows."""
    import torch

    model.eval()
    with torch.no_grad():
        return _validate_vq(model, windows, mean, std, batch_size, max_joint_windows)


def _validate_vq(
    model: MotionVQVAE | JointVQVAE, windows: torch.Tensor, mean: np.ndarray, std: np.ndarray, batch_size: int,
    max_joint_windows: int,
) -> dict[str, float]:
    import torch
    import torch.nn.functional as F

    from t2m.model.data.motion_data import SKELETON_BY_DIM
    from t2m.model.networks.quantizers import code_perplexity
    from t2m.motion.features import features_to_joints
    from t2m.motion.skeleton import get_skeleton

    losses, codes, errors, bone_stds = [], [], [], []
    skeleton = SKELETON_BY_DIM[windows.shape[-1]]
    parents = list(get_skeleton(skeleton).parents[1:])
    for start in range(0, len(windows), batch_size):
        x = windows[start : start + batch_size]
        recon, parts = model(x)
        losses.append(float(F.smooth_l1_loss(recon, x)) * len(x))
        codes.append(parts["codes"].reshape(-1, parts["codes"].shape[-1]) if parts["codes"].dim() == 3
                     else parts["codes"].reshape(-1))
        for index in range(len(x)):
            if start + index >= max_joint_windows:
                break
            truth = features_to_joints(x[index].numpy() * std + mean, skeleton)
            guess = features_to_joints(recon[index].numpy() * std + mean, skeleton)
            errors.append(float(np.linalg.norm(truth - guess, axis=-1).mean()))
            bone_lengths = np.linalg.norm(guess[:, 1:] - guess[:, parents], axis=-1)
            bone_stds.append(float(bone_lengths.std(axis=0).mean()))
    all_codes = torch.cat(codes)
    first_layer = all_codes[:, 0] if all_codes.dim() == 2 else all_codes
    return {
        "recon": sum(losses) / len(windows),
        "perplexity": float(code_perplexity(first_layer, model.config.nb_code)),
        "mpjpe_mm": 1000.0 * float(np.mean(errors)),
        "bone_std_mm": 1000.0 * float(np.mean(bone_stds)),
    }


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from t2m.model.training.run_options import add_bookkeeping_arguments, add_schedule_arguments

    add_schedule_arguments(parser, steps=20_000, batch_size=64)
    parser.add_argument("--window", type=int, default=64,
                        help="frames per training window (a multiple of 2**down-t frames per code)")
    parser.add_argument("--width", type=int, default=256)
    parser.add_argument("--code-dim", type=int, default=256)
    parser.add_argument("--nb-code", type=int, default=512)
    parser.add_argument("--down-t", type=int, default=2,
                        help="temporal downsamplings by 2: 2 = 4 frames per code (T2M-GPT), 3 = 8 (T2M-HiFiGPT)")
    parser.add_argument("--depth", type=int, default=3)
    parser.add_argument("--quantizer", choices=QUANTIZERS, default="ema_reset")
    parser.add_argument("--residual-layers", type=int, default=1, help="residual depth R (with --quantizer residual)")
    parser.add_argument("--shared-codebook", action="store_true",
                        help="one codebook for every residual depth (T2M-HiFiGPT's RVQ-VAE; --quantizer residual)")
    parser.add_argument("--quantizer-dropout", type=float, default=0.2)
    parser.add_argument("--vel-weight", type=float, default=0.5)
    parser.add_argument("--bone-weight", type=float, default=0.0,
                        help="weight of the bone-length L1 term (metres; 0 = off, as in T2M-GPT)")
    parser.add_argument("--commit-weight", type=float, default=None,
                        help="weight of the quantiser loss (default 0.02 for ema_reset/residual, 1.0 for plain)")
    parser.add_argument("--balance-power", type=float, default=1.0, help=BALANCE_POWER_HELP)
    add_bookkeeping_arguments(parser, every=1000)


def window_loader(train_set: Any, batch_size: int, balance_power: float, out: Path) -> Any:
    """Shuffled windows, or (balance_power < 1) windows drawn with action-balanced weights.

    The weights come from t2m.model.data.balancing."""
    from torch.utils.data import DataLoader, WeightedRandomSampler

    from t2m.model.data.balancing import run_sampling_weights

    drop_last = len(train_set) >= batch_size
    weights = run_sampling_weights(train_set.ids, balance_power, out, train_set.captions_of)
    if weights is None:
        return DataLoader(train_set, batch_size=batch_size, shuffle=True, drop_last=drop_last)
    sampler = WeightedRandomSampler(weights.tolist(), num_samples=len(train_set), replacement=True)
    return DataLoader(train_set, batch_size=batch_size, sampler=sampler, drop_last=drop_last)


def main(args: argparse.Namespace) -> int:
    import torch

    from t2m.model.data.datasets import VQWindowDataset, open_split
    from t2m.model.data.motion_data import SKELETON_BY_DIM
    from t2m.model.networks.vqvae import MotionVQVAE, VQConfig
    from t2m.model.training.bone_lengths import BoneLengths
    from t2m.model.training.loop import LoopSettings, infinite, run_training, set_seed, set_threads
    from t2m.model.training.run_options import parse_milestones
    from t2m.motion.skeleton import get_skeleton

    if args.down_t < 1:
        raise ValueError(f"--down-t must be >= 1, got {args.down_t}")
    frames_per_code = 2**args.down_t
    if args.window % frames_per_code or args.window < frames_per_code:
        raise ValueError(f"--window must be a positive multiple of {frames_per_code} (2**down-t), got {args.window}")
    if args.shared_codebook and args.quantizer != "residual":
        raise ValueError("--shared-codebook needs --quantizer residual")
    for name in ("steps", "batch_size"):
        if getattr(args, name) < 1:
            raise ValueError(f"--{name.replace('_', '-')} must be >= 1")
    if args.bone_weight < 0:
        raise ValueError(f"--bone-weight must be >= 0, got {args.bone_weight}")
    if not 0.0 <= args.balance_power <= 1.0:
        raise ValueError(f"--balance-power must be in [0, 1], got {args.balance_power}")
    if args.commit_weight is None:
        args.commit_weight = 1.0 if args.quantizer == "plain" else 0.02
    out = Path(args.out)
    if out.exists() and (out / "config.json").exists() and not args.resume:
        raise ValueError(f"{out} already holds a run; pass --resume to continue it or choose another --out")
    set_threads(args.threads)
    set_seed(args.seed)

    train_reader = open_split(args.data, "train")
    val_reader = open_split(args.data, "val")
    mean, std = np.asarray(train_reader.mean, np.float32), np.asarray(train_reader.std, np.float32)
    train_set = VQWindowDataset(train_reader, window=args.window)
    val_set = VQWindowDataset(val_reader, window=args.window, fixed_offsets=True)
    val_windows = torch.stack([val_set[i] for i in range(min(len(val_set), 512))])

    config = VQConfig(
        feat_dim=int(mean.shape[0]), width=args.width, code_dim=args.code_dim, nb_code=args.nb_code,
        down_t=args.down_t, depth=args.depth, quantizer=args.quantizer, residual_layers=args.residual_layers,
        quantizer_dropout=args.quantizer_dropout, shared_codebook=args.shared_codebook,
    )
    model = MotionVQVAE(config)
    out.mkdir(parents=True, exist_ok=True)
    np.save(out / "mean.npy", mean)
    np.save(out / "std.npy", std)
    loader = window_loader(train_set, args.batch_size, args.balance_power, out)
    settings = LoopSettings(
        steps=args.steps, lr=args.lr, weight_decay=args.weight_decay, warmup_steps=args.warmup_steps,
        lr_milestones=parse_milestones(args.lr_milestones), lr_gamma=args.lr_gamma, grad_clip=None,
        log_every=args.log_every, val_every=args.val_every, save_every=args.save_every, seed=args.seed,
    )

    bones = BoneLengths(mean, std, get_skeleton(SKELETON_BY_DIM[int(mean.shape[0])]).parents)

    def step_fn(net: MotionVQVAE, batch: torch.Tensor) -> tuple[torch.Tensor, dict[str, float], int]:
        loss, metrics = vq_loss(net, batch, args.vel_weight, args.commit_weight, bones, args.bone_weight)
        return loss, metrics, len(batch)

    data_info: dict[str, Any] = {
        "data_dir": str(Path(args.data).resolve()), "train_clips": len(train_set), "val_windows": len(val_windows),
        "window": args.window, "batch_size": args.batch_size, "seed": args.seed, "balance_power": args.balance_power,
        "loss": {"vel_weight": args.vel_weight, "commit_weight": args.commit_weight,
                 "bone_weight": args.bone_weight},
        "normalization": {"mean": "mean.npy", "std": "std.npy"},
    }
    run_training(
        model, infinite(loader), step_fn, settings, out,
        val_fn=lambda net: validate_vq(net, val_windows, mean, std),
        data_info=data_info, resume=args.resume, name="vq",
    )
    return 0
