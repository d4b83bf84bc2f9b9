"""Command-line options the trainers on the shared loop share (data, run dir, schedule, text, bookkeeping), their
checks, and the LoopSettings they make. Each trainer adds its own model and loss options between the groups. (The
evaluator's trainer has its own short schedule: no warm-up or milestones.)"""
from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING

from t2m.model.data.balancing import BALANCE_POWER_HELP

if TYPE_CHECKING:
    from t2m.model.training.loop import LoopSettings


def add_schedule_arguments(
    parser: argparse.ArgumentParser, steps: int, batch_size: int, lr: float = 2e-4, weight_decay: float = 0.0,
    warmup_steps: int = 500,
) -> None:
    """--data --out --steps --batch-size --lr --weight-decay --warmup-steps --lr-milestones --lr-gamma"""
    parser.add_argument("--data", required=True, help="dataset directory (HumanML3D layout)")
    parser.add_argument("--out", required=True, help="run directory for checkpoints and logs")
    parser.add_argument("--steps", type=int, default=steps)
    parser.add_argument("--batch-size", type=int, default=batch_size)
    parser.add_argument("--lr", type=float, default=lr)
    parser.add_argument("--weight-decay", type=float, default=weight_decay)
    parser.add_argument("--warmup-steps", type=int, default=warmup_steps)
    parser.add_argument("--lr-milestones", default="0.7", help="comma-separated fractions of --steps where LR x gamma")
    parser.add_argument("--lr-gamma", type=float, default=0.1)


def add_text_arguments(parser: argparse.ArgumentParser) -> None:
    """--text-encoder --clip-weights --text-cache (as the GPT trainer has them)."""
    parser.add_argument("--text-encoder", choices=("minilm", "clip"), default="minilm")
    parser.add_argument("--clip-weights", default=None,
                        help="OpenAI's CLIP ViT-B-32.pt (for --text-encoder clip)")
    parser.add_argument("--text-cache", default=None, help="caption feature cache (default <out>/text_features.npz)")


def add_codes_and_condition_arguments(parser: argparse.ArgumentParser, cond_drop: float) -> None:
    """--codes-cache (a VQ's per-clip codes), --cond-drop, --cond-noise, --balance-power: the token models' data
    options (the masked family's and T2M-HiFiGPT's)."""
    parser.add_argument("--codes-cache", default=None,
                        help="directory of the VQ's per-clip codes, reused when made by the same VQ (default <out>)")
    parser.add_argument("--cond-drop", type=float, default=cond_drop,
                        help="condition dropout probability (trains the null condition for guidance)")
    parser.add_argument("--cond-noise", type=float, default=0.0,
                        help="largest relative noise added to the text feature (0 = off; see train_gpt)")
    parser.add_argument("--balance-power", type=float, default=1.0, help=BALANCE_POWER_HELP)


def add_bookkeeping_arguments(parser: argparse.ArgumentParser, every: int = 500) -> None:
    """--log-every --val-every --save-every --seed --threads --resume"""
    parser.add_argument("--log-every", type=int, default=50)
    parser.add_argument("--val-every", type=int, default=every)
    parser.add_argument("--save-every", type=int, default=every)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--resume", action="store_true", help="continue from <out>/resume.pt")


def check_arguments(args: argparse.Namespace, positive: tuple[str, ...], fractions: tuple[str, ...] = ()) -> Path:
    """Refuse bad numbers and a second run into a used --out (naming the option); returns --out as a Path."""
    for name in ("steps", "batch_size", *positive):
        if getattr(args, name) < 1:
            raise ValueError(f"--{name.replace('_', '-')} must be >= 1, got {getattr(args, name)}")
    for name in fractions:
        if not 0.0 <= getattr(args, name) <= 1.0:
            raise ValueError(f"--{name.replace('_', '-')} must be in [0, 1], got {getattr(args, name)}")
    out = Path(args.out)
    if (out / "config.json").exists() and not args.resume:
        raise ValueError(f"{out} already holds a run; pass --resume to continue it or choose another --out")
    return out


def parse_milestones(text: str) -> tuple[float, ...]:
    """--lr-milestones: comma-separated fractions of --steps in (0, 1]."""
    try:
        values = tuple(float(v) for v in text.split(",") if v.strip())
    except ValueError:
        raise ValueError(f"--lr-milestones must be comma-separated fractions, got {text!r}") from None
    if any(not 0.0 < v <= 1.0 for v in values):
        raise ValueError(f"--lr-milestones must be fractions in (0, 1], got {text!r}")
    return values


def loop_settings(args: argparse.Namespace, grad_clip: float | None) -> LoopSettings:
    from t2m.model.training.loop import LoopSettings

    return LoopSettings(
        steps=args.steps, lr=args.lr, weight_decay=args.weight_decay, warmup_steps=args.warmup_steps,
        lr_milestones=parse_milestones(args.lr_milestones), lr_gamma=args.lr_gamma, grad_clip=grad_clip,
        log_every=args.log_every, val_every=args.val_every, save_every=args.save_every, seed=args.seed,
    )


def text_features(args: argparse.Namespace, readers: list, out: Path) -> dict:
    """Caption -> feature for every caption of the readers, through the --text-cache (the GPT trainer's cache)."""
    from t2m.model.networks.text_encoders import cache_text_features, get_text_encoder

    encoder_kwargs = {"weights": args.clip_weights} if args.text_encoder == "clip" else {}
    encoder = get_text_encoder(args.text_encoder, **encoder_kwargs)
    cache = Path(args.text_cache) if args.text_cache else out / "text_features.npz"
    return cache_text_features(readers, encoder, cache)
