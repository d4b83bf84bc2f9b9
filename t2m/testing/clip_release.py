"""CLIP weights written in EXACTLY the format of OpenAI's ``ViT-B-32.pt`` (../shared/docs/t2m-gpt-checkpoints.md,
"The CLIP file users hold"), built from that description - not from our module - with random values.

OpenAI's file is a TorchScript archive of the whole CLIP: text keys, ``visual.*`` keys, ``logit_scale`` and three
integer buffers; linear/attention/conv weights and biases, ``text_projection`` and ``visual.proj`` are float16, the
rest float32. :func:`save_torchscript_archive` scripts a module whose attribute paths are the key names, so the
archive's ``state_dict()`` has exactly those keys, shapes and dtypes.
"""
from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import torch
from torch import nn

VIT_B_32_TEXT = {"width": 512, "layers": 12, "context": 77, "vocab": 49408, "embed_dim": 512}
# OpenAI's convert_weights: these become float16 in the released file
FLOAT16_SUFFIXES = ("attn.in_proj_weight", "attn.in_proj_bias", "out_proj.weight", "out_proj.bias", "c_fc.weight",
                    "c_fc.bias", "c_proj.weight", "c_proj.bias", "conv1.weight")
FLOAT16_KEYS = ("text_projection", "visual.proj")


def _block(state: dict, prefix: str, width: int, rand) -> None:
    state |= {
        f"{prefix}.attn.in_proj_weight": rand(3 * width, width, scale=width**-0.5),
        f"{prefix}.attn.in_proj_bias": rand(3 * width, scale=0.02),
        f"{prefix}.attn.out_proj.weight": rand(width, width, scale=width**-0.5),
        f"{prefix}.attn.out_proj.bias": rand(width, scale=0.02),
        f"{prefix}.ln_1.weight": 1 + rand(width, scale=0.1), f"{prefix}.ln_1.bias": rand(width, scale=0.1),
        f"{prefix}.mlp.c_fc.weight": rand(4 * width, width, scale=width**-0.5),
        f"{prefix}.mlp.c_fc.bias": rand(4 * width, scale=0.02),
        f"{prefix}.mlp.c_proj.weight": rand(width, 4 * width, scale=(4 * width) ** -0.5),
        f"{prefix}.mlp.c_proj.bias": rand(width, scale=0.02),
        f"{prefix}.ln_2.weight": 1 + rand(width, scale=0.1), f"{prefix}.ln_2.bias": rand(width, scale=0.1),
    }


def openai_clip_state(width: int = 512, layers: int = 12, context: int = 77, vocab: int = 49408,
                      embed_dim: int = 512, vision_width: int = 64, seed: int = 0,
                      released_dtypes: bool = True) -> dict[str, torch.Tensor]:
    """A full-CLIP state dict with OpenAI's key names: the whole text tower, a one-block vision tower at
    ``vision_width`` (a few ``visual.*`` keys, as loaders must skip them), ``logit_scale`` and the integer buffers."""
    g = torch.Generator().manual_seed(seed)

    def rand(*shape: int, scale: float = 1.0) -> torch.Tensor:
        return torch.randn(*shape, generator=g) * scale

    state: dict[str, torch.Tensor] = {
        "positional_embedding": rand(context, width, scale=0.01),
        "text_projection": rand(width, embed_dim, scale=width**-0.5),
        "logit_scale": torch.tensor(4.6052),
        "visual.class_embedding": rand(vision_width, scale=vision_width**-0.5),
        "visual.positional_embedding": rand(50, vision_width, scale=0.01),
        "visual.proj": rand(vision_width, embed_dim, scale=vision_width**-0.5),
        "visual.conv1.weight": rand(vision_width, 3, 32, 32, scale=0.02),
        "visual.ln_pre.weight": torch.ones(vision_width), "visual.ln_pre.bias": torch.zeros(vision_width),
        "visual.ln_post.weight": torch.ones(vision_width), "visual.ln_post.bias": torch.zeros(vision_width),
    }
    _block(state, "visual.transformer.resblocks.0", vision_width, rand)
    for i in range(layers):
        _block(state, f"transformer.resblocks.{i}", width, rand)
    state |= {
        "token_embedding.weight": rand(vocab, width, scale=0.02),
        "ln_final.weight": 1 + rand(width, scale=0.1), "ln_final.bias": rand(width, scale=0.1),
        "input_resolution": torch.tensor(224), "context_length": torch.tensor(context),
        "vocab_size": torch.tensor(vocab),
    }
    return released_format(state) if released_dtypes else state


def released_format(state: Mapping[str, torch.Tensor]) -> dict[str, torch.Tensor]:
    """The dtypes of OpenAI's file: float16 where its convert_weights put them, float32 elsewhere."""
    out = {}
    for key, tensor in state.items():
        if tensor.is_floating_point():
            half = key in FLOAT16_KEYS or key.endswith(FLOAT16_SUFFIXES)
            tensor = tensor.to(torch.float16 if half else torch.float32)
        out[key] = tensor
    return out


class _Node(nn.Module):
    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return x


def save_torchscript_archive(state: Mapping[str, torch.Tensor], path: str | Path) -> Path:
    """A TorchScript archive whose state_dict() is ``state`` (same keys, shapes, dtypes): floating tensors as
    parameters, integer ones as buffers, nested under modules named by the dotted key parts."""
    root = _Node()
    for key, tensor in state.items():
        *parents, leaf = key.split(".")
        node: nn.Module = root
        for part in parents:
            if part not in node._modules:
                node.add_module(part, _Node())
            node = node.get_submodule(part)
        if tensor.is_floating_point():
            node.register_parameter(leaf, nn.Parameter(tensor.clone(), requires_grad=False))
        else:
            node.register_buffer(leaf, tensor.clone())
    path = Path(path)
    torch.jit.save(torch.jit.script(root), str(path))
    return path
