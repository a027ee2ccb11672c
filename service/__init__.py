"""fpscan server side: reconstruction (`fpscan.service.recon`), sensor masks and plans
(`fpscan.service.plans`), metrics, storage, the job store and the HTTP API."""

__all__: list[str] = []  # the package's API is its modules
