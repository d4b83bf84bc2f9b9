"""An independent reference of MoMask's computation, written from the facts (../shared/docs/masked-models.md §1.2-1.4),
NOT from the project's token_transformer: torch's own nn.TransformerEncoder (post-LN, GELU, sequence-first), the
BERT-style output head, the share-weight tables of the residual transformer, MoMask's two ``generate`` loops in torch
(float32 schedule, double argsort ranks, CFG as uncond + s (cond - uncond), top-k by ``topk`` + scatter, confidence
from the unfiltered guided logits, frozen tokens at 1e5, pad samples -> -1) and the RVQ decode by plain convolutions.

The modules load the release's state dicts strictly (their parameter names are the release's), so they also check
the test helper's key layout. Sampling with top-k 1 is deterministic (facts §3.16), which is where a numpy port can
be compared token for token.
"""
from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import nn


class _PoseEmbedding(nn.Module):
    def __init__(self, code_dim: int, latent: int) -> None:
        super().__init__()
        self.poseEmbedding = nn.Linear(code_dim, latent)


class _PositionTable(nn.Module):
    pe: torch.Tensor

    def __init__(self, rows: int, latent: int) -> None:
        super().__init__()
        self.register_buffer("pe", torch.zeros(rows, 1, latent))


class _Head(nn.Module):
    """dense -> GELU -> LayerNorm(eps 1e-12) -> poseFinal."""

    def __init__(self, latent: int, out: int) -> None:
        super().__init__()
        self.dense = nn.Linear(latent, latent)
        self.LayerNorm = nn.LayerNorm(latent, eps=1e-12)
        self.poseFinal = nn.Linear(latent, out)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.poseFinal(self.LayerNorm(F.gelu(self.dense(x))))


class _Encoder(nn.Module):
    """What both transformers share: token features [T, B, code_dim] + prefix rows -> encoder outputs of the tokens."""

    def __init__(self, code_dim: int, latent: int, heads: int, layers: int, ff: int, text_dim: int, pe_rows: int,
                 head_out: int) -> None:
        super().__init__()
        self.input_process = _PoseEmbedding(code_dim, latent)
        self.position_enc = _PositionTable(pe_rows, latent)
        layer = nn.TransformerEncoderLayer(latent, heads, ff, dropout=0.2, activation="gelu")  # sequence-first
        self.seqTransEncoder = nn.TransformerEncoder(layer, layers, enable_nested_tensor=False)
        self.cond_emb = nn.Linear(text_dim, latent)
        self.output_process = _Head(latent, head_out)

    def run(self, tokens: torch.Tensor, prefix: list[torch.Tensor], padding: torch.Tensor) -> torch.Tensor:
        """tokens [B, T, code_dim], prefix rows [B, latent] each, padding [B, T] (True = pad) -> head [B, T, out]."""
        x = self.input_process.poseEmbedding(tokens.permute(1, 0, 2))            # [T, B, latent]
        x = x + self.position_enc.pe[: x.shape[0]]                                 # PE on the motion tokens only
        sequence = torch.cat([torch.stack(prefix, 0), x], dim=0)                  # prefix rows without PE
        keys = torch.cat([padding.new_zeros(padding.shape[0], len(prefix)), padding], dim=1)
        out = self.seqTransEncoder(sequence, src_key_padding_mask=keys)[len(prefix):]
        return self.output_process(out).permute(1, 0, 2)


class ReferenceMaskTransformer(_Encoder):
    """ids [B, T] (mask id K, pad id K + 1), text [B, Dt], padding [B, T] -> logits [B, T, K]."""

    def __init__(self, nb_code: int, code_dim: int, latent: int, heads: int, layers: int, ff: int, text_dim: int,
                 pe_rows: int) -> None:
        super().__init__(code_dim, latent, heads, layers, ff, text_dim, pe_rows, nb_code)
        self.token_emb = nn.Embedding(nb_code + 2, code_dim)
        self.mask_id, self.pad_id = nb_code, nb_code + 1

    def forward(self, ids: torch.Tensor, text: torch.Tensor, padding: torch.Tensor, null: bool = False) -> torch.Tensor:
        cond = self.cond_emb(torch.zeros_like(text) if null else text)
        return self.run(self.token_emb(ids), [cond], padding)


class ReferenceResidualTransformer(_Encoder):
    """history [B, T, code_dim], layer q [B], text, padding -> logits [B, T, K + 1] for layer q."""

    def __init__(self, nb_code: int, code_dim: int, quantizers: int, latent: int, heads: int, layers: int, ff: int,
                 text_dim: int, pe_rows: int) -> None:
        super().__init__(code_dim, latent, heads, layers, ff, text_dim, pe_rows, code_dim)
        vocab = nb_code + 1
        self.embed_proj_shared_weight = nn.Parameter(torch.zeros(quantizers - 2, vocab, code_dim))
        self.token_embed_weight_ = nn.Parameter(torch.zeros(1, vocab, code_dim))
        self.output_proj_weight_ = nn.Parameter(torch.zeros(1, vocab, code_dim))
        self.quant_emb = nn.Linear(quantizers, latent)
        self.quantizers, self.pad_id = quantizers, nb_code

    def input_tables(self) -> torch.Tensor:
        """E_0..E_4: E_0 its own, E_k = shared[k - 1]."""
        return torch.cat([self.token_embed_weight_, self.embed_proj_shared_weight], 0)

    def output_tables(self) -> torch.Tensor:
        """W_1..W_5: W_k = shared[k - 1] for k <= 4, W_5 its own."""
        return torch.cat([self.embed_proj_shared_weight, self.output_proj_weight_], 0)

    def forward(self, history: torch.Tensor, layer: torch.Tensor, text: torch.Tensor, padding: torch.Tensor,
                null: bool = False) -> torch.Tensor:
        cond = self.cond_emb(torch.zeros_like(text) if null else text)
        quant = self.quant_emb(F.one_hot(layer, self.quantizers).float())
        features = self.run(history, [cond, quant], padding)                       # [B, T, code_dim]
        return torch.einsum("bvd,btd->btv", self.output_tables()[layer - 1], features)


def _guided(forward, scale: float) -> torch.Tensor:
    """MoMask's CFG: one conditional and one null pass; scale 1 = the conditional logits alone."""
    logits = forward(False)
    if scale == 1:
        return logits
    null = forward(True)
    return null + (logits - null) * scale


def _top_k(logits: torch.Tensor, ratio: float, k: int | None) -> torch.Tensor:
    """Keep the ceil((1 - ratio) V) largest logits (or the ``k`` largest), -inf elsewhere (torch.topk + scatter)."""
    k = math.ceil((1 - ratio) * logits.shape[-1]) if k is None else k
    values, index = logits.topk(k, dim=-1)
    return torch.full_like(logits, float("-inf")).scatter(-1, index, values)


def remask_count(tau: torch.Tensor, lengths: torch.Tensor) -> torch.Tensor:
    """Tokens re-masked at schedule time tau (a float32 0-d tensor from torch.linspace): round(cos(pi tau / 2) len),
    at least 1, in torch's float32 arithmetic."""
    return torch.round(torch.cos(tau * math.pi * 0.5) * lengths).clamp(min=1)


@torch.no_grad()
def generate_mask_stage(model: ReferenceMaskTransformer, text: torch.Tensor, lengths: torch.Tensor, steps: int,
                        scale: float, keep_ratio: float = 0.9, top_k: int | None = None,
                        generator: torch.Generator | None = None) -> torch.Tensor:
    """MoMask's MaskTransformer.generate (categorical sampling at temperature 1) -> ids [B, T] (-1 past a length);
    ``top_k`` replaces the ratio's k (1: deterministic)."""
    rows = int(lengths.max())
    padding = torch.arange(rows)[None, :] >= lengths[:, None]
    ids = torch.where(padding, model.pad_id, model.mask_id)
    scores = torch.where(padding, 1e5, 0.0)
    for tau in torch.linspace(0, 1, steps):
        count = remask_count(tau, lengths)
        ranks = scores.argsort(dim=1).argsort(dim=1)
        masked = ranks < count[:, None]
        ids = torch.where(masked, model.mask_id, ids)
        logits = _guided(lambda null, ids=ids: model(ids, text, padding, null), scale)
        probs = F.softmax(_top_k(logits, keep_ratio, top_k), dim=-1)
        drawn = torch.multinomial(probs.reshape(-1, probs.shape[-1]), 1, generator=generator).view(ids.shape)
        ids = torch.where(masked, drawn, ids)
        scores = logits.softmax(-1).gather(2, drawn[..., None])[..., 0]
        scores = scores.masked_fill(~masked, 1e5)
    return torch.where(padding, -1, ids)


@torch.no_grad()
def generate_residual_stage(model: ReferenceResidualTransformer, ids: torch.Tensor, text: torch.Tensor,
                            lengths: torch.Tensor, scale: float, keep_ratio: float = 0.9, top_k: int | None = None,
                            generator: torch.Generator | None = None) -> torch.Tensor:
    """MoMask's ResidualTransformer.generate (Gumbel-max at temperature 1) -> ids [B, T, Q] (-1: unused / padding)."""
    padding = torch.arange(ids.shape[1])[None, :] >= lengths[:, None]
    current = torch.where(padding, model.pad_id, ids)
    layers, history = [current], torch.zeros(*ids.shape, model.token_embed_weight_.shape[-1])
    tables = model.input_tables()
    for q in range(1, model.quantizers):
        history = history + tables[q - 1][current]
        layer = torch.full((ids.shape[0],), q, dtype=torch.long)
        logits = _guided(lambda null, h=history, layer=layer: model(h, layer, text, padding, null), scale)
        uniform = torch.rand(logits.shape, generator=generator)
        gumbel = -torch.log((-torch.log(uniform.clamp(min=1e-20))).clamp(min=1e-20))
        drawn = (_top_k(logits, keep_ratio, top_k) + gumbel).argmax(-1)
        current = torch.where(padding, model.pad_id, drawn)
        layers.append(current)
    out = torch.stack(layers, -1)
    return torch.where(out == model.pad_id, -1, out)


@torch.no_grad()
def rvq_decode(vq: dict[str, torch.Tensor], ids: torch.Tensor, mean: torch.Tensor, std: torch.Tensor) -> torch.Tensor:
    """ids [B, T, Q] (-1 = zero vector) -> de-normalised features [B, 4T, D]: the sum of the layers' codebook
    vectors through the decoder (resblocks dilated 9, 3, 1; nearest x2 upsampling), then x * std + mean."""
    latent = sum(torch.where(ids[..., q, None] >= 0, vq[f"quantizer.layers.{q}.codebook"][ids[..., q].clamp(min=0)],
                             torch.zeros(()))
                 for q in range(ids.shape[-1]))
    assert isinstance(latent, torch.Tensor)

    def conv(x: torch.Tensor, key: str, dilation: int = 1) -> torch.Tensor:
        weight = vq[f"{key}.weight"]
        return F.conv1d(x, weight, vq[f"{key}.bias"], padding=dilation * (weight.shape[-1] // 2), dilation=dilation)

    x = F.relu(conv(latent.permute(0, 2, 1), "decoder.model.0"))
    for stage in (2, 3):
        for block, dilation in enumerate((9, 3, 1)):
            p = f"decoder.model.{stage}.0.model.{block}"
            x = x + conv(F.relu(conv(F.relu(x), f"{p}.conv1", dilation)), f"{p}.conv2")
        x = conv(F.interpolate(x, scale_factor=2, mode="nearest"), f"decoder.model.{stage}.2")
    x = conv(F.relu(conv(x, "decoder.model.4")), "decoder.model.6")
    return x.permute(0, 2, 1) * std + mean
