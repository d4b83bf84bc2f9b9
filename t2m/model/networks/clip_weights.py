"""Read OpenAI's CLIP weights (``ViT-B-32.pt`` as ``clip.load`` downloads it) into :class:`ClipTextTransformer`.

Two forms are accepted:

- OpenAI's file itself: a TorchScript archive (a traced full CLIP, ``visual.*`` keys included). It is read with
  ``torch.jit.load(path, map_location="cpu").state_dict()``, which is also how OpenAI's own loader reads it when it
  builds a non-JIT model. Why that and not a hand-written reader of the zip: TorchScript deserialisation does not
  run Python pickles (its unpickler builds only tensors, TorchScript classes and plain values), the archive's
  TorchScript code is compiled but never called here (we take the tensors and drop the module), and it needs
  nothing but torch (no torchvision, no OpenAI package). A reader of the zip's ``data.pkl`` would re-implement
  torch's storage layout and its mangled class names, which change between torch versions.
  ``torch.load(..., weights_only=True)`` refuses such archives, by design. torch 2.14 marks ``torch.jit.load`` as
  deprecated (a FutureWarning, silenced here); if a later torch drops it, this one call needs a replacement.
- A plain state dict in OpenAI's key layout (``torch.save(model.state_dict())``), read with ``weights_only=True``.

Only the text keys are used: ``token_embedding.weight``, ``positional_embedding``,
``transformer.resblocks.{i}.{ln_1, attn.in_proj_weight/in_proj_bias, attn.out_proj, ln_2, mlp.c_fc, mlp.c_proj}``,
``ln_final``, ``text_projection``. ``visual.*``, ``logit_scale`` and the archive's integer buffers
(``input_resolution``, ``context_length``, ``vocab_size``) are ignored; OpenAI's float16 tensors become float32.
Sizes are read from the shapes (width, layers, context, vocabulary, embed dim; heads = width / 64 as in every
OpenAI CLIP). Every text tensor's shape is checked before loading, and a wrong, truncated or foreign file is
refused with one line naming the key and the shape expected (:class:`ClipWeightsError`).

Not detectable from the weights: a checkpoint trained with GELU in OpenAI's key layout (e.g. open_clip's own
LAION-trained ViT-B-32) would load and be computed with QuickGELU. Pass OpenAI's file.
"""
from __future__ import annotations

import re
import warnings
import zipfile
from collections.abc import Mapping
from pathlib import Path

import torch

from t2m.model.networks.clip_text import ClipTextConfig, ClipTextTransformer

HEAD_WIDTH = 64
EXPECTED = "OpenAI's CLIP ViT-B-32.pt (TorchScript archive) or a state dict in its key layout"
_BLOCK_KEY = re.compile(r"transformer\.resblocks\.(\d+)\.ln_1\.weight")


class ClipWeightsError(ValueError):
    """A CLIP weights file that cannot be used; the message is one line naming the file and what is wrong."""


def read_clip_state(path: str | Path) -> dict[str, torch.Tensor]:
    """Every tensor of the file (archive or plain state dict), on the CPU, as stored."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(str(path))
    if _is_torchscript_archive(path):
        try:
            with warnings.catch_warnings():
                warnings.filterwarnings("ignore", category=FutureWarning)  # torch 2.14: "torch.jit.load is deprecated"
                state = torch.jit.load(str(path), map_location="cpu").state_dict()
        except Exception as error:
            raise ClipWeightsError(
                f"{path}: unreadable TorchScript archive ({one_line(error)}); expected {EXPECTED}") from None
    else:
        try:
            state = torch.load(path, map_location="cpu", weights_only=True)
        except Exception as error:
            raise ClipWeightsError(
                f"{path}: not a complete PyTorch file ({one_line(error)}); expected {EXPECTED}") from None
    if not isinstance(state, Mapping):
        raise ClipWeightsError(f"{path}: holds a {type(state).__name__}, not a dict of tensors; expected {EXPECTED}")
    if not all(isinstance(v, torch.Tensor) for v in state.values()):
        keys = [str(k) for k in list(state)[:5]]
        raise ClipWeightsError(f"{path}: holds a dict with keys {keys}, not a dict of tensors; expected {EXPECTED}")
    return {str(key): value for key, value in state.items()}


def clip_text_config(state: Mapping[str, torch.Tensor], file: str = "CLIP weights") -> ClipTextConfig:
    """Sizes of the text tower from the shapes of its tensors."""
    tokens = _require(state, "token_embedding.weight", "[vocab, width]", file, ndim=2)
    positions = _require(state, "positional_embedding", "[context, width]", file, ndim=2)
    projection = _require(state, "text_projection", "[width, embed_dim]", file, ndim=2)
    vocab, width = (int(n) for n in tokens.shape)
    layers = len({m.group(1) for key in state if (m := _BLOCK_KEY.fullmatch(key))})
    if layers == 0:
        raise ClipWeightsError(f"{file}: missing tensor 'transformer.resblocks.0.ln_1.weight' [{width}]")
    if width % HEAD_WIDTH:
        raise ClipWeightsError(f"{file}: 'token_embedding.weight' width {width} is not a multiple of {HEAD_WIDTH} "
                               "(OpenAI's CLIP has width / 64 attention heads)")
    return ClipTextConfig(vocab_size=vocab, context_length=int(positions.shape[0]), width=width, layers=layers,
                          heads=width // HEAD_WIDTH, embed_dim=int(projection.shape[1]))


def expected_text_shapes(config: ClipTextConfig) -> dict[str, tuple[int, ...]]:
    """Every text-tower key of OpenAI's layout with its shape for these sizes."""
    w = config.width
    shapes: dict[str, tuple[int, ...]] = {
        "token_embedding.weight": (config.vocab_size, w),
        "positional_embedding": (config.context_length, w),
    }
    for i in range(config.layers):
        block = f"transformer.resblocks.{i}"
        shapes |= {
            f"{block}.ln_1.weight": (w,), f"{block}.ln_1.bias": (w,),
            f"{block}.attn.in_proj_weight": (3 * w, w), f"{block}.attn.in_proj_bias": (3 * w,),
            f"{block}.attn.out_proj.weight": (w, w), f"{block}.attn.out_proj.bias": (w,),
            f"{block}.ln_2.weight": (w,), f"{block}.ln_2.bias": (w,),
            f"{block}.mlp.c_fc.weight": (4 * w, w), f"{block}.mlp.c_fc.bias": (4 * w,),
            f"{block}.mlp.c_proj.weight": (w, 4 * w), f"{block}.mlp.c_proj.bias": (w,),
        }
    shapes |= {"ln_final.weight": (w,), "ln_final.bias": (w,), "text_projection": (w, config.embed_dim)}
    return shapes


def text_tower_state(state: Mapping[str, torch.Tensor], file: str = "CLIP weights"
                     ) -> tuple[ClipTextConfig, dict[str, torch.Tensor]]:
    """(sizes, the text tensors in float32), after checking that every one is present with the right shape."""
    config = clip_text_config(state, file)
    text: dict[str, torch.Tensor] = {}
    for key, shape in expected_text_shapes(config).items():
        tensor = _require(state, key, _shape(shape), file)
        if tuple(tensor.shape) != shape:
            raise ClipWeightsError(f"{file}: tensor '{key}' has shape {_shape(tensor.shape)}, expected {_shape(shape)}"
                                   f" (width {config.width}, {config.layers} layers)")
        if not tensor.is_floating_point():
            raise ClipWeightsError(f"{file}: tensor '{key}' is {tensor.dtype}, expected floating point")
        text[key] = tensor.detach().to(torch.float32)
    return config, text


def load_clip_text(path: str | Path) -> ClipTextTransformer:
    """OpenAI's CLIP file -> our text tower in float32, eval mode, frozen."""
    config, text = text_tower_state(read_clip_state(path), str(path))
    model = ClipTextTransformer(config)
    model.load_state_dict(text, strict=True)  # cannot fail: every key and shape was checked above
    model.eval()
    for parameter in model.parameters():
        parameter.requires_grad_(False)
    return model


def _is_torchscript_archive(path: Path) -> bool:
    """TorchScript zips carry the module's code and constants; torch.save zips carry only data.pkl + tensors."""
    if not zipfile.is_zipfile(path):
        return False
    try:
        with zipfile.ZipFile(path) as archive:
            return any(name.endswith("/constants.pkl") or "/code/" in name for name in archive.namelist())
    except zipfile.BadZipFile:
        return False


def _require(state: Mapping[str, torch.Tensor], key: str, shape: str, file: str, ndim: int | None = None
             ) -> torch.Tensor:
    if key not in state:
        hint = "" if "token_embedding.weight" in state else f"; is this {EXPECTED}?"
        raise ClipWeightsError(f"{file}: missing tensor '{key}' {shape}{hint}")
    tensor = state[key]
    if ndim is not None and tensor.ndim != ndim:
        raise ClipWeightsError(f"{file}: tensor '{key}' has shape {_shape(tensor.shape)}, expected {shape}")
    return tensor


def _shape(shape: tuple[int, ...] | torch.Size) -> str:
    return "[" + ", ".join(str(int(n)) for n in shape) + "]"


def one_line(error: BaseException) -> str:
    text = " ".join(str(error).split())
    return (text[:200] + "...") if len(text) > 200 else (text or type(error).__name__)
