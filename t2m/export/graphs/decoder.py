"""decoder.onnx: codes -> codebook lookup -> VQ decoder -> x * std + mean -> features [B, 4T, D].

The service never sees normalised features: de-normalisation is part of the graph, with the
mean/std of the training data baked in (the bundle also carries them as mean.npy/std.npy).
For a residual VQ the input is [B, T, R] and the layers' codebook vectors are summed inside;
a code of -1 means "layer not used" and contributes nothing (a sampler that only has the first
layer's codes can pass -1 for the others).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import torch
from torch import nn

from t2m.export.graphs.export import export_graph
from t2m.model.networks.fused_vqvae import FusedVQVAE
from t2m.model.networks.joint_vqvae import JointVQVAE
from t2m.model.networks.vqvae import MotionVQVAE


class DecoderGraph(nn.Module):
    """Wraps a MotionVQVAE's decoding path with the de-normalisation, for export."""

    # buffers: the training data's statistics
    mean: torch.Tensor
    std: torch.Tensor

    def __init__(self, vq: MotionVQVAE | JointVQVAE | FusedVQVAE, mean: np.ndarray, std: np.ndarray) -> None:
        super().__init__()
        feat_dim = vq.config.feat_dim
        mean_t = torch.as_tensor(np.asarray(mean, dtype=np.float32))
        std_t = torch.as_tensor(np.asarray(std, dtype=np.float32))
        if mean_t.shape != (feat_dim,) or std_t.shape != (feat_dim,):
            raise ValueError(
                f"mean/std must be [{feat_dim}] to match the VQ's feat_dim, "
                f"got {list(mean_t.shape)}/{list(std_t.shape)}"
            )
        self.vq = vq
        self.register_buffer("mean", mean_t)
        self.register_buffer("std", std_t)

    def _motion_vq(self) -> MotionVQVAE:
        """The 1D VQ whose quantiser and decoder this graph's own path uses (JointDecoderGraph has its own)."""
        if not isinstance(self.vq, MotionVQVAE):
            raise TypeError(f"DecoderGraph decodes a MotionVQVAE, got {type(self.vq).__name__}")
        return self.vq

    def latent(self, codes: torch.Tensor) -> torch.Tensor:
        """The quantiser's own decoding path (residual: every depth's vectors summed, -1 contributing zeros)."""
        return self._motion_vq().quantizer.codes_to_latent(codes)

    def forward(self, codes: torch.Tensor) -> torch.Tensor:
        latent = self.latent(codes)
        features = self._motion_vq().decoder(latent.transpose(1, 2)).transpose(1, 2)
        return features * self.std + self.mean


def example_codes(vq: MotionVQVAE, batch: int = 2, tokens: int = 5) -> torch.Tensor:
    generator = torch.Generator().manual_seed(0)
    shape = (batch, tokens) if vq.config.quantizer != "residual" else (batch, tokens, vq.config.residual_layers)
    return torch.randint(0, vq.config.nb_code, shape, generator=generator)


def export_decoder(vq: MotionVQVAE, mean: np.ndarray, std: np.ndarray, path: str | Path) -> Path:
    """Write decoder.onnx (input ``codes`` [B, T] or [B, T, R], output ``features`` [B, 4T, D]; B and T dynamic)."""
    graph = DecoderGraph(vq, mean, std).eval()
    return export_graph(
        graph,
        (example_codes(vq),),
        path,
        input_names=["codes"],
        output_names=["features"],
        dynamic_axes={"codes": {0: "batch", 1: "tokens"}, "features": {0: "batch", 1: "frames"}},
    )
