"""Train the residual transformer: RVQ layer q from layers 0..q-1 of a VQ's codes (MoMask's design).

Per batch: a layer q in 1..R-1 per motion (t2m.families.masked.masking.residual_layer_schedule, low layers more
often), the
true codes of layers below q as input, condition dropout (--cond-drop, MoMask 0.2) for guidance.
loss = cross entropy over layer q's codes at every real token (no masking: the whole layer is predicted at once).
Validation: the same on fixed batches and layers.
"""
from __future__ import annotations

import argparse
from typing import TYPE_CHECKING

from t2m.model.training import token_models

if TYPE_CHECKING:
    import torch

    from t2m.families.masked.residual_transformer import ResidualTransformer
    from t2m.model.networks.token_transformer import TokenTransformerConfig


def residual_loss(
    model: ResidualTransformer, batch: dict[str, torch.Tensor], cond: torch.Tensor,
    generator: torch.Generator | None = None,
) -> tuple[torch.Tensor, dict[str, float]]:
    """Cross entropy of each motion's layer q over its real tokens; returns (loss, {ce, acc, layer})."""
    import torch
    import torch.nn.functional as F

    from t2m.families.masked.masking import residual_layer_schedule
    from t2m.model.data.token_maps import trim_rows

    length = batch["length"]
    codes = trim_rows(batch["codes"], length)  # [B, T, C, R]
    batch_size, rows, columns, layers = codes.shape
    layer = residual_layer_schedule(batch_size, layers, generator)
    logits = model(codes, layer, cond, length)  # [B, T, C, K + 1]
    targets = codes.gather(-1, layer[:, None, None, None].expand(batch_size, rows, columns, 1))[..., 0]
    targets = torch.where(targets < 0, torch.full_like(targets, model.pad_id), targets)
    real = model.valid_rows(length, rows)[:, :, None].expand(batch_size, rows, columns)
    loss = F.cross_entropy(logits[real], targets[real])
    accuracy = (logits[real].argmax(-1) == targets[real]).float().mean()
    return loss, {"ce": float(loss.detach()), "acc": float(accuracy), "layer": float(layer.float().mean())}


def validate_residual(model: ResidualTransformer, batches: list[dict[str, torch.Tensor]]) -> dict[str, float]:
    metrics = token_models.validate(model, batches, residual_loss)
    metrics.pop("layer", None)
    return metrics


def add_arguments(parser: argparse.ArgumentParser) -> None:
    token_models.add_arguments(parser, cond_drop=0.2)
    parser.add_argument("--share-weight", action=argparse.BooleanOptionalAction, default=True,
                        help="one matrix for layer k's embedding and classifier (MoMask's released setting)")


def main(args: argparse.Namespace) -> int:
    from dataclasses import replace

    from t2m.families.masked.residual_transformer import ResidualTransformer

    def build(config: TokenTransformerConfig) -> ResidualTransformer:
        return ResidualTransformer(replace(config, share_weight=args.share_weight))

    return token_models.train(args, build, residual_loss, validate_residual, name="residual", min_layers=2)
