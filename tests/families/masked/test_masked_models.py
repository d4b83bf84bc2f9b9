"""The masked family's networks: the joint map round trip, the joint VQ, the masked and residual transformers (2D and
MoMask's 1D layout), the length estimator, the masking schedule and the reference decoding."""
from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
import torch

from t2m.families.masked.length_estimator import LengthEstimator, LengthEstimatorConfig, sample_length
from t2m.families.masked.masked_transformer import MaskedTransformer
from t2m.families.masked.masking import (
    bert_replace,
    remask_counts,
    residual_layer_schedule,
    temporal_spatial_mask,
)
from t2m.families.masked.residual_transformer import ResidualTransformer
from t2m.families.masked.sampling import generate_token_maps
from t2m.model.networks.joint_layout import (
    features_to_joint_map,
    joint_map_index,
    joint_map_to_features,
    joints_for_dim,
)
from t2m.model.networks.joint_vqvae import JointVQConfig, JointVQVAE
from t2m.model.networks.token_transformer import TokenTransformerConfig
from t2m.model.training.train_vq import vq_loss
from tests.model.synthetic_motion_data import _source_motion

torch.set_num_threads(1)


def tiny(columns: int = 6, **changes) -> TokenTransformerConfig:
    one_d = columns == 1
    config = TokenTransformerConfig(
        codebook_size=16, columns=columns, residual_layers=4, max_tokens=12, latent=32, n_head=2, n_layer=1,
        ff_size=64, dropout=0.0, text_dim=8, code_dim=16, positional="1d" if one_d else "2d",
        spatial_attention=not one_d, temporal_attention=not one_d,
    )
    return replace(config, **changes)


# --- the 263 <-> [22, 12] joint map ---------------------------------------------------------------------------------


@pytest.mark.parametrize("feat_dim", [263, 251])
def test_joint_map_round_trips_exactly_and_places_every_feature_once(feat_dim):
    joints = joints_for_dim(feat_dim)
    index = joint_map_index(joints)
    assert index.shape == (joints, 12)
    used = index[index >= 0]
    assert sorted(used.tolist()) == list(range(feat_dim))  # each feature in exactly one slot
    assert [tuple(x) for x in np.argwhere(index < 0)] == [(0, 8)]
    x = torch.randn(3, 7, feat_dim, dtype=torch.float64) * 1e3
    joint_map = features_to_joint_map(x)
    assert joint_map.shape == (3, 7, joints, 12) and joint_map.dtype == torch.float64
    assert torch.equal(joint_map_to_features(joint_map), x)  # bit for bit
    assert torch.all(joint_map[..., 0, 8] == 0)


def test_joint_map_slots_on_real_motion():
    features, _, _ = _source_motion()
    x = torch.from_numpy(features)
    joint_map = features_to_joint_map(x)
    assert torch.equal(joint_map_to_features(joint_map), x)
    # root: its four features and the foot contacts; joint 5 (right knee... any joint): ric, rotation, velocity
    assert torch.equal(joint_map[:, 0, 0:4], x[:, 0:4])
    assert torch.equal(joint_map[:, 0, 4:8], x[:, 259:263])
    assert torch.equal(joint_map[:, 0, 9:12], x[:, 193:196])
    j = 5
    assert torch.equal(joint_map[:, j, 0:3], x[:, 4 + 3 * (j - 1) : 4 + 3 * j])
    assert torch.equal(joint_map[:, j, 3:9], x[:, 67 + 6 * (j - 1) : 67 + 6 * j])
    assert torch.equal(joint_map[:, j, 9:12], x[:, 193 + 3 * j : 196 + 3 * j])
    with pytest.raises(ValueError, match="12 J - 1"):
        features_to_joint_map(torch.zeros(2, 100))


# --- the joint VQ-VAE -----------------------------------------------------------------------------------------------


@pytest.mark.parametrize("feat_dim, down_j, columns, padding", [
    (263, 0, 22, (0, 0)), (263, 1, 11, (0, 0)), (263, 2, 6, (1, 1)), (251, 2, 6, (1, 2)),
])
def test_joint_vq_shapes(feat_dim, down_j, columns, padding):
    torch.manual_seed(0)
    config = JointVQConfig(feat_dim=feat_dim, width=8, code_dim=8, nb_code=16, down_j=down_j, residual_layers=3,
                           quantizer_dropout=0.0)
    assert config.columns == columns and config.joint_padding == padding
    model = JointVQVAE(config)
    x = torch.randn(2, 32, feat_dim)
    recon, parts = model(x)
    assert recon.shape == x.shape
    assert parts["codes"].shape == (2, 8 * columns, 3)  # the map flattened for train_vq's metrics
    codes = model.encode(torch.randn(1, 30, feat_dim))  # any length: 30 frames -> 7 rows
    assert codes.shape == (1, 7, columns, 3) and codes.dtype == torch.long and int(codes.min()) >= 0
    assert model.decode(codes).shape == (1, 28, feat_dim)
    assert model.decode(codes[..., 0]).shape == (1, 28, feat_dim)  # the first layer alone
    with pytest.raises(ValueError, match="columns"):
        model.decode(torch.zeros(1, 4, columns + 1, 3, dtype=torch.long))


def test_joint_vq_key_names_follow_mogents():
    model = JointVQVAE(JointVQConfig(width=8, code_dim=8, nb_code=16, residual_layers=2))
    keys = set(model.state_dict())
    assert {"encoder2d.model.0.weight", "encoder2d.model.2.0.weight", "encoder2d.model.2.1.model.0.conv1.weight",
            "encoder2d.model.4.weight", "decoder2d.model.0.weight", "decoder2d.model.2.0.model.2.conv2.weight",
            "decoder2d.model.6.weight", "quantizer2d.layers.0.codebook", "quantizer2d.layers.1.codebook"} <= keys
    assert model.state_dict()["encoder2d.model.2.0.weight"].shape == (8, 8, 4, 4)  # halves time and joints
    assert model.state_dict()["decoder2d.model.6.weight"].shape == (12, 8, 3, 3)


def test_joint_vq_quantizer_dropout_uses_the_first_layers_only_in_training():
    torch.manual_seed(0)
    model = JointVQVAE(JointVQConfig(width=8, code_dim=8, nb_code=16, residual_layers=4, quantizer_dropout=1.0))
    x = torch.randn(2, 16, 263)
    active = set()
    for _ in range(30):
        _, parts = model.train()(x)
        layers = model.quantizer2d.last_active_layers
        active.add(layers)
        codes = parts["codes"]
        assert (codes[..., :layers] >= 0).all() and (codes[..., layers:] == -1).all()
    assert active == {1, 2, 3, 4}
    assert (model.eval()(x)[1]["codes"] >= 0).all() and (model.encode(x) >= 0).all()  # eval: every layer


def test_joint_vq_training_steps_lower_the_loss():
    torch.manual_seed(0)
    features, mean, std = _source_motion()
    x = torch.from_numpy((features[:64] - mean) / std)[None].repeat(4, 1, 1)
    model = JointVQVAE(JointVQConfig(width=16, code_dim=16, nb_code=32, residual_layers=2, quantizer_dropout=0.0))
    optimizer = torch.optim.AdamW(model.parameters(), lr=2e-3)
    losses = []
    for _ in range(25):
        loss, _ = vq_loss(model, x)
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
        losses.append(loss.item())
    assert sum(losses[-3:]) / 3 < 0.85 * losses[0], losses


# --- the masking schedule ---------------------------------------------------------------------------------------


def test_remask_counts_follow_the_cosine_schedule_as_momask_and_mogents_count():
    # N = 10 steps, 49 rows: MoMask's 1D counts and MoGenTS's over 49 x 6 tokens (../shared/docs/masked-models.md)
    assert remask_counts(49, 10) == [49, 48, 46, 42, 38, 31, 24, 17, 9, 1]
    assert remask_counts(49, 10, columns=6) == [294, 290, 276, 255, 225, 189, 147, 101, 51, 1]
    for length in range(1, 60):
        counts = remask_counts(length, 10)
        assert counts[0] == length and counts[-1] == 1 and counts == sorted(counts, reverse=True)
    # float32 like torch: cos(pi/3) * 37 rounds to 18 (a float64 count would give 19 at this exact half)
    assert remask_counts(37, 10)[6] == round(float(torch.cos(torch.tensor(6 / 9) * math.pi * 0.5)) * 37)
    with pytest.raises(ValueError):
        remask_counts(0, 10)


def test_temporal_spatial_mask_takes_whole_frames_first_then_tokens_in_every_other_frame():
    generator = torch.Generator().manual_seed(0)
    length = torch.tensor([20, 7, 1, 12])
    ratio = torch.tensor([0.5, 0.3, 0.05, 1.0])
    mask = temporal_spatial_mask(length, 20, 6, ratio, generator=generator)
    assert mask.shape == (4, 20, 6)
    for b in range(4):
        rows = int(length[b])
        per_frame = mask[b, :rows].sum(-1)
        whole = int((per_frame == 6).sum())
        expected_frames = max(1, round(float(ratio[b]) * rows))
        expected_tokens = round(float(ratio[b]) * 6)
        if expected_tokens < 6:  # frames masked whole by the temporal step, exactly round(gamma C) in the others
            assert whole == expected_frames
            assert (per_frame[per_frame != 6] == expected_tokens).all()
        else:
            assert whole == rows
        assert not mask[b, rows:].any()  # never past the length
    one_d = temporal_spatial_mask(length, 20, 1, ratio, spatial=False, generator=generator)
    assert one_d[:, :, 0].sum(-1).tolist() == [10, 2, 1, 12]  # MoMask: max(1, round(gamma * length)) tokens


def test_temporal_mask_frames_are_random():
    generator = torch.Generator().manual_seed(1)
    masks = temporal_spatial_mask(torch.full((400,), 10), 10, 4, torch.full((400,), 0.3), generator=generator)
    whole_frames = (masks.sum(-1) == 4).float().mean(0)  # every frame equally likely to be masked whole
    assert whole_frames.min() > 0.2 and whole_frames.max() < 0.4


def test_bert_replacement_proportions():
    generator = torch.Generator().manual_seed(0)
    tokens = torch.randint(0, 100, (200, 50, 6), generator=generator)
    mask = torch.rand(tokens.shape, generator=generator) < 0.5
    out = bert_replace(tokens, mask, codebook_size=100, mask_id=100, generator=generator)
    assert torch.equal(out[~mask], tokens[~mask])
    masked = out[mask]
    to_mask = (masked == 100).float().mean().item()
    changed_to_code = ((masked != 100) & (masked != tokens[mask])).float().mean().item()
    assert to_mask == pytest.approx(0.8, abs=0.01)
    assert changed_to_code == pytest.approx(0.1 * 0.99, abs=0.01)  # a random code equals the old one 1% of the time
    assert int(masked[masked != 100].max()) < 100


def test_residual_layer_schedule_covers_1_to_r_minus_1_low_layers_more_often():
    layers = residual_layer_schedule(20000, 6, torch.Generator().manual_seed(0))
    counts = torch.bincount(layers, minlength=6).tolist()
    assert counts[0] == 0 and all(c > 0 for c in counts[1:])
    assert counts[1] > counts[3] > counts[5]
    assert residual_layer_schedule(10, 2).unique().tolist() == [1]


# --- the transformers -------------------------------------------------------------------------------------------


@pytest.mark.parametrize("columns", [6, 1])
def test_masked_transformer_shapes_and_independence_from_padding_and_batch(columns):
    torch.manual_seed(0)
    model = MaskedTransformer(tiny(columns)).eval()
    tokens = torch.randint(0, 16, (3, 9, columns))
    cond, length = torch.randn(3, 8), torch.tensor([9, 5, 1])
    logits = model(tokens, cond, length)
    assert logits.shape == (3, 9, columns, 16)
    changed = tokens.clone()
    changed[1, 5:] = 3
    changed[2, 1:] = -1
    torch.testing.assert_close(model(changed, cond, length)[1, :5], logits[1, :5])
    torch.testing.assert_close(model(changed, cond, length)[2, :1], logits[2, :1])
    alone = model(tokens[1:2, :5], cond[1:2], length[1:2])
    torch.testing.assert_close(alone, logits[1:2, :5], atol=1e-5, rtol=1e-5)


def test_masked_transformer_refuses_bad_shapes():
    model = MaskedTransformer(tiny())
    with pytest.raises(ValueError, match="token map"):
        model(torch.zeros(1, 13, 6, dtype=torch.long), torch.zeros(1, 8), torch.tensor([13]))
    with pytest.raises(ValueError, match="cond"):
        model(torch.zeros(1, 4, 6, dtype=torch.long), torch.zeros(1, 5), torch.tensor([4]))


def test_the_null_condition_is_the_condition_embedding_bias():
    model = MaskedTransformer(tiny()).eval()
    torch.nn.init.normal_(model.cond_emb.bias)
    tokens, length = torch.randint(0, 16, (1, 4, 6)), torch.tensor([4])
    a = model(tokens, torch.zeros(1, 8), length)
    torch.nn.init.normal_(model.cond_emb.weight)  # the weight plays no part in the null condition
    torch.testing.assert_close(model(tokens, torch.zeros(1, 8), length), a)


def test_stacks_follow_the_config():
    assert {"seqTransEncoder2", "seqTransEncoder3"} <= {n for n, _ in MaskedTransformer(tiny()).named_children()}
    plain = MaskedTransformer(tiny(spatial_attention=False, temporal_attention=False))
    assert not any(n.startswith(("seqTransEncoder2", "seqTransEncoder3")) for n in plain.state_dict())
    with pytest.raises(ValueError, match="1D positions"):
        tiny(columns=6, positional="1d")


def test_temporal_mask_cond_hides_the_text_from_the_temporal_stack_only():
    torch.manual_seed(0)
    model = MaskedTransformer(tiny(spatial_attention=False)).eval()
    tokens, length, cond = torch.randint(0, 16, (1, 5, 6)), torch.tensor([5]), torch.randn(1, 8)
    hidden = MaskedTransformer(tiny(spatial_attention=False, temporal_mask_cond=True)).eval()
    hidden.load_state_dict(model.state_dict())
    assert not torch.allclose(hidden(tokens, cond, length), model(tokens, cond, length))


def test_residual_transformer_sees_only_the_layers_below_the_one_it_predicts():
    torch.manual_seed(0)
    model = ResidualTransformer(tiny()).eval()
    codes = torch.randint(0, 16, (2, 6, 6, 4))
    cond, length = torch.randn(2, 8), torch.tensor([6, 4])
    for q in (1, 2, 3):
        layer = torch.full((2,), q)
        logits = model(codes, layer, cond, length)
        assert logits.shape == (2, 6, 6, 17)  # K codes + pad
        changed = codes.clone()
        changed[..., q:] = torch.randint(0, 16, changed[..., q:].shape)
        torch.testing.assert_close(model(changed, layer, cond, length), logits)
        if q > 1:
            changed[..., q - 1] = (codes[..., q - 1] + 1) % 16
            assert not torch.allclose(model(changed, layer, cond, length), logits)
    mixed = model(codes, torch.tensor([1, 3]), cond, length)  # a layer per motion, as in training
    torch.testing.assert_close(mixed[1], model(codes, torch.tensor([3, 3]), cond, length)[1])


@pytest.mark.parametrize("share", [True, False])
def test_residual_weight_sharing_ties_embeddings_to_classifiers(share):
    model = ResidualTransformer(tiny(share_weight=share))
    inputs, outputs = model.input_tables(), model.output_tables()
    assert inputs.shape == outputs.shape == (3, 17, 16)
    # shared: embedding of layer k (k = 1, 2) is the classifier of layer k
    assert torch.equal(inputs[1:], outputs[:-1]) == share
    names = {n for n, _ in model.named_parameters()}
    assert ({"token_embed_weight_", "embed_proj_shared_weight", "output_proj_weight_"} <= names) == share


def momask_sized(columns: int, stacks: bool, **changes) -> TokenTransformerConfig:
    config = TokenTransformerConfig(
        codebook_size=512, columns=columns, residual_layers=6, latent=384, n_head=6, n_layer=8, ff_size=1024,
        dropout=0.2, text_dim=512, code_dim=512, max_tokens=49, positional="2d" if stacks else "1d",
        spatial_attention=stacks, temporal_attention=stacks,
    )
    return replace(config, **changes)


def test_released_key_layouts():
    """Tensor counts and shapes of MoMask's t2m_transformer (108) / res_transformer (112) / estimator (14) and of
    MoGenTS's t2m_transformer_ts (300), ../shared/docs/masked-models.md, at the released sizes."""
    masked = MaskedTransformer(momask_sized(1, stacks=False)).state_dict()
    assert len(masked) == 108
    assert masked["token_emb.weight"].shape == (514, 512) and masked["position_enc.pe"].shape[1:] == (1, 384)
    assert masked["seqTransEncoder.layers.7.self_attn.in_proj_weight"].shape == (1152, 384)
    assert masked["seqTransEncoder.layers.0.linear1.weight"].shape == (1024, 384)
    assert masked["output_process.poseFinal.weight"].shape == (512, 384)
    assert masked["output_process.LayerNorm.weight"].shape == (384,)
    assert masked["cond_emb.weight"].shape == (384, 512)
    parameters = {"masked": 12_048_768, "residual": 13_364_224, "ts": 34_239_616}  # as released (PE is a buffer)
    assert sum(v.numel() for k, v in masked.items() if not k.endswith(".pe")) == parameters["masked"]
    residual = ResidualTransformer(momask_sized(1, stacks=False)).state_dict()
    assert len(residual) == 112
    assert residual["embed_proj_shared_weight"].shape == (4, 513, 512)
    assert residual["token_embed_weight_"].shape == residual["output_proj_weight_"].shape == (1, 513, 512)
    assert residual["quant_emb.weight"].shape == (384, 6)
    assert residual["output_process.poseFinal.weight"].shape == (512, 384)
    assert sum(v.numel() for k, v in residual.items() if not k.endswith(".pe")) == parameters["residual"]
    estimator = LengthEstimator(LengthEstimatorConfig(text_dim=512, hidden=512, max_tokens=49)).state_dict()
    assert len(estimator) == 14 and estimator["output.11.weight"].shape == (50, 128)
    assert estimator["output.0.weight"].shape == (512, 512) and estimator["output.9.weight"].shape == (128,)
    ts = MaskedTransformer(momask_sized(6, stacks=True, codebook_size=256, code_dim=1024)).state_dict()
    assert len(ts) == 300
    assert ts["token_emb.weight"].shape == (258, 1024) and ts["position2d_enc.pe"].shape[1:] == (6, 384)
    assert ts["seqTransEncoder3.layers.7.norm2.weight"].shape == (384,)
    assert sum(v.numel() for k, v in ts.items() if not k.endswith(".pe")) == parameters["ts"]


def test_2d_positions_encode_column_then_row():
    model = MaskedTransformer(tiny(latent=32))
    pe = model.position2d_enc.pe  # [rows, columns, 32]
    assert pe.shape == (13, 6, 32)
    torch.testing.assert_close(pe[0, :, 0], torch.sin(torch.arange(6.0)))  # channel 0 = sin(column)
    torch.testing.assert_close(pe[:, 2, 0], torch.full((13,), math.sin(2.0)))  # the column half ignores the row
    torch.testing.assert_close(pe[3, :, 16], torch.full((6,), math.sin(3.0)))  # the row half ignores the column
    torch.testing.assert_close(pe[3, 0, 17], torch.tensor(math.cos(3.0)))


# --- length estimator and decoding ------------------------------------------------------------------------------


def test_length_sampling_is_seeded_and_never_zero():
    estimator = LengthEstimator(LengthEstimatorConfig(text_dim=8, hidden=16, max_tokens=10)).eval()
    logits = estimator(torch.randn(200, 8))
    assert logits.shape == (200, 11)
    logits[:, 0] = 100.0  # even when 0 rows is the likeliest, it is never drawn
    a = sample_length(logits, torch.Generator().manual_seed(3))
    b = sample_length(logits, torch.Generator().manual_seed(3))
    assert torch.equal(a, b) and a.min() >= 1 and a.max() <= 10 and a.dtype == torch.long


@pytest.mark.parametrize("columns", [6, 1])
def test_decoding_fills_the_map_and_runs_the_residual_once_per_layer(columns):
    torch.manual_seed(0)
    masked, residual = MaskedTransformer(tiny(columns)), ResidualTransformer(tiny(columns))
    cond, rows = torch.randn(2, 8), [7, 3]
    calls = []
    masked.register_forward_hook(lambda *args: calls.append("masked"))
    residual.register_forward_hook(lambda *args: calls.append("residual"))
    codes = generate_token_maps(masked, residual, cond, rows, steps=4, guidance=2.0, residual_guidance=3.0, top_k=5,
                                rng=0)
    assert calls == ["masked"] * 4 + ["residual"] * 3  # one batched pass (cond + null rows) per step; R - 1 = 3
    assert codes.shape == (2, 7, columns, 4)
    assert (codes[0, ..., 0] >= 0).all() and (codes[1, :3, :, 0] >= 0).all() and (codes[1, 3:] == -1).all()
    assert (codes[0] >= -1).all() and (codes[0] < 16).all()
    again = generate_token_maps(masked, residual, cond, rows, steps=4, guidance=2.0, residual_guidance=3.0, top_k=5,
                                rng=0)
    np.testing.assert_array_equal(codes, again)


def test_encoder_layer_computes_what_torchs_transformer_layer_does():
    """Released MoMask/MoGenTS weights are nn.TransformerEncoderLayer's (post-LN, GELU): same keys, same function."""
    from t2m.model.networks.token_transformer import EncoderLayer

    torch.manual_seed(0)
    config = tiny()
    reference = torch.nn.TransformerEncoderLayer(32, 2, 64, 0.0, activation="gelu", batch_first=True).eval()
    layer = EncoderLayer(config).eval()
    layer.load_state_dict(reference.state_dict(), strict=True)
    x = torch.randn(3, 7, 32)
    keys = torch.ones(3, 7, dtype=torch.bool)
    keys[1, 4:] = False
    with torch.no_grad():
        expected = reference(x, src_key_padding_mask=~keys)
        actual = layer(x, keys)
    torch.testing.assert_close(actual[keys], expected[keys], atol=1e-5, rtol=1e-5)
