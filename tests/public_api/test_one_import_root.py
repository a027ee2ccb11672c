"""One import root: every module of the product is ``fpscan`` or under it (docs/architecture.md,
"Folders and import names"). The product's own code is held to it by ruff (banned API, no relative
imports); this test holds the rest of the repository that imports the product: the tests, the
benchmarks, the gallery and the scripts, read as source (an AST walk of their imports)."""
from __future__ import annotations

import ast

import pytest

from tests.source_tree import REPO

OLD_ROOTS = {"service", "driver", "clients", "wire"}
FOLDERS = ("tests", "benchmarks", "examples", "scripts", "docs")


def _imported_roots(tree: ast.AST) -> list[tuple[int, str]]:
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found += [(node.lineno, alias.name.split(".")[0]) for alias in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            found.append((node.lineno, node.module.split(".")[0]))
    return found


def test_the_walk_tells_an_old_root_from_fpscan():
    """The oracle itself: ``import service.x`` is an old root; ``from fpscan.service import x`` is not."""
    tree = ast.parse("import service.recon\nfrom fpscan.service import plans\nfrom driver import plan\n")
    assert [root for _line, root in _imported_roots(tree) if root in OLD_ROOTS] == ["service", "driver"]


@pytest.mark.parametrize("folder", FOLDERS)
def test_nothing_imports_the_folder_names(folder):
    bad = []
    for path in sorted((REPO / folder).rglob("*.py")):
        if "__pycache__" in path.parts:
            continue
        tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
        bad += [f"{path.relative_to(REPO)}:{line}: {root}" for line, root in _imported_roots(tree) if root in OLD_ROOTS]
    assert not bad, "import fpscan.<package>, not the folder's name:\n" + "\n".join(bad)
