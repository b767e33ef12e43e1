"""A job's status document with typed accessors, as vegas/gvar users expect them."""

from __future__ import annotations

import math
from typing import Any, Dict, Optional, Tuple

__all__ = ["JobResult"]


class JobResult(Dict[str, Any]):
    """The status document of ``GET /v1/jobs/{id}`` (docs/api.md), still a ``dict``
    (``r["estimate"]["mean"]`` works as before), plus:

    - ``mean``, ``sdev`` (the standard error of the mean), ``ci`` (the confidence interval,
      ``(lo, hi)`` at ``confidence``), ``n``: the estimate of channel 0; they raise
      ``ValueError`` on a job without a scalar estimate (an image job: use ``Client.image``,
      or a job that has not run yet);
    - ``id``, ``state``, ``stop_reason``, ``target_met``, ``samples``, ``summary``,
      ``error_message``.
    """

    def _estimate(self) -> Dict[str, Any]:
        est = self.get("estimate")
        if not isinstance(est, dict) or not isinstance(est.get("mean"), (int, float)):
            raise ValueError(f"job {self.get('id', '?')} ({self.get('state', '?')}) has no scalar estimate"
                             + (" (an image job: use Client.image)" if (self.get("plan") or {}).get("image") else ""))
        return est

    @property
    def mean(self) -> float:
        return float(self._estimate()["mean"])

    @property
    def sdev(self) -> float:
        """Standard error of the mean (gvar's ``sdev``)."""
        value = self._estimate().get("std_error")
        return float(value) if isinstance(value, (int, float)) else math.nan

    @property
    def ci(self) -> Tuple[float, float]:
        ci = self._estimate().get("ci")
        if not isinstance(ci, list) or len(ci) != 2:
            return (math.nan, math.nan)
        return (float(ci[0]), float(ci[1]))

    @property
    def confidence(self) -> float:
        value = self._estimate().get("confidence")
        return float(value) if isinstance(value, (int, float)) else math.nan

    @property
    def n(self) -> int:
        return int(self._estimate().get("n", 0))

    @property
    def id(self) -> str:
        return str(self.get("id", ""))

    @property
    def state(self) -> str:
        return str(self.get("state", ""))

    @property
    def stop_reason(self) -> Optional[str]:
        value = self.get("stop_reason")
        return str(value) if value is not None else None

    @property
    def target_met(self) -> Optional[bool]:
        value = self.get("target_met")
        return bool(value) if value is not None else None

    @property
    def samples(self) -> int:
        return int(self.get("samples", 0) or 0)

    @property
    def summary(self) -> Optional[str]:
        value = self.get("summary")
        return value if isinstance(value, str) else None

    @property
    def error_message(self) -> Optional[str]:
        value = self.get("error_message")
        return value if isinstance(value, str) else None
