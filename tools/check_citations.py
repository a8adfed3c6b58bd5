#!/usr/bin/env python3
"""List the equation citations in jerklab that do not follow the house form.

The form (CONTRIBUTING.md, issue 19): one paper, one number each, so that
``grep -rn "Stojčić eq. 17"`` finds the implementation::

    Stojčić eq. 17      Stojcic eq. 17      Xu & Meckl eq. 13      Yang eq. 7

A sub-numbered equation of the paper (Xu & Meckl eq. 15.1) is one number. Offenders are
citations without the paper's name ("eq. 11"), plural or ranged forms ("eqs. 12–13",
"eq. 16-18", "eqs. 7, 8", "eq. 8/13", "eq. 5 and 6"), a capital "Eq." and "equation 4".
A citation of another source named just before it (Ljung's book, Mayergoyz) is not a paper
equation and is left alone. A module that cites Stojčić must also give the ASCII spelling
"Stojcic" in its docstring (so ``grep -rn Stojcic`` finds it).

Usage::

    python tools/check_citations.py [paths...]     # default: every jerklab/**/*.py

prints ``file:line: text`` for each offender and exits 1 if there is any, 0 otherwise.
"""

from __future__ import annotations

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
#: the accepted form, anchored at the citation's start
GOOD = re.compile(r"eq\. \d+(?:\.\d+)?(?![\d.]*\s*(?:[-–/,]\s*\d|and\s+\d|&\s*\d))")
#: the paper's name right before the citation (possibly across a line break in a docstring)
NAMED = re.compile(PAPERS + r"(?:'s)?\s+$")


def check_text(text: str, name: str = "<text>") -> list[tuple[str, int, str]]:
    """Offending citations in ``text`` as ``(name, line, excerpt)``."""
    out = []
    for m in CITE.finditer(text):
        start = m.start()
        before = text[max(0, start - _LOOKBEHIND) : start]
        if OTHER_SOURCES.search(before) and not re.search(PAPERS, before.split("\n")[-1]):
            continue
        ok = GOOD.match(text, start) is not None and NAMED.search(text[max(0, start - 40) : start])
        if not ok:
            line = text.count("\n", 0, start) + 1
            lo = text.rfind("\n", 0, start) + 1
            hi = text.find("\n", start)
            out.append((name, line, text[lo : hi if hi >= 0 else None].strip()))
    return out


def check_ascii_spelling(text: str, name: str = "<text>") -> list[tuple[str, int, str]]:
    """A module that cites Stojčić must give the ASCII spelling "Stojcic" in its docstring."""
    import ast

    try:
        doc = ast.get_docstring(ast.parse(text)) or ""
    except SyntaxError:
        doc = ""
    if "Stojčić" in text and "Stojcic" not in doc:
        return [(name, 1, "module docstring lacks the ASCII spelling 'Stojcic'")]
    return []


def check_files(paths) -> list[tuple[str, int, str]]:
    out = []
    for p in paths:
        p = Path(p)
        rel = p.resolve().relative_to(ROOT) if p.resolve().is_relative_to(ROOT) else p
        text = p.read_text(encoding="utf-8")
        out.extend(check_ascii_spelling(text, str(rel)))
        out.extend(check_text(text, str(rel)))
    return out


def default_paths() -> list[Path]:
    return sorted(f for g in DEFAULT_GLOBS for f in ROOT.glob(g))


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    paths = [Path(a) for a in argv] or default_paths()
    bad = check_files(paths)
    for name, line, excerpt in bad:
        print(f"{name}:{line}: {excerpt}")
    total = sum(len(CITE.findall(Path(p).read_text(encoding="utf-8"))) for p in paths)
    n_doc = sum(1 for b in bad if b[2].startswith("module docstring"))
    print(
        f"{len(bad) - n_doc} of {total} equation citations do not read 'Stojčić eq. N' / 'Xu & Meckl eq. N' / "
        f"'Yang eq. N'; {n_doc} module docstrings lack the ASCII spelling 'Stojcic'",
        file=sys.stderr,
    )
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
