"""Train the length estimator: text feature -> number of token rows (t2m.families.masked.length_estimator).

Items are (caption feature, rows) for every caption of every clip, rows = min(frames // frames_per_token,
max_tokens) (a longer clip counts as the longest motion the masked model makes). loss = cross entropy over
0..max_tokens. Validation: that loss, exact accuracy, and the mean absolute error in rows of the most likely and of
the expected count.
"""
from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from t2m.model.training import run_options

if TYPE_CHECKING:
    import torch

    from t2m.families.masked.length_estimator import LengthEstimator


def caption_lengths(reader: Any, text_features: dict[str, np.ndarray], frames_per_token: int, max_tokens: int):
    """(features [N, Dt] float32, rows [N] int64, clip ids [N]) over every (clip, caption) pair of a split."""
    features, rows, ids = [], [], []
    for clip_id in reader.ids:
        count = min(len(reader.features(clip_id)) // frames_per_token, max_tokens)
        for caption in reader.captions(clip_id):
            if caption in text_features:
                features.append(text_features[caption])
                rows.append(count)
                ids.append(clip_id)
    if not features:
        raise ValueError("no caption has a cached text feature")
    return np.stack(features).astype(np.float32), np.asarray(rows, dtype=np.int64), ids


def length_loss(model: LengthEstimator, cond: torch.Tensor, rows: torch.Tensor) -> tuple[torch.Tensor, dict]:
    import torch
    import torch.nn.functional as F

    logits = model(cond)
    loss = F.cross_entropy(logits, rows)
    probs = logits.detach().softmax(-1)
    expected = (probs * torch.arange(logits.shape[-1])).sum(-1)
    return loss, {
        "ce": float(loss.detach()),
        "acc": float((logits.argmax(-1) == rows).float().mean()),
        "mae_rows": float((logits.argmax(-1) - rows).abs().float().mean()),
        "mae_expected_rows": float((expected - rows).abs().mean()),
    }


def add_arguments(parser: argparse.ArgumentParser) -> None:
    run_options.add_schedule_arguments(parser, steps=3000, batch_size=256, lr=1e-3, weight_decay=1e-4,
                                       warmup_steps=100)
    parser.add_argument("--hidden", type=int, default=256, help="first hidden width (then /2, /4)")
    parser.add_argument("--dropout", type=float, default=0.2)
    parser.add_argument("--max-tokens", type=int, default=50, help="largest row count (the masked model's)")
    parser.add_argument("--frames-per-token", type=int, default=4)
    run_options.add_text_arguments(parser)
    run_options.add_bookkeeping_arguments(parser)


def main(args: argparse.Namespace) -> int:
    import torch
    from torch.utils.data import DataLoader, TensorDataset

    from t2m.families.masked.length_estimator import LengthEstimator, LengthEstimatorConfig
    from t2m.model.data.datasets import open_split
    from t2m.model.training.loop import infinite, run_training, set_seed, set_threads

    out = run_options.check_arguments(args, ("hidden", "max_tokens", "frames_per_token"), ("dropout",))
    set_threads(args.threads)
    set_seed(args.seed)
    train_reader, val_reader = open_split(args.data, "train"), open_split(args.data, "val")
    out.mkdir(parents=True, exist_ok=True)
    text_features = run_options.text_features(args, [train_reader, val_reader], out)
    train_x, train_y, _ = caption_lengths(train_reader, text_features, args.frames_per_token, args.max_tokens)
    val_x, val_y, _ = caption_lengths(val_reader, text_features, args.frames_per_token, args.max_tokens)
    val_x, val_y = torch.from_numpy(val_x), torch.from_numpy(val_y)

    config = LengthEstimatorConfig(text_dim=train_x.shape[1], hidden=args.hidden, max_tokens=args.max_tokens,
                                   dropout=args.dropout)
    model = LengthEstimator(config)
    dataset = TensorDataset(torch.from_numpy(train_x), torch.from_numpy(train_y))
    loader = DataLoader(dataset, batch_size=args.batch_size, shuffle=True, drop_last=len(dataset) >= args.batch_size)

    def step_fn(net: LengthEstimator, batch: list[torch.Tensor]) -> tuple[torch.Tensor, dict[str, float], int]:
        loss, metrics = length_loss(net, batch[0], batch[1])
        return loss, metrics, len(batch[1])

    def val_fn(net: LengthEstimator) -> dict[str, float]:
        net.eval()
        with torch.no_grad():
            return length_loss(net, val_x, val_y)[1]

    data_info: dict[str, Any] = {
        "data_dir": str(Path(args.data).resolve()), "train_pairs": len(train_y), "val_pairs": len(val_y),
        "frames_per_token": args.frames_per_token, "max_tokens": args.max_tokens, "seed": args.seed,
        "text_encoder": {"kind": args.text_encoder, "dim": config.text_dim},
    }
    run_training(model, infinite(loader), step_fn, run_options.loop_settings(args, grad_clip=1.0), out,
                 val_fn=val_fn, data_info=data_info, resume=args.resume, name="length")
    return 0
