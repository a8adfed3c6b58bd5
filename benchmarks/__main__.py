"""Run every ``benchmarks/bench_*.py`` (or those named on the command line) and print its table.

``python -m benchmarks faults`` runs the fault probe (``bench_faults.py``); it takes minutes, so a
plain ``python -m benchmarks`` (``make bench``) leaves it out (``ON_REQUEST``).
"""
from __future__ import annotations

import importlib
import pathlib
import sys


#: benchmarks run only when named on the command line
ON_REQUEST = {"bench_faults"}


def main(argv: list[str]) -> int:
    here = pathlib.Path(__file__).parent
    names = argv or sorted(p.stem for p in here.glob("bench_*.py") if p.stem not in ON_REQUEST)
    for name in names:
        mod = importlib.import_module(f"benchmarks.{name if name.startswith('bench_') else 'bench_' + name}")
        print(f"\n=== {mod.__name__} ===")
        mod.main()
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
