"""Train a new decoder for a trained VQ-VAE on its frozen codes (the encoder and quantiser stay as they are).

Why: the codes are what the text-to-code models were trained on, so a decoder trained on the same codes serves
them unchanged, with another decoder shape. --causal-decoder-blocks gives the decoder's dilated residual blocks
past-only convolutions: T2M-HiFiGPT's decoder (three x2 levels) then looks 3 codes ahead instead of 25, and a
stream's frames are final almost as soon as their codes are sampled (service/engine/streaming.py).

The new decoder starts from the old one's weights (a causal block's k=3 taps move one tap into the past: the old
t - d and t taps read t - d and t, the old t + d tap is dropped), and is trained with train_vq's loss (reconstruction,
velocity, bone lengths; the quantiser's commitment is constant here) on windows of every depth's codes: the
quantiser runs in eval mode (no dropout of depths, no EMA update). The output is an ordinary VQ run directory
(config.json kind "vq", model.safetensors, mean.npy, std.npy) that `t2m eval --vq` and the exporters take.
"""
from __future__ import annotations

import argparse
import shutil
from pathlib import Path
from typing import TYPE_CHECKING, Any

from t2m.model.data.balancing import BALANCE_POWER_HELP
from t2m.model.training import run_options

if TYPE_CHECKING:
    import torch

    from t2m.model.networks.vqvae import MotionVQVAE


def add_arguments(parser: argparse.ArgumentParser) -> None:
    run_options.add_schedule_arguments(parser, steps=8000, batch_size=64, lr=1e-4, warmup_steps=200)
    parser.add_argument("--vq", required=True, help="run directory of the trained VQ whose codes stay")
    parser.add_argument("--causal-decoder-blocks", action=argparse.BooleanOptionalAction, default=True,
                        help="past-only dilated convolutions in the decoder's residual blocks (a short lookahead)")
    parser.add_argument("--window", type=int, default=64,
                        help="frames per training window (a multiple of the VQ's frames per code)")
    parser.add_argument("--vel-weight", type=float, default=0.5)
    parser.add_argument("--bone-weight", type=float, default=0.5)
    parser.add_argument("--balance-power", type=float, default=1.0, help=BALANCE_POWER_HELP)
    run_options.add_bookkeeping_arguments(parser, every=1000)


def move_taps_into_the_past(source: MotionVQVAE, target: MotionVQVAE) -> None:
    """Copy source's weights into target; where target's decoder blocks are causal and source's are not, a k=3
    dilated kernel's taps (t - d, t, t + d) become (t - 2d, t - d, t) = (0, old t - d, old t)."""
    state = source.state_dict()
    causal = target.config.causal_decoder_blocks and not source.config.causal_decoder_blocks
    for name, tensor in list(state.items()):
        if causal and name.startswith("decoder.") and name.endswith("conv1.weight"):
            moved = tensor.clone()
            moved[..., 0] = 0.0
            moved[..., 1:] = tensor[..., :2]
            state[name] = moved
    target.load_state_dict(state, strict=True)


def freeze_codes(model: MotionVQVAE) -> None:
    """Only the decoder learns: the encoder and quantiser keep their weights, codebooks and EMA statistics."""
    for module in (model.encoder, model.quantizer):
        module.requires_grad_(False)
        module.eval()


def main(args: argparse.Namespace) -> int:
    import numpy as np
    import torch

    from t2m.model.data.datasets import VQWindowDataset, open_split
    from t2m.model.data.motion_data import SKELETON_BY_DIM
    from t2m.model.networks.vqvae import MotionVQVAE, VQConfig
    from t2m.model.training.bone_lengths import BoneLengths
    from t2m.model.training.checkpoint import CODES_OF, load_model
    from t2m.model.training.loop import infinite, run_training, set_seed, set_threads
    from t2m.model.training.train_vq import validate_vq, vq_loss, window_loader
    from t2m.motion.skeleton import get_skeleton

    out = run_options.check_arguments(args, positive=("window",), fractions=("balance_power",))
    source_dir = Path(args.vq)
    if source_dir.resolve() == out.resolve():
        raise ValueError("--out must differ from --vq: the source VQ run is read, never overwritten")
    if args.bone_weight < 0:
        raise ValueError(f"--bone-weight must be >= 0, got {args.bone_weight}")
    source = load_model(source_dir, "vq")
    per_code = source.frames_per_token
    if args.window % per_code:
        raise ValueError(f"--window must be a multiple of the VQ's {per_code} frames per code, got {args.window}")
    set_threads(args.threads)
    set_seed(args.seed)

    config = VQConfig.from_dict({**source.config.to_dict(), "causal_decoder_blocks": args.causal_decoder_blocks})
    model = MotionVQVAE(config)
    move_taps_into_the_past(source, model)
    freeze_codes(model)

    mean, std = np.load(source_dir / "mean.npy"), np.load(source_dir / "std.npy")
    train_reader, val_reader = open_split(args.data, "train"), open_split(args.data, "val")
    if not np.allclose(np.asarray(train_reader.mean), mean):
        raise ValueError(f"{args.data}: its normalisation differs from {source_dir}'s mean.npy (another dataset?)")
    train_set = VQWindowDataset(train_reader, window=args.window)
    val_set = VQWindowDataset(val_reader, window=args.window, fixed_offsets=True)
    val_windows = torch.stack([val_set[i] for i in range(min(len(val_set), 512))])
    out.mkdir(parents=True, exist_ok=True)
    for name in ("mean.npy", "std.npy"):
        shutil.copyfile(source_dir / name, out / name)

    bones = BoneLengths(mean, std, get_skeleton(SKELETON_BY_DIM[int(mean.shape[0])]).parents)

    def step_fn(net: MotionVQVAE, batch: torch.Tensor) -> tuple[torch.Tensor, dict[str, float], int]:
        freeze_codes(net)   # run_training switches the whole model to train mode after each validation
        loss, metrics = vq_loss(net, batch, args.vel_weight, 0.0, bones, args.bone_weight)
        return loss, metrics, len(batch)

    data_info: dict[str, Any] = {
        "data_dir": str(Path(args.data).resolve()), "train_clips": len(train_set), "val_windows": len(val_windows),
        "window": args.window, "batch_size": args.batch_size, "seed": args.seed, "balance_power": args.balance_power,
        "loss": {"vel_weight": args.vel_weight, "bone_weight": args.bone_weight},
        CODES_OF: str(source_dir.resolve()),
        "normalization": {"mean": "mean.npy", "std": "std.npy"},
    }
    run_training(
        model, infinite(window_loader(train_set, args.batch_size, args.balance_power, out)), step_fn,
        run_options.loop_settings(args, grad_clip=None), out,
        val_fn=lambda net: validate_vq(net, val_windows, mean, std),
        data_info=data_info, resume=args.resume, name="vq-decoder",
    )
    return 0
