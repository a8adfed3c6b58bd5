"""Every attack of issue 32 tried on this checkout, with its outcome (``python -m benchmarks security``).

The attacks live in registry modules (:data:`PARTS`), each adding its own with
:func:`attack`; this module runs them all, one after another, and prints one row per attack:
``stopped`` (the attack failed, as it must), ``NOT STOPPED`` (it worked), or ``skipped`` with
the reason (a tool or root missing). The tests in tests/security/ are the same attacks with
assertions; this table is the count to quote before and after a fix.

    python -m benchmarks security
    python -m benchmarks.bench_security --only queue
"""

from __future__ import annotations

import argparse
import importlib
import time
import traceback

from benchmarks._record import table

__all__ = ["ATTACKS", "PARTS", "Skip", "attack", "main"]

#: ``(area, name, function)``; ``function()`` returns ``(stopped: bool, detail: str)`` or raises
#: :class:`Skip`.
ATTACKS: list[tuple[str, str, object]] = []

#: Modules that register attacks when imported (append yours).
PARTS = ["benchmarks._attacks_hub"]


class Skip(Exception):
    """The attack cannot be tried here (the reason is the message)."""


def attack(area, name):
    """Register the decorated ``() -> (stopped, detail)`` as an attack of ``area``."""

    def deco(fn):
        ATTACKS.append((area, name, fn))
        return fn

    return deco


def run(only=None):
    """Run the attacks (of the areas in ``only``, if given); return the table rows."""
    for part in PARTS:
        importlib.import_module(part)
    rows = []
    for area, name, fn in ATTACKS:
        if only and area not in only:
            continue
        t0 = time.monotonic()
        try:
            stopped, detail = fn()
            outcome = "stopped" if stopped else "NOT STOPPED"
        except Skip as exc:
            outcome, detail = "skipped", str(exc)
        except Exception as exc:  # noqa: BLE001 - an attack that crashes is reported, not hidden
            outcome = "error"
            detail = f"{type(exc).__name__}: {exc}"[:160]
            traceback.print_exc()
        rows.append([f"{area}: {name}", outcome, round(time.monotonic() - t0, 1), detail[:110]])
    return rows


def main(argv=None):
    ap = argparse.ArgumentParser(prog="python -m benchmarks security")
    ap.add_argument("--only", action="append", help="run only this area (repeatable)")
    args = ap.parse_args(argv or [])
    rows = run(args.only)
    counts = {
        k: sum(r[1] == k for r in rows) for k in ("stopped", "NOT STOPPED", "skipped", "error")
    }
    table(
        "Attacks of issue 32 on this checkout",
        ["attack", "outcome", "s", "detail"],
        rows,
        note=", ".join(f"{v} {k}" for k, v in counts.items()),
    )
    return counts


if __name__ == "__main__":
    import sys

    main(sys.argv[1:])
