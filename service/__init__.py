"""fpscan server side: reconstruction (`service.recon`), sensor masks and plans
(`service.plans`), metrics, storage, the job store and the HTTP API."""
