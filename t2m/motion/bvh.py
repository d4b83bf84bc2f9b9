"""Reading, forward kinematics and writing of BVH motion capture files (numpy only).

BVH is the lingua franca of mocap: a joint hierarchy (offsets + channel lists) followed by one line of channel
values per frame. Files in the wild vary (CRLF, tabs, 3 or 6 channels, any rotation order, End Sites), so the
reader accepts all of that and rejects anything malformed with a `BvhError` that names the line and what was
expected, because a user pointing the CLI at a broken file needs to know where to look.

Conventions (the ones every major exporter uses):
- a rotation is the product of the per-channel elementary rotations in channel order (intrinsic), e.g.
  `Zrotation Xrotation Yrotation` gives R = Rz @ Rx @ Ry, angles in degrees;
- a joint's local translation is its OFFSET, with any position channel replacing that component of the offset;
- world transform of a joint = parent's world transform @ [R_local | t_local].
"""
from __future__ import annotations

import math
import os
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO

import numpy as np

__all__ = ["CHANNEL_NAMES", "BvhError", "BvhMotion", "read_bvh", "write_bvh"]

CHANNEL_NAMES = ("Xposition", "Yposition", "Zposition", "Xrotation", "Yrotation", "Zrotation")
_CANONICAL = {name.lower(): name for name in CHANNEL_NAMES}
_AXIS = {"X": 0, "Y": 1, "Z": 2}


class BvhError(ValueError):
    """A malformed BVH file; the message names the line (or the MOTION frame) and what was expected."""


@dataclass(eq=False)
class BvhMotion:
    """A parsed BVH file: the hierarchy in file (depth-first) order plus the raw channel values.

    `motion[:, channel_starts[j] : channel_starts[j] + len(channels[j])]` are joint j's values, in the order of
    `channels[j]`. End Sites are kept apart (they have no channels) as `end_site_parents` / `end_site_offsets`.
    """

    joint_names: list[str]
    parents: np.ndarray            # int [J], -1 for a root; a parent always comes before its children
    offsets: np.ndarray            # float [J, 3], file units
    channels: list[tuple[str, ...]]
    frame_time: float              # seconds per frame
    motion: np.ndarray             # float [T, C], C = sum of channel counts
    end_site_parents: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))  # int [E]
    end_site_offsets: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))            # float [E, 3]

    def __post_init__(self) -> None:
        self.joint_names = list(self.joint_names)
        self.parents = np.asarray(self.parents, dtype=np.int64).reshape(-1)
        self.offsets = np.asarray(self.offsets, dtype=np.float64).reshape(-1, 3)
        self.channels = [tuple(_canonical_channel(c, f"joint {name!r}") for c in chans)
                         for name, chans in zip(self.joint_names, self.channels)]
        self.motion = np.asarray(self.motion, dtype=np.float64)
        if self.motion.ndim == 1 and self.motion.size == 0:
            self.motion = self.motion.reshape(0, self.num_channels)
        self.end_site_parents = np.asarray(self.end_site_parents, dtype=np.int64).reshape(-1)
        self.end_site_offsets = np.asarray(self.end_site_offsets, dtype=np.float64).reshape(-1, 3)
        self._validate()

    def _validate(self) -> None:
        count = len(self.joint_names)
        if count == 0:
            raise BvhError("BVH hierarchy has no joints")
        if len(self.parents) != count or len(self.offsets) != count or len(self.channels) != count:
            raise BvhError(f"BVH hierarchy: {count} joint names but {len(self.parents)} parents, "
                           f"{len(self.offsets)} offsets and {len(self.channels)} channel lists")
        for index, parent in enumerate(self.parents):
            if not -1 <= parent < index:
                raise BvhError(f"BVH hierarchy: joint {self.joint_names[index]!r} has parent {parent}; "
                               f"a parent must be -1 or an earlier joint")
        if self.motion.ndim != 2 or self.motion.shape[1] != self.num_channels:
            raise BvhError(f"BVH motion has shape {self.motion.shape}, expected [frames, {self.num_channels}]")
        if not (math.isfinite(self.frame_time) and self.frame_time > 0):
            raise BvhError(f"BVH frame time must be a positive number of seconds, got {self.frame_time}")
        if len(self.end_site_parents) != len(self.end_site_offsets):
            raise BvhError("BVH end sites: parents and offsets differ in length")
        if np.any((self.end_site_parents < 0) | (self.end_site_parents >= count)):
            raise BvhError("BVH end sites: a parent index is out of range")

    # --- shape and lookup -------------------------------------------------------------------------------------
    @property
    def num_joints(self) -> int:
        return len(self.joint_names)

    @property
    def num_frames(self) -> int:
        return int(self.motion.shape[0])

    @property
    def num_channels(self) -> int:
        return sum(len(c) for c in self.channels)

    @property
    def fps(self) -> float:
        return 1.0 / self.frame_time

    @property
    def channel_starts(self) -> np.ndarray:
        """Column of each joint's first channel in `motion`."""
        counts = [len(c) for c in self.channels]
        return np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.int64) if counts else np.zeros(0, np.int64)

    def joint_index(self, name: str) -> int:
        try:
            return self.joint_names.index(name)
        except ValueError:
            raise KeyError(f"BVH has no joint named {name!r}; joints: {', '.join(self.joint_names)}") from None

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, BvhMotion):
            return NotImplemented
        return (self.joint_names == other.joint_names and self.channels == other.channels
                and self.frame_time == other.frame_time
                and np.array_equal(self.parents, other.parents) and np.array_equal(self.offsets, other.offsets)
                and np.array_equal(self.motion, other.motion)
                and np.array_equal(self.end_site_parents, other.end_site_parents)
                and np.array_equal(self.end_site_offsets, other.end_site_offsets))

    # --- kinematics -------------------------------------------------------------------------------------------
    def local_transforms(self) -> tuple[np.ndarray, np.ndarray]:
        """Per-frame local rotation matrices [T, J, 3, 3] and translations [T, J, 3] from every channel."""
        frames = self.num_frames
        rotations = np.broadcast_to(np.eye(3), (frames, self.num_joints, 3, 3)).copy()
        translations = np.broadcast_to(self.offsets, (frames, self.num_joints, 3)).copy()
        for joint, (start, chans) in enumerate(zip(self.channel_starts, self.channels)):
            for k, channel in enumerate(chans):
                values = self.motion[:, start + k]
                axis = _AXIS[channel[0]]
                if channel.endswith("position"):
                    translations[:, joint, axis] = values
                else:
                    rotations[:, joint] = rotations[:, joint] @ _axis_rotation(axis, np.radians(values))
        return rotations, translations

    def forward_kinematics(self, include_end_sites: bool = False) -> np.ndarray:
        """World positions [T, J, 3] in file units (End Sites appended after the joints when asked: [T, J+E, 3])."""
        local_rot, local_pos = self.local_transforms()
        world_rot = np.empty_like(local_rot)
        world_pos = np.empty_like(local_pos)
        for joint, parent in enumerate(self.parents):
            if parent < 0:
                world_rot[:, joint] = local_rot[:, joint]
                world_pos[:, joint] = local_pos[:, joint]
            else:
                world_rot[:, joint] = world_rot[:, parent] @ local_rot[:, joint]
                world_pos[:, joint] = (np.einsum("tij,tj->ti", world_rot[:, parent], local_pos[:, joint])
                                       + world_pos[:, parent])
        if not include_end_sites or len(self.end_site_parents) == 0:
            return world_pos
        ends = (np.einsum("teij,ej->tei", world_rot[:, self.end_site_parents], self.end_site_offsets)
                + world_pos[:, self.end_site_parents])
        return np.concatenate([world_pos, ends], axis=1)


def _axis_rotation(axis: int, angles: np.ndarray) -> np.ndarray:
    """Right-handed rotation matrices [T, 3, 3] about one coordinate axis (radians).

    Private on purpose: BVH allows any number of rotation channels in any order (including repeated axes),
    so the joint rotation is built as a product of elementary rotations rather than via a 3-angle Euler API.
    """
    c, s = np.cos(angles), np.sin(angles)
    out = np.zeros(angles.shape + (3, 3))
    i, j = [(1, 2), (2, 0), (0, 1)][axis]
    out[..., axis, axis] = 1.0
    out[..., i, i] = c
    out[..., j, j] = c
    out[..., i, j] = -s
    out[..., j, i] = s
    return out


def _canonical_channel(name: str, where: str) -> str:
    canonical = _CANONICAL.get(name.lower())
    if canonical is None:
        raise BvhError(f"{where}: unknown channel {name!r}; expected one of {', '.join(CHANNEL_NAMES)}")
    return canonical


# --- reading --------------------------------------------------------------------------------------------------
class _Lines:
    """Non-blank lines with their 1-based numbers, so every error can point at the file."""

    def __init__(self, text: str) -> None:
        self.items = [(number, line.strip()) for number, line in enumerate(text.splitlines(), start=1)
                      if line.strip()]
        self.position = 0
        self.last_number = len(text.splitlines())

    def peek(self) -> tuple[int, str] | None:
        return self.items[self.position] if self.position < len(self.items) else None

    def next(self, expected: str) -> tuple[int, str]:
        item = self.peek()
        if item is None:
            raise BvhError(f"line {self.last_number + 1}: unexpected end of file, expected {expected}")
        self.position += 1
        return item


def _numbers(parts: Sequence[str], number: int, what: str, line: str) -> list[float]:
    try:
        values = [float(p) for p in parts]
    except ValueError:
        raise BvhError(f"line {number}: expected {what}, got {line!r} (not a number)") from None
    if not all(math.isfinite(v) for v in values):
        raise BvhError(f"line {number}: expected {what}, got {line!r} (not finite)")
    return values


def _expect_open_brace(lines: _Lines, header_line: str) -> None:
    if header_line.endswith("{"):
        return
    number, line = lines.next("'{'")
    if line != "{":
        raise BvhError(f"line {number}: expected '{{', got {line!r}")


def _read_offset(lines: _Lines) -> list[float]:
    number, line = lines.next("'OFFSET x y z'")
    parts = line.split()
    if parts[0].upper() != "OFFSET" or len(parts) != 4:
        raise BvhError(f"line {number}: expected 'OFFSET x y z', got {line!r}")
    return _numbers(parts[1:], number, "'OFFSET x y z'", line)


def _read_channels(lines: _Lines, joint: str) -> tuple[str, ...]:
    number, line = lines.next(f"'CHANNELS n ...' for joint {joint!r}")
    parts = line.split()
    if parts[0].upper() != "CHANNELS" or len(parts) < 2:
        raise BvhError(f"line {number}: expected 'CHANNELS n name...' for joint {joint!r}, got {line!r}")
    try:
        count = int(parts[1])
    except ValueError:
        raise BvhError(f"line {number}: expected a channel count after CHANNELS, got {parts[1]!r}") from None
    names = parts[2:]
    if count != len(names):
        raise BvhError(f"line {number}: CHANNELS says {count} channels but lists {len(names)}: {line!r}")
    if count > 6:
        raise BvhError(f"line {number}: at most 6 channels per joint, got {count}")
    return tuple(_canonical_channel(n, f"line {number}") for n in names)


def _parse_hierarchy(lines: _Lines) -> tuple[list[str], list[int], list[list[float]], list[tuple[str, ...]],
                                              list[int], list[list[float]]]:
    names: list[str] = []
    parents: list[int] = []
    offsets: list[list[float]] = []
    channels: list[tuple[str, ...]] = []
    end_parents: list[int] = []
    end_offsets: list[list[float]] = []

    def parse_joint(header_number: int, header: str, parent: int) -> None:
        keyword, _, rest = header.partition(" ")
        name = rest.strip().removesuffix("{").strip()
        if not name:
            raise BvhError(f"line {header_number}: expected '{keyword} name', got {header!r} (no name)")
        _expect_open_brace(lines, header)
        index = len(names)
        names.append(name)
        parents.append(parent)
        offsets.append(_read_offset(lines))
        channels.append(_read_channels(lines, name))
        while True:
            number, line = lines.next(f"'JOINT', 'End Site' or '}}' closing joint {name!r}")
            word = line.split()[0].upper()
            if line == "}":
                return
            if word == "JOINT":
                parse_joint(number, " ".join(line.split()), index)
            elif word == "END":
                if " ".join(line.split()).removesuffix("{").strip().upper() != "END SITE":
                    raise BvhError(f"line {number}: expected 'End Site', got {line!r}")
                _expect_open_brace(lines, line)
                end_parents.append(index)
                end_offsets.append(_read_offset(lines))
                close_number, close = lines.next("'}' closing End Site")
                if close != "}":
                    raise BvhError(f"line {close_number}: expected '}}' closing End Site of {name!r}, got {close!r}")
            else:
                raise BvhError(f"line {number}: expected 'JOINT', 'End Site' or '}}' in joint {name!r}, got {line!r}")

    number, line = lines.next("'HIERARCHY'")
    if line.upper() != "HIERARCHY":
        raise BvhError(f"line {number}: expected 'HIERARCHY', got {line!r}")
    while True:
        item = lines.peek()
        if item is None:
            raise BvhError(f"line {lines.last_number + 1}: unexpected end of file, expected 'MOTION'"
                           if names else f"line {lines.last_number + 1}: unexpected end of file, expected 'ROOT name'")
        number, line = item
        word = line.split()[0].upper()
        if word == "MOTION" and names:
            return names, parents, offsets, channels, end_parents, end_offsets
        lines.next("'ROOT name'")
        if word != "ROOT":
            expected = "'ROOT name' or 'MOTION'" if names else "'ROOT name'"
            raise BvhError(f"line {number}: expected {expected}, got {line!r}")
        parse_joint(number, " ".join(line.split()), -1)


def _parse_motion(lines: _Lines, num_channels: int) -> tuple[float, np.ndarray]:
    number, line = lines.next("'MOTION'")
    if line.upper() != "MOTION":
        raise BvhError(f"line {number}: expected 'MOTION', got {line!r}")
    number, line = lines.next("'Frames: n'")
    label, _, value = line.partition(":")
    if label.strip().upper() != "FRAMES":
        raise BvhError(f"line {number}: expected 'Frames: n', got {line!r}")
    try:
        frames = int(value.strip())
    except ValueError:
        raise BvhError(f"line {number}: expected 'Frames: n' with a whole number, got {line!r}") from None
    if frames < 0:
        raise BvhError(f"line {number}: frame count must not be negative, got {frames}")
    frames_line = number
    number, line = lines.next("'Frame Time: seconds'")
    label, _, value = line.partition(":")
    if " ".join(label.split()).upper() != "FRAME TIME":
        raise BvhError(f"line {number}: expected 'Frame Time: seconds', got {line!r}")
    frame_time = _numbers([value.strip()], number, "'Frame Time: seconds'", line)[0]
    if frame_time <= 0:
        raise BvhError(f"line {number}: frame time must be positive, got {frame_time}")

    rows = lines.items[lines.position:]
    if len(rows) != frames:
        raise BvhError(f"MOTION: 'Frames: {frames}' (line {frames_line}) but {len(rows)} frame lines follow")
    motion = np.empty((frames, num_channels), dtype=np.float64)
    for frame, (number, line) in enumerate(rows):
        parts = line.split()
        if len(parts) != num_channels:
            raise BvhError(f"MOTION: frame {frame} (line {number}) has {len(parts)} values, expected {num_channels}")
        try:
            motion[frame] = np.array(parts, dtype=np.float64)
        except ValueError:
            bad = next(p for p in parts if not _is_float(p))
            raise BvhError(f"line {number}: MOTION frame {frame} has a non-numeric value {bad!r}") from None
    if not np.all(np.isfinite(motion)):
        frame = int(np.argwhere(~np.isfinite(motion))[0, 0])
        raise BvhError(f"line {rows[frame][0]}: MOTION frame {frame} has a non-finite value")
    lines.position = len(lines.items)
    return frame_time, motion


def _is_float(text: str) -> bool:
    try:
        float(text)
        return True
    except ValueError:
        return False


def _looks_like_text(source: str) -> bool:
    return "\n" in source or source.lstrip().upper().startswith("HIERARCHY")


def read_bvh(source: str | os.PathLike | IO[str]) -> BvhMotion:
    """Parse a BVH file given as a path, the file's text, or a text stream. Raises `BvhError` on malformed input."""
    if hasattr(source, "read"):
        text = source.read()
        if isinstance(text, bytes):
            text = text.decode("utf-8-sig")
        where = getattr(source, "name", "<stream>")
    elif isinstance(source, str) and _looks_like_text(source):
        text, where = source, "<text>"
    else:
        path = Path(source)
        text = path.read_text(encoding="utf-8-sig", errors="strict")
        where = str(path)
    text = text.lstrip("\ufeff")
    try:
        lines = _Lines(text)
        names, parents, offsets, channels, end_parents, end_offsets = _parse_hierarchy(lines)
        frame_time, motion = _parse_motion(lines, sum(len(c) for c in channels))
    except BvhError as error:
        if where == "<text>":
            raise
        raise BvhError(f"{where}: {error}") from None
    return BvhMotion(joint_names=names, parents=np.array(parents), offsets=np.array(offsets, dtype=np.float64),
                     channels=channels, frame_time=frame_time, motion=motion,
                     end_site_parents=np.array(end_parents, dtype=np.int64),
                     end_site_offsets=np.array(end_offsets, dtype=np.float64).reshape(-1, 3))


# --- writing --------------------------------------------------------------------------------------------------
def _depth_first(parents: np.ndarray) -> list[int]:
    children: dict[int, list[int]] = {}
    for index, parent in enumerate(parents):
        children.setdefault(int(parent), []).append(index)
    order: list[int] = []
    stack = list(reversed(children.get(-1, [])))
    while stack:
        joint = stack.pop()
        order.append(joint)
        stack.extend(reversed(children.get(joint, [])))
    return order


def _format(values: Iterator[float] | Sequence[float], precision: int | None) -> str:
    if precision is None:  # shortest text that reads back to the identical float
        return " ".join(repr(float(v)) for v in values)
    return " ".join(f"{float(v):.{precision}g}" for v in values)


def write_bvh(target: str | os.PathLike | IO[str] | None, bvh: BvhMotion, precision: int | None = None) -> str:
    """Write `bvh` as a BVH file to a path or text stream (or only return the text when `target` is None).

    Joints are written depth-first (children in index order), with the motion columns permuted to match; a
    BvhMotion whose joints are already depth-first (anything `read_bvh` returns) reads back identical.
    `precision=None` writes each float's shortest exact representation; an int writes that many significant
    digits (6 is what most exporters use and is plenty for centimetres and degrees).
    """
    order = _depth_first(bvh.parents)
    starts = bvh.channel_starts
    children: dict[int, list[int]] = {}
    for index, parent in enumerate(bvh.parents):
        children.setdefault(int(parent), []).append(index)
    ends: dict[int, list[int]] = {}
    for index, parent in enumerate(bvh.end_site_parents):
        ends.setdefault(int(parent), []).append(index)

    out: list[str] = ["HIERARCHY"]

    def emit(joint: int, depth: int) -> None:
        pad = "  " * depth
        keyword = "ROOT" if bvh.parents[joint] < 0 else "JOINT"
        out.append(f"{pad}{keyword} {bvh.joint_names[joint]}")
        out.append(f"{pad}{{")
        out.append(f"{pad}  OFFSET {_format(bvh.offsets[joint], precision)}")
        chans = bvh.channels[joint]
        out.append(f"{pad}  CHANNELS {len(chans)}" + "".join(f" {c}" for c in chans))
        for child in children.get(joint, []):
            emit(child, depth + 1)
        for end in ends.get(joint, []):
            out.append(f"{pad}  End Site")
            out.append(f"{pad}  {{")
            out.append(f"{pad}    OFFSET {_format(bvh.end_site_offsets[end], precision)}")
            out.append(f"{pad}  }}")
        out.append(f"{pad}}}")

    for root in children.get(-1, []):
        emit(root, 0)
    columns = np.concatenate([np.arange(starts[j], starts[j] + len(bvh.channels[j])) for j in order]).astype(int)
    out.append("MOTION")
    out.append(f"Frames: {bvh.num_frames}")
    out.append(f"Frame Time: {_format([bvh.frame_time], precision)}")
    for row in bvh.motion[:, columns]:
        out.append(_format(row.tolist(), precision))
    text = "\n".join(out) + "\n"
    if target is None:
        return text
    if hasattr(target, "write"):
        target.write(text)
    else:
        Path(target).write_text(text, encoding="utf-8")
    return text
