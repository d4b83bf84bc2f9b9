"""MDM / DiP modules (t2m.families.diffusion.network): the released state-dict layouts key by key (built on the meta
device, no memory), the hard-coded sizes, loading, and the forward's conventions on tiny random weights: condition
token at position 0, zero text as the null condition, frame and text masks, DiP's prefix."""
from __future__ import annotations

import pytest
import torch

from t2m.families.diffusion.network import MDM, DiffusionConfig, released_weights

torch.set_num_threads(1)

E, F = 512, 263


def released_layout(decoder: bool, text_dim: int) -> dict[str, tuple[int, ...]]:
    """The keys and shapes listed in ../shared/docs/diffusion-models.md §4.3 (written out from the list)."""
    layout: dict[str, tuple[int, ...]] = {
        "input_process.poseEmbedding.weight": (E, F), "input_process.poseEmbedding.bias": (E,),
        "sequence_pos_encoder.pe": (5000, 1, E),
        "embed_timestep.sequence_pos_encoder.pe": (5000, 1, E),
        "embed_timestep.time_embed.0.weight": (E, E), "embed_timestep.time_embed.0.bias": (E,),
        "embed_timestep.time_embed.2.weight": (E, E), "embed_timestep.time_embed.2.bias": (E,),
        "embed_text.weight": (E, text_dim), "embed_text.bias": (E,),
        "output_process.poseFinal.weight": (F, E), "output_process.poseFinal.bias": (F,),
    }
    stack = "seqTransDecoder" if decoder else "seqTransEncoder"
    attentions = ("self_attn", "multihead_attn") if decoder else ("self_attn",)
    norms = ("norm1", "norm2", "norm3") if decoder else ("norm1", "norm2")
    for i in range(8):
        p = f"{stack}.layers.{i}."
        for attention in attentions:
            layout |= {p + f"{attention}.in_proj_weight": (3 * E, E), p + f"{attention}.in_proj_bias": (3 * E,),
                       p + f"{attention}.out_proj.weight": (E, E), p + f"{attention}.out_proj.bias": (E,)}
        layout |= {p + "linear1.weight": (1024, E), p + "linear1.bias": (1024,),
                   p + "linear2.weight": (E, 1024), p + "linear2.bias": (E,)}
        for norm in norms:
            layout |= {p + f"{norm}.weight": (E,), p + f"{norm}.bias": (E,)}
    return layout


def meta_model(config: DiffusionConfig) -> MDM:
    with torch.device("meta"):
        return MDM(config)


@pytest.mark.parametrize("config, decoder, text_dim, tensors, parameters", [
    (DiffusionConfig.mdm(), False, 512, 108, 17_880_327),
    (DiffusionConfig.mdm(steps=50), False, 512, 108, 17_880_327),
    (DiffusionConfig.dip(), True, 768, 156, 26_424_583),
])
def test_released_layout(config, decoder, text_dim, tensors, parameters):
    model = meta_model(config)
    shapes = {key: tuple(value.shape) for key, value in model.state_dict().items()}
    assert shapes == released_layout(decoder, text_dim)
    assert len(shapes) == tensors
    assert sum(p.numel() for p in model.parameters()) == parameters


def test_control_layout_check_sees_a_wrong_size():
    """Control: a model with another ff size (the value args.json cannot change) fails the layout comparison."""
    model = meta_model(DiffusionConfig(ff_size=2048))
    shapes = {key: tuple(value.shape) for key, value in model.state_dict().items()}
    assert shapes != released_layout(False, 512)


def test_released_hyper_parameters():
    mdm, dip = DiffusionConfig.mdm(), DiffusionConfig.dip()
    for config in (mdm, dip):
        assert (config.latent_dim, config.layers, config.ff_size, config.heads) == (512, 8, 1024, 4)
        assert (config.dropout, config.activation, config.pos_embed_max_len) == (0.1, "gelu", 5000)
    assert (mdm.arch, mdm.text_dim, mdm.text_tokens, mdm.diffusion_steps) == ("trans_enc", 512, False, 1000)
    assert (dip.arch, dip.text_dim, dip.text_tokens, dip.diffusion_steps) == ("trans_dec", 768, True, 10)
    assert (dip.context_len, dip.pred_len) == (20, 40)


@torch.no_grad()
@pytest.mark.parametrize("decoder", [False, True])
def test_layers_compute_what_torchs_transformer_layers_compute(decoder):
    """The written-out layers under torch's names: load a torch post-norm GELU layer's state dict strictly and give
    its outputs (with key masks), so the released weights mean what they meant to the official nn.Transformer*."""
    torch.manual_seed(1)
    layer_type = torch.nn.TransformerDecoderLayer if decoder else torch.nn.TransformerEncoderLayer
    theirs = layer_type(16, 2, 32, 0.1, "gelu").eval()                    # sequence first, post-norm
    model = tiny(arch="trans_dec" if decoder else "trans_enc", text_tokens=decoder)
    ours = (model.seqTransDecoder if decoder else model.seqTransEncoder).layers[0]
    ours.load_state_dict(theirs.state_dict())
    x, memory = torch.randn(2, 6, 16), torch.randn(2, 4, 16)
    keys = torch.tensor([[True] * 6, [True] * 4 + [False] * 2])
    memory_keys = torch.tensor([[True] * 4, [True, True, False, False]])
    if decoder:
        expected = theirs(x.transpose(0, 1), memory.transpose(0, 1), tgt_key_padding_mask=~keys,
                          memory_key_padding_mask=~memory_keys).transpose(0, 1)
        got = ours(x, keys, memory, memory_keys)
    else:
        expected = theirs(x.transpose(0, 1), src_key_padding_mask=~keys).transpose(0, 1)
        got = ours(x, keys)
    torch.testing.assert_close(got, expected, rtol=0, atol=1e-5)
    # control: the same weights under another layer order (pre-norm) are another function
    pre_norm = layer_type(16, 2, 32, 0.1, "gelu", norm_first=True).eval()
    pre_norm.load_state_dict(theirs.state_dict())
    other = (pre_norm(x.transpose(0, 1), memory.transpose(0, 1)) if decoder
             else pre_norm(x.transpose(0, 1))).transpose(0, 1)
    assert (other - ours(x, None, memory, None) if decoder else other - ours(x, None)).abs().max() > 1e-2


def test_config_from_args_json():
    assert DiffusionConfig.from_args({}) == DiffusionConfig.mdm()
    dip = DiffusionConfig.from_args({"arch": "trans_dec", "text_encoder_type": "bert", "diffusion_steps": 10,
                                     "context_len": 20, "pred_len": 40, "mask_frames": True, "use_ema": True})
    assert dip == DiffusionConfig.dip()
    assert DiffusionConfig.from_args({"context_len": 20}).pred_len == 20      # pred_len defaults to context_len
    assert DiffusionConfig.from_args({"dataset": "kit"}).features == 251
    assert DiffusionConfig.from_dict(DiffusionConfig.dip().to_dict()) == DiffusionConfig.dip()


@pytest.mark.parametrize("args", [
    {"arch": "gru"}, {"text_encoder_type": "bert"}, {"noise_schedule": "linear"}, {"sigma_small": False},
    {"lambda_target_loc": 1.0}, {"multi_target_cond": True}, {"dataset": "humanact12"}, {"emb_policy": "concat"},
])
def test_config_refuses_what_it_does_not_build(args):
    with pytest.raises(ValueError):
        DiffusionConfig.from_args(args)


def tiny(**overrides) -> MDM:
    torch.manual_seed(0)
    settings = {"features": 7, "latent_dim": 16, "layers": 2, "heads": 2, "ff_size": 32, "text_dim": 5,
                "diffusion_steps": 10, "pos_embed_max_len": 64} | overrides
    return MDM(DiffusionConfig(**settings)).eval()


def test_loading_released_weights_recomputes_pe_and_picks_ema():
    model = tiny()
    plain = {k: v.clone() for k, v in model.state_dict().items()}
    other = {k: v + 1 for k, v in plain.items()}
    for key in ("sequence_pos_encoder.pe", "embed_timestep.sequence_pos_encoder.pe"):
        other[key] = torch.zeros(3, 1, 16)                    # any saved table: replaced by the computed one
    other["clip_model.token_embedding.weight"] = torch.zeros(2)
    released_weights_ema = released_weights({"model": plain, "model_avg": other}, use_ema=True)
    assert "clip_model.token_embedding.weight" not in released_weights_ema
    fresh = tiny()
    fresh.load_state_dict(released_weights_ema)
    assert torch.equal(fresh.embed_text.weight, plain["embed_text.weight"] + 1)
    assert torch.equal(fresh.sequence_pos_encoder.pe, plain["sequence_pos_encoder.pe"])
    assert fresh.embed_timestep.sequence_pos_encoder is fresh.sequence_pos_encoder
    fresh.load_state_dict(released_weights({"model": plain, "model_avg": other}, use_ema=False))
    assert torch.equal(fresh.embed_text.weight, plain["embed_text.weight"])
    assert released_weights(plain, use_ema=False).keys() == plain.keys()
    with pytest.raises(ValueError):
        released_weights(plain, use_ema=True)
    with pytest.raises(ValueError):
        released_weights({"model": plain}, use_ema=True)


def manual_trans_enc(model: MDM, x: torch.Tensor, t: torch.Tensor, text: torch.Tensor) -> torch.Tensor:
    """The trans_enc layout spelled out: [time MLP(pe[t]) + W text + b, frames], pe rows 0..T added, token 0
    dropped."""
    pe = model.sequence_pos_encoder.pe[:, 0]
    condition = model.embed_timestep.time_embed(pe[t]) + model.embed_text(text)          # [B, E]
    frames = model.input_process.poseEmbedding(x)                                          # [B, T, E]
    sequence = torch.cat([condition[:, None], frames], dim=1) + pe[: x.shape[1] + 1]
    out = model.seqTransEncoder(sequence, None)[:, 1:]
    return model.output_process.poseFinal(out)


@torch.no_grad()
def test_trans_enc_condition_token_at_position_zero():
    model = tiny()
    x, t, text = torch.randn(2, 6, 7), torch.tensor([9, 3]), torch.randn(2, 5)
    torch.testing.assert_close(model(x, t, text), manual_trans_enc(model, x, t, text), rtol=0, atol=1e-6)
    # control: the frames at pe rows 0..T-1 (no room for the token) is another function
    model.sequence_pos_encoder.pe[1:] = model.sequence_pos_encoder.pe[:-1].clone()
    assert (model(x, t, text) - manual_trans_enc(tiny(), x, t, text)).abs().max() > 1e-3


@torch.no_grad()
@pytest.mark.parametrize("arch, tokens", [("trans_enc", False), ("trans_dec", False), ("trans_dec", True)])
def test_zero_text_is_the_null_condition(arch, tokens):
    """With zero text the projection's weight cannot matter (the null token is embed_text.bias + time); a real
    text does depend on it (control)."""
    model = tiny(arch=arch, text_tokens=tokens)
    x, t = torch.randn(2, 6, 7), torch.tensor([4, 4])
    text = torch.randn(2, 3, 5) if tokens else torch.randn(2, 5)
    mask = torch.tensor([[True, True, True], [True, False, False]]) if tokens else None
    null = torch.zeros_like(text)
    before_null, before_text = model(x, t, null, mask), model(x, t, text, mask)
    model.embed_text.weight.normal_()
    assert torch.equal(model(x, t, null, mask), before_null)
    assert (model(x, t, text, mask) - before_text).abs().max() > 1e-3


@torch.no_grad()
def test_text_padding_tokens_are_ignored():
    model = tiny(arch="trans_dec", text_tokens=True)
    x, t = torch.randn(1, 6, 7), torch.tensor([2])
    text, mask = torch.randn(1, 4, 5), torch.tensor([[True, True, False, False]])
    other = text.clone()
    other[:, 2:] = 9.0
    torch.testing.assert_close(model(x, t, other, mask), model(x, t, text, mask), rtol=0, atol=1e-6)
    assert (model(x, t, other, torch.ones_like(mask)) - model(x, t, text, mask)).abs().max() > 1e-3   # control


@torch.no_grad()
@pytest.mark.parametrize("arch, tokens", [("trans_enc", False), ("trans_dec", True)])
def test_mask_frames_keeps_padding_out(arch, tokens):
    """mask_frames: a short row's valid frames ignore what is past its length; the 2022 models (no mask_frames)
    let it leak (control)."""
    x, t = torch.randn(1, 8, 7), torch.tensor([5])
    text = torch.randn(1, 3, 5) if tokens else torch.randn(1, 5)
    mask = torch.ones(1, 3, dtype=torch.bool) if tokens else None
    length = torch.tensor([5])
    padded = x.clone()
    padded[:, 5:] = 3.0
    for mask_frames, leaks in ((True, False), (False, True)):
        model = tiny(arch=arch, text_tokens=tokens, mask_frames=mask_frames)
        change = (model(padded, t, text, mask, length) - model(x, t, text, mask, length))[:, :5].abs().max()
        assert (change > 1e-3) == leaks


@torch.no_grad()
@pytest.mark.parametrize("emb_trans_dec", [False, True])
def test_dip_prefix_is_attended_to_but_not_returned(emb_trans_dec):
    model = tiny(arch="trans_dec", text_tokens=True, mask_frames=True, context_len=4, pred_len=6,
                 emb_trans_dec=emb_trans_dec)
    x, prefix, t = torch.randn(2, 6, 7), torch.randn(2, 4, 7), torch.tensor([3, 3])
    text, mask = torch.randn(2, 3, 5), torch.ones(2, 3, dtype=torch.bool)
    out = model(x, t, text, mask, torch.tensor([6, 6]), prefix)
    assert out.shape == (2, 6, 7)
    whole = model(torch.cat([prefix, x], dim=1), t, text, mask, torch.tensor([10, 10]))
    torch.testing.assert_close(out, whole[:, 4:], rtol=0, atol=1e-6)
    assert (model(x, t, text, mask, torch.tensor([6, 6]), prefix + 1) - out).abs().max() > 1e-3   # control


def test_eval_is_deterministic_and_token_states_need_a_mask():
    model = tiny(arch="trans_dec", text_tokens=True)
    x, t, text = torch.randn(1, 6, 7), torch.tensor([1]), torch.randn(1, 2, 5)
    mask = torch.ones(1, 2, dtype=torch.bool)
    assert torch.equal(model(x, t, text, mask), model(x, t, text, mask))
    with pytest.raises(ValueError):
        model(x, t, text)
    with pytest.raises(ValueError):
        DiffusionConfig(text_tokens=True)           # trans_enc + token states: the official code asserts
    with pytest.raises(ValueError):
        DiffusionConfig(activation="relu")
