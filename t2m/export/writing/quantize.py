"""Optional int8 dynamic quantisation of the GPT step graph and the text encoder (onnxruntime.quantization), and
opt-in int4 weights for a GPT step graph (MatMulNBits).

Dynamic quantisation stores MatMul/Gemm weights as int8 and quantises activations on the fly, so
it needs no calibration data: a 4x smaller file and faster MatMuls on CPU, at the price of small
logit/feature errors. ``int8_report`` measures that price on a bundle-like pair of graphs:
max abs logit difference and whether greedy code sequences still match (GPT), cosine similarity
to the float32 features (text), and the speed of both.
"""
from __future__ import annotations

import logging
import os
import tempfile
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import numpy as np

# MatMul/Gemm carry the compute; Gather carries the embedding tables (MiniLM's 30522 x 384 words: half its bytes).
# Per-channel weight scales matter: on all-MiniLM-L6-v2, per-tensor int8 gives cosine 0.955 to the float32
# features, per-channel 0.992 (8 motion captions; measured with text_int8_report).
QUANTIZED_OPS = ["MatMul", "Gemm", "Gather"]


@contextmanager
def _quiet_logging(*names: str) -> Iterator[None]:
    """Raise the named loggers ("" = root) to ERROR for the block: onnxruntime's quantisers are chatty."""
    loggers = [logging.getLogger(name or None) for name in names]
    levels = [logger.level for logger in loggers]
    for logger in loggers:
        logger.setLevel(logging.ERROR)
    try:
        yield
    finally:
        for logger, level in zip(loggers, levels):
            logger.setLevel(level)


def quantize_graph(src: str | Path, dst: str | Path, reduce_range: bool = True, per_row: bool = False) -> Path:
    """Write an int8 dynamically quantised copy of ``src`` to ``dst`` (``dst`` may equal ``src``).

    ``reduce_range`` keeps weights in 7 bits. On CPUs without VNNI, onnxruntime multiplies uint8 activations by int8
    weights with pairwise int16 sums (VPMADDUBSW) that saturate for 8-bit weights: emulating that arithmetic puts a
    small GPT's logits 0.11 off (a CI machine saw 0.13), against 0.005 with VNNI. With 7-bit weights no sum can
    saturate (2 x 255 x 64 < 32767): the integer results are the same on every x86 CPU and what the export measured is
    what the service computes.

    ``per_row`` quantises each activation row on its own instead of the whole tensor (row_quantize.py): the rule for
    graphs whose rows are different requests (the token graphs), so that batching never changes a request.
    """
    from onnxruntime.quantization import QuantType, quantize_dynamic

    src, dst = Path(src), Path(dst)
    handle, tmp_name = tempfile.mkstemp(suffix=".onnx", dir=dst.parent)
    os.close(handle)
    tmp = Path(tmp_name)
    try:
        with _quiet_logging(""):  # quantize_dynamic logs a pre-processing hint on the root logger at WARNING
            quantize_dynamic(src, tmp, op_types_to_quantize=QUANTIZED_OPS, weight_type=QuantType.QInt8,
                             per_channel=True, reduce_range=reduce_range, extra_options={"MatMulConstBOnly": True})
        if per_row:
            from t2m.export.writing.row_quantize import row_quantize_graph

            row_quantize_graph(tmp, tmp)
        tmp.chmod(0o644)  # mkstemp makes 0600 files; bundle files are world-readable like the others
        tmp.replace(dst)
    finally:
        tmp.unlink(missing_ok=True)
    return dst


INT4_BLOCK = 128   # weights per scale along the input dimension (T2M-GPT's 1024 and our 256/384 widths divide by it)


def quantize_weights_nbits(src: str | Path, dst: str | Path, bits: int, block: int = 32,
                           accuracy_level: int | None = None) -> Path:
    """Write a copy of ``src`` whose MatMul weights are block-wise symmetric ``bits``-bit integers (MatMulNBits).

    ``accuracy_level`` None/0: float32 activations (the kernel dequantises the weights); 4: activations quantised to
    int8 per block and integer products (the fast path on CPUs)."""
    import onnx
    from onnxruntime.quantization.matmul_nbits_quantizer import DefaultWeightOnlyQuantConfig, MatMulNBitsQuantizer

    # the quantiser logs every node it skips at INFO, on its own logger and the root one
    with _quiet_logging("", "onnxruntime.quantization.matmul_nbits_quantizer"):
        config = DefaultWeightOnlyQuantConfig(block_size=block, is_symmetric=True, bits=bits,
                                              accuracy_level=accuracy_level)
        quantizer = MatMulNBitsQuantizer(onnx.load(str(src)), bits=bits, block_size=block, is_symmetric=True,
                                         accuracy_level=accuracy_level, algo_config=config)
        quantizer.process()
        quantizer.model.save_model_to_file(str(dst), use_external_data_format=False)
    return Path(dst)


def quantize_graph_int4(src: str | Path, dst: str | Path) -> Path:
    """int4 weights with int8 compute (MatMulNBits, block 128, accuracy level 4): about half of int8's weight bytes
    (126 against 230 MB at T2M-GPT's release size), which is what a bandwidth-bound step needs
    (t2m/bench/quantized_release.py).

    No 7-bit rule is needed: a 4-bit weight times an 8-bit activation cannot saturate the int16 pair sums of CPUs
    without VNNI (at most 2 x 255 x 8 = 4080 < 32767)."""
    return quantize_weights_nbits(src, dst, bits=4, block=INT4_BLOCK, accuracy_level=4)


@dataclass
class TextInt8Report:
    min_cosine: float
    mean_cosine: float
    fp32_ms_per_batch: float
    int8_ms_per_batch: float
    fp32_bytes: int
    int8_bytes: int


REPORT_TEXTS = [
    "a person walks forward and waves with the right hand",
    "someone jumps up and down twice",
    "a man sits down slowly on a chair",
    "the figure runs in a circle, then stops and bows",
    "she kicks with her left leg",
    "a person is dancing happily",
    "walking backwards carefully",
    "he throws a ball overhand with his right arm",
]


def text_int8_report(fp32_path: str | Path, int8_path: str | Path, tokenizer_path: str | Path,
                     repeats: int = 5, threads: int = 1) -> TextInt8Report:
    """Cosine similarity of int8 vs float32 text features (pooled, or every real token's state) on a handful of
    motion captions, and speed."""
    from t2m.export.graphs.export import ort_session
    from t2m.export.graphs.text import tokenize

    ids, mask = tokenize(tokenizer_path, REPORT_TEXTS)
    feeds = {"input_ids": ids.numpy(), "attention_mask": mask.numpy()}
    outputs, times = [], []
    for path in (fp32_path, int8_path):
        session = ort_session(path, threads=threads)
        session.run(None, feeds)
        start = time.perf_counter()
        for _ in range(repeats):
            features = session.run(None, feeds)[0]
        times.append((time.perf_counter() - start) / repeats)
        outputs.append(features)
    a, b = outputs
    if a.ndim == 3:   # token states (the diffusion family's DiP): every real token's vector
        keep = mask.numpy().astype(bool)
        a, b = a[keep], b[keep]
    cosine = (a * b).sum(1) / (np.linalg.norm(a, axis=1) * np.linalg.norm(b, axis=1))
    return TextInt8Report(
        min_cosine=float(cosine.min()), mean_cosine=float(cosine.mean()),
        fp32_ms_per_batch=1000 * times[0], int8_ms_per_batch=1000 * times[1],
        fp32_bytes=Path(fp32_path).stat().st_size, int8_bytes=Path(int8_path).stat().st_size,
    )


# Op types kept float32 in an fp16 graph: onnxruntime.transformers.float16's default block list (ops without float16
# kernels on CPU or CUDA, or numerically unsafe in half precision) plus what our graphs need on top (FP16_EXTRA_BLOCK).
FP16_EXTRA_BLOCK: tuple[str, ...] = ()


def convert_graph_fp16(src: str | Path, dst: str | Path) -> Path:
    """Write a float16 copy of ``src``: weights and compute in half precision, the graph's float32 inputs and outputs
    kept (Cast nodes at the edges), so a bundle's contract and the served loop are unchanged.

    Meant for GPUs (CUDA runs float16 MatMuls on tensor cores); onnxruntime's CPU provider runs it too, often slower
    than float32, which is how its parity is measured here. Op types in onnxruntime's default block list (and
    FP16_EXTRA_BLOCK) stay float32."""
    import onnx
    from onnxruntime.transformers.float16 import DEFAULT_OP_BLOCK_LIST, convert_float_to_float16

    model = onnx.load(str(src))
    with _quiet_logging("", "onnxruntime.transformers.float16"):
        converted = convert_float_to_float16(model, keep_io_types=True,
                                             op_block_list=[*DEFAULT_OP_BLOCK_LIST, *FP16_EXTRA_BLOCK])
    onnx.save(converted, str(dst))
    return Path(dst)
