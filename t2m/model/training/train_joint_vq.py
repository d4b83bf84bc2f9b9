"""Train the 2D joint VQ-VAE (MoGenTS's quantiser, t2m.model.networks.joint_vqvae) on random feature windows.

The loss, validation (reconstruction, first-layer perplexity, MPJPE in mm, bone_std_mm) and data pipeline are the
1D VQ's (t2m.model.training.train_vq): the joint VQ reads and writes the same normalised [B, T, 263] features; only
the network in the middle differs. The run directory gets mean.npy / std.npy as a VQ run does.
"""
from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from t2m.model.data.balancing import BALANCE_POWER_HELP
from t2m.model.training import run_options

if TYPE_CHECKING:
    import torch

    from t2m.model.networks.joint_vqvae import JointVQVAE


def add_arguments(parser: argparse.ArgumentParser) -> None:
    run_options.add_schedule_arguments(parser, steps=6000, batch_size=32)
    parser.add_argument("--window", type=int, default=64, help="frames per training window (multiple of 4)")
    parser.add_argument("--width", type=int, default=64, help="channels of the 2D convolutions")
    parser.add_argument("--code-dim", type=int, default=128)
    parser.add_argument("--nb-code", type=int, default=256, help="codes per quantiser layer")
    parser.add_argument("--down-t", type=int, default=2, help="time halvings (2: 4 frames per token row)")
    parser.add_argument("--down-j", type=int, default=2,
                        help="joint halvings (2: 22 joints padded to 24 -> 6 columns, MoGenTS; 0: one per joint)")
    parser.add_argument("--depth", type=int, default=3, help="residual blocks per resolution")
    parser.add_argument("--residual-layers", type=int, default=4, help="quantiser layers R")
    parser.add_argument("--quantizer-dropout", type=float, default=0.2,
                        help="probability of training a batch on the first r ~ U{1..R} layers only")
    parser.add_argument("--vel-weight", type=float, default=0.5)
    parser.add_argument("--bone-weight", type=float, default=0.0, help="weight of the bone-length L1 term (metres)")
    parser.add_argument("--commit-weight", type=float, default=0.02)
    parser.add_argument("--balance-power", type=float, default=1.0, help=BALANCE_POWER_HELP)
    run_options.add_bookkeeping_arguments(parser, every=1000)


def main(args: argparse.Namespace) -> int:
    import torch

    from t2m.model.data.datasets import VQWindowDataset, open_split
    from t2m.model.data.motion_data import SKELETON_BY_DIM
    from t2m.model.networks.joint_vqvae import JointVQConfig, JointVQVAE
    from t2m.model.training.bone_lengths import BoneLengths
    from t2m.model.training.loop import infinite, run_training, set_seed, set_threads
    from t2m.model.training.train_vq import validate_vq, vq_loss, window_loader
    from t2m.motion.skeleton import get_skeleton

    out = run_options.check_arguments(args, (), ("balance_power", "quantizer_dropout"))
    if args.window % 4 or args.window < 4:
        raise ValueError(f"--window must be a positive multiple of 4, got {args.window}")
    if args.bone_weight < 0:
        raise ValueError(f"--bone-weight must be >= 0, got {args.bone_weight}")
    set_threads(args.threads)
    set_seed(args.seed)

    train_reader, val_reader = open_split(args.data, "train"), open_split(args.data, "val")
    mean, std = np.asarray(train_reader.mean, np.float32), np.asarray(train_reader.std, np.float32)
    config = JointVQConfig(
        feat_dim=int(mean.shape[0]), width=args.width, code_dim=args.code_dim, nb_code=args.nb_code,
        down_t=args.down_t, down_j=args.down_j, depth=args.depth, residual_layers=args.residual_layers,
        quantizer_dropout=args.quantizer_dropout,
    )
    model = JointVQVAE(config)
    train_set = VQWindowDataset(train_reader, window=args.window)
    val_set = VQWindowDataset(val_reader, window=args.window, fixed_offsets=True)
    val_windows = torch.stack([val_set[i] for i in range(min(len(val_set), 512))])
    out.mkdir(parents=True, exist_ok=True)
    np.save(out / "mean.npy", mean)
    np.save(out / "std.npy", std)
    loader = window_loader(train_set, args.batch_size, args.balance_power, out)
    bones = BoneLengths(mean, std, get_skeleton(SKELETON_BY_DIM[int(mean.shape[0])]).parents)

    def step_fn(net: JointVQVAE, batch: torch.Tensor) -> tuple[torch.Tensor, dict[str, float], int]:
        loss, metrics = vq_loss(net, batch, args.vel_weight, args.commit_weight, bones, args.bone_weight)
        return loss, metrics, len(batch)

    data_info: dict[str, Any] = {
        "data_dir": str(Path(args.data).resolve()), "train_clips": len(train_set), "val_windows": len(val_windows),
        "window": args.window, "batch_size": args.batch_size, "seed": args.seed, "balance_power": args.balance_power,
        "frames_per_token": config.frames_per_token, "columns": config.columns,
        "loss": {"vel_weight": args.vel_weight, "commit_weight": args.commit_weight, "bone_weight": args.bone_weight},
        "normalization": {"mean": "mean.npy", "std": "std.npy"},
    }
    run_training(
        model, infinite(loader), step_fn, run_options.loop_settings(args, grad_clip=None), out,
        val_fn=lambda net: validate_vq(net, val_windows, mean, std),
        data_info=data_info, resume=args.resume, name="joint_vq",
    )
    return 0
