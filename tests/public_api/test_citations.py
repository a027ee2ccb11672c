"""The code and the docs cite what a reader can open: the paper, a published method, or the
repository's own pages. No comment, docstring or page points at the project's issue tracker by
number or at a design file that lives outside the repository. The oracle is the text itself, read
from every source, page, test, benchmark and example in the repository, the release notes
(CHANGELOG.md) and the measurement history (docs/history/) included."""
from __future__ import annotations

import re

import pytest

from tests.source_tree import REPO

#: "issue" or "issues" followed by a number, as prose cites a tracker entry
ISSUE = re.compile(r"\bissues?\s+\d", re.IGNORECASE)
#: the design file outside the repository
DESIGN = re.compile(r"\bDESIGN\b")
FOLDERS = ("service", "driver", "clients", "fpscan", "tests", "benchmarks", "examples", "scripts", "docs")
SUFFIXES = {".py", ".md", ".rst", ".html", ".js", ".css", ".sh", ".toml", ".ipynb"}
SKIP_PARTS = {"__pycache__", "_build", "generated", "_generated", "auto_examples"}


def _files() -> dict[str, list]:
    """The files read, by folder (``"root"``: the repository's top-level files)."""
    found = {"root": [p for p in (REPO / "README.md", REPO / "CHANGELOG.md", REPO / "CONTRIBUTING.md",
                                  REPO / "pyproject.toml", REPO / "Dockerfile") if p.exists()]}
    for folder in FOLDERS:
        found[folder] = [p for p in sorted((REPO / folder).rglob("*")) if p.is_file() and p.suffix in SUFFIXES
                         and not SKIP_PARTS & set(p.relative_to(REPO).parts)]
    return found


FILES = _files()


def _hits(text: str) -> list[tuple[int, str]]:
    return [(k, line.strip()) for k, line in enumerate(text.splitlines(), 1)
            if ISSUE.search(line) or DESIGN.search(line)]


def test_the_patterns_tell_a_citation_from_prose():
    """The oracle itself: a tracker number and the outside design file are caught; prose about
    issues in general, or a method's design, is not."""
    caught = "\n".join(["per the " + "issue" + " 21 rule", "see " + "DESIGN" + " §3", "Issues " + "19 and 47"])
    fine = "\n".join(["an issue the user meets", "the design of the band", "issued 3 warnings"])
    assert [k for k, _ in _hits(caught)] == [1, 2, 3]
    assert _hits(fine) == []


@pytest.mark.parametrize("folder", ("root", *FOLDERS))
def test_nothing_cites_what_a_reader_cannot_open(folder):
    bad = [f"{p.relative_to(REPO)}:{k}: {line[:120]}" for p in FILES[folder]
           for k, line in _hits(p.read_text(encoding="utf-8", errors="replace"))]
    # this file names the patterns it looks for
    bad = [b for b in bad if not b.startswith("tests/public_api/test_citations.py")]
    assert not bad, "cite the paper, a published method or the repository's docs instead of:\n" + "\n".join(bad)


#: a path out of the repository (the project's shared folder beside a checkout), which a user's copy lacks
OUTSIDE = re.compile(r"\.\./shared\b")


def test_the_user_docs_name_no_path_outside_the_repository():
    """README.md, CHANGELOG.md, every page of docs/ (the measurement history too), the examples, the
    package's docstrings and comments (what the API reference is made of) and the benchmarks name the
    k-Wave reference files by their names and the variable that says where they are
    (``FPSCAN_SHARED``), never a path beside the checkout. The tests and CONTRIBUTING.md, written for
    developers of this checkout, may."""
    pages = [REPO / "README.md", REPO / "CHANGELOG.md", *FILES["docs"], *FILES["examples"], *FILES["fpscan"],
             *FILES["service"], *FILES["driver"], *FILES["clients"], *FILES["benchmarks"], *FILES["scripts"]]
    assert OUTSIDE.search("at " + "../" + "shared/data") and not OUTSIDE.search("shared/data")
    bad = [f"{p.relative_to(REPO)}:{k}: {line.strip()[:120]}" for p in pages if p.exists()
           for k, line in enumerate(p.read_text(encoding="utf-8").splitlines(), 1) if OUTSIDE.search(line)]
    assert not bad, "name the k-Wave reference files and FPSCAN_SHARED instead of:\n" + "\n".join(bad)
