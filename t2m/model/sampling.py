"""The PyTorch reference sampler: the service's generation recipe (docs/contracts.md), step by step with a KV cache.

Per segment one conditional row and, when guidance != 1, one unconditional row whose
condition is zeros (the null condition trained by condition dropout); both rows keep
the segment's length input. All rows step in lockstep. At every step:
logits = uncond + s * (cond - uncond), then the length rule (End masked before a
segment's target, forced at it; a free segment gets at least one code and at most
max_tokens), then temperature and top-k, then sampling (or argmax when greedy).
"""
from __future__ import annotations

from collections.abc import Sequence

import torch

from t2m.model.networks.gpt import MotionGPT


def guided_logits(cond_logits: torch.Tensor, uncond_logits: torch.Tensor, guidance: float) -> torch.Tensor:
    """Classifier-free guidance: uncond + s * (cond - uncond). s = 1 gives the conditional logits."""
    return uncond_logits + guidance * (cond_logits - uncond_logits)


def length_rule_mask(
    step: int, target_tokens: Sequence[int | None], codebook_size: int, max_tokens: int
) -> torch.Tensor:
    """Additive mask [B, K+1] for the code emitted at ``step`` (0-based): 0 where allowed, -inf where not.

    Target n: End forbidden while step < n, only End allowed at step n.
    Free (None): End forbidden at step 0, only End allowed at step max_tokens.
    """
    mask = torch.zeros(len(target_tokens), codebook_size + 1)
    for row, target in enumerate(target_tokens):
        stop_at = max_tokens if target is None else target
        if step < stop_at and (target is not None or step == 0):
            mask[row, codebook_size] = float("-inf")
        if step >= stop_at:
            mask[row, :codebook_size] = float("-inf")
    return mask


def filter_logits(logits: torch.Tensor, temperature: float, top_k: int | None) -> torch.Tensor:
    """Divide by the temperature and keep only the top_k classes of each row (others -inf)."""
    logits = logits / temperature
    if top_k is not None and 0 < top_k < logits.shape[-1]:
        kth = torch.topk(logits, top_k, dim=-1).values[:, -1:]
        logits = logits.masked_fill(logits < kth, float("-inf"))
    return logits


def check_targets(target_tokens: Sequence[int | None], max_tokens: int) -> None:
    for index, target in enumerate(target_tokens):
        if target is not None and not 1 <= int(target) <= max_tokens:
            raise ValueError(f"target_tokens[{index}] must be in 1..{max_tokens} or None, got {target}")


@torch.no_grad()
def sample_codes(
    gpt: MotionGPT,
    cond: torch.Tensor,
    target_tokens: Sequence[int | None],
    guidance: float = 1.0,
    temperature: float = 1.0,
    top_k: int | None = None,
    generator: torch.Generator | None = None,
    greedy: bool = False,
) -> list[list[int]]:
    """Generate one code sequence per condition row.

    cond [B, Dt] text features; target_tokens[i] = number of codes for row i (None = free length,
    stop on End). temperature 0 or greedy=True picks the argmax. Returns B lists of code ids (< K).
    """
    config = gpt.config
    batch = cond.shape[0]
    if len(target_tokens) != batch:
        raise ValueError(f"target_tokens has {len(target_tokens)} entries for {batch} condition rows")
    check_targets(target_tokens, config.max_tokens)
    greedy = greedy or temperature == 0
    use_guidance = guidance != 1.0
    was_training = gpt.training
    gpt.eval()

    lengths = torch.tensor(
        [int(t) if (t is not None and config.length_conditioning) else 0 for t in target_tokens], dtype=torch.long
    )
    rows_cond, rows_length = cond.float(), lengths
    if use_guidance:
        rows_cond = torch.cat([rows_cond, torch.zeros_like(rows_cond)])
        rows_length = torch.cat([lengths, lengths])
    rows = rows_cond.shape[0]

    past_kv = gpt.empty_cache(rows, device=cond.device)
    token = torch.zeros(rows, dtype=torch.long, device=cond.device)
    codes: list[list[int]] = [[] for _ in range(batch)]
    finished = [False] * batch
    end_id = config.end_id
    try:
        for step in range(config.max_tokens + 1):
            mask = length_rule_mask(step, target_tokens, config.codebook_size, config.max_tokens)
            forced_end = torch.isinf(mask[:, :end_id]).all(dim=1)
            if all(done or bool(forced) for done, forced in zip(finished, forced_end)):
                break  # every row is finished or must emit End now: no need to run the model
            logits, past_kv = gpt.forward_step(rows_cond, token, step, rows_length, past_kv)
            if use_guidance:
                logits = guided_logits(logits[:batch], logits[batch:], guidance)
            logits = logits + mask.to(logits.device)
            if greedy:
                next_token = logits.argmax(dim=-1)
            else:
                probs = torch.softmax(filter_logits(logits, temperature, top_k), dim=-1)
                next_token = torch.multinomial(probs, 1, generator=generator)[:, 0]
            for row in range(batch):
                if finished[row]:
                    continue
                if int(next_token[row]) == end_id:
                    finished[row] = True
                else:
                    codes[row].append(int(next_token[row]))
            token = torch.cat([next_token, next_token]) if use_guidance else next_token
    finally:
        gpt.train(was_training)
    return codes
