"""The asyncio variant of :class:`~tally_client.Client`: the same methods as coroutines.

Each call runs the blocking client in a worker thread (``asyncio.to_thread``), so an event
loop is never blocked and several calls may run at once (each worker thread keeps its own
kept-alive connection). ``events()`` is an async generator fed by one thread per stream.
Standard library only.
"""

from __future__ import annotations

import asyncio
import ssl
import threading
from types import TracebackType
from typing import Any, AsyncIterator, List, Mapping, Optional, Type

from .client import Client, Event, JsonObject
from .image import Image
from .result import JobResult

__all__ = ["AsyncClient"]

_END = object()


class AsyncClient:
    """``async with AsyncClient(url, token) as c: job = await c.submit(spec); r = await c.wait(job)``.

    Arguments as for :class:`~tally_client.Client` (``TALLY_SERVER``/``TALLY_TOKEN`` when
    omitted); ``client`` is the blocking client underneath.
    """

    def __init__(self, url: Optional[str] = None, token: Optional[str] = None, *, timeout: float = 30.0,
                 ssl_context: Optional[ssl.SSLContext] = None):
        self.client = Client(url, token, timeout=timeout, ssl_context=ssl_context)

    async def __aenter__(self) -> "AsyncClient":
        return self

    async def __aexit__(self, exc_type: Optional[Type[BaseException]], exc: Optional[BaseException],
                        tb: Optional[TracebackType]) -> None:
        self.client.close()

    async def submit(self, spec: Mapping[str, Any], *, priority: Optional[int] = None, base_dir: str = ".",
                     upload: bool = True) -> str:
        return await asyncio.to_thread(self.client.submit, spec, priority=priority, base_dir=base_dir, upload=upload)

    async def validate(self, spec: Mapping[str, Any], *, base_dir: str = ".", upload: bool = True) -> JsonObject:
        return await asyncio.to_thread(self.client.validate, spec, base_dir=base_dir, upload=upload)

    async def status(self, job_id: str) -> JobResult:
        return await asyncio.to_thread(self.client.status, job_id)

    async def list(self, state: Optional[str] = None, *, page_size: Optional[int] = None) -> List[JsonObject]:
        return await asyncio.to_thread(self.client.list, state, page_size=page_size)

    async def cancel(self, job_id: str) -> JsonObject:
        return await asyncio.to_thread(self.client.cancel, job_id)

    async def delete(self, job_id: str) -> None:
        await asyncio.to_thread(self.client.delete, job_id)

    async def extend(self, job_id: str, *, max_samples: Optional[int] = None, abs_error: Optional[float] = None,
                     rel_error: Optional[float] = None, time_budget_s: Optional[float] = None) -> JsonObject:
        return await asyncio.to_thread(self.client.extend, job_id, max_samples=max_samples, abs_error=abs_error,
                                       rel_error=rel_error, time_budget_s=time_budget_s)

    async def set_priority(self, job_id: str, priority: int) -> JsonObject:
        return await asyncio.to_thread(self.client.set_priority, job_id, priority)

    async def wait(self, job_id: str, timeout: Optional[float] = None, *, raise_on_failure: bool = True,
                   reconnect_timeout: float = 60.0) -> JobResult:
        return await asyncio.to_thread(self.client.wait, job_id, timeout, raise_on_failure=raise_on_failure,
                                       reconnect_timeout=reconnect_timeout)

    async def image(self, job_id: str, *, source: str = "tiles") -> Image:
        return await asyncio.to_thread(self.client.image, job_id, source=source)

    async def image_bytes(self, job_id: str, fmt: str = "exr") -> bytes:
        return await asyncio.to_thread(self.client.image_bytes, job_id, fmt)

    async def upload_asset(self, path: str, *, skip_if_present: bool = True) -> str:
        return await asyncio.to_thread(self.client.upload_asset, path, skip_if_present=skip_if_present)

    async def events(self, job_id: str, *, last_event_id: Optional[int] = None,
                     reconnect_timeout: float = 60.0) -> AsyncIterator[Event]:
        """The job's live events (see Client.events); ends after ``end``. Leaving the loop
        early stops the reader thread at its next event or heartbeat."""
        loop = asyncio.get_running_loop()
        queue: "asyncio.Queue[object]" = asyncio.Queue()
        stop = threading.Event()

        def read() -> None:
            try:
                for ev in self.client.events(job_id, last_event_id=last_event_id,
                                             reconnect_timeout=reconnect_timeout):
                    loop.call_soon_threadsafe(queue.put_nowait, ev)
                    if stop.is_set():
                        return
                loop.call_soon_threadsafe(queue.put_nowait, _END)
            except BaseException as e:  # handed to the consumer, raised there
                loop.call_soon_threadsafe(queue.put_nowait, e)

        reader = threading.Thread(target=read, name=f"tally-events-{job_id}", daemon=True)
        reader.start()
        try:
            while True:
                item = await queue.get()
                if item is _END:
                    return
                if isinstance(item, BaseException):
                    raise item
                assert isinstance(item, Event)
                yield item
        finally:
            stop.set()
