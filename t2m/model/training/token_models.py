"""What `t2m train masked` and `t2m train residual` share: arguments, the VQ's codes, text features, batches.

Both train on the code maps of a trained VQ: a joint VQ run (kind ``joint_vq``: MoGenTS's 2D tokens, C columns)
or a 1D VQ run with the residual quantiser (kind ``vq``: MoMask's tokens, one column). The transformer's shape
follows: 2D positions and the spatial/temporal stacks for C > 1, MoMask's 1D layout for C = 1.

Codes are computed once per VQ and split (``codes_<split>.npz`` + a ``.json`` stamp naming the VQ run and step, so
a later run given the same ``--codes-cache`` directory reuses them only for that VQ); caption features are cached
as for the GPT (``--text-cache``).
"""
from __future__ import annotations

import argparse
import json
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from t2m.model.data.balancing import BALANCE_POWER_HELP

if TYPE_CHECKING:
    import torch

    from t2m.model.data.token_maps import TokenMapDataset
    from t2m.model.networks.token_transformer import TokenTransformerConfig
    from t2m.model.training.loop import LoopSettings

VQ_KINDS = ("joint_vq", "vq")


def add_arguments(parser: argparse.ArgumentParser, cond_drop: float) -> None:
    """The options of both transformer trainers (sizes default to a 2-core CPU budget)."""
    parser.add_argument("--data", required=True, help="dataset directory (HumanML3D layout)")
    parser.add_argument("--vq", required=True, help="run directory of a trained joint VQ (2D) or residual 1D VQ")
    parser.add_argument("--out", required=True, help="run directory for checkpoints and logs")
    parser.add_argument("--steps", type=int, default=4000)
    parser.add_argument("--batch-size", type=int, default=32)
    parser.add_argument("--lr", type=float, default=2e-4)
    parser.add_argument("--weight-decay", type=float, default=1e-5)
    parser.add_argument("--warmup-steps", type=int, default=500)
    parser.add_argument("--lr-milestones", default="0.7", help="comma-separated fractions of --steps where LR x gamma")
    parser.add_argument("--lr-gamma", type=float, default=0.1)
    parser.add_argument("--text-encoder", choices=("minilm", "clip"), default="minilm")
    parser.add_argument("--clip-weights", default=None,
                        help="local open_clip ViT-B-32 weights (for --text-encoder clip)")
    parser.add_argument("--text-cache", default=None, help="caption feature cache (default <out>/text_features.npz)")
    parser.add_argument("--codes-cache", default=None,
                        help="directory of the VQ's per-clip codes, reused when made by the same VQ (default <out>)")
    parser.add_argument("--latent", type=int, default=256, help="transformer width")
    parser.add_argument("--heads", type=int, default=4)
    parser.add_argument("--layers", type=int, default=2, help="layers per stack (joint-time, spatial, temporal)")
    parser.add_argument("--ff-size", type=int, default=512)
    parser.add_argument("--dropout", type=float, default=0.1)
    parser.add_argument("--token-dim", type=int, default=None,
                        help="token embedding width (default: the VQ's code_dim)")
    parser.add_argument("--max-tokens", type=int, default=50, help="token rows per motion (4 frames each)")
    parser.add_argument("--spatial-attention", action=argparse.BooleanOptionalAction, default=True,
                        help="the spatial stack (2D maps only)")
    parser.add_argument("--temporal-attention", action=argparse.BooleanOptionalAction, default=True,
                        help="the temporal stack (2D maps only)")
    parser.add_argument("--cond-drop", type=float, default=cond_drop,
                        help="condition dropout probability (trains the null condition for guidance)")
    parser.add_argument("--cond-noise", type=float, default=0.0,
                        help="largest relative noise added to the text feature (0 = off; see train_gpt)")
    parser.add_argument("--balance-power", type=float, default=1.0, help=BALANCE_POWER_HELP)
    parser.add_argument("--log-every", type=int, default=50)
    parser.add_argument("--val-every", type=int, default=500)
    parser.add_argument("--save-every", type=int, default=500)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--resume", action="store_true", help="continue from <out>/resume.pt")


@dataclass
class TokenData:
    """Everything a token-model trainer needs besides its model and step."""

    train_set: TokenMapDataset
    loader: Any
    val_batches: list[dict[str, torch.Tensor]]
    vq_config: dict[str, Any]
    vq_kind: str
    text_dim: int
    data_info: dict[str, Any]

    @property
    def columns(self) -> int:
        return self.train_set.columns


def _codes(vq: Any, vq_run: Path, vq_step: int, reader: Any, cache: Path, split: str) -> dict[str, np.ndarray]:
    """The VQ's codes of every clip of a split, from the cache when it holds this VQ's, else encoded and cached."""
    from t2m.model.data.datasets import load_codes, precompute_codes, save_codes

    path, stamp_path = cache / f"codes_{split}.npz", cache / f"codes_{split}.json"
    stamp = {"vq_run": str(vq_run.resolve()), "vq_step": vq_step}
    if path.is_file() and stamp_path.is_file() and json.loads(stamp_path.read_text()) == stamp:
        return load_codes(path)
    codes = precompute_codes(vq, reader)
    cache.mkdir(parents=True, exist_ok=True)
    save_codes(path, codes)
    stamp_path.write_text(json.dumps(stamp) + "\n")
    return codes


def prepare_data(args: argparse.Namespace, out: Path, min_layers: int = 1) -> TokenData:
    """Load the VQ (any of VQ_KINDS), encode/cached codes, caption features, datasets and loaders."""
    import torch
    from torch.utils.data import DataLoader

    from t2m.model.data.balancing import run_sampling_weights
    from t2m.model.data.datasets import LengthBucketSampler, open_split
    from t2m.model.data.token_maps import TokenMapDataset
    from t2m.model.networks.text_encoders import cache_text_features, get_text_encoder
    from t2m.model.training.checkpoint import load_model, read_run_config
    from t2m.model.training.train_gpt import encoder_max_length, text_features_dim

    vq_run = Path(args.vq)
    record = read_run_config(vq_run)
    if record["kind"] not in VQ_KINDS:
        raise ValueError(f"{vq_run}: --vq must be a joint_vq or vq run, found {record['kind']!r}")
    vq_config = record["config"]
    layers = int(vq_config.get("residual_layers", 1))
    if layers < min_layers:
        raise ValueError(f"{vq_run}: the VQ has {layers} quantiser layer(s); this model needs at least {min_layers}")
    train_reader, val_reader = open_split(args.data, "train"), open_split(args.data, "val")
    vq_mean = vq_run / "mean.npy"
    if vq_mean.is_file() and not np.allclose(np.load(vq_mean), train_reader.mean, atol=1e-5):
        raise ValueError(f"{args.data}: Mean.npy differs from the VQ run's {vq_mean}; codes would be wrong")

    out.mkdir(parents=True, exist_ok=True)
    encoder_kwargs = {"weights": args.clip_weights} if args.text_encoder == "clip" else {}
    encoder = get_text_encoder(args.text_encoder, **encoder_kwargs)
    text_cache = Path(args.text_cache) if args.text_cache else out / "text_features.npz"
    text_features = cache_text_features([train_reader, val_reader], encoder, text_cache)
    del encoder

    vq = load_model(vq_run, expect_kind=record["kind"])
    cache = Path(args.codes_cache) if args.codes_cache else out
    step = int(record.get("step", 0))
    train_codes = _codes(vq, vq_run, step, train_reader, cache, "train")
    val_codes = _codes(vq, vq_run, step, val_reader, cache, "val")
    del vq
    train_set = TokenMapDataset(train_reader, train_codes, text_features, args.max_tokens)
    val_set = TokenMapDataset(val_reader, val_codes, text_features, args.max_tokens)

    generator = torch.Generator().manual_seed(args.seed + 1)  # validation: the same captions and windows every time
    torch.manual_seed(args.seed + 1)
    val_batches = list(DataLoader(val_set, batch_size=args.batch_size, shuffle=False, generator=generator))[:8]
    torch.manual_seed(args.seed)
    weights = run_sampling_weights(train_set.ids, args.balance_power, out)
    loader = DataLoader(train_set, batch_sampler=LengthBucketSampler(train_set.token_counts, args.batch_size,
                                                                     weights=weights))
    text_dim = text_features_dim(text_features)
    data_info: dict[str, Any] = {
        "data_dir": str(Path(args.data).resolve()), "vq_run": str(vq_run.resolve()), "vq_kind": record["kind"],
        "train_clips": len(train_set), "val_clips": len(val_set), "batch_size": args.batch_size, "seed": args.seed,
        "frames_per_token": 2 ** int(vq_config.get("down_t", 2)), "max_tokens": args.max_tokens,
        "columns": train_set.columns, "residual_layers": train_set.layers,
        "text_encoder": {
            "kind": args.text_encoder, "dim": text_dim, "max_length": encoder_max_length(args.text_encoder),
            "pooling": "mean" if args.text_encoder == "minilm" else "eot",
            "normalize": args.text_encoder == "minilm", "null_condition": "zeros",
            **({"clip_weights": str(Path(args.clip_weights).resolve())} if args.clip_weights else {}),
        },
        "training": {"cond_drop": args.cond_drop, "cond_noise": args.cond_noise, "balance_power": args.balance_power},
    }
    return TokenData(train_set, loader, val_batches, vq_config, record["kind"], text_dim, data_info)


def check_arguments(args: argparse.Namespace) -> Path:
    """The argument checks both trainers need; returns --out."""
    from t2m.model.training.train_joint_vq import check_common_arguments

    out = check_common_arguments(args, ("steps", "batch_size", "latent", "heads", "layers", "ff_size", "max_tokens"),
                                 ("cond_drop", "balance_power", "dropout"))
    if args.cond_noise < 0:
        raise ValueError(f"--cond-noise must be >= 0, got {args.cond_noise}")
    if args.token_dim is not None and args.token_dim < 1:
        raise ValueError(f"--token-dim must be >= 1, got {args.token_dim}")
    return out


def model_config(args: argparse.Namespace, data: TokenData) -> TokenTransformerConfig:
    """The transformer's config for this VQ: 2D layout and stacks for a joint map, MoMask's 1D one otherwise."""
    from t2m.model.networks.token_transformer import TokenTransformerConfig

    two_d = data.columns > 1
    return TokenTransformerConfig(
        codebook_size=int(data.vq_config["nb_code"]), columns=data.columns, residual_layers=data.train_set.layers,
        max_tokens=args.max_tokens, latent=args.latent, n_head=args.heads, n_layer=args.layers,
        ff_size=args.ff_size, dropout=args.dropout, text_dim=data.text_dim,
        code_dim=args.token_dim or int(data.vq_config["code_dim"]), positional="2d" if two_d else "1d",
        spatial_attention=two_d and args.spatial_attention, temporal_attention=two_d and args.temporal_attention,
    )


def loop_settings(args: argparse.Namespace) -> LoopSettings:
    from t2m.model.training.loop import LoopSettings
    from t2m.model.training.train_vq import parse_milestones

    return LoopSettings(
        steps=args.steps, lr=args.lr, weight_decay=args.weight_decay, warmup_steps=args.warmup_steps,
        lr_milestones=parse_milestones(args.lr_milestones), lr_gamma=args.lr_gamma, grad_clip=1.0,
        log_every=args.log_every, val_every=args.val_every, save_every=args.save_every, seed=args.seed,
    )


def noisy_condition(cond: torch.Tensor, args: argparse.Namespace, generator: torch.Generator | None = None):
    """The training condition: noise (--cond-noise), then dropout to the null condition (--cond-drop)."""
    from t2m.model.training.train_gpt import drop_condition, perturb_condition

    return drop_condition(perturb_condition(cond, args.cond_noise, generator), args.cond_drop, generator)


def validate(model: Any, batches: list[dict[str, torch.Tensor]], loss_fn: Any, seed: int = 0) -> dict[str, float]:
    """Mean of loss_fn's metrics over fixed batches, its random draws (masks, layers) from a fixed generator."""
    import torch

    model.eval()
    generator = torch.Generator().manual_seed(seed)
    totals: dict[str, float] = {}
    weight = 0
    with torch.no_grad():
        for batch in batches:
            _, metrics = loss_fn(model, batch, batch["cond"], generator)
            for key, value in metrics.items():
                totals[key] = totals.get(key, 0.0) + value * len(batch["length"])
            weight += len(batch["length"])
    return {k: v / max(weight, 1) for k, v in totals.items()}
