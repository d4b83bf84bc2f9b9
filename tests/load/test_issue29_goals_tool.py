"""benchmarks/issue29_goals.py reads issue 29's CPU goals off step_order.py's and released_models_speed.py's JSON:
checked on made-up figures whose verdicts are known, both ways, and on figures that lack a phase."""
from __future__ import annotations

import json

import pytest

from benchmarks.issue29_goals import main


def _phase(server: str, phase: str, kind: str, p90: float, per_s: float = 1.0, p99: float = 0.0) -> dict:
    return {"server": server, "phase": phase, "kind": kind, "p90_ms": p90, "ok_per_s": per_s, "p99_ms": p99}


def _scheduling(after_loaded_p90: float, after_long: float, sixteen: tuple[float, float]) -> dict:
    return {"results": [
        _phase("before", "short alone", "short", 40), _phase("before", "mixed", "short", 226),
        _phase("before", "mixed", "long", 0, per_s=6.0), _phase("before", "sixteen", "ten", 0, 18.5, 1226),
        _phase("after", "short alone", "short", 50), _phase("after", "mixed", "short", after_loaded_p90),
        _phase("after", "mixed", "long", 0, per_s=after_long),
        _phase("after", "sixteen", "ten", 0, per_s=sixteen[0], p99=sixteen[1])]}


def _released(mogents_int8_ms: float) -> dict:
    def case(total: float) -> dict:
        return {"10 s, 1 sentence": {"text": 1.0, "codes": total - 2, "decode": 1.0, "seconds": 9.8, "cpu": total,
                                     "total": total}}

    return {"1": {"t2m-gpt float32": case(2000), "t2m-gpt int8": case(1000), "t2m-gpt int4": case(500),
                  "mogents float32": case(8000), "mogents int8": case(mogents_int8_ms)},
            "2": {"t2m-gpt float32": case(1000), "t2m-gpt int8": case(400),
                  "mogents float32": case(4000), "mogents int8": case(mogents_int8_ms / 2)}}


def _run(tmp_path, capsys, scheduling: dict, released: dict) -> str:
    (tmp_path / "s.json").write_text(json.dumps(scheduling))
    (tmp_path / "r.json").write_text(json.dumps(released))
    assert main(["--scheduling", str(tmp_path / "s.json"), "--released", str(tmp_path / "r.json")]) == 0
    return capsys.readouterr().out


def _row(out: str, start: str) -> str:
    return next(line for line in out.splitlines() if line.startswith(f"| {start}"))


def test_goals_met(tmp_path, capsys):
    out = _run(tmp_path, capsys, _scheduling(100, 5.5, (61, 450)), _released(1800))
    assert _row(out, "2 s requests").endswith("| 2.00 | 5.65 | met |")
    assert "(-8%)" in _row(out, "30 s requests") and _row(out, "30 s requests").endswith("| met |")
    assert _row(out, "16 clients").endswith("| met |")
    assert "| 900 ms (int8, 2 thread(s)) |" in _row(out, "MoGenTS's 10 s motion")
    assert _row(out, "MoGenTS's 10 s motion").endswith("| met |")
    assert "| int8 2.0x, int4 4.0x |" in _row(out, "T2M-GPT import, --quantize vs float32 (1 thread(s)")
    assert "| int8 2.5x |" in _row(out, "T2M-GPT import, --quantize vs float32 (2 thread(s)")


def test_goals_not_met(tmp_path, capsys):
    out = _run(tmp_path, capsys, _scheduling(101, 4.7, (61, 500)), _released(2400))   # MoGenTS 1.2 s at best
    for start in ("2 s requests", "30 s requests", "16 clients", "MoGenTS's"):
        assert _row(out, start).endswith("| not met |"), start


def test_a_missing_phase_is_named(tmp_path, capsys):
    scheduling = _scheduling(100, 5.5, (61, 450))
    scheduling["results"] = [row for row in scheduling["results"] if row["phase"] != "sixteen"]
    with pytest.raises(SystemExit, match="no 'sixteen' 'ten' phase for the 'before' server"):
        _run(tmp_path, capsys, scheduling, _released(900))


def test_unreadable_figures_are_one_line(tmp_path, capsys):
    (tmp_path / "s.json").write_text("{")
    with pytest.raises(SystemExit) as stop:
        main(["--scheduling", str(tmp_path / "s.json"), "--released", str(tmp_path / "missing.json")])
    assert stop.value.code == 2
    assert "cannot read the figures" in capsys.readouterr().err


def test_step_order_figures_keep_the_phase_the_goals_read():
    """step_order.py's --json-out names each row by its phase ('short alone', 'mixed'), not by the request kind the
    phase's own summary carries (a bug once: every row said 'short' or 'long', and the goals could not be read)."""
    from benchmarks.issue29_goals import _phase
    from benchmarks.load_test import PhaseResult
    from benchmarks.step_order import phase_figures

    alone = PhaseResult(name="short", clients=1, seconds=1.0, latencies_ms=[40.0] * 10, status_2xx=10)
    loaded = PhaseResult(name="short", clients=1, seconds=1.0, latencies_ms=[80.0] * 10, status_2xx=10)
    figures = phase_figures({("after", "short alone", "short"): alone, ("after", "mixed", "short"): loaded})
    assert _phase(figures, "after", "mixed", "short")["p90_ms"] == 80.0
    assert _phase(figures, "after", "short alone", "short")["p90_ms"] == 40.0
