#!/usr/bin/env python3
"""Check the equation citations in jerklab against the house form, and find them.

The form (CONTRIBUTING.md): the paper's name, then one equation or a list of them::

    Stojčić eq. 17          Stojcic eq. 17          Xu & Meckl eq. 15.1      Yang eq. 7
    Stojčić eqs. 16–18      Stojčić eqs. 12, 13     Xu & Meckl eqs. 3–6, 13  Yang eqs. 7 and 8

A list is ``eqs.`` followed by two or more numbers: single equations and ranges (an en dash, the
first number below the second) separated by ", " or " and " (a docstring may wrap the line
after either). A sub-numbered equation of the paper
(Xu & Meckl eq. 15.1) is one number. Offenders are citations without the paper's name
("eq. 11"), a list or range after the singular "eq." ("eq. 16–18", "eq. 1, 8"), the plural with
one number ("eqs. 12"), a hyphen or slash between numbers ("eqs. 16-18", "eq. 8/13"), a range
that does not rise ("eqs. 18–16"), a capital "Eq." and "equation 4". A citation of another source
named just before it (Ljung's book, Mayergoyz) is not a paper equation and is left alone. A module
that cites Stojčić must also give the ASCII spelling "Stojcic" in its module docstring.

Greppability: ``grep "Stojčić eq. 17"`` misses a range; ``--find`` does not. It expands every
list and range, so ``--find "Stojčić eq. 17"`` (or ``"Stojcic eq. 17"``) lists each line that
cites equation 17, alone or inside "Stojčić eqs. 16–18".

Usage::

    python tools/check_citations.py [paths...]           # default: every jerklab/**/*.py
    python tools/check_citations.py --find "Yang eq. 7" [paths...]

The check prints ``file:line: text`` for each offender and exits 1 if there is any, 0 otherwise;
``--find`` prints ``file:line: text`` for each citation of that equation and exits 1 if there is none.
"""

from __future__ import annotations

import argparse
import ast
import re
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_GLOBS = ("jerklab/**/*.py",)

PAPERS = r"(?:Stojčić|Stojcic|Xu\s*&\s*Meckl|Yang)"
#: a citation of another source: this many characters before the "eq." may name it
OTHER_SOURCES = re.compile(r"(Ljung|Mayergoyz|Bhat\s*&\s*Miu\s*\()")
_LOOKBEHIND = 80

#: anything that cites an equation by number
CITE = re.compile(r"\b(?:[Ee]qs?\.\s*\(?\s*\d|[Ee]qn\.?\s*\d|[Ee]quations?\s+\(?\d)", re.UNICODE)
_NUM = r"\d+(?:\.\d+)?"
_ITEM = rf"{_NUM}(?:–{_NUM})?"
#: what may not follow an accepted citation: another number joined by a separator
_NO_MORE = r"(?![\d.]*\s*(?:[-–/,]\s*\d|and\s+\d|&\s*\d))"
#: the accepted forms, anchored at the citation's start (``eq.`` one number; ``eqs.`` a list)
SINGLE = re.compile(rf"eq\. ({_NUM}){_NO_MORE}")
_SEP = r"(?:,\s+(?:and\s+)?|\s+and\s+)"  # ", " or " and ", a line break allowed after either
PLURAL = re.compile(rf"eqs\. ({_ITEM}(?:{_SEP}{_ITEM})*){_NO_MORE}")
#: the paper's name right before the citation (possibly across a line break in a docstring)
NAMED = re.compile(r"(" + PAPERS + r")(?:'s)?\s+$")
#: a well-formed citation with its paper, for --find and the THEORY.md check
WELL_FORMED = re.compile(rf"({PAPERS})(?:'s)?\s+(eqs?\.) ({_ITEM}(?:{_SEP}{_ITEM})*)")


def _key(num: str) -> tuple[int, int]:
    whole, _, sub = num.partition(".")
    return int(whole), int(sub or 0)


def expand(numbers: str) -> list[str]:
    """The equations a list names: ``"3–6, 13"`` → ``["3", "4", "5", "6", "13"]``.

    A range runs over the whole numbers from its first to its last ("15.1–17" gives 15.1, 16, 17).
    """
    out = []
    for item in re.split(_SEP, numbers):
        lo, dash, hi = item.partition("–")
        if not dash:
            out.append(lo)
            continue
        out.append(lo)
        out.extend(str(n) for n in range(_key(lo)[0] + 1, _key(hi)[0]))
        out.append(hi)
    return out


def _plural_ok(numbers: str) -> bool:
    """A plural citation names two or more equations and each range rises."""
    items = re.split(_SEP, numbers)
    for item in items:
        lo, dash, hi = item.partition("–")
        if dash and not _key(lo) < _key(hi):
            return False
    return len(items) > 1 or "–" in numbers


def check_text(text: str, name: str = "<text>") -> list[tuple[str, int, str]]:
    """Offending citations in ``text`` as ``(name, line, excerpt)``."""
    out = []
    for m in CITE.finditer(text):
        start = m.start()
        before = text[max(0, start - _LOOKBEHIND) : start]
        if OTHER_SOURCES.search(before) and not re.search(PAPERS, before.split("\n")[-1]):
            continue
        single, plural = SINGLE.match(text, start), PLURAL.match(text, start)
        form = single is not None or (plural is not None and _plural_ok(plural.group(1)))
        ok = form and NAMED.search(text[max(0, start - 40) : start])
        if not ok:
            line = text.count("\n", 0, start) + 1
            lo = text.rfind("\n", 0, start) + 1
            hi = text.find("\n", start)
            out.append((name, line, text[lo : hi if hi >= 0 else None].strip()))
    return out


def _paper(name: str) -> str:
    name = re.sub(r"\s*&\s*", " & ", name)
    return "Stojčić" if name == "Stojcic" else name


def citations(text: str) -> list[tuple[int, str, str]]:
    """Every well-formed citation in ``text`` expanded: ``(line, paper, number)``, paper spelled
    "Stojčić", "Xu & Meckl" or "Yang"."""
    out = []
    for m in WELL_FORMED.finditer(text):
        line = text.count("\n", 0, m.start()) + 1
        paper = _paper(m.group(1))
        out.extend((line, paper, n) for n in expand(m.group(3)))
    return out


def find(query: str, paths) -> list[tuple[str, int, str]]:
    """Lines that cite the equation ``query`` (e.g. ``"Stojčić eq. 17"``), alone, in a list or
    inside a range, as ``(file, line, text)``."""
    m = re.fullmatch(rf"\s*({PAPERS})\s+eqs?\.\s*({_NUM})\s*", query)
    if m is None:
        raise ValueError(f"query must read like 'Stojčić eq. 17', got {query!r}")
    want = (_paper(m.group(1)), m.group(2))
    out = []
    for p in paths:
        p = Path(p)
        text = p.read_text(encoding="utf-8")
        lines = text.splitlines()
        seen = set()
        for line, paper, num in citations(text):
            if (paper, num) == want and line not in seen:
                seen.add(line)
                out.append((_rel(p), line, lines[line - 1].strip()))
    return out


def check_ascii_spelling(text: str, name: str = "<text>") -> list[tuple[str, int, str]]:
    """A module that cites Stojčić must give the ASCII spelling "Stojcic" in its docstring."""
    try:
        doc = ast.get_docstring(ast.parse(text)) or ""
    except SyntaxError:
        doc = ""
    if "Stojčić" in text and "Stojcic" not in doc:
        return [(name, 1, "module docstring lacks the ASCII spelling 'Stojcic'")]
    return []


def _rel(p: Path) -> str:
    r = p.resolve()
    return str(r.relative_to(ROOT) if r.is_relative_to(ROOT) else p)


def check_files(paths) -> list[tuple[str, int, str]]:
    out = []
    for p in paths:
        p = Path(p)
        text = p.read_text(encoding="utf-8")
        out.extend(check_ascii_spelling(text, _rel(p)))
        out.extend(check_text(text, _rel(p)))
    return out


def default_paths() -> list[Path]:
    return sorted(f for g in DEFAULT_GLOBS for f in ROOT.glob(g))


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("paths", nargs="*", help="files to read (default: every jerklab/**/*.py)")
    ap.add_argument(
        "--find", metavar="CITATION", help='list the lines citing e.g. "Stojčić eq. 17"'
    )
    a = ap.parse_args(argv)
    paths = [Path(p) for p in a.paths] or default_paths()
    if a.find is not None:
        try:
            hits = find(a.find, paths)
        except ValueError as exc:
            ap.error(str(exc))
        for name, line, text in hits:
            print(f"{name}:{line}: {text}")
        return 0 if hits else 1
    bad = check_files(paths)
    for name, line, excerpt in bad:
        print(f"{name}:{line}: {excerpt}")
    total = sum(len(CITE.findall(Path(p).read_text(encoding="utf-8"))) for p in paths)
    n_doc = sum(1 for b in bad if b[2].startswith("module docstring"))
    print(
        f"{len(bad) - n_doc} of {total} equation citations do not read 'Stojčić eq. N' / "
        f"'Xu & Meckl eqs. N–M, K' / 'Yang eq. N'; {n_doc} module docstrings lack the ASCII "
        "spelling 'Stojcic'",
        file=sys.stderr,
    )
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
