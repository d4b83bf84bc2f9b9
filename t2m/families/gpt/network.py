"""MotionGPT: a causal transformer over VQ codes, conditioned on a text feature (T2M-GPT's design, nanoGPT style).

Sequence layout: position 0 is the condition token ``cond_emb(text) (+ len_emb(length))``,
positions 1..S are code tokens. The output at position t predicts code t (classes
0..K-1 = codes, K = End). Token ids K (End) and K+1 (Pad) exist as inputs only.

Module names follow T2M-GPT's ``Text2Motion_Transformer`` so its released weights load:

    trans_base: tok_emb [K+2, E], cond_emb Linear(Dt, E), pos_embed.embed [block_size, 1, E] (fixed sinusoids),
                blocks.{i}.{ln1, ln2, attn.{key,query,value,proj}, mlp.{0,2}}    (+ len_emb if length conditioning)
    trans_head: blocks.{i}..., ln_f, head Linear(E, K+1, bias=False)

T2M-GPT's checkpoints also hold ``trans_base.pos_embedding.weight`` (a learned table it never uses) and
``attn.mask`` (a causal-mask buffer); both are accepted on load and dropped, so a strict load succeeds.

Two entry points share the same weights and give the same logits:
``forward`` (whole sequence, training) and ``forward_step`` (one token with a KV cache,
sampling and the ONNX step graph; no Python control flow on tensor values).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import nn

from t2m.model.networks.config import ConfigDict
from t2m.model.networks.positions import sinusoid_table


@dataclass
class GPTConfig(ConfigDict):
    """Hyper-parameters of :class:`MotionGPT` (T2M-GPT's release: E=1024, 9+9 layers, 16 heads, Dt=512)."""

    label = "GPT"

    codebook_size: int = 512
    embed: int = 384
    n_head: int = 6
    n_layer_base: int = 3
    n_layer_head: int = 3
    block_size: int = 51
    dropout: float = 0.1
    text_dim: int = 384
    ff_rate: int = 4
    length_conditioning: bool = True

    def __post_init__(self) -> None:
        for name in ("codebook_size", "embed", "n_head", "block_size", "text_dim", "ff_rate"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name} must be >= 1, got {getattr(self, name)}")
        if self.n_layer_base < 0 or self.n_layer_head < 0 or self.n_layer < 1:
            raise ValueError(
                f"need at least one layer, got n_layer_base={self.n_layer_base} n_layer_head={self.n_layer_head}"
            )
        if self.embed % self.n_head:
            raise ValueError(f"embed ({self.embed}) must be divisible by n_head ({self.n_head})")
        if self.block_size < 2:
            raise ValueError(f"block_size must be >= 2 (condition + one code), got {self.block_size}")

    @property
    def n_layer(self) -> int:
        return self.n_layer_base + self.n_layer_head

    @property
    def head_dim(self) -> int:
        return self.embed // self.n_head

    @property
    def max_tokens(self) -> int:
        return self.block_size - 1

    @property
    def end_id(self) -> int:
        return self.codebook_size

    @property
    def pad_id(self) -> int:
        return self.codebook_size + 1



class SinusoidalPositions(nn.Module):
    """Holds the fixed table as the buffer ``embed`` [block_size, 1, E] (the name T2M-GPT's weights use)."""

    embed: torch.Tensor  # buffer

    def __init__(self, block_size: int, embed: int) -> None:
        super().__init__()
        self.register_buffer("embed", sinusoid_table(block_size, embed))

    def table(self) -> torch.Tensor:
        """[block_size, E]"""
        return self.embed[:, 0, :]


def _drop_legacy_keys(*names: str):
    """A load_state_dict pre-hook removing T2M-GPT keys that hold nothing this model uses."""

    def hook(state_dict, prefix, *args, **kwargs) -> None:
        for name in names:
            state_dict.pop(prefix + name, None)

    return hook


class CausalSelfAttention(nn.Module):
    """Multi-head causal self-attention with separate key/query/value projections (T2M-GPT's layout)."""

    causal_mask: torch.Tensor  # buffer (not saved)

    def __init__(self, config: GPTConfig) -> None:
        super().__init__()
        self.n_head = config.n_head
        self.head_dim = config.head_dim
        self.key = nn.Linear(config.embed, config.embed)
        self.query = nn.Linear(config.embed, config.embed)
        self.value = nn.Linear(config.embed, config.embed)
        self.proj = nn.Linear(config.embed, config.embed)
        self.attn_drop = nn.Dropout(config.dropout)
        self.resid_drop = nn.Dropout(config.dropout)
        causal = torch.tril(torch.ones(config.block_size, config.block_size, dtype=torch.bool))
        self.register_buffer("causal_mask", causal, persistent=False)
        self._register_load_state_dict_pre_hook(_drop_legacy_keys("mask"))

    def _heads(self, x: torch.Tensor) -> torch.Tensor:
        """[B, S, E] -> [B, H, S, hd]"""
        batch, length, _ = x.shape
        return x.view(batch, length, self.n_head, self.head_dim).transpose(1, 2)

    def _attend(self, q: torch.Tensor, k: torch.Tensor, v: torch.Tensor, mask: torch.Tensor | None) -> torch.Tensor:
        scores = (q @ k.transpose(-2, -1)) * (1.0 / math.sqrt(self.head_dim))
        if mask is not None:
            scores = scores.masked_fill(~mask, float("-inf"))
        weights = self.attn_drop(F.softmax(scores, dim=-1))
        y = weights @ v  # [B, H, S, hd]
        batch, _, length, _ = y.shape
        return self.resid_drop(self.proj(y.transpose(1, 2).reshape(batch, length, -1)))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        length = x.shape[1]
        q, k, v = self._heads(self.query(x)), self._heads(self.key(x)), self._heads(self.value(x))
        return self._attend(q, k, v, self.causal_mask[:length, :length])

    def forward_step(self, x: torch.Tensor, past_k: torch.Tensor, past_v: torch.Tensor):
        """x [B, 1, E]; past [B, H, P, hd] -> (y [B, 1, E], k [B, H, P+1, hd], v [B, H, P+1, hd]).

        The single new query is the last position, so it may attend to everything: no mask.
        """
        k = torch.cat([past_k, self._heads(self.key(x))], dim=2)
        v = torch.cat([past_v, self._heads(self.value(x))], dim=2)
        return self._attend(self._heads(self.query(x)), k, v, None), k, v


class Block(nn.Module):
    """Pre-LayerNorm transformer block: x + attn(ln1(x)), then x + mlp(ln2(x))."""

    def __init__(self, config: GPTConfig) -> None:
        super().__init__()
        self.ln1 = nn.LayerNorm(config.embed)
        self.ln2 = nn.LayerNorm(config.embed)
        self.attn = CausalSelfAttention(config)
        hidden = config.ff_rate * config.embed
        self.mlp = nn.Sequential(
            nn.Linear(config.embed, hidden), nn.GELU(), nn.Linear(hidden, config.embed), nn.Dropout(config.dropout)
        )

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        x = x + self.attn(self.ln1(x))
        return x + self.mlp(self.ln2(x))

    def forward_step(self, x: torch.Tensor, past_k: torch.Tensor, past_v: torch.Tensor):
        y, k, v = self.attn.forward_step(self.ln1(x), past_k, past_v)
        x = x + y
        return x + self.mlp(self.ln2(x)), k, v


class TransBase(nn.Module):
    """Input embeddings (condition token, code tokens, fixed positions) and the first blocks."""

    def __init__(self, config: GPTConfig) -> None:
        super().__init__()
        self.config = config
        self.tok_emb = nn.Embedding(config.codebook_size + 2, config.embed)
        self.cond_emb = nn.Linear(config.text_dim, config.embed)
        if config.length_conditioning:
            self.len_emb = nn.Embedding(config.max_tokens + 1, config.embed)  # 0 = free length
        self.pos_embed = SinusoidalPositions(config.block_size, config.embed)
        self.drop = nn.Dropout(config.dropout)
        self.blocks = nn.ModuleList(Block(config) for _ in range(config.n_layer_base))
        self._register_load_state_dict_pre_hook(_drop_legacy_keys("pos_embedding.weight"))

    def condition_token(self, cond: torch.Tensor, length: torch.Tensor | None) -> torch.Tensor:
        """[B, Dt] (+ lengths [B]) -> [B, E]"""
        x = self.cond_emb(cond)
        if self.config.length_conditioning:
            if length is None:
                length = torch.zeros(cond.shape[0], dtype=torch.long, device=cond.device)
            x = x + self.len_emb(length)
        return x


class TransHead(nn.Module):
    """The last blocks, the final LayerNorm and the classifier over codes + End."""

    def __init__(self, config: GPTConfig) -> None:
        super().__init__()
        self.blocks = nn.ModuleList(Block(config) for _ in range(config.n_layer_head))
        self.ln_f = nn.LayerNorm(config.embed)
        self.head = nn.Linear(config.embed, config.codebook_size + 1, bias=False)


class MotionGPT(nn.Module):
    """Text (and optional length) conditioned autoregressive model over motion codes."""

    def __init__(self, config: GPTConfig | None = None) -> None:
        super().__init__()
        self.config = config or GPTConfig()
        self.trans_base = TransBase(self.config)
        self.trans_head = TransHead(self.config)
        self.apply(self._init_weights)

    @staticmethod
    def _init_weights(module: nn.Module) -> None:
        if isinstance(module, (nn.Linear, nn.Embedding)):
            nn.init.normal_(module.weight, mean=0.0, std=0.02)
            if isinstance(module, nn.Linear) and module.bias is not None:
                nn.init.zeros_(module.bias)
        elif isinstance(module, nn.LayerNorm):
            nn.init.ones_(module.weight)
            nn.init.zeros_(module.bias)

    def blocks(self) -> list[Block]:
        """All blocks in order (base then head): the layer index of the KV cache."""
        return [*self.trans_base.blocks, *self.trans_head.blocks]

    def forward(self, cond: torch.Tensor, tokens: torch.Tensor, length: torch.Tensor | None = None) -> torch.Tensor:
        """cond [B, Dt], tokens [B, S] int64 (S may be 0), length [B] | None -> logits [B, S+1, K+1]."""
        base = self.trans_base
        if tokens.shape[1] + 1 > self.config.block_size:
            raise ValueError(f"sequence of {tokens.shape[1]} tokens exceeds max_tokens={self.config.max_tokens}")
        x = base.condition_token(cond, length).unsqueeze(1)
        if tokens.shape[1] > 0:
            x = torch.cat([x, base.tok_emb(tokens)], dim=1)
        x = base.drop(x + base.pos_embed.table()[: x.shape[1]].unsqueeze(0))
        for block in self.blocks():
            x = block(x)
        return self.trans_head.head(self.trans_head.ln_f(x))

    def empty_cache(self, batch: int, device: torch.device | None = None) -> torch.Tensor:
        """The KV cache before step 0: [n_layer, 2, B, H, 0, hd]."""
        c = self.config
        return torch.zeros(c.n_layer, 2, batch, c.n_head, 0, c.head_dim, device=device)

    def forward_step(
        self,
        cond: torch.Tensor,
        token: torch.Tensor,
        position: int | torch.Tensor,
        length: torch.Tensor | None,
        past_kv: torch.Tensor,
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """One autoregressive step with a KV cache.

        cond [B, Dt]; token [B] int64 (the previous token, ignored at position 0); position: index of
        the token being fed (0 = condition token; an int, a 0-d or a [1] tensor); length [B] | None;
        past_kv [n_layer, 2, B, H, P, hd] with P = position. Returns (logits [B, K+1], present_kv with P+1).
        """
        base = self.trans_base
        if isinstance(position, int):
            position = torch.tensor([position], dtype=torch.long, device=cond.device)
        position = position.reshape(1).long()
        cond_x = base.condition_token(cond, length)  # [B, E]
        token_x = base.tok_emb(token.clamp(0, self.config.codebook_size + 1))  # [B, E]
        x = torch.where((position == 0).view(1, 1), cond_x, token_x)
        x = x + base.pos_embed.table().index_select(0, position)  # [1, E] broadcast over B
        x = base.drop(x).unsqueeze(1)  # [B, 1, E]
        present = []
        for index, block in enumerate(self.blocks()):
            x, k, v = block.forward_step(x, past_kv[index, 0], past_kv[index, 1])
            present.append(torch.stack([k, v]))
        logits = self.trans_head.head(self.trans_head.ln_f(x))[:, 0, :]
        return logits, torch.stack(present)

    def num_parameters(self) -> int:
        return sum(p.numel() for p in self.parameters())
