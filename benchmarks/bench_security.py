"""Every attack of issue 32 and its outcome: ``python -m benchmarks security [AREA ...]``.

The attacks live in registered *areas*: an area is a function that runs its attacks and
returns one ``(attack, blocked, outcome)`` row each. :data:`AREAS` is the registry; a module
``benchmarks/attacks_<area>.py`` adds its area with :func:`area` (imported by :func:`load`),
so that grading, the hub and the rig queue each keep their own file:

>>> from benchmarks.bench_security import area
>>> @area("example")                     # doctest: +SKIP
... def run(tmp):
...     return [("an attack", True, "refused")]

The table prints every attack with ``held`` (yes: the defence held; for a row that checks
honest work, that it still scores) and what came out, then the count held per area.
Areas: ``grading`` (:mod:`benchmarks.attacks_grading`: the crafted submissions through the
real ``python -m jerklab.lab grade``).
"""

from __future__ import annotations

import importlib
import os
import pathlib
import sys
import tempfile
import time

from benchmarks._record import table

HERE = pathlib.Path(__file__).parent

#: area name -> function(tmp folder) -> [(attack, blocked, outcome)]
AREAS: dict = {}


def area(name):
    """Register the decorated function as the attacks of area ``name``."""

    def deco(fn):
        AREAS[name] = fn
        return fn

    return deco


def load():
    """Import every ``benchmarks/attacks_*.py`` (each registers its area)."""
    for p in sorted(HERE.glob("attacks_*.py")):
        importlib.import_module(f"benchmarks.{p.stem}")
    return AREAS


def main(argv=None):
    load()
    names = [a for a in (argv or []) if not a.startswith("-")] or sorted(AREAS)
    unknown = [n for n in names if n not in AREAS]
    if unknown:
        print(f"unknown area(s) {unknown}; known: {sorted(AREAS)}", file=sys.stderr)
        return 2
    summary = []
    for name in names:
        with tempfile.TemporaryDirectory(prefix=f"bench-security-{name}-") as tmp:
            t0 = time.monotonic()
            rows = AREAS[name](pathlib.Path(tmp))
            wall = time.monotonic() - t0
        table(
            f"{name}: attacks and outcomes",
            ["attack", "held", "outcome"],
            [[a, "yes" if ok else "NO", str(out)[:90]] for a, ok, out in rows],
            note=f"{wall:.0f} s, load average {os.getloadavg()[0]:.1f}",
        )
        summary.append([name, sum(1 for _, ok, _ in rows if ok), len(rows)])
    table("held per area", ["area", "held", "rows"], summary)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
