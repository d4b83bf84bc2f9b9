"""Pictures of generated motions for the README and the model card: a contact sheet and an animated stream.

docs/images/contact_sheet.png: one row per motion (a probe sentence, 3 s, or the three-sentence stream of
t2m.model.evaluation.probes.STREAM), each row a strip of stick-figure frames seen from the front-left of where the
motion starts (left bones blue, right bones red), with the pelvis path drawn on a 0.5 m floor grid and the probe's
measurement in the title. docs/images/stream.gif: the stream animated, the current sentence written above the figure.

    python scripts/render_motions.py                             # t2m/bundles/default, seed 0
    python scripts/render_motions.py --bundle DIR --seed 3 --guidance 3 --out docs/images
"""
from __future__ import annotations

import argparse
import io
import logging
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from t2m.model.evaluation.probes import STREAM, initial_facing, path_length, probe_by_name
from t2m.motion.skeleton import SMPL22

if TYPE_CHECKING:
    from t2m.runtime.types import Motion

__all__ = ["SINGLE_MOTIONS", "Camera", "SheetRow", "contact_sheet", "load_engine", "main", "stream_gif"]

log = logging.getLogger("scripts.render_motions")

REPO = Path(__file__).resolve().parent.parent
LEFT, RIGHT, CENTRE = "#1f5fbf", "#d62728", "#333333"
JOIN_COLOUR = "#ff8c00"
UP = np.array([0.0, 1.0, 0.0])

# (probe, which of its phrasings): one row per entry, 3 s each
SINGLE_MOTIONS: tuple[tuple[str, int], ...] = (
    ("walk_forward", 0), ("walk_backward", 0), ("run_vs_walk", 0), ("turn_left", 0), ("turn_right", 0),
    ("raise_right", 0), ("raise_left", 1), ("raise_both", 2), ("bow", 0), ("kick", 0),
)


@dataclass(frozen=True)
class SheetRow:
    """One row of the contact sheet: the motion, its title, and the frames where a new sentence starts."""

    joints: np.ndarray          # [T, 22, 3]
    title: str
    joins: tuple[int, ...] = ()
    fps: int = 20


class Camera:
    """An orthographic camera looking at the body from the front-left of its initial facing, slightly from above.

    Screen x is the camera's right, screen y its up; `depth` grows towards the camera (to draw far bones first).
    """

    def __init__(self, facing: np.ndarray, azimuth_deg: float = 60.0, elevation_deg: float = 15.0) -> None:
        forward = facing / np.linalg.norm(facing)
        left = np.cross(UP, forward)
        azimuth, elevation = np.radians(azimuth_deg), np.radians(elevation_deg)
        self.towards_camera = np.cos(elevation) * (np.cos(azimuth) * forward + np.sin(azimuth) * left) \
            + np.sin(elevation) * UP
        look = -self.towards_camera
        self.right = np.cross(look, UP)
        self.right /= np.linalg.norm(self.right)
        self.up = np.cross(self.right, look)

    def project(self, points: np.ndarray, centre: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Screen coordinates [..., 2] and depth [...] of world points, relative to `centre`."""
        relative = points - centre
        return np.stack([relative @ self.right, relative @ self.up], axis=-1), relative @ self.towards_camera


def _bone_colours() -> list[tuple[int, int, str]]:
    """(parent, child, colour) for every bone, coloured by the side of the body the bone is on."""
    bones = []
    for child, parent in enumerate(SMPL22.parents):
        if parent < 0:
            continue
        name = SMPL22.joint_names[child]
        colour = LEFT if name.startswith("left_") else RIGHT if name.startswith("right_") else CENTRE
        bones.append((parent, child, colour))
    return bones


BONES = _bone_colours()


def draw_pose(ax, joints: np.ndarray, frame: int, camera: Camera, *, linewidth: float = 2.2,
              grid_half: float = 1.5) -> None:
    """One frame on `ax`: floor grid and pelvis path (centred on the current pelvis) and the skeleton."""
    pelvis = joints[frame, 0]
    centre = np.array([pelvis[0], 0.0, pelvis[2]])
    # floor grid lines every 0.5 m, fixed in the world, so that travel shows as the grid sliding by
    start = np.floor((centre[[0, 2]] - grid_half) / 0.5) * 0.5
    for k in range(int(2 * grid_half / 0.5) + 2):
        for axis in (0, 2):
            value = start[0 if axis == 0 else 1] + 0.5 * k
            line = np.zeros((2, 3))
            line[:, axis] = value
            other = 2 if axis == 0 else 0
            line[:, other] = centre[other] + np.array([-grid_half, grid_half])
            xy, _ = camera.project(line, centre)
            ax.plot(xy[:, 0], xy[:, 1], color="#dddddd", linewidth=0.6, zorder=0)
    path = joints[:, 0].copy()
    path[:, 1] = 0.0
    xy, _ = camera.project(path, centre)
    ax.plot(xy[:, 0], xy[:, 1], color="#999999", linewidth=1.0, zorder=1)
    ax.plot(xy[frame, 0], xy[frame, 1], "o", color="#999999", markersize=3, zorder=1)
    points, depth = camera.project(joints[frame], centre)
    for parent, child, colour in sorted(BONES, key=lambda bone: depth[bone[0]] + depth[bone[1]]):
        ax.plot(points[[parent, child], 0], points[[parent, child], 1], color=colour, linewidth=linewidth,
                solid_capstyle="round", zorder=2)
    head = points[SMPL22.joint_names.index("head")]
    ax.plot(head[0], head[1], "o", color=CENTRE, markersize=linewidth * 2.5, zorder=3)
    ax.set_xlim(-1.1, 1.1)
    ax.set_ylim(-0.45, 2.0)
    ax.set_aspect("equal")
    ax.axis("off")


def _pick_frames(length: int, count: int, joins: Sequence[int]) -> list[int]:
    """`count` frames spread over the motion, each join frame included exactly (it replaces its nearest pick)."""
    frames = list(np.linspace(0, length - 1, count).round().astype(int))
    for join in joins:
        nearest = min(range(len(frames)), key=lambda i: abs(frames[i] - join))
        frames[nearest] = join
    return sorted(set(frames))


def _segment_of(frame: int, joins: Sequence[int]) -> int:
    return sum(frame >= join for join in joins)


def contact_sheet(rows: Sequence[SheetRow], path: str | Path, frames_per_row: int = 8, dpi: int = 72) -> Path:
    """Write the PNG: one strip of frames per row, the row's title above it, join frames boxed in orange."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    if not rows:
        raise ValueError("rows: nothing to draw")
    columns = max(frames_per_row + (len(row.joins) and 2) for row in rows)
    header = 0.3
    figure = plt.figure(figsize=(1.5 * columns, 2.3 * len(rows) + header), dpi=dpi)
    subfigures = figure.subfigures(len(rows) + 1, 1, squeeze=False, height_ratios=[header] + [2.3] * len(rows))[:, 0]
    subfigures[0].text(0.01, 0.5, "Blue: the body's left side, red: its right side. Grey: the pelvis path on a "
                       "0.5 m floor grid. Seen from the front-left of where each motion starts.",
                       fontsize=10, va="center", color="#444444")
    for subfigure, row in zip(subfigures[1:], rows):
        camera = Camera(initial_facing(row.joints))
        count = frames_per_row + (2 if row.joins else 0)
        frames = _pick_frames(len(row.joints), count, row.joins)
        axes = subfigure.subplots(1, columns)
        subfigure.subplots_adjust(left=0.005, right=0.995, bottom=0.01, top=0.80, wspace=0.04)
        subfigure.suptitle(row.title, fontsize=11, x=0.01, ha="left", y=0.975)
        for ax in axes[len(frames):]:
            ax.axis("off")
        for ax, frame in zip(axes, frames):
            draw_pose(ax, row.joints, frame, camera)
            label = f"{frame / row.fps:.1f} s"
            if row.joins:
                label += f" · {_segment_of(frame, row.joins) + 1}"
            is_join = frame in row.joins
            ax.set_title(label + (" · join" if is_join else ""), fontsize=8.5,
                         color=JOIN_COLOUR if is_join else "#444444", pad=1)
            if is_join:
                ax.axis("on")
                ax.set_xticks([])
                ax.set_yticks([])
                for spine in ax.spines.values():
                    spine.set_edgecolor(JOIN_COLOUR)
                    spine.set_linewidth(2.0)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    figure.savefig(path, dpi=dpi, facecolor="white")
    plt.close(figure)
    return path


def stream_gif(joints: np.ndarray, sentences: Sequence[str], starts: Sequence[int], path: str | Path,
               fps: int = 20, every: int = 1, size_px: int = 300) -> Path:
    """Write the animated GIF of a stream: one frame per `every` motion frames, the current sentence on top."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from PIL import Image

    if len(sentences) != len(starts):
        raise ValueError(f"sentences: {len(sentences)} sentences but {len(starts)} start frames")
    camera = Camera(initial_facing(joints))
    dpi = 100
    figure = plt.figure(figsize=(size_px / dpi, size_px * 1.25 / dpi), dpi=dpi)
    images = []
    for frame in range(0, len(joints), every):
        figure.clear()
        ax = figure.add_axes((0.0, 0.0, 1.0, 0.86))
        draw_pose(ax, joints, frame, camera, linewidth=2.5)
        segment = _segment_of(frame, starts[1:])
        figure.text(0.5, 0.955, f'{segment + 1}/{len(sentences)}: "{sentences[segment]}"', ha="center",
                    va="center", fontsize=7.5, wrap=True)
        figure.text(0.5, 0.895, f"{frame / fps:.2f} s", ha="center", va="center", fontsize=7.5, color="#666666")
        _timeline(figure.add_axes((0.05, 0.02, 0.9, 0.025)), len(joints), starts, frame)
        buffer = io.BytesIO()
        figure.savefig(buffer, format="png", dpi=dpi, facecolor="white")
        images.append(Image.open(io.BytesIO(buffer.getvalue())).convert("P", palette=Image.Palette.ADAPTIVE,
                                                                          colors=32))
    plt.close(figure)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    images[0].save(path, save_all=True, append_images=images[1:], duration=round(1000 * every / fps), loop=0,
                   optimize=True, disposal=2)
    return path


def _timeline(ax, frames: int, starts: Sequence[int], frame: int) -> None:
    """A bar of the stream's sentences (alternating greys, joins in orange) with the current frame marked."""
    ends = list(starts[1:]) + [frames]
    for index, (start, end) in enumerate(zip(starts, ends)):
        ax.axvspan(start, end, color="#cccccc" if index % 2 == 0 else "#999999", linewidth=0)
        if index:
            ax.axvline(start, color=JOIN_COLOUR, linewidth=2)
    ax.axvline(frame, color="black", linewidth=2)
    ax.set_xlim(0, frames)
    ax.axis("off")


def _title(text: str, seconds: float, seed: int, probe: str, joints: np.ndarray) -> str:
    """The sentence, then what its probe measured on this very motion (a paired probe: the pelvis path)."""
    if probe_by_name(probe).reference_phrasings:
        measured = f"   [pelvis path {path_length(joints):.2f} m]"
    else:
        result = probe_by_name(probe).check(joints)
        details = "".join(f", {key.replace('_', ' ')} {value:.2f}" for key, value in result.details.items())
        measured = (f"   [{result.probe}: {result.value:+.2f} {result.unit}{details}, "
                    f"{'pass' if result.passed else 'FAIL'}]")
    return f'"{text}"  ({seconds:g} s, seed {seed}){measured}'


def generated_rows(engine, seed: int, guidance: float, duration: float = 3.0) -> tuple[list[SheetRow], Motion]:
    """Generate the single-sentence motions and the stream; the sheet's rows and the stream's Motion."""
    from t2m.runtime.types import GenerationRequest, SegmentRequest

    singles = [(name, probe_by_name(name).phrasings[index]) for name, index in SINGLE_MOTIONS]
    requests = [GenerationRequest(segments=[SegmentRequest(text, duration)], seed=seed, guidance=guidance)
                for _, text in singles]
    requests.append(GenerationRequest(segments=[SegmentRequest(text, seconds) for text, seconds, _ in STREAM],
                                      seed=seed, guidance=guidance))
    results = engine.generate_batch(requests)
    for result in results:
        if isinstance(result, BaseException):
            raise result
    rows = [SheetRow(motion.joints, _title(text, duration, seed, name, motion.joints))
            for (name, text), motion in zip(singles, results)]
    stream = results[-1]
    joins = tuple(span.start_frame for span in stream.segments[1:])
    sentences = " -> ".join(f'"{text}" {seconds:g} s' for text, seconds, _ in STREAM)
    rows.append(SheetRow(stream.joints, f"stream, seed {seed}: {sentences}  (orange: first frame of a sentence)",
                         joins))
    return rows, stream


def load_engine(bundle: str) -> Any:
    """The bundle's OnnxEngine, or None after one line on stderr saying why it did not load."""
    from t2m.runtime.engine import OnnxEngine

    try:
        return OnnxEngine.load(bundle)
    except (ValueError, FileNotFoundError) as error:
        print(f"error: {error}", file=sys.stderr)
        return None


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--bundle", default=str(REPO / "t2m" / "bundles" / "default"), help="bundle directory")
    parser.add_argument("--out", default=str(REPO / "docs" / "images"), help="output directory")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--guidance", type=float, default=None,
                        help="classifier-free guidance (default: the manifest's, or 1 without an unconditional branch)")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(message)s")
    engine = load_engine(args.bundle)
    if engine is None:
        return 2
    limits = engine.limits
    guidance = limits.guidance(args.guidance)
    log.info("generating %d motions with seed %d, guidance %g", len(SINGLE_MOTIONS) + 1, args.seed, guidance)
    rows, stream = generated_rows(engine, args.seed, guidance)
    log.info("drawing %s", out_dir := Path(args.out))
    sheet = contact_sheet(rows, out_dir / "contact_sheet.png")
    gif = stream_gif(stream.joints, [span.text for span in stream.segments],
                     [span.start_frame for span in stream.segments], out_dir / "stream.gif", fps=stream.fps)
    for written in (sheet, gif):
        print(f"wrote {written} ({written.stat().st_size / 1024:.0f} KiB)")
    print(f"model {limits.name} {limits.version}, guidance {guidance:g}, seed {args.seed}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
