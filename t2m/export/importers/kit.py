"""What every importer of a released checkpoint does the same way: read a PyTorch file as plain tensors (the full
unpickler only with --allow-pickle), find its state dicts by their keys, check each tensor a module needs (present,
its shape, nothing extra) naming the first one that is wrong, load strictly, and read the release's statistics."""
from __future__ import annotations

import logging
import pickle
import tempfile
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any, Protocol, TypeVar

import numpy as np
import torch
from torch import nn

__all__ = ["check_tensors", "import_quantized", "load_checked", "load_checkpoint_entries", "load_checkpoint_entry",
           "load_strict", "read_stat", "read_torch_file", "require_tensor", "shape_text", "strip_prefix"]

log = logging.getLogger(__name__)


def load_checkpoint_entry(path: str | Path, keys: tuple[str, ...], allow_pickle: bool = False
                          ) -> tuple[str, dict[str, torch.Tensor]]:
    """(the first of ``keys`` the file has, its state dict with float tensors as float32).

    ``torch.load`` with ``weights_only=True``. A file holding other Python objects needs the full unpickler, which
    can run code from the file: only with ``allow_pickle`` (``--allow-pickle``), for files from a source the user
    trusts. A file torch cannot read at all (truncated, not a checkpoint) is named as such.
    """
    (entry,) = load_checkpoint_entries(path, (keys,), allow_pickle)
    return entry


def load_checkpoint_entries(path: str | Path, wanted: tuple[tuple[str, ...], ...], allow_pickle: bool = False
                            ) -> list[tuple[str, dict[str, torch.Tensor]]]:
    """:func:`load_checkpoint_entry` for several state dicts of one file (MoGenTS keeps two models in each),
    read once: per tuple of ``wanted``, the first key the file has and its state dict."""
    path = Path(path)
    data = read_torch_file(path, allow_pickle)
    entries = []
    for keys in wanted:
        alternatives = " or ".join(f"'{k}'" for k in keys)
        if not isinstance(data, Mapping):
            raise ValueError(f"{path}: expected a dict with key {alternatives}, got {type(data).__name__}")
        key = next((k for k in keys if k in data), None)
        if key is None:
            raise ValueError(f"{path}: no key {alternatives} (keys: {', '.join(map(str, list(data)[:10]))})")
        state = data[key]
        if not isinstance(state, Mapping) or not all(isinstance(v, torch.Tensor) for v in state.values()):
            raise ValueError(f"{path}: '{key}' is not a state dict of tensors")
        entries.append((key, {str(k): v.float() if v.is_floating_point() else v for k, v in state.items()}))
    return entries


def read_torch_file(path: Path, allow_pickle: bool = False) -> Any:
    """What a PyTorch file holds, on the CPU: ``weights_only=True``; the full unpickler only with ``allow_pickle``
    (it can run code from the file); an unreadable file (truncated, not a checkpoint) refused in one line."""
    if not path.is_file():
        raise FileNotFoundError(str(path))
    try:
        return torch.load(path, map_location="cpu", weights_only=True)
    except pickle.UnpicklingError as error:
        if not allow_pickle:
            raise ValueError(f"{path}: not loadable as plain tensors ({_first_line(error)}); if you trust the file, "
                             "pass --allow-pickle") from error
        log.warning("%s: loading with the full unpickler (--allow-pickle)", path)
        return torch.load(path, map_location="cpu", weights_only=False)
    except Exception as error:
        raise ValueError(f"{path}: not a complete PyTorch file ({_first_line(error)})") from None


def _first_line(error: BaseException) -> str:
    text = str(error).strip()
    return text.splitlines()[0][:200] if text else type(error).__name__


def strip_prefix(state: Mapping[str, torch.Tensor], prefix: str) -> dict[str, torch.Tensor]:
    return {k[len(prefix):] if k.startswith(prefix) else k: v for k, v in state.items()}


def shape_text(shape: tuple[int, ...] | torch.Size) -> str:
    return "[" + ", ".join(str(int(n)) for n in shape) + "]"


def require_tensor(state: Mapping[str, torch.Tensor], key: str, where: str, expected: str, ndim: int) -> torch.Tensor:
    """A tensor the sizes are read from: present, with ``ndim`` axes."""
    if key not in state:
        raise ValueError(f"{where}: missing tensor '{key}' {expected}")
    tensor = state[key]
    if tensor.ndim != ndim:
        raise ValueError(f"{where}: tensor '{key}' has shape {shape_text(tensor.shape)}, expected {expected}")
    return tensor


def check_tensors(state: Mapping[str, torch.Tensor], module: nn.Module, where: str, release: str) -> None:
    """Every tensor of ``module`` in ``state`` with its shape, and nothing else: one line naming the first key that
    is missing, has another shape (with the one expected) or is not part of the model."""
    expected = {key: tuple(value.shape) for key, value in module.state_dict().items()}
    for key, shape in expected.items():
        if key not in state:
            raise ValueError(f"{where}: missing tensor '{key}' {shape_text(shape)}")
        if tuple(state[key].shape) != shape:
            raise ValueError(f"{where}: tensor '{key}' has shape {shape_text(state[key].shape)}, expected "
                             f"{shape_text(shape)}")
    extra = sorted(set(state) - set(expected))
    if extra:
        raise ValueError(f"{where}: unexpected tensor '{extra[0]}' (not part of {release}'s released model)")


def load_strict(module: nn.Module, state: Mapping[str, torch.Tensor], where: str) -> None:
    """torch's strict load (the module's own load hooks drop what a release keeps and it does not use: T2M-GPT's
    attention masks and unused position table), its error as one line."""
    try:
        module.load_state_dict(dict(state), strict=True)
    except RuntimeError as error:
        detail = " ".join(str(error).split())  # one line: torch's message spans several
        raise ValueError(f"{where}: weights do not fit the inferred model ({detail})") from error


def load_checked(module: nn.Module, state: Mapping[str, torch.Tensor], where: str, release: str) -> Any:
    """``module`` with every tensor of ``state`` checked (check_tensors), loaded, in eval mode."""
    check_tensors(state, module, where, release)
    module.load_state_dict(dict(state), strict=True)  # cannot fail: every key and shape was checked
    return module.eval()


def read_stat(path: Path, feat_dim: int, what: str = "the VQ's features") -> np.ndarray:
    """meta/mean.npy or std.npy: [feat_dim] float32 (``what``: whose features, for the refusal)."""
    try:
        array = np.load(path, allow_pickle=False)
    except (ValueError, OSError) as error:
        raise ValueError(f"{path}: not a numpy array file ({' '.join(str(error).split())[:160]})") from None
    array = np.asarray(array, dtype=np.float32).reshape(-1)
    if array.shape != (feat_dim,):
        raise ValueError(f"{path}: expected [{feat_dim}] values ({what}), got {list(array.shape)}")
    return array


class _Checks(Protocol):
    quantization: dict[str, Any] | None


ChecksT = TypeVar("ChecksT", bound=_Checks)


def import_quantized(out_dir: str | Path, quantize: str | None,
                     write: Callable[[Path], tuple[dict, ChecksT]]) -> tuple[dict, ChecksT]:
    """An import, quantised (`--quantize int8|int4|fp16`) when asked: `write(folder)` imports float32 there (into
    `out_dir` itself without `quantize`); with `quantize`, into a scratch folder beside `out_dir`, from which
    t2m.export.writing.int8.quantize_bundle writes the quantised bundle to `out_dir`, measured against the float32
    import and said in its card; the checks' `quantization` gets that report."""
    from t2m.export.writing.bundle import check_out_dir
    from t2m.export.writing.int8 import SCHEMES, quantize_bundle

    out_dir = Path(out_dir)
    if quantize is None:
        return write(out_dir)
    if quantize not in SCHEMES:
        raise ValueError(f"--quantize must be one of {', '.join(SCHEMES)}, got {quantize!r}")
    check_out_dir(out_dir)   # refused before the slow import
    out_dir.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix=f".{out_dir.name}-float32-", dir=out_dir.parent) as scratch:
        float32 = Path(scratch) / "bundle"
        _, checks = write(float32)
        log.info("quantising the imported graphs (%s) and measuring them against float32", quantize)
        manifest, report = quantize_bundle(float32, out_dir, scheme=quantize)
    checks.quantization = report
    return manifest, checks
