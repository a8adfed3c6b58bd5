"""Benchmark tables: printed, and kept for the JSON record that ``python -m benchmarks`` writes.

A benchmark module calls :func:`table` with a title, the column names and the rows (first
cell a label, the others numbers or text). The table is printed at once; the runner
(:mod:`benchmarks.__main__`) collects every table of the run, together with the printed
text of modules that print by hand, into one JSON record in ``benchmarks/results/``
(machine, versions, date, git commit). ``python -m benchmarks compare A.json B.json``
prints, for every table and row present in both records, the ratio B/A of each numeric
cell.
"""

from __future__ import annotations

import math
import numbers

__all__ = ["table", "TABLES", "format_table"]

#: tables recorded in this process: dicts with module, title, columns, rows, note
TABLES: list[dict] = []
#: the module currently running (set by the runner)
CURRENT = {"module": None}


def _cell(x):
    if isinstance(x, bool):
        return str(x)
    if isinstance(x, numbers.Integral):
        return str(int(x))
    if isinstance(x, numbers.Real):
        x = float(x)
        if not math.isfinite(x):
            return str(x)
        a = abs(x)
        if a == 0.0:
            return "0"
        if a >= 1e6 or a < 1e-3:
            return f"{x:.3e}"
        if a >= 100:
            return f"{x:.1f}"
        if a >= 1:
            return f"{x:.3f}"
        return f"{x:.4f}"
    return str(x)


def format_table(title, columns, rows, note=None) -> str:
    """The table as aligned text (label column left, the others right)."""
    cells = [[_cell(c) for c in r] for r in rows]
    widths = [
        max([len(str(col))] + [len(r[j]) for r in cells if j < len(r)])
        for j, col in enumerate(columns)
    ]
    out = [title]
    out.append(
        "  ".join(
            str(c).ljust(w) if j == 0 else str(c).rjust(w)
            for j, (c, w) in enumerate(zip(columns, widths))
        )
    )
    for r in cells:
        out.append(
            "  ".join(
                c.ljust(w) if j == 0 else c.rjust(w) for j, (c, w) in enumerate(zip(r, widths))
            )
        )
    if note:
        out.append(note)
    return "\n".join(out)


def _jsonable(x):
    if isinstance(x, bool) or x is None or isinstance(x, str):
        return x
    if isinstance(x, numbers.Integral):
        return int(x)
    if isinstance(x, numbers.Real):
        x = float(x)
        return x if math.isfinite(x) else str(x)
    return str(x)


def table(title, columns, rows, note=None):
    """Print a table and keep it for the run's JSON record.

    Parameters
    ----------
    title : str
        Unique within the module (the key :func:`compare` matches on).
    columns : list of str
        Column names; the first column holds the row labels.
    rows : list of sequences
        One row per entry, ``len(columns)`` cells each.
    note : str, optional
        A line printed under the table (and recorded).
    """
    columns = [str(c) for c in columns]
    rows = [list(r) for r in rows]
    for r in rows:
        if len(r) != len(columns):
            raise ValueError(f"row {r!r} has {len(r)} cells for {len(columns)} columns")
    print(format_table(title, columns, rows, note))
    TABLES.append(
        dict(
            module=CURRENT["module"],
            title=str(title),
            columns=columns,
            rows=[[_jsonable(c) for c in r] for r in rows],
            note=note,
        )
    )
