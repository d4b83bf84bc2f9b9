"""MoGenTS's released VQ-VAE (facts §2.1-2.2): a 1D RVQ-VAE and a 2D joint VQ side by side, fused per frame.

Decoding needs both token sets of a motion: the 1D map [B, T, R] (MoMask's RVQ-VAE, ``encoder1d / decoder1d /
quantizer1d``) and the 2D map [B, T, C, R] (C = 6 joint columns, ``encoder2d / decoder2d / quantizer2d``). The 2D
latent of a time step, its C columns concatenated (column-major: index = column * code_dim + channel), passes
``linear_merge`` before the 2D decoder; the decoder's joint map, cropped to the real joints, becomes a feature vector
the way MoGenTS assembles its "jmotion" (joint 0's slots carry root and foot contacts: exactly
t2m.model.networks.joint_layout's map); ``linear_out`` maps [1D output, jmotion] (2 D) to D per frame.

Only the decoding path is computed here (generation needs nothing else); the encoders are held so the release's
state dict loads strictly. Our masked family carries the two maps as one [B, T, C + 1, R] map (2D columns first,
then the 1D tokens as one more column), the shape the bundle's decoder graph takes.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import torch
from torch import nn

from t2m.model.networks.config import ConfigDict
from t2m.model.networks.joint_layout import joint_map_to_features
from t2m.model.networks.joint_vqvae import JointVQConfig, decoder2d, encoder2d
from t2m.model.networks.quantizers import ResidualQuantizer
from t2m.model.networks.vqvae import Decoder, Encoder, VQConfig


@dataclass
class FusedVQConfig(ConfigDict):
    """Sizes of :class:`FusedVQVAE` (MoGenTS's release: width 512, 2D 256 x 1024, 1D 512 x 512, 6 layers)."""

    label = "fused VQ"
    quantizer: ClassVar[str] = "residual"

    feat_dim: int = 263
    width: int = 64
    code_dim: int = 128     # 2D codes (the primary map's)
    nb_code: int = 256
    code_dim1d: int = 64
    nb_code1d: int = 128
    down_t: int = 2
    down_j: int = 2
    depth: int = 3
    dilation_growth: int = 3
    residual_layers: int = 6

    def __post_init__(self) -> None:
        self.joint_config()  # the 2D branch's checks
        self._require_positive("code_dim1d", "nb_code1d")

    def joint_config(self) -> JointVQConfig:
        return JointVQConfig(feat_dim=self.feat_dim, width=self.width, code_dim=self.code_dim, nb_code=self.nb_code,
                             down_t=self.down_t, down_j=self.down_j, depth=self.depth,
                             dilation_growth=self.dilation_growth, residual_layers=self.residual_layers)

    def motion_config(self) -> VQConfig:
        return VQConfig(feat_dim=self.feat_dim, width=self.width, code_dim=self.code_dim1d, nb_code=self.nb_code1d,
                        down_t=self.down_t, depth=self.depth, dilation_growth=self.dilation_growth,
                        quantizer="residual", residual_layers=self.residual_layers)

    @property
    def frames_per_token(self) -> int:
        return 2**self.down_t

    @property
    def columns(self) -> int:
        """2D columns of the code map (the decoder's input adds one column for the 1D tokens)."""
        return self.joint_config().columns


class FusedVQVAE(nn.Module):
    """codes [B, T, C + 1, R] (columns 0..C-1: the 2D map; column C: the 1D tokens; -1 = layer unused) ->
    normalised features [B, 4T, D]."""

    def __init__(self, config: FusedVQConfig | None = None) -> None:
        super().__init__()
        self.config = c = config or FusedVQConfig()
        joint, motion = c.joint_config(), c.motion_config()
        self.encoder1d = Encoder(motion)
        self.decoder1d = Decoder(motion)
        self.quantizer1d = ResidualQuantizer(c.nb_code1d, c.code_dim1d, c.residual_layers)
        self.encoder2d = encoder2d(joint)
        self.linear_merge = nn.Linear(joint.columns * c.code_dim, joint.columns * c.code_dim)
        self.decoder2d = decoder2d(joint)
        self.linear_out = nn.Linear(2 * c.feat_dim, c.feat_dim)
        self.quantizer2d = ResidualQuantizer(c.nb_code, c.code_dim, c.residual_layers)
        self._joint = joint

    @property
    def frames_per_token(self) -> int:
        return self.config.frames_per_token

    def decode_1d(self, codes: torch.Tensor) -> torch.Tensor:
        """[B, T, R] -> [B, 4T, D]: MoMask's RVQ decode."""
        latent = self.quantizer1d.codes_to_latent(codes)
        return self.decoder1d(latent.transpose(1, 2)).transpose(1, 2)

    def joint_motion(self, codes: torch.Tensor) -> torch.Tensor:
        """[B, T, C, R] -> the 2D branch's features [B, 4T, D] (MoGenTS's jmotion)."""
        batch, time, columns, layers = codes.shape
        latent = self.quantizer2d.codes_to_latent(codes.reshape(batch, time * columns, layers))
        merged = self.linear_merge(latent.reshape(batch, time, columns * self.config.code_dim))
        image = merged.view(batch, time, columns, self.config.code_dim).permute(0, 3, 1, 2)  # [B, code_dim, T, C]
        joints = self.decoder2d(image).permute(0, 2, 3, 1)  # [B, 4T, J + padding, 12]
        before = self._joint.joint_padding[0]
        return joint_map_to_features(joints[:, :, before : before + self._joint.joints])

    def decode(self, codes: torch.Tensor) -> torch.Tensor:
        """codes [B, T, C + 1, R] -> normalised features [B, 4T, D]."""
        columns = self.config.columns
        if codes.dim() != 4 or codes.shape[2] != columns + 1:
            raise ValueError(f"codes must be [B, T, {columns} + 1, R], got {list(codes.shape)}")
        fused = torch.cat([self.decode_1d(codes[:, :, columns]), self.joint_motion(codes[:, :, :columns])], dim=-1)
        return self.linear_out(fused)


__all__ = ["FusedVQConfig", "FusedVQVAE"]
