"""Random-weight DistilBERT folders in the layout of the Hugging Face repo ``distilbert-base-uncased``: config.json
(transformers' DistilBertConfig fields), the weights as the hub holds them (DistilBertForMaskedLM's state dict:
every encoder key under ``distilbert.`` plus the MLM head ``vocab_transform``, ``vocab_layer_norm``,
``vocab_projector``) in model.safetensors or pytorch_model.bin, and a vocab.txt. Keys written from that layout, not
from our module. Sizes are parameters: the release's (``RELEASE``) in slow tests, small ones elsewhere."""
from __future__ import annotations

import json
from pathlib import Path

import torch

RELEASE = {"vocab_size": 30522, "max_position_embeddings": 512, "dim": 768, "n_layers": 6, "n_heads": 12,
           "hidden_dim": 3072}
SPECIAL = ["[PAD]", "[UNK]", "[CLS]", "[SEP]", "[MASK]"]
WORDS = ("a person walks forward slowly then turns around man jumps up and down twice someone waves with the right "
         "hand while standing still runs in circle stops woman sits on chair stands again kicks left leg raises both "
         "arms backwards bows he dances happily spinning to tired limps she throws ball her crouches , . !")


def tiny_vocab() -> list[str]:
    """[PAD] = 0, [UNK], [CLS], [SEP], [MASK], the letters with and without '##', some motion words."""
    letters = [chr(c) for c in range(ord("a"), ord("z") + 1)]
    return SPECIAL + letters + ["##" + c for c in letters] + sorted(set(WORDS.split()) - set(letters))


def hub_state(sizes: dict[str, int], seed: int = 0, std: float = 0.05, mlm_head: bool = True,
              prefix: str = "distilbert.") -> dict[str, torch.Tensor]:
    """DistilBertForMaskedLM's state dict with random values (LayerNorm weights near 1)."""
    g = torch.Generator().manual_seed(seed)
    d, h = sizes["dim"], sizes["hidden_dim"]

    def rand(*shape: int, scale: float = std) -> torch.Tensor:
        return torch.randn(*shape, generator=g) * scale

    def norm(key: str) -> dict[str, torch.Tensor]:
        return {f"{key}.weight": 1 + rand(d, scale=0.1), f"{key}.bias": rand(d, scale=0.1)}

    state = {"embeddings.word_embeddings.weight": rand(sizes["vocab_size"], d, scale=0.5),
             "embeddings.position_embeddings.weight": rand(sizes["max_position_embeddings"], d, scale=0.5),
             **norm("embeddings.LayerNorm")}
    for i in range(sizes["n_layers"]):
        p = f"transformer.layer.{i}."
        for lin in ("q_lin", "k_lin", "v_lin", "out_lin"):
            state |= {p + f"attention.{lin}.weight": rand(d, d, scale=d**-0.5), p + f"attention.{lin}.bias": rand(d)}
        state |= {p + "ffn.lin1.weight": rand(h, d, scale=d**-0.5), p + "ffn.lin1.bias": rand(h),
                  p + "ffn.lin2.weight": rand(d, h, scale=h**-0.5), p + "ffn.lin2.bias": rand(d),
                  **norm(p + "sa_layer_norm"), **norm(p + "output_layer_norm")}
    state = {prefix + key: value for key, value in state.items()}
    if mlm_head:
        state |= {"vocab_transform.weight": rand(d, d), "vocab_transform.bias": rand(d),
                  **norm("vocab_layer_norm"), "vocab_projector.weight": rand(sizes["vocab_size"], d),
                  "vocab_projector.bias": rand(sizes["vocab_size"])}
    return state


def hub_config(sizes: dict[str, int]) -> dict:
    """config.json as the hub repo has it (transformers' fields; sizes given)."""
    return {"activation": "gelu", "architectures": ["DistilBertForMaskedLM"], "attention_dropout": 0.1,
            "dropout": 0.1, "initializer_range": 0.02, "model_type": "distilbert", "pad_token_id": 0,
            "qa_dropout": 0.1, "seq_classif_dropout": 0.2, "sinusoidal_pos_embds": False, "tie_weights_": True,
            "transformers_version": "4.10.0.dev0", **sizes}


def write_distilbert_folder(root: Path, sizes: dict[str, int] | None = None, vocab: list[str] | None = None,
                            weights: str = "model.safetensors", seed: int = 0,
                            state: dict[str, torch.Tensor] | None = None) -> Path:
    """A folder: config.json, ``weights`` (model.safetensors or pytorch_model.bin), vocab.txt."""
    vocab = vocab if vocab is not None else tiny_vocab()
    sizes = dict(sizes or {"max_position_embeddings": 64, "dim": 32, "n_layers": 2, "n_heads": 4, "hidden_dim": 64})
    sizes["vocab_size"] = len(vocab)
    root.mkdir(parents=True, exist_ok=True)
    (root / "config.json").write_text(json.dumps(hub_config(sizes), indent=2), encoding="utf-8")
    (root / "vocab.txt").write_text("\n".join(vocab) + "\n", encoding="utf-8")
    state = state if state is not None else hub_state(sizes, seed)
    if weights == "model.safetensors":
        from safetensors.torch import save_file

        save_file({k: v.contiguous() for k, v in state.items()}, str(root / weights))
    else:
        torch.save(state, root / weights)
    return root
