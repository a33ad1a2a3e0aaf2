"""The prose cites what a reader can open: papers by authors and year, files inside the repository.

The three papers are cited as :mod:`skynav.pipeline.references` names them (``Andreis et al.
(2023a)``, ``(2023b)``, ``(2024)``) with the equation, table or section number. Private shorthands
for them (a number after the word "paper") and pointers to files that are not part of the
project (upper-case house notes, anything under a sibling ``shared`` folder) mean nothing to a
reader of the repository; the project's own references are docs/architecture.md and
docs/conventions.md. Checked over every tracked text file: code, tests, docs, benchmarks, schemas.
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
