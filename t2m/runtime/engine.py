"""OnnxEngine: a verified bundle turned into `generate(request) -> Motion` (the recipe of docs/contracts.md).

Per request: its texts through the text graph as one batch; its segments' codes sampled in lockstep with every other
request of the batch; its codes concatenated and decoded once (a continuous motion); features -> joints with
motion.features; each segment's joints fitted to its exact frame count, round(duration * fps) (engine/timeline.py).
Nothing here knows about HTTP or about any one family: the family-specific part (which codes,
from which graphs) is the object its ModelFamily serves (t2m.bundle.family, engine/family_codes.py), and what it can
do is its `capabilities`; the text encoding, the unknown-text check, the single decode and the joints are shared. A
streamed request (`on_frames`) of a family with `early_frames` also gets its frames while its codes are sampled
(engine/streaming.py, as far as engine/reach.py allows).
"""
from __future__ import annotations

import logging
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from t2m.bundle import CaptionIndex, get_family
from t2m.motion.features import features_to_joints
from t2m.motion.skeleton import get_skeleton
from t2m.runtime.bundle_loader import Bundle, load_bundle
from t2m.runtime.continuous import CohortSource, PreparedJobs, RunningCohorts
from t2m.runtime.decoder import Decoder
from t2m.runtime.early_frames import FrameStreamer
from t2m.runtime.execution import Execution
from t2m.runtime.family_codes import (
    FamilyCodes,
    RecipeHandles,
    body_parts,
    code_layout,
    decoder_reach,
    ends_segments,
    recipe_handles,
)
from t2m.runtime.reach import DecoderReach, probe_reach
from t2m.runtime.requests import segment_steps
from t2m.runtime.step_order import StepOrder
from t2m.runtime.text import TextEncoder, load_tokenizer
from t2m.runtime.timeline import FittedSink, Timeline, fit_frames
from t2m.runtime.types import (
    GenerationCancelled,
    GenerationRequest,
    ModelLimits,
    Motion,
    RequestLimitError,
    SegmentSpan,
    frames_for_duration,
)

__all__ = ["OnnxEngine"]

log = logging.getLogger(__name__)


class OnnxEngine:
    """Generates motions from a bundle with onnxruntime; thread-safe (sessions are, and no state is kept per call)."""

    def __init__(self, bundle: Bundle, unknown_text: str = "warn", stream_every: int = 8,
                 exact_durations: bool = True) -> None:
        """`unknown_text`: "warn" (a warning in the answer) or "reject" (a 422 naming the segment) for a sentence far
        from every training caption; only bundles with a caption index can tell. `stream_every`: a streamed request
        gets its first final frames at once, then the next when at least this many more codes' frames (and as many
        as sent before) are final (engine/streaming.py; one decode each). `exact_durations` False answers the
        decoded frames as they are (round(duration * fps / f) * f a segment): what the fixed-seed recordings and
        t2m/quality/joins.py compare the fitted frames with."""
        if unknown_text not in ("warn", "reject"):
            raise ValueError(f"unknown_text must be 'warn' or 'reject', got {unknown_text!r}")
        manifest = bundle.manifest
        self.bundle = bundle
        self.skeleton = get_skeleton(manifest.skeleton)
        if len(self.skeleton.joint_names) != manifest.num_joints:
            from t2m.bundle import BundleError
            raise BundleError(f"manifest.json: field 'num_joints' is {manifest.num_joints} but skeleton "
                              f"{manifest.skeleton!r} has {len(self.skeleton.joint_names)} joints")
        self.text = TextEncoder(bundle.text_session, load_tokenizer(bundle.tokenizer_file, manifest.text_max_length))
        self.family = get_family(manifest.family)
        self.capabilities = self.family.capabilities_of(manifest)
        self.codes: FamilyCodes = self.family.serve(bundle)
        self.decoder = Decoder(bundle.decoder_session, manifest.feature_dim)
        # a family without early frames streams once the whole motion is decoded; the reach probe feeds the decoder
        # rows of R codes where the family's decoder reads [steps, R]; a served object whose decoder reads no codes
        # measures its decoder's reach itself (family_codes.decoder_reach)
        self.reach: DecoderReach | None = None if not self.capabilities.early_frames else (
            decoder_reach(self.codes) or probe_reach(
                self.decoder.decode, manifest.codebook_size, manifest.frames_per_token,
                depth=manifest.residual_layers if self.capabilities.code_depth else None))
        self.stream_every = stream_every
        self.exact_durations = exact_durations
        self.unknown_text = unknown_text
        info = manifest.caption_index
        self.caption_index = None if info is None else CaptionIndex.load(bundle.path / info.file, manifest.text_dim)
        self.unknown_threshold = None if info is None else info.threshold
        raw = manifest.raw
        self.limits = ModelLimits(
            name=manifest.name, version=manifest.version, fps=manifest.fps,
            frames_per_token=manifest.frames_per_token, max_tokens=manifest.max_tokens,
            codebook_size=manifest.codebook_size, default_guidance=manifest.default_guidance,
            unconditional_branch=manifest.unconditional_branch, length_conditioning=manifest.length_conditioning,
            skeleton=manifest.skeleton, joint_names=tuple(self.skeleton.joint_names),
            parents=tuple(int(p) for p in self.skeleton.parents),
            details={**{key: raw[key] for key in ("license", "text_encoder", "training_data", "quantization")
                        if key in raw}, "unknown_text": self._unknown_text_details(),
                     "streaming": self._streaming_details(),
                     "execution": {"providers": list(bundle.execution.providers),
                                   "cuda_graphs": bundle.cuda_graphs},
                     "family": manifest.family,
                     **({manifest.family: raw[manifest.family]} if manifest.family in raw else {})},
            ends_segments=ends_segments(self.codes), codes=code_layout(self.codes), edits=self.capabilities.edits,
            inpaints=self.capabilities.inpaints,
            body_parts=body_parts(self.codes) if "body_part" in self.capabilities.edits else {},
            encodes=bundle.encoder_session is not None and code_layout(self.codes) is not None,
            recipe=recipe_handles(self.codes))

    @classmethod
    def load(cls, path: str | Path, *, check_hashes: bool = True, intra_op_threads: int = 0,
             inter_op_threads: int = 1, unknown_text: str = "warn", stream_every: int = 8,
             exact_durations: bool = True, execution: Execution | None = None) -> OnnxEngine:
        """`execution`: the sessions' providers and whether the step caches stay on the device (default: CPU)."""
        return cls(load_bundle(path, check_hashes=check_hashes, intra_op_threads=intra_op_threads,
                               inter_op_threads=inter_op_threads, execution=execution),
                   unknown_text=unknown_text, stream_every=stream_every, exact_durations=exact_durations)

    def _streaming_details(self) -> dict:
        """What /health says about streamed frames: how far the decoder looks ahead, hence when frames can go."""
        if self.reach is None:
            return {"early_frames": False, "reason": self.capabilities.why_not_early
                    if not self.capabilities.early_frames else "the decoder looks further than the probe"}
        return {"early_frames": True, "lookahead_tokens": self.reach.ahead, "lookbehind_tokens": self.reach.behind,
                "every_tokens": self.stream_every}

    def _stream_early(self, job: Any, request: GenerationRequest) -> None:
        """Give a streamed request's job a FrameStreamer as its `progress` hook (families with early frames; the
        others stream at the end), its frames fitted on the way by the request's Timeline as the whole answer's are."""
        if request.on_frames is None or self.reach is None:
            return
        per_token = self.limits.frames_per_token
        planned = [None if steps is None else steps * per_token for steps in segment_steps(request, self.limits)]
        sink = FittedSink(Timeline(self._targets(request), planned), request.on_frames)
        streamer = FrameStreamer(self.decoder.decode, self.skeleton, self.reach, per_token, self.stream_every, sink)
        job.progress = streamer.codes_arrived

    def _targets(self, request: GenerationRequest) -> list[int | None]:
        """Each segment's frames in the answer: round(duration * fps), or None (the decoded ones) for a null
        duration, or for every segment without exact durations."""
        return [None if segment.duration is None or not self.exact_durations
                else frames_for_duration(segment.duration, self.limits.fps) for segment in request.segments]

    def _unknown_text_details(self) -> dict:
        """What /health says about detecting sentences the model was not trained on."""
        if self.caption_index is None:
            return {"detection": "off", "reason": "the bundle carries no index of its training captions (e.g. an "
                                                  "imported release): sentences far from the training data are "
                                                  "not detected"}
        return {"detection": self.unknown_text, "captions": len(self.caption_index.captions),
                "threshold": self.unknown_threshold}

    def unknown_text_warnings(self, texts: Sequence[str], conds: np.ndarray) -> list[str]:
        """One warning per segment whose text feature is far from every training caption (none without an index);
        with unknown_text="reject" the first such segment raises a RequestLimitError naming it instead."""
        if self.caption_index is None or self.unknown_threshold is None:
            return []
        warnings = []
        for index, (text, neighbours) in enumerate(zip(texts, self.caption_index.nearest(conds, k=3))):
            best = neighbours[0].similarity
            if best >= self.unknown_threshold:
                continue
            nearest = "; ".join(f"{n.caption!r} {n.similarity:.2f}" for n in neighbours)
            why = (f"{text!r} is far from everything model {self.limits.name!r} was trained on (best similarity "
                   f"{best:.2f} < {self.unknown_threshold:.2f}; nearest: {nearest}); the motion may not follow it")
            if self.unknown_text == "reject":
                raise RequestLimitError(f"segments.{index}.text", why)
            warnings.append(f"segments.{index}.text: {why}")
        return warnings

    def generate(self, request: GenerationRequest) -> Motion:
        """One request on its own; raises what the batch would have returned in its place."""
        (result,) = self.generate_batch([request])
        if isinstance(result, BaseException):
            raise result
        return result

    def generate_batch(self, requests: Sequence[GenerationRequest],
                       on_step: Callable[[int], None] | None = None) -> list[Motion | BaseException]:
        """Generate all requests with their GPT steps batched together; a request's failure lands in its slot."""
        prepared = self.prepare(requests)
        results: list[Motion | BaseException | None] = list(prepared.failures)
        if prepared.jobs:
            codes = self.codes.sample(prepared.jobs, self.limits.max_tokens, on_step)
            for index, segment_codes, warnings in zip(prepared.owners, codes, prepared.notes):
                results[index] = self.finish(requests[index], segment_codes, warnings)
        return results  # type: ignore[return-value]

    def prepare(self, requests: Sequence[GenerationRequest]) -> PreparedJobs:
        """Each request's sampling job (texts encoded, limits checked, streaming attached), or its failure."""
        prepared = PreparedJobs(failures=[None] * len(requests))
        for index, request in enumerate(requests):
            if request.cancelled:
                prepared.failures[index] = GenerationCancelled("request cancelled before it started")
                continue
            try:
                job = self.codes.job(request, self.text, self.limits)
                warnings = self.unknown_text_warnings([s.text for s in request.segments], job.conds)
                self._stream_early(job, request)
            except RequestLimitError as error:
                prepared.failures[index] = error
                continue
            except Exception as error:  # one bad request must not sink the batch
                log.exception("text encoding failed")
                prepared.failures[index] = error
                continue
            prepared.jobs.append(job)
            prepared.owners.append(index)
            prepared.notes.append(warnings)
        return prepared

    def finish(self, request: GenerationRequest, segment_codes: list[np.ndarray] | None,
               warnings: list[str]) -> Motion | BaseException:
        """A request's codes (None: cancelled on the way) decoded once into its Motion, or the failure."""
        if segment_codes is None:
            return GenerationCancelled("request cancelled during generation")
        try:
            return self._motion(request, segment_codes, warnings)
        except Exception as error:
            log.exception("decoding failed")
            return error

    def encode(self, features: np.ndarray) -> np.ndarray:
        """Features [frames, D] (frames a multiple of frames_per_token) -> normalised with the bundle's mean/std ->
        codes [frames / f, *step shape] by its encoder.onnx, the layout its decoder reads (an uploaded motion:
        service/uploads.py)."""
        session = self.bundle.encoder_session
        layout = self.limits.codes
        if session is None or layout is None:
            raise ValueError(f"model {self.limits.name!r} has no encoder graph")
        normalised = (np.asarray(features, dtype=np.float32) - self.bundle.mean) / self.bundle.std
        codes = session.run(["codes"], {"features": normalised.astype(np.float32)[None]})[0][0]
        return np.asarray(codes, dtype=np.int64).reshape(len(codes), *layout.shape)

    def compose(self, request: GenerationRequest, segment_codes: Sequence[np.ndarray]) -> Motion:
        """The motion of given codes, one array per segment of `request` (an edit: kept segments' codes from a
        handle, the regenerated ones' just sampled), decoded once and fitted to the request's durations exactly as
        a generated request's are; nothing is sampled. The codes must be the model's (service/handles.py checks a
        handle's against `limits.codes`)."""
        if len(segment_codes) != len(request.segments):
            raise ValueError(f"{len(segment_codes)} code arrays for {len(request.segments)} segments")
        dtype = np.float32 if self.limits.recipe else np.int64   # the diffusion family's codes are its frames
        return self._motion(request, [np.asarray(codes, dtype=dtype) for codes in segment_codes], [])

    def edit_recipe(self, handle: str, edits: Sequence[Any]) -> Any:
        """The edit of one of this model's recipe handles, made by its family's served object on its own frames
        (the diffusion family); a model whose handles are codes has none (ValueError)."""
        if not isinstance(self.codes, RecipeHandles):
            raise ValueError(f"model {self.limits.name!r} answers with handles of codes, not recipes")
        return self.codes.edit_recipe(self, handle, edits)

    def continuous(self, order: StepOrder | None = None) -> RunningCohorts | None:
        """A continuous-batching session (requests join and leave at step boundaries; `order` picks the cohorts
        that step at each: the shortest work first by default) for the families that can, or None (e.g. the masked
        family, not autoregressive: run-to-completion micro-batching)."""
        if not self.capabilities.continuous_batching:
            return None
        if not isinstance(self.codes, CohortSource):
            raise TypeError(f"family {self.bundle.manifest.family!r} declares continuous batching, but its served "
                            "object starts no cohorts (no `cohort` method)")
        return RunningCohorts(self, self.codes, order)

    def _motion(self, request: GenerationRequest, segment_codes: list[np.ndarray], warnings: list[str]) -> Motion:
        per_token = self.limits.frames_per_token
        decoded = [len(codes) * per_token for codes in segment_codes]
        features = self.decoder.decode(np.concatenate(segment_codes))
        if len(features) != sum(decoded):
            raise RuntimeError(f"decoder.onnx returned {len(features)} frames for {sum(decoded) // per_token} tokens, "
                               f"expected {sum(decoded)} (frames_per_token {per_token})")
        targets = self._targets(request)
        joints = fit_frames(np.asarray(features_to_joints(features, self.skeleton), dtype=np.float32), decoded,
                            targets)
        spans, start = [], 0
        for segment, target, frames in zip(request.segments, targets, decoded):
            end = start + (frames if target is None else target)
            spans.append(SegmentSpan(text=segment.text, start_frame=start, end_frame=end))
            start = end
        warnings = list(warnings)
        if request.guidance != 1.0 and not self.limits.unconditional_branch:
            warnings.append(f"guidance {request.guidance:g} requested but model {self.limits.name!r} was trained "
                            "without an unconditional branch; the null-condition logits are untrained")
        return Motion(joints=joints, fps=self.limits.fps, segments=spans, seed=request.seed,
                      tokens=sum(decoded) // per_token, warnings=warnings, codes=list(segment_codes))
