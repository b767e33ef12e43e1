"""Exceptions of the tally client.

Every HTTP error of tally-server is an RFC 9457 ``application/problem+json`` document
(``type``, ``title``, ``status``, ``detail`` and, for spec errors, ``pointer``). The
client raises it as a :class:`ProblemError` subclass chosen by the status code, so a
script can catch what it can handle (``except InvalidSpec as e: print(e.pointer)``).
A server that cannot be reached raises :class:`TallyConnectionError`.
"""

from __future__ import annotations

import json
from typing import Any, Dict, Mapping, Optional, Type

__all__ = [
    "TallyError",
    "TallyConnectionError",
    "ProblemError",
    "BadRequest",
    "Unauthorized",
    "Forbidden",
    "NotFound",
    "MethodNotAllowed",
    "Conflict",
    "PayloadTooLarge",
    "UnsupportedMediaType",
    "InvalidSpec",
    "HeaderTooLarge",
    "ServerError",
    "NotImplementedByServer",
    "ServiceUnavailable",
    "JobFailed",
    "problem_from_response",
]


class TallyError(Exception):
    """Base class of every error the client raises."""


class TallyConnectionError(TallyError, ConnectionError):
    """The server could not be reached, or the connection broke and could not be resumed."""


class JobFailed(TallyError):
    """``wait()`` saw the job end ``failed`` or ``cancelled``; ``result`` is its final status
    (a :class:`~tally_client.JobResult`), ``state`` and ``error_message`` say why."""

    def __init__(self, result: Mapping[str, Any]):
        self.result = result
        self.state = str(result.get("state", ""))
        self.error_message = str(result.get("error_message", "")) or None
        why = f": {self.error_message}" if self.error_message else ""
        super().__init__(f"job {result.get('id', '?')} {self.state}{why}")


class ProblemError(TallyError):
    """An HTTP error answered by the server, with its problem+json fields."""

    status: int
    title: str
    detail: str
    pointer: Optional[str]
    type: str
    problem: Dict[str, Any]
    headers: Dict[str, str]

    def __init__(self, status: int, problem: Mapping[str, Any], headers: Optional[Mapping[str, str]] = None):
        self.status = status
        self.problem = dict(problem)
        self.title = str(problem.get("title", ""))
        self.detail = str(problem.get("detail", ""))
        pointer = problem.get("pointer")
        self.pointer = pointer if isinstance(pointer, str) else None
        self.type = str(problem.get("type", "about:blank"))
        self.headers = {k.lower(): v for k, v in (headers or {}).items()}
        where = f" at {self.pointer}" if self.pointer is not None else ""
        super().__init__(f"{status} {self.title}{where}: {self.detail}" if self.detail else f"{status} {self.title}")


class BadRequest(ProblemError):
    """400: malformed JSON, bad query parameter, malformed HTTP."""


class Unauthorized(ProblemError):
    """401: a token is required or was not accepted."""


class Forbidden(ProblemError):
    """403: the token may not do this."""


class NotFound(ProblemError):
    """404: unknown route, job or tile, or an image route on a job without an image."""


class MethodNotAllowed(ProblemError):
    """405: the path exists but not with this method."""


class Conflict(ProblemError):
    """409: cancel of a finished job, extend of a running/failed job or with a rule already met."""


class PayloadTooLarge(ProblemError):
    """413: the body is over the server's --max-body."""


class UnsupportedMediaType(ProblemError):
    """415: the body is not application/json."""


class InvalidSpec(ProblemError):
    """422: the spec is invalid or over a per-job cap; ``pointer`` names the field."""


class HeaderTooLarge(ProblemError):
    """431: the request head is over the server's --max-header."""


class ServerError(ProblemError):
    """Any 5xx without a more specific class."""


class NotImplementedByServer(ServerError):
    """501: e.g. image encoding not in this build of the server."""


class ServiceUnavailable(ServerError):
    """503: queue full, shutting down, too many connections. ``retry_after`` in seconds, if sent."""

    @property
    def retry_after(self) -> Optional[float]:
        value = self.headers.get("retry-after")
        try:
            return float(value) if value is not None else None
        except ValueError:
            return None


_BY_STATUS: Dict[int, Type[ProblemError]] = {
    400: BadRequest,
    401: Unauthorized,
    403: Forbidden,
    404: NotFound,
    405: MethodNotAllowed,
    409: Conflict,
    413: PayloadTooLarge,
    415: UnsupportedMediaType,
    422: InvalidSpec,
    431: HeaderTooLarge,
    501: NotImplementedByServer,
    503: ServiceUnavailable,
}


def problem_from_response(status: int, body: bytes, headers: Optional[Mapping[str, str]] = None) -> ProblemError:
    """The exception for an error response; a body that is not problem+json becomes the detail."""
    problem: Dict[str, Any]
    try:
        parsed = json.loads(body.decode("utf-8")) if body else {}
        problem = parsed if isinstance(parsed, dict) else {"detail": body.decode("utf-8", "replace")}
    except (ValueError, UnicodeDecodeError):
        problem = {"detail": body.decode("utf-8", "replace").strip()}
    problem.setdefault("status", status)
    cls = _BY_STATUS.get(status)
    if cls is None:
        cls = ServerError if status >= 500 else ProblemError
    return cls(status, problem, headers)
