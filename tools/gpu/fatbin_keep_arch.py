"""Zero the GPU machine code of every architecture but one in a CUDA library's fatbins (tools/gpu/transport.sh).

Why: onnxruntime-gpu's CUDA provider (284 MB) carries kernels for sm_75, 80, 86, 89, 90 and 120, while a lent device
machine has one H100/H200 (sm_90) and a device call carries at most 64 MiB. The driver loads only the image that
matches the GPU, so the other images' bytes can be zeros (headers kept, sizes and offsets unchanged): the file stays
the same length and layout, and zeros compress to nothing (185 MB of xz -> about half).

A fatbin is a 16-byte header (magic 0xBA55ED50, version 1, header size, payload size) followed by entries, each a
header (kind: 1 PTX, 2 ELF; its header and padded payload sizes; the SM version) and its payload. The walk must tile
every fatbin exactly, else nothing is written.
    python tools/gpu/fatbin_keep_arch.py LIB OUT --keep-sm 90
"""
from __future__ import annotations

import argparse
import struct
import sys
from collections import Counter
from pathlib import Path

MAGIC = struct.pack("<I", 0xBA55ED50)
ENTRY = struct.Struct("<HHIIIIIIII")      # kind, version, header size, padded payload, _, payload, _, _, sm, bits
ELF_KIND = 2


def keep_arch(data: bytearray, keep_sm: int) -> Counter[str]:
    """Zero, in place, the ELF payloads of every SM version but keep_sm; PTX entries stay. Returns bytes per outcome."""
    counts: Counter[str] = Counter()
    pos = 0
    while (start := data.find(MAGIC, pos)) >= 0:
        version, header_size, fat_size = struct.unpack_from("<HHQ", data, start + 4)
        if version != 1 or header_size != 16:
            pos = start + 4
            continue
        offset, end = start + header_size, start + header_size + fat_size
        if end > len(data):
            raise ValueError(f"fatbin at byte {start}: says {fat_size} bytes, the file ends first; nothing written")
        while offset + ENTRY.size <= end:
            kind, _, entry_header, padded, _, _, _, _, sm, _ = ENTRY.unpack_from(data, offset)
            payload = offset + entry_header
            if kind == ELF_KIND and sm != keep_sm:
                data[payload:payload + padded] = bytes(padded)
                counts["zeroed"] += padded
            else:
                counts[f"kept sm_{sm} kind {kind}"] += padded
            offset = payload + padded
        if offset != end:
            raise ValueError(f"fatbin at byte {start}: entries end at {offset}, header says {end}; nothing written")
        counts["fatbins"] += 1
        pos = end
    return counts


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("library", type=Path)
    parser.add_argument("out", type=Path)
    parser.add_argument("--keep-sm", type=int, default=90,
                        help="the SM version whose machine code stays (90: H100/H200)")
    args = parser.parse_args(argv)
    data = bytearray(args.library.read_bytes())
    try:
        counts = keep_arch(data, args.keep_sm)
    except ValueError as error:
        print(f"fatbin_keep_arch: {error}", file=sys.stderr)
        return 1
    if not counts["fatbins"]:
        print(f"fatbin_keep_arch: no fatbin in {args.library}", file=sys.stderr)
        return 1
    args.out.write_bytes(data)
    print(", ".join(f"{key}: {value / 1e6:.1f} MB" if key != "fatbins" else f"{value} fatbins"
                    for key, value in sorted(counts.items())))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
