"""Run every ``benchmarks/bench_*.py`` (or those named on the command line) and print its table.

Options after a name go to that benchmark (``python -m benchmarks class --minutes 0.5``). The
class load test (``class``, ~15 min) runs only when named.
"""
from __future__ import annotations

import importlib
import pathlib
import sys


#: Benchmarks that run only when named (long: a server and many clients).
OPT_IN = {"bench_class"}


def main(argv: list[str]) -> int:
    here = pathlib.Path(__file__).parent
    runs = []
    for arg in argv:
        if arg.startswith("-") and runs:
            runs[-1][1].append(arg)
        elif runs and runs[-1][1] and runs[-1][1][-1].startswith("--") and "=" not in runs[-1][1][-1]:
            runs[-1][1].append(arg)  # the value of the option before it
        else:
            runs.append((arg, []))
    if not runs:
        runs = [(p.stem, []) for p in sorted(here.glob("bench_*.py")) if p.stem not in OPT_IN]
    for name, opts in runs:
        mod = importlib.import_module(f"benchmarks.{name if name.startswith('bench_') else 'bench_' + name}")
        print(f"\n=== {mod.__name__} ===")
        if opts or mod.__name__.split(".")[-1] in OPT_IN:
            mod.main(opts)
        else:
            mod.main()
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
