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
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from t2m.model.training import run_options

if TYPE_CHECKING:
    import torch

    from t2m.model.data.token_maps import TokenMapDataset
    from t2m.model.networks.token_transformer import TokenTransformerConfig

VQ_KINDS = ("joint_vq", "vq")
# loss_fn(model, batch, cond, generator) -> (loss, metrics)
LossFn = Callable[[Any, dict, Any, Any], tuple[Any, dict[str, float]]]


def add_arguments(parser: argparse.ArgumentParser, cond_drop: float) -> None:
    """The options of both transformer trainers (sizes default to a 2-core CPU budget)."""
    run_options.add_schedule_arguments(parser, steps=4000, batch_size=32, weight_decay=1e-5)
    parser.add_argument("--vq", required=True, help="run directory of a trained joint VQ (2D) or residual 1D VQ")
    run_options.add_text_arguments(parser)
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
    run_options.add_codes_and_condition_arguments(parser, cond_drop)
    run_options.add_bookkeeping_arguments(parser)


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
    from t2m.model.training.checkpoint import load_model, read_run_config
    from t2m.model.training.conditioning import encoder_max_length, text_features_dim

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
    text_features = run_options.text_features(args, [train_reader, val_reader], out)

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
    weights = run_sampling_weights(train_set.ids, args.balance_power, out, train_set.captions_of)
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
    out = run_options.check_arguments(args, ("latent", "heads", "layers", "ff_size", "max_tokens"),
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


def noisy_condition(cond: torch.Tensor, args: argparse.Namespace, generator: torch.Generator | None = None):
    """The training condition: noise (--cond-noise), then dropout to the null condition (--cond-drop)."""
    from t2m.model.training.conditioning import drop_condition, perturb_condition

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


def train(
    args: argparse.Namespace, build: Callable[[TokenTransformerConfig], Any], loss_fn: LossFn,
    val_fn: Callable[[Any, list], dict[str, float]], name: str, min_layers: int = 1,
) -> int:
    """The whole of `t2m train masked|residual`: checks, data, the model from ``build(config)``, the shared loop."""
    from t2m.model.training.loop import infinite, run_training, set_seed, set_threads

    out = check_arguments(args)
    set_threads(args.threads)
    set_seed(args.seed)
    data = prepare_data(args, out, min_layers=min_layers)
    model = build(model_config(args, data))

    def step_fn(net: Any, batch: dict) -> tuple[torch.Tensor, dict[str, float], int]:
        loss, metrics = loss_fn(net, batch, noisy_condition(batch["cond"], args), None)
        return loss, metrics, len(batch["length"])

    run_training(
        model, infinite(data.loader), step_fn, run_options.loop_settings(args, grad_clip=1.0), out,
        val_fn=lambda net: val_fn(net, data.val_batches), data_info=data.data_info, resume=args.resume, name=name,
    )
    return 0
