"""The prose cites what a reader can open: papers by authors and year, files inside the repository.

The three papers are cited as :mod:`skynav.pipeline.references` names them (``Andreis et al.
(2023a)``, ``(2023b)``, ``(2024)``) with the equation, table or section number. Private shorthands
for them (a number after the word "paper") and pointers to files that are not part of the
project (upper-case house notes, anything under a sibling ``shared`` folder) mean nothing to a
reader of the repository; the project's own references are docs/architecture.md and
docs/conventions.md. Checked over every tracked text file: code, tests, docs, benchmarks, schemas.

The guides and the code's comments say what is true now and why; the history of how it came to
be (issue numbers, rounds of work, dated re-measurements, commits) lives in CHANGELOG.md and the
dated figures in docs/performance.md. Issue numbers are checked over every tracked text file but
those two; the other run-history phrases over README.md, docs/*.md and the product code (the
rooms and the command line; a benchmark may speak of its own rounds).
"""

from __future__ import annotations

import re
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
TEXT_SUFFIXES = (".py", ".md", ".json", ".yaml", ".yml", ".toml", ".txt", ".cfg", ".html")
#: a private paper number, or a pointer to a file outside the repository
FORBIDDEN = re.compile(r"[Pp]apers? 0\d\d|\b(CONVENTIONS|STYLE|ARCHITECTURE)\.md\b|\.\./shared\b")
#: the two files that may carry history and dated figures
HISTORY_FILES = ("CHANGELOG.md", "docs/performance.md")
#: an issue number: "issue 25", "issue #25", "issues 11-13", "(#25)", "the issue's target"
ISSUE = re.compile(r"\b[Ii]ssues?[ -]#?\d+|\(#\d+\)|\bthe issue(?:'s)?\b")
#: a run history: rounds of work, dated (re-)measurements, commits named by hash
HISTORY = re.compile(r"\b(first round|(second|third|fourth|fifth|sixth|seventh) (round|look))\b|\bre-measured\b"
                     r"|\b(measured|on|as of|before|after|since|until)( main)? 20\d\d-[01]\d-[0-3]\d\b"
                     r"|\b(in a later|in an earlier|the same) session\b|`[0-9a-f]{7,40}`")


def _tracked_text_files() -> list[Path]:
    try:
        out = subprocess.run(["git", "ls-files"], cwd=ROOT, capture_output=True, text=True, check=True).stdout
        names = out.split()
    except (OSError, subprocess.CalledProcessError):   # not a git checkout (an sdist): walk the tree
        names = [str(p.relative_to(ROOT)) for p in ROOT.rglob("*") if p.is_file()]
    return [ROOT / n for n in names if n.endswith(TEXT_SUFFIXES) and (ROOT / n).is_file()]


def _hits(pattern: re.Pattern, files) -> list[str]:
    hits = []
    for path in files:
        for lineno, line in enumerate(path.read_text(encoding="utf-8", errors="replace").splitlines(), 1):
            if pattern.search(line):
                hits.append(f"{path.relative_to(ROOT)}:{lineno}: {line.strip()[:100]}")
    return hits


def test_citations_name_authors_and_year_and_files_in_the_repository():
    hits = _hits(FORBIDDEN, _tracked_text_files())
    assert not hits, ("cite the papers as Andreis et al. (2023a/2023b/2024) with the equation or table "
                      "number, and only files in the repository:\n" + "\n".join(hits))


# the forbidden forms, spelled in two parts so that this file passes its own check
@pytest.mark.parametrize("head, tail", [("paper", " 002 table 4"), ("see CONVENTIONS", ".md"),
                                        ("(STYLE", ".md section 2)"), ("papers", " 001/002"),
                                        ("../sha", "red/papers")])
def test_the_check_catches_each_form(head, tail):
    assert FORBIDDEN.search(head + tail)


@pytest.mark.parametrize("line", ["Andreis et al. (2024), Table 4", "docs/conventions.md \"Files\"",
                                  "the paper camera", "docs/architecture.md"])
def test_the_check_passes_proper_citations(line):
    assert not FORBIDDEN.search(line)


def _guides() -> list[Path]:
    return [ROOT / "README.md"] + sorted(p for p in (ROOT / "docs").glob("*.md")
                                         if p.relative_to(ROOT).as_posix() not in HISTORY_FILES)


def test_no_issue_numbers_outside_the_changelog_and_performance():
    files = [p for p in _tracked_text_files() if p.relative_to(ROOT).as_posix() not in HISTORY_FILES
             and p.name != "test_prose.py"]
    hits = _hits(ISSUE, files)
    assert not hits, ("say what is true and why; an issue number means nothing to a reader of the "
                      "repository (history goes to CHANGELOG.md):\n" + "\n".join(hits))


#: the product code's top-level folders: the rooms and the command line
PRODUCT = ("skynav", "infra", "scenes", "renderer", "datasets", "pipeline", "calibration", "service")


def test_no_run_histories_in_the_guides_or_the_code():
    code = [p for p in _tracked_text_files() if p.suffix == ".py" and p.relative_to(ROOT).parts[0] in PRODUCT]
    hits = _hits(HISTORY, _guides() + code)
    assert not hits, ("the guides say what is true now; move the history to CHANGELOG.md and dated "
                      "figures to docs/performance.md:\n" + "\n".join(hits))


@pytest.mark.parametrize("pattern, line", [
    (ISSUE, "the fifth round of issue #25"), (ISSUE, "Issue 12's targets"), (ISSUE, "see (#25)"),
    (ISSUE, "within the issue's 20 %"), (HISTORY, "the fifth round of work"),
    (HISTORY, "(re-measured on main 2026-11-25)"), (HISTORY, "measured 2026-11-24"),
    (HISTORY, "main `d8794d3` in the same minutes")])
def test_the_history_checks_catch_each_form(pattern, line):
    assert pattern.search(line)


@pytest.mark.parametrize("pattern, line", [
    (ISSUE, 'color="#228833"'), (ISSUE, "[link](#render-service)"), (ISSUE, "test_issue_12_closed_loop"),
    (HISTORY, 'epoch: "2027-02-01T00:00:00"'), (HISTORY, "departure window 2026-10-01 .. 2027-01-15"),
    (HISTORY, "an interactive session"), (HISTORY, "a first look before any calibration"),
    (ISSUE, 'print(f"{label} #{n + 1} differs")')])
def test_the_history_checks_pass_the_present_tense(pattern, line):
    assert not pattern.search(line)
