"""tally_client as a session: TALLY_SERVER/TALLY_TOKEN, one kept-alive connection, the
context manager, wait() raising on a failed job, cancel() leaving a finished job alone,
the typed result (.mean, .sdev, .ci) and the asyncio variant, against a real tally-server."""

from __future__ import annotations

import asyncio
import math
import os
import sys
import unittest
from typing import List
from unittest import mock

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from tally_test_support import CuttingProxy, ServerTestCase, disk_spec, header_value  # noqa: E402

from tally_client import AsyncClient, Client, Conflict, Event, JobFailed, JobResult  # noqa: E402


def failing_spec() -> dict:
    # sqrt of a negative number is NaN at every sample: the job fails ("the integrand is NaN").
    return {"kind": "integrate", "seed": 1, "integrand": {"expression": "sqrt(x0 - 2)"},
            "domain": {"type": "box", "lower": [0], "upper": [1]}, "stop": {"max_samples": 10000}}


class Session(ServerTestCase):
    def test_environment_names_server_and_token(self) -> None:
        proxy = CuttingProxy(self.server.port, cut_streams=0)
        try:
            with mock.patch.dict(os.environ, {"TALLY_SERVER": proxy.url, "TALLY_TOKEN": "from-env"}):
                c = Client()
                self.assertEqual((c.url, c.token), (proxy.url, "from-env"))
                c.list()
                c.close()
            heads = proxy.request_heads(b"GET /v1/jobs")
            self.assertEqual(len(heads), 1)
            self.assertEqual(header_value(heads[0], "Authorization"), "Bearer from-env")
            with mock.patch.dict(os.environ, {}, clear=True):
                self.assertEqual(Client().url, "http://127.0.0.1:8080")
                self.assertIsNone(Client().token)
        finally:
            proxy.close()

    def test_requests_share_one_connection_and_close_ends_it(self) -> None:
        proxy = CuttingProxy(self.server.port, cut_streams=0)
        try:
            with Client(proxy.url, timeout=30) as c:
                job = c.submit(disk_spec(1000, seed=3))
                for _ in range(5):
                    c.status(job)
                c.list()
                conn = c._local.conn
                self.assertIsNotNone(conn)
            self.assertIsNone(c._local.conn)  # the with block closed it
            # The proxy records the first request of each TCP connection: 7 requests, 1 connection.
            self.assertEqual(len(proxy.requests), 1, [r.split(b"\r\n", 1)[0] for r in proxy.requests])
        finally:
            proxy.close()

    def test_wait_raises_on_a_failed_job_unless_asked_not_to(self) -> None:
        c = Client(self.server.url, timeout=30)
        job = c.submit(failing_spec())
        with self.assertRaises(JobFailed) as cm:
            c.wait(job, timeout=60)
        self.assertEqual(cm.exception.state, "failed")
        self.assertEqual(cm.exception.result["id"], job)
        self.assertIn("NaN", cm.exception.error_message or "")
        r = c.wait(job, timeout=60, raise_on_failure=False)
        self.assertEqual(r.state, "failed")

    def test_cancel_of_a_finished_job_does_not_delete_it(self) -> None:
        c = Client(self.server.url, timeout=30)
        job = c.submit(disk_spec(1000, seed=4))
        c.wait(job, timeout=60)
        with self.assertRaises(Conflict) as cm:
            c.cancel(job)
        self.assertIn("already finished (succeeded)", cm.exception.detail)
        self.assertEqual(c.status(job).state, "succeeded")  # still there
        # A running job is cancelled as before.
        slow = c.submit(disk_spec(50_000_000_000, seed=5))
        c.cancel(slow)
        self.assertEqual(c.wait(slow, timeout=60, raise_on_failure=False).state, "cancelled")

    def test_typed_result(self) -> None:
        c = Client(self.server.url, timeout=30)
        spec = disk_spec(200_000, seed=6, domain={"type": "box", "lower": [-1, -1], "upper": [1, 1]})
        r = c.wait(c.submit(spec), timeout=60)
        self.assertIsInstance(r, JobResult)
        est = r["estimate"]  # still the status document
        self.assertEqual((r.mean, r.sdev, r.ci), (est["mean"], est["std_error"], tuple(est["ci"])))
        self.assertEqual(r.n, 200_000)
        self.assertEqual(r.samples, 200_000)
        self.assertGreater(r.sdev, 0)
        self.assertLess(r.ci[0], r.mean)
        self.assertLess(r.mean, r.ci[1])
        # The unit disk's area: pi, within 6 standard errors (false failure ~2e-9; the seed is fixed).
        self.assertLess(abs(r.mean - math.pi), 6 * r.sdev)
        # A job that has not run has no estimate: said plainly.
        with self.assertRaises(ValueError):
            _ = JobResult({"id": "x", "state": "queued"}).mean

    def test_async_client(self) -> None:
        async def session() -> List[Event]:
            async with AsyncClient(self.server.url, timeout=30) as c:
                jobs = await asyncio.gather(*(c.submit(disk_spec(100_000, seed=s)) for s in (7, 8)))
                results = await asyncio.gather(*(c.wait(j, timeout=60) for j in jobs))
                self.assertEqual([r.samples for r in results], [100_000, 100_000])
                events = [ev async for ev in c.events(jobs[0])]
                with self.assertRaises(JobFailed):
                    await c.wait(await c.submit(failing_spec()), timeout=60)
                return events

        events = asyncio.run(session())
        self.assertEqual(events[-1].event, "end")
        self.assertEqual(events[-1].data["state"], "succeeded")


if __name__ == "__main__":
    unittest.main()
