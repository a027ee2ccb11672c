"""Jobs: the SQLite job store (:mod:`service.jobs.store`), executors (local process pool,
dask.distributed), the one dispatch loop of the runners (:mod:`service.jobs.dispatcher`),
the reconstruction queue with memory admission (:mod:`service.jobs.queue`), the scan runner
(:mod:`service.jobs.scan_manager`) and the live preview of scans (:mod:`service.jobs.preview`), the
job body that runs in a worker, and MIP/PNG helpers."""

__all__: list[str] = []  # the package's API is its modules
