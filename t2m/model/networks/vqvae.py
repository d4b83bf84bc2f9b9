"""The motion VQ-VAE: 1D convolutions over time, 2**down_t frames per code (T2M-GPT's architecture: 4; T2M-HiFiGPT: 8).

Module names mirror T2M-GPT's ``vqvae.*`` keys (without the prefix) so its released
``net_last.pth`` loads 1:1 into :class:`MotionVQVAE`:

    encoder.model = [Conv(in, W, 3), ReLU, (Conv(W, W, 4, stride 2) -> Resnet1D) x down_t, Conv(W, code_dim, 3)]
    decoder.model = [Conv(code_dim, W, 3), ReLU, (Resnet1D -> Upsample x2 -> Conv(W, W, 3)) x down_t,
                     Conv(W, W, 3), ReLU, Conv(W, feat_dim, 3)]
    quantizer.codebook  (or quantizer.layers.{i}.codebook for the residual quantiser; layers.0 only when shared)

Inputs and outputs are normalised features ``[B, T, feat_dim]`` ((x - mean) / std);
de-normalisation happens outside (in the exported decoder graph).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import TypeAlias

import torch
import torch.nn.functional as F
from torch import nn

from t2m.model.networks.config import ConfigDict
from t2m.model.networks.quantizers import EMAResetQuantizer, PlainQuantizer, ResidualQuantizer

QUANTIZERS = ("ema_reset", "plain", "residual")


@dataclass
class VQConfig(ConfigDict):
    """Hyper-parameters of :class:`MotionVQVAE`. Defaults are sized for a 2-core CPU (T2M-GPT: 512/512/512)."""

    label = "VQ"

    feat_dim: int = 263
    width: int = 256
    code_dim: int = 256
    nb_code: int = 512
    down_t: int = 2
    depth: int = 3
    dilation_growth: int = 3
    quantizer: str = "ema_reset"
    residual_layers: int = 1
    quantizer_dropout: float = 0.2
    ema_mu: float = 0.99
    shared_codebook: bool = False  # residual only: one codebook for every depth (T2M-HiFiGPT's RVQ-VAE)
    # the decoder's dilated residual convolutions see only past frames: a frame then depends on 3 codes ahead at
    # most instead of ~25 (8 frames per code), so a stream's frames are final almost as soon as their codes exist
    causal_decoder_blocks: bool = False

    def __post_init__(self) -> None:
        if self.quantizer not in QUANTIZERS:
            raise ValueError(f"quantizer must be one of {', '.join(QUANTIZERS)}, got {self.quantizer!r}")
        if self.quantizer == "residual" and self.residual_layers < 1:
            raise ValueError(f"residual_layers must be >= 1, got {self.residual_layers}")
        if self.quantizer != "residual":
            self.residual_layers = 1
            self.shared_codebook = False
        if not 0.0 <= self.quantizer_dropout <= 1.0:
            raise ValueError(f"quantizer_dropout must be in [0, 1], got {self.quantizer_dropout}")
        for name in ("feat_dim", "width", "code_dim", "nb_code", "down_t", "depth", "dilation_growth"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name} must be >= 1, got {getattr(self, name)}")

    @property
    def frames_per_token(self) -> int:
        return 2**self.down_t



class ResBlock(nn.Module):
    """x + conv2(relu(conv1(relu(x)))): a dilated k=3 conv then a k=1 conv, no normalisation.

    causal: conv1 reads frames t - 2d, t - d, t instead of t - d, t, t + d (padded by 2d both sides, the last 2d
    outputs dropped: one Conv and one Slice in ONNX, where a left-only Pad would export as a subgraph)."""

    def __init__(self, width: int, dilation: int, causal: bool = False) -> None:
        super().__init__()
        self.trim = 2 * dilation if causal else 0
        self.conv1 = nn.Conv1d(width, width, kernel_size=3, stride=1, padding=dilation + self.trim // 2,
                               dilation=dilation)
        self.conv2 = nn.Conv1d(width, width, kernel_size=1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        h = self.conv1(F.relu(x))
        if self.trim:
            h = h[..., : -self.trim]
        return x + self.conv2(F.relu(h))


class Resnet1D(nn.Module):
    """``depth`` residual blocks with dilations growth**i, largest first (9, 3, 1 for depth 3, growth 3)."""

    def __init__(self, width: int, depth: int, dilation_growth: int, causal: bool = False) -> None:
        super().__init__()
        dilations = [dilation_growth**i for i in range(depth)][::-1]
        self.model = nn.Sequential(*(ResBlock(width, d, causal) for d in dilations))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.model(x)


class Encoder(nn.Module):
    """[B, feat_dim, T] -> [B, code_dim, T / 2**down_t]."""

    def __init__(self, config: VQConfig) -> None:
        super().__init__()
        w = config.width
        layers: list[nn.Module] = [nn.Conv1d(config.feat_dim, w, 3, 1, 1), nn.ReLU()]
        for _ in range(config.down_t):
            layers.append(nn.Sequential(nn.Conv1d(w, w, 4, 2, 1), Resnet1D(w, config.depth, config.dilation_growth)))
        layers.append(nn.Conv1d(w, config.code_dim, 3, 1, 1))
        self.model = nn.Sequential(*layers)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.model(x)


class Decoder(nn.Module):
    """[B, code_dim, T'] -> [B, feat_dim, T' * 2**down_t]."""

    def __init__(self, config: VQConfig) -> None:
        super().__init__()
        w = config.width
        layers: list[nn.Module] = [nn.Conv1d(config.code_dim, w, 3, 1, 1), nn.ReLU()]
        for _ in range(config.down_t):
            layers.append(
                nn.Sequential(
                    Resnet1D(w, config.depth, config.dilation_growth, config.causal_decoder_blocks),
                    nn.Upsample(scale_factor=2, mode="nearest"),
                    nn.Conv1d(w, w, 3, 1, 1),
                )
            )
        layers += [nn.Conv1d(w, w, 3, 1, 1), nn.ReLU(), nn.Conv1d(w, config.feat_dim, 3, 1, 1)]
        self.model = nn.Sequential(*layers)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.model(x)


Quantizer: TypeAlias = EMAResetQuantizer | PlainQuantizer | ResidualQuantizer


def build_quantizer(config: VQConfig) -> Quantizer:
    if config.quantizer == "ema_reset":
        return EMAResetQuantizer(config.nb_code, config.code_dim, mu=config.ema_mu)
    if config.quantizer == "plain":
        return PlainQuantizer(config.nb_code, config.code_dim)
    return ResidualQuantizer(
        config.nb_code, config.code_dim, config.residual_layers, config.quantizer_dropout, mu=config.ema_mu,
        shared=config.shared_codebook,
    )


class MotionVQVAE(nn.Module):
    """Encoder -> quantiser -> decoder over normalised HumanML3D features."""

    def __init__(self, config: VQConfig | None = None) -> None:
        super().__init__()
        self.config = config or VQConfig()
        self.encoder = Encoder(self.config)
        self.decoder = Decoder(self.config)
        self.quantizer = build_quantizer(self.config)

    @property
    def frames_per_token(self) -> int:
        return self.config.frames_per_token

    def _check_input(self, x: torch.Tensor) -> None:
        if x.dim() != 3 or x.shape[-1] != self.config.feat_dim:
            raise ValueError(f"motion features must be [B, T, {self.config.feat_dim}], got {list(x.shape)}")
        if x.shape[1] < self.frames_per_token:
            raise ValueError(f"motion needs at least {self.frames_per_token} frames, got {x.shape[1]}")

    def encode_latent(self, x: torch.Tensor) -> torch.Tensor:
        """[B, T, feat_dim] -> pre-quantisation latent [B, T // frames_per_token, code_dim]."""
        self._check_input(x)
        return self.encoder(x.transpose(1, 2)).transpose(1, 2)

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
        """Reconstruct [B, T, feat_dim] (T a multiple of frames_per_token).

        Returns (recon, {"commit", "perplexity", "codes"})."""
        self._check_input(x)
        if x.shape[1] % self.frames_per_token:
            raise ValueError(f"training windows must be a multiple of {self.frames_per_token} frames, got {x.shape[1]}")
        quantized, codes, commit, perplexity = self.quantizer(self.encode_latent(x))
        recon = self.decoder(quantized.transpose(1, 2)).transpose(1, 2)
        return recon, {"commit": commit, "perplexity": perplexity, "codes": codes}

    @torch.no_grad()
    def encode(self, x: torch.Tensor) -> torch.Tensor:
        """[B, T, feat_dim] -> codes [B, T // fpt] (or [B, T // fpt, R] for the residual quantiser), no EMA update."""
        was_training = self.training
        self.eval()
        try:
            _, codes, _, _ = self.quantizer(self.encode_latent(x))
        finally:
            self.train(was_training)
        return codes

    def decode(self, codes: torch.Tensor) -> torch.Tensor:
        """codes [B, T] (or [B, T, R]; -1 = layer unused) int64 -> normalised features [B, fpt T, feat_dim]."""
        latent = self.quantizer.codes_to_latent(codes)
        return self.decoder(latent.transpose(1, 2)).transpose(1, 2)
