"""What the load benchmarks share, the HTTP ones (benchmarks/load_test.py, step_order.py) and the in-process one
(`t2m bench scheduler`): the sentences they send, the kinds of request of the step-order phases, one phase's
answers (PhaseResult) and the step-order table."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

SENTENCES = [
    "a person walks forward",
    "a person jumps up and down",
    "a person waves with the right hand",
    "a person turns around",
    "a person runs in a circle",
    "a person sits down",
    "a person kicks with the left leg",
    "a person raises both arms",
]
MODES = {"before": "every-cohort", "after": "shortest-first"}    # label -> T2M_STEP_ORDER
KINDS = {"short": (2.0, 1), "long": (30.0, 3), "ten": (10.0, 1)}   # kind -> (motion seconds, sentences)


@dataclass
class PhaseResult:
    name: str
    clients: int
    seconds: float
    latencies_ms: list[float] = field(default_factory=list)  # of 2xx answers
    status_2xx: int = 0
    status_4xx: int = 0  # other than 429
    status_429: int = 0
    status_5xx: int = 0
    connection_errors: int = 0
    error_samples: list[str] = field(default_factory=list)

    @classmethod
    def pooled(cls, name: str, clients: int, phases: list[PhaseResult]) -> PhaseResult:
        """One result from several phases' answers (their seconds added): rounds of a benchmark, or its chunks."""
        pooled = cls(name=name, clients=clients, seconds=sum(p.seconds for p in phases))
        for phase in phases:
            pooled.latencies_ms += phase.latencies_ms
            pooled.status_2xx += phase.status_2xx
            pooled.status_4xx += phase.status_4xx
            pooled.status_429 += phase.status_429
            pooled.status_5xx += phase.status_5xx
            pooled.connection_errors += phase.connection_errors
            pooled.error_samples += phase.error_samples
        return pooled

    @property
    def requests(self) -> int:
        return self.status_2xx + self.status_4xx + self.status_429 + self.status_5xx + self.connection_errors

    def percentile(self, q: float) -> float | None:
        return float(np.percentile(self.latencies_ms, q)) if self.latencies_ms else None

    def summary(self) -> dict:
        return {
            "phase": self.name, "clients": self.clients, "seconds": round(self.seconds, 2),
            "requests": self.requests, "ok_per_s": round(self.status_2xx / self.seconds, 3) if self.seconds else 0.0,
            "p50_ms": self.percentile(50), "p95_ms": self.percentile(95), "p99_ms": self.percentile(99),
            "2xx": self.status_2xx, "4xx": self.status_4xx, "429": self.status_429, "5xx": self.status_5xx,
            "connection_errors": self.connection_errors, "error_samples": self.error_samples[:5],
        }


def _ms(value: float | None) -> str:
    return "-" if value is None else f"{value:.0f}"


def format_table(pooled: dict[tuple[str, str, str], PhaseResult], orders: dict[str, str] | None = None) -> str:
    """One row per server (`orders`: label -> its step order, MODES by default): the probe alone and under load, the
    long load alone and beside the probe, sixteen."""
    def get(mode: str, phase: str, kind: str) -> PhaseResult | None:
        return pooled.get((mode, phase, kind))

    lines = ["| step order | short p50 / p90 alone ms | short p50 / p90 under load ms | p90 ratio | long answers/s "
             "alone | long answers/s beside the probe | long p50 ms beside it | 16 clients answers/s | 16 clients "
             "p50 / p99 ms | non-2xx |", "| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |"]
    for mode, order in (orders or MODES).items():
        alone, loaded = get(mode, "short alone", "short"), get(mode, "mixed", "short")
        long_alone, long_mixed = get(mode, "long alone", "long"), get(mode, "mixed", "long")
        sixteen = get(mode, "sixteen", "ten")
        ratio = "-"
        if alone and loaded and alone.percentile(90) and loaded.percentile(90):
            ratio = f"{loaded.percentile(90) / alone.percentile(90):.2f}"   # type: ignore[operator]
        errors = sum(r.summary()[key] for (m, _, _), r in pooled.items() if m == mode
                     for key in ("4xx", "429", "5xx", "connection_errors"))

        def pair(result: PhaseResult | None, low: float, high: float) -> str:
            return "-" if result is None else f"{_ms(result.percentile(low))} / {_ms(result.percentile(high))}"

        def rate(result: PhaseResult | None) -> str:
            return "-" if result is None else f"{result.summary()['ok_per_s']:.2f}"

        long_p50 = _ms(long_mixed.percentile(50) if long_mixed else None)
        lines.append(f"| {mode} ({order}) | {pair(alone, 50, 90)} | {pair(loaded, 50, 90)} | {ratio} | "
                     f"{rate(long_alone)} | {rate(long_mixed)} | {long_p50} | {rate(sixteen)} | "
                     f"{pair(sixteen, 50, 99)} | {errors} |")
    return "\n".join(lines)
