"""Light imports: what a fresh interpreter loads for the pieces that must stay cheap."""
from __future__ import annotations

import subprocess
import sys

import pytest


@pytest.mark.parametrize("module, heavy", [
    ("fpscan.physics", ("numba", "finufft")),          # Ball & co.: numpy only
    ("fpscan.physics.nufft", ("finufft",)),            # not the forward model
    ("fpscan.service.plans", ("numba", "finufft")),           # weights without the reconstruction
    ("fpscan.driver.host", ("numba", "finufft", "scipy")),    # the link needs no physics
])
def test_import_does_not_load_heavy_modules(module, heavy):
    code = (f"import sys, {module}; "
            f"print(','.join(m for m in {heavy!r} if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True, timeout=120)
    assert out.stdout.strip() == ""
