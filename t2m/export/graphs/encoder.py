"""encoder.onnx: normalised features [B, frames, D] -> the VQ's encoder -> nearest codes, in the decoder's layout.

The service encodes a motion a user uploads to POST /edit with it, so the codes must be exactly what the bundle's
decoder reads: [B, T] for a one-layer 1D VQ (T2M-GPT), [B, T, R] for a residual one (every depth, the greedy chain of
`ResidualQuantizer`), [B, T, C, R] for the masked family's maps (a joint VQ's token map; a 1D VQ's codes as a
one-column map). T = frames // frames_per_token (the service gives whole code steps). The graph is the PyTorch
VQ's `encode` traced in eval mode (no EMA update, no quantiser dropout), so its codes are `encode`'s.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn

from t2m.export.graphs.export import export_graph, ort_session
from t2m.model.networks.joint_vqvae import JointVQVAE
from t2m.model.networks.vqvae import MotionVQVAE

__all__ = ["ENCODER_FILE", "EncoderGraph", "encoder_card_lines", "encoder_parity", "export_encoder", "write_encoder"]

ENCODER_FILE = "encoder.onnx"   # = t2m.bundle.ENCODER_GRAPH

EncodableVQ = MotionVQVAE | JointVQVAE


class EncoderGraph(nn.Module):
    """A VQ's `encode`, its codes given the rank of the decoder's input (`rank`: 2, 3 or 4 with the batch)."""

    def __init__(self, vq: EncodableVQ, rank: int) -> None:
        super().__init__()
        if not isinstance(vq, (MotionVQVAE, JointVQVAE)):
            raise TypeError(f"no encoder graph for a {type(vq).__name__} (it has no encode)")
        self.vq, self.rank = vq, rank

    def forward(self, features: torch.Tensor) -> torch.Tensor:
        codes = self.vq.encode(features)
        if self.rank == 4 and codes.dim() == 2:        # a one-layer 1D VQ as a one-column, one-layer map
            codes = codes.unsqueeze(-1)
        if self.rank == 4 and codes.dim() == 3:        # a 1D VQ's [B, T, R] as a one-column map
            codes = codes.unsqueeze(2)
        if codes.dim() != self.rank:
            raise ValueError(f"the VQ encodes rank-{codes.dim()} codes; the decoder reads rank {self.rank}")
        return codes


def _example(vq: EncodableVQ, batch: int = 2, steps: int = 5) -> torch.Tensor:
    generator = torch.Generator().manual_seed(0)
    return torch.randn(batch, steps * vq.frames_per_token, vq.config.feat_dim, generator=generator)


def export_encoder(vq: EncodableVQ, path: str | Path, rank: int) -> Path:
    """Write encoder.onnx (input ``features`` [B, frames, D], output ``codes`` of rank `rank`; B and frames dynamic)."""
    graph = EncoderGraph(vq.eval(), rank).eval()
    codes_axes = {0: "batch", 1: "tokens"}
    return export_graph(graph, (_example(vq),), path, input_names=["features"], output_names=["codes"],
                        dynamic_axes={"features": {0: "batch", 1: "frames"}, "codes": codes_axes})


def encoder_parity(vq: EncodableVQ, path: str | Path, rank: int, batch: int = 3, steps: int = 9,
                   seed: int = 1) -> dict[str, Any]:
    """encoder.onnx against the PyTorch VQ's `encode` on random features of another batch and length than the
    export's example: {"codes_identical", "steps", "mismatches"}."""
    generator = torch.Generator().manual_seed(seed)
    features = torch.randn(batch, steps * vq.frames_per_token, vq.config.feat_dim, generator=generator)
    expected = EncoderGraph(vq.eval(), rank)(features).numpy()
    got = ort_session(path).run(["codes"], {"features": features.numpy()})[0]
    same = got.shape == expected.shape and bool(np.array_equal(got, expected))
    mismatches = int(np.sum(got != expected)) if got.shape == expected.shape else int(expected.size)
    return {"codes_identical": same, "steps": steps, "mismatches": mismatches}


def write_encoder(vq: Any, out_dir: Path, rank: int) -> list[str]:
    """Write `out_dir`/encoder.onnx for a VQ that encodes (a 1D or joint VQ); the files written (none for another
    kind, such as MoGenTS's fused VQ, whose bundle then cannot encode uploaded motions)."""
    if not isinstance(vq, (MotionVQVAE, JointVQVAE)):
        return []
    export_encoder(vq, out_dir / ENCODER_FILE, rank)
    return [ENCODER_FILE]


def encoder_card_lines(parity: dict[str, Any]) -> list[str]:
    """The model card's line on encoder.onnx's parity (none when the export wrote no encoder)."""
    report = parity.get("encoder")
    if report is None:
        return []
    return [f"- encoder: codes identical to the VQ's encode {report['codes_identical']} ({report['mismatches']} "
            f"differ over {report['steps']} steps)"]
