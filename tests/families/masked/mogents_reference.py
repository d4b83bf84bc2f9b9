"""An independent reference of MoGenTS's computation, written from the facts (../shared/docs/masked-models.md §2.3,
§2.5, §2.6, §2.2 and §3), NOT from the project's token_transformer: torch's own nn.TransformerEncoder
(sequence-first, post-LN, GELU), the stacks written the way the facts describe the release, and its quirks done the
release's way rather than reproduced:

- the mask model's padding mask is ONE tensor: the spatial stage writes True into the text row of a view of it,
  and the temporal stage then reads the same tensor (so the text row is a masked key there);
- the spatial stages pick the real rows with ``nonzero`` and index-assign their outputs;
- the residual model's spatial output [J, B T] is reshaped to [T, B, J] without a transpose (B = 1 per call here,
  as MoGenTS's demo runs one prompt);
- the residual generate loop ends with pad -> -1 and, if any id equals the mask id, a clip to [0, K - 1].

The 1D "aux" models are MoMask's (momask_reference.py); the fused decode is plain convolutions. Sampling at
top-k 1 is deterministic (facts §3.16), where the service's loop can be compared token for token.
"""
from __future__ import annotations

import torch
import torch.nn.functional as F
from momask_reference import _guided, _Head, _PoseEmbedding, _top_k, generate_mask_stage, rvq_decode
from torch import nn


class _Table2d(nn.Module):
    pe: torch.Tensor

    def __init__(self, rows: int, columns: int, latent: int) -> None:
        super().__init__()
        self.register_buffer("pe", torch.zeros(rows, columns, latent))


def _stack(latent: int, heads: int, layers: int, ff: int) -> nn.TransformerEncoder:
    layer = nn.TransformerEncoderLayer(latent, heads, ff, dropout=0.2, activation="gelu")  # sequence-first
    return nn.TransformerEncoder(layer, layers, enable_nested_tensor=False)


class _Model2d(nn.Module):
    """The keys both 2D models have."""

    J = 6

    def __init__(self, code_dim: int, latent: int, heads: int, layers: int, ff: int, text_dim: int,
                 pe: tuple[int, int], head_out: int) -> None:
        super().__init__()
        self.input_process = _PoseEmbedding(code_dim, latent)
        self.position2d_enc = _Table2d(*pe, latent)
        self.seqTransEncoder = _stack(latent, heads, layers, ff)
        self.seqTransEncoder2 = _stack(latent, heads, layers, ff)
        self.seqTransEncoder3 = _stack(latent, heads, layers, ff)
        self.cond_emb = nn.Linear(text_dim, latent)
        self.output_process = _Head(latent, head_out)

    def add_pe(self, x: torch.Tensor, first_row: int = 0) -> torch.Tensor:
        """x [rows, J, B, D] + pe[first_row.., :J]."""
        return x + self.position2d_enc.pe[first_row:first_row + x.shape[0], : x.shape[1], None, :]


class ReferenceMask2d(_Model2d):
    """ids [B, T, J] (mask id K, pad id K + 1), text [B, Dt], padding [B, T] (True = pad) -> logits [B, T, J, K]."""

    def __init__(self, nb_code: int, code_dim: int, latent: int, heads: int, layers: int, ff: int, text_dim: int,
                 pe: tuple[int, int]) -> None:
        super().__init__(code_dim, latent, heads, layers, ff, text_dim, pe, nb_code)
        self.token_emb = nn.Embedding(nb_code + 2, code_dim)
        self.mask_id, self.pad_id = nb_code, nb_code + 1

    def forward(self, ids: torch.Tensor, text: torch.Tensor, padding: torch.Tensor, null: bool = False):
        B, T, J = ids.shape
        ids = torch.where(padding[:, :, None], self.pad_id, ids)
        x = self.input_process.poseEmbedding(self.token_emb(ids).permute(1, 2, 0, 3))        # [T, J, B, D]
        cond = self.cond_emb(torch.zeros_like(text) if null else text)                      # [B, D]
        x = self.add_pe(torch.cat([cond[None, None].expand(1, J, B, -1), x], 0))             # [T+1, J, B, D]
        keys = torch.cat([torch.zeros(B, 1, dtype=torch.bool), padding], 1)[:, :, None].repeat(1, 1, J)
        keys = keys.reshape(B, (T + 1) * J)                                                 # ONE mask tensor
        out = self.seqTransEncoder(x.reshape((T + 1) * J, B, -1), src_key_padding_mask=keys)
        # spatial: rows (b, t) of J tokens; the text row is marked padded IN PLACE, through a view of `keys`
        x2 = self.add_pe(out.reshape(T + 1, J, B, -1)).permute(1, 2, 0, 3).reshape(J, B * (T + 1), -1)
        view = keys.view(B, T + 1, J)
        view[:, 0] = True
        rows = torch.nonzero(~view.reshape(B * (T + 1), J)[:, 0])[:, 0]
        x2 = x2.clone()
        x2[:, rows] = self.seqTransEncoder2(x2[:, rows])
        spatial = x2.reshape(J, B, T + 1, -1).permute(2, 0, 1, 3)[1:]                     # [T, J, B, D]
        # temporal: per (b, j) the text row then the T rows; the key mask is `keys` as it is NOW
        x3 = self.add_pe(torch.cat([cond[None, None].expand(1, J, B, -1), spatial], 0))     # [T+1, J, B, D]
        x3 = x3.permute(0, 2, 1, 3).reshape(T + 1, B * J, -1)
        keys3 = keys.view(B, T + 1, J).permute(0, 2, 1).reshape(B * J, T + 1)
        temporal = self.seqTransEncoder3(x3, src_key_padding_mask=keys3).reshape(T + 1, B, J, -1)[1:]
        out = spatial + temporal.permute(0, 2, 1, 3)
        return self.output_process(out).permute(2, 0, 1, 3)                                # [B, T, J, K]


class ReferenceResidual2d(_Model2d):
    """history [1, T J, code_dim] (one motion, no padding, as the demo runs), layer q [1], text [1, Dt] -> logits
    [1, T J, K + 2]; ``padding`` (all False) and flattened ids keep momask_reference's generate loop usable."""

    def __init__(self, nb_code: int, code_dim: int, quantizers: int, latent: int, heads: int, layers: int, ff: int,
                 text_dim: int, pe: tuple[int, int]) -> None:
        super().__init__(code_dim, latent, heads, layers, ff, text_dim, pe, code_dim)
        vocab = nb_code + 2
        self.embed_proj_shared_weight = nn.Parameter(torch.zeros(quantizers - 2, vocab, code_dim))
        self.token_embed_weight_ = nn.Parameter(torch.zeros(1, vocab, code_dim))
        self.output_proj_weight_ = nn.Parameter(torch.zeros(1, vocab, code_dim))
        self.quant_emb = nn.Linear(quantizers, latent)
        self.quantizers, self.mask_id, self.pad_id = quantizers, nb_code, nb_code + 1

    def input_tables(self) -> torch.Tensor:
        return torch.cat([self.token_embed_weight_, self.embed_proj_shared_weight], 0)

    def output_tables(self) -> torch.Tensor:
        return torch.cat([self.embed_proj_shared_weight, self.output_proj_weight_], 0)

    def forward(self, history: torch.Tensor, layer: torch.Tensor, text: torch.Tensor, padding: torch.Tensor,
                null: bool = False) -> torch.Tensor:
        B, J = history.shape[0], self.J
        T = history.shape[1] // J
        assert B == 1 and not padding.any(), "the release's layout is reproduced for one motion per call"
        x = self.input_process.poseEmbedding(history.permute(1, 0, 2)).reshape(T, J, B, -1)
        cond = self.cond_emb(torch.zeros_like(text) if null else text)
        quant = self.quant_emb(F.one_hot(layer, self.quantizers).float())
        prefix = [cond[None, None].expand(1, J, B, -1), quant[None, None].expand(1, J, B, -1)]
        x = self.add_pe(torch.cat([*prefix, x], 0))                                          # [T+2, J, B, D]
        out = self.seqTransEncoder(x.reshape((T + 2) * J, B, -1)).reshape(T + 2, J, B, -1)[2:]
        # spatial: positions from row 0; the output [J, B T] read back as [T, B, J] WITHOUT a transpose
        x2 = self.add_pe(out, first_row=0).permute(1, 2, 0, 3).reshape(J, B * T, -1)
        spatial = torch.zeros_like(x2)
        rows = torch.nonzero(torch.ones(B * T, dtype=torch.bool))[:, 0]
        spatial[:, rows] = self.seqTransEncoder2(x2[:, rows])
        out = out + spatial.reshape(T, B, J, -1).permute(0, 2, 1, 3)                          # [T, J, B, D]
        x3 = self.add_pe(torch.cat([*prefix, out], 0)).permute(0, 2, 1, 3).reshape(T + 2, B * J, -1)
        temporal = self.seqTransEncoder3(x3).reshape(T + 2, B, J, -1)[2:]
        out = out + temporal.permute(0, 2, 1, 3)
        features = self.output_process(out).reshape(T * J, B, -1).permute(1, 0, 2)           # [B, T J, code_dim]
        return torch.einsum("bvd,bnd->bnv", self.output_tables()[layer - 1], features)


class FlatMask2d(nn.Module):
    """The 2D mask model over the flattened map, so momask_reference's generate loop runs MoGenTS's ts generate
    (re-masking over T J tokens, counts round(cos(.) L 6))."""

    def __init__(self, model: ReferenceMask2d) -> None:
        super().__init__()
        self.model, self.mask_id, self.pad_id = model, model.mask_id, model.pad_id

    def forward(self, ids: torch.Tensor, text: torch.Tensor, padding: torch.Tensor, null: bool = False):
        B, J = ids.shape[0], ReferenceMask2d.J
        rows = padding.view(B, -1, J)[:, :, 0]
        return self.model(ids.view(B, -1, J), text, rows, null).reshape(B, -1, self.mask_id)


@torch.no_grad()
def generate_ts(masked: ReferenceMask2d, residual: ReferenceResidual2d, text: torch.Tensor, rows: int,
                steps: int = 10, top_k: int = 1) -> torch.Tensor:
    """MoGenTS's ts mask generate then ts residual generate for ONE motion -> ids [rows, 6, Q]."""
    J = ReferenceMask2d.J
    length = torch.tensor([rows * J])
    ids = generate_mask_stage(FlatMask2d(masked), text, length, steps, 4.0, top_k=top_k)        # [1, T J]
    current = ids.clone()
    layers, history = [current], torch.zeros(1, rows * J, residual.token_embed_weight_.shape[-1])
    tables = residual.input_tables()
    padding = torch.zeros(1, rows * J, dtype=torch.bool)
    for q in range(1, residual.quantizers):
        history = history + tables[q - 1][current]
        layer = torch.tensor([q])
        logits = _guided(lambda null, h=history, layer=layer: residual(h, layer, text, padding, null), 5.0)
        current = _top_k(logits, 0.9, top_k).argmax(-1)            # top-k 1: the Gumbel draw is the argmax
        layers.append(current)
    out = torch.stack(layers, -1)
    out = torch.where(out == residual.pad_id, -1, out)
    if out.max() == residual.mask_id:
        out = out.clip(0, residual.mask_id - 1)
    return out.reshape(rows, J, -1)


@torch.no_grad()
def fused_decode(vq: dict[str, torch.Tensor], ids1d: torch.Tensor, ids2d: torch.Tensor, mean: torch.Tensor,
                 std: torch.Tensor) -> torch.Tensor:
    """ids1d [B, T, Q], ids2d [B, T, 6, Q] (-1 = zero vector) -> de-normalised features [B, 4T, 263]."""
    one_d = {k.replace("decoder1d.", "decoder.").replace("quantizer1d.", "quantizer."): v for k, v in vq.items()}
    out1d = rvq_decode(one_d, ids1d, torch.zeros(()), torch.ones(()))                          # normalised
    B, T, J, Q = ids2d.shape
    latent = sum(torch.where(ids2d[..., q, None] >= 0,
                             vq[f"quantizer2d.layers.{q}.codebook"][ids2d[..., q].clamp(min=0)], torch.zeros(()))
                 for q in range(Q))
    assert isinstance(latent, torch.Tensor)
    D = latent.shape[-1]
    merged = F.linear(latent.reshape(B, T, J * D), vq["linear_merge.weight"], vq["linear_merge.bias"])
    x = merged.reshape(B, T, J, D).permute(0, 3, 1, 2)                                         # [B, D, T, J]

    def conv(x: torch.Tensor, key: str, dilation: int = 1) -> torch.Tensor:
        weight = vq[f"{key}.weight"]
        return F.conv2d(x, weight, vq[f"{key}.bias"], padding=dilation * (weight.shape[-1] // 2), dilation=dilation)

    x = F.relu(conv(x, "decoder2d.model.0"))
    for stage in (2, 3):
        for block, dilation in enumerate((9, 3, 1)):
            p = f"decoder2d.model.{stage}.0.model.{block}"
            x = x + conv(F.relu(conv(F.relu(x), f"{p}.conv1", dilation)), f"{p}.conv2")
        x = conv(F.interpolate(x, scale_factor=2, mode="nearest"), f"decoder2d.model.{stage}.2")
    x = conv(F.relu(conv(x, "decoder2d.model.4")), "decoder2d.model.6")
    joints = x.permute(0, 2, 3, 1)[:, :, 1:-1]                                                # [B, 4T, 22, 12]
    jmotion = torch.zeros(B, joints.shape[1], 263)
    jmotion[:, :, :4] = joints[:, :, 0, :4]
    jmotion[:, :, -4:] = joints[:, :, 0, 4:8]
    jmotion[:, :, 4:67] = joints[:, :, 1:, :3].flatten(2)
    jmotion[:, :, 67:193] = joints[:, :, 1:, 3:9].flatten(2)
    jmotion[:, :, 193:259] = joints[:, :, :, 9:12].flatten(2)
    fused = F.linear(torch.cat([out1d, jmotion], -1), vq["linear_out.weight"], vq["linear_out.bias"])
    return fused * std + mean
