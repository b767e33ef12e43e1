"""Python client of tally-server (docs/python.md).

    from tally_client import Client
    c = Client("http://127.0.0.1:8080")
    job = c.submit({"kind": "integrate", "integrand": {"builtin": "unit_disk"},
                    "stop": {"max_samples": 1000000}})
    print(c.wait(job)["summary"])

Standard library only; numpy is needed only for the arrays of :class:`Image`.
"""

from .client import TERMINAL_STATES, Client, Event
from .errors import (BadRequest, Conflict, Forbidden, HeaderTooLarge, InvalidSpec, MethodNotAllowed,
                     NotFound, NotImplementedByServer, PayloadTooLarge, ProblemError, ServerError,
                     ServiceUnavailable, TallyConnectionError, TallyError, Unauthorized, UnsupportedMediaType)
from .image import ExrError, Image, decode_exr

__version__ = "0.1.0"

__all__ = [
    "Client", "Event", "TERMINAL_STATES", "Image", "decode_exr", "ExrError",
    "TallyError", "TallyConnectionError", "ProblemError", "BadRequest", "Unauthorized", "Forbidden",
    "NotFound", "MethodNotAllowed", "Conflict", "PayloadTooLarge", "UnsupportedMediaType", "InvalidSpec",
    "HeaderTooLarge", "ServerError", "NotImplementedByServer", "ServiceUnavailable",
]
