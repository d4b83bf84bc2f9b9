"""The bundle contract (docs/contracts.md "The bundle"), written once and read by both the exporter and the service.

Torch-free and onnxruntime-free (json + numpy only): `t2m.export` writes and re-checks bundles with it, and
`t2m.service` loads them with it. A bundle problem is always a `BundleError` naming the file or manifest field.
"""
from __future__ import annotations

from t2m.bundle.caption_index import CaptionIndex, Neighbour, unit_rows
from t2m.bundle.errors import BundleError
from t2m.bundle.files import check_files, files_table, sha256_of
from t2m.bundle.graphs import DeclaredTensor, GraphSpec, TensorSpec, check_graph_io, expected_graphs
from t2m.bundle.manifest import (
    CAPTION_INDEX_FILE,
    FAMILIES,
    FORMAT_VERSION,
    LENGTH_GRAPH,
    MANIFEST_NAME,
    OPTIONAL_FILES,
    REQUIRED_FILES,
    CaptionIndexInfo,
    GptSettings,
    HiFiGPTSettings,
    Manifest,
    MaskedSettings,
    check_manifest_fields,
    family_of,
    parse_manifest,
    read_manifest,
    read_manifest_dict,
    required_files,
)

__all__ = [
    "CAPTION_INDEX_FILE",
    "FAMILIES",
    "FORMAT_VERSION",
    "LENGTH_GRAPH",
    "MANIFEST_NAME",
    "OPTIONAL_FILES",
    "REQUIRED_FILES",
    "BundleError",
    "CaptionIndex",
    "CaptionIndexInfo",
    "DeclaredTensor",
    "GptSettings",
    "GraphSpec",
    "HiFiGPTSettings",
    "Manifest",
    "MaskedSettings",
    "Neighbour",
    "TensorSpec",
    "check_files",
    "check_graph_io",
    "check_manifest_fields",
    "expected_graphs",
    "family_of",
    "files_table",
    "parse_manifest",
    "read_manifest",
    "read_manifest_dict",
    "required_files",
    "sha256_of",
    "unit_rows",
]
