"""A contact sheet of a built dataset (HumanML3D layout): a few clips spread over it, each row titled with its id,
split and first caption, drawn with scripts/render_motions.py's contact sheet, to look at what a build made.

    python scripts/dataset_contact_sheet.py data/cmu                   # data/cmu/contact_sheet.png, 12 clips
    python scripts/dataset_contact_sheet.py data/cmu --rows 6 --out /tmp/sheet.png
"""
from __future__ import annotations

import argparse
import textwrap
from pathlib import Path

import numpy as np

from scripts.render_motions import SheetRow, contact_sheet
from t2m.model.data.motion_data import MotionDirectory

__all__ = ["dataset_rows", "main"]


def dataset_rows(root: Path, rows: int) -> list[SheetRow]:
    """`rows` original (not mirrored) clips spread evenly over the sorted ids of all splits."""
    items = []
    for split in ("train", "val", "test"):
        data = MotionDirectory(root, split)
        items += [(item, split, data) for item in data.ids if not item.startswith("M")]
    items.sort(key=lambda entry: entry[0])
    if not items:
        raise ValueError(f"{root}: no clips to draw")
    picks = sorted(set(np.linspace(0, len(items) - 1, min(rows, len(items))).round().astype(int).tolist()))
    sheet = []
    for k in picks:
        item, split, data = items[k]
        caption = textwrap.shorten(data.captions(item)[0], 110)
        sheet.append(SheetRow(joints=data.joints(item), title=f"{item} ({split}, {data.num_frames(item) / 20:.1f} s): "
                              f"{caption}"))
    return sheet


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("dataset", type=Path, help="a built dataset directory")
    parser.add_argument("--rows", type=int, default=12, help="clips to draw (default 12)")
    parser.add_argument("--out", type=Path, default=None, help="PNG path (default DATASET/contact_sheet.png)")
    args = parser.parse_args(argv)
    path = contact_sheet(dataset_rows(args.dataset, args.rows), args.out or args.dataset / "contact_sheet.png")
    print(path)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
