"""The GPU tests: run where CuPy sees a CUDA device, skipped elsewhere (CI has none)."""
from __future__ import annotations

import pytest

from fpscan.service.recon import device


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """Mark every test here ``gpu``; skip them all without a GPU."""
    here = [item for item in items if "tests/gpu/" in str(item.fspath).replace("\\", "/")]
    if not here:
        return
    skip = None if device.cuda_devices() else pytest.mark.skip(reason="no CUDA GPU visible (CuPy and a device needed)")
    for item in here:
        item.add_marker(pytest.mark.gpu)
        if skip is not None:
            item.add_marker(skip)
