"""fpscan scanner side: the serial protocol, the host driver, scan files and the
simulated Fabry-Perot scanner. Deployable alone; never imports `service`.

Keep this file free of heavy imports: `driver.physics` is imported by
`service.recon` and must stay numpy/scipy/finufft only.
"""
