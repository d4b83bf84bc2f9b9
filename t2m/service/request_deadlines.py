"""Deadlines for receiving a request, which uvicorn lacks: half-sent requests no longer hold connections.

uvicorn times out only idle keep-alive connections, and only after a response: a client that opens a connection and
sends part of its headers (or dribbles them a byte at a time, or declares a Content-Length it never sends) keeps the
connection, and with a half-sent body an app task, open for ever - 3,000 such connections were still open 70 s later.
No uvicorn option covers it (`timeout_keep_alive` is cancelled by every byte received; its issue #157 asks for a
request-start timeout), and ASGI middleware cannot, since the app only sees a request once its headers are complete.

`DeadlineHTTPProtocol` is uvicorn's own HTTP protocol (httptools, else h11, as uvicorn's "auto" picks) with a
watchdog around it: a request's headers must be complete `T2M_HEADER_TIMEOUT_S` after the connection opened or the
request's first byte arrived, its body `T2M_BODY_TIMEOUT_S` after the headers. A deadline is absolute (dribbled bytes
do not extend it). When one passes, the client gets a 408 JSON answer and the connection is closed; an app task
waiting for the body sees a disconnect. Generating and sending the answer is never timed here (that is
T2M_REQUEST_TIMEOUT_S). A request uvicorn cannot parse gets a JSON 400 here (uvicorn's own is text/plain), like
every other error of the service. `t2m serve` passes the class to uvicorn by its import path (`http=`), which works
with any number of workers; each process reads the two settings from the environment once.
"""
from __future__ import annotations

import asyncio
import functools
import json
import logging
from typing import Any, Literal, cast

from uvicorn.protocols.http.auto import AutoHTTPProtocol

__all__ = ["IMPORT_PATH", "DeadlineHTTPProtocol", "deadline_protocol"]

IMPORT_PATH = "t2m.service.request_deadlines:DeadlineHTTPProtocol"
ABORT_AFTER_S = 1.0   # a closed connection whose 408 cannot be flushed (the client reads nothing) is then dropped

log = logging.getLogger("service")

Phase = Literal["headers", "body", "app"]


@functools.cache
def _timeouts_from_env() -> tuple[float, float]:
    """(header, body) seconds from T2M_HEADER_TIMEOUT_S and T2M_BODY_TIMEOUT_S, read once per process."""
    from t2m.service.settings import Settings

    settings = Settings()
    return settings.header_timeout_s, settings.body_timeout_s


def _json_answer(status_line: bytes, detail: str) -> bytes:
    """A whole HTTP/1.1 response with a JSON body, ending the connection."""
    body = json.dumps({"detail": detail}).encode()
    return (b"HTTP/1.1 " + status_line + b"\r\ncontent-type: application/json\r\nconnection: close\r\n"
            b"content-length: " + str(len(body)).encode() + b"\r\n\r\n" + body)


def _answer_408(what: str, seconds: float, setting: str) -> bytes:
    return _json_answer(b"408 Request Timeout", f"request {what} not complete within {seconds:g} s ({setting})")


class DeadlineHTTPProtocol(asyncio.Protocol):
    """uvicorn's HTTP protocol for one connection, closed with 408 when a request's headers or body arrive too late.

    The phase comes from uvicorn's request cycle (`cycle`, the same attributes in its httptools and h11 protocols):
    no cycle or an answered one = the next request's headers are awaited; `more_body` = its body is; else the app
    runs and nothing is timed. Each phase of each request gets one deadline, armed when the phase is first seen.
    """

    header_timeout_s: float | None = None   # None: T2M_HEADER_TIMEOUT_S
    body_timeout_s: float | None = None     # None: T2M_BODY_TIMEOUT_S

    def __init__(self, config: Any, server_state: Any, app_state: dict[str, Any],
                 _loop: asyncio.AbstractEventLoop | None = None) -> None:
        inner: Any = AutoHTTPProtocol(config=config, server_state=server_state,  # type: ignore[call-arg]
                                      app_state=app_state, _loop=_loop)
        # uvicorn answers a request it cannot parse with text/plain; every error of the service is JSON
        inner.send_400_response = self._answer_400
        self._inner = inner
        self._loop = _loop or asyncio.get_event_loop()
        self._header_s = self.header_timeout_s if self.header_timeout_s is not None else _timeouts_from_env()[0]
        self._body_s = self.body_timeout_s if self.body_timeout_s is not None else _timeouts_from_env()[1]
        self._transport: asyncio.Transport | None = None
        self._armed: tuple[Phase, object] | None = None
        self._timer: asyncio.TimerHandle | None = None
        self._lost = False

    # asyncio.Protocol, forwarded to uvicorn's protocol; the phase is looked at after each event
    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        self._transport = cast(asyncio.Transport, transport)   # uvloop's transports do not subclass asyncio's
        self._inner.connection_made(transport)
        self._watch()

    def data_received(self, data: bytes) -> None:
        self._inner.data_received(data)
        self._watch()

    def eof_received(self) -> bool | None:
        return self._inner.eof_received()

    def connection_lost(self, exc: Exception | None) -> None:
        self._lost = True
        self._disarm()
        self._inner.connection_lost(exc)

    def pause_writing(self) -> None:
        self._inner.pause_writing()

    def resume_writing(self) -> None:
        self._inner.resume_writing()

    def _answer_400(self, message: str) -> None:
        if self._transport is not None and not self._transport.is_closing():
            self._transport.write(_json_answer(b"400 Bad Request", message))
            self._transport.close()

    # the watchdog
    def _phase(self) -> tuple[Phase, object]:
        cycle = getattr(self._inner, "cycle", None)
        if cycle is None or cycle.response_complete:
            return "headers", cycle
        return ("body" if cycle.more_body else "app"), cycle

    def _watch(self) -> None:
        """A new phase ends the running deadline and, unless the app runs, starts its own."""
        phase = self._phase()
        if phase == self._armed or self._lost:
            return
        self._disarm()
        self._armed = phase
        if phase[0] != "app":
            seconds = self._header_s if phase[0] == "headers" else self._body_s
            self._timer = self._loop.call_later(seconds, self._expire, phase)

    def _disarm(self) -> None:
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None
        self._armed = None

    def _expire(self, phase: tuple[Phase, object]) -> None:
        self._timer = None
        transport = self._transport
        if (self._lost or transport is None or transport.is_closing() or transport.get_protocol() is not self
                or self._phase() != phase):   # closed, upgraded, or moved on without a byte (an answer sent)
            return
        cycle: Any = phase[1]
        if phase[0] == "headers":
            transport.write(_answer_408("headers", self._header_s, "T2M_HEADER_TIMEOUT_S"))
        elif not cycle.response_started:
            transport.write(_answer_408("body", self._body_s, "T2M_BODY_TIMEOUT_S"))
        log.info("closed a connection from %s: request %s not complete in time", _peer(transport), phase[0])
        transport.close()   # the app's receive() then answers http.disconnect (uvicorn's connection_lost)
        self._loop.call_later(ABORT_AFTER_S, self._abort_if_open, transport)

    def _abort_if_open(self, transport: asyncio.Transport) -> None:
        if not self._lost:
            transport.abort()


def _peer(transport: asyncio.Transport) -> str:
    peer = transport.get_extra_info("peername")
    return f"{peer[0]}:{peer[1]}" if isinstance(peer, tuple) and len(peer) >= 2 else "?"


def deadline_protocol(header_timeout_s: float, body_timeout_s: float) -> type[DeadlineHTTPProtocol]:
    """The protocol with these deadlines instead of the environment's (an in-process uvicorn, one worker)."""
    return type("DeadlineHTTPProtocol", (DeadlineHTTPProtocol,),
                {"header_timeout_s": header_timeout_s, "body_timeout_s": body_timeout_s})
