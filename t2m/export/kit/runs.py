"""Training runs as exporters read them: a run's record, the statistics its VQ was trained with, and the training data
(name, licence, attribution) a bundle must carry."""
from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["normalisation", "run_record", "run_training_data", "training_data_entry"]


def run_record(run_dir: Path) -> dict[str, Any]:
    from t2m.model.training.checkpoint import read_run_config

    return read_run_config(run_dir)


def normalisation(vq_run: Path, record: dict[str, Any]) -> tuple[np.ndarray, np.ndarray]:
    """mean/std the VQ was trained with: the run's mean.npy/std.npy, else the data directory's Mean.npy/Std.npy."""
    candidates = [(vq_run / "mean.npy", vq_run / "std.npy")]
    data_dir = record.get("data", {}).get("data_dir")
    if data_dir:
        candidates.append((Path(data_dir) / "Mean.npy", Path(data_dir) / "Std.npy"))
    for mean_path, std_path in candidates:
        if mean_path.is_file() and std_path.is_file():
            return np.load(mean_path).astype(np.float32), np.load(std_path).astype(np.float32)
    raise FileNotFoundError(str(candidates[0][0]))


def training_data_entry(summary_path: Path) -> dict[str, str]:
    """{name, license, attribution} from a dataset's summary.json (written by `t2m data build`)."""
    if not summary_path.is_file():
        raise FileNotFoundError(str(summary_path))
    try:
        summary = json.loads(summary_path.read_text(encoding="utf-8"))
    except json.JSONDecodeError as error:
        raise ValueError(f"{summary_path}: not valid JSON ({error})") from error
    for key in ("name", "license"):
        if not isinstance(summary.get(key), str) or not summary[key]:
            raise ValueError(
                f"{summary_path}: field '{key}' is missing; the bundle must state the training data licence")
    attribution = summary.get("attribution", "")
    if summary.get("captions"):
        attribution = f"{attribution} Captions: {summary['captions']}.".strip()
    for source in summary.get("sources") or []:     # a merged dataset (t2m data merge): every source's terms
        part = f"{source.get('name', source.get('prefix', '?'))} ({source.get('license', 'licence not stated')}): " \
               f"{source.get('attribution', '')}".strip()
        attribution = f"{attribution} {part}".strip()
    return {"name": summary["name"], "license": summary["license"], "attribution": attribution}


def run_training_data(run: Path, run_data: Mapping[str, Any], vq_record: Mapping[str, Any],
                      data_summary: str | Path | None) -> dict[str, str]:
    """The manifest's training_data for a model run: from --data-summary, else the summary.json of the data directory
    the run (or its VQ run) recorded."""
    if data_summary is None:
        data_dir = run_data.get("data_dir") or vq_record.get("data", {}).get("data_dir")
        if not data_dir:
            raise ValueError(f"{run}/config.json records no data_dir; pass --data-summary DATA/summary.json")
        data_summary = Path(data_dir) / "summary.json"
    return training_data_entry(Path(data_summary))
