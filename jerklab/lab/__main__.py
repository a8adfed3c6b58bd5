"""``python -m jerklab.lab grade SUBMISSIONS_DIR --out grades.csv [--jobs N]``, ``... assign``
and ``... service`` (the class rig service, :mod:`jerklab.lab.service`).

``grade`` runs every worksheet in a bubblewrap sandbox and scores its exported answers
outside it (:mod:`jerklab.lab.grade`); without bubblewrap it refuses, unless
``--unsafe-no-sandbox`` is given for trusted submissions.
"""

from __future__ import annotations

import argparse
import sys

from jerklab.lab.grade import assign, grade_folder
from jerklab.lab.motors import instructor_key
from jerklab.lab.sandbox import SandboxUnavailable
from jerklab.lab.service import main as service_main
from jerklab.rig import load_profile


def main(argv=None):
    argv = sys.argv[1:] if argv is None else list(argv)
    if argv[:1] == ["service"]:
        return service_main(argv[1:])
    ap = argparse.ArgumentParser(prog="python -m jerklab.lab", description=__doc__)
    sub = ap.add_subparsers(dest="cmd", required=True)
    g = sub.add_parser("grade", help="grade a folder of hand-in zips and notebooks")
    g.add_argument("submissions", metavar="SUBMISSIONS_DIR")
    g.add_argument("--out", default="grades.csv", help="CSV to write (default grades.csv)")
    g.add_argument(
        "--feedback",
        default=None,
        help="folder for the feedback files (default: feedback/ beside the CSV)",
    )
    g.add_argument(
        "--timeout", type=float, default=300.0, help="seconds per submission (default 300)"
    )
    g.add_argument(
        "--jobs",
        type=int,
        default=1,
        help="submissions graded at once, one sandbox each (default 1)",
    )
    g.add_argument(
        "--unsafe-no-sandbox",
        action="store_true",
        help="grade without bubblewrap: the worksheets run as you (trusted submissions only)",
    )
    g.add_argument(
        "--check-log",
        default=None,
        help="the class rig service's check log: attempts per check into the CSV",
    )
    g.add_argument(
        "--profile",
        default=None,
        help="the class's motor profile, as given to the service's --profile (a built-in name "
        "or a profile file): the hidden motors and the lab's numbers are scored on it",
    )
    a = sub.add_parser(
        "assign", help="write the student worksheets (solutions stripped) from the masters"
    )
    a.add_argument("--out", default="notebooks/labs", help="folder (default notebooks/labs)")
    sub.add_parser(
        "service",
        help="run the class rig service (graded hidden motors; "
        "python -m jerklab.lab service --help)",
        add_help=False,
    )
    args = ap.parse_args(argv)
    if args.cmd == "grade":
        _, source = instructor_key(warn=True)
        if args.jobs < 1:
            ap.error(f"--jobs must be at least 1, got {args.jobs}")
        if args.unsafe_no_sandbox:
            print(
                "WARNING: --unsafe-no-sandbox: every worksheet runs as you, with no isolation "
                "(it can read your files and key and change other submissions)",
                file=sys.stderr,
            )
        if args.profile is not None:
            try:
                load_profile(args.profile)
            except (ValueError, TypeError, OSError) as exc:
                ap.error(f"--profile: {exc}")
        try:
            rows = grade_folder(
                args.submissions,
                args.out,
                args.feedback,
                args.timeout,
                jobs=args.jobs,
                unsafe_no_sandbox=args.unsafe_no_sandbox,
                check_log=args.check_log,
                profile=args.profile,
            )
        except SandboxUnavailable as exc:
            print(f"grade: refused: {exc}", file=sys.stderr)
            return 2
        for r in rows:
            print(
                f"{r['student'] or '?':>16}  lab {r['lab'] or '?'}  {r['total']:5.1f} / "
                f"{r['max']:4.1f}  {r['status']}"
            )
        print(f"{len(rows)} submissions -> {args.out} (instructor key from: {source})")
        return 0
    for p in assign(args.out):
        print(f"wrote {p}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
