"""A contrastive text-motion evaluator (TMR-style), our stand-in for Guo et al.'s evaluator.

The papers' metrics (R-precision, FID, MM-Dist, Diversity, MModality) are all computed in the joint embedding
space of a text encoder and a motion encoder trained to retrieve each other. Guo et al.'s released evaluator is
not available here, so we train our own on the training split: a small transformer over normalised 263-dim
features (masked mean pooling, any length up to `max_frames`) and a projection head on frozen MiniLM sentence
features, both L2-normalised, trained with a symmetric InfoNCE loss (Petrovich et al., TMR, 2023).
Numbers from it are comparable between our own models, not with the papers' tables.
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from t2m.model.networks.config import ConfigDict
from t2m.motion.constants import FRAMES_PER_TOKEN


@dataclass
class EvaluatorConfig(ConfigDict):
    label = "evaluator"

    feature_dim: int = 263      # 263 for SMPL-22 (HumanML3D), 251 for KIT-21
    text_dim: int = 384         # MiniLM sentence features
    text_encoder: str = "minilm"
    embed_dim: int = 256        # the shared space the metrics are computed in
    width: int = 128
    n_layer: int = 2
    n_head: int = 4
    max_frames: int = 196       # HumanML3D's longest clip (9.8 s at 20 fps)
    downsample: int = FRAMES_PER_TOKEN  # frames per transformer token
    dropout: float = 0.1
    temperature: float = 0.1



class Block(nn.Module):
    """A pre-norm transformer block (nanoGPT's, without the causal mask): padding keys are masked out."""

    def __init__(self, width: int, n_head: int, dropout: float):
        super().__init__()
        if width % n_head:
            raise ValueError(f"width {width} must be divisible by n_head {n_head}")
        self.n_head = n_head
        self.ln_1 = nn.LayerNorm(width)
        self.qkv = nn.Linear(width, 3 * width)
        self.proj = nn.Linear(width, width)
        self.ln_2 = nn.LayerNorm(width)
        self.mlp = nn.Sequential(nn.Linear(width, 4 * width), nn.GELU(), nn.Linear(4 * width, width))
        self.dropout = nn.Dropout(dropout)

    def forward(self, x: torch.Tensor, key_mask: torch.Tensor) -> torch.Tensor:
        batch, tokens, width = x.shape
        q, k, v = self.qkv(self.ln_1(x)).split(width, dim=2)
        q, k, v = (t.view(batch, tokens, self.n_head, width // self.n_head).transpose(1, 2) for t in (q, k, v))
        y = F.scaled_dot_product_attention(q, k, v, attn_mask=key_mask[:, None, None, :])
        x = x + self.dropout(self.proj(y.transpose(1, 2).reshape(batch, tokens, width)))
        return x + self.dropout(self.mlp(self.ln_2(x)))


class MotionEncoder(nn.Module):
    """Normalised features [B, T, D] with valid lengths [B] -> one vector per motion [B, width].

    Every `downsample` frames are flattened into one token (cheap on CPU, and 5 tokens a second are plenty
    to tell actions apart); a small transformer mixes time; masked mean pooling makes the result independent
    of padding, so a motion gets the same embedding alone or in a padded batch."""

    def __init__(self, config: EvaluatorConfig):
        super().__init__()
        self.downsample = config.downsample
        self.patch = nn.Linear(config.feature_dim * config.downsample, config.width)
        self.max_tokens = -(-config.max_frames // config.downsample)
        self.position = nn.Parameter(torch.randn(1, self.max_tokens, config.width) * 0.02)
        self.blocks = nn.ModuleList(Block(config.width, config.n_head, config.dropout) for _ in range(config.n_layer))
        self.norm = nn.LayerNorm(config.width)

    def token_lengths(self, lengths: torch.Tensor) -> torch.Tensor:
        """Valid tokens after patching: a token counts if any of its frames is valid."""
        return torch.div(lengths + self.downsample - 1, self.downsample, rounding_mode="floor").clamp(min=1)

    def forward(self, features: torch.Tensor, lengths: torch.Tensor) -> torch.Tensor:
        batch, frames, dim = features.shape
        tokens = -(-frames // self.downsample)
        if tokens > self.max_tokens:
            raise ValueError(f"motion of {frames} frames is longer than the evaluator's maximum "
                             f"({self.max_tokens * self.downsample} frames)")
        frame_mask = torch.arange(frames, device=features.device)[None, :] < lengths[:, None]
        x = features * frame_mask[..., None]  # whatever the padding held, it contributes nothing
        x = F.pad(x, (0, 0, 0, tokens * self.downsample - frames))
        x = self.patch(x.reshape(batch, tokens, self.downsample * dim)) + self.position[:, :tokens]
        token_mask = torch.arange(tokens, device=x.device)[None, :] < self.token_lengths(lengths)[:, None]
        for block in self.blocks:
            x = block(x, token_mask)
        x = self.norm(x) * token_mask[..., None]
        return x.sum(1) / token_mask.sum(1, keepdim=True)


class MotionEvaluator(nn.Module):
    """Joint text-motion embedding: `encode_motion` and `encode_text` return unit vectors [B, embed_dim]."""

    kind = "evaluator"
    # buffers: the normalisation statistics (set_normalization)
    mean: torch.Tensor
    std: torch.Tensor

    def __init__(self, config: EvaluatorConfig | None = None):
        super().__init__()
        self.config = config or EvaluatorConfig()
        c = self.config
        self.motion_encoder = MotionEncoder(c)
        self.motion_head = nn.Linear(c.width, c.embed_dim)
        self.text_head = nn.Sequential(nn.Linear(c.text_dim, c.width), nn.GELU(), nn.Dropout(c.dropout),
                                       nn.Linear(c.width, c.embed_dim))
        # The evaluator's own normalisation statistics travel with its weights, so that it judges every
        # model's output on the same scale whatever statistics that model was trained with.
        self.register_buffer("mean", torch.zeros(c.feature_dim))
        self.register_buffer("std", torch.ones(c.feature_dim))

    def set_normalization(self, mean, std) -> None:
        mean = torch.as_tensor(mean, dtype=torch.float32)
        std = torch.as_tensor(std, dtype=torch.float32)
        if mean.shape != self.mean.shape or std.shape != self.std.shape:
            raise ValueError(f"mean/std must have shape {tuple(self.mean.shape)}, "
                             f"got {tuple(mean.shape)}/{tuple(std.shape)}")
        self.mean.copy_(mean)
        self.std.copy_(std.clamp(min=1e-8))

    def normalize(self, features: torch.Tensor) -> torch.Tensor:
        """Raw (de-normalised) 263-dim features -> the evaluator's normalised input."""
        return (features - self.mean) / self.std

    def encode_motion(self, features_norm: torch.Tensor, lengths: torch.Tensor) -> torch.Tensor:
        if features_norm.ndim != 3 or features_norm.shape[-1] != self.config.feature_dim:
            raise ValueError(f"features must be [B, T, {self.config.feature_dim}], got {tuple(features_norm.shape)}")
        pooled = self.motion_encoder(features_norm, lengths.to(features_norm.device))
        return F.normalize(self.motion_head(pooled), dim=-1)

    def encode_text(self, text_features: torch.Tensor) -> torch.Tensor:
        if text_features.ndim != 2 or text_features.shape[-1] != self.config.text_dim:
            raise ValueError(f"text features must be [B, {self.config.text_dim}], got {tuple(text_features.shape)}")
        return F.normalize(self.text_head(text_features), dim=-1)

    def forward(self, features_norm: torch.Tensor, lengths: torch.Tensor,
                text_features: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        return self.encode_text(text_features), self.encode_motion(features_norm, lengths)


def false_negative_mask(text_features: torch.Tensor, threshold: float = 0.95) -> torch.Tensor:
    """[B, B] True where two different items of a batch have (near-)identical captions.

    Captions written from labels repeat a lot ("a person walks happily"); treating another clip with the same
    caption as a negative would teach the evaluator to separate motions the text cannot tell apart."""
    unit = F.normalize(text_features, dim=-1)
    similar = unit @ unit.T >= threshold
    return similar & ~torch.eye(len(unit), dtype=torch.bool, device=unit.device)


def info_nce(text_emb: torch.Tensor, motion_emb: torch.Tensor, temperature: float,
             ignore: torch.Tensor | None = None) -> torch.Tensor:
    """Symmetric InfoNCE over a batch of matching pairs; `ignore` [B, B] removes false negatives."""
    logits = text_emb @ motion_emb.T / temperature
    if ignore is not None:
        logits = logits.masked_fill(ignore, float("-inf"))
    targets = torch.arange(len(logits), device=logits.device)
    return 0.5 * (F.cross_entropy(logits, targets) + F.cross_entropy(logits.T, targets))


def pad_batch(motions: Sequence[np.ndarray]) -> tuple[torch.Tensor, torch.Tensor]:
    """Motions [T_i, D] -> zero-padded [B, max T, D] and lengths [B]."""
    lengths = torch.tensor([len(m) for m in motions], dtype=torch.long)
    batch = torch.zeros(len(motions), int(lengths.max()), motions[0].shape[1])
    for row, motion in enumerate(motions):
        batch[row, :len(motion)] = torch.from_numpy(np.ascontiguousarray(motion, dtype=np.float32))
    return batch, lengths


@torch.no_grad()
def embed_motions(model: MotionEvaluator, motions: Sequence[np.ndarray], normalized: bool = True,
                  batch_size: int = 128) -> np.ndarray:
    """Embeddings [N, embed_dim] of motions [T_i, D] of any lengths, batched by similar length.

    normalized=False takes raw (de-normalised) features and applies the evaluator's own statistics."""
    model.eval()
    out = np.zeros((len(motions), model.config.embed_dim), dtype=np.float32)
    order = np.argsort([len(m) for m in motions], kind="stable")
    for start in range(0, len(order), batch_size):
        index = order[start:start + batch_size]
        features, lengths = pad_batch([motions[i] for i in index])
        if not normalized:
            features = model.normalize(features)
        out[index] = model.encode_motion(features, lengths).numpy()
    return out


@torch.no_grad()
def embed_texts(model: MotionEvaluator, text_features: np.ndarray, batch_size: int = 1024) -> np.ndarray:
    """Embeddings [N, embed_dim] of frozen text-encoder features [N, text_dim]."""
    model.eval()
    features = torch.as_tensor(np.asarray(text_features, dtype=np.float32))
    chunks = [model.encode_text(features[i:i + batch_size]).numpy() for i in range(0, len(features), batch_size)]
    return np.concatenate(chunks) if chunks else np.zeros((0, model.config.embed_dim), np.float32)
