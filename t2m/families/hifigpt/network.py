"""T2M-HiFiGPT's double-tier GPT over residual VQ codes (nanoGPT style; the paper: ../shared/papers/t2m-hifigpt.txt).

A motion is a code map S [T, R]: T time steps (8 frames each in the paper) x R residual depths. Two causal
transformers share the work:

- the **temporal GPT** reads position 0 = the condition token (text feature, + a length embedding like the GPT
  family's), position t = u_t = W_t (sum_d C_d[S_t,d]) + PET(t): the quantised latent of step t (the VQ's own
  codebooks, summed over depth as the decoder sums them, then projected) plus a learned time position. Its output
  h_p summarises the text and steps 1..p: h_{t-1} is the context F_t that starts step t, and a stop head
  sigmoid(Linear(LayerNorm(h_p))) says whether the motion ends after p steps (never after 0).
- the **residual GPT** runs R positions per step: position 0 = F_t, position d = W_r C_{d-1}[S_t,d-1] for d >= 1,
  each + a learned depth position PER(d) shared over time; its output at position d predicts S_t,d (one head over
  the K codes for every depth).

The codebooks are a frozen copy of the VQ's ([R, K, D], or [1, K, D] for the shared codebook of the paper's
RVQ-VAE), so the GPT's inputs live in the space the decoder reads; only the projections are learned.
`forward` runs both tiers over whole sequences (training); `temporal_step` and `residual_step` are the same maths one
position at a time with a key/value cache each (sampling and the ONNX step graphs, no Python control flow on tensor
values). The transformer blocks are the GPT family's (`t2m.families.gpt.network.Block`).
"""
from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import nn

from t2m.families.gpt.network import Block, GPTConfig, MotionGPT
from t2m.model.networks.config import ConfigDict


@dataclass
class HiFiGPTConfig(ConfigDict):
    """Hyper-parameters of :class:`HiFiGPT` (the paper: K 256, E 512, 16 heads, 9 + 9 layers, CLIP text 512)."""

    label = "HiFiGPT"

    codebook_size: int = 256
    depth: int = 6                       # residual depth R of the VQ
    code_dim: int = 256                  # the VQ's code_dim
    shared_codebook: bool = False        # the VQ has one codebook for every depth
    embed: int = 384
    n_head: int = 6
    n_layer_temporal: int = 3
    n_layer_residual: int = 3
    max_tokens: int = 25                 # time steps (25 x 8 frames = 10 s at 20 fps)
    text_dim: int = 384
    dropout: float = 0.1
    ff_rate: int = 4
    length_conditioning: bool = True

    def __post_init__(self) -> None:
        self._require_positive("codebook_size", "depth", "code_dim", "embed", "n_head", "n_layer_temporal",
                               "n_layer_residual", "max_tokens", "text_dim", "ff_rate")
        if self.embed % self.n_head:
            raise ValueError(f"embed ({self.embed}) must be divisible by n_head ({self.n_head})")

    @property
    def head_dim(self) -> int:
        return self.embed // self.n_head

    @property
    def block_size(self) -> int:
        """Temporal positions: the condition token and max_tokens steps."""
        return self.max_tokens + 1

    @property
    def books(self) -> int:
        return 1 if self.shared_codebook else self.depth

    def tier(self, layers: int, positions: int) -> GPTConfig:
        """The GPT family's block settings for one tier."""
        return GPTConfig(codebook_size=self.codebook_size, embed=self.embed, n_head=self.n_head,
                         n_layer_base=layers, n_layer_head=0, block_size=max(positions, 2), dropout=self.dropout,
                         text_dim=self.text_dim, ff_rate=self.ff_rate, length_conditioning=self.length_conditioning)


def step_position(position: int | torch.Tensor, device: torch.device) -> torch.Tensor:
    """An int, 0-d or [1] position as a [1] int64 tensor (what the step graphs take)."""
    if isinstance(position, int):
        return torch.tensor([position], dtype=torch.long, device=device)
    return position.reshape(1).long()


class HiFiGPT(nn.Module):
    """Text (and optional length) conditioned double-tier GPT over code maps [B, T, R]."""

    codebooks: torch.Tensor  # buffer [books, K, D]: the VQ's codebooks, frozen

    def __init__(self, config: HiFiGPTConfig | None = None) -> None:
        super().__init__()
        c = self.config = config or HiFiGPTConfig()
        self.register_buffer("codebooks", torch.randn(c.books, c.codebook_size, c.code_dim) / c.code_dim**0.5)
        # temporal tier
        self.cond_emb = nn.Linear(c.text_dim, c.embed)
        if c.length_conditioning:
            self.len_emb = nn.Embedding(c.max_tokens + 1, c.embed)  # 0 = free length
        self.latent_proj = nn.Linear(c.code_dim, c.embed)
        self.time_emb = nn.Embedding(c.block_size, c.embed)
        temporal = c.tier(c.n_layer_temporal, c.block_size)
        self.temporal_blocks = nn.ModuleList(Block(temporal) for _ in range(c.n_layer_temporal))
        self.stop_ln = nn.LayerNorm(c.embed)
        self.stop_head = nn.Linear(c.embed, 1)
        # residual tier
        self.code_proj = nn.Linear(c.code_dim, c.embed)
        self.depth_emb = nn.Embedding(c.depth, c.embed)
        residual = c.tier(c.n_layer_residual, c.depth)
        self.residual_blocks = nn.ModuleList(Block(residual) for _ in range(c.n_layer_residual))
        self.ln_f = nn.LayerNorm(c.embed)
        self.head = nn.Linear(c.embed, c.codebook_size, bias=False)
        self.drop = nn.Dropout(c.dropout)
        self.apply(MotionGPT._init_weights)

    @torch.no_grad()
    def set_codebooks(self, codebooks: torch.Tensor) -> None:
        """Copy the VQ's codebooks [books, K, D] (ResidualQuantizer.codebooks()) in."""
        if codebooks.shape != self.codebooks.shape:
            raise ValueError(f"codebooks must be {list(self.codebooks.shape)}, got {list(codebooks.shape)}")
        self.codebooks.copy_(codebooks)

    # ------------------------------------------------------------------------------------------- embeddings

    def _vectors(self, codes: torch.Tensor, depth: torch.Tensor) -> torch.Tensor:
        """Codebook vectors of codes [...] at depths [...] (broadcast); -1 (unused / padding) gives zeros."""
        c = self.config
        book = depth.clamp(max=c.books - 1)
        flat = self.codebooks.reshape(c.books * c.codebook_size, c.code_dim)
        vectors = flat[book * c.codebook_size + codes.clamp(min=0)]
        return vectors * (codes >= 0).unsqueeze(-1).to(vectors.dtype)

    def latent(self, codes: torch.Tensor) -> torch.Tensor:
        """Code rows [..., R] -> their quantised latent [..., D] (sum over depth, as the decoder reads it)."""
        depths = torch.arange(self.config.depth, device=codes.device)
        return self._vectors(codes, depths).sum(dim=-2)

    def condition_token(self, cond: torch.Tensor, length: torch.Tensor | None) -> torch.Tensor:
        """[B, Dt] (+ lengths [B], 0 = free) -> [B, E]"""
        x = self.cond_emb(cond)
        if self.config.length_conditioning:
            if length is None:
                length = torch.zeros(cond.shape[0], dtype=torch.long, device=cond.device)
            x = x + self.len_emb(length.clamp(0, self.config.max_tokens))
        return x

    # ------------------------------------------------------------------------------------------- training

    def forward(self, cond: torch.Tensor, codes: torch.Tensor, length: torch.Tensor | None = None,
                history: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor]:
        """cond [B, Dt], codes [B, T, R] int64 (-1 past a motion's end), length [B] | None, history: the codes the
        temporal GPT reads (default `codes`; training passes a corrupted copy). Returns (code logits [B, T, R, K]
        where [b, t, d] predicts codes[b, t, d], stop logits [B, T + 1] where [b, p] = "the motion ends after p
        steps")."""
        c = self.config
        batch, steps, depth = codes.shape
        if depth != c.depth:
            raise ValueError(f"codes must have {c.depth} depths, got {depth}")
        if steps > c.max_tokens:
            raise ValueError(f"{steps} time steps exceed max_tokens={c.max_tokens}")
        history = codes if history is None else history
        x = torch.cat([self.condition_token(cond, length).unsqueeze(1),
                       self.latent_proj(self.latent(history))], dim=1)
        x = self.drop(x + self.time_emb.weight[: steps + 1])
        for block in self.temporal_blocks:
            x = block(x)
        stop = self.stop_head(self.stop_ln(x))[..., 0]
        # residual tier: one R-position sequence per (motion, step), started by that step's context h_{t-1}
        context = x[:, :steps].reshape(batch * steps, 1, c.embed)
        depths = torch.arange(depth - 1, device=codes.device)
        inner = self.code_proj(self._vectors(codes[..., :-1], depths)).reshape(batch * steps, depth - 1, c.embed)
        y = self.drop(torch.cat([context, inner], dim=1) + self.depth_emb.weight)
        for block in self.residual_blocks:
            y = block(y)
        logits = self.head(self.ln_f(y))
        return logits.view(batch, steps, depth, c.codebook_size), stop

    # ------------------------------------------------------------------------------------------- sampling

    def empty_cache(self, tier: str, batch: int, device: torch.device | None = None) -> torch.Tensor:
        """A tier's ("temporal" | "residual") KV cache before its first position: [n_layer, 2, B, H, 0, hd]."""
        c = self.config
        layers = c.n_layer_temporal if tier == "temporal" else c.n_layer_residual
        return torch.zeros(layers, 2, batch, c.n_head, 0, c.head_dim, device=device)

    @staticmethod
    def _step_blocks(blocks: nn.ModuleList, x: torch.Tensor, past: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        present = []
        for index, block in enumerate(blocks):
            assert isinstance(block, Block)
            x, k, v = block.forward_step(x, past[index, 0], past[index, 1])
            present.append(torch.stack([k, v]))
        return x, torch.stack(present)

    def temporal_step(self, cond: torch.Tensor, codes: torch.Tensor, position: int | torch.Tensor,
                      length: torch.Tensor | None, past: torch.Tensor
                      ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """One temporal position. cond [B, Dt]; codes [B, R]: step `position`'s codes (ignored at position 0, the
        condition token); past [n_layer_t, 2, B, H, position, hd]. Returns (context h_position [B, E], stop logit
        [B], present)."""
        position = step_position(position, cond.device)
        step_x = self.latent_proj(self.latent(codes))
        x = torch.where((position == 0).view(1, 1), self.condition_token(cond, length), step_x)
        x = self.drop(x + self.time_emb(position)).unsqueeze(1)
        x, present = self._step_blocks(self.temporal_blocks, x, past)
        context = x[:, 0]
        return context, self.stop_head(self.stop_ln(context))[:, 0], present

    def residual_step(self, context: torch.Tensor, code: torch.Tensor, depth: int | torch.Tensor,
                      past: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """One residual position. context [B, E] (the step's F, read at depth 0); code [B]: the code of depth - 1
        (ignored at depth 0); past [n_layer_r, 2, B, H, depth, hd]. Returns (logits [B, K] for code `depth`,
        present)."""
        depth = step_position(depth, context.device)
        code_x = self.code_proj(self._vectors(code, (depth - 1).clamp(min=0)))
        x = torch.where((depth == 0).view(1, 1), context, code_x)
        x = self.drop(x + self.depth_emb(depth)).unsqueeze(1)
        x, present = self._step_blocks(self.residual_blocks, x, past)
        return self.head(self.ln_f(x))[:, 0], present

    def num_parameters(self) -> int:
        return sum(p.numel() for p in self.parameters())


def vq_fields(vq_config: dict) -> dict:
    """The HiFiGPTConfig fields a VQ fixes (from its config dict): codebook size, depth, code_dim, shared codebook."""
    residual = vq_config.get("quantizer") == "residual"
    return {"codebook_size": int(vq_config["nb_code"]), "code_dim": int(vq_config["code_dim"]),
            "depth": int(vq_config.get("residual_layers", 1)) if residual else 1,
            "shared_codebook": bool(vq_config.get("shared_codebook", False)) and residual}


def check_fits_vq(config: HiFiGPTConfig, vq_config: dict, names: tuple[str, str] = ("the HiFiGPT", "the VQ")) -> None:
    """Refuse a VQ whose codebook size, depth, code_dim or codebook sharing differ from what the GPT was built for."""
    fields = vq_fields(vq_config)
    mine = {key: getattr(config, key) for key in fields}
    if mine != fields:
        raise ValueError(f"{names[0]} was built for a VQ with {mine}, {names[1]} has {fields}")


def vq_codebooks(vq: nn.Module) -> torch.Tensor:
    """A MotionVQVAE's codebooks as HiFiGPT.codebooks holds them: [books, K, D] (a single-layer VQ: [1, K, D])."""
    from t2m.model.networks.quantizers import ResidualQuantizer

    quantizer = getattr(vq, "quantizer", None)
    if isinstance(quantizer, ResidualQuantizer):
        return quantizer.codebooks().detach().clone()
    codebook = getattr(quantizer, "codebook", None)
    if not isinstance(codebook, torch.Tensor):
        raise ValueError(f"{type(vq).__name__} has no codebook HiFiGPT can read")
    return codebook.detach().clone()[None]
