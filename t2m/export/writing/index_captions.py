"""`t2m index-captions`: give a bundle the index of its training captions and a calibrated "unknown text" threshold.

A model trained on ~27 templated actions answers "a person jumps" with a walk and HTTP 200. With this index the
service warns instead: it compares each sentence's text feature with every training caption and warns when the best
cosine similarity is below the threshold. The features come from the bundle's own text graph through the service's
own text path, so the index compares exactly what the service will compute.

The threshold is chosen on hand-written phrasings of known and unknown actions ("calibration" set: the midpoint that
minimises the mean of the false-warning and missed-warning rates) and reported on a held-out "evaluation" set.
"""
from __future__ import annotations

import json
import logging
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

from t2m.bundle import CAPTION_INDEX_FILE, CaptionIndex, read_manifest
from t2m.export.writing.bundle import write_bundle
from t2m.runtime.text import TextEncoder, load_tokenizer

__all__ = [
    "DEFAULT_PHRASINGS",
    "Rates",
    "add_caption_index",
    "choose_threshold",
    "encode_with_bundle",
    "rates",
    "training_captions",
]

log = logging.getLogger(__name__)
DEFAULT_PHRASINGS = Path(__file__).resolve().parent / "phrasings" / "bandai_known_unknown.json"
CARD_START, CARD_END = "<!-- caption-index -->", "<!-- /caption-index -->"


def training_captions(data_dir: Path, split: str = "train") -> list[str]:
    """The unique captions of a dataset split (HumanML3D layout), sorted."""
    from t2m.model.data.motion_data import MotionDirectory

    reader = MotionDirectory(data_dir, split)
    return sorted({caption for item in reader.ids for caption in reader.captions(item)})


def encode_with_bundle(bundle_dir: Path, texts: list[str], batch: int = 256, progress: bool = True) -> np.ndarray:
    """Text features of `texts` as the service computes them (the bundle's tokenizer + text graph; a token-state
    graph's real tokens averaged, as the diffusion family's requests pool them)."""
    import onnxruntime as ort

    from t2m.runtime.text import encode_token_states, pooled_token_states

    manifest = read_manifest(bundle_dir)
    session = ort.InferenceSession(str(bundle_dir / "text_encoder.onnx"), providers=["CPUExecutionProvider"])
    encoder = TextEncoder(session, load_tokenizer(bundle_dir / "tokenizer.json", manifest.text_max_length))
    tokens = "token_states" in {output.name for output in session.get_outputs()}

    def encode(chunk: list[str]) -> np.ndarray:
        return pooled_token_states(encode_token_states(encoder, chunk)[0]) if tokens else encoder.encode(chunk)

    starts = range(0, len(texts), batch)
    return np.concatenate([encode(texts[s:s + batch])
                           for s in tqdm(starts, desc="caption features", unit="batch", disable=not progress)])


@dataclass(frozen=True)
class Rates:
    """How the warning does on one labelled set at one threshold."""

    known: int
    unknown: int
    false_warnings: int          # known sentences warned about
    missed_warnings: int         # unknown sentences not warned about

    @property
    def false_warning_rate(self) -> float:
        return self.false_warnings / max(self.known, 1)

    @property
    def missed_warning_rate(self) -> float:
        return self.missed_warnings / max(self.unknown, 1)


def rates(known: np.ndarray, unknown: np.ndarray, threshold: float) -> Rates:
    """A sentence is warned about when its best similarity is below `threshold`."""
    return Rates(len(known), len(unknown), int((known < threshold).sum()), int((unknown >= threshold).sum()))


def choose_threshold(known: np.ndarray, unknown: np.ndarray) -> float:
    """The midpoint between adjacent scores that minimises the mean of the two error rates (ties: the lower one,
    fewer false warnings)."""
    scores = np.unique(np.concatenate([known, unknown]))
    candidates = np.concatenate([[scores[0] - 1e-3], (scores[1:] + scores[:-1]) / 2, [scores[-1] + 1e-3]])
    errors = [(rates(known, unknown, t).false_warning_rate + rates(known, unknown, t).missed_warning_rate) / 2
              for t in candidates]
    return float(candidates[int(np.argmin(errors))])


def _best_similarities(index: CaptionIndex, features: np.ndarray) -> np.ndarray:
    return np.asarray([row[0].similarity for row in index.nearest(features, k=1)])


def _card_section(threshold: float, count: int, report: dict[str, Any]) -> str:
    lines = [CARD_START, "## Unknown sentences", "",
             f"The bundle carries the text features of its {count} unique training captions ({CAPTION_INDEX_FILE}). "
             "The service warns (or, with `T2M_UNKNOWN_TEXT=reject`, refuses with a 422) when a sentence's best "
             f"cosine similarity to them is below **{threshold:.3f}**, naming the nearest captions. The threshold was "
             "chosen on hand-written phrasings of known and unknown actions (calibration set) and checked on a "
             f"held-out set ({report['phrasings']}):", "",
             "| set | known | unknown | false warnings (known warned) | missed warnings (unknown not warned) |",
             "| --- | ---: | ---: | ---: | ---: |"]
    for name in ("calibration", "evaluation"):
        r = report[name]
        lines.append(f"| {name} | {r['known']} | {r['unknown']} | {r['false_warnings']} "
                     f"({r['false_warning_rate']:.2f}) | {r['missed_warnings']} ({r['missed_warning_rate']:.2f}) |")
    missed = ", ".join(repr(s) for s in report["evaluation"]["missed"]) or "none"
    falsely_warned = ", ".join(repr(s) for s in report["evaluation"]["false"]) or "none"
    lines += ["", f"Missed on the evaluation set: {missed}. Falsely warned: {falsely_warned}.",
              "A similarity is a property of the text encoder, not of the motion: a sentence near a caption can still "
              "be generated badly (see the probes), and the index says nothing about style words.", CARD_END]
    return "\n".join(lines)


def _with_card_section(card: str, section: str) -> str:
    if CARD_START in card and CARD_END in card:
        before, rest = card.split(CARD_START, 1)
        return before + section + rest.split(CARD_END, 1)[1]
    return card.rstrip() + "\n\n" + section + "\n"


def add_caption_index(bundle_dir: str | Path, data_dir: str | Path, phrasings: str | Path = DEFAULT_PHRASINGS,
                      split: str = "train", progress: bool = True) -> dict[str, Any]:
    """Write caption_index.npz + the manifest's caption_index (with the calibrated threshold) + the card's section,
    re-hash and verify the bundle; returns the calibration report."""
    bundle_dir, data_dir = Path(bundle_dir), Path(data_dir)
    try:
        sets = json.loads(Path(phrasings).read_text(encoding="utf-8"))
        labelled = {name: (list(sets[name]["known"]), list(sets[name]["unknown"]))
                    for name in ("calibration", "evaluation")}
    except (OSError, json.JSONDecodeError, KeyError, TypeError) as error:
        raise ValueError(f"{phrasings}: expected JSON {{calibration|evaluation: {{known: [...], unknown: [...]}}}} "
                         f"({error})") from None
    captions = training_captions(data_dir, split)
    if not captions:
        raise ValueError(f"{data_dir}: the {split} split has no captions")
    index = CaptionIndex.build(captions, encode_with_bundle(bundle_dir, captions, progress=progress))
    scores = {name: tuple(_best_similarities(index, encode_with_bundle(bundle_dir, texts, progress=False))
                          for texts in pair) for name, pair in labelled.items()}
    threshold = round(choose_threshold(*scores["calibration"]), 4)   # what the manifest stores
    report: dict[str, Any] = {"phrasings": Path(phrasings).name, "split": split, "threshold": threshold}
    for name, (known, unknown) in scores.items():
        texts_known, texts_unknown = labelled[name]
        report[name] = {**asdict(rates(known, unknown, threshold)),
                        "false_warning_rate": rates(known, unknown, threshold).false_warning_rate,
                        "missed_warning_rate": rates(known, unknown, threshold).missed_warning_rate,
                        "false": [t for t, s in zip(texts_known, known) if s < threshold],
                        "missed": [t for t, s in zip(texts_unknown, unknown) if s >= threshold],
                        "known_similarity": [round(float(s), 4) for s in known],
                        "unknown_similarity": [round(float(s), 4) for s in unknown]}
    index.save(bundle_dir / CAPTION_INDEX_FILE)
    manifest = dict(read_manifest(bundle_dir).raw)
    manifest["caption_index"] = {
        "file": CAPTION_INDEX_FILE, "count": len(captions), "threshold": threshold,
        "calibration": {name: {key: report[name][key] for key in ("known", "unknown", "false_warnings",
                                                                  "missed_warnings")}
                        for name in ("calibration", "evaluation")}}
    card = bundle_dir / "MODEL_CARD.md"
    card.write_text(_with_card_section(card.read_text(encoding="utf-8"),
                                       _card_section(threshold, len(captions), report)), encoding="utf-8")
    files = {name: bundle_dir / name for name in manifest["files"]} | {CAPTION_INDEX_FILE: bundle_dir /
                                                                      CAPTION_INDEX_FILE}
    write_bundle(bundle_dir, files, manifest)
    log.info("caption index: %d captions, threshold %.3f", len(captions), threshold)
    return report
