"""The diffusion family's text encoders (t2m.families.diffusion.text_encoders, distilbert): MDM's CLIP path (22 ids =
20 BPE tokens + start/end, end token last; features equal at MDM's 77-padding; float16 vs float32 measured), DiP's
DistilBERT token states (equal to transformers' DistilBertModel on random weights in the hub's folder layout; the
uncased WordPiece equal to transformers' tokenizer), the token-state ONNX graph vs the module with other batch and
token counts, MiniLM's token states, and one line for each refusal of a DistilBERT folder."""
from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch

from t2m.export.graphs.export import ort_session
from t2m.export.kit.text_sources import token_states_text_source
from t2m.families.diffusion.distilbert import DistilBert, DistilBertConfig, build_wordpiece_tokenizer, load_distilbert
from t2m.families.diffusion.distilbert_release import RELEASE, hub_state, tiny_vocab, write_distilbert_folder
from t2m.families.diffusion.text_encoders import (
    MDM_CLIP_CONTEXT,
    MdmClipEncoder,
    clip_encode_text_fp16,
    distilbert_encoder,
    mdm_clip_features,
    mdm_clip_text_source,
    minilm_token_encoder,
)
from t2m.model.networks.text_encoders import ClipEncoder, minilm_model_dir
from t2m.testing.clip_release import VIT_B_32_TEXT, openai_clip_state, save_torchscript_archive

os.environ.setdefault("HF_HUB_OFFLINE", "1")
os.environ.setdefault("TRANSFORMERS_OFFLINE", "1")
torch.set_num_threads(1)

SMALL_CLIP = {"width": 64, "layers": 2, "embed_dim": 512}     # MDM's 512-d feature, a small tower
CAPTIONS = ["a person walks forward",
            "a person walks forward, turns around to the left, then waves with both hands while jumping up and down",
            "she throws a ball with her left hand and crouches"]
TRICKY = ["A Person WALKS!", "naïve café résumé", "他在走路 and waves", "don't stop-running...", "  extra   spaces ",
          "x" * 120, "UNKNOWNWORDZZZ", ""]


def rows_cosine(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return (a * b).sum(-1) / (np.linalg.norm(a, axis=-1) * np.linalg.norm(b, axis=-1))


# --------------------------------------------------------------------------------------------- MDM's CLIP path

@pytest.fixture(scope="module")
def clip_archive(tmp_path_factory) -> Path:
    return save_torchscript_archive(openai_clip_state(**SMALL_CLIP, seed=5),
                                    tmp_path_factory.mktemp("clip") / "ViT-B-32.pt")


@pytest.fixture(scope="module")
def mdm_clip(clip_archive) -> MdmClipEncoder:
    return MdmClipEncoder(clip_archive)


def test_mdm_tokenization_keeps_20_tokens_and_the_end_token_last(mdm_clip):
    ids, mask = mdm_clip.tokenize(CAPTIONS)
    assert MDM_CLIP_CONTEXT == 22 and ids.shape == (3, 22)
    full = ClipEncoder(mdm_clip.weights).tokenize(CAPTIONS)[0]                     # T2M-GPT's: up to 77 ids
    assert full[1].ne(0).sum() > 22                                                # the long caption is cut
    assert ids[1].tolist() == full[1, :21].tolist() + [49407]                       # start + 20 tokens + end
    assert ids[0, :6].tolist() == full[0, :6].tolist() and ids[0, 6:].eq(0).all()   # short: unchanged, 0-padded
    assert mask.sum(1).tolist() == [6, 22, 13]


def test_mdm_feature_is_the_end_token_feature_at_77(mdm_clip):
    """MDM zero-pads the 22 ids to 77: the causal tower gives the same end-token feature."""
    ids, _ = mdm_clip.tokenize(CAPTIONS)
    padded = torch.cat([ids, torch.zeros(3, 77 - 22, dtype=ids.dtype)], dim=1)
    with torch.no_grad():
        at_77 = mdm_clip.module.encode_text(padded)
    features = mdm_clip_features(mdm_clip, CAPTIONS)
    assert features.dtype == np.float32 and features.shape == (3, 512)
    assert np.abs(features - at_77.numpy()).max() < 1e-5
    assert not np.allclose(np.linalg.norm(features, axis=1), 1.0)              # not normalised


def fp16_report(encoder: MdmClipEncoder, label: str) -> tuple[float, float, float]:
    f32 = mdm_clip_features(encoder, CAPTIONS, "float32")
    f16 = mdm_clip_features(encoder, CAPTIONS, "float16")
    diff, scale, cosine = float(np.abs(f32 - f16).max()), float(np.abs(f32).max()), float(rows_cosine(f32, f16).min())
    print(f"\nMDM CLIP text feature, float16 (MDM) vs float32 (service), {label}: max |diff| {diff:.2e} "
          f"(features up to {scale:.2f}), min cosine {cosine:.7f}")
    return diff, scale, cosine


def test_float16_vs_float32_is_small_and_measured(mdm_clip):
    diff, scale, cosine = fp16_report(mdm_clip, "small tower (width 64, 2 layers)")
    assert 0 < diff < 2e-2 * scale and cosine > 0.9999


def test_fp16_emulation_casts_where_openai_does(mdm_clip):
    """Rounded weights alone account for part of the change; the half arithmetic for the rest: the emulation is
    neither the float32 feature nor a feature of half-rounded weights computed in float32."""
    ids, mask = mdm_clip.tokenize(CAPTIONS)
    module = mdm_clip.module
    rounded = MdmClipEncoder(mdm_clip.weights).module
    with torch.no_grad():
        for name, parameter in rounded.named_parameters():
            if name.endswith(("in_proj_weight", "in_proj_bias", "out_proj.weight", "out_proj.bias", "c_fc.weight",
                              "c_fc.bias", "c_proj.weight", "c_proj.bias", "text_projection")):
                parameter.copy_(parameter.half().float())
        f16 = clip_encode_text_fp16(module, ids)
        assert torch.equal(f16, clip_encode_text_fp16(rounded, ids))            # only half-rounded weights enter
        assert not torch.equal(f16, rounded(ids, mask)) and not torch.equal(f16, module(ids, mask))


@pytest.mark.slow
def test_float16_vs_float32_at_the_released_size(tmp_path):
    """The card's figure: OpenAI's ViT-B/32 text tower at its size with random weights."""
    archive = save_torchscript_archive(openai_clip_state(**VIT_B_32_TEXT, seed=11), tmp_path / "ViT-B-32.pt")
    diff, scale, cosine = fp16_report(MdmClipEncoder(archive), "ViT-B/32 size, random weights")
    assert 0 < diff < 2e-2 * scale and cosine > 0.9999


def test_mdm_text_graph_matches_the_module(mdm_clip, tmp_path):
    entry = mdm_clip_text_source(mdm_clip.weights).write(tmp_path)
    assert entry["kind"] == "clip" and entry["max_length"] == 22 and entry["dim"] == 512
    from tokenizers import Tokenizer

    tokenizer = Tokenizer.from_file(str(tmp_path / "tokenizer.json"))
    encodings = tokenizer.encode_batch(CAPTIONS)
    ids = np.array([e.ids for e in encodings], np.int64)
    assert ids.tolist() == mdm_clip.tokenize(CAPTIONS)[0].tolist()              # the saved tokenizer cuts at 22
    mask = np.array([e.attention_mask for e in encodings], np.int64)
    (graph,) = ort_session(tmp_path / "text_encoder.onnx").run(None, {"input_ids": ids, "attention_mask": mask})
    assert np.abs(graph - mdm_clip_features(mdm_clip, CAPTIONS)).max() < 1e-4


# --------------------------------------------------------------------------------------------- DistilBERT

@pytest.fixture(scope="module")
def bert_folder(tmp_path_factory) -> Path:
    return write_distilbert_folder(tmp_path_factory.mktemp("bert") / "distilbert-base-uncased")


def test_released_distilbert_layout():
    with torch.device("meta"):
        module = DistilBert(DistilBertConfig())
    shapes = {k: tuple(v.shape) for k, v in module.state_dict().items()}
    hub = {k.removeprefix("distilbert."): tuple(v.shape) for k, v in hub_state(RELEASE, mlm_head=False).items()}
    assert shapes == hub and len(shapes) == 100
    assert sum(p.numel() for p in module.parameters()) == 66_362_880             # DistilBertModel's count


@pytest.mark.parametrize("weights", ["model.safetensors", "pytorch_model.bin"])
def test_distilbert_equals_transformers(tmp_path, weights):
    from transformers import DistilBertModel

    folder = write_distilbert_folder(tmp_path / "bert", weights=weights, seed=3)
    reference, info = DistilBertModel.from_pretrained(str(folder), output_loading_info=True)
    assert not info["missing_keys"] and not info["mismatched_keys"]             # the folder is the hub's layout
    encoder = distilbert_encoder(folder)
    ids, mask = encoder.tokenize(CAPTIONS)
    assert mask[0].eq(0).any()                                                   # a padded row
    with torch.no_grad():
        expected = reference.eval()(input_ids=ids, attention_mask=mask).last_hidden_state
    states, keys = encoder.encode(CAPTIONS)
    assert states.shape == (3, ids.shape[1], 32) and keys.dtype == np.bool_
    assert np.array_equal(keys, mask.numpy() == 1)
    real = keys[..., None]
    assert np.abs((states - expected.numpy()) * real).max() < 1e-5


def test_padding_does_not_change_a_captions_states(bert_folder):
    encoder = distilbert_encoder(bert_folder)
    alone, _ = encoder.encode(CAPTIONS[:1])
    batched, mask = encoder.encode(CAPTIONS)
    assert np.abs(batched[0, : alone.shape[1]] - alone[0]).max() < 1e-5 and mask[0].sum() == alone.shape[1]


def test_wordpiece_matches_transformers_uncased_tokenizer(tmp_path):
    from transformers import DistilBertTokenizer

    vocab = minilm_model_dir() / "vocab.txt"                                    # bert-base-uncased's 30,522 lines
    ours = build_wordpiece_tokenizer(vocab)
    (tmp_path / "hub").mkdir()
    shutil.copy(vocab, tmp_path / "hub" / "vocab.txt")
    reference = DistilBertTokenizer.from_pretrained(str(tmp_path / "hub"))     # AutoTokenizer's, as DiP loads it
    expected = reference(TRICKY + CAPTIONS, padding=True)
    encodings = ours.encode_batch(TRICKY + CAPTIONS)
    assert [e.ids for e in encodings] == expected["input_ids"]
    assert [e.attention_mask for e in encodings] == expected["attention_mask"]
    assert encodings[0].ids[0] == 101 and 102 in encodings[0].ids               # [CLS] = 101, [SEP] = 102
    ours.save(str(tmp_path / "tokenizer.json"))                                 # and from a tokenizer.json
    again = build_wordpiece_tokenizer(tmp_path / "tokenizer.json").encode_batch(TRICKY + CAPTIONS)
    assert [e.ids for e in again] == expected["input_ids"]


def test_token_state_graph_matches_the_module_at_other_sizes(bert_folder, tmp_path):
    encoder = distilbert_encoder(bert_folder)
    entry = token_states_text_source(encoder).write(tmp_path)                   # exported with 2 rows
    assert entry == {"kind": "distilbert", "dim": 32, "max_length": 64, "pooling": "tokens", "normalize": False,
                     "null_condition": "zeros"}
    session = ort_session(tmp_path / "text_encoder.onnx")
    for texts in (CAPTIONS, CAPTIONS[:1], [CAPTIONS[2]] * 5):
        ids, mask = encoder.tokenize(texts)
        (states,) = session.run(["token_states"], {"input_ids": ids.numpy(), "attention_mask": mask.numpy()})
        expected, expected_keys = encoder.encode(texts)
        assert np.array_equal(mask.numpy() != 0, expected_keys)
        assert np.abs((states - expected) * expected_keys[..., None]).max() < 1e-5


def test_minilm_token_states():
    encoder = minilm_token_encoder()
    assert encoder.dim == 384 and encoder.max_length == 64 and encoder.name == "minilm-tokens"
    states, mask = encoder.encode(CAPTIONS)
    from t2m.model.networks.text_encoders import MiniLMEncoder

    pooled = MiniLMEncoder().encode(CAPTIONS)                                    # mean of the states, normalised
    mean = (states * mask[..., None]).sum(1) / mask.sum(1, keepdims=True)
    assert np.abs(mean / np.linalg.norm(mean, axis=1, keepdims=True) - pooled).max() < 1e-5


def refuse(folder: Path, text: str) -> None:
    with pytest.raises(ValueError) as error:
        load_distilbert(folder)
    assert text in str(error.value) and "\n" not in str(error.value), str(error.value)


def test_distilbert_folder_refusals(tmp_path):
    refuse(tmp_path / "none", "no such folder")
    folder = write_distilbert_folder(tmp_path / "a")
    (folder / "model.safetensors").unlink()
    refuse(folder, "missing file model.safetensors")
    folder = write_distilbert_folder(tmp_path / "b")
    (folder / "config.json").unlink()
    refuse(folder, "config.json: missing file")
    folder = write_distilbert_folder(tmp_path / "c")
    (folder / "vocab.txt").unlink()
    refuse(folder, "missing file vocab.txt")
    sizes = {"max_position_embeddings": 64, "dim": 32, "n_layers": 2, "n_heads": 4, "hidden_dim": 64,
             "vocab_size": len(tiny_vocab())}
    state = hub_state(sizes)
    del state["distilbert.transformer.layer.1.ffn.lin2.bias"]
    refuse(write_distilbert_folder(tmp_path / "d", state=state),
           "missing tensor 'transformer.layer.1.ffn.lin2.bias' [32]")
    state = hub_state(sizes) | {"distilbert.pooler.weight": torch.zeros(2)}
    refuse(write_distilbert_folder(tmp_path / "e", state=state), "unexpected tensor 'distilbert.pooler.weight'")
    state = hub_state(sizes | {"hidden_dim": 48})
    refuse(write_distilbert_folder(tmp_path / "f", state=state),
           "tensor 'transformer.layer.0.ffn.lin1.weight' has shape [48, 32], expected [64, 32]")
    folder = write_distilbert_folder(tmp_path / "g")
    config = json.loads((folder / "config.json").read_text()) | {"model_type": "bert"}
    (folder / "config.json").write_text(json.dumps(config))
    refuse(folder, "model_type 'bert', expected 'distilbert'")
    folder = write_distilbert_folder(tmp_path / "h")
    (folder / "model.safetensors").write_bytes(b"not a file")
    refuse(folder, "not a readable weights file")
