"""The tally-server HTTP client (docs/api.md), standard library only."""

from __future__ import annotations

import http.client
import json
import os
import socket
import ssl
import threading
import time
import urllib.parse
from dataclasses import dataclass
from types import TracebackType
from typing import Any, BinaryIO, Dict, Iterator, List, Mapping, Optional, Tuple, Type, Union

from .errors import Conflict, JobFailed, ProblemError, TallyConnectionError, problem_from_response
from .image import Image, decode_exr, image_from_tiles
from .packing import ScenePacker, sha256_file
from .result import JobResult

__all__ = ["Client", "Event", "TERMINAL_STATES", "DEFAULT_URL"]

DEFAULT_URL = "http://127.0.0.1:8080"

TERMINAL_STATES = frozenset({"succeeded", "failed", "cancelled"})
JsonObject = Dict[str, Any]

# Errors that mean "the connection broke" (as opposed to an HTTP error answer).
_NETWORK_ERRORS: Tuple[Type[Exception], ...] = (OSError, http.client.HTTPException)
# What a kept-alive connection the server has closed meanwhile gives on its next use:
# the request is sent again once on a new connection.
_STALE_CONNECTION: Tuple[Type[Exception], ...] = (http.client.RemoteDisconnected, ConnectionResetError,
                                                  BrokenPipeError, http.client.CannotSendRequest)


@dataclass(frozen=True)
class Event:
    """One event of a job's stream: ``state``, ``progress``, ``tile``, ``end`` or ``shutdown``."""

    id: int
    event: str
    data: JsonObject


class _Response:
    def __init__(self, status: int, headers: Dict[str, str], body: bytes):
        self.status = status
        self.headers = headers
        self.body = body

    def json(self) -> Any:
        return json.loads(self.body.decode("utf-8")) if self.body else None


class Client:
    """A client of one tally-server.

    ``url`` is the server's base URL (``http://127.0.0.1:8080``, ``https://host/prefix``);
    without it ``TALLY_SERVER`` is used, then ``http://127.0.0.1:8080``. ``token``, or else
    ``TALLY_TOKEN``, is sent as ``Authorization: Bearer <token>``. https uses the system's
    certificate store (``ssl.create_default_context()``) unless ``ssl_context`` is given.
    ``timeout`` bounds each request's connect and each read, in seconds.

    Requests reuse one kept-alive connection per thread (a connection the server closed
    meanwhile is replaced, and the request sent again once); event streams have their own.
    ``close()`` closes the calling thread's connection; ``with Client() as c:`` does it at
    the end. Instances may be shared between threads.

    Every method raises a :class:`~tally_client.errors.ProblemError` subclass for an
    HTTP error (with the server's ``status``, ``title``, ``detail``, ``pointer``) and
    :class:`~tally_client.errors.TallyConnectionError` when the server cannot be reached.
    """

    def __init__(self, url: Optional[str] = None, token: Optional[str] = None, *, timeout: float = 30.0,
                 ssl_context: Optional[ssl.SSLContext] = None):
        if url is None:
            url = os.environ.get("TALLY_SERVER") or DEFAULT_URL
        if token is None:
            token = os.environ.get("TALLY_TOKEN") or None
        parts = urllib.parse.urlsplit(url)
        if parts.scheme not in ("http", "https") or not parts.hostname:
            raise ValueError(f"url must be http://host[:port][/prefix] or https://..., got {url!r}")
        self.url = url.rstrip("/")
        self.token = token
        self.timeout = timeout
        self._https = parts.scheme == "https"
        self._host = parts.hostname
        self._port = parts.port or (443 if self._https else 80)
        self._prefix = parts.path.rstrip("/")
        self._ssl = ssl_context if ssl_context is not None else (ssl.create_default_context() if self._https else None)
        self._local = threading.local()
        self._lock = threading.Lock()
        self._conns: List[http.client.HTTPConnection] = []  # every thread's, for close()

    def __enter__(self) -> "Client":
        return self

    def __exit__(self, exc_type: Optional[Type[BaseException]], exc: Optional[BaseException],
                 tb: Optional[TracebackType]) -> None:
        self.close()

    def close(self) -> None:
        """Closes the kept-alive connections of every thread (call it when no request is in
        flight); the next request opens a new one. Also done when the client is collected."""
        with self._lock:
            conns, self._conns = self._conns, []
        for conn in conns:
            conn.close()
        self._local.conn = None

    def __del__(self) -> None:
        if getattr(self, "_conns", None):  # not when __init__ refused the URL
            self.close()

    def __repr__(self) -> str:
        return f"Client({self.url!r}{', token=...' if self.token else ''})"

    # --- jobs ----------------------------------------------------------------------

    def submit(self, spec: Mapping[str, Any], *, priority: Optional[int] = None, base_dir: str = ".",
               upload: bool = True) -> str:
        """Submits a job spec (docs/jobs.md); returns the new job's id. ``priority``: -5..5.

        With ``upload`` (the default) the scene's local files, and the files they name, are
        uploaded first (only what the server lacks) and named by their hash, as ``tally
        submit`` does (see :meth:`upload_scene_assets`; relative names are taken relative to
        ``base_dir``). An error about an uploaded file names its local path, not its hash.
        """
        query = {"priority": str(priority)} if priority is not None else None
        if not upload:
            return str(self._json("POST", "/v1/jobs", body=spec, query=query)["id"])
        packer = self._packer(base_dir)
        sent = packer.pack_spec(spec)
        try:
            return str(self._json("POST", "/v1/jobs", body=sent, query=query)["id"])
        except ProblemError as e:
            raise _with_user_paths(e, packer) from None

    def validate(self, spec: Mapping[str, Any], *, base_dir: str = ".", upload: bool = True) -> JsonObject:
        """Dry run: the plan, a short pilot and the predicted samples and seconds per rule.
        Uploads the scene's files as :meth:`submit` does (unless ``upload`` is false)."""
        if not upload:
            return self._json("POST", "/v1/jobs/validate", body=spec)
        packer = self._packer(base_dir)
        sent = packer.pack_spec(spec)
        try:
            return self._json("POST", "/v1/jobs/validate", body=sent)
        except ProblemError as e:
            raise _with_user_paths(e, packer) from None

    def status(self, job_id: str) -> JobResult:
        """The status document of a job (state, estimate, prediction, timing, ...), a dict
        with typed accessors (``.mean``, ``.sdev``, ``.ci``, ``.state``; see JobResult)."""
        return JobResult(self._json("GET", f"/v1/jobs/{_segment(job_id)}"))

    def list(self, state: Optional[str] = None, *, page_size: Optional[int] = None) -> List[JsonObject]:
        """Job summaries in submission order, optionally only those in ``state``.

        The server answers in pages (``limit``, default 100); this follows every page's
        ``next`` link and returns them all. ``page_size`` sets ``limit`` (1 to 1000).
        """
        query: Dict[str, str] = {}
        if state is not None:
            query["state"] = state
        if page_size is not None:
            query["limit"] = str(int(page_size))
        page = self._json("GET", "/v1/jobs", query=query or None)
        jobs = list(page["jobs"])
        while page.get("next"):
            # The link is server-relative and keeps the query (state, limit, cursor).
            path, _, qs = str(page["next"]).partition("?")
            page = self._json("GET", path, query=dict(urllib.parse.parse_qsl(qs)))
            jobs.extend(page["jobs"])
        return jobs

    def cancel(self, job_id: str) -> JsonObject:
        """Cancels a queued or running job: its summary (state ``cancelled``, or still
        ``running`` until the next chunk boundary). A job that has already finished is
        left alone: :class:`Conflict` (409) says so (``tally cancel`` refuses the same way;
        :meth:`delete` deletes a finished job). If the job finishes between the check and
        the request, the server deletes it and {} is returned."""
        state = self.status(job_id).state
        if state in TERMINAL_STATES:
            raise Conflict(409, {"title": "Conflict", "status": 409,
                                 "detail": f"job {job_id} has already finished ({state}); delete() deletes it"})
        return self._json("DELETE", f"/v1/jobs/{_segment(job_id)}")

    def delete(self, job_id: str) -> None:
        """Deletes a finished job and its stored state (then it is NotFound). A job that
        still runs is cancelled instead: call it again once it has finished."""
        self._request("DELETE", f"/v1/jobs/{_segment(job_id)}")

    def extend(self, job_id: str, *, max_samples: Optional[int] = None, abs_error: Optional[float] = None,
               rel_error: Optional[float] = None, time_budget_s: Optional[float] = None) -> JsonObject:
        """Reopens a finished job with new targets (totals over the job's life)."""
        body = {k: v for k, v in (("max_samples", max_samples), ("abs_error", abs_error),
                                  ("rel_error", rel_error), ("time_budget_s", time_budget_s)) if v is not None}
        if not body:
            raise ValueError("extend needs at least one of max_samples, abs_error, rel_error, time_budget_s")
        return self._json("POST", f"/v1/jobs/{_segment(job_id)}/extend", body=body)

    def set_priority(self, job_id: str, priority: int) -> JsonObject:
        """Changes a queued or running job's priority (-5..5, ``PATCH /v1/jobs/{id}``): its
        place in the queue and its share of the workers from now on. Returns the job's
        summary. A finished job is :class:`Conflict` (409); a value out of range the
        server's 422 naming ``/priority``."""
        return self._json("PATCH", f"/v1/jobs/{_segment(job_id)}", body={"priority": priority})

    def wait(self, job_id: str, timeout: Optional[float] = None, *, raise_on_failure: bool = True,
             reconnect_timeout: float = 60.0) -> JobResult:
        """Follows the job's event stream until it ends; returns the final status document
        (a :class:`JobResult`: ``.mean``, ``.sdev``, ``.ci``, or as a dict).

        A job that ends ``failed`` or ``cancelled`` raises :class:`JobFailed` (its
        ``result`` is the status) unless ``raise_on_failure`` is false. Raises TimeoutError
        when ``timeout`` seconds pass first (the job keeps running). A dropped connection is
        resumed as in :meth:`events`.
        """
        deadline = None if timeout is None else time.monotonic() + timeout
        for ev in self._events(job_id, None, reconnect_timeout, deadline):
            if ev is not None and ev.event == "end":
                result = self.status(job_id)
                if raise_on_failure and result.state in ("failed", "cancelled"):
                    raise JobFailed(result)
                return result
        raise TimeoutError(f"job {job_id} did not finish within {timeout} s")  # pragma: no cover

    def events(self, job_id: str, *, last_event_id: Optional[int] = None,
               reconnect_timeout: float = 60.0) -> Iterator[Event]:
        """The job's live events, as a generator; it returns after the ``end`` event.

        A new stream starts with a snapshot (``state``, the latest ``progress``, ``end``
        if finished). When the connection drops (or the server restarts: ``shutdown``
        event), the generator reconnects with ``Last-Event-ID`` and carries on with the
        events after the last one it yielded, retrying for up to ``reconnect_timeout``
        seconds before raising TallyConnectionError. Pass ``last_event_id`` to resume a
        stream read earlier.
        """
        for ev in self._events(job_id, last_event_id, reconnect_timeout, None):
            if ev is not None:
                yield ev

    # --- images --------------------------------------------------------------------

    def tile(self, job_id: str, n: int) -> JsonObject:
        """One tile of an image job: x, y, w, h, pass, mean, std_error, samples (flat lists)."""
        return self._json("GET", f"/v1/jobs/{_segment(job_id)}/tiles/{int(n)}")

    def image(self, job_id: str, *, source: str = "tiles") -> Image:
        """The job's current image (mean, standard error and samples per pixel).

        ``source="tiles"`` assembles it from the tiles endpoint; ``source="exr"`` decodes
        the server's EXR (one request, plus the ``tally:*`` metadata). Both give the same
        float32 values. The tiles are read one by one, so on a running job they may come
        from different passes.
        """
        if source == "exr":
            return decode_exr(self.image_bytes(job_id, "exr"))
        if source != "tiles":
            raise ValueError(f"source must be 'tiles' or 'exr', got {source!r}")
        st = self.status(job_id)
        geometry = (st.get("plan") or {}).get("image")
        if not geometry:
            raise ValueError(f"job {job_id} has no image (its plan has no 'image')")
        tiles = [self.tile(job_id, n) for n in range(int(geometry["tiles"]))]
        return image_from_tiles(int(geometry["width"]), int(geometry["height"]), tiles)

    def image_bytes(self, job_id: str, fmt: str = "exr") -> bytes:
        """The server's image file: ``"exr"`` (float, with errors and counts) or ``"png"`` (preview)."""
        if fmt not in ("exr", "png"):
            raise ValueError(f"fmt must be 'exr' or 'png', got {fmt!r}")
        return self._request("GET", f"/v1/jobs/{_segment(job_id)}/image.{fmt}").body

    # --- assets --------------------------------------------------------------------

    def has_asset(self, ref: str) -> bool:
        """Whether the server stores the asset ``"sha256:<hex>"`` for this caller (HEAD)."""
        resp = self._exchange("HEAD", f"/v1/assets/{ref}", None, None, self._headers(), self.timeout)
        if resp.status == 404:
            return False
        if resp.status >= 400:
            raise problem_from_response(resp.status, b"", resp.headers)
        return True

    def upload_asset(self, path: str, *, skip_if_present: bool = True) -> str:
        """Uploads a file to the server's asset store and returns its name, ``"sha256:<hex>"``
        (what a scene uses wherever it names a file). The file is streamed, never read whole
        into memory; with ``skip_if_present`` a HEAD first avoids sending what the server has.
        The file is sent as it is: :meth:`upload_scene_assets` also packs the files it names."""
        ref = "sha256:" + sha256_file(path)
        if skip_if_present and self.has_asset(ref):
            return ref
        self._put_asset(ref, path, None)
        return ref

    def upload_scene_assets(self, spec: Mapping[str, Any], base_dir: str = ".") -> JsonObject:
        """A copy of ``spec`` whose local files are uploaded (only those the server lacks)
        and named by their hash, as ``tally submit`` does (tally_client.packing): the scene
        fields ``obj``, ``file`` and ``map`` (relative to ``base_dir``), a glTF's buffers and
        images (.gltf or .glb), an OBJ's ``mtllib`` files and their ``map_Kd`` textures.
        A file that names others is uploaded with those names rewritten. Spec names that
        are not local files are left alone; a file named inside a packed file that cannot be
        read raises :class:`~tally_client.packing.PackError` naming both files."""
        return self._packer(base_dir).pack_spec(spec)

    def _packer(self, base_dir: str) -> ScenePacker:
        def put_file(ref: str, path: str) -> None:
            if not self.has_asset(ref):
                self._put_asset(ref, path, None)

        def put_bytes(ref: str, data: bytes, origin: str) -> None:
            if not self.has_asset(ref):
                self._put_asset(ref, origin, data)

        return ScenePacker(put_file, put_bytes, base_dir)

    def _put_asset(self, ref: str, path: str, data: Optional[bytes]) -> None:
        size = len(data) if data is not None else os.path.getsize(path)
        headers = self._headers({"Content-Type": "application/octet-stream", "Content-Length": str(size)})
        if data is not None:
            resp = self._exchange("PUT", f"/v1/assets/{ref}", None, data, headers, self.timeout + size / 2e6)
        else:
            with open(path, "rb") as f:
                resp = self._exchange("PUT", f"/v1/assets/{ref}", None, f, headers, self.timeout + size / 2e6)
        if resp.status >= 400:
            raise _with_path(problem_from_response(resp.status, resp.body, resp.headers), ref, path)

    # --- HTTP ----------------------------------------------------------------------

    def _connection(self, timeout: float) -> http.client.HTTPConnection:
        if self._https:
            return http.client.HTTPSConnection(self._host, self._port, timeout=timeout, context=self._ssl)
        return http.client.HTTPConnection(self._host, self._port, timeout=timeout)

    def _headers(self, extra: Optional[Mapping[str, str]] = None) -> Dict[str, str]:
        h = {"Accept": "application/json", "User-Agent": "tally_client-python"}
        if self.token:
            h["Authorization"] = f"Bearer {self.token}"
        if extra:
            h.update(extra)
        return h

    def _target(self, path: str, query: Optional[Mapping[str, str]]) -> str:
        return self._prefix + path + ("?" + urllib.parse.urlencode(query) if query else "")

    def _request(self, method: str, path: str, *, body: Any = None, query: Optional[Mapping[str, str]] = None,
                 raw_body: Optional[bytes] = None, headers: Optional[Mapping[str, str]] = None) -> _Response:
        data = raw_body
        extra: Dict[str, str] = {}
        if body is not None:
            data = json.dumps(body).encode("utf-8")
            extra["Content-Type"] = "application/json"
        if headers:
            extra.update(headers)
        resp = self._exchange(method, path, query, data, self._headers(extra), self.timeout)
        if resp.status >= 400:
            raise problem_from_response(resp.status, resp.body, resp.headers)
        return resp

    def _exchange(self, method: str, path: str, query: Optional[Mapping[str, str]],
                  body: Optional[Union[bytes, BinaryIO]], headers: Mapping[str, str], timeout: float) -> _Response:
        """One request on the thread's kept-alive connection and the whole answer, whatever
        its status (a file body is streamed); a network failure is a TallyConnectionError.
        A reused connection the server has closed is replaced and the request sent once more."""
        target = self._target(path, query)
        start = body.tell() if body is not None and not isinstance(body, bytes) else 0
        for attempt in (0, 1):
            conn: Optional[http.client.HTTPConnection] = getattr(self._local, "conn", None)
            reused = conn is not None
            if conn is None:
                conn = self._connection(timeout)
                self._local.conn = conn
                with self._lock:
                    self._conns.append(conn)
            conn.timeout = timeout
            if conn.sock is not None:
                conn.sock.settimeout(timeout)
            try:
                conn.request(method, target, body=body, headers=dict(headers))
                resp = conn.getresponse()
                payload = resp.read()
            except _NETWORK_ERRORS as e:
                self._forget(conn)
                if reused and attempt == 0 and isinstance(e, _STALE_CONNECTION):
                    if body is not None and not isinstance(body, bytes):
                        body.seek(start)
                    continue
                raise TallyConnectionError(f"{method} {self.url}{path}: {e}") from e
            if resp.will_close:
                self._forget(conn)
            return _Response(resp.status, {k.lower(): v for k, v in resp.getheaders()}, payload)
        raise AssertionError("unreachable")  # pragma: no cover

    def _forget(self, conn: http.client.HTTPConnection) -> None:
        conn.close()
        self._local.conn = None
        with self._lock:
            if conn in self._conns:
                self._conns.remove(conn)

    def _json(self, method: str, path: str, **kw: Any) -> JsonObject:
        out = self._request(method, path, **kw).json()
        if out is None:  # 204 No Content
            return {}
        return out if isinstance(out, dict) else {"value": out}

    def _events(self, job_id: str, last_event_id: Optional[int], reconnect_timeout: float,
                deadline: Optional[float]) -> Iterator[Optional[Event]]:
        """Events, with None for every comment/heartbeat (lets wait() check its deadline)."""
        last = last_event_id
        broken_since: Optional[float] = None
        delay = 0.05
        while True:
            if deadline is not None and time.monotonic() >= deadline:
                raise TimeoutError(f"job {job_id}: no end event before the deadline")
            headers = {"Accept": "text/event-stream"}
            resumed_after = last  # events up to this id were yielded already
            if last is not None:
                headers["Last-Event-ID"] = str(last)
            read_timeout = max(self.timeout, 60.0)  # > the server's 15 s heartbeat
            if deadline is not None:
                read_timeout = max(0.05, min(read_timeout, deadline - time.monotonic()))
            conn = self._connection(read_timeout)
            ended = False
            try:
                try:
                    conn.request("GET", self._target(f"/v1/jobs/{_segment(job_id)}/events", None),
                                 headers=self._headers(headers))
                    resp = conn.getresponse()
                except _NETWORK_ERRORS as e:
                    err: Exception = e
                else:
                    if resp.status >= 400:
                        raise problem_from_response(resp.status, resp.read(),
                                                    {k.lower(): v for k, v in resp.getheaders()})
                    try:
                        for ev in _parse_sse(resp):
                            if ev is None:
                                yield None
                                if deadline is not None and time.monotonic() >= deadline:
                                    raise TimeoutError(f"job {job_id}: no end event before the deadline")
                                continue
                            broken_since = None
                            delay = 0.05
                            # A resumed stream may start with a fresh snapshot of what was
                            # yielded already. (The events of one snapshot may share an id.)
                            if resumed_after is not None and ev.id <= resumed_after and ev.event != "end":
                                continue
                            last = ev.id if last is None else max(last, ev.id)
                            yield ev
                            if ev.event == "end":
                                ended = True
                                return
                            if deadline is not None and time.monotonic() >= deadline:
                                raise TimeoutError(f"job {job_id}: no end event before the deadline")
                        err = TallyConnectionError("the event stream closed before the job's end event")
                    except socket.timeout as e:
                        if deadline is not None and time.monotonic() >= deadline:
                            raise TimeoutError(f"job {job_id}: no end event before the deadline") from e
                        err = e
                    except _NETWORK_ERRORS as e:
                        err = e
            finally:
                conn.close()
            if ended:
                return
            # Broken or closed (e.g. after `shutdown`): resume after `last`.
            now = time.monotonic()
            if broken_since is None:
                broken_since = now
            if now - broken_since > reconnect_timeout:
                raise TallyConnectionError(
                    f"event stream of job {job_id} lost for {reconnect_timeout} s (last event id {last}): {err}") from err
            time.sleep(delay)
            delay = min(delay * 2, 1.0)


def _with_user_paths(e: ProblemError, packer: ScenePacker) -> ProblemError:
    """The same error with the hashes the packer gave files replaced by their paths."""
    problem = dict(e.problem)
    if isinstance(problem.get("detail"), str):
        problem["detail"] = packer.with_user_paths(problem["detail"])
    return type(e)(e.status, problem, e.headers)


def _with_path(e: ProblemError, ref: str, path: str) -> ProblemError:
    problem = dict(e.problem)
    problem["detail"] = f"uploading {path} ({ref}): {problem.get('detail', '')}"
    return type(e)(e.status, problem, e.headers)


def _segment(job_id: str) -> str:
    return urllib.parse.quote(str(job_id), safe="")


def _parse_sse(resp: http.client.HTTPResponse) -> Iterator[Optional[Event]]:
    """Server-sent events (WHATWG): id/event/data fields, a blank line dispatches.
    An event cut off by a dropped connection is never dispatched."""
    ev_id: Optional[int] = None
    ev_type = "message"
    data: List[str] = []
    while True:
        raw = resp.readline()
        if not raw:
            return
        if not raw.endswith(b"\n"):
            return  # truncated last line: the connection broke mid-event
        line = raw.decode("utf-8").rstrip("\r\n")
        if line == "":
            if data:
                yield Event(ev_id if ev_id is not None else 0, ev_type, json.loads("\n".join(data)))
            ev_type, data = "message", []
            continue
        if line.startswith(":"):
            yield None  # heartbeat
            continue
        name, _, value = line.partition(":")
        if value.startswith(" "):
            value = value[1:]
        if name == "id":
            try:
                ev_id = int(value)
            except ValueError:
                pass
        elif name == "event":
            ev_type = value
        elif name == "data":
            data.append(value)

