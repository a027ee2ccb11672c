"""Every public module of ``driver``, ``service`` and ``clients`` declares its API in
``__all__``: each name listed exists, none is private or listed twice, and
every public function and class the module defines (read from its source, not from the
module) is listed -- a new public definition fails here until it is declared or made
private."""
from __future__ import annotations

import ast
import importlib
from pathlib import Path

import pytest

from tests.source_tree import module_files

REPO = Path(__file__).resolve().parents[2]
#: Paths exempt from the rule (none left: the modules once exempt declare theirs).
PENDING: dict[str, str] = {}


def _public_modules() -> list[str]:
    """Dotted names of the modules whose file and package names do not start with ``_``
    (package ``__init__`` files included), outside ``PENDING``."""
    names = []
    for name, path in module_files():
        if name == "fpscan":  # the flat namespace: tests/public_api/test_package.py
            continue
        rel = path.relative_to(REPO)
        if any(p.startswith("_") for p in name.split(".")) or rel.as_posix().startswith(tuple(PENDING)):
            continue
        names.append(name)
    return names


MODULES = _public_modules()


def _defined_functions_and_classes(module_name: str) -> list[str]:
    """Public functions and classes defined at the top level of the module's source."""
    path = REPO / Path(*module_name.split("."))
    path = path / "__init__.py" if path.is_dir() else path.with_suffix(".py")
    tree = ast.parse(path.read_text(encoding="utf-8"))
    return [node.name for node in tree.body
            if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef | ast.ClassDef)
            and not node.name.startswith("_")]


def test_the_walk_finds_the_packages_modules():
    assert {"fpscan.physics.balls", "fpscan.service.metrics.roi", "fpscan.clients.http.client", "fpscan.clients.cli.recon",
            "fpscan.service.api.app", "fpscan.driver", "fpscan.physics", "fpscan.wire.models",
            "fpscan.experiments", "fpscan.experiments.dense"} <= set(MODULES)
    assert {"fpscan.service.storage.loader", "fpscan.service.formats.ipasc", "fpscan.service.recon.tv"} <= set(MODULES)
    assert not any(m.startswith(tuple(p.removesuffix(".py").replace("/", ".") for p in PENDING)) for m in MODULES)
    assert not any(part.startswith("_") for m in MODULES for part in m.split("."))


@pytest.mark.parametrize("module_name", MODULES)
def test_all_declares_the_public_api(module_name):
    module = importlib.import_module(module_name)
    declared = getattr(module, "__all__", None)
    assert isinstance(declared, list | tuple), f"{module_name} has no __all__"
    assert all(isinstance(n, str) for n in declared), declared
    assert len(set(declared)) == len(declared), f"{module_name}.__all__ lists a name twice"
    missing = [n for n in declared if not hasattr(module, n)]
    assert not missing, f"{module_name}.__all__ names what the module lacks: {missing}"
    private = [n for n in declared if n.startswith("_")]
    assert not private, f"{module_name}.__all__ lists private names: {private}"
    undeclared = [n for n in _defined_functions_and_classes(module_name) if n not in declared]
    assert not undeclared, f"{module_name} defines public {undeclared} not in __all__ (declare or rename _x)"
