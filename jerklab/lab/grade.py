"""Autograding with otter-grader: student versions, autograder zips, and grading a folder.

``otter assign`` turns each master notebook (``jerklab/lab/masters/``, solutions and tests
marked in otter's format) into the student worksheet (solutions stripped) and an autograder
zip. ``otter run`` executes a submission and runs the tests locally (no Docker), in a
subprocess with a timeout. The tests call the same checks as the worksheet's cells, so each
submission is scored against its own student's hidden motor: the grader sets
``JERKLAB_LAB_GRADING=1``, which makes every worksheet run on the virtual rig of the
student ID it names, seeded with the instructor key of the grading environment.
"""

from __future__ import annotations

import csv
import hashlib
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

from jerklab.lab.handin import HandinError, read_handin
from jerklab.lab.motors import normalize_student
from jerklab.lab.registry import LABS
from jerklab.lab.service import attempt_counts

__all__ = [
    "MASTERS",
    "master_path",
    "assign",
    "autograder_zip",
    "grade_folder",
    "student_version_name",
]

MASTERS = Path(__file__).parent / "masters"


def student_version_name(lab: int) -> str:
    return f"lab{lab}_{LABS[lab]}.ipynb"


def master_path(lab: int) -> Path:
    return MASTERS / student_version_name(lab)


def _otter(*args, cwd=None, timeout=600):
    cmd = [sys.executable, "-m", "otter", *map(str, args)]
    return subprocess.run(cmd, cwd=cwd, capture_output=True, text=True, timeout=timeout)


def _assign_into(lab: int, dest: Path) -> Path:
    src = master_path(lab)
    work = dest / "master"
    work.mkdir(parents=True, exist_ok=True)
    shutil.copy(src, work / src.name)
    out = dest / "dist"
    r = _otter("assign", work / src.name, out, "-v", cwd=work)
    if r.returncode != 0 or not (out / "student" / src.name).is_file():
        raise RuntimeError(
            f"otter assign failed for lab {lab}:\n{r.stdout[-3000:]}\n{r.stderr[-3000:]}"
        )
    return out


def _cache_dir(lab: int) -> Path:
    import otter

    h = hashlib.sha256(master_path(lab).read_bytes() + otter.__version__.encode()).hexdigest()[:16]
    base = Path(os.environ.get("JERKLAB_CACHE", Path(tempfile.gettempdir()) / "jerklab-autograder"))
    return base / f"lab{lab}-{h}"


def _assigned(lab: int) -> Path:
    d = _cache_dir(lab)
    out = d / "dist"
    if not (out / "student" / student_version_name(lab)).is_file():
        d.mkdir(parents=True, exist_ok=True)
        tmp = Path(tempfile.mkdtemp(prefix="assign-", dir=d))
        try:
            _assign_into(lab, tmp)
            try:  # atomic: a complete folder appears or, if another process won, stays theirs
                os.rename(tmp / "dist", out)
            except OSError:
                if not (out / "student" / student_version_name(lab)).is_file():
                    raise
        finally:
            shutil.rmtree(tmp, ignore_errors=True)
    return out


def autograder_zip(lab: int) -> Path:
    """The autograder zip of ``lab`` (made by ``otter assign`` from the master, cached by its hash)."""
    zips = sorted((_assigned(lab) / "autograder").glob("*.zip"))
    if not zips:
        raise RuntimeError(f"otter assign made no autograder zip for lab {lab}")
    return zips[-1]


# otter's initialisation cell becomes jerklab's check runner, so that a student's machine needs no
# otter-grader (jerklab.lab.notebook runs the same checks from the notebook's metadata)
_OTTER_INIT = re.compile(r"# Initialize Otter\nimport otter\ngrader = otter\.Notebook\(")
_CHECKS_INIT = (
    "# The checks (otter-grader's format, run by jerklab without otter)\n"
    "from jerklab.lab.notebook import Notebook\ngrader = Notebook("
)


def assign(out_dir, labs=tuple(LABS)) -> list[Path]:
    """Write the student versions (solutions stripped) of ``labs`` into ``out_dir``."""
    import nbformat

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    written = []
    for lab in labs:
        src = _assigned(lab) / "student" / student_version_name(lab)
        nb = nbformat.read(src, as_version=4)
        for c in nb.cells:  # otter stamps ids; keep the committed files stable
            c.pop("id", None)
            if c.cell_type == "code" and _OTTER_INIT.search(c.source):
                c.source = _OTTER_INIT.sub(_CHECKS_INIT, c.source)
            if c.cell_type == "code":
                c.outputs, c.execution_count = [], None
        nb.nbformat_minor = 4
        dst = out_dir / src.name
        nbformat.write(nb, dst)
        written.append(dst)
    return written


# ------------------------------------------------------------------ grading a folder
_STUDENT_RE = re.compile(r"""^\s*STUDENT\s*=\s*["']([^"']+)["']""", re.M)


def _notebook_info(data: bytes, name: str):
    """(student, lab) named in a notebook's source; ValueError if unreadable."""
    import nbformat

    if not data.strip():
        raise ValueError("empty notebook file")
    try:
        nb = nbformat.reads(data.decode("utf-8"), as_version=4)
    except Exception as exc:  # nbformat raises several kinds on junk
        raise ValueError(
            f"not a readable notebook ({type(exc).__name__}: {str(exc)[:120]})"
        ) from None
    lab = nb.metadata.get("jerklab", {}).get("lab")
    if lab is None:
        m = re.search(r"lab(\d)", name)
        lab = int(m.group(1)) if m else None
    student = None
    for c in nb.cells:
        if c.cell_type == "code":
            m = _STUDENT_RE.search(c.source)
            if m:
                student = m.group(1)
                break
    return student, lab


def _run_otter(lab, nb_bytes, student, timeout):
    student = normalize_student(student)
    with tempfile.TemporaryDirectory(prefix="jerklab-grade-") as tmp:
        tmp = Path(tmp)
        nb = tmp / student_version_name(lab)
        nb.write_bytes(nb_bytes)
        out = tmp / "out"
        out.mkdir()
        env = dict(
            os.environ,
            JERKLAB_LAB_GRADING="1",
            JERKLAB_LAB_WORK=str(tmp / "work"),
            JERKLAB_RECORDINGS=str(tmp / "rec"),
            MPLBACKEND="Agg",
        )
        cmd = [
            sys.executable,
            "-m",
            "otter",
            "run",
            "-a",
            str(autograder_zip(lab)),
            "-o",
            str(out),
            str(nb),
        ]
        # a session of its own, so that a timeout ends otter *and* the kernel it started
        proc = subprocess.Popen(
            cmd,
            cwd=tmp,
            env=env,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            start_new_session=True,
        )
        try:
            stdout, stderr = proc.communicate(timeout=timeout)
        except subprocess.TimeoutExpired:
            _kill_group(proc)
            return None, f"timed out after {timeout:g} s (an endless loop or a very slow cell?)"
        res = out / "results.json"
        if not res.is_file():
            return None, f"the autograder did not finish: {(stderr or stdout)[-400:].strip()}"
        return json.loads(res.read_text()), None


def _kill_group(proc):
    import signal

    try:
        if hasattr(os, "killpg"):
            os.killpg(proc.pid, signal.SIGKILL)
        else:  # Windows: the process only
            proc.kill()
    except (ProcessLookupError, PermissionError):
        pass
    proc.communicate()


def _hint(output: str) -> str:
    """The check's own message out of otter's doctest report (the AssertionError), else its tail."""
    found = re.findall(r"AssertionError: (.+)", output or "")
    if found:
        return found[-1].strip()
    errs = re.findall(r"^\s*(\w+Error: .+)$", output or "", re.M)
    return errs[-1].strip() if errs else (output or "").strip()[-300:]


def _scores(results):
    qs = {}
    for t in results.get("tests", []):
        if t.get("name") == "Public Tests" or "score" not in t:
            continue
        qs[t["name"]] = (
            float(t.get("score") or 0.0),
            float(t.get("max_score") or 0.0),
            t.get("output", ""),
        )
    return qs


def grade_folder(
    folder, out_csv, feedback_dir=None, timeout=300.0, labs=None, check_log=None
) -> list[dict]:
    """Grade every ``*.zip`` hand-in and bare ``*.ipynb`` in ``folder``.

    Writes ``out_csv`` (one row per submission: student, lab, file, status, one column per
    question, total, max) and a feedback text file per submission into ``feedback_dir``
    (default: ``feedback/`` beside the CSV). A corrupt, empty or unverifiable submission gets
    a row with its status and zero points; it never stops the run.

    With ``check_log`` (the class rig service's log, :func:`jerklab.lab.service.attempt_counts`)
    each row also gets ``attempts_<check>``: how often the student tried each check.
    """
    folder, out_csv = Path(folder), Path(out_csv)
    if not folder.is_dir():
        raise ValueError(f"SUBMISSIONS_DIR {str(folder)!r} is not a folder")
    feedback_dir = Path(feedback_dir) if feedback_dir else out_csv.parent / "feedback"
    feedback_dir.mkdir(parents=True, exist_ok=True)
    rows = []
    subs = sorted(
        p for p in folder.iterdir() if p.is_file() and p.suffix.lower() in (".zip", ".ipynb")
    )
    for p in subs:
        row = {"file": p.name, "student": "", "lab": "", "status": "", "total": 0.0, "max": 0.0}
        notes = []
        try:
            if p.suffix.lower() == ".zip":
                h = read_handin(p)
                student, lab, nb = h["student"], h["lab"], h["notebook"]
                if nb is None:
                    raise HandinError(f"{p.name}: no notebook in the hand-in")
                s2, _ = _notebook_info(nb, h["notebook_name"] or "")
                if s2 is not None and s2.strip().lower() != student:
                    notes.append(
                        f"the notebook names student {s2!r}, the manifest {student!r}: graded as {student!r}"
                    )
                    nb = _STUDENT_RE.sub(
                        f'STUDENT = "{student}"', nb.decode("utf-8"), count=1
                    ).encode()
                notes.append(f"manifest verified ({len(h['files'])} files)")
            else:
                nb = p.read_bytes()
                student, lab = _notebook_info(nb, p.name)
                if student is None:
                    raise ValueError("no `STUDENT = \"...\"` line in the notebook")
            if lab not in LABS:
                raise ValueError(f"cannot tell which lab this is (lab = {lab!r})")
            row.update(student=student, lab=lab)
            results, err = _run_otter(lab, nb, student, timeout)
            if err:
                raise RuntimeError(err)
            for q, (sc, mx, out) in _scores(results).items():
                row[q] = sc
                row["total"] += sc
                row["max"] += mx
                verdict = "right" if sc >= mx else "not yet"
                notes.append(
                    f"{q}: {sc:g}/{mx:g} ({verdict})" + (f"\n    {_hint(out)}" if sc < mx else "")
                )
            row["status"] = "graded"
        except (HandinError, ValueError, RuntimeError, OSError, UnicodeDecodeError) as exc:
            row["status"] = f"error: {exc}"
            notes.append(f"not graded: {exc}")
        rows.append(row)
        who = row["student"] or p.stem
        fb = feedback_dir / f"{who}_lab{row['lab'] or 'X'}_{p.stem}.txt"
        fb.write_text(
            f"Feedback for {who}, lab {row['lab']}, file {p.name}\n"
            f"Score: {row['total']:g} / {row['max']:g}  ({row['status']})\n\n"
            + "\n".join(notes)
            + "\n"
        )
    if check_log is not None:  # the class rig service's log: attempts per check
        counts = attempt_counts(check_log)
        for r in rows:
            for q, n in counts.get((r["student"], r["lab"]), {}).items():
                r[f"attempts_{q}"] = n
    qcols = sorted(
        {k for r in rows for k in r} - {"file", "student", "lab", "status", "total", "max"}
    )
    out_csv.parent.mkdir(parents=True, exist_ok=True)
    with out_csv.open("w", newline="") as f:
        w = csv.DictWriter(
            f, ["student", "lab", "file", "status", *qcols, "total", "max"], restval=""
        )
        w.writeheader()
        for r in rows:
            w.writerow(r)
    return rows
