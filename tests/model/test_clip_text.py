"""OpenAI CLIP's text tower and its loader, on random weights in the exact format of OpenAI's ViT-B-32.pt (a
TorchScript archive with visual keys and float16 tensors, or a plain state dict), at small sizes: the file loads,
the tower computes what an independent functional forward computes, the ONNX text graph agrees, and wrong files
are refused with one line naming the key and the shape expected."""
from __future__ import annotations

import json
import warnings

import numpy as np
import pytest
import torch
import torch.nn.functional as F

from t2m.model.networks.clip_text import ClipTextConfig
from t2m.model.networks.clip_weights import ClipWeightsError, load_clip_text, read_clip_state
from t2m.model.networks.text_encoders import ClipEncoder, get_text_encoder
from t2m.testing.clip_release import openai_clip_state, save_torchscript_archive

torch.set_num_threads(1)
SMALL = {"width": 128, "layers": 2, "embed_dim": 48}  # 2 heads of 64, OpenAI's vocabulary and context
TEXTS = ["a person walks forward", "someone waves with the left hand while jumping up and down", "bow",
         "a man runs " * 30]  # the last one is cut to 77 tokens


@pytest.fixture(scope="module")
def small_state() -> dict[str, torch.Tensor]:
    return openai_clip_state(**SMALL, seed=4)


@pytest.fixture(scope="module")
def small_files(small_state, tmp_path_factory) -> dict[str, object]:
    folder = tmp_path_factory.mktemp("clip")
    plain = folder / "ViT-B-32-state-dict.pt"
    torch.save(small_state, plain)
    return {"archive": save_torchscript_archive(small_state, folder / "ViT-B-32.pt"), "state_dict": plain}


@pytest.fixture(scope="module")
def encoder(small_files) -> ClipEncoder:
    return get_text_encoder("clip", weights=small_files["archive"])


@torch.no_grad()
def functional_encode_text(state: dict[str, torch.Tensor], ids: torch.Tensor, heads: int) -> torch.Tensor:
    """OpenAI's encode_text from the raw tensors, attention by torch's own multi_head_attention_forward (which
    defines the packed in_proj layout and the head split), QuickGELU in the MLP."""
    s = {k: v.float() for k, v in state.items()}
    width, length = s["token_embedding.weight"].shape[1], ids.shape[1]
    x = s["token_embedding.weight"][ids] + s["positional_embedding"][:length]
    mask = torch.full((length, length), float("-inf")).triu(1)
    layers = sum(1 for k in s if k.startswith("transformer.resblocks.") and k.endswith(".ln_1.weight"))
    for i in range(layers):
        p = f"transformer.resblocks.{i}."
        h = F.layer_norm(x, (width,), s[p + "ln_1.weight"], s[p + "ln_1.bias"]).transpose(0, 1)
        attended, _ = F.multi_head_attention_forward(
            h, h, h, width, heads, s[p + "attn.in_proj_weight"], s[p + "attn.in_proj_bias"], None, None, False, 0.0,
            s[p + "attn.out_proj.weight"], s[p + "attn.out_proj.bias"], training=False, need_weights=False,
            attn_mask=mask)
        x = x + attended.transpose(0, 1)
        h = F.linear(F.layer_norm(x, (width,), s[p + "ln_2.weight"], s[p + "ln_2.bias"]),
                     s[p + "mlp.c_fc.weight"], s[p + "mlp.c_fc.bias"])
        x = x + F.linear(h * torch.sigmoid(1.702 * h), s[p + "mlp.c_proj.weight"], s[p + "mlp.c_proj.bias"])
    x = F.layer_norm(x, (width,), s["ln_final.weight"], s["ln_final.bias"])
    return x[torch.arange(len(ids)), ids.argmax(-1)] @ s["text_projection"]


def test_archive_and_state_dict_give_the_same_tower_with_sizes_from_the_weights(small_files, small_state):
    with warnings.catch_warnings():  # why a loader is needed at all: weights_only refuses OpenAI's archive
        warnings.simplefilter("ignore")
        with pytest.raises(RuntimeError):
            torch.load(small_files["archive"], weights_only=True)
    stored = read_clip_state(small_files["archive"])
    assert stored["text_projection"].dtype == torch.float16 and stored["ln_final.weight"].dtype == torch.float32
    assert {"visual.proj", "logit_scale", "vocab_size"} <= set(stored)
    from_archive, from_dict = load_clip_text(small_files["archive"]), load_clip_text(small_files["state_dict"])
    assert from_archive.config == from_dict.config == ClipTextConfig(
        vocab_size=49408, context_length=77, width=128, layers=2, heads=2, embed_dim=48)
    for (name, a), (_, b) in zip(from_archive.state_dict().items(), from_dict.state_dict().items()):
        assert a.dtype == torch.float32 and torch.equal(a, b), name
    assert not any(p.requires_grad for p in from_archive.parameters())


def test_tower_matches_a_functional_forward_of_the_raw_tensors(encoder, small_state):
    ids, _ = encoder.tokenize(TEXTS)
    assert ids.shape == (4, 77) and ids[3, -1] == 49407  # truncated, end token kept last
    ours = encoder.encode(TEXTS)
    reference = functional_encode_text(small_state, ids, heads=2).numpy()
    assert ours.shape == (4, 48) and ours.dtype == np.float32
    assert np.abs(ours - reference).max() <= 1e-5
    assert not np.allclose(np.linalg.norm(ours, axis=1), 1.0, atol=1e-3)  # raw encode_text, not normalised
    assert np.abs(encoder.encode([TEXTS[2]])[0] - ours[2]).max() <= 1e-5  # batch-independent


def test_quickgelu_is_what_the_tower_uses(encoder, small_state):
    """The same tensors through GELU give other features: the activation is not a detail."""
    ids, _ = encoder.tokenize(TEXTS[:2])
    quick = functional_encode_text(small_state, ids, heads=2)
    original = torch.sigmoid
    try:  # GELU(x) = x * Phi(x); patch the forward's x * sigmoid(1.702 x) into x * Phi(x)
        torch.sigmoid = lambda t: 0.5 * (1 + torch.erf(t / 1.702 / 2**0.5))
        gelu = functional_encode_text(small_state, ids, heads=2)
    finally:
        torch.sigmoid = original
    assert (quick - gelu).abs().max() > 1e-3


def test_onnx_text_graph_matches_pytorch(encoder, tmp_path):
    from t2m.export.graphs.export import ort_session
    from t2m.export.graphs.text import tokenize
    from t2m.export.kit.text_sources import encoder_text_source

    entry = encoder_text_source(encoder).write(tmp_path)
    assert entry == {"kind": "clip", "dim": 48, "max_length": 77, "pooling": "eot", "normalize": False,
                     "null_condition": "zeros"}
    ids, mask = tokenize(tmp_path / "tokenizer.json", TEXTS)
    assert ids.shape == (4, 77) and mask[2].sum() == 3  # the longest is cut to 77, the others zero padded
    session = ort_session(tmp_path / "text_encoder.onnx")
    assert [i.name for i in session.get_inputs()] == ["input_ids", "attention_mask"]
    (features,) = session.run(None, {"input_ids": ids.numpy(), "attention_mask": mask.numpy()})
    assert np.abs(features - encoder.encode(TEXTS)).max() <= 1e-5
    short_ids, short_mask = tokenize(tmp_path / "tokenizer.json", TEXTS[:3])  # padded to their longest
    longest = int(short_mask.sum(1).max())
    assert short_ids.shape == (3, longest) and torch.equal(short_ids, ids[:3, :longest])
    assert ids[:3, longest:].eq(0).all()
    (short,) = session.run(None, {"input_ids": short_ids.numpy(), "attention_mask": short_mask.numpy()})
    assert np.abs(short - features[:3]).max() <= 1e-5  # causal attention: what follows the end token is never seen
    assert json.loads((tmp_path / "tokenizer.json").read_text())["padding"]["strategy"] == "BatchLongest"


# ------------------------------------------------------------------------------------------------- refusals

def _without(state: dict, key: str) -> dict:
    return {k: v for k, v in state.items() if k != key}


def _reshaped(state: dict, key: str, shape: tuple[int, ...]) -> dict:
    return {**state, key: torch.zeros(shape, dtype=state[key].dtype)}


REFUSALS = {
    "missing key": (lambda s: _without(s, "transformer.resblocks.1.mlp.c_proj.bias"),
                    "missing tensor 'transformer.resblocks.1.mlp.c_proj.bias' [128]"),
    "missing final norm": (lambda s: _without(s, "ln_final.weight"), "missing tensor 'ln_final.weight' [128]"),
    "wrong shape": (lambda s: _reshaped(s, "transformer.resblocks.0.attn.in_proj_weight", (384, 127)),
                    "tensor 'transformer.resblocks.0.attn.in_proj_weight' has shape [384, 127], expected [384, 128]"),
    "wrong projection rank": (lambda s: _reshaped(s, "text_projection", (128,)),
                              "tensor 'text_projection' has shape [128], expected [width, embed_dim]"),
    "not a CLIP file": (lambda s: {"trans_base.tok_emb.weight": torch.zeros(3, 4)},
                        "missing tensor 'token_embedding.weight' [vocab, width]; is this OpenAI's CLIP"),
}


@pytest.mark.parametrize("case", sorted(REFUSALS))
@pytest.mark.parametrize("form", ["archive", "state_dict"])
def test_wrong_files_are_refused_naming_key_and_shape(case, form, small_state, tmp_path):
    change, message = REFUSALS[case]
    path = tmp_path / "bad.pt"
    state = change(small_state)
    save_torchscript_archive(state, path) if form == "archive" else torch.save(state, path)
    with pytest.raises(ClipWeightsError) as error:
        load_clip_text(path)
    assert message in str(error.value) and str(error.value).startswith(str(path))
    assert "\n" not in str(error.value)


def test_truncated_foreign_and_missing_files_are_refused(small_files, tmp_path):
    for name in ("archive", "state_dict"):
        data = small_files[name].read_bytes()
        cut = tmp_path / f"cut-{name}.pt"
        cut.write_bytes(data[: len(data) // 2])
        with pytest.raises(ClipWeightsError, match=r"not a complete PyTorch file .*expected OpenAI's CLIP"):
            load_clip_text(cut)
    text = tmp_path / "notes.txt"
    text.write_text("not weights")
    with pytest.raises(ClipWeightsError, match="not a complete PyTorch file"):
        load_clip_text(text)
    release = tmp_path / "net_last.pth"
    torch.save({"net": {"vqvae.encoder.model.0.weight": torch.zeros(2)}}, release)
    with pytest.raises(ClipWeightsError, match=r"holds a dict with keys \['net'\], not a dict of tensors"):
        load_clip_text(release)
    with pytest.raises(FileNotFoundError):
        load_clip_text(tmp_path / "absent.pt")


def test_a_vocabulary_other_than_openais_is_refused_by_the_encoder(tmp_path):
    state = openai_clip_state(width=64, layers=1, vocab=1000, embed_dim=8)
    path = tmp_path / "small-vocab.pt"
    torch.save(state, path)
    with pytest.raises(ClipWeightsError, match=r"'token_embedding.weight' has 1000 rows, expected 49408"):
        ClipEncoder(path)
    with pytest.raises(ValueError, match="clip-weights"):
        get_text_encoder("clip")
