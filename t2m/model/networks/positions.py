"""The fixed sin/cos position table the transformers share (T2M-GPT's GPT, the masked family's and MDM's
transformers); written once because every released checkpoint that stores it must match it bit for bit."""
from __future__ import annotations

import math

import torch


def sinusoid_table(length: int, dim: int) -> torch.Tensor:
    """Fixed sin/cos position table [length, 1, dim] (sin on even channels, cos on odd ones)."""
    position = torch.arange(length, dtype=torch.float32).unsqueeze(1)
    frequency = torch.exp(torch.arange(0, dim, 2, dtype=torch.float32) * (-math.log(10000.0) / dim))
    table = torch.zeros(length, dim)
    table[:, 0::2] = torch.sin(position * frequency)
    table[:, 1::2] = torch.cos(position * frequency)[:, : dim // 2]
    return table.unsqueeze(1)
