"""Grading rate: solved lab-1 hand-ins per minute through ``python -m jerklab.lab grade``.

Each hand-in is lab 1's worksheet with the master's solutions, for its own student ID, packed
as a student's ``S.submit()`` packs it. The real command grades the folder (one bubblewrap
sandbox per hand-in, the hidden motor served by the grader, the answers scored outside), once
per ``--jobs`` value; the table gives the wall time and the rate. Issue 32 asks for at least 4
hand-ins a minute on 2 cores (30 in at most 8 minutes); the grader before it took about 50 s a
hand-in, one after the other (1.2 a minute). The machine's load average is printed with the
table: on a shared machine the rate falls with it.

Run: ``python -m benchmarks grading [--n=8] [--jobs=1,2]``.
"""

from __future__ import annotations

import argparse
import csv
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from benchmarks._record import table

KEY = "benchmark-grading-key"


def solved_worksheet(student: str) -> bytes:
    """Lab 1's worksheet as a student has it (jerklab's check runner), solved, for ``student``."""
    from jerklab.lab.grade import solved_master

    return solved_master(1, student)


def _grade(subs: Path, jobs: int, env) -> tuple[float, list]:
    out = subs.parent / f"grades-{jobs}.csv"
    t0 = time.monotonic()
    r = subprocess.run(
        [
            sys.executable,
            "-m",
            "jerklab.lab",
            "grade",
            str(subs),
            "--out",
            str(out),
            "--jobs",
            str(jobs),
            "--timeout",
            "600",
        ],
        env=env,
        capture_output=True,
        text=True,
    )
    wall = time.monotonic() - t0
    if r.returncode != 0:
        raise RuntimeError(f"grade failed:\n{r.stderr[-2000:]}")
    return wall, list(csv.DictReader(out.open()))


def main(argv=None):
    ap = argparse.ArgumentParser(
        prog="python -m benchmarks grading", description=__doc__.split("\n")[0]
    )
    ap.add_argument("--n", type=int, default=8, help="hand-ins (default 8)")
    ap.add_argument("--jobs", default="1,2", help="--jobs values, comma separated (default 1,2)")
    args = ap.parse_args(argv or [])
    from jerklab.lab.handin import pack

    env = dict(os.environ, JERKLAB_INSTRUCTOR_KEY=KEY)
    env.pop("JERKLAB_LAB_GRADING", None)
    rows = []
    with tempfile.TemporaryDirectory(prefix="bench-grading-") as tmp:
        subs = Path(tmp) / "subs"
        subs.mkdir()
        for i in range(args.n):
            sid = f"bench{i:03d}"
            pack(
                {"notebook/lab1_identify.ipynb": solved_worksheet(sid)},
                sid,
                1,
                subs / f"lab1_{sid}.zip",
            )
        for jobs in (int(j) for j in args.jobs.split(",")):
            load0 = os.getloadavg()[0]
            wall, graded = _grade(subs, jobs, env)
            full = sum(
                1
                for r in graded
                if r["status"] == "graded" and float(r["total"]) == float(r["max"]) > 0
            )
            rows.append(
                [
                    f"--jobs {jobs}",
                    args.n,
                    full,
                    round(wall, 1),
                    round(60.0 * args.n / wall, 2),
                    round(load0, 1),
                ]
            )
    table(
        "lab 1 hand-ins graded in sandboxes",
        ["run", "hand-ins", "full marks", "wall s", "hand-ins/min", "load avg"],
        rows,
        note=f"{os.cpu_count()} CPUs; the goal: >= 4 hand-ins/min on 2 cores",
    )


if __name__ == "__main__":
    main(sys.argv[1:])
