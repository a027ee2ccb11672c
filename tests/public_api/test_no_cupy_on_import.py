"""CuPy is imported only when a job may run on the GPU: importing the public
package, the service's library, the dispatch and the command line leaves it out, GPU or not."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]

IMPORTS = "import fpscan, service, fpscan.service.recon, fpscan.service.pipeline, fpscan.clients.cli"


def test_imports_leave_cupy_out(tmp_path):
    """In a fresh interpreter with the GPU not hidden (``FPSCAN_NO_GPU`` unset), the imports
    leave ``cupy`` out of ``sys.modules``. A stand-in ``cupy`` package comes first on the path,
    so that an import of it would be seen here too, where CuPy is not installed."""
    stand_in = tmp_path / "cupy"
    stand_in.mkdir()
    (stand_in / "__init__.py").write_text('"""A stand-in: importing it is the failure this test looks for."""\n')
    env = {k: v for k, v in os.environ.items() if k != "FPSCAN_NO_GPU"}
    env["PYTHONPATH"] = os.pathsep.join([str(tmp_path), *filter(None, [env.get("PYTHONPATH")])])
    code = (f"import sys; {IMPORTS}; import fpscan; fpscan.reconstruct; "
            "print(sorted(m for m in sys.modules if m == 'cupy' or m.startswith(('cupy.', 'cupyx', 'cupy_backends'))))")
    res = subprocess.run([sys.executable, "-c", code], cwd=REPO, env=env, capture_output=True, text=True, timeout=60)
    assert res.returncode == 0, res.stderr
    assert res.stdout.strip().splitlines()[-1] == "[]", res.stdout


def test_check_device_refuses_an_unknown_device():
    from fpscan.service.recon.device import DEVICES, check_device

    assert check_device(None) == "auto"
    assert [check_device(d) for d in DEVICES] == list(DEVICES)
    with pytest.raises(ValueError, match="device must be one of auto, cpu, cuda, got 'tpu'"):
        check_device("tpu")
