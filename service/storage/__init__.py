"""fpscan files on the server side: result volumes (HDF5, with their PNG renderings drawn by
:mod:`fpscan.service.pictures`), dataset import for reconstruction and the IPASC export/import of scan files.
Formats: docs/file-formats.md. The scan file itself lives in :mod:`fpscan.driver.scanfile`."""

__all__: list[str] = []
