"""Python client of tally-server (docs/python.md).

    from tally_client import Client
    with Client() as c:                      # TALLY_SERVER / TALLY_TOKEN, or the defaults
        job = c.submit({"kind": "integrate", "integrand": {"builtin": "unit_disk"},
                        "stop": {"max_samples": 1000000}})
        r = c.wait(job)                      # raises JobFailed if the job failed
        print(r.mean, r.sdev, r.ci)

Standard library only; numpy is needed only for the arrays of :class:`Image`.
``AsyncClient`` (tally_client.aio) has the same methods as coroutines.
"""

from .aio import AsyncClient
from .client import DEFAULT_URL, TERMINAL_STATES, Client, Event
from .errors import (BadRequest, Conflict, Forbidden, HeaderTooLarge, InvalidSpec, JobFailed, MethodNotAllowed,
                     NotFound, NotImplementedByServer, PayloadTooLarge, ProblemError, ServerError,
                     ServiceUnavailable, TallyConnectionError, TallyError, Unauthorized, UnsupportedMediaType)
from .image import ExrError, Image, decode_exr
from .packing import PackError, ScenePacker
from .result import JobResult

__version__ = "0.1.0"

__all__ = [
    "Client", "AsyncClient", "Event", "JobResult", "TERMINAL_STATES", "DEFAULT_URL", "Image", "decode_exr",
    "ExrError", "PackError", "ScenePacker",
    "TallyError", "TallyConnectionError", "ProblemError", "BadRequest", "Unauthorized", "Forbidden",
    "NotFound", "MethodNotAllowed", "Conflict", "PayloadTooLarge", "UnsupportedMediaType", "InvalidSpec",
    "HeaderTooLarge", "ServerError", "NotImplementedByServer", "ServiceUnavailable", "JobFailed",
]
