"""Train the text-to-code GPT on codes of a trained VQ-VAE (T2M-GPT + T2M-HiFiGPT + T2LM ingredients).

Per batch:
- code corruption (T2M-GPT): a fraction tau of the *input* codes is replaced by random codes, so the model
  learns to recover from its own sampling mistakes; tau fixed (--corruption 0.5) or drawn U[0, 1] per sample
  (--corruption uniform). End and Pad are left as they are.
- condition noise: each row's text feature is moved to a random direction at a random distance (cosine down to
  1/sqrt(1 + s^2) for --cond-noise s), keeping its norm. A new wording lands about 0.2 in cosine from the nearest
  training caption; without noise the GPT saw only the ~15k caption embeddings and did not carry their motion to
  such neighbours (a turn probe whose nearest captions are all turns still walked straight).
- condition dropout (T2M-HiFiGPT / MoMask): with probability p the text feature becomes zeros, which trains the
  unconditional branch that classifier-free guidance needs (the null condition = zeros).
- length conditioning (T2LM-style): with probability --length-keep the true code count is given, else 0 (free).
- loss: cross entropy over codes + End at every position; Pad targets are ignored.

Text features are computed once per caption and cached (<out>/text_features.npz); codes are computed once per
clip with the VQ (<out>/codes_<split>.npz).
"""
from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from t2m.model.data.balancing import BALANCE_POWER_HELP
from t2m.model.training.conditioning import drop_condition, encoder_max_length, perturb_condition, text_features_dim

if TYPE_CHECKING:  # torch is imported inside the functions: `t2m --help` must not pay for it
    import torch

    from t2m.families.gpt.network import MotionGPT
    from t2m.model.networks.vqvae import MotionVQVAE


def corrupt_codes(
    tokens: torch.Tensor, tau: torch.Tensor | float, codebook_size: int, generator: torch.Generator | None = None
) -> torch.Tensor:
    """Replace each code token (< K) with probability tau (scalar or per row [B]) by a uniformly random code."""
    import torch

    tau = torch.as_tensor(tau, dtype=torch.float32)
    if tau.dim() == 1:
        tau = tau[:, None]
    is_code = tokens < codebook_size
    replace = (torch.rand(tokens.shape, generator=generator) < tau) & is_code
    random_codes = torch.randint(0, codebook_size, tokens.shape, generator=generator)
    return torch.where(replace, random_codes, tokens)


def drop_length(length: torch.Tensor, keep: float, generator: torch.Generator | None = None) -> torch.Tensor:
    """Keep each row's true length with probability keep, else 0 (free length)."""
    import torch

    kept = torch.rand(length.shape[0], generator=generator) < keep
    return torch.where(kept, length, torch.zeros_like(length))


def sample_tau(batch: int, corruption: str | float, generator: torch.Generator | None = None) -> torch.Tensor:
    """Per-row corruption rates: a fixed value or U[0, 1] ('uniform')."""
    import torch

    if corruption == "uniform":
        return torch.rand(batch, generator=generator)
    return torch.full((batch,), float(corruption))


def next_token_loss(
    model: MotionGPT, cond: torch.Tensor, inputs: torch.Tensor, targets: torch.Tensor, length: torch.Tensor | None
) -> tuple[torch.Tensor, dict[str, float]]:
    """logits for [cond, inputs] vs targets [B, S+1]; Pad targets ignored. Returns (loss, {ce, acc})."""
    import torch.nn.functional as F

    logits = model(cond, inputs, length)
    pad_id = model.config.pad_id
    loss = F.cross_entropy(logits.reshape(-1, logits.shape[-1]), targets.reshape(-1), ignore_index=pad_id)
    valid = targets != pad_id
    accuracy = ((logits.argmax(-1) == targets) & valid).sum() / valid.sum().clamp(min=1)
    return loss, {"ce": float(loss.detach()), "acc": float(accuracy)}


def validate_gpt(model: MotionGPT, batches: list[dict[str, torch.Tensor]]) -> dict[str, float]:
    """Teacher-forced CE and accuracy on clean inputs, true condition and true length."""
    import torch

    model.eval()
    totals, weight = {"ce": 0.0, "acc": 0.0}, 0
    for batch in batches:
        tokens = batch["tokens"]
        length = batch["length"] if model.config.length_conditioning else None
        with torch.no_grad():
            _, metrics = next_token_loss(model, batch["cond"], tokens[:, :-1], tokens, length)
        for key in totals:
            totals[key] += metrics[key] * len(tokens)
        weight += len(tokens)
    return {k: v / max(weight, 1) for k, v in totals.items()}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from t2m.model.training.run_options import add_bookkeeping_arguments, add_schedule_arguments, add_text_arguments

    add_schedule_arguments(parser, steps=20_000, batch_size=64, weight_decay=0.01)
    parser.add_argument("--vq", required=True, help="run directory of the trained VQ-VAE")
    add_text_arguments(parser)
    parser.add_argument("--embed", type=int, default=384)
    parser.add_argument("--layers", type=int, default=6, help="transformer blocks (split between trans_base/head)")
    parser.add_argument("--heads", type=int, default=6)
    parser.add_argument("--dropout", type=float, default=0.1)
    parser.add_argument("--max-tokens", type=int, default=50, help="codes per sequence (block size - 1)")
    parser.add_argument("--length-conditioning", action=argparse.BooleanOptionalAction, default=True)
    parser.add_argument("--length-keep", type=float, default=0.8, help="probability of giving the true length")
    parser.add_argument("--corruption", default="0.5", help="code corruption rate tau in [0, 1], or 'uniform'")
    parser.add_argument("--cond-noise", type=float, default=0.0,
                        help="largest relative noise added to the text feature (0 = off; see the module docstring)")
    parser.add_argument("--cond-drop", type=float, default=0.1, help="condition dropout probability")
    parser.add_argument("--balance-power", type=float, default=1.0, help=BALANCE_POWER_HELP)
    add_bookkeeping_arguments(parser, every=1000)


def parse_corruption(text: str) -> str | float:
    if text == "uniform":
        return text
    try:
        value = float(text)
    except ValueError:
        raise ValueError(f"--corruption must be a number in [0, 1] or 'uniform', got {text!r}") from None
    if not 0.0 <= value <= 1.0:
        raise ValueError(f"--corruption must be in [0, 1], got {value}")
    return value


def load_or_encode_codes(vq: MotionVQVAE, reader: Any, path: Path, reuse: bool) -> dict[str, np.ndarray]:
    from t2m.model.data.datasets import load_codes, precompute_codes, save_codes

    if reuse and path.is_file():
        return load_codes(path)
    codes = precompute_codes(vq, reader)
    save_codes(path, codes)
    return codes


def main(args: argparse.Namespace) -> int:
    import torch
    from torch.utils.data import DataLoader

    from t2m.families.gpt.network import GPTConfig, MotionGPT
    from t2m.model.data.balancing import run_sampling_weights
    from t2m.model.data.datasets import LengthBucketSampler, TextMotionDataset, open_split, trim_padding
    from t2m.model.networks.text_encoders import cache_text_features, get_text_encoder
    from t2m.model.training.checkpoint import load_model
    from t2m.model.training.loop import LoopSettings, infinite, run_training, set_seed, set_threads
    from t2m.model.training.run_options import parse_milestones

    corruption = parse_corruption(args.corruption)
    for name in ("steps", "batch_size", "layers", "heads", "max_tokens"):
        if getattr(args, name) < 1:
            raise ValueError(f"--{name.replace('_', '-')} must be >= 1")
    for name in ("cond_drop", "length_keep", "balance_power"):
        if not 0.0 <= getattr(args, name) <= 1.0:
            raise ValueError(f"--{name.replace('_', '-')} must be in [0, 1]")
    if args.cond_noise < 0:
        raise ValueError(f"--cond-noise must be >= 0, got {args.cond_noise}")
    out = Path(args.out)
    if out.exists() and (out / "config.json").exists() and not args.resume:
        raise ValueError(f"{out} already holds a run; pass --resume to continue it or choose another --out")
    set_threads(args.threads)
    set_seed(args.seed)

    vq = load_model(args.vq, expect_kind="vq")
    train_reader = open_split(args.data, "train")
    val_reader = open_split(args.data, "val")
    vq_mean = Path(args.vq) / "mean.npy"
    if vq_mean.is_file() and not np.allclose(np.load(vq_mean), train_reader.mean, atol=1e-5):
        raise ValueError(f"{args.data}: Mean.npy differs from the VQ run's {vq_mean}; codes would be wrong")

    out.mkdir(parents=True, exist_ok=True)
    encoder_kwargs = {"weights": args.clip_weights} if args.text_encoder == "clip" else {}
    encoder = get_text_encoder(args.text_encoder, **encoder_kwargs)
    text_cache = Path(args.text_cache) if args.text_cache else out / "text_features.npz"
    text_features = cache_text_features([train_reader, val_reader], encoder, text_cache)

    train_codes = load_or_encode_codes(vq, train_reader, out / "codes_train.npz", reuse=args.resume)
    val_codes = load_or_encode_codes(vq, val_reader, out / "codes_val.npz", reuse=args.resume)
    nb_code = vq.config.nb_code
    train_set = TextMotionDataset(train_reader, train_codes, text_features, nb_code, args.max_tokens)
    val_set = TextMotionDataset(val_reader, val_codes, text_features, nb_code, args.max_tokens)
    del vq, encoder  # free memory: both are done

    config = GPTConfig(
        codebook_size=nb_code, embed=args.embed, n_head=args.heads,
        n_layer_base=args.layers - args.layers // 2, n_layer_head=args.layers // 2,
        block_size=args.max_tokens + 1, dropout=args.dropout, text_dim=text_features_dim(text_features),
        length_conditioning=args.length_conditioning,
    )
    model = MotionGPT(config)
    generator = torch.Generator().manual_seed(args.seed + 1)  # validation batches: the same captions every time
    val_loader = DataLoader(val_set, batch_size=args.batch_size, shuffle=False, generator=generator)
    torch.manual_seed(args.seed + 1)
    val_batches = list(val_loader)[:8]
    torch.manual_seed(args.seed)
    weights = run_sampling_weights(train_set.ids, args.balance_power, out, train_set.captions_of)
    loader = DataLoader(train_set, batch_sampler=LengthBucketSampler(train_set.token_counts, args.batch_size,
                                                                     weights=weights))
    settings = LoopSettings(
        steps=args.steps, lr=args.lr, weight_decay=args.weight_decay, warmup_steps=args.warmup_steps,
        lr_milestones=parse_milestones(args.lr_milestones), lr_gamma=args.lr_gamma, grad_clip=1.0,
        log_every=args.log_every, val_every=args.val_every, save_every=args.save_every, seed=args.seed,
    )

    def step_fn(net: MotionGPT, batch: dict[str, torch.Tensor]) -> tuple[torch.Tensor, dict[str, float], int]:
        tokens = trim_padding(batch["tokens"], config.pad_id)
        inputs = corrupt_codes(tokens[:, :-1], sample_tau(len(tokens), corruption), nb_code)
        cond = drop_condition(perturb_condition(batch["cond"], args.cond_noise), args.cond_drop)
        length = drop_length(batch["length"], args.length_keep) if config.length_conditioning else None
        loss, metrics = next_token_loss(net, cond, inputs, tokens, length)
        return loss, metrics, len(tokens)

    data_info: dict[str, Any] = {
        "data_dir": str(Path(args.data).resolve()), "vq_run": str(Path(args.vq).resolve()),
        "train_clips": len(train_set), "val_clips": len(val_set), "batch_size": args.batch_size, "seed": args.seed,
        "frames_per_token": 2 ** load_model_config_down_t(args.vq), "max_tokens": args.max_tokens,
        "text_encoder": {
            "kind": args.text_encoder, "dim": config.text_dim, "max_length": encoder_max_length(args.text_encoder),
            "pooling": "mean" if args.text_encoder == "minilm" else "eot",
            "normalize": args.text_encoder == "minilm", "null_condition": "zeros",
            **({"clip_weights": str(Path(args.clip_weights).resolve())} if args.clip_weights else {}),
        },
        "training": {"corruption": corruption, "cond_noise": args.cond_noise, "cond_drop": args.cond_drop,
                     "length_keep": args.length_keep, "balance_power": args.balance_power},
    }
    run_training(
        model, infinite(loader), step_fn, settings, out,
        val_fn=lambda net: validate_gpt(net, val_batches),
        data_info=data_info, resume=args.resume, name="gpt",
    )
    return 0


def load_model_config_down_t(vq_run: str | Path) -> int:
    from t2m.model.training.checkpoint import read_run_config

    return int(read_run_config(vq_run)["config"].get("down_t", 2))
