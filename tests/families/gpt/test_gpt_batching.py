"""Length-bucketed GPT batches: trimming the all-Pad tail leaves the loss unchanged; the sampler covers every item."""
from __future__ import annotations

import torch

from t2m.families.gpt.network import GPTConfig, MotionGPT
from t2m.families.gpt.training import next_token_loss
from t2m.model.data.datasets import LengthBucketSampler, trim_padding

torch.set_num_threads(1)


def test_trimming_the_pad_tail_keeps_the_loss() -> None:
    torch.manual_seed(0)
    config = GPTConfig(codebook_size=16, embed=32, n_head=2, n_layer_base=1, n_layer_head=1, block_size=11,
                       text_dim=8, dropout=0.0, length_conditioning=True)
    model = MotionGPT(config).eval()
    pad, end = config.pad_id, config.codebook_size
    tokens = torch.full((3, 11), pad)
    for row, count in enumerate((2, 5, 3)):
        tokens[row, :count] = torch.randint(0, 16, (count,))
        tokens[row, count] = end
    trimmed = trim_padding(tokens, pad)
    assert trimmed.shape == (3, 6)
    cond, length = torch.randn(3, 8), torch.tensor([2, 5, 3])
    full_loss, _ = next_token_loss(model, cond, tokens[:, :-1], tokens, length)
    trimmed_loss, _ = next_token_loss(model, cond, trimmed[:, :-1], trimmed, length)
    assert torch.allclose(full_loss, trimmed_loss, atol=1e-6)


def test_bucket_sampler_yields_every_item_once_in_similar_length_batches() -> None:
    counts = torch.randint(2, 51, (1000,), generator=torch.Generator().manual_seed(1)).tolist()
    sampler = LengthBucketSampler(counts, batch_size=32, pool_batches=8, generator=torch.Generator().manual_seed(2))
    batches = list(sampler)
    assert len(batches) == len(sampler)
    assert sorted(i for batch in batches for i in batch) == list(range(1000))
    spread = sum(max(counts[i] for i in b) - min(counts[i] for i in b) for b in batches) / len(batches)
    assert spread < 10  # random batches of 32 would span ~45 tokens
    assert batches != list(LengthBucketSampler(counts, 32, 8, generator=torch.Generator().manual_seed(3)))
