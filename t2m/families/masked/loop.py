"""The masked family's loop (MoMask / MoGenTS): confidence re-masking of the first token layer, then the residual
layers one pass each, for every segment of every request in one batch.

A segment is a token map of `rows` time steps x `columns` tokens (1 column: MoMask's 1D tokens; 6 or 22: MoGenTS's
joint tokens). Stage 1 starts fully masked; before step n of N the `remask_counts` least confident tokens of each
segment are masked (again) and predicted; a token's confidence is the guided, unfiltered probability of the code drawn
for it, and a token not re-masked in a step is frozen from then on (MoMask's rule). Stage 2 predicts layer q = 1..R-1
from the layers below it in one pass; a drawn pad id means "layer unused" (-1).

Guidance runs each segment's condition row and a null row (zero condition) in the same batch; logits = uncond + s
(cond - uncond), with its own scale, top-k and (optionally) temperature per stage: MoMask's residual stage samples at
temperature 1 whatever the mask stage's is, which `residual_temperature` reproduces. Each request draws from its
own Generator, per step one uniform per token of its segments in segment order, so its tokens do not depend on what
else shares the batch (padded rows of shorter segments are never drawn). `MaskedStep`/`ResidualStep` are what the
loop needs from the networks: the service wraps the ONNX graphs, the PyTorch reference wraps the modules
(t2m.families.masked.sampling). A segment may come with an `Inpaint` (an edit, t2m.decoding.inpaint): its known tokens
start unmasked and frozen, only the others are scheduled and drawn, and its answer is the map's kept rows.
"""
from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from t2m.decoding.inpaint import Inpaint
from t2m.decoding.tokens import draw_tokens, guided_logits

__all__ = ["MaskedJob", "MaskedStep", "ResidualStep", "remask_counts", "sample_branch_maps", "sample_token_maps"]


class MaskedStep(Protocol):
    """The masked transformer: tokens [B, T, C] (mask id where unknown), cond [B, Dt], length [B] -> [B, T, C, K]."""

    columns: int
    mask_id: int

    def __call__(self, tokens: np.ndarray, cond: np.ndarray, length: np.ndarray) -> np.ndarray: ...


class ResidualStep(Protocol):
    """The residual transformer: codes [B, T, C, R] (-1 = not yet), layer [B], cond, length -> logits for layer q.
    ``mask_id``: None, or the mask class K the logits also score (MoGenTS's 2D residual model, K + 2 classes): a
    drawn K stays in the map (its embedding enters the next layer), and a segment with one gets every code clipped
    to [0, K - 1] at the end (-1 included), as MoGenTS's ``generate`` does for the one motion of its call."""

    layers: int
    pad_id: int
    mask_id: int | None

    def __call__(self, codes: np.ndarray, layer: np.ndarray, cond: np.ndarray, length: np.ndarray) -> np.ndarray: ...


@dataclass
class MaskedJob:
    """One request's segments: their text features and token rows, and the decoding settings of both stages."""

    conds: np.ndarray                  # float32 [S, Dt]
    rows: Sequence[int]                # token rows (time steps) per segment, >= 1
    rng: np.random.Generator
    steps: int = 10
    guidance: float = 4.0
    residual_guidance: float = 5.0
    temperature: float = 1.0
    top_k: int | None = None
    residual_top_k: int | None = None
    residual_temperature: float | None = None  # None: `temperature` (MoMask's generate: always 1 in this stage)
    greedy: bool = False
    cancelled: Callable[[], bool] = field(default=lambda: False)
    branches: list[MaskedJob] = field(default_factory=list)  # further generators on these segments (sample_branch_maps)
    # per segment, None or the kept codes around (or within) it and the tokens to fill: an edit (decoding/inpaint.py)
    inpaint: Sequence[Inpaint | None] | None = None


def remask_counts(tokens: int, steps: int) -> list[int]:
    """Tokens (re)masked before each step for a map of `tokens` tokens: max(1, round(cos(pi/2 tau_n) tokens)),
    tau_n = n / (N - 1), computed in float32 as MoMask's torch code does (float64 differs at exact halves)."""
    if steps < 1 or tokens < 1:
        raise ValueError(f"steps and tokens must be >= 1, got {steps} and {tokens}")
    tau = np.linspace(0, 1, steps, dtype=np.float32) if steps > 1 else np.zeros(1, np.float32)
    ratio = np.cos(tau * np.float32(math.pi * 0.5)).astype(np.float32)
    return [max(1, int(count)) for count in np.round(ratio * np.float32(tokens))]


@dataclass
class _Segment:
    job: int
    rows: int
    tokens: np.ndarray                 # int64 [rows * C] first-layer tokens (mask id where unknown)
    scores: np.ndarray                 # float64 [rows * C] confidence; inf = frozen
    counts: list[int]
    inpaint: Inpaint | None = None     # an edit's kept codes, put back after every residual pass


def _batch_conds(jobs: Sequence[MaskedJob], segments: list[_Segment], guided: bool) -> tuple[np.ndarray, np.ndarray]:
    """[cond rows; null rows] and their lengths: null rows only when some job uses guidance."""
    conds = np.concatenate([job.conds for job in jobs]).astype(np.float32)
    length = np.asarray([segment.rows for segment in segments], dtype=np.int64)
    if guided:
        return np.concatenate([conds, np.zeros_like(conds)]), np.concatenate([length, length])
    return conds, length


def _guided(logits: np.ndarray, index: int, count: int, scale: float, guided: bool,
            tokens: slice | np.ndarray) -> np.ndarray:
    """Segment `index`'s logits at `tokens` (of its token axis) after guidance (float64); the null rows follow the
    `count` cond rows. Each token's numbers are its own, whichever others are taken."""
    cond = logits[index, tokens].astype(np.float64)
    if not guided or scale == 1.0:
        return cond
    return guided_logits(cond, logits[count + index, tokens].astype(np.float64), scale)


def _softmax_at(logits: np.ndarray, chosen: np.ndarray) -> np.ndarray:
    shifted = logits - logits.max(axis=1, keepdims=True)
    probs = np.exp(shifted)
    return probs[np.arange(len(chosen)), chosen] / probs.sum(axis=1)


def _draws(logits: np.ndarray, jobs: Sequence[MaskedJob], segments: list[_Segment], guided: bool,
           stage: str, only: Sequence[np.ndarray] | None = None) -> list[tuple[np.ndarray, np.ndarray]]:
    """Per segment (guided logits over its real tokens, the codes drawn from them) with its job's settings for
    `stage` ("mask": guidance, top_k, temperature; "residual": residual_guidance, residual_top_k and
    residual_temperature, which defaults to temperature), in segment order. `only` (per segment, a mask over its
    tokens): the logits and codes of those tokens alone, the same numbers (tokens.draw_tokens's `only`; every
    token still takes its uniform)."""
    count, out = len(segments), []
    logits = logits.reshape(len(logits), -1, logits.shape[-1])
    for index, segment in enumerate(segments):
        job = jobs[segment.job]
        if stage == "mask":
            scale, top_k, temperature = job.guidance, job.top_k, job.temperature
        else:
            scale, top_k = job.residual_guidance, job.residual_top_k
            temperature = job.temperature if job.residual_temperature is None else job.residual_temperature
        mine = None if only is None else only[index]
        tokens = slice(0, segment.tokens.size) if mine is None else np.flatnonzero(mine)   # its real tokens only
        chosen = _guided(logits, index, count, scale, guided, tokens)
        out.append((chosen, draw_tokens(chosen, temperature, top_k, job.rng, job.greedy, only=mine)))
    return out


def _first_layer(step: MaskedStep, jobs: Sequence[MaskedJob], segments: list[_Segment], steps: int,
                 on_call: Callable[[int], None] | None) -> None:
    columns, count = step.columns, len(segments)
    guided = any(job.guidance != 1.0 for job in jobs)
    cond, length = _batch_conds(jobs, segments, guided)
    rows = max(segment.rows for segment in segments)
    for n in range(steps):
        batch_tokens = np.full((count, rows * columns), step.mask_id, dtype=np.int64)
        masked_now = []
        for index, segment in enumerate(segments):
            masked = np.zeros(segment.rows * columns, dtype=bool)
            masked[np.argsort(segment.scores, kind="stable")[:segment.counts[n]]] = True
            segment.tokens[masked] = step.mask_id
            batch_tokens[index, :segment.rows * columns] = segment.tokens
            masked_now.append(masked)
        tokens_in = batch_tokens.reshape(count, rows, columns)
        logits = step(np.concatenate([tokens_in, tokens_in]) if guided else tokens_in, cond, length)
        if on_call is not None:
            on_call(len(cond))
        draws = _draws(logits, jobs, segments, guided, "mask", only=masked_now)   # the re-masked tokens' alone
        for segment, masked, (chosen, drawn) in zip(segments, masked_now, draws):
            segment.tokens[masked] = drawn
            segment.scores = np.full(segment.tokens.size, np.inf)
            segment.scores[masked] = _softmax_at(chosen, drawn)


def _residual_layers(step: ResidualStep, jobs: Sequence[MaskedJob], segments: list[_Segment], columns: int,
                     on_call: Callable[[int], None] | None) -> np.ndarray:
    count, rows = len(segments), max(segment.rows for segment in segments)
    codes = np.full((count, rows, columns, step.layers), -1, dtype=np.int64)
    for index, segment in enumerate(segments):
        codes[index, :segment.rows, :, 0] = segment.tokens.reshape(segment.rows, columns)
    guided = any(job.residual_guidance != 1.0 for job in jobs)
    cond, length = _batch_conds(jobs, segments, guided)
    for q in range(1, step.layers):
        layer = np.full(len(cond), q, dtype=np.int64)
        logits = step(np.concatenate([codes, codes]) if guided else codes, layer, cond, length)
        if on_call is not None:
            on_call(len(cond))
        for index, (segment, (_, drawn)) in enumerate(zip(segments, _draws(logits, jobs, segments, guided,
                                                                            "residual"))):
            drawn[drawn == step.pad_id] = -1
            codes[index, :segment.rows, :, q] = drawn.reshape(segment.rows, columns)
            if segment.inpaint is not None:
                segment.inpaint.restore(codes[index, :segment.rows], q)
    if step.mask_id is not None:
        for index, segment in enumerate(segments):
            own = codes[index, :segment.rows]
            if (own == step.mask_id).any():
                own[...] = own.clip(0, step.mask_id - 1)
    return codes


def _new_segment(job: int, rows: int, masked: MaskedStep, steps: int, paint: Inpaint | None) -> _Segment:
    """A segment's first-layer state: all masked, or (an edit) its known tokens kept and only `fill` masked."""
    size = rows * masked.columns
    if paint is None:
        return _Segment(job, rows, np.full(size, masked.mask_id, np.int64), np.zeros(size),
                        remask_counts(size, steps))
    if paint.rows != rows or paint.fill.shape[1] != masked.columns:
        raise ValueError(f"an inpainted map of {paint.rows} rows x {paint.fill.shape[1]} columns for a segment of "
                         f"{rows} rows x {masked.columns} columns")
    tokens, scores = paint.first_layer(masked.mask_id)
    return _Segment(job, rows, tokens, scores, paint.counts(remask_counts(max(1, int(paint.fill.sum())), steps)),
                    paint)


def sample_token_maps(masked: MaskedStep, residual: ResidualStep | None, jobs: Sequence[MaskedJob],
                      on_call: Callable[[int], None] | None = None) -> list[list[np.ndarray] | None]:
    """Per job, one int64 code map [rows, C, R] per segment (R = 1 without a residual stage; -1 = unused layer),
    or None for a job cancelled before it started. All jobs must use the same number of steps."""
    if not jobs:
        return []
    steps = jobs[0].steps
    if any(job.steps != steps for job in jobs):
        raise ValueError("jobs batched together must use the same number of steps")
    live = [j for j, job in enumerate(jobs) if not job.cancelled()]
    segments: list[_Segment] = []
    for j in live:
        job = jobs[j]
        if len(job.rows) != len(job.conds) or min(job.rows, default=0) < 1:
            raise ValueError(f"every segment needs >= 1 token rows and a text feature, got rows {list(job.rows)}")
        for k, rows in enumerate(job.rows):
            paint = None if job.inpaint is None else job.inpaint[k]
            segments.append(_new_segment(j, rows, masked, steps, paint))
    live_jobs = [jobs[j] for j in live]
    for segment in segments:
        segment.job = live.index(segment.job)
    if not segments:
        return [None] * len(jobs)
    _first_layer(masked, live_jobs, segments, steps, on_call)
    if residual is not None and residual.layers > 1:
        codes = _residual_layers(residual, live_jobs, segments, masked.columns, on_call)
    else:
        codes = np.stack([np.pad(s.tokens.reshape(s.rows, masked.columns)[..., None],
                                 ((0, max(x.rows for x in segments) - s.rows), (0, 0), (0, 0)), constant_values=-1)
                          for s in segments])
    maps: dict[int, list[np.ndarray]] = {j: [] for j in live}
    for index, segment in enumerate(segments):
        own = codes[index, :segment.rows]
        maps[live[segment.job]].append(own if segment.inpaint is None else segment.inpaint.answer(own))
    return [maps.get(j) for j in range(len(jobs))]


def sample_branch_maps(branches: Sequence[tuple[MaskedStep, ResidualStep | None]], jobs: Sequence[MaskedJob],
                       on_call: Callable[[int], None] | None = None) -> list[list[np.ndarray] | None]:
    """Several token generators on the same rows (MoGenTS: its 2D map, then its 1D tokens): branch 0 runs
    ``jobs``, branch b > 0 each job's ``branches[b - 1]`` (a request's jobs share its rows, text features and
    generator, so its draws follow one another in branch order), and each segment's maps are joined along the
    column axis in branch order: [rows, C_0 + C_1 + ..., R]. Every branch needs the same number of layers R. A
    request cancelled in any branch is None."""
    if any(len(job.branches) != len(branches) - 1 for job in jobs):
        raise ValueError(f"every job needs {len(branches) - 1} branch job(s), one per further generator")
    results = [sample_token_maps(masked, residual, [job.branches[b - 1] if b else job for job in jobs], on_call)
               for b, (masked, residual) in enumerate(branches)]
    joined: list[list[np.ndarray] | None] = []
    for per_branch in zip(*results):
        if any(maps is None for maps in per_branch):
            joined.append(None)
            continue
        joined.append([np.concatenate(segment, axis=1) for segment in zip(*per_branch)])
    return joined
