"""Train the masked transformer on a VQ's first-layer codes (MoMask's 1D tokens or MoGenTS's joint map).

Per batch (t2m.families.masked.masking): a mask ratio gamma = cos(pi tau / 2), tau ~ U(0, 1), per motion; whole frames
first, then random tokens in the other frames (MoGenTS's temporal-spatial masking; frames only for 1D maps); BERT's
80 / 10 / 10 replacement of the masked tokens; condition dropout (--cond-drop, MoMask 0.1) for guidance.
loss = cross entropy over the codes at the masked tokens.
Validation (fixed batches and masks): the same loss and accuracy, and the loss with every token masked (what the
first sampling step faces).
"""
from __future__ import annotations

import argparse
from typing import TYPE_CHECKING

from t2m.model.training import token_models

if TYPE_CHECKING:
    import torch

    from t2m.families.masked.masked_transformer import MaskedTransformer


def masked_loss(
    model: MaskedTransformer, batch: dict[str, torch.Tensor], cond: torch.Tensor,
    generator: torch.Generator | None = None, all_masked: bool = False,
) -> tuple[torch.Tensor, dict[str, float]]:
    """Cross entropy at the masked tokens of a batch {"codes" [B, T, C, R], "length"}; returns (loss, {ce, acc})."""
    import torch
    import torch.nn.functional as F

    from t2m.families.masked.masking import bert_replace, mask_ratio, temporal_spatial_mask
    from t2m.model.data.token_maps import trim_rows

    length = batch["length"]
    codes = trim_rows(batch["codes"], length)[..., 0]  # first layer [B, T, C]
    batch_size, rows, columns = codes.shape
    ratio = torch.ones(batch_size) if all_masked else mask_ratio(torch.rand(batch_size, generator=generator))
    mask = temporal_spatial_mask(length, rows, columns, ratio, spatial=columns > 1, generator=generator)
    c = model.config
    inputs = torch.where(mask, torch.full_like(codes, c.mask_id), codes) if all_masked else \
        bert_replace(codes, mask, c.codebook_size, c.mask_id, generator)
    logits = model(inputs, cond, length)[mask]
    targets = codes[mask]
    loss = F.cross_entropy(logits, targets)
    accuracy = (logits.argmax(-1) == targets).float().mean()
    return loss, {"ce": float(loss.detach()), "acc": float(accuracy)}


def validate_masked(model: MaskedTransformer, batches: list[dict[str, torch.Tensor]]) -> dict[str, float]:
    metrics = token_models.validate(model, batches, masked_loss)
    full = token_models.validate(model, batches, lambda m, b, c, g: masked_loss(m, b, c, g, all_masked=True))
    return {**metrics, "ce_all_masked": full["ce"]}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    token_models.add_arguments(parser, cond_drop=0.1)


def main(args: argparse.Namespace) -> int:
    from t2m.families.masked.masked_transformer import MaskedTransformer

    return token_models.train(args, MaskedTransformer, masked_loss, validate_masked, name="masked")
