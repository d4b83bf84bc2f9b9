"""A streamed generation seen from the event loop: the frames the engine's thread sends (GenerationRequest.on_frames),
then its Motion, in that order, within the request's time limit.

The engine calls the request's frame sink in its worker thread; each chunk is handed to the event loop with
call_soon_threadsafe, and so is the end (the batcher's Future resolving, after the last chunk), so the loop sees them
in the order the worker made them. Closing the stream before its end (the client went away) cancels the request, so
the engine stops spending CPU on it at its next step.
"""
from __future__ import annotations

import asyncio
import contextlib
from concurrent.futures import Future

import numpy as np

from t2m.runtime.scheduling import GenerationTimeout, QueuedWorkers
from t2m.runtime.types import GenerationRequest, Motion

__all__ = ["MotionStream"]


class _End:
    """The sentinel after the last chunk: the Future has resolved."""


class MotionStream:
    """Queues `request` on `batcher` (QueueFullError propagates) and yields its frame chunks, then its Motion."""

    def __init__(self, batcher: QueuedWorkers, request: GenerationRequest, timeout_s: float) -> None:
        self._loop = asyncio.get_running_loop()
        self._items: asyncio.Queue[np.ndarray | _End] = asyncio.Queue()
        self._timeout_s = timeout_s
        self._deadline = self._loop.time() + timeout_s
        self.request = request
        request.on_frames = self._from_engine
        self._future: Future = batcher.submit_nowait(request)
        self._future.add_done_callback(lambda _: self._from_engine(_End()))

    def _from_engine(self, item: np.ndarray | _End) -> None:
        """In the engine's thread: pass the item to the event loop (dropped when the loop has already closed)."""
        with contextlib.suppress(RuntimeError):   # raised when the loop has closed: nobody is listening any more
            self._loop.call_soon_threadsafe(self._items.put_nowait, item)

    async def next(self) -> np.ndarray | Motion:
        """The next chunk of frames (float32 [n, J, 3]), or the finished Motion. A failed generation raises its
        error; past the time limit the request is cancelled and GenerationTimeout raised."""
        try:
            item = await asyncio.wait_for(self._items.get(), max(0.0, self._deadline - self._loop.time()))
        except asyncio.TimeoutError:
            self.request.cancel()
            raise GenerationTimeout(f"generation did not finish within {self._timeout_s:g} s") from None
        if isinstance(item, _End):
            return self._future.result()
        return item

    def close(self) -> None:
        """Stop the generation if it is still running (harmless once it has finished)."""
        if not self._future.done():
            self.request.cancel()
