"""The clip suite (``-m clip``, in .venv-clip: ``scripts/setup_env.sh .venv-clip clip,dev``): our CLIP text tower and
tokenizer against OpenAI's own code (the ``clip-anytorch`` packaging of OpenAI's repository) and open_clip's, at
ViT-B/32's released sizes with random weights in OpenAI's exact file format.

- features: ours (``load_clip_text``) vs open_clip's OpenAI loader (``load_openai_model``) on the same TorchScript
  archive, and vs OpenAI's ``build_model`` on its state dict: max |diff| <= 1e-5;
- open_clip's plain ``ViT-B-32`` configuration (GELU) on the same weights differs (> 1e-3): the test can fail;
- token ids vs OpenAI's and open_clip's SimpleTokenizer on many sentences, >77-token ones included.

OpenAI's package cannot be imported whole here (its ``clip/clip.py`` needs ``pkg_resources``, gone from current
setuptools), so its ``model.py`` and ``simple_tokenizer.py`` are loaded from the installed files.
"""
from __future__ import annotations

import importlib.util
import random
import sys
from pathlib import Path
from types import ModuleType

import numpy as np
import pytest
import torch

pytestmark = pytest.mark.clip
open_clip = pytest.importorskip("open_clip", reason="needs the [clip] extra (its own environment: .venv-clip)")

from t2m.model.data.captions import make_captions  # noqa: E402
from t2m.model.networks.clip_tokenizer import build_clip_tokenizer  # noqa: E402
from t2m.model.networks.clip_weights import load_clip_text  # noqa: E402
from t2m.testing.clip_release import released_format, save_torchscript_archive  # noqa: E402

torch.set_num_threads(1)
SOT, EOT = 49406, 49407


def openai_module(name: str) -> ModuleType:
    """clip/<name>.py of OpenAI's package, without running clip/__init__.py."""
    spec = importlib.util.find_spec("clip")
    if spec is None or not spec.submodule_search_locations:
        pytest.skip("clip-anytorch (OpenAI's CLIP code) is not installed")
    path = Path(next(iter(spec.submodule_search_locations))) / f"{name}.py"
    module_spec = importlib.util.spec_from_file_location(f"openai_clip_{name}", path)
    module = importlib.util.module_from_spec(module_spec)
    sys.modules[module_spec.name] = module
    module_spec.loader.exec_module(module)
    return module


def sentences() -> list[str]:
    """Captions of this project's data, people's phrasings with punctuation and numbers, seeded Unicode mixes,
    and sentences far over 77 tokens."""
    labels = [("walk", "normal"), ("run", "happy"), ("bow", "elderly"), ("wave-left-hand", "tired"),
              ("walk-back", "active"), ("kick", "angry"), ("raise-up-right-hand", "youthful"), ("dance-long", "proud")]
    texts = [c for i, (content, style) in enumerate(labels) for c in make_captions(content, style, f"id{i}", count=8)]
    texts += [
        "A person walks forward, turns 90 degrees to the left, and then sits down on a chair.",
        "the man's right arm swings back & forth 3 times; he's clearly tired...",
        "Someone does a cartwheel!!! Then: a back-flip (maybe two?)",
        "she isn't walking -- she's jogging at ~2.5 m/s",
        "A figure crouches low,then springs up;lands softly.",
        "person picks up an object from the floor with both hands and places it on a table to their right",
        "\u201cA person\u2019s walking\u201d \u2014 said nobody \u2026 ever",
        "Ｔｈｅ ｐｅｒｓｏｎ ｗａｌｋｓ ﬁrst, then ﬂips",
        "ΟΔΥΣΣΕΥΣ walks; a Greek ΧΟΡΟΣ dances",
        "caf\u00e9 vs cafe\u0301, na\u00efve, Z\u00fcrich, \u00c5ngstr\u00f6m, 東京で歩く人, 🏃\u200d♂️ running",
        "rock &amp; roll, &quot;quoted&quot;, it&#39;s, x&nbsp;y &rsquo;",
        "  lots\t\tof \n whitespace \u3000 here  ",
        "",
    ]
    texts += ["a person walks forward and then " * 20, "jumping " * 100, "Ω" * 120, "1234567890 " * 20]
    rng = random.Random(7)
    alphabet = ("abcdefghijklmnopqrstuvwxyz ABCDEFGHIJ 0123456789 .,;:!?'\"()-&/ éüñøçß ΣΑΒΓσ ς 東京人 🏃👍 "
                "\u2019\u201c\u201d \u00a0\u3000 ﬁ Ａｂ")
    texts += ["".join(rng.choice(alphabet) for _ in range(rng.randint(1, 120))) for _ in range(300)]
    return texts


@pytest.fixture(scope="module")
def vit_b_32(tmp_path_factory) -> dict:
    """ViT-B/32's full state (open_clip's OpenAI layout, randomly initialised, every float tensor perturbed so
    that biases and norms matter), saved as OpenAI's file is: a TorchScript archive with its dtypes."""
    torch.manual_seed(11)  # open_clip initialises from the global generator
    model = open_clip.create_model("ViT-B-32-quickgelu", pretrained=None)
    g = torch.Generator().manual_seed(11)
    state = {k: v + 0.02 * torch.randn(v.shape, generator=g) for k, v in model.state_dict().items()}
    state |= {"input_resolution": torch.tensor(224), "context_length": torch.tensor(77),
              "vocab_size": torch.tensor(49408)}
    released = released_format(state)
    archive = save_torchscript_archive(released, tmp_path_factory.mktemp("vit") / "ViT-B-32.pt")
    return {"released": released, "archive": archive}


@pytest.fixture(scope="module")
def batch_ids() -> torch.Tensor:
    """Short captions as the bundle's tokenizer gives them: padded to the batch's longest."""
    texts = [t for t in sentences() if "<|" not in t][:64]
    return torch.tensor([e.ids for e in build_clip_tokenizer().encode_batch(texts)])


@pytest.fixture(scope="module")
def token_ids(batch_ids) -> torch.Tensor:
    """The same, zero-padded to 77 as clip.tokenize gives them (OpenAI's model needs all 77 positions)."""
    assert batch_ids.shape[1] < 77
    return torch.nn.functional.pad(batch_ids, (0, 77 - batch_ids.shape[1]))


@pytest.fixture(scope="module")
def ours(vit_b_32, batch_ids, token_ids) -> torch.Tensor:
    tower = load_clip_text(vit_b_32["archive"])
    assert (tower.config.width, tower.config.layers, tower.config.heads) == (512, 12, 8)
    with torch.no_grad():
        at_77, at_longest = tower.encode_text(token_ids), tower.encode_text(batch_ids)
    diff = (at_77 - at_longest).abs().max().item()
    print(f"ours padded to 77 vs to the batch's longest ({batch_ids.shape[1]}): max |diff| {diff:.2e}")
    assert diff <= 1e-5  # float32 rounding of other matrix shapes; nothing after the end token is seen
    return at_77


def test_features_match_open_clips_openai_loader_on_the_same_archive(vit_b_32, token_ids, ours):
    reference = open_clip.load_openai_model(str(vit_b_32["archive"]), device="cpu").eval()
    with torch.no_grad():
        expected = reference.encode_text(token_ids)
    diff = (ours - expected).abs().max().item()
    print(f"ViT-B/32 text, {len(token_ids)} sentences: max |ours - open_clip load_openai_model| = {diff:.2e}"
          f" (feature scale {expected.abs().max().item():.2f})")
    assert diff <= 1e-5


def test_features_match_openais_own_model(vit_b_32, token_ids, ours):
    model = openai_module("model").build_model(dict(vit_b_32["released"])).float().eval()
    with torch.no_grad():
        expected = model.encode_text(token_ids)
    diff = (ours - expected).abs().max().item()
    print(f"ViT-B/32 text: max |ours - OpenAI build_model| = {diff:.2e}")
    assert diff <= 1e-5


def test_open_clips_plain_vit_b_32_uses_gelu_and_differs(vit_b_32, token_ids, ours):
    gelu = open_clip.create_model("ViT-B-32", pretrained=None)
    weights = {k: v.float() for k, v in vit_b_32["released"].items() if k in gelu.state_dict()}
    gelu.load_state_dict(weights, strict=True)
    with torch.no_grad():
        expected = gelu.eval().encode_text(token_ids)
    diff = (ours - expected).abs().max().item()
    print(f"ViT-B/32 text: max |ours - open_clip ViT-B-32 (GELU)| = {diff:.2e}")
    assert diff > 1e-3


def test_token_ids_match_openais_and_open_clips_tokenizers():
    texts = sentences()
    ours = [e.ids for e in build_clip_tokenizer().encode_batch(texts)]
    assert sum(row[-1] == EOT for row in ours) >= 4  # over 77 tokens, cut
    openai = openai_module("simple_tokenizer").SimpleTokenizer()

    def openai_tokenize(text: str) -> list[int]:  # clip.tokenize(text, truncate=True), row 0
        ids = [SOT, *openai.encode(text), EOT]
        if len(ids) > 77:
            ids = ids[:77]
            ids[-1] = EOT
        return ids + [0] * (77 - len(ids))

    expected = [openai_tokenize(t) for t in texts]
    mismatches = [(t, a, b) for t, a, b in zip(texts, ours, expected) if a != b]
    assert not mismatches, f"{len(mismatches)} of {len(texts)} differ from OpenAI's, first: {mismatches[0][0]!r}"
    from_open_clip = open_clip.get_tokenizer("ViT-B-32")(texts).tolist()  # same rules; no special literals here
    assert ours == from_open_clip
    print(f"{len(texts)} sentences: token ids identical to OpenAI's and open_clip's tokenizers"
          f" ({sum(r[-1] == EOT for r in ours)} truncated to 77)")


def test_specials_follow_openai_where_open_clip_differs():
    """A literal <|endoftext|> in a caption is OpenAI's end token (open_clip spells its specials differently)."""
    openai = openai_module("simple_tokenizer").SimpleTokenizer()
    text = "a person walks <|endoftext|> and <|startoftext|> runs"
    ours = build_clip_tokenizer().encode(text).ids
    assert ours[: ours.index(EOT, 5) + 1] == [SOT, *openai.encode(text), EOT]
    assert np.count_nonzero(np.array(ours) == EOT) == 2
