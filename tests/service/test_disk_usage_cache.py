"""/api/health's disk usage (``service.api.app.DiskUsageCache``) on a real folder, walked by
the service's own ``disk_usage``: a stored change shows in the next answer; a file that
grows in place (no folder changes) is answered from the last walk at once while a new walk
runs beside it, and shows once that walk is done; one walk serves callers that ask together."""
from __future__ import annotations

import asyncio

from service.api.app import DiskUsageCache
from service.jobs.lifecycle import disk_usage


def test_changes_show_at_once_and_growth_after_a_walk_beside_the_answer(tmp_path):
    walks = []

    def counted_walk(path):
        walks.append(path)
        return disk_usage(path)

    async def scenario():
        (tmp_path / "datasets").mkdir()
        (tmp_path / "scans").mkdir()
        cache = DiskUsageCache(tmp_path, counted_walk, ttl_s=0.0)
        first = await asyncio.gather(*(cache.get() for _ in range(5)))
        assert len(walks) == 1 and all(f == first[0] for f in first)
        assert first[0]["datasets_bytes"] == 0
        # a stored change (a new folder in datasets/): the next answer has it
        (tmp_path / "datasets" / "d1").mkdir()
        (tmp_path / "datasets" / "d1" / "dataset.h5").write_bytes(b"x" * 4096)
        assert (await cache.get())["datasets_bytes"] == 4096
        # growth in place: answered from the last walk, a walk starts beside the answer
        scan = tmp_path / "scans" / "s1.h5"
        (tmp_path / "scans" / "s1.h5").write_bytes(b"")
        before = (await cache.get())["scans_bytes"]
        with open(scan, "ab") as f:
            f.write(b"y" * 8192)
        n = len(walks)
        stale = await cache.get()
        assert stale["scans_bytes"] == before == 0
        while cache._background is not None and not cache._background.done():
            await asyncio.sleep(0)
        assert len(walks) == n + 1
        assert (await cache.get())["scans_bytes"] == 8192

    asyncio.run(scenario())
