"""The masked family's codes for the engine (MoMask / MoGenTS): per segment a token map [rows, C, R] from
masked.onnx (confidence re-masking) and residual.onnx (one pass per layer) through t2m.families.masked.loop, every
segment of every request in one batch, each request drawing from its own seeded generator.

Rows per segment come from its duration (tokens_for_duration); a null duration is drawn from length.onnx's
distribution with the request's generator (one uniform per null segment, in segment order, before the token draws),
or refused naming the segment's duration when the bundle has no length estimator. Request options: `guidance` is
the mask stage's scale, `temperature` and `top_k` (null: the manifest's) apply to the mask stage; the residual stage
uses the manifest's guidance and top-k, and the request's temperature unless the manifest fixes
`residual_temperature` (MoMask's imports: 1, as MoMask's own generation does).

An edit's request (POST /edit) carries an `inpaint` map per sampled segment (t2m.decoding.inpaint): its rows are the
map's, kept codes around the tokens to fill, and each further generator gets the map's columns of its own.
`body_parts` are the token columns a `body_part` edit may regenerate (engine/body_parts.py).
"""
from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import replace

import numpy as np
import onnxruntime as ort

from t2m.decoding.inpaint import Inpaint
from t2m.families.masked.loop import MaskedJob, sample_branch_maps, sample_token_maps
from t2m.motion.skeleton import get_skeleton
from t2m.runtime.body_parts import part_columns
from t2m.runtime.bundle_loader import Bundle
from t2m.runtime.onnx_step import OnnxMaskedStep, OnnxResidualStep
from t2m.runtime.requests import check_top_k, segment_steps
from t2m.runtime.text import TextEncoder
from t2m.runtime.types import CodeLayout, GenerationRequest, ModelLimits, RequestLimitError

__all__ = ["MaskedCodes", "draw_rows"]


def draw_rows(logits: np.ndarray, rng: np.random.Generator, max_tokens: int, min_rows: int = 1) -> int:
    """A row count from length logits [max_tokens + 1] (softmax, counts below `min_rows` excluded): one uniform."""
    logits = np.asarray(logits, dtype=np.float64)[: max_tokens + 1].copy()
    logits[:min_rows] = -np.inf
    probabilities = np.exp(logits - logits.max())
    cumulative = np.cumsum(probabilities / probabilities.sum())
    index = int(np.searchsorted(cumulative, rng.random(), side="right"))
    return min(max(index, min_rows), max_tokens)


class MaskedCodes:
    """Requests -> per-segment token maps [rows, C, R] with the bundle's masked (and residual) graphs."""

    def __init__(self, bundle: Bundle) -> None:
        manifest = bundle.manifest
        settings = manifest.settings  # t2m.families.masked.family.MaskedSettings
        self.settings = settings
        self.masked, self.residual = self._steps(bundle, ("masked.onnx", "residual.onnx"), settings.columns,
                                                 settings.mask_id, settings.pad_id, settings.residual_mask_class)
        self.branches = [self._steps(bundle, b.graphs, b.columns, b.mask_id, b.pad_id, b.residual_mask_class)
                         for b in settings.branches]
        self.length: ort.InferenceSession | None = bundle.sessions.get("length.onnx")
        self.ends_segments = None if self.length is None else "a length drawn from its length estimator"
        # a row of the map the decoder reads: the primary columns, then each branch's, each its own codebook; -1 is
        # a residual layer left unused (t2m.families.masked.loop)
        bounds = [bundle.manifest.codebook_size] * settings.columns
        for branch in settings.branches:
            bounds += [branch.codebook_size] * branch.columns
        self.code_layout = CodeLayout((len(bounds), bundle.manifest.residual_layers), tuple(bounds), low=-1)
        self.body_parts = part_columns(get_skeleton(manifest.skeleton).joint_names, settings.columns)

    @staticmethod
    def _steps(bundle: Bundle, files: tuple[str, str], columns: int, mask_id: int, pad_id: int,
               mask_class: bool) -> tuple[OnnxMaskedStep, OnnxResidualStep | None]:
        """One generator's steps: its masked graph, and its residual graph when the VQ has more than one layer."""
        residual = bundle.step_session(files[1])
        return (OnnxMaskedStep(bundle.step_session(files[0]), columns, mask_id),
                None if residual is None else OnnxResidualStep(residual, bundle.manifest.residual_layers, pad_id,
                                                               mask_id if mask_class else None))

    def _rows(self, steps: list[int | None], conds: np.ndarray, rng: np.random.Generator,
              limits: ModelLimits) -> list[int]:
        """Rows per segment: its steps, or a draw from the length estimator for a null duration."""
        free = [i for i, s in enumerate(steps) if s is None]
        rows = [0 if s is None else s for s in steps]
        if free and self.length is not None:
            (logits,) = self.length.run(["logits"], {"cond": conds[free]})
            for index, segment_logits in zip(free, logits):
                rows[index] = draw_rows(segment_logits, rng, limits.max_tokens)
        return rows

    def _inpaint_rows(self, request: GenerationRequest, steps: list[int | None], limits: ModelLimits) -> list[int]:
        """Rows per segment of an edit's request: each inpainted map's (its kept rows: the segment's steps)."""
        assert request.inpaint is not None
        if len(request.inpaint) != len(request.segments):
            raise ValueError(f"{len(request.inpaint)} inpaint maps for {len(request.segments)} segments")
        rows = []
        for index, (paint, own) in enumerate(zip(request.inpaint, steps)):
            kept = None if paint is None else paint.keep[1] - paint.keep[0]
            if paint is None and own is None:
                raise RequestLimitError(f"segments.{index}.duration", "give a duration in seconds")
            if paint is not None and (paint.known.shape[1:] != self.code_layout.shape or paint.rows > limits.max_tokens
                                      or own not in (None, kept)):
                raise ValueError(f"segment {index}: an inpaint map of {paint.known.shape} keeping {kept} rows does "
                                 f"not fit ({own} steps, at most {limits.max_tokens} rows of {self.code_layout.shape})")
            rows.append(paint.rows if paint is not None else int(own or 0))
        return rows

    def job(self, request: GenerationRequest, text: TextEncoder, limits: ModelLimits) -> MaskedJob:
        steps = segment_steps(request, limits, free=None if self.length is not None or request.inpaint is not None
                              else f"model {limits.name!r} has no length estimator; give this segment a duration in "
                                   "seconds")
        check_top_k(request, limits)
        conds = text.encode([s.text for s in request.segments])
        rng = np.random.default_rng(request.seed)
        s = self.settings
        rows = (self._rows(steps, conds, rng, limits) if request.inpaint is None
                else self._inpaint_rows(request, steps, limits))
        job = MaskedJob(conds=conds, rows=rows, rng=rng, steps=s.steps, inpaint=request.inpaint,
                        guidance=request.guidance, residual_guidance=s.residual_guidance,
                        temperature=request.temperature if s.temperature is None else s.temperature,
                        top_k=request.top_k if request.top_k is not None else s.top_k,
                        residual_top_k=s.residual_top_k, residual_temperature=s.residual_temperature,
                        cancelled=lambda: request.cancelled)
        # further generators: the same segments, rows and generator, their own top-k (a request's top_k, like its
        # guidance and temperature, applies to every generator's mask stage)
        starts = np.cumsum([s.columns] + [branch.columns for branch in s.branches]).tolist()
        job.branches = [replace(job, top_k=request.top_k if request.top_k is not None else branch.top_k,
                                residual_top_k=branch.residual_top_k, branches=[],
                                inpaint=_columns(request.inpaint, start, start + branch.columns))
                        for branch, start in zip(s.branches, starts)]
        if request.inpaint is not None:
            job.inpaint = _columns(request.inpaint, 0, s.columns)
        return job

    def sample(self, jobs: Sequence[MaskedJob], max_tokens: int,
               on_step: Callable[[int], None] | None) -> list[list[np.ndarray] | None]:
        if not self.branches:
            return sample_token_maps(self.masked, self.residual, jobs, on_step)
        return sample_branch_maps([(self.masked, self.residual), *self.branches], jobs, on_step)


def _columns(inpaint: tuple[Inpaint | None, ...] | None, start: int, stop: int) -> tuple[Inpaint | None, ...] | None:
    """An edit's maps cut to one generator's columns."""
    if inpaint is None:
        return None
    return tuple(None if paint is None else paint.columns(start, stop) for paint in inpaint)
