"""fpscan's modules as files, for the tests that read the source: one import root, ``fpscan``,
whose subpackages ``fpscan.service``, ``fpscan.driver`` and ``fpscan.clients`` are links to the
repository's folders of those names (docs/architecture.md, "Folders and import names")."""
from __future__ import annotations

import os
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
PACKAGE = REPO / "fpscan"


def module_files(package: str = "fpscan") -> list[tuple[str, Path]]:
    """``(dotted name, path)`` of every module of ``package`` (``"fpscan"`` or a dotted name under
    it), ``__init__`` files as their package, in a stable order. The path runs through the link
    (``fpscan/service/...``); ``path.resolve()`` is the file in its folder (``service/...``)."""
    base = PACKAGE.joinpath(*package.split(".")[1:])
    found = []
    for dirpath, dirnames, filenames in os.walk(base, followlinks=True):
        dirnames[:] = sorted(d for d in dirnames if d != "__pycache__")
        for name in sorted(filenames):
            if name.endswith(".py"):
                path = Path(dirpath) / name
                parts = path.relative_to(REPO).with_suffix("").parts
                found.append((".".join(parts[:-1] if parts[-1] == "__init__" else parts), path))
    return found
