"""Equation citations read "Stojčić eq. 17", "Xu & Meckl eqs. 3–6" or "Yang eqs. 7, 8".

``tools/check_citations.py`` finds the offenders and, with ``--find``, every citation of one
equation (inside lists and ranges too); the checker itself is tested on examples here, and every
module of the package (``jerklab/**/*.py``) must pass it.
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
        "Stojčić eqs. 16–18",
        "Stojčić eqs. 12, 13",
        "Xu & Meckl eqs. 3–6",
        "Xu & Meckl eqs. 3–6, 13, 16",
        "(Xu & Meckl eqs. 14.1, 15.1, 16, 17)",
        "Yang eqs. 7, 8",
        "Yang eqs. 7 and 8",
        "(Stojčić eqs. 6, 9)",
        "Stojcic eqs. 1, 16–18.",
        "the PID of Stojčić\n    eqs. 17, 18 (wrapped docstring)",
        "(Xu & Meckl eqs. 14.1, 15.1,\n    16, 17 wrapped inside the list)",
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
        "eqs. 16–18",
        "Stojčić eq. 16-18",
        "Stojčić eq. 16–18",
        "Stojčić eqs. 16-18",
        "Stojčić eqs. 18–16",
        "Stojčić eqs. 12",
        "Stojčić eq. 1, 8",
        "Xu & Meckl eq. 8/13",
        "Xu & Meckl eqs. 8/13",
        "Xu & Meckl eqs. 3–6/13",
        "Yang eq. 5 and 6",
        "Eq. 4 on the scan",
        "Stojčić Eq. 4",
        "Stojčić Eqs. 4, 5",
        "equation 4",
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
    assert bad == [], "\n".join(f"{n}:{line}: {t}" for n, line, t in bad)


@pytest.mark.parametrize(
    "numbers,expanded",
    [
        ("17", ["17"]),
        ("16–18", ["16", "17", "18"]),
        ("3–6, 13", ["3", "4", "5", "6", "13"]),
        ("14.1, 15.1, 16, 17", ["14.1", "15.1", "16", "17"]),
        ("15.1–17", ["15.1", "16", "17"]),
        ("7 and 8", ["7", "8"]),
        ("1, 16–18", ["1", "16", "17", "18"]),
        ("14.1, 15.1,\n    16, 17", ["14.1", "15.1", "16", "17"]),
    ],
)
def test_lists_and_ranges_expand(numbers, expanded):
    assert check_citations.expand(numbers) == expanded


def test_find_sees_an_equation_inside_a_range(tmp_path):
    f = tmp_path / "m.py"
    f.write_text(
        '"""Stojcic.\n\nThe law, Stojčić eqs. 16–18.\n"""\n'
        "X = 1  # Stojcic eq. 17 alone\n"
        "Y = 2  # Stojčić eqs. 12, 13 and Yang eqs. 17, 18\n"
        "Z = 3  # Stojčić eq. 170 is not 17\n",
        encoding="utf-8",
    )
    hits = check_citations.find("Stojčić eq. 17", [f])
    assert [h[1] for h in hits] == [3, 5]
    assert check_citations.find("Stojcic eq. 17", [f]) == hits  # either spelling asks the same
    assert [h[1] for h in check_citations.find("Yang eq. 17", [f])] == [6]
    assert check_citations.find("Stojčić eq. 14", [f]) == []
    assert check_citations.main(["--find", "Stojčić eq. 13", str(f)]) == 0
    assert check_citations.main(["--find", "Stojčić eq. 14", str(f)]) == 1
    with pytest.raises(ValueError, match="query"):
        check_citations.find("eq. 17", [f])


def test_find_locates_the_law_in_either_spelling():
    """``--find "Stojčić eq. 17"`` and ``--find "Stojcic eq. 17"`` find the law, although its
    docstrings cite it inside "Stojčić eqs. 17, 18" and "Stojcic eqs. 1, 16–18"."""
    for spelling in ("Stojcic eq. 17", "Stojčić eq. 17"):
        hits = {h[0] for h in check_citations.find(spelling, check_citations.default_paths())}
        assert "jerklab/law.py" in hits, spelling


def test_no_long_lists_of_single_citations_left():
    """The package writes "Xu & Meckl eqs. 3–6", not "Xu & Meckl eq. 3, Xu & Meckl eq. 4, ..."."""
    import re

    chain = re.compile(
        r"(Stojčić|Stojcic|Xu & Meckl|Yang) eq\. [\d.]+(?:,\s*|\s+and\s+|\s+to\s+)\1 eq\. [\d.]+"
    )
    left = [
        f"{p.relative_to(ROOT)}: {m.group(0)}"
        for p in check_citations.default_paths()
        for m in chain.finditer(p.read_text(encoding="utf-8"))
    ]
    assert left == []
