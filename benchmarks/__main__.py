"""Run the benchmarks and keep a record; compare two records.

``python -m benchmarks [NAME ...]``
    Run every ``benchmarks/bench_*.py`` (or those named; ``faults``, the fault probe,
    ``class``, the class load test, and ``security``, the attacks of issue 32, only when
    named; ``--opt=value`` after a name goes to that benchmark: ``class --minutes=0.5
    --n=1,10``), print their tables and write the
    run as JSON to ``benchmarks/results/<UTC date>_<host>_<commit>.json``: the machine,
    Python and package versions, the date, the git commit of the jerklab that was
    imported, and every table (modules that print by hand are kept as text).
    ``--out PATH`` writes there instead, ``--no-save`` writes nothing.

``python -m benchmarks compare A.json B.json``
    For every table and row present in both records, the ratio B/A of each numeric cell
    (a time ratio > 1 means B is slower; for a "x peer" or rate column, higher is better).
"""

from __future__ import annotations

import contextlib
import datetime as _dt
import importlib
import io
import json
import os
import pathlib
import platform
import subprocess
import sys

from benchmarks import _record

HERE = pathlib.Path(__file__).parent
#: benchmarks run only when named (``python -m benchmarks faults``: the fault probe takes minutes)
ON_REQUEST = {"bench_faults", "bench_class", "bench_grading", "bench_security"}
RESULTS = HERE / "results"


class _Tee(io.TextIOBase):
    def __init__(self, *streams):
        self.streams = streams

    def write(self, s):
        for st in self.streams:
            st.write(s)
        return len(s)

    def flush(self):
        for st in self.streams:
            st.flush()


def _versions():
    out = {"python": platform.python_version()}
    for name in ("numpy", "scipy", "numba", "control", "matplotlib", "ruckig", "jerklab"):
        try:
            mod = importlib.import_module(name)
            out[name] = getattr(mod, "__version__", "?")
        except Exception:  # noqa: BLE001 - a missing optional peer is recorded as absent
            out[name] = None
    return out


def _git(root):
    def run(*args):
        try:
            return subprocess.run(
                ["git", "-C", str(root), *args], capture_output=True, text=True, timeout=10
            ).stdout.strip()
        except (OSError, subprocess.SubprocessError):
            return ""

    commit = run("rev-parse", "HEAD")
    dirty = bool(run("status", "--porcelain", "--untracked-files=no"))
    return {"commit": commit or None, "dirty": dirty if commit else None}


def _machine():
    cpu = platform.processor()
    try:
        for line in pathlib.Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    load = os.getloadavg() if hasattr(os, "getloadavg") else None
    return {
        "host": platform.node(),
        "system": platform.platform(),
        "cpu": cpu,
        "cpus": os.cpu_count(),
        "load_average": list(load) if load else None,
    }


def run(names, out=None, save=True, options=None):
    names = names or sorted(p.stem for p in HERE.glob("bench_*.py") if p.stem not in ON_REQUEST)
    import jerklab

    jl_root = pathlib.Path(jerklab.__file__).resolve().parent.parent
    started = _dt.datetime.now(_dt.timezone.utc)
    record = {
        "date": started.isoformat(timespec="seconds"),
        "machine": _machine(),
        "versions": _versions(),
        "jerklab_path": str(jl_root),
        "git": _git(jl_root),
        "argv": sys.argv[1:],
        "modules": {},
    }
    for name in names:
        modname = f"benchmarks.{name if name.startswith('bench_') else 'bench_' + name}"
        mod = importlib.import_module(modname)
        print(f"\n=== {mod.__name__} ===")
        _record.CURRENT["module"] = mod.__name__
        n0 = len(_record.TABLES)
        buf = io.StringIO()
        opts = (options or {}).get(name)
        with contextlib.redirect_stdout(_Tee(sys.stdout, buf)):
            if opts:
                mod.main(opts)
            else:
                mod.main()
        tables = _record.TABLES[n0:]
        entry = {"tables": tables}
        if not tables:
            entry["text"] = buf.getvalue()
        record["modules"][mod.__name__] = entry
    record["seconds"] = round((_dt.datetime.now(_dt.timezone.utc) - started).total_seconds(), 1)
    record["machine"]["load_average_end"] = (
        list(os.getloadavg()) if hasattr(os, "getloadavg") else None
    )
    if save:
        if out is None:
            RESULTS.mkdir(exist_ok=True)
            tag = (record["git"]["commit"] or "nogit")[:8] + (
                "-dirty" if record["git"]["dirty"] else ""
            )
            out = RESULTS / f"{started:%Y%m%dT%H%M%SZ}_{platform.node() or 'host'}_{tag}.json"
        out = pathlib.Path(out)
        out.write_text(json.dumps(record, indent=1, ensure_ascii=False) + "\n")
        print(f"\nrecord written: {out}")
    return record


def _numeric(x):
    return isinstance(x, (int, float)) and not isinstance(x, bool)


def compare(a_path, b_path, file=None):
    """Print B/A for every numeric cell of the tables and rows both records have."""
    file = sys.stdout if file is None else file
    A = json.loads(pathlib.Path(a_path).read_text())
    B = json.loads(pathlib.Path(b_path).read_text())
    print(f"A: {a_path}  ({A.get('date')}, {A.get('git', {}).get('commit')})", file=file)
    print(f"B: {b_path}  ({B.get('date')}, {B.get('git', {}).get('commit')})", file=file)
    print("cells: B/A", file=file)
    found = 0
    for mod, ea in A.get("modules", {}).items():
        eb = B.get("modules", {}).get(mod)
        if eb is None:
            continue
        tb_by_title = {t["title"]: t for t in eb.get("tables", [])}
        for ta in ea.get("tables", []):
            tb = tb_by_title.get(ta["title"])
            if tb is None:
                continue
            cols = [c for c in ta["columns"][1:] if c in tb["columns"]]
            rows_b = {str(r[0]): r for r in tb["rows"]}
            out_rows = []
            for ra in ta["rows"]:
                rb = rows_b.get(str(ra[0]))
                if rb is None:
                    continue
                cells = [str(ra[0])]
                for c in cols:
                    x = ra[ta["columns"].index(c)]
                    y = rb[tb["columns"].index(c)]
                    cells.append(y / x if _numeric(x) and _numeric(y) and x != 0 else "-")
                out_rows.append(cells)
            if out_rows:
                found += 1
                print("", file=file)
                print(
                    _record.format_table(
                        f"[{mod}] {ta['title']}", [ta["columns"][0]] + cols, out_rows
                    ),
                    file=file,
                )
    if not found:
        print("no table in common", file=file)
    return found


def main(argv: list[str]) -> int:
    if argv and argv[0] == "compare":
        if len(argv) != 3:
            print("usage: python -m benchmarks compare A.json B.json", file=sys.stderr)
            return 2
        compare(argv[1], argv[2])
        return 0
    save, out, names, options = True, None, [], {}
    it = iter(argv)
    for a in it:
        if a == "--no-save":
            save = False
        elif a == "--out":
            out = next(it, None)
            if out is None:
                print("--out needs a path", file=sys.stderr)
                return 2
        elif a.startswith("--") and names:
            # an option of the benchmark named before it (``class --minutes=0.5 --n=1,10``)
            options.setdefault(names[-1], []).append(a)
        else:
            names.append(a)
    run(names, out=out, save=save, options=options)
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
