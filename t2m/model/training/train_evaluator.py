"""`t2m train evaluator`: train the contrastive text-motion evaluator (t2m/model/evaluator.py) on a dataset's train
split.

    t2m train evaluator --data DIR --out RUN [--steps 1000 --batch-size 64 --lr 3e-4 --seed 0 --threads 1]

Each step draws a batch of (clip, one of its captions): a crop of at most 196 frames (a multiple of 4, as the
generated motions are), normalised with the dataset's Mean/Std (stored in the checkpoint), against the frozen
MiniLM feature of the caption. Batches are made of clips of similar length: less padding (faster on CPU) and the
evaluator cannot tell pairs apart by duration alone. Validation reports the loss and the 32-way R@1/R@3 of
Guo et al. on the val split. Checkpoints follow docs/contracts.md (kind "evaluator").
"""
from __future__ import annotations

import argparse
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from t2m.model.networks.evaluator import (
    EvaluatorConfig,
    MotionEvaluator,
    embed_motions,
    false_negative_mask,
    info_nce,
    pad_batch,
)
from t2m.motion.constants import FRAMES_PER_TOKEN

TEXT_CACHE = "text_features.npz"


@dataclass
class PairSet:
    """A split held in memory: normalised feature arrays and, per clip, the rows of its captions' features."""

    ids: list[str]
    clips: list[np.ndarray]            # [T_i, D] normalised float32
    caption_rows: list[np.ndarray]     # int indices into text_features
    captions: list[list[str]]
    text_features: np.ndarray          # [C, Dt]


def load_pairs(reader, text_features: dict[str, np.ndarray], mean: np.ndarray, std: np.ndarray,
               min_frames: int = 4) -> PairSet:
    """Read every clip of a MotionDirectory-like reader, with its captions' cached features."""
    from tqdm import tqdm

    texts = list(text_features)
    row_of = {text: row for row, text in enumerate(texts)}
    ids, clips, rows, captions = [], [], [], []
    for clip_id in tqdm(list(reader.ids), desc=f"loading {getattr(reader, 'split', 'clips')}", unit="clip",
                        leave=False):
        features = reader.features(clip_id)
        clip_captions = [c for c in reader.captions(clip_id) if c in row_of]
        if features.shape[0] < min_frames or not clip_captions:
            continue
        ids.append(clip_id)
        clips.append(((features - mean) / std).astype(np.float32))
        rows.append(np.array([row_of[c] for c in clip_captions], dtype=np.int64))
        captions.append(clip_captions)
    if len(ids) < 2:
        raise ValueError(f"{getattr(reader, 'root', 'dataset')}: need at least 2 clips with captions and "
                         f">= {min_frames} frames, found {len(ids)}")
    matrix = np.stack([text_features[t] for t in texts]).astype(np.float32) if texts else np.zeros((0, 0), np.float32)
    return PairSet(ids, clips, rows, captions, matrix)


def crop(clip: np.ndarray, max_frames: int, unit: int, rng: np.random.Generator | None) -> np.ndarray:
    """At most max_frames frames, a multiple of `unit`; a random start with rng, else from the first frame."""
    length = min(len(clip), max_frames)
    length = max(unit, length - length % unit) if length >= unit else length
    start = 0 if rng is None else int(rng.integers(0, len(clip) - length + 1))
    return clip[start:start + length]


def training_batches(pairs: PairSet, batch_size: int, max_frames: int, unit: int, seed: int,
                     bucket: int = 8) -> Iterator[tuple[torch.Tensor, torch.Tensor, torch.Tensor]]:
    """Endless (features, lengths, text features) batches: every epoch visits each clip once, with a random
    caption and crop; `bucket` batches' worth of clips are sorted by length before being cut into batches."""
    rng = np.random.default_rng(seed)
    batch_size = min(batch_size, len(pairs.ids))
    while True:
        order = rng.permutation(len(pairs.ids))
        batches = []
        for start in range(0, len(order), batch_size * bucket):
            chunk = order[start:start + batch_size * bucket]
            chunk = chunk[np.argsort([len(pairs.clips[i]) for i in chunk], kind="stable")]
            batches += [chunk[i:i + batch_size] for i in range(0, len(chunk), batch_size)]
        batches = [b for b in batches if len(b) >= 2]
        for index in rng.permutation(len(batches)):
            items = batches[index]
            motions = [crop(pairs.clips[i], max_frames, unit, rng) for i in items]
            rows = [int(rng.choice(pairs.caption_rows[i])) for i in items]
            features, lengths = pad_batch(motions)
            yield features, lengths, torch.from_numpy(pairs.text_features[rows])


def fixed_pairs(pairs: PairSet, max_frames: int, unit: int, seed: int = 0) -> tuple[list[np.ndarray], np.ndarray]:
    """One deterministic (crop from the first frame, seeded caption choice) pair per clip, for validation."""
    rng = np.random.default_rng(seed)
    motions = [crop(clip, max_frames, unit, None) for clip in pairs.clips]
    rows = np.array([int(rng.choice(r)) for r in pairs.caption_rows])
    return motions, pairs.text_features[rows]


def make_step_fn(fn_threshold: float):
    def step_fn(model: MotionEvaluator, batch) -> tuple[torch.Tensor, dict[str, float], int]:
        features, lengths, text = batch
        text_emb, motion_emb = model(features, lengths, text)
        ignore = false_negative_mask(text, fn_threshold)
        loss = info_nce(text_emb, motion_emb, model.config.temperature, ignore)
        with torch.no_grad():
            logits = (text_emb @ motion_emb.T).masked_fill(ignore, float("-inf"))
            accuracy = (logits.argmax(1) == torch.arange(len(logits))).float().mean()
        return loss, {"batch_acc": float(accuracy)}, len(lengths)
    return step_fn


def make_val_fn(pairs: PairSet, max_frames: int, unit: int, batch_size: int, fn_threshold: float):
    """Validation on fixed pairs: mean InfoNCE over batches of the training size, and 32-way R@1/R@3."""
    from t2m.model.evaluation.metrics import r_precision

    motions, text_features = fixed_pairs(pairs, max_frames, unit)
    text = torch.from_numpy(text_features)

    @torch.no_grad()
    def val_fn(model: MotionEvaluator) -> dict[str, float]:
        motion_emb = torch.from_numpy(embed_motions(model, motions))
        text_emb = model.encode_text(text)
        losses = []
        for start in range(0, len(text), batch_size):
            chunk = slice(start, start + batch_size)
            if len(text[chunk]) < 2:
                continue
            ignore = false_negative_mask(text[chunk], fn_threshold)
            losses.append(float(info_nce(text_emb[chunk], motion_emb[chunk], model.config.temperature, ignore)))
        top = r_precision(text_emb.numpy(), motion_emb.numpy(), top_k=3, pool=32, seed=0)
        return {"loss": float(np.mean(losses)), "r1": float(top[0]), "r3": float(top[2])}

    return val_fn


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--data", required=True, help="dataset directory in HumanML3D layout (train and val splits)")
    parser.add_argument("--out", required=True, help="run directory for the checkpoint, logs and curves")
    parser.add_argument("--steps", type=int, default=1000, help="optimisation steps (default 1000)")
    parser.add_argument("--batch-size", type=int, default=64,
                        help="pairs per batch, the InfoNCE negatives (default 64)")
    parser.add_argument("--lr", type=float, default=3e-4, help="peak learning rate (default 3e-4)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--threads", type=int, default=1,
                        help="torch CPU threads (default 1: on shared cores more threads mostly wait for each other)")
    parser.add_argument("--val-every", type=int, default=250, help="validate every N steps (default 250)")
    parser.add_argument("--embed-dim", type=int, default=EvaluatorConfig.embed_dim)
    parser.add_argument("--width", type=int, default=EvaluatorConfig.width)
    parser.add_argument("--layers", type=int, default=EvaluatorConfig.n_layer)
    parser.add_argument("--temperature", type=float, default=EvaluatorConfig.temperature)
    parser.add_argument("--fn-threshold", type=float, default=0.95,
                        help="captions whose MiniLM cosine similarity is at least this are not negatives "
                             "(default 0.95)")
    parser.add_argument("--text-cache", default=None,
                        help=f"npz cache of caption features (default RUN/{TEXT_CACHE}; shareable between runs)")
    parser.add_argument("--resume", action="store_true", help="continue from RUN/resume.pt")


def _check_args(args: argparse.Namespace) -> None:
    for name in ("steps", "batch_size", "threads", "val_every", "embed_dim", "width", "layers"):
        value = getattr(args, name)
        if value < 1:
            raise ValueError(f"--{name.replace('_', '-')} must be at least 1, got {value}")
    if args.batch_size < 2:
        raise ValueError(f"--batch-size must be at least 2 (InfoNCE needs negatives), got {args.batch_size}")
    if not args.lr > 0 or not args.temperature > 0:
        raise ValueError("--lr and --temperature must be positive")


def main(args: argparse.Namespace) -> int:
    from t2m.model.data.motion_data import MotionDirectory
    from t2m.model.networks.text_encoders import cache_text_features, get_text_encoder
    from t2m.model.training.loop import LoopSettings, run_training, set_seed, set_threads

    _check_args(args)
    set_threads(args.threads)
    set_seed(args.seed)
    run_dir = Path(args.out)
    run_dir.mkdir(parents=True, exist_ok=True)
    train_reader = MotionDirectory(args.data, "train")
    val_reader = MotionDirectory(args.data, "val")
    config = EvaluatorConfig(feature_dim=train_reader.feature_dim, embed_dim=args.embed_dim, width=args.width,
                             n_layer=args.layers, temperature=args.temperature)
    encoder = get_text_encoder(config.text_encoder)
    config.text_dim = encoder.dim
    cache = Path(args.text_cache) if args.text_cache else run_dir / TEXT_CACHE
    text_features = cache_text_features([train_reader, val_reader], encoder, cache)
    train = load_pairs(train_reader, text_features, train_reader.mean, train_reader.std)
    val = load_pairs(val_reader, text_features, train_reader.mean, train_reader.std)

    model = MotionEvaluator(config)
    model.set_normalization(train_reader.mean, train_reader.std)
    unit = FRAMES_PER_TOKEN  # real crops match the lengths generated motions can have
    settings = LoopSettings(steps=args.steps, lr=args.lr, weight_decay=0.01, warmup_steps=min(100, args.steps // 10),
                            lr_milestones=(0.8,), lr_gamma=0.1, log_every=min(50, args.steps),
                            val_every=args.val_every, save_every=args.val_every, seed=args.seed)
    data_info = {"data": str(Path(args.data).resolve()), "train_items": len(train.ids), "val_items": len(val.ids),
                 "text_encoder": config.text_encoder, "batch_size": args.batch_size, "fn_threshold": args.fn_threshold,
                 "crop_unit": unit}
    run_training(model, training_batches(train, args.batch_size, config.max_frames, unit, args.seed),
                 make_step_fn(args.fn_threshold), settings, run_dir,
                 val_fn=make_val_fn(val, config.max_frames, unit, args.batch_size, args.fn_threshold),
                 data_info=data_info, resume=args.resume, name="evaluator")
    return 0
