"""MDM and DiP (GuyTevet/motion-diffusion-model): a transformer that predicts the clean motion x0 from a noised one.

One module for both released architectures, with the released parameter names, so a release's state dict loads
strictly (docs: ../shared/docs/diffusion-models.md §1, §4.3):

    input_process.poseEmbedding    Linear(F -> E)                     frames -> tokens
    sequence_pos_encoder.pe        [max_len, 1, E] fixed sinusoids     one table, also saved as
                                                                       embed_timestep.sequence_pos_encoder.pe;
                                                                       recomputed on load
    embed_timestep.time_embed.{0,2} Linear(E, E), SiLU, Linear(E, E)   applied to pe[t], t the integer step
    embed_text                     Linear(Dt -> E)                     the text condition (CLIP 512, DistilBERT 768)
    seqTransEncoder.layers.{i}     post-norm encoder layers (arch trans_enc, MDM)    nn.TransformerEncoderLayer's
    seqTransDecoder.layers.{i}     post-norm decoder layers (arch trans_dec, DiP)    and ...DecoderLayer's names
    output_process.poseFinal       Linear(E -> F)

- ``trans_enc``: the condition token (time embedding + projected text feature) is prepended at position 0, the
  frames take positions 1..T, and the output drops token 0.
- ``trans_dec``: the frames (optionally after a time-embedding token, ``emb_trans_dec``) attend to a memory: one
  token (time + text) for a pooled text feature, or one token per text token (token state + time) with the text's
  padding mask.
- DiP's prefix completion: clean prefix frames are concatenated in front of the noised frames and only the noised
  frames' predictions are returned.

Frames are [B, T, F] here (the project's feature layout); the official code holds [B, F, 1, T]. The text encoder is
not part of this module: the condition enters as features (``text`` [B, Dt], or token states [B, L, Dt] with
``text_mask`` [B, L], True = a real token). The null condition of classifier-free guidance is a zero text (MDM's
``mask_cond``): zeroed features with the real mask kept, so the null token is ``embed_text.bias`` + time.
"""
from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import torch
import torch.nn.functional as F
from torch import nn

from t2m.model.networks.config import ConfigDict
from t2m.model.networks.positions import sinusoid_table
from t2m.model.networks.token_transformer import InputProcess, attention_scale, index_range

__all__ = ["MDM", "AveragedMDM", "DiffusionConfig", "released_weights"]

ARCHS = ("trans_enc", "trans_dec")
FEATURES = {"humanml": 263, "kit": 251}
TEXT_DIMS = {"clip": 512, "bert": 768}


@dataclass
class DiffusionConfig(ConfigDict):
    """Hyper-parameters of :class:`MDM`. The defaults are the released MDM (trans_enc, CLIP, 1000 steps); ff size,
    heads, dropout and activation are constants in the official code (not read from args.json), kept here as
    fields only so tests can build tiny models."""

    label = "diffusion"

    arch: str = "trans_enc"
    features: int = 263             # HumanML3D's 263-d vector (KIT: 251)
    latent_dim: int = 512
    layers: int = 8
    ff_size: int = 1024
    heads: int = 4
    dropout: float = 0.1
    activation: str = "gelu"
    text_dim: int = 512             # CLIP ViT-B/32 512; DistilBERT token states 768
    text_tokens: bool = False       # token states + mask (a cross-attention memory) instead of one pooled vector
    emb_trans_dec: bool = False     # trans_dec: a time-embedding token in front of the frames (2025 meaning)
    mask_frames: bool = False       # padded frames masked out of attention (the 2022 models attend to them)
    pos_embed_max_len: int = 5000
    diffusion_steps: int = 1000     # trained steps: 1000 (paper), 50 (MDM-50), 10 (DiP); sampled without respacing
    context_len: int = 0            # DiP: clean prefix frames per call (20)
    pred_len: int = 0               # DiP: new frames per call (40)
    cond_mask_prob: float = 0.1     # training's condition dropout; guidance needs it > 0

    def __post_init__(self) -> None:
        self._require_positive("features", "latent_dim", "layers", "ff_size", "heads", "text_dim",
                               "pos_embed_max_len", "diffusion_steps")
        if self.activation != "gelu":
            raise ValueError(f"activation must be 'gelu' (the released models' constant), got {self.activation!r}")
        if self.arch not in ARCHS:
            raise ValueError(f"arch must be one of {', '.join(ARCHS)}, got {self.arch!r}")
        if self.text_tokens and self.arch != "trans_dec":
            raise ValueError("text token states need arch trans_dec (the official code asserts it)")
        if self.latent_dim % self.heads:
            raise ValueError(f"latent_dim ({self.latent_dim}) must be divisible by heads ({self.heads})")
        if self.diffusion_steps > self.pos_embed_max_len:
            raise ValueError(f"diffusion_steps ({self.diffusion_steps}) must fit the position table "
                             f"({self.pos_embed_max_len} rows): the time embedding looks up row t")
        if self.context_len < 0 or self.pred_len < 0:
            raise ValueError("context_len and pred_len must be >= 0")

    @classmethod
    def mdm(cls, steps: int = 1000) -> DiffusionConfig:
        """The released MDM: trans_enc + CLIP; 1000 steps (paper model) or 50 (MDM-50steps)."""
        return cls(diffusion_steps=steps)

    @classmethod
    def dip(cls) -> DiffusionConfig:
        """The released DiP: trans_dec over DistilBERT token states, 10 steps, 20 prefix + 40 new frames per call."""
        return cls(arch="trans_dec", text_dim=TEXT_DIMS["bert"], text_tokens=True, mask_frames=True,
                   diffusion_steps=10, context_len=20, pred_len=40)

    @classmethod
    def from_args(cls, args: Mapping[str, Any]) -> DiffusionConfig:
        """The config of a release's args.json; a missing key takes the official parser's default. Refuses what
        this module does not build (gru, target conditioning, other schedules, FIXED_LARGE variance)."""
        dataset = args.get("dataset", "humanml")
        encoder = args.get("text_encoder_type", "clip")
        unsupported = {
            "dataset": dataset not in FEATURES,
            "arch": args.get("arch", "trans_enc") not in ARCHS,
            "text_encoder_type": encoder not in TEXT_DIMS,
            "noise_schedule": args.get("noise_schedule", "cosine") != "cosine",
            "sigma_small": not args.get("sigma_small", True),
            "multi_target_cond": bool(args.get("multi_target_cond")) or args.get("lambda_target_loc", 0) > 0,
            "unconstrained": bool(args.get("unconstrained")),
            "emb_policy": args.get("emb_policy", "add") != "add",
        }
        refused = [name for name, bad in unsupported.items() if bad]
        if refused:
            raise ValueError(f"unsupported MDM args: {', '.join(f'{n}={args.get(n)!r}' for n in refused)}")
        context = int(args.get("context_len", 0))
        return cls(arch=args.get("arch", "trans_enc"), features=FEATURES[dataset],
                   latent_dim=int(args.get("latent_dim", 512)), layers=int(args.get("layers", 8)),
                   text_dim=TEXT_DIMS[encoder], text_tokens=encoder == "bert",
                   emb_trans_dec=bool(args.get("emb_trans_dec", False)),
                   mask_frames=bool(args.get("mask_frames", False)),
                   pos_embed_max_len=int(args.get("pos_embed_max_len", 5000)),
                   diffusion_steps=int(args.get("diffusion_steps", 1000)), context_len=context,
                   pred_len=int(args.get("pred_len", 0)) or context,
                   cond_mask_prob=float(args.get("cond_mask_prob", 0.1)))


def released_weights(checkpoint: Mapping[str, Any], use_ema: bool) -> dict[str, torch.Tensor]:
    """The state dict to load from a release's model*.pt: ``model_avg`` iff args.json says use_ema (loading the
    other one changes outputs), else ``model`` or the plain dict; text-encoder keys (``clip_model.*``, also
    DistilBERT's) dropped. The pe tables are recomputed on load whatever the file holds."""
    if "model" in checkpoint and isinstance(checkpoint["model"], Mapping):
        if use_ema and "model_avg" not in checkpoint:
            raise ValueError("args.json says use_ema but the checkpoint has no 'model_avg'")
        weights = checkpoint["model_avg" if use_ema else "model"]
    elif use_ema:
        raise ValueError("args.json says use_ema but the checkpoint is a plain state dict")
    else:
        weights = checkpoint
    return {key: value for key, value in weights.items() if not key.startswith("clip_model.")}


class OutputProcess(nn.Module):
    """Tokens [B, T, E] -> frames [B, T, F]."""

    def __init__(self, features: int, latent_dim: int) -> None:
        super().__init__()
        self.poseFinal = nn.Linear(latent_dim, features)

    def forward(self, h: torch.Tensor) -> torch.Tensor:
        return self.poseFinal(h)


class PositionalEncoding(nn.Module):
    """Adds pe[0..S-1] to a sequence [B, S, E], then dropout. The table is torch's float32 sinusoids (a float64
    table differs by up to 4e-4 over 5000 rows); a loaded table is replaced by this one, as the official loader
    recomputes it."""

    pe: torch.Tensor  # buffer [max_len, 1, E] (the released shape)

    def __init__(self, latent_dim: int, dropout: float, max_len: int) -> None:
        super().__init__()
        self.dropout = nn.Dropout(dropout)
        self.register_buffer("pe", sinusoid_table(max_len, latent_dim))
        self._register_load_state_dict_pre_hook(self._keep_own_table)

    def _keep_own_table(self, state_dict: dict[str, Any], prefix: str, *args: Any, **kwargs: Any) -> None:
        state_dict[prefix + "pe"] = self.pe

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.dropout(x + self.pe[: x.shape[1], 0])


class TimestepEmbedder(nn.Module):
    """Integer steps [B] -> [B, 1, E]: the MLP of the same sinusoid table the positions use, row t."""

    def __init__(self, latent_dim: int, sequence_pos_encoder: PositionalEncoding) -> None:
        super().__init__()
        self.sequence_pos_encoder = sequence_pos_encoder
        self.time_embed = nn.Sequential(nn.Linear(latent_dim, latent_dim), nn.SiLU(),
                                        nn.Linear(latent_dim, latent_dim))

    def forward(self, timesteps: torch.Tensor) -> torch.Tensor:
        return self.time_embed(self.sequence_pos_encoder.pe[timesteps])


# The transformer layers compute what torch's nn.TransformerEncoderLayer / nn.TransformerDecoderLayer (post-norm,
# exact GELU, eval: no dropout) compute, under their parameter names (the released keys); they are written out, as
# in token_transformer.py, because torch's modules trace to ONNX graphs whose sequence length is fixed at export.


class Attention(nn.Module):
    """nn.MultiheadAttention's parameters (q/k/v packed in ``in_proj_weight`` [3E, E], rows q, k, v; ``out_proj``)
    and arithmetic, batch first: queries from x [B, S, E], keys and values from source [B, S', E]; ``keys`` [B, S']
    bool, False = may not be attended to."""

    def __init__(self, dim: int, heads: int, dropout: float) -> None:
        super().__init__()
        self.heads, self.dropout, self.scale = heads, dropout, attention_scale(dim // heads)
        self.in_proj_weight = nn.Parameter(nn.init.xavier_uniform_(torch.empty(3 * dim, dim)))
        self.in_proj_bias = nn.Parameter(torch.zeros(3 * dim))
        self.out_proj = nn.Linear(dim, dim)
        nn.init.zeros_(self.out_proj.bias)

    def _heads(self, x: torch.Tensor, weight: torch.Tensor, bias: torch.Tensor) -> torch.Tensor:
        """[B, S, E] -> projected [B, H, S, E/H]"""
        return F.linear(x, weight, bias).unflatten(-1, (self.heads, -1)).transpose(1, 2)

    def forward(self, x: torch.Tensor, source: torch.Tensor, keys: torch.Tensor | None) -> torch.Tensor:
        weights, biases = self.in_proj_weight.chunk(3), self.in_proj_bias.chunk(3)
        q = self._heads(x, weights[0], biases[0])
        k, v = self._heads(source, weights[1], biases[1]), self._heads(source, weights[2], biases[2])
        mask = None if keys is None else keys[:, None, None, :]
        y = F.scaled_dot_product_attention(q, k, v, attn_mask=mask, dropout_p=self.dropout if self.training else 0.0,
                                           scale=self.scale)
        return self.out_proj(y.transpose(1, 2).flatten(2))


class EncoderLayer(nn.Module):
    """x = norm1(x + self_attn(x)); x = norm2(x + linear2(gelu(linear1(x))))."""

    def __init__(self, dim: int, heads: int, ff_size: int, dropout: float) -> None:
        super().__init__()
        self.self_attn = Attention(dim, heads, dropout)
        self.linear1 = nn.Linear(dim, ff_size)
        self.linear2 = nn.Linear(ff_size, dim)
        self.norm1 = nn.LayerNorm(dim)
        self.norm2 = nn.LayerNorm(dim)
        self.dropout = nn.Dropout(dropout)

    def feed_forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.dropout(self.linear2(self.dropout(F.gelu(self.linear1(x)))))

    def forward(self, x: torch.Tensor, keys: torch.Tensor | None) -> torch.Tensor:
        x = self.norm1(x + self.dropout(self.self_attn(x, x, keys)))
        return self.norm2(x + self.feed_forward(x))


class DecoderLayer(EncoderLayer):
    """x = norm1(x + self_attn(x)); x = norm2(x + multihead_attn(x, memory)); x = norm3(x + feed-forward(x))."""

    def __init__(self, dim: int, heads: int, ff_size: int, dropout: float) -> None:
        super().__init__(dim, heads, ff_size, dropout)
        self.multihead_attn = Attention(dim, heads, dropout)
        self.norm3 = nn.LayerNorm(dim)

    def forward(self, x: torch.Tensor, keys: torch.Tensor | None, memory: torch.Tensor | None = None,
                memory_keys: torch.Tensor | None = None) -> torch.Tensor:
        assert memory is not None
        x = self.norm1(x + self.dropout(self.self_attn(x, x, keys)))
        x = self.norm2(x + self.dropout(self.multihead_attn(x, memory, memory_keys)))
        return self.norm3(x + self.feed_forward(x))


class TransformerStack(nn.Module):
    """``layers.{i}`` (nn.TransformerEncoder / nn.TransformerDecoder's key names; no final norm)."""

    def __init__(self, layer: type[EncoderLayer], config: DiffusionConfig) -> None:
        super().__init__()
        c = config
        self.layers = nn.ModuleList(layer(c.latent_dim, c.heads, c.ff_size, c.dropout) for _ in range(c.layers))

    def forward(self, x: torch.Tensor, keys: torch.Tensor | None, memory: torch.Tensor | None = None,
                memory_keys: torch.Tensor | None = None) -> torch.Tensor:
        for layer in self.layers:
            x = layer(x, keys) if memory is None else layer(x, keys, memory, memory_keys)
        return x


def _prepend_valid(keys: torch.Tensor | None) -> torch.Tensor | None:
    """A key mask [B, S] with one always-attendable column in front (the condition or time token)."""
    if keys is None:
        return None
    return torch.cat([torch.ones_like(keys[:, :1]), keys], dim=1)


class MDM(nn.Module):
    """The x0 predictor of MDM (trans_enc) and DiP (trans_dec); see the module docstring."""

    def __init__(self, config: DiffusionConfig) -> None:
        super().__init__()
        self.config = config
        c = config
        self.input_process = InputProcess(c.features, c.latent_dim)
        self.sequence_pos_encoder = PositionalEncoding(c.latent_dim, c.dropout, c.pos_embed_max_len)
        if c.arch == "trans_enc":
            self.seqTransEncoder = TransformerStack(EncoderLayer, c)
        else:
            self.seqTransDecoder = TransformerStack(DecoderLayer, c)
        self.embed_timestep = TimestepEmbedder(c.latent_dim, self.sequence_pos_encoder)
        self.embed_text = nn.Linear(c.text_dim, c.latent_dim)
        self.output_process = OutputProcess(c.features, c.latent_dim)

    def forward(self, x: torch.Tensor, timesteps: torch.Tensor, text: torch.Tensor,
                text_mask: torch.Tensor | None = None, length: torch.Tensor | None = None,
                prefix: torch.Tensor | None = None) -> torch.Tensor:
        """x0 [B, T, F] predicted from x_t [B, T, F] at integer steps [B].

        text: [B, Dt] (pooled) or [B, L, Dt] token states with ``text_mask`` [B, L] (True = real token); zeros for
        the null condition. length: valid frames of x per row (used when ``mask_frames``). prefix: DiP's clean
        frames [B, P, F], attended to but not returned.
        """
        frames = x.shape[1]
        if prefix is not None:
            x = torch.cat([prefix, x], dim=1)
        h = self.input_process(x)                                  # [B, S, E]
        keys = self._frame_keys(length, h.shape[1], prefix)
        time = self.embed_timestep(timesteps)                      # [B, 1, E]
        if self.config.arch == "trans_enc":
            condition = time + self.embed_text(text)[:, None]
            sequence = self.sequence_pos_encoder(torch.cat([condition, h], dim=1))
            out = self.seqTransEncoder(sequence, _prepend_valid(keys))[:, 1:]
        else:
            out = self._decode(h, time, text, text_mask, keys)
        return self.output_process(out)[:, -frames:]

    def _decode(self, h: torch.Tensor, time: torch.Tensor, text: torch.Tensor, text_mask: torch.Tensor | None,
                keys: torch.Tensor | None) -> torch.Tensor:
        """trans_dec: frames (after a time token with emb_trans_dec) attend to the text memory."""
        if self.config.text_tokens:
            if text_mask is None:
                raise ValueError("token-state text needs text_mask [B, L]")
            memory, memory_keys = self.embed_text(text) + time, text_mask.bool()      # [B, L, E]
        else:
            memory, memory_keys = time + self.embed_text(text)[:, None], None
        if self.config.emb_trans_dec:
            target = self.sequence_pos_encoder(torch.cat([time, h], dim=1))
            keys = _prepend_valid(keys)
        else:
            target = self.sequence_pos_encoder(h)
        out = self.seqTransDecoder(target, keys, memory, memory_keys)
        return out[:, 1:] if self.config.emb_trans_dec else out

    def _frame_keys(self, length: torch.Tensor | None, frames: int,
                    prefix: torch.Tensor | None = None) -> torch.Tensor | None:
        """[B, S] True up to each row's length, when the model masks frames (and, as officially, S > 1); S counts
        the prefix's frames, which are always valid (`length` counts x's frames only). The prefix's columns are
        joined to x's mask rather than added to `length`: a length plus a traced prefix size would be worked out on
        the host by onnxruntime's CUDA provider and copied to the device inside each run
        (t2m/export/graphs/capture_check.py)."""
        if not self.config.mask_frames or length is None or frames <= 1:
            return None
        if prefix is None:
            return index_range(frames, length)[None, :] < length[:, None]
        valid = index_range(frames - prefix.shape[1], length)[None, :] < length[:, None]
        return torch.cat([torch.ones_like(prefix[:, :, 0], dtype=torch.bool), valid], dim=1)


class AveragedMDM(nn.Module):
    """A model trained here (`t2m train dip`) with its EMA copy, as the 2025 official trainer keeps them
    (``{'model', 'model_avg'}`` with ``use_ema``): ``model`` is what the optimiser trains; ``model_avg`` (no
    gradients) follows it after each update, avg <- decay * avg + (1 - decay) * param over the parameters (the
    buffers are the fixed pe tables). forward is the trained model's; exports and evaluation take ``model_avg``."""

    def __init__(self, config: DiffusionConfig) -> None:
        super().__init__()
        self.config = config
        self.model = MDM(config)
        self.model_avg = MDM(config)
        self.model_avg.load_state_dict(self.model.state_dict())
        self.model_avg.requires_grad_(False)

    def forward(self, *args: Any, **kwargs: Any) -> torch.Tensor:
        return self.model(*args, **kwargs)

    @torch.no_grad()
    def update_average(self, decay: float) -> None:
        for average, parameter in zip(self.model_avg.parameters(), self.model.parameters()):
            average.lerp_(parameter, 1.0 - decay)
