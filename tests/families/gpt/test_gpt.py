"""MotionGPT: shapes, KV-cached steps equal the full forward, T2M-GPT's key layout, traceability of a step."""
from __future__ import annotations

import pytest
import torch

from t2m.families.gpt.network import GPTConfig, MotionGPT
from t2m.model.networks.positions import sinusoid_table

torch.set_num_threads(1)


def tiny_config(**overrides) -> GPTConfig:
    values = {"codebook_size": 16, "embed": 32, "n_head": 4, "n_layer_base": 2, "n_layer_head": 1, "block_size": 9,
              "text_dim": 8, "dropout": 0.0, "length_conditioning": True}
    values.update(overrides)
    return GPTConfig(**values)


def test_forward_shapes_including_the_empty_prefix():
    torch.manual_seed(0)
    gpt = MotionGPT(tiny_config()).eval()
    cond = torch.randn(3, 8)
    assert gpt(cond, torch.zeros(3, 0, dtype=torch.long), None).shape == (3, 1, 17)
    tokens = torch.randint(0, 18, (3, 8))
    assert gpt(cond, tokens, torch.tensor([0, 2, 8])).shape == (3, 9, 17)
    with pytest.raises(ValueError, match="max_tokens"):
        gpt(cond, torch.zeros(3, 9, dtype=torch.long))


@pytest.mark.parametrize("length_conditioning", [True, False])
def test_forward_step_equals_forward_at_every_position(length_conditioning):
    torch.manual_seed(0)
    gpt = MotionGPT(tiny_config(length_conditioning=length_conditioning)).eval()
    batch = 3
    cond = torch.randn(batch, 8)
    tokens = torch.randint(0, 18, (batch, 8))  # codes, End and Pad ids all appear as inputs
    length = torch.tensor([0, 3, 8])
    full = gpt(cond, tokens, length)
    past = gpt.empty_cache(batch)
    for position in range(9):
        token = tokens[:, position - 1] if position else torch.full((batch,), 5)  # ignored at position 0
        step_position = position if position % 2 else torch.tensor(position)  # int and tensor both accepted
        logits, past = gpt.forward_step(cond, token, step_position, length, past)
        assert past.shape == (3, 2, batch, 4, position + 1, 8)
        torch.testing.assert_close(logits, full[:, position], atol=1e-5, rtol=0)


def test_length_conditioning_changes_the_condition_token_only_when_enabled():
    torch.manual_seed(0)
    gpt = MotionGPT(tiny_config()).eval()
    cond = torch.randn(1, 8).repeat(2, 1)
    out = gpt(cond, torch.zeros(2, 0, dtype=torch.long), torch.tensor([0, 5]))
    assert not torch.allclose(out[0], out[1])
    plain = MotionGPT(tiny_config(length_conditioning=False)).eval()
    out = plain(cond, torch.zeros(2, 0, dtype=torch.long), torch.tensor([0, 5]))
    assert torch.allclose(out[0], out[1])
    assert "trans_base.len_emb.weight" not in plain.state_dict()


def t2m_gpt_state_dict(K: int, E: int, Dt: int, block: int, n_base: int, n_head_layers: int) -> dict[str, torch.Tensor]:
    """Keys and shapes as in docs/t2m-gpt-checkpoints.md, at small sizes."""
    state = {
        "trans_base.tok_emb.weight": torch.randn(K + 2, E),
        "trans_base.cond_emb.weight": torch.randn(E, Dt),
        "trans_base.cond_emb.bias": torch.randn(E),
        "trans_base.pos_embedding.weight": torch.randn(block, E),
        "trans_base.pos_embed.embed": torch.randn(block, 1, E),
        "trans_head.ln_f.weight": torch.randn(E),
        "trans_head.ln_f.bias": torch.randn(E),
        "trans_head.head.weight": torch.randn(K + 1, E),
    }
    for part, count in (("trans_base", n_base), ("trans_head", n_head_layers)):
        for i in range(count):
            prefix = f"{part}.blocks.{i}"
            for norm in ("ln1", "ln2"):
                state[f"{prefix}.{norm}.weight"] = torch.randn(E)
                state[f"{prefix}.{norm}.bias"] = torch.randn(E)
            for name in ("key", "query", "value", "proj"):
                state[f"{prefix}.attn.{name}.weight"] = torch.randn(E, E)
                state[f"{prefix}.attn.{name}.bias"] = torch.randn(E)
            state[f"{prefix}.attn.mask"] = torch.tril(torch.ones(block, block)).view(1, 1, block, block)
            state[f"{prefix}.mlp.0.weight"] = torch.randn(4 * E, E)
            state[f"{prefix}.mlp.0.bias"] = torch.randn(4 * E)
            state[f"{prefix}.mlp.2.weight"] = torch.randn(E, 4 * E)
            state[f"{prefix}.mlp.2.bias"] = torch.randn(E)
    return state


def test_t2m_gpt_shaped_state_dict_loads_strict():
    state = t2m_gpt_state_dict(K=16, E=32, Dt=8, block=9, n_base=2, n_head_layers=1)
    # the release has 9 + 9 blocks: 8 tensors outside blocks + 17 per block (the mask included) = 314
    assert len(t2m_gpt_state_dict(K=4, E=8, Dt=4, block=3, n_base=9, n_head_layers=9)) == 314
    gpt = MotionGPT(tiny_config(length_conditioning=False))
    gpt.load_state_dict(state, strict=True)
    assert torch.equal(gpt.trans_base.pos_embed.embed, state["trans_base.pos_embed.embed"])
    assert torch.equal(gpt.trans_head.head.weight, state["trans_head.head.weight"])
    assert gpt.trans_head.head.bias is None
    # the loaded position table is the one the forward pass adds
    gpt.eval()
    cond = torch.randn(1, 8)
    before = gpt(cond, torch.zeros(1, 0, dtype=torch.long))
    gpt.trans_base.pos_embed.embed.zero_()
    assert not torch.allclose(before, gpt(cond, torch.zeros(1, 0, dtype=torch.long)))


def test_default_position_table_is_the_sinusoid():
    table = sinusoid_table(5, 6)[:, 0]
    assert table.shape == (5, 6)
    assert torch.allclose(table[0], torch.tensor([0.0, 1.0, 0.0, 1.0, 0.0, 1.0]))
    assert torch.allclose(table[3, 0], torch.sin(torch.tensor(3.0)))


def test_forward_step_traces_without_value_dependent_control_flow():
    """A graph traced at position 0 with an empty cache must run correctly at a later position and batch size."""
    torch.manual_seed(0)
    gpt = MotionGPT(tiny_config()).eval()

    class Step(torch.nn.Module):
        def __init__(self) -> None:
            super().__init__()
            self.gpt = gpt

        def forward(self, cond, token, position, length, past_kv):
            return self.gpt.forward_step(cond, token, position, length, past_kv)

    example = (torch.randn(2, 8), torch.zeros(2, dtype=torch.long), torch.tensor([0]), torch.tensor([3, 0]),
               gpt.empty_cache(2))
    traced = torch.jit.trace(Step(), example, check_trace=False)
    cond, tokens, length = torch.randn(3, 8), torch.randint(0, 16, (3, 4)), torch.tensor([4, 0, 2])
    full = gpt(cond, tokens, length)
    past = gpt.empty_cache(3)
    for position in range(5):
        token = tokens[:, position - 1] if position else torch.zeros(3, dtype=torch.long)
        logits, past = traced(cond, token, torch.tensor([position]), length, past)
        torch.testing.assert_close(logits, full[:, position], atol=1e-5, rtol=0)


def test_config_errors_are_clear():
    with pytest.raises(ValueError, match="divisible"):
        GPTConfig(embed=30, n_head=4)
    with pytest.raises(ValueError, match="unknown GPT config"):
        GPTConfig.from_dict({"embed": 32, "colour": 1})
