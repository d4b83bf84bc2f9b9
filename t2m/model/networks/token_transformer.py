"""What the masked and the residual transformer share: a text-conditioned encoder over a map of motion tokens.

A motion is a token map [B, T, C]: T token rows (4 frames each), C columns (C = 1: MoMask's 1D tokens; C = 6 or 22:
MoGenTS's joint tokens). Each model embeds its tokens to [B, T, C, latent] and gives one or two prefix rows (the
text condition, plus the layer token of the residual model); :meth:`TokenMapEncoder.encode` then runs

1. ``seqTransEncoder``: attention over every token of the map and the prefix, flattened time-major (joint-time);
2. ``seqTransEncoder2`` (option): attention among the C tokens of each frame (spatial), padded frames skipped;
3. ``seqTransEncoder3`` (option): attention along time within each column, with the prefix rows in front
   (temporal); its output is added to the spatial stage's.

Positions: ``position_enc`` (1D, MoMask: a sinusoid over t on the motion tokens only) or ``position2d_enc`` (2D,
MoGenTS: half the channels a sinusoid of the column, half of the row, on every row including the prefix), added
(with dropout) before each stack. Padded rows (``length`` [B] gives the real rows) are masked as keys, so the
outputs of real tokens do not depend on what sits in the padding, nor on the rest of the batch.

Layers compute what torch's ``nn.TransformerEncoderLayer`` (post-LN, GELU) does, under its parameter names, which
are the ones in MoMask's and MoGenTS's checkpoints (``seqTransEncoder.layers.{i}.self_attn.in_proj_weight``,
``linear1``, ``norm1``, ...). They are written out here (:class:`EncoderLayer`) because torch's module traces to an
ONNX graph whose sequence length is fixed at export.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import nn

from t2m.model.networks.config import ConfigDict
from t2m.model.networks.positions import sinusoid_table

POSITIONAL = ("1d", "2d")


def index_range(count: int, like: torch.Tensor) -> torch.Tensor:
    """0 .. count-1 (int64) on `like`'s device, as a cumulative sum of ones rather than torch.arange: exported with a
    traced count, arange becomes a Range node fed by Shape, which onnxruntime's CUDA provider runs on the CPU, so its
    output is copied to the device inside every run and the graph cannot be captured as a CUDA graph
    (t2m/export/graphs/capture_check.py)."""
    return torch.ones(count, dtype=torch.long, device=like.device).cumsum(0) - 1


def attention_scale(head_dim: int) -> float:
    """scaled_dot_product_attention's default scale, given as a number: left to the exporter, it is computed from
    the query's Shape on the CPU (see `index_range`). The same double as torch's default, 1 / sqrt(E)."""
    return 1.0 / math.sqrt(head_dim)


@dataclass
class TokenTransformerConfig(ConfigDict):
    """Hyper-parameters of the masked and residual transformers (MoMask: latent 384, 6 heads, 8 layers, ff 1024,
    code_dim 512, text 512; MoGenTS: the same per stack, 3 stacks, 6 columns)."""

    label = "token transformer"

    codebook_size: int = 256
    columns: int = 6
    residual_layers: int = 4  # quantiser layers R of the VQ (the residual transformer predicts layers 1..R-1)
    max_tokens: int = 50  # token rows
    latent: int = 256
    n_head: int = 4
    n_layer: int = 2  # per stack
    ff_size: int = 512
    dropout: float = 0.1
    text_dim: int = 384
    code_dim: int = 128  # width of the token embeddings (MoMask: the VQ's code_dim)
    positional: str = "2d"
    spatial_attention: bool = True
    temporal_attention: bool = True
    temporal_mask_cond: bool = False  # True: the temporal stack cannot see the text row (MoGenTS's release does this)
    # MoGenTS's released 2D residual model (facts §2.5): its spatial stack adds positions from row 0 (not after the
    # prefix rows), its spatial output is laid out as one motion per call does without a transpose
    # (release_spatial_layout), and it scores K + 2 classes (mask id K and pad K + 1 can both be drawn)
    spatial_rows_from_zero: bool = False
    spatial_scramble: bool = False
    residual_mask_class: bool = False
    share_weight: bool = True  # residual: embedding of layer k = classifier of layer k (MoMask's --share_weight)

    def __post_init__(self) -> None:
        self._require_positive("codebook_size", "columns", "residual_layers", "max_tokens", "latent", "n_head",
                               "n_layer", "ff_size", "text_dim", "code_dim")
        if self.positional not in POSITIONAL:
            raise ValueError(f"positional must be one of {', '.join(POSITIONAL)}, got {self.positional!r}")
        if self.latent % self.n_head:
            raise ValueError(f"latent ({self.latent}) must be divisible by n_head ({self.n_head})")
        if self.positional == "2d" and self.latent % 4:
            raise ValueError(f"2D positions need latent divisible by 4, got {self.latent}")
        if self.positional == "1d" and (self.columns != 1 or self.spatial_attention or self.temporal_attention):
            raise ValueError("1D positions (MoMask) go with columns=1 and no spatial/temporal stacks")

    @property
    def mask_id(self) -> int:
        return self.codebook_size

    @property
    def pad_id(self) -> int:
        return self.codebook_size + 1


def sinusoid_table_2d(rows: int, columns: int, dim: int) -> torch.Tensor:
    """[rows, columns, dim]: channels [0, dim/2) encode the column, [dim/2, dim) the row (sin/cos interleaved)."""
    half = dim // 2
    column = sinusoid_table(columns, half)[:, 0]  # [columns, half]
    row = sinusoid_table(rows, half)[:, 0]  # [rows, half]
    return torch.cat([column[None].expand(rows, -1, -1), row[:, None].expand(-1, columns, -1)], dim=-1)


def release_spatial_layout(spatial: torch.Tensor, length: torch.Tensor) -> torch.Tensor:
    """MoGenTS's released residual model re-lays its spatial output [T, C] without the transpose back: with one
    motion of L rows per call (its demo's B = 1), slot n = t' C + j' receives the output computed at (t, j) =
    (n mod L, n div L). Done per batch row with that row's own L, by one gather (static shapes, so it exports);
    rows past L keep their own (zero) output. spatial [B, T, C, D], length [B] -> [B, T, C, D]."""
    batch, rows, columns, dim = spatial.shape
    slot = index_range(rows * columns, spatial)[None, :]
    rows_of = length.clamp(min=1)[:, None]
    source = torch.where(slot < rows_of * columns, (slot % rows_of) * columns + slot // rows_of, slot)
    flat = spatial.reshape(batch, rows * columns, dim)
    return torch.gather(flat, 1, source[..., None].expand(batch, rows * columns, dim)).view(batch, rows, columns, dim)


class PositionalEncoding(nn.Module):
    """The fixed table as buffer ``pe``: [L, 1, D] in 1D (MoMask's layout), [rows, columns, D] in 2D (MoGenTS's)."""

    pe: torch.Tensor

    def __init__(self, table: torch.Tensor) -> None:
        super().__init__()
        self.register_buffer("pe", table)


class InputProcess(nn.Module):
    """Token embedding width -> latent (``input_process.poseEmbedding``)."""

    def __init__(self, code_dim: int, latent: int) -> None:
        super().__init__()
        self.poseEmbedding = nn.Linear(code_dim, latent)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.poseEmbedding(x)


class OutputProcess(nn.Module):
    """dense -> GELU -> LayerNorm -> poseFinal (MoMask's output heads; LayerNorm eps 1e-12 as there)."""

    def __init__(self, latent: int, out_dim: int) -> None:
        super().__init__()
        self.dense = nn.Linear(latent, latent)
        self.LayerNorm = nn.LayerNorm(latent, eps=1e-12)
        self.poseFinal = nn.Linear(latent, out_dim)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.poseFinal(self.LayerNorm(nn.functional.gelu(self.dense(x))))


class SelfAttention(nn.Module):
    """Multi-head self-attention, q/k/v packed in one projection (nn.MultiheadAttention's parameters)."""

    def __init__(self, dim: int, heads: int, dropout: float) -> None:
        super().__init__()
        self.heads, self.dropout = heads, dropout
        self.in_proj_weight = nn.Parameter(nn.init.xavier_uniform_(torch.empty(3 * dim, dim)))
        self.in_proj_bias = nn.Parameter(torch.zeros(3 * dim))
        self.out_proj = nn.Linear(dim, dim)

    def forward(self, x: torch.Tensor, keys: torch.Tensor | None) -> torch.Tensor:
        """x [N, S, D]; keys [N, S] bool (False = may not be attended to) or None -> [N, S, D]."""
        dim = x.shape[-1]
        qkv = F.linear(x, self.in_proj_weight, self.in_proj_bias).unflatten(-1, (3, self.heads, dim // self.heads))
        q, k, v = qkv.permute(2, 0, 3, 1, 4)  # each [N, H, S, hd]
        mask = None if keys is None else keys[:, None, None, :]
        y = F.scaled_dot_product_attention(q, k, v, attn_mask=mask, dropout_p=self.dropout if self.training else 0.0,
                                           scale=attention_scale(dim // self.heads))
        return self.out_proj(y.transpose(1, 2).flatten(2))


class EncoderLayer(nn.Module):
    """Post-LN transformer layer: x = norm1(x + attn(x)), then x = norm2(x + linear2(gelu(linear1(x))))."""

    def __init__(self, config: TokenTransformerConfig) -> None:
        super().__init__()
        c = config
        self.self_attn = SelfAttention(c.latent, c.n_head, c.dropout)
        self.linear1 = nn.Linear(c.latent, c.ff_size)
        self.linear2 = nn.Linear(c.ff_size, c.latent)
        self.norm1 = nn.LayerNorm(c.latent)
        self.norm2 = nn.LayerNorm(c.latent)
        self.dropout = nn.Dropout(c.dropout)

    def forward(self, x: torch.Tensor, keys: torch.Tensor | None) -> torch.Tensor:
        x = self.norm1(x + self.dropout(self.self_attn(x, keys)))
        return self.norm2(x + self.dropout(self.linear2(self.dropout(F.gelu(self.linear1(x))))))


class EncoderStack(nn.Module):
    """``layers.{i}``: n_layer EncoderLayers, the same key mask for all."""

    def __init__(self, config: TokenTransformerConfig) -> None:
        super().__init__()
        self.layers = nn.ModuleList(EncoderLayer(config) for _ in range(config.n_layer))

    def forward(self, x: torch.Tensor, keys: torch.Tensor | None = None) -> torch.Tensor:
        for layer in self.layers:
            x = layer(x, keys)
        return x


class TokenMapEncoder(nn.Module):
    """The conditioned encoder both token models build on (see the module docstring).

    ``spatial_adds``: the spatial stage's output is added to its input (residual model) instead of replacing the
    rows it ran on (masked model): the two MoGenTS models differ so.
    """

    def __init__(self, config: TokenTransformerConfig, prefix_rows: int, spatial_adds: bool) -> None:
        super().__init__()
        self.config = config
        self.prefix_rows = prefix_rows
        self.spatial_adds = spatial_adds
        c = config
        self.cond_emb = nn.Linear(c.text_dim, c.latent)
        self.input_process = InputProcess(c.code_dim, c.latent)
        if c.positional == "1d":
            self.position_enc = PositionalEncoding(sinusoid_table(c.max_tokens, c.latent))
        else:
            self.position2d_enc = PositionalEncoding(sinusoid_table_2d(c.max_tokens + prefix_rows, c.columns, c.latent))
        self.position_drop = nn.Dropout(c.dropout)
        self.seqTransEncoder = EncoderStack(c)
        if c.spatial_attention:
            self.seqTransEncoder2 = EncoderStack(c)
        if c.temporal_attention:
            self.seqTransEncoder3 = EncoderStack(c)

    def _init_weights(self) -> None:
        """Small normal init for linear layers and embeddings (as MoMask's transformers do)."""
        for module in self.modules():
            if isinstance(module, (nn.Linear, nn.Embedding)):
                nn.init.normal_(module.weight, mean=0.0, std=0.02)
                if isinstance(module, nn.Linear) and module.bias is not None:
                    nn.init.zeros_(module.bias)

    def num_parameters(self) -> int:
        return sum(p.numel() for p in self.parameters())

    def _positions(self, x: torch.Tensor) -> torch.Tensor:
        """x [B, P + T, C, D] (prefix rows first) plus positions, dropout."""
        if self.config.positional == "1d":
            pe = self.position_enc.pe[: x.shape[1] - self.prefix_rows, 0]  # [T, D], motion rows only
            motion = x[:, self.prefix_rows :] + pe[None, :, None, :]
            return self.position_drop(torch.cat([x[:, : self.prefix_rows], motion], dim=1))
        return self.position_drop(x + self.position2d_enc.pe[: x.shape[1], : x.shape[2]][None])

    def _positions_from(self, motion: torch.Tensor, first_row: int) -> torch.Tensor:
        """motion [B, T, C, D] (2D) plus the positions of rows first_row.., dropout."""
        return self.position_drop(motion + self.position2d_enc.pe[first_row : first_row + motion.shape[1],
                                                                  : motion.shape[2]][None])

    def check_shapes(self, tokens: torch.Tensor, cond: torch.Tensor, length: torch.Tensor) -> None:
        c = self.config
        if tokens.shape[1] > c.max_tokens or tokens.shape[2] != c.columns:
            raise ValueError(f"token map must be [B, <= {c.max_tokens}, {c.columns}, ...], got {list(tokens.shape)}")
        if cond.shape != (tokens.shape[0], c.text_dim):
            raise ValueError(f"cond must be [B, {c.text_dim}], got {list(cond.shape)}")
        if length.shape != (tokens.shape[0],):
            raise ValueError(f"length must be [B], got {list(length.shape)}")

    @staticmethod
    def valid_rows(length: torch.Tensor, rows: int) -> torch.Tensor:
        """[B, T] bool: row t is a real token row (t < length)."""
        return index_range(rows, length)[None, :] < length[:, None]

    def encode(self, motion: torch.Tensor, prefix: torch.Tensor, length: torch.Tensor) -> torch.Tensor:
        """motion [B, T, C, D] embedded tokens, prefix [B, P, D], length [B] -> features [B, T, C, D]."""
        batch, rows, columns, dim = motion.shape
        p = self.prefix_rows
        valid = self.valid_rows(length, rows)  # [B, T]
        prefix_rows = prefix[:, :, None, :].expand(batch, p, columns, dim)
        if self.config.positional == "1d":  # MoMask: P prefix tokens, then the T tokens
            x = self._positions(torch.cat([prefix[:, :, None, :], motion], dim=1))
            keys = torch.cat([valid.new_ones(batch, p), valid], dim=1)
            x = self.seqTransEncoder(x.reshape(batch, p + rows, dim), keys)
            return x[:, p:].reshape(batch, rows, columns, dim)

        x = self._positions(torch.cat([prefix_rows, motion], dim=1)).reshape(batch, (p + rows) * columns, dim)
        keys = torch.cat([valid.new_ones(batch, p), valid], dim=1)[:, :, None].expand(batch, p + rows, columns)
        x = self.seqTransEncoder(x, keys.reshape(batch, -1))
        motion = x.reshape(batch, p + rows, columns, dim)[:, p:]
        real = valid[:, :, None, None]
        if self.config.spatial_attention:  # the C tokens of each frame attend to each other
            inputs = self._positions_from(motion, 0 if self.config.spatial_rows_from_zero else p)
            spatial = self.seqTransEncoder2(inputs.reshape(batch * rows, columns, dim)).view(batch, rows, columns, dim)
            if self.spatial_adds:
                spatial = torch.where(real, spatial, torch.zeros_like(spatial))
                if self.config.spatial_scramble:
                    spatial = release_spatial_layout(spatial, length)
                motion = motion + spatial
            else:
                motion = torch.where(real, spatial, inputs)
        if self.config.temporal_attention:  # each column along time, behind the prefix rows
            inputs = self._positions(torch.cat([prefix_rows, motion], dim=1))  # [B, P + T, C, D]
            sequences = inputs.permute(0, 2, 1, 3).reshape(batch * columns, p + rows, dim)
            prefix_keys = valid.new_ones(batch, p)
            if self.config.temporal_mask_cond:  # hide the text row (row 0) from the temporal stack
                prefix_keys = torch.cat([valid.new_zeros(batch, 1), prefix_keys[:, 1:]], dim=1)
            keys = torch.cat([prefix_keys, valid], dim=1).repeat_interleave(columns, dim=0)
            temporal = self.seqTransEncoder3(sequences, keys)
            motion = motion + temporal.view(batch, columns, p + rows, dim).permute(0, 2, 1, 3)[:, p:]
        return motion
