"""t2m/bench/scheduler.py: a phase runs on the service's batcher in this process and records every answer;
a --before-code that is no checkout of this repository is refused in one line before anything runs."""
from __future__ import annotations

import pytest

from benchmarks.load_test import SENTENCES
from benchmarks.step_order import KINDS
from t2m.bench.scheduler import main, run_phase_here


def test_a_mixed_phase_records_the_probe_and_the_long_requests():
    figures = run_phase_here("t2m/bundles/default", "mixed", seconds=1.0, long_clients=1, clients=1, interval_s=0.2,
                             seed=0, kinds=KINDS, sentences=SENTENCES)
    assert set(figures) == {"short", "long"}
    assert len(figures["short"]["latencies_ms"]) >= 5 and len(figures["long"]["latencies_ms"]) >= 1
    assert all(ms > 0 for kind in figures.values() for ms in kind["latencies_ms"])


def test_a_folder_that_is_no_checkout_is_refused(tmp_path, capsys):
    with pytest.raises(SystemExit) as stopped:
        main(["--before-code", str(tmp_path)])
    assert stopped.value.code == 2 and "not a checkout of this repository" in capsys.readouterr().err
