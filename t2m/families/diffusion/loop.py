"""The diffusion family's loop (MDM, DiP): DDPM ancestral sampling of an x0 predictor, torch-free.

The official sampler (docs: ../shared/docs/diffusion-models.md §3, §5, §6), reproduced here:

- the cosine schedule with the model's trained number of steps N (1000, 50 or 10), no respacing, tables in float64,
  each step's coefficient cast to float32 when used;
- a step from x_t to x_{t-1}: x0 = denoiser(x_t, t, condition), guided as uncond + s (cond - uncond) with a zero text
  as the null condition; known x0 values overwrite the prediction where a mask says so (MDM's editing: in-between,
  body parts); mean = coef1[t] x0 + coef2[t] x_t; x_{t-1} = mean + sigma_t noise (FIXED_SMALL: the posterior
  variance; noise is drawn at every step, also at t = 0 where it is multiplied by 0). At t = 0 coef1 = 1 and
  coef2 = 0, so known values come out exactly;
- draws in the official order: x_T, then one draw of the motion's shape per step. A job's draws come from its own
  Generator (or from injected noise, for parity with the official code whose torch RNG numpy cannot reproduce), so
  a request's result does not depend on what else shares the batch;
- DiP: each call denoises `pred_len` (40) frames after a clean prefix of `context_len` (20) frames; the last 20
  frames of a call are the next call's prefix, and each call may have its own text.

What the service adds for a request of several sentences (segments of exact frame counts):

- DiP (:class:`SegmentChain`): a segment covers its own calls, ⌈frames / pred_len⌉ of them, all with its text; its
  last call keeps only the frames the segment still needs (the rest is dropped) and the next call continues from
  the last `context_len` frames kept. No call straddles two sentences, and every segment has exactly its frames.
  With `crossfade` F > 0 (not in the official code, which switches texts from one call to the next), the first call
  of every sentence after the first cross-fades the condition: its conditional prediction is w (new text) + (1 - w)
  (previous text), w rising linearly from 0 at its first frame to 1 at frame F, then guided as usual. Switched at
  full guidance, the new text's prediction is pushed away from the prefix's motion and the join is a near cut
  (t2m/families/diffusion/README.md measures both).
- MDM (:func:`join_windows`): each sentence is one whole motion; at each join a window is denoised again with
  known frames on its two sides (MDM's own in-betweening, edit.py's in_between mode) so the join is made anew.

Frames are [T, F] per job ([B, T, F] batched). The denoiser is one batched call per step, an ONNX graph or a
PyTorch module behind :class:`Denoiser`: a job's conditional row and, when its guidance is not 1, its null row go
into the same call, and jobs of any length share it (each row's valid length is an input).
"""
from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import NamedTuple, Protocol

import numpy as np

__all__ = ["DIP_GUIDANCE", "MDM_GUIDANCE", "CrossFade", "Denoiser", "DiffusionChain", "DiffusionJob", "JoinWindow",
           "NoiseSource", "Schedule", "SegmentChain", "chain_calls", "cosine_alpha_bar", "cosine_betas",
           "cosine_schedule", "crossfade_weights", "denoise_step", "guided", "join_windows", "noise_from",
           "numbered_join_windows", "official_to_frames", "run_jobs", "sample", "sample_chains",
           "sample_segment_chains", "start"]

MDM_GUIDANCE = 2.5   # generate.py's default guidance_param
DIP_GUIDANCE = 7.5   # DiP.md's command line
MAX_BETA = 0.999

NoiseSource = Callable[[tuple[int, ...]], np.ndarray]
"""shape -> float32 standard normal draws of that shape; called for x_T, then once per step."""


class Denoiser(Protocol):
    """The network as one batched call, what an ONNX graph takes: x_t float32 [B, T, F], t int64 [B], text float32
    [B, Dt] (pooled) or [B, L, Dt] (token states), text_mask bool [B, L] (True = real token) or None, length int64
    [B] (valid frames of x_t; rows are zero-padded past it), prefix float32 [B, P, F] (DiP's clean frames) or None
    -> x0 float32 [B, T, F]."""

    def __call__(self, x_t: np.ndarray, t: np.ndarray, text: np.ndarray, text_mask: np.ndarray | None,
                 length: np.ndarray, prefix: np.ndarray | None) -> np.ndarray: ...


# ---------------------------------------------------------------------------------------------------- schedule


@dataclass(frozen=True)
class Schedule:
    """The float64 tables of a trained step count; index t = 0..N-1 (t = N-1 is the noisiest)."""

    betas: np.ndarray
    alphas_cumprod: np.ndarray
    alphas_cumprod_prev: np.ndarray
    posterior_variance: np.ndarray
    posterior_log_variance: np.ndarray   # log of the variance, entry 0 replaced by entry 1 (log 0 is -inf)
    coef1: np.ndarray                    # posterior mean = coef1 x0 + coef2 x_t
    coef2: np.ndarray

    @property
    def steps(self) -> int:
        return len(self.betas)

    def at(self, t: int) -> tuple[np.float32, np.float32, np.float32]:
        """(coef1, coef2, sigma) of step t in float32, as the official code casts per step."""
        sigma = np.exp(np.float32(0.5) * np.float32(self.posterior_log_variance[t]))
        return np.float32(self.coef1[t]), np.float32(self.coef2[t]), np.float32(sigma)


def cosine_alpha_bar(s: float) -> float:
    """ᾱ at diffusion time s in [0, 1]: cos((s + 0.008) / 1.008 · π/2)²."""
    return math.cos((s + 0.008) / 1.008 * math.pi / 2) ** 2


def cosine_betas(steps: int) -> np.ndarray:
    """β_i = min(1 − ᾱ((i+1)/N) / ᾱ(i/N), 0.999), computed in Python floats."""
    if steps < 1:
        raise ValueError(f"steps must be >= 1, got {steps}")
    betas = [min(1 - cosine_alpha_bar((i + 1) / steps) / cosine_alpha_bar(i / steps), MAX_BETA)
             for i in range(steps)]
    return np.array(betas, dtype=np.float64)


def cosine_schedule(steps: int) -> Schedule:
    """The tables the official sampler uses for a model trained with `steps` steps. Its respacing wrapper keeps
    every step but re-derives β_i = 1 − ᾱ_i / ᾱ_{i−1} from the cumulative product, which differs from the raw
    cosine betas in the last bits; done the same way here, so the tables agree exactly."""
    if steps < 2:
        raise ValueError(f"a diffusion schedule needs at least 2 steps, got {steps}")
    raw_cumprod = np.cumprod(1.0 - cosine_betas(steps))
    previous, betas = 1.0, []
    for value in raw_cumprod:
        betas.append(1 - value / previous)
        previous = value
    beta = np.array(betas, dtype=np.float64)
    alphas = 1.0 - beta
    cumprod = np.cumprod(alphas)
    cumprod_prev = np.append(1.0, cumprod[:-1])
    variance = beta * (1.0 - cumprod_prev) / (1.0 - cumprod)
    log_variance = np.log(np.append(variance[1], variance[1:]))
    return Schedule(
        betas=beta,
        alphas_cumprod=cumprod,
        alphas_cumprod_prev=cumprod_prev,
        posterior_variance=variance,
        posterior_log_variance=log_variance,
        coef1=beta * np.sqrt(cumprod_prev) / (1.0 - cumprod),
        coef2=(1.0 - cumprod_prev) * np.sqrt(alphas) / (1.0 - cumprod),
    )


def guided(cond: np.ndarray, uncond: np.ndarray, scale: float) -> np.ndarray:
    """Classifier-free guidance on x0: uncond + s (cond − uncond), in float32 (s = 0: the unconditional output)."""
    return uncond + np.float32(scale) * (cond - uncond)


def crossfade_weights(frames: int, fade: int) -> np.ndarray:
    """The new text's weight per frame [frames, 1]: 0 at frame 0 (the previous text's prediction), rising linearly
    to 1 at frame `fade` and after."""
    if fade < 1:
        raise ValueError(f"a cross-fade needs at least one frame, got {fade}")
    return np.minimum(np.arange(frames, dtype=np.float64) / fade, 1.0).astype(np.float32)[:, None]


# --------------------------------------------------------------------------------------------------------- noise


def noise_from(draws: Sequence[np.ndarray] | Callable[[tuple[int, ...]], np.ndarray]) -> NoiseSource:
    """Injected noise: arrays used in order (x_T, then one per step, call after call), or a callable. Shapes are
    checked, so a parity test cannot silently consume noise in another order."""
    if callable(draws):
        return draws
    remaining = iter(draws)

    def next_draw(shape: tuple[int, ...]) -> np.ndarray:
        try:
            draw = np.asarray(next(remaining), dtype=np.float32)
        except StopIteration:
            raise ValueError("the injected noise ran out") from None
        if draw.shape != shape:
            raise ValueError(f"injected noise has shape {draw.shape}, the sampler needs {shape}")
        return draw

    return next_draw


def official_to_frames(x: np.ndarray) -> np.ndarray:
    """An official tensor [B, F, 1, T] (noise, samples) as frames [B, T, F]."""
    return np.ascontiguousarray(np.asarray(x)[:, :, 0, :].transpose(0, 2, 1))


# ---------------------------------------------------------------------------------------------------------- jobs


class CrossFade(NamedTuple):
    """Where a job's conditional prediction fades in from: the previous sentence's text and mask, and the job's own
    text's weight per frame [frames, 1] (crossfade_weights)."""

    text: np.ndarray
    text_mask: np.ndarray | None
    weight: np.ndarray


@dataclass
class DiffusionJob:
    """One motion to denoise: its condition, length, generator and settings, and the running state (x_t and the
    next step). `known` / `known_mask` [T, F] (the mask may broadcast, e.g. [1, F] for body parts): x0 values
    imposed where the mask is True. `prefix` [P, F]: DiP's clean frames before the motion."""

    text: np.ndarray                        # [Dt] pooled, or [L, Dt] token states
    frames: int
    rng: np.random.Generator
    guidance: float = 1.0
    text_mask: np.ndarray | None = None     # [L] bool, True = real token (token states only)
    crossfade: CrossFade | None = None      # DiP: the first call of a later sentence
    prefix: np.ndarray | None = None
    known: np.ndarray | None = None
    known_mask: np.ndarray | None = None
    noise: NoiseSource | None = None        # None: the job's rng
    x: np.ndarray = field(init=False, repr=False)
    t: int = field(init=False, default=-1)  # the next step; -1 = done (or not started)

    @property
    def guided(self) -> bool:
        """Whether the job needs a null row (any scale other than 1)."""
        return self.guidance != 1.0

    def draw(self, shape: tuple[int, ...]) -> np.ndarray:
        if self.noise is not None:
            return self.noise(shape)
        return self.rng.standard_normal(shape, dtype=np.float32)

    def impose_known(self, x0: np.ndarray) -> np.ndarray:
        """The prediction with known values written over it (nothing to do without a mask)."""
        if self.known is None or self.known_mask is None:
            return x0
        return np.where(self.known_mask, self.known, x0).astype(np.float32)


def start(job: DiffusionJob, schedule: Schedule, features: int) -> None:
    """Draw x_T and set the job at step N − 1."""
    if job.frames < 1:
        raise ValueError(f"a job needs at least one frame, got {job.frames}")
    if (job.known is None) != (job.known_mask is None):
        raise ValueError("inpainting needs both known values and their mask")
    if job.known is not None and job.known_mask is not None:
        shape = (job.frames, features)
        if job.known.shape != shape or np.broadcast_shapes(job.known_mask.shape, shape) != shape:
            raise ValueError(f"known values {job.known.shape} / mask {job.known_mask.shape} do not fit {shape}")
    job.x = job.draw((job.frames, features))
    job.t = schedule.steps - 1


def _batch_text(texts: Sequence[tuple[np.ndarray, np.ndarray | None]]) -> tuple[np.ndarray, np.ndarray | None]:
    """Texts (text, mask) stacked; token states zero-padded to the longest, with their masks."""
    if any((mask is None) != (texts[0][1] is None) for _, mask in texts):
        raise ValueError("jobs in one batch must all give token states with masks, or all pooled features")
    if texts[0][1] is None:
        return np.stack([np.asarray(text, np.float32) for text, _ in texts]), None
    tokens = max(len(text) for text, _ in texts)
    stacked = np.zeros((len(texts), tokens, texts[0][0].shape[-1]), np.float32)
    masks = np.zeros((len(texts), tokens), bool)
    for row, (text, mask) in enumerate(texts):
        stacked[row, : len(text)] = text
        masks[row, : len(text)] = np.asarray(mask, bool)
    return stacked, masks


def _batch_prefix(jobs: Sequence[DiffusionJob]) -> np.ndarray | None:
    if all(job.prefix is None for job in jobs):
        return None
    prefixes = [job.prefix for job in jobs if job.prefix is not None]
    if len(prefixes) < len(jobs) or len({prefix.shape for prefix in prefixes}) > 1:
        raise ValueError("jobs in one batch must all have prefixes of one shape, or none")
    return np.stack(prefixes).astype(np.float32)


class _Rows(NamedTuple):
    """The Denoiser's arguments, in its order."""

    x_t: np.ndarray
    t: np.ndarray
    text: np.ndarray
    text_mask: np.ndarray | None
    length: np.ndarray
    prefix: np.ndarray | None


def _denoiser_rows(jobs: Sequence[DiffusionJob], features: int) -> _Rows:
    """The inputs of one step's call: each job's conditional row, then a null row (zero text, same mask and
    prefix) for each guided job, then a row of the previous sentence's text for each cross-fading job; x_t
    zero-padded to the longest job."""
    nulls = [job for job in jobs if job.guided]
    fading = [job for job in jobs if job.crossfade is not None]
    rows = [*jobs, *nulls, *fading]
    x = np.zeros((len(rows), max(job.frames for job in jobs), features), np.float32)
    for row, job in enumerate(rows):
        x[row, : job.frames] = job.x
    fades = [job.crossfade for job in fading if job.crossfade is not None]
    text, mask = _batch_text([(job.text, job.text_mask) for job in [*jobs, *nulls]]
                             + [(fade.text, fade.text_mask) for fade in fades])
    text[len(jobs):len(jobs) + len(nulls)] = 0.0
    return _Rows(x, np.array([job.t for job in rows], np.int64), text, mask,
                 np.array([job.frames for job in rows], np.int64), _batch_prefix(rows))


def denoise_step(denoiser: Denoiser, schedule: Schedule, jobs: Sequence[DiffusionJob]) -> None:
    """One step for every started job (each at its own t): one denoiser call, then each job's posterior draw."""
    jobs = [job for job in jobs if job.t >= 0]
    if not jobs:
        return
    x0 = np.asarray(denoiser(*_denoiser_rows(jobs, jobs[0].x.shape[1])), np.float32)
    null_row = len(jobs)
    fade_row = null_row + sum(job.guided for job in jobs)
    for row, job in enumerate(jobs):
        prediction = x0[row, : job.frames]
        if job.crossfade is not None:
            weight = job.crossfade.weight
            prediction = weight * prediction + (np.float32(1.0) - weight) * x0[fade_row, : job.frames]
            fade_row += 1
        if job.guided:
            prediction = guided(prediction, x0[null_row, : job.frames], job.guidance)
            null_row += 1
        _posterior_step(job, schedule, job.impose_known(prediction))


def _posterior_step(job: DiffusionJob, schedule: Schedule, x0: np.ndarray) -> None:
    """x_{t-1} = coef1 x0 + coef2 x_t + sigma noise (noise drawn also at t = 0, where it is not added)."""
    coef1, coef2, sigma = schedule.at(job.t)
    mean = coef1 * x0 + coef2 * job.x
    noise = job.draw(job.x.shape)
    job.x = (mean + sigma * noise if job.t > 0 else mean).astype(np.float32)
    job.t -= 1


def sample(denoiser: Denoiser, schedule: Schedule, jobs: Sequence[DiffusionJob], features: int) -> list[np.ndarray]:
    """Each job's motion [frames, F] after all N steps, the jobs stepped together in one batch."""
    run_jobs(denoiser, schedule, jobs, features)
    return [job.x for job in jobs]


# ---------------------------------------------------------------------------------------------------------- DiP


@dataclass
class DiffusionChain:
    """One DiP request: `frames` frames made `pred_len` at a time after a clean prefix; call i uses texts[i] (the
    last text when there are fewer texts than calls). `prefix` [P, F] is updated after every call to the call's
    last P frames, so a chain can be continued."""

    texts: Sequence[np.ndarray]                        # per call: [L, Dt] token states or [Dt]
    prefix: np.ndarray
    frames: int
    rng: np.random.Generator
    guidance: float = DIP_GUIDANCE
    text_masks: Sequence[np.ndarray] | None = None     # per call, with token states
    noise: NoiseSource | None = None

    def job(self, call: int, pred_len: int) -> DiffusionJob:
        index = min(call, len(self.texts) - 1)
        return DiffusionJob(text=self.texts[index], frames=pred_len, rng=self.rng, guidance=self.guidance,
                            text_mask=None if self.text_masks is None else self.text_masks[index],
                            prefix=self.prefix, noise=self.noise)


def chain_calls(frames: int, pred_len: int) -> int:
    """Calls needed for `frames` frames: ⌈frames / pred_len⌉."""
    return -(-frames // pred_len)


def sample_chains(denoiser: Denoiser, schedule: Schedule, chains: Sequence[DiffusionChain],
                  pred_len: int) -> list[np.ndarray]:
    """Each chain's frames [frames, F]: call after call, the chains still running batched together."""
    features = chains[0].prefix.shape[1]
    made: list[list[np.ndarray]] = [[] for _ in chains]
    for call in range(max(chain_calls(chain.frames, pred_len) for chain in chains)):
        running = [i for i, chain in enumerate(chains) if call < chain_calls(chain.frames, pred_len)]
        outputs = sample(denoiser, schedule, [chains[i].job(call, pred_len) for i in running], features)
        for i, new in zip(running, outputs):
            made[i].append(new)
            chains[i].prefix = _next_prefix(chains[i].prefix, new)
    return [np.concatenate(parts)[: chain.frames] for parts, chain in zip(made, chains)]


def _next_prefix(prefix: np.ndarray, new: np.ndarray) -> np.ndarray:
    """The last P frames of what the call made (and of the old prefix, were a call shorter than P)."""
    return np.concatenate([prefix, new])[-len(prefix):]


def run_jobs(denoiser: Denoiser, schedule: Schedule, jobs: Sequence[DiffusionJob], features: int,
             on_step: Callable[[int], None] | None = None,
             keep: Callable[[DiffusionJob], bool] | None = None) -> None:
    """All N steps of the jobs, stepped together (`sample` with hooks): after each step `on_step(steps so far)`;
    `keep(job)` False stops a job (its request was cancelled) before the next step."""
    for job in jobs:
        start(job, schedule, features)
    steps = 0
    while True:
        if keep is not None:
            for job in jobs:
                if job.t >= 0 and not keep(job):
                    job.t = -1
        if not any(job.t >= 0 for job in jobs):
            return
        denoise_step(denoiser, schedule, jobs)
        steps += 1
        if on_step is not None:
            on_step(steps)


# ------------------------------------------------------------------------------------- sentences: DiP and MDM


@dataclass
class SegmentChain:
    """One DiP request of several sentences: segment k's `frames[k]` frames come from ⌈frames[k] / pred_len⌉ calls
    with its own text (`texts[k]`, `text_masks[k]`); the last call's first frames are kept, as many as the segment
    still needs, and the next call starts after them. `prefix` [P, F]: the clean frames before the first call (the
    bundle's standing pose), then the last P frames kept. `made[k]`: segment k's kept frames, call by call.
    `crossfade`: frames over which the first call of each later segment cross-fades from the previous segment's
    text to its own (0: off, the official switch)."""

    texts: Sequence[np.ndarray]
    frames: Sequence[int]
    prefix: np.ndarray
    rng: np.random.Generator
    guidance: float = DIP_GUIDANCE
    text_masks: Sequence[np.ndarray] | None = None
    noise: NoiseSource | None = None
    cancelled: Callable[[], bool] | None = None
    crossfade: int = 0
    made: list[list[np.ndarray]] = field(init=False, repr=False)

    def __post_init__(self) -> None:
        if len(self.texts) != len(self.frames) or min(self.frames, default=0) < 1:
            raise ValueError(f"one text per segment and at least one frame each, got {len(self.texts)} texts for "
                             f"{list(self.frames)} frames")
        self.made = [[] for _ in self.frames]

    def calls(self, pred_len: int) -> list[tuple[int, int]]:
        """(segment, frames kept) of every call, in order."""
        return [(k, min(pred_len, frames - call * pred_len)) for k, frames in enumerate(self.frames)
                for call in range(chain_calls(frames, pred_len))]

    def job(self, segment: int, pred_len: int) -> DiffusionJob:
        mask = None if self.text_masks is None else self.text_masks[segment]
        job = DiffusionJob(text=self.texts[segment], frames=pred_len, rng=self.rng, guidance=self.guidance,
                           text_mask=mask, prefix=self.prefix, noise=self.noise)
        if self.crossfade > 0 and segment > 0 and not self.made[segment]:
            job.crossfade = CrossFade(self.texts[segment - 1],
                                      None if self.text_masks is None else self.text_masks[segment - 1],
                                      crossfade_weights(pred_len, self.crossfade))
        return job

    def keep(self, segment: int, new: np.ndarray, kept: int) -> None:
        self.made[segment].append(new[:kept])
        self.prefix = _next_prefix(self.prefix, new[:kept])

    def segments(self) -> list[np.ndarray]:
        """Each segment's frames kept so far [n, F] (n = frames[k] once it is finished)."""
        features = self.prefix.shape[1]
        return [np.concatenate(parts) if parts else np.zeros((0, features), np.float32) for parts in self.made]

    def finished(self) -> list[bool]:
        return [sum(len(part) for part in parts) == frames for parts, frames in zip(self.made, self.frames)]


def sample_segment_chains(denoiser: Denoiser, schedule: Schedule, chains: Sequence[SegmentChain], pred_len: int, *,
                          after_call: Callable[[int, SegmentChain], None] | None = None,
                          on_step: Callable[[int], None] | None = None) -> list[list[np.ndarray] | None]:
    """Every chain's segments ([frames[k], F] each; None: cancelled on the way), call after call, the chains still
    running batched together (their k-th calls share the denoiser calls, whatever segment each is in). After each
    call, `after_call(index, chain)`: the frames kept so far are final (DiP streams them)."""
    plans = [chain.calls(pred_len) for chain in chains]
    features = chains[0].prefix.shape[1]
    dropped: set[int] = set()
    steps = 0
    for call in range(max(len(plan) for plan in plans)):
        for index, chain in enumerate(chains):
            if chain.cancelled is not None and chain.cancelled():
                dropped.add(index)
        running = [i for i, plan in enumerate(plans) if call < len(plan) and i not in dropped]
        if not running:
            break
        jobs = [chains[i].job(plans[i][call][0], pred_len) for i in running]
        run_jobs(denoiser, schedule, jobs, features, _offset(on_step, steps))
        steps += schedule.steps
        for i, job in zip(running, jobs):
            segment, kept = plans[i][call]
            chains[i].keep(segment, job.x, kept)
            if after_call is not None:
                after_call(i, chains[i])
    return [None if index in dropped else chain.segments() for index, chain in enumerate(chains)]


def _offset(on_step: Callable[[int], None] | None, before: int) -> Callable[[int], None] | None:
    """on_step counting from `before` steps already made."""
    if on_step is None:
        return None
    return lambda steps: on_step(before + steps)


@dataclass(frozen=True)
class JoinWindow:
    """The in-between edit at one join of sentences made as whole motions: frames [start, end) of the joined motion
    are denoised again, the first `before` and the last `after` of them known (they come out exactly), the ones
    between them, around the join, made anew."""

    start: int
    end: int
    before: int
    after: int

    @property
    def frames(self) -> int:
        return self.end - self.start

    def known_mask(self) -> np.ndarray:
        """[frames, 1] bool: True on the known frames (every feature of them)."""
        mask = np.zeros((self.frames, 1), bool)
        mask[: self.before] = True
        mask[self.frames - self.after:] = True
        return mask


def join_windows(frames: Sequence[int], join: int, context: int) -> list[JoinWindow]:
    """The windows at the joins of segments of `frames` frames put end to end: on each side of a join, up to `join`
    frames made anew after up to `context` known ones. A segment lends each of its two joins at most half of its
    frames (its only join: all of them), so windows never overlap; a side lending fewer than join + context frames
    makes half of them anew (at most `join`) and keeps the rest. No window where nothing would be made anew."""
    return [window for _, window in numbered_join_windows(frames, join, context)]


def numbered_join_windows(frames: Sequence[int], join: int, context: int) -> list[tuple[int, JoinWindow]]:
    """join_windows with each window's join k (between segments k and k + 1)."""
    if join < 0 or context < 0:
        raise ValueError(f"join and context frames must be >= 0, got {join} and {context}")
    windows: list[tuple[int, JoinWindow]] = []
    boundary = 0
    last = len(frames) - 1
    for k in range(last):
        boundary += frames[k]
        left = frames[k] if k == 0 else frames[k] - frames[k] // 2
        right = frames[k + 1] if k + 1 == last else frames[k + 1] // 2
        sides = []
        for lent in (left, right):
            made = min(join, lent // 2 if context else lent)
            sides.append((made, min(context, lent - made)))
        (made_left, known_left), (made_right, known_right) = sides
        if made_left + made_right == 0:
            continue
        windows.append((k, JoinWindow(start=boundary - made_left - known_left,
                                      end=boundary + made_right + known_right, before=known_left, after=known_right)))
    return windows
