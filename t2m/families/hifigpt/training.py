"""Train T2M-HiFiGPT's double-tier GPT on the code maps [T, R] of a trained residual VQ (`t2m train vq --quantizer
residual`, the paper: --down-t 3 --shared-codebook).

Per batch (the paper's section 3.4):
- per-time-step corruption: each time step of the temporal GPT's *input* is replaced, with probability tau
  (--corruption 0.5, or 'uniform' for tau ~ U[0, 1] per motion), by a whole row of R random codes: the residual
  sum of a partly replaced row is noise, so rows are kept or replaced whole. The residual GPT reads its own row's
  true lower depths (teacher forcing inside the step) and every target is the true code.
- condition dropout: the text feature becomes zeros with probability --cond-drop (0.1), which trains the
  unconditional logits guidance needs (for codes and for the stop); --cond-noise as for the GPT.
- length conditioning (as the GPT family): the true step count with probability --length-keep, else 0 (free).
- loss = cross entropy over the K codes at every (step, depth) of every real step + --stop-weight x binary cross
  entropy of the stop logits at positions 0..length (1 after the last step of a window that reaches its clip's end;
  a crop of a longer clip has no stop).
Validation (fixed batches): the same losses without corruption, with the true condition and length.
Codes and caption features are cached as for the masked family (t2m.model.training.token_models).
"""
from __future__ import annotations

import argparse
from typing import TYPE_CHECKING, Any

from t2m.model.training import run_options

if TYPE_CHECKING:
    import torch

    from t2m.families.hifigpt.network import HiFiGPT


def corrupt_steps(codes: torch.Tensor, tau: torch.Tensor | float, codebook_size: int,
                  generator: torch.Generator | None = None) -> tuple[torch.Tensor, torch.Tensor]:
    """Replace whole time steps of code maps [B, T, R] with probability tau (scalar or per motion [B]) by rows of
    random codes; rows past a motion's end (-1) stay. Returns (corrupted maps, replaced [B, T] bool)."""
    import torch

    tau = torch.as_tensor(tau, dtype=torch.float32)
    tau = tau[:, None] if tau.dim() == 1 else tau
    replaced = (torch.rand(codes.shape[:2], generator=generator) < tau) & (codes[..., 0] >= 0)
    random_rows = torch.randint(0, codebook_size, codes.shape, generator=generator)
    return torch.where(replaced[..., None], random_rows, codes), replaced


def hifigpt_loss(model: HiFiGPT, batch: dict[str, torch.Tensor], cond: torch.Tensor,
                 generator: torch.Generator | None = None, *, tau: torch.Tensor | float | None = None,
                 length_keep: float = 1.0, stop_weight: float = 1.0) -> tuple[torch.Tensor, dict[str, float]]:
    """The training loss of a batch {"codes" [B, T, 1, R], "length", "ends"}; returns (loss, {ce, acc, acc_d0,
    stop_bce, stop_acc})."""
    import torch
    import torch.nn.functional as F

    from t2m.families.gpt.training import drop_length
    from t2m.model.data.token_maps import trim_rows

    length = batch["length"]
    codes = trim_rows(batch["codes"], length)[:, :, 0]   # [B, T, R]
    steps = codes.shape[1]
    history = corrupt_steps(codes, tau, model.config.codebook_size, generator)[0] if tau is not None else codes
    length_in = drop_length(length, length_keep, generator) if model.config.length_conditioning else None
    logits, stop = model(cond, codes, length_in, history)
    real = torch.arange(steps)[None, :] < length[:, None]
    ce = F.cross_entropy(logits[real].reshape(-1, logits.shape[-1]), codes[real].reshape(-1))
    right = logits[real].argmax(-1) == codes[real]
    positions = torch.arange(steps + 1)[None, :]
    valid = positions <= length[:, None]
    target = ((positions == length[:, None]) & batch["ends"][:, None]).float()
    bce = F.binary_cross_entropy_with_logits(stop[valid], target[valid])
    loss = ce + stop_weight * bce
    return loss, {"ce": float(ce.detach()), "acc": float(right.float().mean()),
                  "acc_d0": float(right[:, 0].float().mean()), "stop_bce": float(bce.detach()),
                  "stop_acc": float(((stop[valid] > 0) == (target[valid] > 0.5)).float().mean())}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    run_options.add_schedule_arguments(parser, steps=6000, batch_size=64, weight_decay=0.01)
    parser.add_argument("--vq", required=True, help="run directory of a trained VQ (--quantizer residual)")
    run_options.add_text_arguments(parser)
    parser.add_argument("--embed", type=int, default=384, help="transformer width E")
    parser.add_argument("--heads", type=int, default=6)
    parser.add_argument("--temporal-layers", type=int, default=3, help="blocks of the temporal GPT (paper: 9)")
    parser.add_argument("--residual-gpt-layers", type=int, default=3, help="blocks of the residual GPT (paper: 9)")
    parser.add_argument("--dropout", type=float, default=0.1)
    parser.add_argument("--max-tokens", type=int, default=25, help="time steps per motion (8 frames each at x8)")
    parser.add_argument("--length-conditioning", action=argparse.BooleanOptionalAction, default=True)
    parser.add_argument("--length-keep", type=float, default=0.8, help="probability of giving the true length")
    parser.add_argument("--corruption", default="0.5",
                        help="per-time-step corruption rate tau in [0, 1] (paper 0.5), or 'uniform'")
    parser.add_argument("--stop-weight", type=float, default=1.0, help="beta of the stop loss (eq. 9)")
    run_options.add_codes_and_condition_arguments(parser, cond_drop=0.1)   # the paper's 0.1
    run_options.add_bookkeeping_arguments(parser)


def _check_vq(vq_run: str) -> dict[str, Any]:
    """The VQ must be a 1D VQ (kind vq): its config dict."""
    from t2m.model.training.checkpoint import read_run_config

    record = read_run_config(vq_run)
    if record["kind"] != "vq":
        raise ValueError(f"{vq_run}: --vq must be a vq run (t2m train vq --quantizer residual), found "
                         f"{record['kind']!r}")
    return dict(record["config"])


def main(args: argparse.Namespace) -> int:

    from t2m.families.gpt.training import parse_corruption, sample_tau
    from t2m.families.hifigpt.network import HiFiGPT, HiFiGPTConfig, vq_codebooks, vq_fields
    from t2m.model.training import token_models
    from t2m.model.training.checkpoint import load_model
    from t2m.model.training.loop import infinite, run_training, set_seed, set_threads

    out = run_options.check_arguments(args, ("embed", "heads", "temporal_layers", "residual_gpt_layers",
                                             "max_tokens"), ("cond_drop", "balance_power", "dropout", "length_keep"))
    corruption = parse_corruption(args.corruption)
    if args.cond_noise < 0 or args.stop_weight < 0:
        raise ValueError("--cond-noise and --stop-weight must be >= 0")
    fields = vq_fields(_check_vq(args.vq))
    set_threads(args.threads)
    set_seed(args.seed)
    data = token_models.prepare_data(args, out)
    config = HiFiGPTConfig(**fields, embed=args.embed, n_head=args.heads, n_layer_temporal=args.temporal_layers,
                           n_layer_residual=args.residual_gpt_layers, max_tokens=args.max_tokens,
                           text_dim=data.text_dim, dropout=args.dropout,
                           length_conditioning=args.length_conditioning)
    model = HiFiGPT(config)
    model.set_codebooks(vq_codebooks(load_model(args.vq, expect_kind="vq")))

    def step_fn(net: HiFiGPT, batch: dict) -> tuple[torch.Tensor, dict[str, float], int]:
        cond = token_models.noisy_condition(batch["cond"], args)
        loss, metrics = hifigpt_loss(net, batch, cond, tau=sample_tau(len(batch["length"]), corruption),
                                     length_keep=args.length_keep, stop_weight=args.stop_weight)
        return loss, metrics, len(batch["length"])

    def val_fn(net: HiFiGPT) -> dict[str, float]:
        return token_models.validate(net, data.val_batches,
                                     lambda m, b, c, g: hifigpt_loss(m, b, c, g, stop_weight=args.stop_weight))

    data.data_info["training"].update({"corruption": corruption, "corruption_granularity": "time step",
                                       "length_keep": args.length_keep, "stop_weight": args.stop_weight})
    run_training(model, infinite(data.loader), step_fn, run_options.loop_settings(args, grad_clip=1.0), out,
                 val_fn=val_fn, data_info=data.data_info, resume=args.resume, name="hifigpt")
    return 0
