"""`t2m eval --hifigpt` end to end: a residual VQ at 8 frames per code and a double-tier GPT trained for 3 steps on
the tiny dataset, evaluated with the same command and evaluator as the other families: crops are multiples of 8
frames, generation goes through the shared loop (t2m.families.hifigpt.loop), streams concatenate the code maps."""
from __future__ import annotations

import json
import math
from pathlib import Path

import pytest
import torch

from t2m.cli.main import main
from tests.model.synthetic_motion_data import make_dataset
from tests.model.test_evaluation import HashTextEncoder

TRAIN = ["--steps", "3", "--batch-size", "4", "--log-every", "1", "--val-every", "3", "--save-every", "3",
         "--threads", "1"]


@pytest.fixture(autouse=True)
def fast_text(monkeypatch):
    torch.set_num_threads(1)
    monkeypatch.setattr("t2m.model.networks.text_encoders.get_text_encoder", lambda name, **kw: HashTextEncoder())


@pytest.fixture
def runs(tmp_path) -> dict[str, Path]:
    from t2m.model.networks.evaluator import EvaluatorConfig, MotionEvaluator
    from t2m.model.training.checkpoint import save_checkpoint

    data = make_dataset(tmp_path / "data", train_clips=8, val_clips=3)
    ids = [line for split in ("train", "val", "test") for line in (data / f"{split}.txt").read_text().split()]
    (data / "test.txt").write_text("\n".join(ids) + "\n")
    runs = {"data": data, **{name: tmp_path / name for name in ("vq", "hifigpt", "evaluator")}}
    torch.manual_seed(0)
    save_checkpoint(runs["evaluator"], MotionEvaluator(EvaluatorConfig(width=16, n_layer=1, n_head=2, embed_dim=8)), 0)
    assert main(["train", "vq", "--data", str(data), "--out", str(runs["vq"]), "--width", "16", "--code-dim", "8",
                 "--nb-code", "16", "--down-t", "3", "--window", "32", "--quantizer", "residual",
                 "--residual-layers", "2", "--shared-codebook", *TRAIN]) == 0
    assert main(["train", "hifigpt", "--data", str(data), "--vq", str(runs["vq"]), "--out", str(runs["hifigpt"]),
                 "--embed", "16", "--heads", "2", "--temporal-layers", "1", "--residual-gpt-layers", "1",
                 "--max-tokens", "12", "--text-cache", str(tmp_path / "text.npz"), *TRAIN]) == 0
    return runs


def test_hifigpt_eval_writes_every_row_through_the_shared_loop(runs, tmp_path, monkeypatch):
    import t2m.families.hifigpt.sampling as sampling

    calls: list[list[int | None]] = []
    real = sampling.sample_code_rows

    def counted(temporal, residual, jobs, max_tokens, on_step=None):
        calls.append([t for job in jobs for t in job.targets])
        return real(temporal, residual, jobs, max_tokens, on_step)

    monkeypatch.setattr(sampling, "sample_code_rows", counted)
    out = tmp_path / "report.md"
    assert main(["eval", "--data", str(runs["data"]), "--evaluator", str(runs["evaluator"]), "--vq", str(runs["vq"]),
                 "--hifigpt", str(runs["hifigpt"]), "--limit", "10", "--repeats", "2", "--mm-texts", "3",
                 "--mm-repeats", "2", "--out", str(out), "--quiet"]) == 0
    report = out.read_text()
    for row in ("Real motion", "VQ reconstruction", "Generation (guidance=1)", "Generation (guidance=3)",
                "Streams (guidance=3)", "Real crops' VQ codes, decoded once"):
        assert f"| {row} |" in report, row
    assert "nan" not in report.lower()
    result = json.loads(out.with_suffix(".json").read_text())
    assert result["family"] == "hifigpt" and set(result["models"]) == {"evaluator", "vq", "hifigpt"}
    assert result["counts"]["max_frames"] == 8 * 12          # the GPT's 12 steps of 8 frames
    for values in result["summary"].values():
        for mean, half in values.values():
            assert math.isfinite(mean) and math.isfinite(half)
    assert calls and all(t is not None and 1 <= t <= 12 for targets in calls for t in targets)


def test_eval_refuses_two_token_runs_and_masked_options(runs, capsys):
    base = ["eval", "--data", str(runs["data"]), "--evaluator", str(runs["evaluator"]), "--vq", str(runs["vq"])]
    assert main([*base, "--hifigpt", str(runs["hifigpt"]), "--gpt", str(runs["hifigpt"])]) == 2
    assert "give exactly one of --gpt RUN" in capsys.readouterr().err
    assert main([*base, "--hifigpt", str(runs["hifigpt"]), "--steps", "3"]) == 2
    assert "--steps applies to the masked family (--masked), not to --hifigpt" in capsys.readouterr().err
