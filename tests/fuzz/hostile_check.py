"""Sends the hostile-input corpus (hostile_corpus.py) to a server on 127.0.0.1 and judges every answer.

Every case: an answer (unless the case's client gave up first) with a status below 500; an error answer's body is
JSON in UTF-8 with a `detail`, read strictly (an escaped lone surrogate, which json.loads lets through, counts as
broken); the case's allowed statuses; the field it names, if it has one. `run_corpus` returns a `Report` whose
`summary()` is the line the tests print.
"""
from __future__ import annotations

import json
from collections import Counter
from collections.abc import Iterator, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

from tests.fuzz.hostile_corpus import Case
from tests.raw_http import RawAnswer, exchange, split

__all__ = ["Outcome", "Report", "judge", "run_corpus", "strict_json"]

WAIT_S = 15.0   # an answer must come within this (the timed cases get their 408 after the server's deadlines)


@dataclass
class Outcome:
    case: Case
    answer: RawAnswer
    problems: list[str] = field(default_factory=list)


@dataclass
class Report:
    outcomes: list[Outcome]

    @property
    def failures(self) -> list[Outcome]:
        return [outcome for outcome in self.outcomes if outcome.problems]

    @property
    def server_errors(self) -> list[Outcome]:
        return [o for o in self.outcomes if o.answer.status is not None and o.answer.status >= 500]

    def summary(self) -> str:
        statuses = Counter(str(o.answer.status) if o.answer.status is not None else "none" for o in self.outcomes)
        counts = ", ".join(f"{status} x{count}" for status, count in sorted(statuses.items()))
        lines = [f"hostile corpus: {len(self.outcomes)} cases, {len(self.server_errors)} answers >= 500, "
                 f"{len(self.failures)} cases failing their checks (statuses: {counts})"]
        lines += [f"  FAIL {o.case.name}: {'; '.join(o.problems)}" for o in self.failures]
        return "\n".join(lines)


def strict_json(body: bytes) -> object:
    """`body` as JSON read strictly: UTF-8, and every string (keys too) encodable as UTF-8 again."""
    value = json.loads(body.decode("utf-8"))
    for text in _strings(value):
        text.encode("utf-8")
    return value


def _strings(value: object) -> Iterator[str]:
    if isinstance(value, str):
        yield value
    elif isinstance(value, dict):
        for key, item in value.items():
            yield key
            yield from _strings(item)
    elif isinstance(value, list):
        for item in value:
            yield from _strings(item)


def _named_fields(detail: object) -> set[str]:
    """The fields a 422's detail names: each loc without its leading "body", joined with dots; "body" for the body
    as a whole (an empty rest, or a JSON syntax error's character position)."""
    if not isinstance(detail, list):
        return set()
    locs = [error.get("loc", []) for error in detail if isinstance(error, dict)]
    return {"body" if not loc[1:] or isinstance(loc[1], int) else ".".join(str(part) for part in loc[1:])
            for loc in locs if isinstance(loc, list)}


def judge(case: Case, answer: RawAnswer) -> list[str]:
    """What is wrong with `answer` to `case` (nothing: an empty list)."""
    status = answer.status
    if status is None:
        return [] if case.answer_optional else ["no answer"]
    problems = []
    if status >= 500:
        problems.append(f"status {status}")
    if case.status and status not in case.status:
        problems.append(f"status {status}, expected one of {case.status}")
    is_json = answer.headers.get("content-type", "").startswith("application/json")
    if status >= 400 or is_json:
        try:
            value = strict_json(answer.body)
        except (UnicodeError, ValueError) as error:
            return [*problems, f"body is not UTF-8 JSON ({type(error).__name__}: {error}): {answer.body[:120]!r}"]
        if status >= 400 and not (isinstance(value, dict) and "detail" in value):
            problems.append(f"error body without a detail: {answer.body[:120]!r}")
        if case.field is not None:
            named = _named_fields(value.get("detail") if isinstance(value, dict) else None)
            if case.field not in named:
                problems.append(f"does not name {case.field!r} (names {sorted(named)})")
    return problems


def send(port: int, case: Case) -> RawAnswer:
    """The case's bytes to the server as the case says (at once, or dribbled), and the answer."""
    head, rest = case.wire[:case.dribble_from], case.wire[case.dribble_from:]
    pieces = ([head] if head else []) + (split(rest, case.pieces) if rest else [b""])
    return exchange(port, pieces, gap_s=case.gap_s, wait_s=WAIT_S, half_close=case.half_close)


def run_corpus(port: int, cases: Sequence[Case], workers: int = 8) -> Report:
    """Every case against 127.0.0.1:`port`, `workers` at a time (the timed ones wait out the server's deadlines)."""
    def one(case: Case) -> Outcome:
        answer = send(port, case)
        return Outcome(case, answer, judge(case, answer))

    with ThreadPoolExecutor(workers) as pool:
        return Report(list(pool.map(one, cases)))
