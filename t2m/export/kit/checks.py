"""What every exporter checks and records the same way: the gross-error bound of float32 parity, int8 dynamic
quantisation of a graph in place with its measured price, and the model card's line for an int8 text encoder."""
from __future__ import annotations

import logging
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

from t2m.bundle.manifest import INT8_LABEL, INT8_LABELS, ROW_INT8_LABEL

__all__ = ["GROSS_PARITY_ERROR", "INT8_LABEL", "INT8_LABELS", "ROW_INT8_LABEL", "quantize_in_place", "text_int8_line"]

log = logging.getLogger(__name__)


GROSS_PARITY_ERROR = 1e-3


def quantize_in_place(graph: Path, report: Callable[[Path, Path], dict[str, Any]], *,
                      per_row: bool = False) -> dict[str, Any]:
    """Replace ``graph`` by its int8 dynamic quantisation (``per_row``: activations per row, the token graphs' rule:
    t2m/export/writing/row_quantize.py); ``report(fp32, int8)`` measures the price while the float32 copy still
    exists (it is removed afterwards)."""
    from t2m.export.writing.quantize import quantize_graph

    log.info("quantising %s to int8", graph.name)
    fp32_copy = graph.with_name(f".{graph.name}.fp32")
    graph.replace(fp32_copy)
    try:
        quantize_graph(fp32_copy, graph, per_row=per_row)
        return report(fp32_copy, graph)
    finally:
        fp32_copy.unlink(missing_ok=True)


def text_int8_line(r: Mapping[str, Any]) -> str:
    """The model card's line for an int8 text encoder (quantize.TextInt8Report as a dict); every family's card."""
    return (f"- text encoder: cosine to float32 features min {r['min_cosine']:.4f}, mean {r['mean_cosine']:.4f};"
            f" {r['fp32_ms_per_batch']:.1f} -> {r['int8_ms_per_batch']:.1f} ms per batch of 8;"
            f" {r['fp32_bytes'] / 1e6:.1f} -> {r['int8_bytes'] / 1e6:.1f} MB")
