"""Jobs: the SQLite job store (:mod:`fpscan.service.jobs.store`), executors (local process pool,
dask.distributed), the one dispatch loop of the runners (:mod:`fpscan.service.jobs.dispatcher`),
the reconstruction queue with memory admission (:mod:`fpscan.service.jobs.queue`), the scan runner
(:mod:`fpscan.service.jobs.scan_manager`) and the live preview of scans (:mod:`fpscan.service.jobs.preview`), the
job body that runs in a worker, and MIP/PNG helpers."""

__all__: list[str] = []  # the package's API is its modules
