"""tools/gpu/fatbin_keep_arch.py: only the kept architecture's machine code survives, layout and length unchanged,
and a fatbin whose entries do not tile it exactly is refused before anything is written."""
from __future__ import annotations

import struct
from pathlib import Path

import pytest

from tools.gpu.fatbin_keep_arch import keep_arch, main

REPO = Path(__file__).resolve().parents[1]


def entry(kind: int, sm: int, payload: bytes) -> bytes:
    """One fatbin entry: a 64-byte header (kind, version, header size, padded size, ..., SM version) and its payload."""
    header = struct.pack("<HHIIIIIIII", kind, 1, 64, len(payload), 0, len(payload), 0, 0, sm, 64)
    return header + bytes(64 - len(header)) + payload


def fatbin(*entries: bytes, claimed: int | None = None) -> bytes:
    body = b"".join(entries)
    return struct.pack("<IHHQ", 0xBA55ED50, 1, 16, len(body) if claimed is None else claimed) + body


def test_only_the_kept_architecture_keeps_its_bytes() -> None:
    sm80, sm90, ptx = b"\x11" * 96, b"\x22" * 128, b"\x33" * 32
    blob = bytearray(b"host code" + fatbin(entry(2, 80, sm80), entry(2, 90, sm90), entry(1, 80, ptx)) + b"tail")
    before = bytes(blob)
    counts = keep_arch(blob, keep_sm=90)
    assert len(blob) == len(before) and counts["fatbins"] == 1 and counts["zeroed"] == len(sm80)
    assert sm80 not in blob and sm90 in blob and ptx in blob            # PTX entries are never touched
    assert blob.startswith(b"host code") and blob.endswith(b"tail")
    start = before.index(sm80)
    assert blob == before[:start] + bytes(len(sm80)) + before[start + len(sm80):]   # nothing else changed


def test_a_fatbin_that_does_not_tile_is_refused(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    library, out = tmp_path / "lib.so", tmp_path / "out.so"
    library.write_bytes(fatbin(entry(2, 80, b"\x11" * 96), claimed=200))
    assert main([str(library), str(out)]) == 1
    assert not out.exists() and "nothing written" in capsys.readouterr().err
    library.write_bytes(b"no fatbin at all")
    assert main([str(library), str(out)]) == 1 and not out.exists()
