"""Jobs: the SQLite job store (:mod:`service.jobs.store`), executors (local process pool,
dask.distributed), the reconstruction queue with memory admission, the job body that runs
in a worker, and MIP/PNG helpers."""

__all__: list[str] = []  # the package's API is its modules
