"""A raw HTTP/1.1 exchange over a loopback socket, for what no HTTP library sends: bytes dribbled, half-sent headers
or bodies, malformed request lines, a wrong Content-Length. Used by the hostile-input corpus (tests/fuzz) and the
request-deadline tests (tests/service)."""
from __future__ import annotations

import socket
import time
from collections.abc import Sequence
from dataclasses import dataclass, field

__all__ = ["RawAnswer", "exchange", "split"]


@dataclass
class RawAnswer:
    """What came back. status None: no answer (the server closed, or the wait ended, before a whole one)."""

    status: int | None = None
    headers: dict[str, str] = field(default_factory=dict)
    body: bytes = b""
    closed_after_s: float | None = None   # from the end of sending to the server's close; None: open when we stopped
    sent_all: bool = True                 # False: the server closed before the client had sent everything


def split(data: bytes, parts: int) -> list[bytes]:
    """`data` in `parts` pieces of (nearly) equal size, none empty."""
    parts = max(1, min(parts, len(data)))
    size = -(-len(data) // parts)
    return [data[i:i + size] for i in range(0, len(data), size)]


def exchange(port: int, pieces: Sequence[bytes], *, gap_s: float = 0.0, wait_s: float = 10.0,
             half_close: bool = False, until_closed: bool = False) -> RawAnswer:
    """Sends `pieces` to 127.0.0.1:`port`, `gap_s` apart, then reads one answer (1xx skipped) for at most `wait_s`.

    `half_close`: shut the sending side after the last piece. `until_closed`: keep reading after the answer until
    the server closes (or `wait_s` ends), to time the close.
    """
    answer = RawAnswer()
    with socket.create_connection(("127.0.0.1", port), timeout=wait_s) as sock:
        for index, piece in enumerate(pieces):
            if index and gap_s:
                time.sleep(gap_s)
            try:
                if piece:
                    sock.sendall(piece)
            except OSError:   # the server answered and closed early (a 408, 413 or 400): read what it said
                answer.sent_all = False
                break
        if half_close and answer.sent_all:
            sock.shutdown(socket.SHUT_WR)
        sent_at = time.perf_counter()
        deadline = sent_at + wait_s
        data = b""
        while True:
            if answer.status is None or until_closed:
                parsed = _parse(data)
                if parsed is not None and answer.status is None:
                    answer.status, answer.headers, answer.body = parsed
                    if not until_closed:
                        break
            remaining = deadline - time.perf_counter()
            if remaining <= 0:
                break
            sock.settimeout(remaining)
            try:
                chunk = sock.recv(65536)
            except TimeoutError:
                break
            except OSError:   # reset by the server: closed
                chunk = b""
            if not chunk:
                answer.closed_after_s = time.perf_counter() - sent_at
                if answer.status is None:
                    parsed = _parse(data, at_eof=True)
                    if parsed is not None:
                        answer.status, answer.headers, answer.body = parsed
                break
            data += chunk
    return answer


def _parse(data: bytes, at_eof: bool = False) -> tuple[int, dict[str, str], bytes] | None:
    """The first final answer in `data` (interim 1xx answers skipped), or None while it is incomplete."""
    while True:
        end = data.find(b"\r\n\r\n")
        if end < 0:
            return None
        lines = data[:end].decode("latin-1").split("\r\n")
        try:
            status = int(lines[0].split(" ", 2)[1])
        except (IndexError, ValueError):
            return None
        headers = {}
        for line in lines[1:]:
            name, _, value = line.partition(":")
            headers[name.strip().lower()] = value.strip()
        rest = data[end + 4:]
        if 100 <= status < 200:
            data = rest
            continue
        if "content-length" in headers:
            length = int(headers["content-length"])
            return (status, headers, rest[:length]) if len(rest) >= length else None
        if headers.get("transfer-encoding", "").lower() == "chunked":
            body = _dechunk(rest)
            return (status, headers, body) if body is not None else None
        return (status, headers, rest) if at_eof else None


def _dechunk(data: bytes) -> bytes | None:
    """A chunked body, or None while its last chunk has not arrived."""
    body = b""
    while True:
        end = data.find(b"\r\n")
        if end < 0:
            return None
        size = int(data[:end].split(b";")[0], 16)
        if size == 0:
            return body
        if len(data) < end + 2 + size + 2:
            return None
        body += data[end + 2:end + 2 + size]
        data = data[end + 2 + size + 2:]
