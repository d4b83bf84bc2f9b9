"""The diffusion family's "codes" for the engine (MDM, DiP): per segment its normalised feature frames [frames, D],
made by t2m.families.diffusion.loop over denoiser.onnx (one call per diffusion step for every job of the batch:
guidance's
null rows and concurrent requests together), then de-normalised by the engine's one decode of decoder.onnx.

- A segment of d seconds is round(d * fps) frames, made exactly (frames_per_token 1: no resampling); a null duration
  is refused (these models have no length estimator).
- Each request draws from its own generator (numpy, seeded by the request's seed) in a fixed order: its jobs step
  together and draw in segment order, so its motion does not depend on what shares the batch.
- MDM (whole motions): every sentence of every request is one job; then, for requests of several sentences, one
  in-between job per join (t2m.families.diffusion.loop.join_windows): the unconditional model (a zero text, as MDM's
  edit.py in_between without a text) re-makes the frames around the join with the frames on both sides known.
- DiP (calls): a SegmentChain per request, each segment its own calls with its own text; the bundle's prefix (a
  standing pose) starts the first call; after each call the frames kept so far are final and go to the request's
  streaming hook (`progress`).
- temperature and top_k have no meaning here: anything but temperature 1 and no top_k is refused naming the field.
- Edits (POST /edit, service/diffusion_edits.py): `inpaint` denoises frames with some values known (MDM: one window;
  DiP: calls of pred_len after a given prefix, the known values imposed wherever they fall); answers' handles are
  recipes (`recipe_handles`: service/recipes.py), and `body_parts` are feature channels (engine/body_parts.py).
"""
from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import onnxruntime as ort

from t2m.bundle import BundleError
from t2m.families.diffusion.edits import edit_recipe
from t2m.families.diffusion.loop import (
    DiffusionJob,
    JoinWindow,
    NoiseSource,
    SegmentChain,
    _next_prefix,
    cosine_schedule,
    join_windows,
    numbered_join_windows,
    run_jobs,
    sample_segment_chains,
)
from t2m.motion.skeleton import get_skeleton
from t2m.runtime.body_parts import part_channels
from t2m.runtime.bundle_loader import Bundle
from t2m.runtime.reach import DecoderReach
from t2m.runtime.requests import segment_steps
from t2m.runtime.text import TextEncoder, encode_token_states, pooled_token_states
from t2m.runtime.types import GenerationRequest, ModelLimits, RequestLimitError

__all__ = ["DiffusionCodes", "DiffusionRequest", "OnnxDenoiser", "frame_reach"]


class OnnxDenoiser:
    """denoiser.onnx as the loop's Denoiser. A graph that masks padded frames (`length` input) takes the whole batch
    in one call; one that does not (the 2022 MDM releases attend to padding) gets one call per distinct length, each
    cropped to it, so no row sees another's padding."""

    def __init__(self, session: ort.InferenceSession) -> None:
        self.session = session
        self.inputs = {graph_input.name for graph_input in session.get_inputs()}
        self.masks_frames = "length" in self.inputs

    def __call__(self, x_t: np.ndarray, t: np.ndarray, text: np.ndarray, text_mask: np.ndarray | None,
                 length: np.ndarray, prefix: np.ndarray | None) -> np.ndarray:
        lengths = np.unique(length)
        if self.masks_frames or (len(lengths) == 1 and lengths[0] == x_t.shape[1]):
            return self._run(x_t, t, text, text_mask, length, prefix)
        out = np.zeros_like(x_t)
        for frames in lengths:
            rows = np.flatnonzero(length == frames)
            out[rows, :frames] = self._run(x_t[rows, :frames], t[rows], text[rows],
                                           None if text_mask is None else text_mask[rows], length[rows],
                                           None if prefix is None else prefix[rows])
        return out

    def _run(self, x_t: np.ndarray, t: np.ndarray, text: np.ndarray, text_mask: np.ndarray | None,
             length: np.ndarray, prefix: np.ndarray | None) -> np.ndarray:
        feed: dict[str, np.ndarray] = {"x_t": np.ascontiguousarray(x_t, np.float32), "t": t.astype(np.int64),
                                       "text": np.ascontiguousarray(text, np.float32)}
        for name, value in (("text_mask", text_mask), ("length", length), ("prefix", prefix)):
            if name in self.inputs:
                if value is None:
                    raise ValueError(f"denoiser.onnx needs {name!r}")
                feed[name] = np.ascontiguousarray(value)
        (x0,) = self.session.run(["x0"], feed)
        return np.asarray(x0, np.float32)


def frame_reach(decoder: ort.InferenceSession, features: int, frames: int = 16) -> DecoderReach:
    """decoder.onnx de-normalises frame by frame, so a frame is final as soon as it is made (reach 0 both ways):
    checked on random frames by changing the middle one; a decoder whose other frames move is refused."""
    rng = np.random.default_rng(0)
    motion = rng.standard_normal((1, frames, features)).astype(np.float32)
    changed = motion.copy()
    changed[0, frames // 2] = rng.standard_normal(features)
    (before,) = decoder.run(["features"], {"motion": motion})
    (after,) = decoder.run(["features"], {"motion": changed})
    moved = np.flatnonzero((np.asarray(before) != np.asarray(after)).any(axis=2)[0])
    if moved.tolist() != [frames // 2]:
        raise BundleError(f"decoder.onnx: changing frame {frames // 2} moved frames {moved.tolist()}; the diffusion "
                          "family's decoder must de-normalise each frame on its own")
    return DecoderReach(ahead=0, behind=0)


@dataclass
class DiffusionRequest:
    """One request's work: its segments' texts (pooled [Dt] or token states [L, Dt] with masks) and frames, its
    guidance and generator; `conds` (pooled features) serve the unknown-text check; `progress` is the engine's
    streaming hook (DiP); `noise` replaces the generator's draws, in the same order (x_T then one per step, job
    after job as the loop draws them), for parity runs."""

    conds: np.ndarray
    texts: list[np.ndarray]
    text_masks: list[np.ndarray] | None
    frames: list[int]
    guidance: float
    rng: np.random.Generator
    cancelled: Callable[[], bool]
    progress: Callable[[Sequence[Any], Sequence[bool]], None] | None = None
    noise: NoiseSource | None = None   # injected draws instead of the generator's (parity runs)


class DiffusionCodes:
    """Requests -> per-segment normalised frames with the bundle's denoiser graph."""

    ends_segments = None   # no length estimator: every segment needs a duration
    recipe_handles = True  # no codes: an answer's handle is its recipe (t2m/runtime/recipes.py)

    def edit_recipe(self, engine: Any, handle: str, edits: Sequence[Any]) -> Any:
        """An edit of one of this model's recipes: replayed, then inpainted on its frames (edits.py)."""
        return edit_recipe(engine, handle, edits)

    def __init__(self, bundle: Bundle) -> None:
        manifest = bundle.manifest
        self.settings = manifest.settings   # t2m.families.diffusion.family.DiffusionSettings
        self.features = manifest.feature_dim
        self.schedule = cosine_schedule(self.settings.steps)
        self.denoiser: Any = OnnxDenoiser(bundle.step_session("denoiser.onnx"))   # replayed with T2M_CUDA_GRAPHS
        self.decoder_reach = frame_reach(bundle.decoder_session, self.features)
        self.body_parts = part_channels(get_skeleton(manifest.skeleton).joint_names, self.features)
        self.prefix: np.ndarray | None = None
        if self.settings.chained:
            path = bundle.path / str(self.settings.prefix)
            try:
                prefix = np.load(path, allow_pickle=False)
            except ValueError as error:
                raise BundleError(f"{path}: not a numpy array file ({error})") from None
            want = (self.settings.context_len, self.features)
            if prefix.shape != want or not np.isfinite(prefix).all():
                raise BundleError(f"{path}: shape {prefix.shape}, expected finite values of shape {want} "
                                  "(diffusion.context_len frames of normalised features)")
            self.prefix = prefix.astype(np.float32)

    def job(self, request: GenerationRequest, text: TextEncoder, limits: ModelLimits) -> DiffusionRequest:
        if request.top_k is not None:
            raise RequestLimitError("top_k", f"model {limits.name!r} is a diffusion model and draws no codes; leave "
                                    "top_k out")
        if request.temperature != 1.0:
            raise RequestLimitError("temperature", f"model {limits.name!r} is a diffusion model (DDPM sampling has no "
                                    f"temperature); leave it at 1, got {request.temperature:g}")
        frames = [int(steps) for steps in segment_steps(
            request, limits, free=f"model {limits.name!r} has no length estimator; give this segment a duration "
                                  "in seconds") if steps is not None]
        sentences = [segment.text for segment in request.segments]
        masks: list[np.ndarray] | None = None
        if self.settings.tokens:
            texts, masks = encode_token_states(text, sentences)
            conds = pooled_token_states(texts)
        else:
            conds = text.encode(sentences)
            texts = list(conds)
        return DiffusionRequest(conds=conds, texts=texts, text_masks=masks, frames=frames, guidance=request.guidance,
                                rng=np.random.default_rng(request.seed), cancelled=lambda: request.cancelled)

    def sample(self, jobs: Sequence[DiffusionRequest], max_tokens: int,
               on_step: Callable[[int], None] | None) -> list[list[np.ndarray] | None]:
        if self.settings.chained:
            return self._chains(jobs, on_step)
        return self._whole(jobs, on_step)

    # ------------------------------------------------------------------------------------------------ edits

    def prefix_before(self, frames: np.ndarray) -> np.ndarray:
        """DiP: the clean frames a call after `frames` [n, F] starts from (the bundle's standing pose before the
        first frames, as the first call of a request)."""
        assert self.prefix is not None
        return _next_prefix(self.prefix, np.asarray(frames, np.float32))

    def inpaint(self, job: DiffusionRequest, known: np.ndarray, known_mask: np.ndarray,
                prefix: np.ndarray | None = None, segment: int = 0) -> np.ndarray:
        """Frames [W, F] made with the job's `segment`-th text, its guidance and generator where `known_mask`
        ([W, F] or [W, 1]) is False, the `known` values elsewhere (imposed on x0 at every step, and exactly in the
        answer). MDM: one window of W frames (W <= max_tokens). DiP: ceil(W / pred_len) calls after `prefix` (a
        call's frames past W are free and dropped), each call continuing from the frames kept before it."""
        text, mask = job.texts[segment], None if job.text_masks is None else job.text_masks[segment]
        known = np.asarray(known, np.float32)
        known_mask = np.broadcast_to(np.asarray(known_mask, bool), known.shape)
        width = self.settings.pred_len if self.settings.chained else len(known)
        context = prefix
        made = []
        for first in range(0, len(known), width):
            kept = min(width, len(known) - first)
            values = np.zeros((width, self.features), np.float32)
            where = np.zeros((width, self.features), bool)
            values[:kept], where[:kept] = known[first:first + kept], known_mask[first:first + kept]
            call = DiffusionJob(text=text, text_mask=mask, frames=width, rng=job.rng, guidance=job.guidance,
                                prefix=context, known=values, known_mask=where, noise=job.noise)
            run_jobs(self.denoiser, self.schedule, [call], self.features)
            made.append(call.x[:kept])
            if context is not None:
                context = _next_prefix(context, call.x[:kept])
        return np.where(known_mask, known, np.concatenate(made)).astype(np.float32)

    def whole(self, job: DiffusionRequest) -> list[np.ndarray]:
        """MDM: each segment of the job a whole motion (one batch), as /generate makes them before its joins."""
        made = [DiffusionJob(text=job.texts[k], frames=frames, rng=job.rng, guidance=job.guidance,
                             text_mask=None if job.text_masks is None else job.text_masks[k], noise=job.noise)
                for k, frames in enumerate(job.frames)]
        run_jobs(self.denoiser, self.schedule, made, self.features)
        return [one.x for one in made]

    def rejoin(self, job: DiffusionRequest, parts: Sequence[np.ndarray], joins: set[int]) -> list[np.ndarray]:
        """MDM: the segments `parts` with the joins k in `joins` (between parts k and k + 1) in-betweened as
        /generate's joins are (the windows of all the parts' joins, only those made again), in one batch."""
        frames = [len(part) for part in parts]
        windows = [window for k, window in numbered_join_windows(frames, self.settings.join_frames,
                                                                 self.settings.join_context) if k in joins]
        motion = np.concatenate(parts)
        edits = [self._join_job(job, motion, window) for window in windows]
        if edits:
            run_jobs(self.denoiser, self.schedule, edits, self.features)
        for window, edit in zip(windows, edits):
            motion[window.start:window.end] = edit.x
        return np.split(motion, np.cumsum(frames)[:-1])

    # ------------------------------------------------------------------------------------------------ DiP

    def _chains(self, jobs: Sequence[DiffusionRequest],
                on_step: Callable[[int], None] | None) -> list[list[np.ndarray] | None]:
        assert self.prefix is not None
        chains = [SegmentChain(texts=job.texts, frames=job.frames, prefix=self.prefix.copy(), rng=job.rng,
                               guidance=job.guidance, text_masks=job.text_masks, cancelled=job.cancelled,
                               noise=job.noise, crossfade=self.settings.crossfade)
                  for job in jobs]

        def after_call(index: int, chain: SegmentChain) -> None:
            progress = jobs[index].progress
            if progress is not None:
                progress(chain.segments(), chain.finished())

        return sample_segment_chains(self.denoiser, self.schedule, chains, self.settings.pred_len,
                                     after_call=after_call, on_step=on_step)

    # ------------------------------------------------------------------------------------------------ MDM

    def _whole(self, jobs: Sequence[DiffusionRequest],
               on_step: Callable[[int], None] | None) -> list[list[np.ndarray] | None]:
        """Every sentence a whole motion (one batch), then every join in-betweened (a second batch)."""
        owners: dict[int, DiffusionRequest] = {}
        sentences = []
        for job in jobs:
            for k, frames in enumerate(job.frames):
                sentence = DiffusionJob(text=job.texts[k], frames=frames, rng=job.rng, guidance=job.guidance,
                                        text_mask=None if job.text_masks is None else job.text_masks[k],
                                        noise=job.noise)
                owners[id(sentence)] = job
                sentences.append(sentence)
        run_jobs(self.denoiser, self.schedule, sentences, self.features, on_step,
                 keep=lambda sentence: not owners[id(sentence)].cancelled())
        made: list[list[np.ndarray] | None] = []
        position = 0
        for job in jobs:
            parts = [sentence.x for sentence in sentences[position:position + len(job.frames)]]
            position += len(job.frames)
            made.append(None if job.cancelled() else parts)
        self._join(jobs, made, on_step)
        return [None if parts is None or job.cancelled() else parts for job, parts in zip(jobs, made)]

    def _null_text(self, job: DiffusionRequest) -> tuple[np.ndarray, np.ndarray | None]:
        """The unconditional condition: a zero text (token states: one zero token, the same memory value as any
        number of them)."""
        dim = job.texts[0].shape[-1]
        if job.text_masks is None:
            return np.zeros(dim, np.float32), None
        return np.zeros((1, dim), np.float32), np.ones(1, bool)

    def _join_job(self, job: DiffusionRequest, motion: np.ndarray, window: JoinWindow) -> DiffusionJob:
        """The in-between of one join window of a request's motion: the unconditional model, its sides known."""
        text, mask = self._null_text(job)
        return DiffusionJob(text=text, text_mask=mask, frames=window.frames, rng=job.rng, guidance=1.0,
                            known=motion[window.start:window.end], known_mask=window.known_mask(), noise=job.noise)

    def _join(self, jobs: Sequence[DiffusionRequest], made: list[list[np.ndarray] | None],
              on_step: Callable[[int], None] | None) -> None:
        """In-between each join of a request's sentences (in place), every join of every request in one batch."""
        s = self.settings
        windows, owners = [], []
        for index, (job, parts) in enumerate(zip(jobs, made)):
            if parts is None or len(parts) < 2 or s.join_frames == 0:
                continue
            motion = np.concatenate(parts)
            for window in join_windows(job.frames, s.join_frames, s.join_context):
                windows.append((window, self._join_job(job, motion, window)))
                owners.append(index)
        if not windows:
            return
        edits = [edit for _, edit in windows]
        owner_of = {id(edit): jobs[index] for edit, index in zip(edits, owners)}
        steps = self.schedule.steps
        run_jobs(self.denoiser, self.schedule, edits, self.features,
                 None if on_step is None else lambda n: on_step(steps + n),
                 keep=lambda edit: not owner_of[id(edit)].cancelled())
        motions = {index: np.concatenate(made[index]) for index in set(owners)}  # type: ignore[arg-type]
        for (window, edit), index in zip(windows, owners):
            motions[index][window.start:window.end] = edit.x
        for index, motion in motions.items():
            bounds = np.cumsum(jobs[index].frames)[:-1]
            made[index] = np.split(motion, bounds)
