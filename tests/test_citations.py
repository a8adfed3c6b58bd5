"""Equation citations read "Stojčić eq. 17" / "Xu & Meckl eq. 13" / "Yang eq. 7" (issue 19).

``tools/check_citations.py`` finds the offenders; the checker itself is tested on examples here,
and every module of the package (``jerklab/**/*.py``) must pass it.
"""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
_spec = importlib.util.spec_from_file_location(
    "check_citations", ROOT / "tools" / "check_citations.py"
)
check_citations = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(check_citations)


@pytest.mark.parametrize(
    "text",
    [
        "Stojčić eq. 17",
        "Stojcic eq. 17: the PID",
        "(Xu & Meckl eq. 13, mapped to z)",
        "Yang eq. 7 and Yang eq. 8",
        "Xu & Meckl eq. 15.1",
        "the feedforward of Stojčić\n    eq. 16 (wrapped docstring)",
        "Stojčić's eq. 11 gains",
        "Ljung, System Identification, eq. 9.19",
        'design=dict(method="eq13")',
        "frequency 2 * pi * f; a sequence of 5 requests",
    ],
)
def test_accepted(text):
    assert check_citations.check_text(text) == []


@pytest.mark.parametrize(
    "text",
    [
        "eq. 11",
        "Stojčić eqs. 16–18",
        "Stojčić eq. 16-18",
        "Stojčić eq. 16–18",
        "Yang eqs. 7, 8",
        "Stojčić eq. 1, 8",
        "Xu & Meckl eq. 8/13",
        "Yang eq. 5 and 6",
        "Eq. 4 on the scan",
        "Stojčić Eq. 4",
        "equation 4",
        "(Stojčić eqs. 6, 9)",
        "Stojčić (2015) §4A and eq. 1",
    ],
)
def test_rejected(text):
    bad = check_citations.check_text(text)
    assert len(bad) == 1 and bad[0][1] == 1


def test_reports_file_and_line(tmp_path):
    f = tmp_path / "m.py"
    f.write_text('"""Stojčić eq. 1 (Stojcic).\n\nSee eq. 4.\n"""\n', encoding="utf-8")
    assert check_citations.check_files([f]) == [(str(f), 3, "See eq. 4.")]
    assert check_citations.main([str(f)]) == 1
    f.write_text('"""Stojčić eq. 1 (ASCII: Stojcic)."""\n', encoding="utf-8")
    assert check_citations.main([str(f)]) == 0


def test_ascii_spelling_in_the_module_docstring(tmp_path):
    f = tmp_path / "m.py"
    f.write_text('"""A module."""\nX = 1  # Stojčić eq. 1\n', encoding="utf-8")
    assert check_citations.check_files([f]) == [
        (str(f), 1, "module docstring lacks the ASCII spelling 'Stojcic'")
    ]
    f.write_text('"""A module (Stojcic)."""\nX = 1  # Stojčić eq. 1\n', encoding="utf-8")
    assert check_citations.check_files([f]) == []
    f.write_text('"""Xu & Meckl eq. 1 only."""\n', encoding="utf-8")
    assert check_citations.check_files([f]) == []


def test_package_citations_follow_the_form():
    bad = check_citations.check_files(check_citations.default_paths())
    assert bad == [], "\n".join(f"{n}:{l}: {t}" for n, l, t in bad)


def test_ascii_grep_finds_the_law():
    """``grep -rn "Stojcic eq. 17" jerklab/`` and ``grep -rn "Stojčić eq. 17" jerklab/`` find the law."""
    for spelling in ("Stojcic eq. 17", "Stojčić eq. 17"):
        hits = {
            p.relative_to(ROOT).as_posix()
            for p in check_citations.default_paths()
            if spelling in p.read_text(encoding="utf-8")
        }
        assert "jerklab/law.py" in hits, spelling
