"""Which running cohorts step at a step boundary: the shortest work first, with a bound on how long others wait.

On a CPU a step's cost grows with its rows, and every cohort is its own graph call: when every cohort steps at every
boundary (`EveryCohort`, the order before shortest-first), a 2 s request that joins three 30 s ones pays for all their
rows at each of its few steps, and its latency grows with the load beside it. Requests arrive with known sizes (their
durations), so a boundary can run the short requests first (`ShortestFirst`): a cohort steps when its smallest
request is at most `ratio` times the size (in steps) of the smallest one anywhere, or when it has been passed over
`max_skips` boundaries in a row. So a short request runs almost as if alone, requests of similar sizes keep stepping
together as before (16 clients asking for 10 s each: every cohort steps every time), and a long one is never held
more than `max_skips` boundaries out of `max_skips + 1` (and only while something much shorter runs): what it loses
is bounded by the short work's share of the machine. Sizes, not steps left: a long request near its end is not
preferred to one that just arrived with the same size, so the oldest do not starve the youngest. No order changes a
motion: each request's codes come from its own generator and its own rows (t2m.runtime.continuous).
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal, Protocol

__all__ = ["STEP_ORDERS", "EveryCohort", "ShortestFirst", "StepOrder", "step_order"]

STEP_ORDERS = ("shortest-first", "every-cohort")
StepOrderName = Literal["shortest-first", "every-cohort"]


class StepOrder(Protocol):
    """Chooses the cohorts that step at a boundary. `ratio`: how much smaller (in steps) a waiting request must be
    than a running cohort for the boundary to end before that cohort; None: nothing waits for smaller work."""

    @property
    def ratio(self) -> float | None: ...

    def choose(self, sizes: Sequence[int], skipped: Sequence[int]) -> list[bool]:
        """Per cohort (oldest first): whether it steps now, given the size in steps of its smallest unfinished
        request and how many boundaries in a row it has been passed over. At least one steps when any runs."""
        ...

    def must_step(self, skipped: int) -> bool:
        """Whether a cohort passed over `skipped` times in a row must step now, whatever waits to join."""
        ...


@dataclass(frozen=True)
class EveryCohort:
    """Every cohort at every boundary (round robin over the cohorts' calls)."""

    ratio: float | None = None

    def choose(self, sizes: Sequence[int], skipped: Sequence[int]) -> list[bool]:
        return [True] * len(sizes)

    def must_step(self, skipped: int) -> bool:
        return True


@dataclass(frozen=True)
class ShortestFirst:
    """The cohort holding the smallest request steps, with those whose smallest is within `ratio` of it and those
    passed over `max_skips` times in a row."""

    ratio: float = 2.0
    max_skips: int = 3

    def __post_init__(self) -> None:
        if self.ratio < 1.0:
            raise ValueError(f"ratio must be >= 1, got {self.ratio}")
        if self.max_skips < 0:
            raise ValueError(f"max_skips must be >= 0, got {self.max_skips}")

    def choose(self, sizes: Sequence[int], skipped: Sequence[int]) -> list[bool]:
        if not sizes:
            return []
        smallest = min(sizes)
        return [size <= self.ratio * smallest or self.must_step(passed) for size, passed in zip(sizes, skipped)]

    def must_step(self, skipped: int) -> bool:
        return skipped >= self.max_skips


def step_order(name: StepOrderName | str, max_skips: int = 3) -> StepOrder:
    """The order a setting names (`T2M_STEP_ORDER`, `T2M_MAX_STEP_SKIPS`)."""
    if name == "shortest-first":
        return ShortestFirst(max_skips=max_skips)
    if name == "every-cohort":
        return EveryCohort()
    raise ValueError(f"unknown step order {name!r}; expected one of {', '.join(STEP_ORDERS)}")
