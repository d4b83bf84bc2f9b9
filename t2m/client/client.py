"""T2MClient (sync) and AsyncT2MClient (async): the t2m HTTP API in Python, on httpx.

    with T2MClient("http://127.0.0.1:8000") as t2m:
        motion = t2m.generate([("a person walks forward", 3.0), ("a person waves", 2.0)], seed=1)
        motion.frames.shape          # (100, 22, 3), metres
        t2m.save_bvh("wave.bvh", [("a person waves", 2.0)])
        for item in t2m.generate_stream([("a person walks forward", 10.0)]):   # frames as they are made
            if isinstance(item, FrameChunk):
                play(item.frames)    # [n, 22, 3], frames item.start_frame.. of the motion
            else:
                motion = item        # the whole Motion, last
        bow = t2m.edit(motion, [Regenerate(2, text="a person bows deeply")])   # the other segments kept
"""
from __future__ import annotations

from collections.abc import AsyncIterator, Iterator, Sequence
from pathlib import Path
from typing import Any

import httpx

from t2m.client._common import (
    DEFAULT_TIMEOUT_S,
    DEFAULT_URL,
    StreamReader,
    auth_headers,
    connection_errors,
    edit_body,
    raise_for_answer,
    raw_result,
    request_body,
    stream_body,
)
from t2m.client.models import EditLike, FrameChunk, Health, Motion, RawResult, SegmentsLike, Upload

__all__ = ["AsyncT2MClient", "T2MClient"]


class T2MClient:
    """Synchronous client. `api_key` is sent as a bearer token; `transport` lets tests plug in any httpx transport."""

    def __init__(self, base_url: str = DEFAULT_URL, *, api_key: str | None = None,
                 timeout: float = DEFAULT_TIMEOUT_S, transport: httpx.BaseTransport | None = None) -> None:
        self._http = httpx.Client(base_url=base_url, timeout=timeout, headers=auth_headers(api_key),
                                  transport=transport)

    def __enter__(self) -> T2MClient:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        self._http.close()

    def _send(self, method: str, path: str, **kwargs: Any) -> httpx.Response:
        with connection_errors(self._http):
            response = self._http.request(method, path, **kwargs)
        raise_for_answer(response)
        return response

    def health(self) -> Health:
        """The server's readiness (a loading server answers status 'loading' rather than raising)."""
        with connection_errors(self._http):
            response = self._http.get("/health")
        if response.status_code == 503:
            return Health.from_json(response.json())
        raise_for_answer(response)
        return Health.from_json(response.json())

    def generate(self, segments: SegmentsLike, *, seed: int | None = None, guidance: float | None = None,
                 temperature: float = 1.0, top_k: int | None = None, model: str | None = None) -> Motion:
        """Joint positions of one continuous motion for the sentences; `model` names a served model
        (`health().model_names`), None = the server's default."""
        body = request_body(segments, "json", seed, guidance, temperature, top_k, model)
        return Motion.from_json(self._send("POST", "/generate", json=body).json())

    def edit(self, motion: Motion | str | Upload, edits: Sequence[EditLike] = (), *,
             model: str | None = None) -> Motion:
        """A motion (or its handle, or an Upload of frames or a BVH file to encode) with some segments changed
        (Regenerate(i, text=..., seed=...), Append([...]), Prepend([...])) and the others kept; no edits gives the
        motion back. The answer has a handle of its own."""
        return Motion.from_json(self._send("POST", "/edit", json=edit_body(motion, edits, "json", model)).json())

    def edit_raw(self, motion: Motion | str | Upload, edits: Sequence[EditLike], fmt: str, *,
                 model: str | None = None) -> RawResult:
        """The edited motion as a 'bvh' | 'glb' | 'json' file."""
        return raw_result(self._send("POST", "/edit", json=edit_body(motion, edits, fmt, model)))

    def generate_stream(self, segments: SegmentsLike, *, seed: int | None = None, guidance: float | None = None,
                        temperature: float = 1.0, top_k: int | None = None,
                        model: str | None = None) -> Iterator[FrameChunk | Motion]:
        """The motion of `generate` as it is made: FrameChunks as their frames become final, then the whole Motion.
        A refused request raises (ValidationError, OverloadedError, ...) when the iteration starts; a failure after
        the first frames raises ServerError there."""
        reader = StreamReader()
        with connection_errors(self._http), self._http.stream("POST", "/generate", json=stream_body(
                segments, seed, guidance, temperature, top_k, model)) as response:
            if response.status_code != 200:
                response.read()
                raise_for_answer(response)
            for line in response.iter_lines():
                if (item := reader.feed(line)) is not None:
                    yield item
        reader.finish()

    def generate_raw(self, segments: SegmentsLike, fmt: str, *, seed: int | None = None,
                     guidance: float | None = None, temperature: float = 1.0, top_k: int | None = None,
                     model: str | None = None) -> RawResult:
        """The file in format 'bvh' | 'glb' | 'json' as bytes, with the seed the server used."""
        body = request_body(segments, fmt, seed, guidance, temperature, top_k, model)
        return raw_result(self._send("POST", "/generate", json=body))

    def generate_bvh(self, segments: SegmentsLike, **options: Any) -> str:
        return self.generate_raw(segments, "bvh", **options).content.decode("utf-8")

    def generate_glb(self, segments: SegmentsLike, **options: Any) -> bytes:
        return self.generate_raw(segments, "glb", **options).content

    def save_bvh(self, path: str | Path, segments: SegmentsLike, **options: Any) -> Path:
        path = Path(path)
        path.write_text(self.generate_bvh(segments, **options), encoding="utf-8")
        return path

    def save_glb(self, path: str | Path, segments: SegmentsLike, **options: Any) -> Path:
        path = Path(path)
        path.write_bytes(self.generate_glb(segments, **options))
        return path


class AsyncT2MClient:
    """Asynchronous client with the same methods as T2MClient (awaitable)."""

    def __init__(self, base_url: str = DEFAULT_URL, *, api_key: str | None = None,
                 timeout: float = DEFAULT_TIMEOUT_S, transport: httpx.AsyncBaseTransport | None = None) -> None:
        self._http = httpx.AsyncClient(base_url=base_url, timeout=timeout, headers=auth_headers(api_key),
                                       transport=transport)

    async def __aenter__(self) -> AsyncT2MClient:
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.aclose()

    async def aclose(self) -> None:
        await self._http.aclose()

    async def _send(self, method: str, path: str, **kwargs: Any) -> httpx.Response:
        with connection_errors(self._http):
            response = await self._http.request(method, path, **kwargs)
        raise_for_answer(response)
        return response

    async def health(self) -> Health:
        with connection_errors(self._http):
            response = await self._http.get("/health")
        if response.status_code == 503:
            return Health.from_json(response.json())
        raise_for_answer(response)
        return Health.from_json(response.json())

    async def generate(self, segments: SegmentsLike, *, seed: int | None = None, guidance: float | None = None,
                       temperature: float = 1.0, top_k: int | None = None, model: str | None = None) -> Motion:
        body = request_body(segments, "json", seed, guidance, temperature, top_k, model)
        return Motion.from_json((await self._send("POST", "/generate", json=body)).json())

    async def edit(self, motion: Motion | str | Upload, edits: Sequence[EditLike] = (), *,
                   model: str | None = None) -> Motion:
        body = edit_body(motion, edits, "json", model)
        return Motion.from_json((await self._send("POST", "/edit", json=body)).json())

    async def edit_raw(self, motion: Motion | str | Upload, edits: Sequence[EditLike], fmt: str, *,
                       model: str | None = None) -> RawResult:
        return raw_result(await self._send("POST", "/edit", json=edit_body(motion, edits, fmt, model)))

    async def generate_stream(self, segments: SegmentsLike, *, seed: int | None = None,
                              guidance: float | None = None, temperature: float = 1.0, top_k: int | None = None,
                              model: str | None = None) -> AsyncIterator[FrameChunk | Motion]:
        """`async for item in client.generate_stream(...)`: FrameChunks, then the whole Motion (as T2MClient's)."""
        reader = StreamReader()
        with connection_errors(self._http):
            async with self._http.stream("POST", "/generate", json=stream_body(segments, seed, guidance, temperature,
                                                                                  top_k, model)) as response:
                if response.status_code != 200:
                    await response.aread()
                    raise_for_answer(response)
                async for line in response.aiter_lines():
                    if (item := reader.feed(line)) is not None:
                        yield item
        reader.finish()

    async def generate_raw(self, segments: SegmentsLike, fmt: str, *, seed: int | None = None,
                           guidance: float | None = None, temperature: float = 1.0,
                           top_k: int | None = None, model: str | None = None) -> RawResult:
        body = request_body(segments, fmt, seed, guidance, temperature, top_k, model)
        return raw_result(await self._send("POST", "/generate", json=body))

    async def generate_bvh(self, segments: SegmentsLike, **options: Any) -> str:
        return (await self.generate_raw(segments, "bvh", **options)).content.decode("utf-8")

    async def generate_glb(self, segments: SegmentsLike, **options: Any) -> bytes:
        return (await self.generate_raw(segments, "glb", **options)).content

    async def save_bvh(self, path: str | Path, segments: SegmentsLike, **options: Any) -> Path:
        path = Path(path)
        path.write_text(await self.generate_bvh(segments, **options), encoding="utf-8")
        return path

    async def save_glb(self, path: str | Path, segments: SegmentsLike, **options: Any) -> Path:
        path = Path(path)
        path.write_bytes(await self.generate_glb(segments, **options))
        return path
