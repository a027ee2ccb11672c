"""The user docs are reference, the changelog is release notes, the measurement log is kept apart.

- The pages of the documentation site (README.md and docs/*.md, *.rst) state today's figures: no
  date in their text (an ISO date, or a time of day in UTC). Each figure says its machine, its
  command and its load instead; the dated record of every run is docs/history/measurements.md,
  which the site leaves out.
- CHANGELOG.md follows Keep a Changelog 1.1.0 (https://keepachangelog.com/en/1.1.0/): its entries
  are ``## [Unreleased]``, ``## [VERSION] - YYYY-MM-DD`` or, while fpscan has no numbered releases,
  ``## YYYY-MM-DD``; under each only the six kinds of change as level-3 headings (Added, Changed,
  Deprecated, Removed, Fixed, Security), nothing deeper, and no measurement tables (a table row may
  map names, never carry figures: no digit in it).
- Every citation of the measurement log by an entry's title (``docs/history/measurements.md,
  "TITLE"``) finds that entry.
The oracle is the text of the files themselves.
"""
from __future__ import annotations

import re

import pytest

from tests.source_tree import REPO

DOCS = REPO / "docs"
HISTORY = DOCS / "history" / "measurements.md"
CHANGELOG = REPO / "CHANGELOG.md"

#: an ISO date (2026-11-28) or a time of day in UTC (23:22 UTC), as a log dates its runs
DATE = re.compile(r"\b(19|20)\d\d-[01]\d-[0-3]\d\b|\b[0-2]?\d:[0-5]\d(?:[–-][0-2]?\d:[0-5]\d)? UTC\b")
#: Keep a Changelog 1.1.0's kinds of change, the only level-3 headings of a release's entry
KINDS = ("Added", "Changed", "Deprecated", "Removed", "Fixed", "Security")
#: a release's heading: unreleased, a version with its date, or (no numbered releases yet) the date
RELEASE = re.compile(r"## (\[Unreleased\]|\[\d+\.\d+\.\d+[^\]]*\] - \d{4}-\d\d-\d\d|\d{4}-\d\d-\d\d)")
#: a citation of the measurement log by an entry's title; the title may wrap onto the next line
CITATION = re.compile(r"docs/history/measurements\.md`?,\s+\"([^\"]+)\"")


def _site_pages() -> list:
    """README.md and the pages of docs/ the site shows (docs/history/ is excluded from it)."""
    return [REPO / "README.md", *sorted(DOCS.glob("*.md")), *sorted(DOCS.glob("*.rst"))]


def _dated(text: str) -> list[tuple[int, str]]:
    return [(k, line.strip()) for k, line in enumerate(text.splitlines(), 1) if DATE.search(line)]


def test_the_date_pattern_tells_a_log_from_reference():
    """The oracle itself: a run's date and clock time are caught; a paper's year, a version, a
    figure range and a duration are not."""
    caught = ["Latest (" + "2026-11-25" + " night, AMD, load 1.7)", "on the H100, 02:35 " + "UTC.",
              "(2026-11-23 16:10–17:10 UTC)"]
    fine = ["Phys. Med. Biol. 61 (2016) 8908", "numpy 2.5.2, CuPy 14.2", "load 1.4-1.8, 0.76-1.33",
            "the parallel part 16:19 → 14:49", "RFC 9110", "Keep a Changelog 1.1.0"]
    assert [k for k, _ in _dated("\n".join(caught))] == [1, 2, 3]
    assert _dated("\n".join(fine)) == []


@pytest.mark.parametrize("page", _site_pages(), ids=lambda p: str(p.relative_to(REPO)))
def test_the_pages_state_todays_figures_without_dates(page):
    """performance.md, results.md and every other page of the site read as reference: no dated
    narrative ("on 2026-11-26 we measured ..."); the machine, the command and the load say where a
    figure comes from."""
    bad = [f"{page.relative_to(REPO)}:{k}: {line[:120]}" for k, line in _dated(page.read_text(encoding="utf-8"))]
    assert not bad, ("state today's figure with its machine, command and load; the dated record goes to "
                     "docs/history/measurements.md:\n" + "\n".join(bad))


def test_the_reference_pages_name_their_commands_and_machines():
    """Each section of performance.md that gives figures names the benchmarks/ script that
    reproduces them (in its heading, as the scripts' table does), and both pages say on what machine
    their figures were measured."""
    text = (DOCS / "performance.md").read_text(encoding="utf-8")
    sections = re.split(r"^## ", text, flags=re.M)[1:]
    assert sections, "performance.md has no sections"
    unnamed = [s.splitlines()[0] for s in sections if not re.search(r"`(bench_\w+\.py|benchmarks/\w+\.py)", s)]
    assert not unnamed, f"sections of performance.md without the script that reproduces them: {unnamed}"
    for name in ("performance.md", "results.md"):
        assert re.search(r"2-core|H100", (DOCS / name).read_text(encoding="utf-8")), f"{name} names no machine"


def test_the_changelog_is_release_notes():
    """Keep a Changelog's shape: releases at level 2, only the six kinds of change at level 3,
    nothing deeper, every release with at least one kind, no measurement table."""
    lines = CHANGELOG.read_text(encoding="utf-8").splitlines()
    assert lines[0] == "# Changelog"
    problems, release, kinds = [], None, 0
    for k, line in enumerate(lines, 1):
        if line.startswith("## "):
            if release is not None and not kinds:
                problems.append(f"{release}: no Added/Changed/... section")
            release, kinds = line, 0
            if not RELEASE.fullmatch(line):
                problems.append(f"{k}: a release heading is ## [Unreleased], ## [X.Y.Z] - DATE or ## DATE: {line}")
        elif line.startswith("### "):
            kinds += 1
            if line[4:] not in KINDS:
                problems.append(f"{k}: {line!r} is not one of Keep a Changelog's {', '.join(KINDS)}")
        elif line.startswith("####"):
            problems.append(f"{k}: no heading below a kind of change: {line}")
        elif line.lstrip().startswith("|") and re.search(r"\d", line):
            problems.append(f"{k}: a table row with figures (measurements go to docs/history/): {line.strip()[:100]}")
    if release is not None and not kinds:
        problems.append(f"{release}: no Added/Changed/... section")
    assert release is not None, "CHANGELOG.md has no release"
    assert not problems, "\n".join(problems)


def test_the_measurement_log_stays_out_of_the_site():
    """The dated record is not a page of the documentation site (docs/conf.py excludes it), and
    the changelog does not carry it."""
    import ast

    conf = (DOCS / "conf.py").read_text(encoding="utf-8")
    excluded = next(ast.literal_eval(node.value) for node in ast.parse(conf).body
                    if isinstance(node, ast.Assign) and getattr(node.targets[0], "id", "") == "exclude_patterns")
    assert "history/**" in excluded
    assert HISTORY.read_text(encoding="utf-8").startswith("# Measurement history")
    assert "### Measured" not in CHANGELOG.read_text(encoding="utf-8")


def _citations() -> list[tuple[str, str]]:
    """``(file, title)`` of every citation of the measurement log by title, in the repository's
    sources, tests, benchmarks and pages."""
    found = []
    for folder in ("service", "driver", "clients", "fpscan", "tests", "benchmarks", "examples", "scripts", "docs"):
        for path in sorted((REPO / folder).rglob("*")):
            if (path.is_file() and path.suffix in {".py", ".md", ".rst", ".sh"}
                    and not {"__pycache__", "_build", "generated", "auto_examples"} & set(path.parts)):
                text = path.read_text(encoding="utf-8", errors="replace")
                found += [(str(path.relative_to(REPO)), " ".join(m.group(1).split())) for m in CITATION.finditer(text)]
    for page in (REPO / "README.md", REPO / "CONTRIBUTING.md", CHANGELOG):
        found += [(page.name, " ".join(m.group(1).split())) for m in CITATION.finditer(page.read_text(encoding="utf-8"))]
    return found


def test_citations_of_the_measurement_log_find_their_entry():
    """A title cited beside ``docs/history/measurements.md`` is part of one of its headings."""
    headings = [line.lstrip("#").strip() for line in HISTORY.read_text(encoding="utf-8").splitlines()
                if line.startswith("#")]
    # this file shows the pattern it looks for
    cited = [(where, title) for where, title in _citations() if not where.endswith("test_docs_reference.py")]
    assert len(cited) >= 5, cited  # the code cites the log: the pattern finds them
    lost = [f"{where}: {title!r}" for where, title in cited if not any(title in h for h in headings)]
    assert not lost, "no entry of docs/history/measurements.md has these titles:\n" + "\n".join(lost)
