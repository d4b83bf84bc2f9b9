"""The bundle contract (docs/contracts.md "The bundle"), written once and read by both the exporter and the service.

Torch-free and onnxruntime-free (json + numpy only): `t2m.export` writes and re-checks bundles with it, and
`t2m.service` loads them with it. A bundle problem is always a `BundleError` naming the file or manifest field.
"""
from __future__ import annotations

from t2m.bundle.caption_index import CaptionIndex, Neighbour, unit_rows
from t2m.bundle.errors import BundleError
from t2m.bundle.family import (
    Capabilities,
    ModelFamily,
    family_names,
    get_family,
    iter_families,
    register_family,
    unregister_family,
)
from t2m.bundle.files import check_files, files_table, sha256_of
from t2m.bundle.graphs import (
    ENCODER_GRAPH,
    FIXED_STEP_GRAPH,
    DeclaredTensor,
    GraphSpec,
    TensorSpec,
    bundle_graphs,
    check_graph_io,
    encoder_graph,
    expected_graphs,
)
from t2m.bundle.manifest import (
    CAPTION_INDEX_FILE,
    COMMON_FILES,
    FORMAT_VERSION,
    LENGTH_GRAPH,
    MANIFEST_NAME,
    OPTIONAL_FILES,
    CaptionIndexInfo,
    Manifest,
    check_manifest_fields,
    family_of,
    parse_manifest,
    read_manifest,
    read_manifest_dict,
    required_files,
)

__all__ = [
    "CAPTION_INDEX_FILE",
    "COMMON_FILES",
    "ENCODER_GRAPH",
    "FIXED_STEP_GRAPH",
    "FORMAT_VERSION",
    "LENGTH_GRAPH",
    "MANIFEST_NAME",
    "OPTIONAL_FILES",
    "BundleError",
    "Capabilities",
    "CaptionIndex",
    "CaptionIndexInfo",
    "DeclaredTensor",
    "GraphSpec",
    "Manifest",
    "ModelFamily",
    "Neighbour",
    "TensorSpec",
    "bundle_graphs",
    "check_files",
    "check_graph_io",
    "check_manifest_fields",
    "encoder_graph",
    "expected_graphs",
    "family_names",
    "family_of",
    "files_table",
    "get_family",
    "iter_families",
    "parse_manifest",
    "read_manifest",
    "read_manifest_dict",
    "register_family",
    "required_files",
    "sha256_of",
    "unit_rows",
    "unregister_family",
]
