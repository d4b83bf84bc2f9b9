"""`t2m bench --bundle`: every family timed in one run through the service's engine (figures printed, never
asserted), and a bad --bundle is one line."""
from __future__ import annotations

from pathlib import Path

import pytest

from t2m.bench.bundles import CASES, run_bundle_bench
from t2m.cli.main import main as t2m
from t2m.families.gpt.random_bundle import build_random_bundle
from t2m.families.hifigpt.random_bundle import build_random_hifigpt_bundle
from t2m.families.masked.random_bundle import build_random_masked_bundle


@pytest.fixture(scope="module")
def three_families(tmp_path_factory) -> list[Path]:
    root = tmp_path_factory.mktemp("bench")
    return [build_random_bundle(root / "gpt"), build_random_masked_bundle(root / "masked"),
            build_random_hifigpt_bundle(root / "hifigpt")]


def test_every_family_and_both_requests_in_one_table(three_families):
    lines: list[str] = []
    results = run_bundle_bench(three_families, repeats=1, threads=1, echo=lines.append)
    assert len(results) == 3
    rows = [line for line in lines if line.startswith("| ") and "---" not in line][1:]
    assert len(rows) == 3 * len(CASES)
    for family in ("gpt:", "masked:", "hifigpt: 1 temporal + 3 residual steps per 8 frames"):
        assert any(family in row for row in rows), family
    for times in (t for model in results.values() for t in model.values()):
        assert min(times.text, times.codes, times.decode) > 0
        assert times.total == pytest.approx(times.text + times.codes + times.decode) and times.cpu > 0
    assert any(line.startswith("- CPU:") for line in lines) and not any("torch" in line for line in lines)


def test_the_stream_case_really_has_three_sentences_of_ten_seconds():
    stream = CASES["10 s, 3-sentence stream"]
    assert len(stream) == 3 and sum(duration for _, duration in stream) == 10.0


def test_a_model_with_shorter_segments_gets_its_longest(tmp_path):
    """MoMask's and MoGenTS's releases make at most 49 rows (9.8 s) per segment: the 10 s case runs at 9.8 s there
    (instead of being refused), the stream's 3 + 3 + 4 s fit as they are."""
    bundle = build_random_masked_bundle(tmp_path / "short", max_tokens=49, length_estimator=False)
    lines: list[str] = []
    (times,) = run_bundle_bench([bundle], repeats=1, threads=1, echo=lines.append).values()
    assert times["10 s, 1 sentence"].seconds == 9.8 and times["10 s, 3-sentence stream"].seconds == 10.0
    assert any("| 10 s, 1 sentence | 9.8 |" in line for line in lines)


def test_a_directory_without_a_bundle_is_one_line(tmp_path, capsys):
    assert t2m(["bench", "--bundle", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "manifest.json" in err and str(tmp_path) in err
