"""Every attack of issue 32 and its outcome: ``python -m benchmarks security [AREA ...]``.

The attacks live in registered *areas*, each in a module of its own (``benchmarks/attacks_*.py``
or ``benchmarks/_attacks_*.py``, imported by :func:`load`). A module registers attacks in one
of two ways:

- :func:`area`: one function ``run(tmp) -> [(attack, held, outcome), ...]`` that tries a whole
  area at once (grading runs every crafted submission in one class folder through the real
  ``python -m jerklab.lab grade``);
- :func:`attack`: one function ``() -> (stopped, detail)`` per attack, grouped by area (the
  hub logins, the rig queue); it raises :class:`Skip` when it cannot be tried here (a tool or
  root missing).

The table prints every attack with ``held`` (yes: the defence held; for a row that checks
honest work, that it still scores) and what came out, then the count held per area. The tests
in tests/security/ are the same attacks with assertions; this table is the count to quote
before and after a fix.

    python -m benchmarks security
    python -m benchmarks security --only=grading --only=hub
    python -m benchmarks.bench_security grading hub

Against an older checkout (the "before" count), from a folder holding only ``benchmarks/``,
so that the checkout's jerklab is the one imported, in process and by every command the
attacks start::

    PYTHONPATH=/path/to/old/checkout python -m benchmarks security
"""

from __future__ import annotations

import argparse
import importlib
import os
import pathlib
import sys
import tempfile
import time
import traceback

from benchmarks._record import table

__all__ = ["AREAS", "ATTACKS", "Skip", "area", "attack", "load", "main"]

HERE = pathlib.Path(__file__).parent

#: area name -> function(tmp folder) -> [(attack, held, outcome)]
AREAS: dict = {}

#: ``(area, name, function)``; ``function()`` returns ``(stopped, detail)`` or raises :class:`Skip`
ATTACKS: list = []


class Skip(Exception):
    """The attack cannot be tried here (the reason is the message)."""


def area(name):
    """Register the decorated ``run(tmp) -> rows`` as the attacks of area ``name``."""

    def deco(fn):
        AREAS[name] = fn
        return fn

    return deco


def attack(area_name, name):
    """Register the decorated ``() -> (stopped, detail)`` as one attack of ``area_name``."""

    def deco(fn):
        ATTACKS.append((area_name, name, fn))
        return fn

    return deco


def _run_attacks(area_name):
    def run(tmp):
        rows = []
        for a, name, fn in ATTACKS:
            if a != area_name:
                continue
            t0 = time.monotonic()
            try:
                stopped, detail = fn()
                held = bool(stopped)
            except Skip as exc:
                held, detail = None, f"skipped: {exc}"
            except Exception as exc:  # noqa: BLE001 - an attack that crashes is reported
                held, detail = False, f"error {type(exc).__name__}: {exc}"
                traceback.print_exc()
            rows.append((name, held, f"{detail} ({time.monotonic() - t0:.1f} s)"))
        return rows

    return run


def load():
    """Import every attack module (each registers its area or its attacks); return the areas.

    The modules register with ``benchmarks.bench_security`` by name, which is another module
    object than this one when it runs as ``python -m benchmarks.bench_security``: the
    registry read is always the named module's."""
    if __name__ != "benchmarks.bench_security":
        return importlib.import_module("benchmarks.bench_security").load()
    for pattern in ("attacks_*.py", "_attacks_*.py"):
        for p in sorted(HERE.glob(pattern)):
            importlib.import_module(f"benchmarks.{p.stem}")
    for a, _, _ in ATTACKS:
        AREAS.setdefault(a, _run_attacks(a))
    return AREAS


def main(argv=None):
    ap = argparse.ArgumentParser(prog="python -m benchmarks security")
    ap.add_argument("areas", nargs="*", help="areas to run (default: all)")
    ap.add_argument("--only", action="append", default=[], help="run only this area (repeatable)")
    args = ap.parse_args(argv or [])
    areas = load()
    names = args.areas + args.only or sorted(areas)
    unknown = [n for n in names if n not in areas]
    if unknown:
        print(f"unknown area(s) {unknown}; known: {sorted(areas)}", file=sys.stderr)
        return 2
    summary = []
    for name in names:
        with tempfile.TemporaryDirectory(prefix=f"bench-security-{name}-") as tmp:
            t0 = time.monotonic()
            rows = areas[name](pathlib.Path(tmp))
            wall = time.monotonic() - t0
        shown = {True: "yes", False: "NO", None: "skipped"}
        table(
            f"{name}: attacks and outcomes",
            ["attack", "held", "outcome"],
            [[a, shown[ok], str(out)[:100]] for a, ok, out in rows],
            note=f"{wall:.0f} s, load average {os.getloadavg()[0]:.1f}",
        )
        summary.append(
            [
                name,
                sum(1 for _, ok, _ in rows if ok),
                sum(1 for _, ok, _ in rows if ok is False),
                sum(1 for _, ok, _ in rows if ok is None),
            ]
        )
    table("held per area", ["area", "held", "not held", "skipped"], summary)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
