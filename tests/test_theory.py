"""docs/THEORY.md: every equation heading the code needs is there, every function it names exists,
and nothing points outside the repository."""

from __future__ import annotations

import importlib
import importlib.util
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
THEORY = (ROOT / "docs" / "THEORY.md").read_text(encoding="utf-8")
HEADINGS = [line for line in THEORY.splitlines() if line.startswith("#")]
_spec = importlib.util.spec_from_file_location("check_citations", ROOT / "tools/check_citations.py")
_citations = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(_citations)
MODULES = (
    "paper",
    "planner",
    "plant",
    "controller",
    "sim",
    "ident",
    "piezo",
    "hysteresis",
    "fpga",
    "multiaxis",
    "shaping",
    "peers",
    "plots",
    "protocol",
    "widgets",
    "rig",
)


def _in_heading(citation):
    pat = re.compile(re.escape(citation) + r"(?!\d)")
    return any(pat.search(h) for h in HEADINGS)


@pytest.mark.parametrize(
    "citation",
    [f"Stojčić eq. {i}" for i in range(1, 19)]
    + [
        f"Xu & Meckl eq. {i}"
        for i in (
            1,
            2,
            3,
            4,
            5,
            6,
            7,
            8,
            9,
            10,
            11,
            12,
            13,
            "14.1",
            "14.2",
            "15.1",
            "15.2",
            "15.3",
            16,
            17,
            18,
            19,
        )
    ]
    + [f"Yang eq. {i}" for i in range(1, 9)],
)
def test_every_equation_has_a_heading(citation):
    assert _in_heading(citation), citation


def test_well_formed_code_citations_are_explained():
    """Each equation the package cites ("Stojčić eq. N", or inside "Stojčić eqs. N–M, K") has its
    heading in THEORY.md; tools/check_citations.py expands the lists and ranges."""
    found = {
        f"{paper} eq. {num}"
        for f in _citations.default_paths()
        for _, paper, num in _citations.citations(f.read_text(encoding="utf-8"))
    }
    assert len(found) > 30  # the package cites the three papers
    missing = sorted(c for c in found if not _in_heading(c))
    assert missing == []


def test_named_functions_exist():
    refs = set(re.findall(r"`((?:%s)(?:\.[A-Za-z_][A-Za-z0-9_]*)+)" % "|".join(MODULES), THEORY))
    assert len(refs) > 60
    bad = []
    for ref in sorted(refs):
        parts = ref.split(".")
        try:
            obj = importlib.import_module(f"jerklab.{parts[0]}")
            for i, name in enumerate(parts[1:], 1):
                try:
                    obj = getattr(obj, name)
                except AttributeError:
                    obj = importlib.import_module(f"jerklab.{'.'.join(parts[: i + 1])}")
        except (AttributeError, ImportError):
            bad.append(ref)
    assert bad == []


# the developers' material beside the repository, spelled in pieces so this file does not name it
_SH = "sha" + "red"
OUTSIDE = (
    "../" + _SH,
    "/work/" + _SH,
    "READ" + "ING.md",
    "RIG" + "-NOTES",
    "LA" + "BS.md",
    "ARCHI" + "TECTURE.md",
    "STY" + "LE.md",
)


def test_the_ascii_spelling_and_no_outside_pointer():
    assert "Stojcic" in THEORY
    for outside in OUTSIDE:
        assert outside not in THEORY


def test_the_repository_points_inside_itself():
    """No file of the repository sends a reader to the developers' folder beside it or to their
    reading notes."""
    here = Path(__file__).resolve()
    roots = [
        ROOT / d
        for d in (
            "jerklab",
            "notebooks",
            "tests",
            "firmware",
            "docs",
            "data",
            "app",
            "benchmarks",
            "tools",
        )
    ] + [ROOT / "README.md", ROOT / "CONTRIBUTING.md"]
    pattern = re.compile("|".join(re.escape(o) for o in OUTSIDE + ("READING §",)))
    bad = []
    for root in roots:
        files = (
            [root]
            if root.is_file()
            else [f for f in root.rglob("*") if f.is_file()]
            if root.exists()
            else []
        )
        for f in files:
            if f.resolve() == here or f.suffix not in {
                ".py",
                ".ipynb",
                ".md",
                ".h",
                ".cpp",
                ".c",
                ".ino",
                ".v",
                ".txt",
                ".json",
                "",
            }:
                continue
            try:
                text = f.read_text(encoding="utf-8")
            except (UnicodeDecodeError, OSError):
                continue
            bad += [
                f"{f.relative_to(ROOT)}:{i}"
                for i, line in enumerate(text.splitlines(), 1)
                if pattern.search(line)
            ]
    assert bad == []
