"""The front half of `t2m import mdm` / `t2m import dip` (t2m.families.diffusion.import_mdm, dip, mdm_files) on
random-weight
releases in the official layout (t2m/families/diffusion/mdm_release.py): the paper model, the 50-step model, the
DistilBERT variant
and DiP, read into our modules (the denoiser equal to a fresh module holding the release's tensors; the EMA choice of
args.json), their text encoders (OpenAI's ViT-B-32.pt cut to 20 tokens, a DistilBERT folder); one line for each
refusal. Small sizes here; the released sizes in the slow tests."""
from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch

from t2m.export.graphs.export import ort_session
from t2m.export.kit.text_sources import token_states_text_source
from t2m.families.diffusion.distilbert_release import RELEASE as BERT_RELEASE
from t2m.families.diffusion.distilbert_release import hub_state, tiny_vocab, write_distilbert_folder
from t2m.families.diffusion.import_card import release_notes
from t2m.families.diffusion.import_dip import load_dip_release
from t2m.families.diffusion.import_mdm import load_mdm_release
from t2m.families.diffusion.mdm_release import (
    RELEASE_SIZES,
    RELEASES,
    SMALL_BERT,
    SMALL_CLIP,
    SMALL_SIZES,
    make_release,
    small_bert_folder,
    small_clip_archive,
)
from t2m.families.diffusion.network import MDM, DiffusionConfig
from t2m.families.diffusion.text_encoders import MdmClipEncoder, TokenStateEncoder
from t2m.testing.clip_release import openai_clip_state, save_torchscript_archive


@pytest.fixture(scope="module")
def clip_archive(tmp_path_factory) -> Path:
    return small_clip_archive(tmp_path_factory.mktemp("clip"))


@pytest.fixture(scope="module")
def bert_dir(tmp_path_factory) -> Path:
    """A small DistilBERT with the released width (768: embed_text takes 768-d states)."""
    return small_bert_folder(tmp_path_factory.mktemp("bert"))


def load(name: str, folder: Path, clip: Path, bert: Path, **options):
    if name == "dip":
        return load_dip_release(folder, bert, **options)
    if RELEASES[name][1]:
        return load_mdm_release(folder, bert_dir=bert, **options)
    return load_mdm_release(folder, clip, **options)


def denoiser_inputs(config: DiffusionConfig, batch: int = 3, frames: int = 12, seed: int = 0) -> dict:
    g = torch.Generator().manual_seed(seed)
    inputs = {"x": torch.randn(batch, frames, config.features, generator=g),
              "timesteps": torch.randint(0, config.diffusion_steps, (batch,), generator=g),
              "length": torch.tensor([frames, frames - 3, 5][:batch])}
    if config.text_tokens:
        inputs["text"] = torch.randn(batch, 7, config.text_dim, generator=g)
        inputs["text_mask"] = torch.arange(7)[None] < torch.tensor([7, 4, 2][:batch])[:, None]
    else:
        inputs["text"] = torch.randn(batch, config.text_dim, generator=g)
    if config.context_len:
        inputs["prefix"] = torch.randn(batch, config.context_len, config.features, generator=g)
    return inputs


def fresh_with(config: DiffusionConfig, state: dict[str, torch.Tensor]) -> MDM:
    """A new module holding the release's tensors (pe recomputed): what the import must equal."""
    module = MDM(config)
    module.load_state_dict({k: v for k, v in state.items() if not k.endswith("pe")} |
                           {k: v for k, v in module.state_dict().items() if k.endswith("pe")}, strict=True)
    return module.eval()


@pytest.mark.parametrize("name", list(RELEASES))
def test_release_loads_and_equals_a_fresh_module(name, tmp_path, clip_archive, bert_dir):
    folder, state = make_release(tmp_path / name, name)
    imported = load(name, folder, clip_archive, bert_dir)
    config, model, text = imported                                              # unpacks as (config, model, text)
    args, decoder = RELEASES[name]
    assert config.diffusion_steps == args["diffusion_steps"] and config.latent_dim == SMALL_SIZES.latent
    assert config.arch == ("trans_dec" if decoder else "trans_enc") and not model.training
    assert (config.context_len, config.pred_len) == ((20, 40) if name == "dip" else (0, 0))
    assert config.mask_frames == bool(args.get("mask_frames"))
    assert imported.entry == ("model_avg" if args.get("use_ema") else "state dict")
    assert isinstance(text, TokenStateEncoder if decoder else MdmClipEncoder)
    if not decoder:
        assert text.max_length == 22
    inputs = denoiser_inputs(config)
    with torch.no_grad():
        assert torch.equal(model(**inputs), fresh_with(config, state)(**inputs))
    assert torch.equal(model.sequence_pos_encoder.pe, fresh_with(config, state).sequence_pos_encoder.pe)


def test_ema_choice_follows_args_json(tmp_path, bert_dir):
    folder, _ = make_release(tmp_path / "bert", "bert")
    plain = torch.load(folder / "model000200000.pt", weights_only=True)["model"]
    config, model, _ = load_mdm_release(folder, bert_dir=bert_dir)
    args = json.loads((folder / "args.json").read_text()) | {"use_ema": False}
    (folder / "args.json").write_text(json.dumps(args))
    imported = load_mdm_release(folder, bert_dir=bert_dir)
    assert imported.entry == "model"
    inputs = denoiser_inputs(config)
    with torch.no_grad():
        assert torch.equal(imported.model(**inputs), fresh_with(config, plain)(**inputs))
        assert (imported.model(**inputs) - model(**inputs)).abs().max() > 0.1


def test_text_keys_and_saved_tables_are_ignored(tmp_path, clip_archive, bert_dir):
    """A pre-2022-12 file with CLIP inside and an old pe of another length loads (as officially)."""
    folder, state = make_release(tmp_path / "paper", "paper")
    old = dict(state) | {"clip_model.token_embedding.weight": torch.zeros(10, 4),
                         "sequence_pos_encoder.pe": torch.zeros(100, 1, SMALL_SIZES.latent)}
    torch.save(old, folder / "model000200000.pt")
    config, model, _ = load_mdm_release(folder, clip_archive)
    inputs = denoiser_inputs(config)
    with torch.no_grad():
        assert torch.equal(model(**inputs), fresh_with(config, state)(**inputs))


def test_text_graphs_of_an_import(tmp_path, bert_dir):
    """DiP's text graph (token states) vs the imported encoder, at other batch and token counts."""
    folder, _ = make_release(tmp_path / "dip", "dip")
    _, _, text = load_dip_release(folder, bert_dir)
    token_states_text_source(text).write(tmp_path / "graph")
    session = ort_session(tmp_path / "graph" / "text_encoder.onnx")
    for texts in (["a person walks forward"], ["she jumps", "a man waves with the right hand twice", "he bows"]):
        ids, mask = text.tokenize(texts)
        (states,) = session.run(["token_states"], {"input_ids": ids.numpy(), "attention_mask": mask.numpy()})
        keys = mask.numpy() != 0
        expected, expected_keys = text.encode(texts)
        assert states.shape[-1] == 768 and np.array_equal(keys, expected_keys)
        assert np.abs((states - expected) * keys[..., None]).max() < 2e-5


@pytest.mark.parametrize("name", ["paper", "dip"])
def test_card_facts(name, tmp_path, clip_archive, bert_dir):
    folder, _ = make_release(tmp_path / name, name)
    notes, data, license = release_notes(load(name, folder, clip_archive, bert_dir))
    assert data["name"] == "HumanML3D" and "non-commercial" in data["license"]
    assert "MIT, Copyright (c) 2022 Guy Tevet" in license and "HumanML3D" in license and "\n" not in license
    if name == "paper":
        assert "OpenAI CLIP ViT-B/32 (openai/CLIP): MIT" in license and "float16" in notes and "1000 DDPM" in notes
        assert "no mask_frames" in notes and "the plain state dict" in notes
    else:
        assert "Apache-2.0" in license and "CLoSD" in license and "`model_avg` (EMA" in notes
        assert "20 clean prefix frames, 40 new frames" in notes and "11 ms per call" in notes


# ------------------------------------------------------------------------------------------------- refusals

def refused(call, text: str) -> None:
    with pytest.raises(ValueError) as error:
        call()
    message = str(error.value)
    assert text in message and "\n" not in message, message


def test_folder_refusals(tmp_path, clip_archive):
    refused(lambda: load_mdm_release(None, clip_archive), "no release folder")
    refused(lambda: load_mdm_release(tmp_path / "nowhere", clip_archive), "nowhere: no such folder")
    folder, _ = make_release(tmp_path / "a", "paper")
    (folder / "args.json").unlink()
    refused(lambda: load_mdm_release(folder, clip_archive), "args.json: missing file")
    folder, _ = make_release(tmp_path / "b", "paper")
    (folder / "model000200000.pt").unlink()
    refused(lambda: load_mdm_release(folder, clip_archive), "missing file model<step>.pt")
    folder, _ = make_release(tmp_path / "c", "paper")
    shutil.copy(folder / "model000200000.pt", folder / "model000475000.pt")
    refused(lambda: load_mdm_release(folder, clip_archive), "2 weights files (model000200000.pt, model000475000.pt)")
    config, _, _ = load_mdm_release(folder, clip_archive, model_file=folder / "model000475000.pt")
    assert config.diffusion_steps == 1000
    refused(lambda: load_mdm_release(folder, clip_archive, model_file=folder / "model9.pt"), "model9.pt: missing file")
    (folder / "model000475000.pt").unlink()
    (folder / "args.json").write_text("{not json")
    refused(lambda: load_mdm_release(folder, clip_archive), "args.json: not JSON")
    (folder / "args.json").write_text("[1, 2]")
    refused(lambda: load_mdm_release(folder, clip_archive), "args.json: not a JSON object")
    folder, _ = make_release(tmp_path / "d", "paper")
    (folder / "model000200000.pt").write_bytes(b"truncated")
    refused(lambda: load_mdm_release(folder, clip_archive), "not a complete PyTorch file")


@pytest.mark.parametrize("name, changes, text", [
    ("paper", {"dataset": "kit"}, "dataset 'kit': only HumanML3D releases"),
    ("paper", {"arch": "gru"}, "unsupported MDM args: arch='gru'"),
    ("paper", {"text_encoder_type": "t5"}, "text_encoder_type='t5'"),
    ("paper", {"noise_schedule": "linear"}, "noise_schedule='linear'"),
    ("paper", {"text_encoder_type": "bert"}, "text token states need arch trans_dec"),
    ("paper", {"context_len": 20}, "a DiP release (prefix completion); import it with t2m import dip"),
    ("bert", {"emb_trans_dec": True}, "emb_trans_dec: its meaning changed"),
    ("dip", {"context_len": 0, "pred_len": 0}, "not a DiP release (no prefix completion); import it with t2m "
     "import mdm"),
    ("dip", {"text_encoder_type": "clip"}, "DiP is trans_dec over DistilBERT token states"),
    ("dip", {"lambda_target_loc": 1.0, "multi_target_cond": True}, "multi_target_cond"),
])
def test_argument_refusals(name, changes, text, tmp_path, clip_archive, bert_dir):
    folder, _ = make_release(tmp_path / name, name, **changes)
    refused(lambda: load(name, folder, clip_archive, bert_dir), text)


def test_ema_refusals(tmp_path, clip_archive, bert_dir):
    folder, state = make_release(tmp_path / "a", "paper", use_ema=True)
    torch.save(state, folder / "model000200000.pt")                           # a plain dict, args say EMA
    refused(lambda: load_mdm_release(folder, clip_archive), "use_ema but the checkpoint is a plain state dict")
    folder, state = make_release(tmp_path / "b", "bert")
    torch.save({"model": state}, folder / "model000200000.pt")
    refused(lambda: load_mdm_release(folder, bert_dir=bert_dir), "use_ema but the checkpoint has no 'model_avg'")


def test_tensor_refusals(tmp_path, clip_archive, bert_dir):
    folder, state = make_release(tmp_path / "a", "paper")
    torch.save({k: v for k, v in state.items() if k != "seqTransEncoder.layers.1.norm2.bias"},
               folder / "model000200000.pt")
    refused(lambda: load_mdm_release(folder, clip_archive), "missing tensor 'seqTransEncoder.layers.1.norm2.bias' [32]")
    torch.save(state | {"embed_target_cond.weight": torch.zeros(2)}, folder / "model000200000.pt")
    refused(lambda: load_mdm_release(folder, clip_archive), "unexpected tensor 'embed_target_cond.weight'")
    args = json.loads((folder / "args.json").read_text()) | {"latent_dim": 64}
    (folder / "args.json").write_text(json.dumps(args))
    torch.save(state, folder / "model000200000.pt")
    refused(lambda: load_mdm_release(folder, clip_archive),
            "tensor 'input_process.poseEmbedding.weight' has shape [32, 263], expected [64, 263]")
    folder, _ = make_release(tmp_path / "b", "dip")
    data = torch.load(folder / "model000200000.pt", weights_only=True)
    data["model_avg"]["seqTransDecoder.layers.0.multihead_attn.in_proj_weight"] = torch.zeros(3, 3)
    torch.save(data, folder / "model000200000.pt")
    refused(lambda: load_dip_release(folder, bert_dir), "['model_avg']: tensor 'seqTransDecoder.layers.0.multihead_"
            "attn.in_proj_weight' has shape [3, 3], expected [96, 32]")


def test_text_encoder_refusals(tmp_path, clip_archive, bert_dir):
    folder, _ = make_release(tmp_path / "paper", "paper")
    refused(lambda: load_mdm_release(folder), "text encoder is CLIP ViT-B/32 (args.json: text_encoder_type 'clip'): "
            "pass --clip ViT-B-32.pt")
    refused(lambda: load_mdm_release(folder, tmp_path / "ViT-B-32.pt"), "ViT-B-32.pt: missing file")
    small = save_torchscript_archive(openai_clip_state(width=64, layers=1, embed_dim=256), tmp_path / "other.pt")
    refused(lambda: load_mdm_release(folder, small), "CLIP embed dim 256, the release's embed_text takes 512")
    folder, _ = make_release(tmp_path / "dip", "dip")
    refused(lambda: load_dip_release(folder), "DiP's text encoder is DistilBERT")
    refused(lambda: load_dip_release(folder, tmp_path / "none"), "no such folder")
    small_bert = write_distilbert_folder(tmp_path / "bert", SMALL_BERT | {"dim": 48})
    refused(lambda: load_dip_release(folder, small_bert), "DistilBERT dim 48, the release's embed_text takes 768")


# ------------------------------------------------------------------------------------------- released sizes

@pytest.mark.slow
def test_released_sizes(tmp_path):
    """The paper model and DiP at their sizes (17,880,327 and 26,424,583 parameters; DiP with EMA) with a DistilBERT
    folder at distilbert-base-uncased's sizes (as AutoModel saves it: no prefix, no MLM head; a small vocabulary is
    the only difference), loaded; denoisers equal to fresh modules; DiP's text graph vs the module."""
    clip = save_torchscript_archive(openai_clip_state(**SMALL_CLIP, seed=5), tmp_path / "ViT-B-32.pt")
    vocab = tiny_vocab()
    sizes = BERT_RELEASE | {"vocab_size": len(vocab)}
    bert = write_distilbert_folder(tmp_path / "bert", sizes, vocab, weights="pytorch_model.bin",
                                   state=hub_state(sizes, mlm_head=False, prefix=""))
    for name, parameters in (("paper", 17_880_327), ("dip", 26_424_583)):
        folder, state = make_release(tmp_path / name, name, RELEASE_SIZES)
        assert (folder / "model000200000.pt").stat().st_size > (160e6 if name == "dip" else 80e6)
        config, model, text = load(name, folder, clip, bert)
        assert sum(p.numel() for p in model.parameters()) == parameters
        inputs = denoiser_inputs(config, frames=40)
        with torch.no_grad():
            assert torch.equal(model(**inputs), fresh_with(config, state)(**inputs))
    assert isinstance(text, TokenStateEncoder) and sum(p.numel() for p in text.module.parameters()) == (
        66_362_880 - (30522 - len(vocab)) * 768)
    token_states_text_source(text).write(tmp_path / "graph")
    ids, mask = text.tokenize(["a person walks forward", "she throws a ball with her left hand and crouches"])
    (states,) = ort_session(tmp_path / "graph" / "text_encoder.onnx").run(
        ["token_states"], {"input_ids": ids.numpy(), "attention_mask": mask.numpy()})
    keys = mask.numpy() != 0
    expected, _ = text.encode(["a person walks forward", "she throws a ball with her left hand and crouches"])
    diff = float(np.abs((states - expected) * keys[..., None]).max())
    print(f"\nDiP text graph vs module at distilbert-base-uncased's sizes: max |diff| {diff:.1e}")
    assert diff < 1e-4
