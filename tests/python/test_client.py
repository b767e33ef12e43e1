"""tally_client against a real tally-server: every method and each error class."""

from __future__ import annotations

import math
import os
import sys
import unittest

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from tally_test_support import (CuttingProxy, Server, TlsProxy, disk_spec, free_port, header_value,  # noqa: E402
                                small_image_spec)

import tally_client  # noqa: E402
from tally_client import (BadRequest, Client, Conflict, HeaderTooLarge, InvalidSpec, JobFailed,  # noqa: E402
                          MethodNotAllowed,
                          NotFound, PayloadTooLarge, ProblemError, ServiceUnavailable, TallyConnectionError,
                          UnsupportedMediaType)

try:
    import numpy as np
except ImportError:  # numpy is optional for the client, but the test set installs it
    np = None


class ClientMethods(unittest.TestCase):
    server: Server
    client: Client

    @classmethod
    def setUpClass(cls) -> None:
        cls.server = Server("--max-body", "65536")
        cls.client = Client(cls.server.url, timeout=30)

    @classmethod
    def tearDownClass(cls) -> None:
        cls.server.stop()

    def test_submit_wait_status(self) -> None:
        job = self.client.submit(disk_spec(200_000, seed=3), priority=2)
        self.assertRegex(job, r"^[0-9a-f]+$")
        final = self.client.wait(job, timeout=120)
        self.assertEqual(final["state"], "succeeded")
        self.assertEqual(final["samples"], 200_000)
        self.assertEqual(final["priority"], 2)
        est = final["estimate"]
        # 4 standard errors: false-failure rate 6e-5.
        self.assertLessEqual(abs(est["mean"] - math.pi), 4 * est["std_error"])
        self.assertEqual(self.client.status(job), final)

    def test_name_travels_with_the_spec(self) -> None:
        job = self.client.submit(disk_spec(1000, name="first try"))
        self.assertEqual(self.client.status(job)["spec"]["name"], "first try")
        entry = [j for j in self.client.list() if j["id"] == job]
        self.assertEqual([j.get("name") for j in entry], ["first try"])  # the list shows it too

    def test_list_and_filter(self) -> None:
        a = self.client.submit(disk_spec(1000, seed=5))
        self.client.wait(a, timeout=60)
        ids = [j["id"] for j in self.client.list()]
        self.assertIn(a, ids)
        done = self.client.list(state="succeeded")
        self.assertIn(a, [j["id"] for j in done])
        self.assertTrue(all(j["state"] == "succeeded" for j in done))
        cancelled = self.client.list(state="cancelled")
        self.assertNotIn(a, [j["id"] for j in cancelled])
        self.assertTrue(all(j["state"] == "cancelled" for j in cancelled))

    def test_validate(self) -> None:
        out = self.client.validate(disk_spec(10_000_000))
        self.assertEqual(out["plan"]["kind"], "integrate")
        self.assertIn("prediction", out)
        with self.assertRaises(InvalidSpec) as cm:
            self.client.validate(disk_spec(-3))
        self.assertEqual(cm.exception.status, 422)
        self.assertEqual(cm.exception.pointer, "/stop/max_samples")

    def test_cancel_then_delete(self) -> None:
        job = self.client.submit(disk_spec(50_000_000_000, seed=9))
        out = self.client.cancel(job)
        self.assertIn(out.get("state"), ("cancelled", "running", "queued"))
        with self.assertRaises(JobFailed) as failed:  # wait() raises for a cancelled job
            self.client.wait(job, timeout=60)
        self.assertEqual(failed.exception.result["state"], "cancelled")
        # Finished: DELETE now deletes it (204), then it is gone (404).
        self.assertIsNone(self.client.delete(job))
        with self.assertRaises(NotFound) as cm:
            self.client.status(job)
        self.assertEqual(cm.exception.status, 404)
        with self.assertRaises(NotFound):
            self.client.delete(job)

    def test_list_follows_pages(self) -> None:
        jobs = [self.client.submit(disk_spec(1000, seed=40 + i)) for i in range(5)]
        for j in jobs:
            self.client.wait(j, timeout=60)
        listed = [j["id"] for j in self.client.list(page_size=2)]
        self.assertEqual([j for j in listed if j in jobs], jobs)
        self.assertEqual(len(listed), len(set(listed)))
        self.assertEqual(listed, [j["id"] for j in self.client.list()])

    def test_extend(self) -> None:
        job = self.client.submit(disk_spec(100_000, seed=4))
        self.assertEqual(self.client.wait(job, timeout=60)["samples"], 100_000)
        self.client.extend(job, max_samples=300_000)
        final = self.client.wait(job, timeout=60)
        self.assertEqual(final["state"], "succeeded")
        self.assertEqual(final["samples"], 300_000)
        with self.assertRaises(Conflict):
            self.client.extend(job, max_samples=300_000)  # already has it
        with self.assertRaises(ValueError):
            self.client.extend(job)

    def test_set_priority(self) -> None:
        job = self.client.submit(disk_spec(50_000_000_000, seed=12))
        out = self.client.set_priority(job, -3)
        self.assertEqual(out["id"], job)
        self.assertEqual(out["priority"], -3)
        self.assertEqual(self.client.status(job)["priority"], -3)
        with self.assertRaises(InvalidSpec) as bad:
            self.client.set_priority(job, 7)
        self.assertEqual(bad.exception.status, 422)
        self.assertEqual(bad.exception.pointer, "/priority")
        self.client.cancel(job)
        with self.assertRaises(JobFailed):
            self.client.wait(job, timeout=60)
        with self.assertRaises(Conflict):
            self.client.set_priority(job, 1)
        self.client.delete(job)

    def test_events_of_a_finished_job(self) -> None:
        job = self.client.submit(disk_spec(50_000, seed=6))
        self.client.wait(job, timeout=60)
        events = list(self.client.events(job))
        self.assertEqual([e.event for e in events][-1], "end")
        self.assertEqual(events[-1].data["state"], "succeeded")
        self.assertIn("state", [e.event for e in events])
        # A snapshot: its events carry the job's latest id (they may share it).
        ids = [e.id for e in events]
        self.assertEqual(ids, sorted(ids))
        self.assertEqual(len(events), len({(e.id, e.event) for e in events}))

    def test_wait_timeout(self) -> None:
        job = self.client.submit(disk_spec(50_000_000_000, seed=10))
        try:
            with self.assertRaises(TimeoutError):
                self.client.wait(job, timeout=0.5)
        finally:
            self.client.cancel(job)

    def test_image_from_tiles_equals_exr(self) -> None:
        job = self.client.submit(small_image_spec(spp=16))
        final = self.client.wait(job, timeout=120)
        self.assertEqual(final["state"], "succeeded")
        from_tiles = self.client.image(job, source="tiles")
        from_exr = self.client.image(job, source="exr")
        self.assertEqual((from_tiles.width, from_tiles.height), (40, 24))
        self.assertEqual((from_exr.width, from_exr.height), (40, 24))
        # The same float32 values, bit for bit, by both routes.
        self.assertEqual(from_tiles.mean_flat.tobytes(), from_exr.mean_flat.tobytes())
        self.assertEqual(from_tiles.std_error_flat.tobytes(), from_exr.std_error_flat.tobytes())
        self.assertEqual(from_tiles.samples_flat.tobytes(), from_exr.samples_flat.tobytes())
        self.assertEqual(set(from_exr.samples_flat), {16.0})
        self.assertEqual(from_exr.metadata["job_id"], job)
        self.assertEqual(from_exr.metadata["samples"], 16.0)
        m, s, n = from_exr.pixel(20, 12)
        self.assertEqual(n, 16.0)
        self.assertTrue(all(v >= 0 for v in m + s))
        self.assertGreater(sum(from_exr.mean_flat), 0)
        png = self.client.image_bytes(job, "png")
        self.assertEqual(png[:8], b"\x89PNG\r\n\x1a\n")
        if np is not None:
            self.assertEqual(from_exr.mean.shape, (24, 40, 3))
            self.assertEqual(from_exr.std_error.shape, (24, 40, 3))
            self.assertEqual(from_exr.samples.shape, (24, 40))
            self.assertEqual(from_exr.mean.dtype, np.float32)
            np.testing.assert_array_equal(from_tiles.mean, from_exr.mean)
            self.assertEqual(float(from_exr.samples.min()), 16.0)
        tile0 = self.client.tile(job, 0)
        self.assertEqual((tile0["x"], tile0["y"], tile0["w"], tile0["h"]), (0, 0, 16, 16))
        with self.assertRaises(NotFound):
            self.client.tile(job, 999)

    def test_image_of_a_job_without_one(self) -> None:
        job = self.client.submit(disk_spec(1000))
        with self.assertRaises(ValueError):
            self.client.image(job)
        with self.assertRaises(NotFound) as cm:
            self.client.image_bytes(job, "exr")
        self.assertEqual(cm.exception.status, 404)

    # --- each error class --------------------------------------------------------

    def test_400_bad_request(self) -> None:
        with self.assertRaises(BadRequest) as cm:
            self.client.list(state="bogus")
        self.assertEqual(cm.exception.status, 400)
        self.assertTrue(cm.exception.detail)
        with self.assertRaises(BadRequest):
            self.client._request("POST", "/v1/jobs", raw_body=b"{not json", headers={"Content-Type": "application/json"})

    def test_404_not_found(self) -> None:
        with self.assertRaises(NotFound) as cm:
            self.client.status("0000000000000000")
        e = cm.exception
        self.assertEqual((e.status, e.problem["status"]), (404, 404))
        self.assertIn("0000000000000000", e.detail)
        self.assertIsInstance(e, ProblemError)

    def test_405_method_not_allowed(self) -> None:
        with self.assertRaises(MethodNotAllowed) as cm:
            self.client._request("PUT", "/v1/jobs", body={})
        self.assertEqual(cm.exception.status, 405)
        self.assertIn("allow", cm.exception.headers)

    def test_413_payload_too_large(self) -> None:
        with self.assertRaises(PayloadTooLarge) as cm:
            self.client.submit(disk_spec(1000, name="x" * 100_000))
        self.assertEqual(cm.exception.status, 413)

    def test_415_unsupported_media_type(self) -> None:
        with self.assertRaises(UnsupportedMediaType) as cm:
            self.client._request("POST", "/v1/jobs", raw_body=b"{}", headers={"Content-Type": "text/plain"})
        self.assertEqual(cm.exception.status, 415)

    def test_422_invalid_spec_names_the_field(self) -> None:
        with self.assertRaises(InvalidSpec) as cm:
            self.client.submit({"kind": "integrate", "integrand": {"builtin": "unit_disk"},
                                "stop": {"max_samples": 10}, "colour": "red"})
        e = cm.exception
        self.assertEqual(e.status, 422)
        self.assertEqual(e.pointer, "/colour")
        self.assertIn("/colour", str(e))
        with self.assertRaises(InvalidSpec) as cm2:
            self.client.submit({**small_image_spec(), "name": 7})
        self.assertEqual(cm2.exception.pointer, "/name")

    def test_431_header_too_large(self) -> None:
        with self.assertRaises(HeaderTooLarge) as cm:
            self.client._request("GET", "/v1/jobs", headers={"X-Padding": "p" * 20_000})
        self.assertEqual(cm.exception.status, 431)

    def test_connection_error(self) -> None:
        c = Client(f"http://127.0.0.1:{free_port()}", timeout=5)
        with self.assertRaises(TallyConnectionError):
            c.list()
        with self.assertRaises(ConnectionError):  # also a builtin ConnectionError
            c.status("x")

    def test_bearer_token_is_sent(self) -> None:
        proxy = CuttingProxy(self.server.port, cut_streams=0)
        try:
            c = Client(proxy.url, token="s3cret", timeout=30)
            c.list()
            no_token = Client(proxy.url, timeout=30)
            no_token.list()
            heads = proxy.request_heads(b"GET /v1/jobs")
            self.assertEqual(len(heads), 2)
            self.assertEqual(header_value(heads[0], "Authorization"), "Bearer s3cret")
            self.assertIsNone(header_value(heads[1], "Authorization"))
        finally:
            proxy.close()

    def test_https(self) -> None:
        import ssl
        proxy = TlsProxy(self.server.port)
        try:
            c = Client(proxy.url, ssl_context=ssl.create_default_context(cafile=proxy.cafile), timeout=30)
            job = c.submit(disk_spec(100_000, seed=12))
            self.assertEqual(c.wait(job, timeout=60)["samples"], 100_000)
            self.assertEqual([e.event for e in c.events(job)][-1], "end")
            # The default context verifies certificates: a self-signed one is refused.
            with self.assertRaises(TallyConnectionError) as cm:
                Client(proxy.url, timeout=30).list()
            self.assertIn("CERTIFICATE_VERIFY_FAILED", str(cm.exception))
        finally:
            proxy.close()

    def test_url_checks_and_prefix(self) -> None:
        with self.assertRaises(ValueError):
            Client("ftp://example.org")
        c = Client("https://example.org:8443/tally/")
        self.assertEqual((c._host, c._port, c._prefix, c._https), ("example.org", 8443, "/tally", True))
        self.assertIsNotNone(c._ssl)
        self.assertEqual(tally_client.__version__, "0.1.0")


class QueueFull(unittest.TestCase):
    def test_503_service_unavailable_with_retry_after(self) -> None:
        server = Server("--max-running", "1", "--max-queued", "1")
        try:
            c = Client(server.url, timeout=30)
            jobs = [c.submit(disk_spec(50_000_000_000, seed=s)) for s in (1, 2)]
            with self.assertRaises(ServiceUnavailable) as cm:
                c.submit(disk_spec(1000))
            self.assertEqual(cm.exception.status, 503)
            self.assertEqual(cm.exception.retry_after, 5.0)
            for j in jobs:
                c.cancel(j)
        finally:
            server.stop()


if __name__ == "__main__":
    unittest.main()
