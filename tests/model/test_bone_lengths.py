"""BoneLengths (the VQ-VAE's bone-length term) against the joints that motion.features recovers."""
from __future__ import annotations

import numpy as np
import pytest
import torch

from t2m.model.networks.vqvae import MotionVQVAE, VQConfig
from t2m.model.training.bone_lengths import BoneLengths
from t2m.model.training.train_vq import vq_loss
from t2m.motion.features import features_to_joints
from t2m.motion.skeleton import SMPL22
from tests.model.synthetic_motion_data import _source_motion

torch.set_num_threads(1)


def normalised_sample() -> tuple[torch.Tensor, np.ndarray, np.ndarray, np.ndarray]:
    features, mean, std = _source_motion()
    return torch.from_numpy((features - mean) / std).float(), features, mean, std


def test_bone_lengths_match_the_joints_recovered_from_the_features():
    """The root-frame shortcut gives the same lengths as the full recovery (root rotation + trajectory)."""
    normalised, features, mean, std = normalised_sample()
    joints = features_to_joints(features, SMPL22)
    expected = np.linalg.norm(joints[:, 1:] - joints[:, list(SMPL22.parents[1:])], axis=-1)
    measured = BoneLengths(mean, std, SMPL22.parents)(normalised).numpy()
    assert measured.shape == (len(features), 21)
    np.testing.assert_allclose(measured, expected, atol=1e-4)
    assert expected.min() > 0.03  # real bones, not a degenerate skeleton that would match anything


def test_bone_lengths_refuse_a_skeleton_that_does_not_fit_the_features():
    with pytest.raises(ValueError, match="263 feature channels"):
        BoneLengths(np.zeros(263, np.float32), np.ones(263, np.float32), (-1, 0, 1))


def test_vq_loss_adds_the_weighted_bone_term_and_its_gradient():
    normalised, _, mean, std = normalised_sample()
    torch.manual_seed(0)
    model = MotionVQVAE(VQConfig(width=32, code_dim=16, nb_code=32)).eval()
    bones = BoneLengths(mean, std, SMPL22.parents)
    x = torch.stack([normalised[:64], normalised[40:104]])
    base, base_parts = vq_loss(model, x)
    weighted, parts = vq_loss(model, x, bones=bones, bone_weight=2.0)
    assert "bone_m" not in base_parts and parts["bone_m"] > 0.005  # an untrained decoder gets bones wrong
    assert float((weighted - base).detach()) == pytest.approx(2.0 * parts["bone_m"], rel=1e-4)
    recon = x.clone().requires_grad_(True)
    torch.nn.functional.l1_loss(bones(recon + 0.1), bones(x)).backward()
    assert recon.grad is not None and float(recon.grad.abs().sum()) > 0

