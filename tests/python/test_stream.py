"""tally_client.Client.events(): a stream cut mid-event (by an in-test TCP proxy) resumes
with Last-Event-ID and loses nothing; a stream that cannot come back raises."""

from __future__ import annotations

import os
import sys
import unittest

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from tally_test_support import CuttingProxy, Server, disk_spec, header_value  # noqa: E402

from tally_client import Client, TallyConnectionError  # noqa: E402


def long_spec(seed: int) -> dict:
    # About 1.5 s of compute: many passes, one progress event each.
    spec = disk_spec(100_000_000_000, seed=seed)
    spec["stop"] = {"time_budget_s": 1.5}
    return spec


class StreamResume(unittest.TestCase):
    server: Server

    @classmethod
    def setUpClass(cls) -> None:
        cls.server = Server("--event-buffer", "100000")

    @classmethod
    def tearDownClass(cls) -> None:
        cls.server.stop()

    def test_cut_mid_job_resumes_with_last_event_id(self) -> None:
        proxy = CuttingProxy(self.server.port, cut_streams=2, cut_after=3)
        try:
            c = Client(proxy.url, timeout=30)
            job = c.submit(long_spec(21))
            events = list(c.events(job, reconnect_timeout=20))
            self.assertEqual(proxy.cuts, 2, "the proxy cut two streams")
            heads = proxy.request_heads(b"/events")
            self.assertEqual(len(heads), 3)  # two cut, the third ran to the end
            self.assertIsNone(header_value(heads[0], "Last-Event-ID"))
            # Each cut came after 3 whole events; the 4th was cut off and never yielded.
            self.assertEqual(header_value(heads[1], "Last-Event-ID"), str(events[2].id))
            self.assertEqual(header_value(heads[2], "Last-Event-ID"), str(events[5].id))
            # The server replays from its buffer: the next events follow without a gap.
            self.assertEqual(events[3].id, events[2].id + 1)
            self.assertEqual(events[6].id, events[5].id + 1)
            ids = [e.id for e in events]
            self.assertEqual(ids, sorted(ids), "ids never go back")
            self.assertEqual(len(events), len({(e.id, e.event) for e in events}), "no event twice")
            self.assertEqual(len(ids[3:]), len(set(ids[3:])), "live events have distinct ids")
            self.assertEqual(events[-1].event, "end")
            self.assertEqual(events[-1].data["state"], "succeeded")
            progress = [e for e in events if e.event == "progress"]
            self.assertGreater(len(progress), 3)
            samples = [e.data["samples"] for e in progress]
            self.assertEqual(samples, sorted(samples))
            final = c.status(job)
            self.assertEqual(progress[-1].data["samples"], final["samples"])
        finally:
            proxy.close()

    def test_wait_survives_a_cut(self) -> None:
        proxy = CuttingProxy(self.server.port, cut_streams=1, cut_after=2)
        try:
            c = Client(proxy.url, timeout=30)
            job = c.submit(long_spec(22))
            final = c.wait(job, timeout=120)
            self.assertEqual(proxy.cuts, 1)
            self.assertEqual(final["state"], "succeeded")
            self.assertEqual(final["stop_reason"], c.status(job)["stop_reason"])
        finally:
            proxy.close()

    def test_gives_up_after_reconnect_timeout(self) -> None:
        proxy = CuttingProxy(self.server.port, cut_streams=1, cut_after=2)
        c = Client(proxy.url, timeout=30)
        job = c.submit(long_spec(23))
        got = []
        with self.assertRaises(TallyConnectionError) as cm:
            for ev in c.events(job, reconnect_timeout=1.0):
                got.append(ev)
                if len(got) == 2:
                    proxy.close()  # nothing listens any more: reconnects are refused
        self.assertEqual(len(got), 2)
        self.assertIn(str(got[-1].id), str(cm.exception))



if __name__ == "__main__":
    unittest.main()
