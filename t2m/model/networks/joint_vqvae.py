"""The 2D joint VQ-VAE (MoGenTS): 2D convolutions over (time, joint), a residual quantiser per token of the map.

The 263 features of a frame become a [J, 12] joint map (t2m.model.networks.joint_layout); a motion [T, J, 12] is an
image with 12 channels, time as height and joints as width. The joint axis is zero-padded to a multiple of
2**down_j (22 -> 24 = 1 + 22 + 1 for down_j = 2; KIT 21 -> 24 = 1 + 21 + 2, as MoGenTS pads). Each downsampling
block halves time and, for the first ``down_j`` blocks, the joints too:

    encoder2d.model = [Conv(12, W, 3), ReLU, (Conv(W, W, 4, stride 2) -> Resnet2D) x down_t, Conv(W, code_dim, 3)]
    decoder2d.model = [Conv(code_dim, W, 3), ReLU, (Resnet2D -> Upsample -> Conv(W, W, 3)) x down_t,
                       Conv(W, W, 3), ReLU, Conv(W, 12, 3)]
    quantizer2d.layers.{i}.codebook      (t2m.model.networks.quantizers.ResidualQuantizer: EMA, dead-code reset,
                                          quantiser dropout; every column of the map shares the codebooks)

Names follow MoGenTS's ``encoder2d / decoder2d / quantizer2d`` keys. Its release adds a 1D branch for the root and
a fusion layer; here the root and foot contacts travel in the root joint's slots of the map, so one model codes the
whole vector (and the map round-trips exactly). Codes are [B, T / 4, C, R]: C = ceil(J / 2**down_j) columns.
The interface is MotionVQVAE's (forward / encode / decode on normalised [B, T, D] features), so train_vq's loss
and validation apply unchanged.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import torch
import torch.nn.functional as F
from torch import nn

from t2m.model.networks.config import ConfigDict
from t2m.model.networks.joint_layout import PER_JOINT, features_to_joint_map, joint_map_to_features, joints_for_dim
from t2m.model.networks.quantizers import ResidualQuantizer


@dataclass
class JointVQConfig(ConfigDict):
    """Hyper-parameters of :class:`JointVQVAE` (MoGenTS's release: W 512, code_dim 1024, 256 codes, 6 layers)."""

    label = "joint VQ"
    quantizer: ClassVar[str] = "residual"  # always (read as VQConfig.quantizer by code that handles both VQs)

    feat_dim: int = 263
    width: int = 64
    code_dim: int = 128
    nb_code: int = 256
    down_t: int = 2
    down_j: int = 2
    depth: int = 3
    dilation_growth: int = 3
    residual_layers: int = 4
    quantizer_dropout: float = 0.2
    ema_mu: float = 0.99

    def __post_init__(self) -> None:
        joints_for_dim(self.feat_dim)
        self._require_positive("width", "code_dim", "nb_code", "down_t", "depth", "dilation_growth",
                               "residual_layers")
        if not 0 <= self.down_j <= self.down_t:
            raise ValueError(f"down_j must be in [0, down_t={self.down_t}], got {self.down_j}")
        if not 0.0 <= self.quantizer_dropout <= 1.0:
            raise ValueError(f"quantizer_dropout must be in [0, 1], got {self.quantizer_dropout}")

    @property
    def frames_per_token(self) -> int:
        return 2**self.down_t

    @property
    def joints(self) -> int:
        return joints_for_dim(self.feat_dim)

    @property
    def joint_padding(self) -> tuple[int, int]:
        """(before, after) zero joints that make the joint axis a multiple of 2**down_j."""
        step = 2**self.down_j
        total = -self.joints % step
        return total // 2, total - total // 2

    @property
    def columns(self) -> int:
        """Tokens per frame of the code map."""
        return (self.joints + sum(self.joint_padding)) // 2**self.down_j


class ResBlock2d(nn.Module):
    """x + conv2(relu(conv1(relu(x)))): a dilated 3x3 conv (both axes) then a 1x1 conv."""

    def __init__(self, width: int, dilation: int) -> None:
        super().__init__()
        self.conv1 = nn.Conv2d(width, width, 3, padding=dilation, dilation=dilation)
        self.conv2 = nn.Conv2d(width, width, 1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return x + self.conv2(F.relu(self.conv1(F.relu(x))))


class Stack(nn.Module):
    """Layers in sequence, kept under the name ``model`` as in the released key layout (``encoder2d.model.0``)."""

    def __init__(self, layers: list[nn.Module]) -> None:
        super().__init__()
        self.model = nn.Sequential(*layers)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.model(x)


def resnet2d(config: JointVQConfig) -> Stack:
    """``depth`` residual blocks, dilations largest first (9, 3, 1)."""
    return Stack([ResBlock2d(config.width, config.dilation_growth**i) for i in reversed(range(config.depth))])


def _halves_joints(config: JointVQConfig, block: int, decoder: bool) -> bool:
    """The encoder halves joints in its first down_j blocks; the decoder restores them in its last down_j."""
    return block >= config.down_t - config.down_j if decoder else block < config.down_j


def encoder2d(config: JointVQConfig) -> Stack:
    """[B, 12, T, J'] -> [B, code_dim, T / 2**down_t, J' / 2**down_j]."""
    w = config.width
    layers: list[nn.Module] = [nn.Conv2d(PER_JOINT, w, 3, 1, 1), nn.ReLU()]
    for block in range(config.down_t):
        # kernel 4 stride 2 halves an axis; kernel 3 stride 1 keeps it (padding 1 either way)
        halve = _halves_joints(config, block, decoder=False)
        down = nn.Conv2d(w, w, (4, 4 if halve else 3), (2, 2 if halve else 1), 1)
        layers.append(nn.Sequential(down, resnet2d(config)))
    layers.append(nn.Conv2d(w, config.code_dim, 3, 1, 1))
    return Stack(layers)


def decoder2d(config: JointVQConfig) -> Stack:
    """[B, code_dim, T', C] -> [B, 12, T' * 2**down_t, C * 2**down_j]."""
    w = config.width
    layers: list[nn.Module] = [nn.Conv2d(config.code_dim, w, 3, 1, 1), nn.ReLU()]
    for block in range(config.down_t):
        joint_scale = 2.0 if _halves_joints(config, block, decoder=True) else 1.0
        layers.append(nn.Sequential(
            resnet2d(config),
            nn.Upsample(scale_factor=(2.0, joint_scale), mode="nearest"),
            nn.Conv2d(w, w, 3, 1, 1),
        ))
    layers += [nn.Conv2d(w, w, 3, 1, 1), nn.ReLU(), nn.Conv2d(w, PER_JOINT, 3, 1, 1)]
    return Stack(layers)


class JointVQVAE(nn.Module):
    """Normalised features [B, T, D] <-> a map of residual codes [B, T / 4, C, R]."""

    def __init__(self, config: JointVQConfig | None = None) -> None:
        super().__init__()
        self.config = config or JointVQConfig()
        c = self.config
        self.encoder2d = encoder2d(c)
        self.decoder2d = decoder2d(c)
        self.quantizer2d = ResidualQuantizer(c.nb_code, c.code_dim, c.residual_layers, c.quantizer_dropout, c.ema_mu)

    @property
    def frames_per_token(self) -> int:
        return self.config.frames_per_token

    def _check_input(self, x: torch.Tensor) -> None:
        if x.dim() != 3 or x.shape[-1] != self.config.feat_dim:
            raise ValueError(f"motion features must be [B, T, {self.config.feat_dim}], got {list(x.shape)}")
        if x.shape[1] < self.frames_per_token:
            raise ValueError(f"motion needs at least {self.frames_per_token} frames, got {x.shape[1]}")

    def _to_image(self, x: torch.Tensor) -> torch.Tensor:
        """[B, T, D] -> [B, 12, T, J + padding]"""
        before, after = self.config.joint_padding
        joint_map = F.pad(features_to_joint_map(x), (0, 0, before, after))  # pad the joint axis
        return joint_map.permute(0, 3, 1, 2)

    def _from_image(self, image: torch.Tensor) -> torch.Tensor:
        """[B, 12, T, J + padding] -> [B, T, D]"""
        before = self.config.joint_padding[0]
        joint_map = image.permute(0, 2, 3, 1)[:, :, before : before + self.config.joints]
        return joint_map_to_features(joint_map)

    def encode_latent(self, x: torch.Tensor) -> torch.Tensor:
        """[B, T, D] -> pre-quantisation latent [B, T // 4, C, code_dim]."""
        self._check_input(x)
        return self.encoder2d(self._to_image(x)).permute(0, 2, 3, 1)

    def _quantize(self, latent: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
        """Every (time, column) position is one token: the quantiser sees [B, T' * C, code_dim]."""
        batch, time, columns, dim = latent.shape
        quantized, codes, loss, perplexity = self.quantizer2d(latent.reshape(batch, time * columns, dim))
        return quantized.view(batch, time, columns, dim), codes.view(batch, time, columns, -1), loss, perplexity

    def _decode_latent(self, latent: torch.Tensor) -> torch.Tensor:
        return self._from_image(self.decoder2d(latent.permute(0, 3, 1, 2)))

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
        """Reconstruct [B, T, D] (T a multiple of 4). Returns (recon, {"commit", "perplexity", "codes"}).

        ``codes`` here is the map flattened time-major to [B, T' * C, R], the shape train_vq's metrics read."""
        self._check_input(x)
        if x.shape[1] % self.frames_per_token:
            raise ValueError(f"training windows must be a multiple of {self.frames_per_token} frames, got {x.shape[1]}")
        quantized, codes, commit, perplexity = self._quantize(self.encode_latent(x))
        recon = self._decode_latent(quantized)
        return recon, {"commit": commit, "perplexity": perplexity, "codes": codes.flatten(1, 2)}

    @torch.no_grad()
    def encode(self, x: torch.Tensor) -> torch.Tensor:
        """[B, T, D] -> codes [B, T // 4, C, R] (eval mode: nearest codes, no EMA update, all layers)."""
        was_training = self.training
        self.eval()
        try:
            codes = self._quantize(self.encode_latent(x))[1]
        finally:
            self.train(was_training)
        return codes

    def decode(self, codes: torch.Tensor) -> torch.Tensor:
        """codes [B, T', C, R'] (R' <= R first layers; -1 = layer unused) or [B, T', C] -> features [B, 4 T', D]."""
        if codes.dim() == 3:
            codes = codes.unsqueeze(-1)
        batch, time, columns, layers = codes.shape
        if columns != self.config.columns:
            raise ValueError(f"code map must have {self.config.columns} columns, got {columns}")
        latent = self.quantizer2d.codes_to_latent(codes.reshape(batch, time * columns, layers))
        return self._decode_latent(latent.view(batch, time, columns, -1))
