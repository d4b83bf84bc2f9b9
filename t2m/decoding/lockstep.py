"""What the autoregressive loops (the GPT's, T2M-HiFiGPT's) share: segments stepping in lockstep through a KV cache.

Each segment of each request is its own sequence (condition token, then one entry per time step), so all rows of a
batch are always at the same position. Per segment there is a cond row and, when its request's guidance != 1, a null
row (zero condition) after all cond rows; logits are combined as uncond + s * (cond - uncond). A segment with a target
stops at it; a free one stops when the family's rule says so or at max_tokens. Finished rows leave the batch (and its
cache) so that a long segment does not make the short ones pay: the loop asks the step to `keep_rows` of its cache
(a step may keep its cache on a device as an opaque handle; the numpy default slices the batch axis). Randomness
comes from each request's own numpy Generator, segments in request order, so a request's result does not depend on
what shares its batch. A job's
`progress` sees its segments' steps after every step that gave it some (the service streams frames from them).
"""
from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from t2m.decoding.tokens import RowRule, RowRules, guide_in_place, guided_logits

__all__ = [
    "Cohort",
    "DrawPlan",
    "Rows",
    "SamplingJob",
    "Segment",
    "StepRows",
    "check_targets",
    "draw_for_jobs",
    "drop_finished",
    "guided",
    "keep_rows",
    "live_segments",
    "report_progress",
    "results",
    "row_maps",
    "start",
]


@dataclass
class SamplingJob:
    """One request's segments in a lockstep batch."""

    conds: np.ndarray                   # float32 [S, Dt] text features, one row per segment
    targets: Sequence[int | None]       # time steps per segment; None = free length (the family's stop rule)
    guidance: float
    temperature: float
    top_k: int | None
    rng: np.random.Generator
    greedy: bool = False
    cancelled: Callable[[], bool] = field(default=lambda: False)
    # after each step that gave the job codes: each segment's steps so far and whether it is finished (streaming)
    progress: Callable[[list[list[Any]], list[bool]], None] | None = None

    @classmethod
    def of(cls, conds: np.ndarray, targets: Sequence[int | None], *, max_tokens: int, guidance: float = 1.0,
           temperature: float = 1.0, top_k: int | None = None, rng: np.random.Generator | int | None = None,
           greedy: bool = False, cancelled: Callable[[], bool] | None = None) -> SamplingJob:
        """The one way to make a job (service, PyTorch reference, bundle evaluation, parity): one condition row per
        target, each target in 1..max_tokens or None; temperature 0 means greedy (argmax); a seed or None becomes
        the job's own Generator."""
        conds = np.asarray(conds, dtype=np.float32)
        if len(targets) != len(conds):
            raise ValueError(f"{len(targets)} targets for {len(conds)} condition rows")
        job = cls(conds=conds, targets=[None if t is None else int(t) for t in targets], guidance=float(guidance),
                  temperature=temperature if temperature > 0 else 1.0, top_k=top_k,
                  rng=rng if isinstance(rng, np.random.Generator) else np.random.default_rng(rng),
                  greedy=greedy or temperature == 0, cancelled=cancelled or (lambda: False))
        check_targets([job], max_tokens)
        return job


@dataclass
class Segment:
    """One segment being generated: its job, its target and what it generated so far (one entry per step)."""

    job: int
    target: int | None
    tokens: list[Any] = field(default_factory=list)
    done: bool = False

    def reached(self, max_tokens: int) -> None:
        """Done once it holds its target's steps (a free segment: max_tokens)."""
        if len(self.tokens) == (self.target if self.target is not None else max_tokens):
            self.done = True


@dataclass
class StepRows:
    """The rows stepping together: row r works for segment `owner[r]`; cond rows come first, null rows after."""

    segments: list[Segment]
    of_job: list[list[int]]             # job -> its segments' indices
    cond: np.ndarray                    # float32 [rows, Dt]
    length: np.ndarray                  # int64 [rows]: the target (0 = free), the length input
    owner: np.ndarray                   # int64 [rows] -> segment index
    past: Any                           # the step's cache: a numpy array, or the step's own handle (a device)


@dataclass(frozen=True)
class Rows:
    """Where each live segment's cond row and (guided) null row are in the current batch."""

    cond: dict[int, int]
    null: dict[int, int]


def check_targets(jobs: Sequence[SamplingJob], max_tokens: int) -> None:
    """Every target within 1..max_tokens (or None), naming the segment: the loops' guard for jobs made by hand."""
    for job in jobs:
        for index, target in enumerate(job.targets):
            if target is not None and not 1 <= target <= max_tokens:
                raise ValueError(f"segment {index}: target of {target} tokens is outside 1..{max_tokens}")


def keep_rows(step: object, past: Any, keep: np.ndarray) -> Any:
    """`past` with only the rows where `keep` is true: the step's own `keep_rows(past, keep)` when it has one (a
    cache kept on a device, t2m.runtime.bound_step), else the numpy default, rows along axis 2 of
    [n_layer, 2, B, n_head, P, head_dim]."""
    own = getattr(step, "keep_rows", None)
    return own(past, keep) if own is not None else past[:, :, keep]


def start(jobs: Sequence[SamplingJob], empty_cache: Callable[[int], Any]) -> StepRows:
    """One cond row per segment of every job, then one null row per segment of every guided job."""
    segments: list[Segment] = []
    of_job: list[list[int]] = []
    conds: list[np.ndarray] = []
    for j, job in enumerate(jobs):
        of_job.append([])
        for s, target in enumerate(job.targets):
            of_job[j].append(len(segments))
            segments.append(Segment(job=j, target=target))
            conds.append(job.conds[s])
    owners = list(range(len(segments)))
    dim = jobs[0].conds.shape[1] if jobs else 0
    for index, segment in enumerate(segments):
        if jobs[segment.job].guidance != 1.0:
            conds.append(np.zeros(dim, dtype=np.float32))
            owners.append(index)
    owner = np.asarray(owners, dtype=np.int64)
    length = np.asarray([segments[s].target or 0 for s in owner], dtype=np.int64)
    cond = np.asarray(conds, dtype=np.float32).reshape(len(owners), dim)
    return StepRows(segments, of_job, cond, length, owner, empty_cache(len(owner)))


def row_maps(owner: np.ndarray) -> Rows:
    cond_row = {int(s): r for r, s in reversed(list(enumerate(owner)))}   # first row of each segment
    return Rows(cond_row, {int(s): r for r, s in enumerate(owner) if r != cond_row[int(s)]})


def guided(job: SamplingJob, active: Sequence[int], logits: np.ndarray, rows: Rows) -> np.ndarray:
    """The float64 logits of `active` segments of one job, with its guidance applied."""
    chosen = logits[[rows.cond[s] for s in active]].astype(np.float64)
    if job.guidance == 1.0:
        return chosen
    return guided_logits(chosen, logits[[rows.null[s] for s in active]].astype(np.float64), job.guidance)


DRAW_GROUP = 64      # segments per batched draw (see draw_for_jobs)


def _job_groups(going: Sequence[tuple[SamplingJob, Sequence[int]]],
                size: int) -> Iterator[tuple[list[tuple[SamplingJob, Sequence[int]]], int, int]]:
    """Runs of consecutive whole jobs of at least `size` segments (the last may be smaller): (the run, the index of
    its first segment among all of `going`'s, one past its last)."""
    group: list[tuple[SamplingJob, Sequence[int]]] = []
    start = count = 0
    for job, active in going:
        group.append((job, active))
        count += len(active)
        if count - start >= size:
            yield group, start, count
            group, start = [], count
    if group:
        yield group, start, count


def draw_for_jobs(logits: np.ndarray, rows: Rows, going: Sequence[tuple[SamplingJob, Sequence[int]]],
                  forbid: tuple[np.ndarray, int] | None = None) -> list[np.ndarray]:
    """Per (job, active segments) of `going`, the class drawn for each segment: its cond row's logits guided with
    its null row by the job's scale (as `guided`), then one draw each with the job's options and generator, all jobs
    in batched draws (tokens.draw_tokens_of_jobs: the same numbers as job by job). `forbid` = (mask over the
    active segments in order, class): that class is impossible where the mask is true (the GPT's End rule)."""
    plan = DrawPlan(rows, going)
    return plan.split(plan.draw(logits, forbid))


@dataclass
class _DrawGroup:
    """A run of whole jobs drawn in one batched draw: its segments' span, their cond and null rows, guidance."""

    start: int
    stop: int
    cond: np.ndarray
    null: np.ndarray | None
    scale: np.ndarray | None
    rules: RowRules

    @property
    def all_guided(self) -> bool:
        """Every row guided (no scale of 1): guidance computed over the cond logits in place."""
        return self.scale is not None and bool((self.scale != 1.0).all())


class DrawPlan:
    """What draw_for_jobs works out from (job, active segments) before any logits: which rows hold each segment's
    cond and null logits, the guidance scales, the per-row rules. Made once, it serves several draws for the same
    segments (T2M-HiFiGPT's R depth calls of a time step) without redoing that Python work per call.

    The segments are drawn in runs of whole jobs of about DRAW_GROUP segments: the same numbers (each row's
    operations and each job's generator are its own), but a run's float64 arrays stay in the CPU's cache. At a
    GPU's batch sizes that matters: the default model's loop at 1,024 motions spent 1.6x less time on the host, the
    same at 256 and fewer (t2m/bench/host_loop.py, docs/measurements/host_loop.log)."""

    def __init__(self, rows: Rows, going: Sequence[tuple[SamplingJob, Sequence[int]]], draws: int = 1) -> None:
        self.draws, self.drawn = draws, 0
        self.sizes = [len(active) for _, active in going]
        self.segments = [s for _, active in going for s in active]
        self.groups: list[_DrawGroup] = []
        self._ahead: list[np.ndarray | None] = []
        for group, start, stop in _job_groups(going, DRAW_GROUP):
            segments = self.segments[start:stop]
            null = scale = None
            if any(job.guidance != 1.0 for job, _ in group):
                scale = np.array([job.guidance for job, active in group for _ in active])
                null = np.asarray([rows.null.get(s, rows.cond[s]) for s in segments], dtype=np.intp)
            rules = RowRules([RowRule(len(active), job.temperature, job.top_k, job.rng, job.greedy)
                              for job, active in group])
            self.groups.append(_DrawGroup(start, stop, np.asarray([rows.cond[s] for s in segments], dtype=np.intp),
                                          null, scale, rules))

    def draw(self, logits: np.ndarray, forbid: tuple[np.ndarray, int] | None = None) -> np.ndarray:
        """One class per segment, in `segments` order (see draw_for_jobs for `forbid`). A plan of several `draws`
        takes each job's uniforms for all of them at its first draw, one generator call per job instead of one per
        draw: the same numbers, as nothing else draws from the jobs' generators between the plan's draws."""
        if self.drawn == self.draws:
            raise RuntimeError(f"this DrawPlan was made for {self.draws} draw(s)")
        if self.draws > 1 and self.drawn == 0:
            self._ahead = [group.rules.uniforms(self.draws) for group in self.groups]
        drawn = np.zeros(len(self.segments), dtype=np.int64)
        for index, group in enumerate(self.groups):
            if group.stop == group.start:
                continue
            chosen = logits[group.cond].astype(np.float64)
            if group.scale is not None:
                null = logits[group.null].astype(np.float64)
                if group.all_guided:
                    guide_in_place(chosen, null, group.scale[:, None])
                else:
                    chosen = np.where((group.scale != 1.0)[:, None],
                                      guided_logits(chosen, null, group.scale[:, None]), chosen)
            if forbid is not None:
                mask, forbidden = forbid
                chosen[np.asarray(mask, dtype=bool)[group.start:group.stop], forbidden] = -np.inf
            ahead = self._ahead[index] if self.draws > 1 else None
            drawn[group.start:group.stop] = group.rules.draw(chosen, None if ahead is None else ahead[self.drawn],
                                                             owned=True)
        self.drawn += 1
        return drawn

    def split(self, drawn: np.ndarray) -> list[np.ndarray]:
        """`draw`'s classes cut per job, in `going` order."""
        ends = np.cumsum(self.sizes).tolist()
        return [drawn[end - size:end] for size, end in zip(self.sizes, ends)]


def live_segments(batch: StepRows, jobs: Sequence[SamplingJob],
                  cancelled: list[bool]) -> Iterator[tuple[SamplingJob, list[int]]]:
    """Each job with segments still going, and those segments; a job cancelled since the last step is marked in
    `cancelled`, its segments done, and skipped."""
    for j, job in enumerate(jobs):
        active = [s for s in batch.of_job[j] if not batch.segments[s].done]
        if not active:
            continue
        if job.cancelled():
            cancelled[j] = True
            for s in batch.of_job[j]:
                batch.segments[s].done = True
            continue
        yield job, active


def report_progress(batch: StepRows, job: SamplingJob, active: Sequence[int]) -> None:
    """After a step in which `active` (segments of `job`, at least one) were live: hand the job's `progress`, if
    any, every segment's steps so far and whether it is finished."""
    if job.progress is None:
        return
    mine = [batch.segments[s] for s in batch.of_job[batch.segments[active[0]].job]]
    job.progress([segment.tokens for segment in mine], [segment.done for segment in mine])


def drop_finished(batch: StepRows, step: object = None) -> np.ndarray:
    """Remove the rows of finished segments (and their cache, through `step`'s `keep_rows`: see keep_rows);
    returns the kept rows' mask."""
    keep = np.asarray([not batch.segments[s].done for s in batch.owner], dtype=bool)
    if not keep.all():
        batch.owner, batch.cond, batch.length = batch.owner[keep], batch.cond[keep], batch.length[keep]
        batch.past = keep_rows(step, batch.past, keep)
    return keep


def results(batch: StepRows, cancelled: Sequence[bool]) -> list[list[np.ndarray] | None]:
    """Per job its segments' int64 arrays (one entry per step), or None for a cancelled job."""
    return [None if cancelled[j] else [np.asarray(batch.segments[s].tokens, dtype=np.int64) for s in indices]
            for j, indices in enumerate(batch.of_job)]


class Cohort:
    """Jobs that start at one step boundary and step together until each is done (a family's loop: `advance`).

    The step graphs take one `position` for all their rows and a past of one length, so rows share a call only if
    they started together: a cohort is such a group. Rows leave as their segments finish; a job is reported by
    `finished` as soon as all its segments are done (or it was cancelled), not when the whole cohort is. Continuous
    batching (t2m.service) runs several cohorts of different ages side by side, one call each per step boundary; a
    family's `sample_*` function runs one cohort to its end.
    """

    def __init__(self, jobs: Sequence[SamplingJob], max_tokens: int,
                 empty_cache: Callable[[int], Any]) -> None:
        check_targets(jobs, max_tokens)
        self.jobs, self.max_tokens = jobs, max_tokens
        self.batch = start(jobs, empty_cache)
        self.cancelled = [False] * len(jobs)
        self.position = 0                      # the next step's position: steps taken so far
        self._reported = [False] * len(jobs)

    @property
    def rows(self) -> int:
        """Rows (segments x cond/null) still stepping."""
        return len(self.batch.owner)

    @property
    def done(self) -> bool:
        return not len(self.batch.owner)

    def shortest_job_steps(self) -> int:
        """The size of its smallest unfinished job, in steps (its longest segment; a free one counts as max_tokens):
        what a scheduler that runs short requests first compares (t2m.runtime.step_order)."""
        def size(indices: list[int]) -> int:
            targets = (self.batch.segments[s].target for s in indices)
            return max(self.max_tokens if target is None else target for target in targets)

        return min((size(indices) for indices in self.batch.of_job
                    if not all(self.batch.segments[s].done for s in indices)), default=0)

    def advance(self, on_step: Callable[[int], None] | None = None) -> None:
        """One time step for every live row (the family's network calls); `on_step(rows)` after each call."""
        raise NotImplementedError

    @classmethod
    def advance_together(cls, cohorts: Sequence[Cohort], on_step: Callable[[int], None] | None = None) -> None:
        """One time step of each of `cohorts` (of this family), the same as each `advance`d alone; a family whose
        calls rows of different positions can share overrides it (T2M-HiFiGPT's residual GPT)."""
        for cohort in cohorts:
            cohort.advance(on_step)

    def run(self, on_step: Callable[[int], None] | None = None) -> list[list[np.ndarray] | None]:
        """Step to the end; per job its segments' arrays, or None for a job cancelled on the way."""
        while not self.done:
            self.advance(on_step)
        return results(self.batch, self.cancelled)

    def finished(self) -> list[tuple[int, list[np.ndarray] | None]]:
        """Jobs finished since the last call, in job order: (index, its segments' arrays, or None if cancelled)."""
        out = []
        for j, indices in enumerate(self.batch.of_job):
            if self._reported[j] or not all(self.batch.segments[s].done for s in indices):
                continue
            self._reported[j] = True
            out.append((j, None if self.cancelled[j] else
                        [np.asarray(self.batch.segments[s].tokens, dtype=np.int64) for s in indices]))
        return out
