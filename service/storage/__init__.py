"""fpscan files on the server side: result volumes (HDF5), their PNG renderings (MIPs,
depth slices), dataset import for reconstruction and the IPASC export/import of scan files.
Formats: docs/file-formats.md. The scan file itself lives in :mod:`driver.scanfile`."""

__all__: list[str] = []
