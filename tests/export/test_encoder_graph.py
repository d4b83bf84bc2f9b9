"""encoder.onnx (uploaded motions): its codes are the PyTorch VQ's `encode`, in the decoder's layout, for
every token family's tiny random bundle; the bundle lists it and passes its signature check; a bundle without one
stays valid."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch

from t2m.bundle import ENCODER_GRAPH, BundleError
from t2m.export.graphs.encoder import EncoderGraph, encoder_parity
from t2m.export.graphs.export import ort_session
from t2m.export.writing.verify import verify_bundle


def _models(family: str) -> tuple[object, int]:
    """(the VQ a tiny random bundle of `family` encodes with, the rank of its decoder's codes)."""
    if family == "gpt":
        from t2m.model.networks.vqvae import MotionVQVAE, VQConfig

        torch.manual_seed(0)
        return MotionVQVAE(VQConfig(width=32, code_dim=16, nb_code=32, depth=1)).eval(), 2
    if family == "hifigpt":
        from t2m.families.hifigpt.random_bundle import random_hifigpt_models

        return random_hifigpt_models()["vq"], 3
    from t2m.families.masked.random_bundle import random_masked_models

    return random_masked_models(variant=family.split("-")[1])["vq"], 4


@pytest.mark.parametrize("family", ["gpt", "hifigpt", "masked-2d", "masked-1d"])
def test_encoder_codes_are_the_vq_encode(family: str, tmp_path: Path) -> None:
    from t2m.export.graphs.encoder import export_encoder

    vq, rank = _models(family)
    path = export_encoder(vq, tmp_path / "encoder.onnx", rank)
    report = encoder_parity(vq, path, rank)
    assert report["codes_identical"], report
    features = torch.randn(1, 6 * vq.frames_per_token, vq.config.feat_dim, generator=torch.Generator().manual_seed(3))
    codes = ort_session(path).run(["codes"], {"features": features.numpy()})[0]
    raw = vq.encode(features).numpy()
    assert codes.ndim == rank and codes.shape[1] == 6
    assert np.array_equal(codes.reshape(raw.shape), raw)        # the VQ's own encode, only reshaped to the layout
    assert np.array_equal(codes, EncoderGraph(vq, rank)(features).numpy())


@pytest.fixture(scope="module")
def hifigpt_bundle(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from t2m.families.hifigpt.random_bundle import build_random_hifigpt_bundle

    return build_random_hifigpt_bundle(tmp_path_factory.mktemp("hifigpt") / "bundle", check_parity=True)


def test_random_bundles_list_a_checked_encoder(random_bundle: Path, hifigpt_bundle: Path, tmp_path: Path) -> None:
    from t2m.families.masked.random_bundle import build_random_masked_bundle

    masked = build_random_masked_bundle(tmp_path / "masked", max_tokens=20)
    for bundle in (random_bundle, masked, hifigpt_bundle):
        manifest = verify_bundle(bundle)
        assert ENCODER_GRAPH in manifest["files"]
    card = (hifigpt_bundle / "MODEL_CARD.md").read_text()     # the export's parity check, in the card
    assert "- encoder: codes identical to the VQ's encode True (0 differ" in card


def test_an_encoder_of_the_wrong_layout_is_refused(random_bundle: Path, hifigpt_bundle: Path, tmp_path: Path) -> None:
    import shutil

    from t2m.bundle import files_table

    target = tmp_path / "bundle"
    shutil.copytree(random_bundle, target)
    shutil.copy(hifigpt_bundle / ENCODER_GRAPH, target / ENCODER_GRAPH)     # [B, T, R] codes for a [B, T] decoder
    manifest = json.loads((target / "manifest.json").read_text())
    manifest["files"].update(files_table(target, [ENCODER_GRAPH]))
    (target / "manifest.json").write_text(json.dumps(manifest))
    with pytest.raises(BundleError, match=r"encoder\.onnx"):
        verify_bundle(target)


def test_a_bundle_without_an_encoder_is_valid(tmp_path: Path) -> None:
    from t2m.families.gpt.random_bundle import build_random_bundle

    bundle = build_random_bundle(tmp_path / "plain", encoder=False)
    assert ENCODER_GRAPH not in verify_bundle(bundle)["files"]
    assert not (bundle / ENCODER_GRAPH).exists()
