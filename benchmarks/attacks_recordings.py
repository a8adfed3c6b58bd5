"""Recordings that claim the class rig service: forged and edited ones against the grader.

The class rig service signs every recording it serves (:mod:`jerklab.lab.signing`); the
grader verifies every recording in a hand-in, and in a worksheet's export, that claims to
come from the service. Each attack builds a served recording on a real
:class:`jerklab.lab.service.ClassRigService` (in this process, a token file, the
instructor key :data:`KEY`) and then:

* hands it in unchanged (honest: ``grades.csv`` says ``signed: N verified``);
* edits one value in it, consistently (the CSV's raw count and its derived angle) and keeps
  its signature;
* forges one: a recording made on the student's own virtual rig, labelled ``"graded"`` and
  carrying the signature of a served one;
* puts a forged one in the worksheet's export (what the checks read).

The hand-ins go through :func:`jerklab.lab.grade.grade_folder` with ``labs=`` another lab, so
no worksheet runs (a few seconds in all): the ``recordings`` column is written for every row
that was read. ``python -m benchmarks security recordings`` prints the verdicts; the tests in
``tests/security/test_signing.py`` are the same attacks with assertions.
"""

from __future__ import annotations

import csv
import json
import os
import tempfile
from contextlib import contextmanager
from pathlib import Path

from benchmarks.bench_security import Skip, attack

KEY = "recording-signature-attack-key"
TOKEN = "tok-alice-recordings-0123"
STUDENT = "alice"


@contextmanager
def instructor_env():
    """``JERKLAB_INSTRUCTOR_KEY`` = :data:`KEY` while inside (the grader reads it)."""
    saved = os.environ.get("JERKLAB_INSTRUCTOR_KEY")
    os.environ["JERKLAB_INSTRUCTOR_KEY"] = KEY
    try:
        yield
    finally:
        if saved is None:
            os.environ.pop("JERKLAB_INSTRUCTOR_KEY", None)
        else:
            os.environ["JERKLAB_INSTRUCTOR_KEY"] = saved


def served_recordings(folder: Path, lab: int = 1) -> dict:
    """Two recordings (``step_p6V``, ``step_p3V``) served to :data:`STUDENT` by a class rig
    service, saved by the student's client in ``folder``; ``{name: csv path}``."""
    from jerklab.lab.classrig import ClassRig
    from jerklab.lab.service import ClassRigService, TokenFile

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    tokens = folder / "tokens.json"
    tokens.write_text(json.dumps({TOKEN: STUDENT}))
    out = {}
    with ClassRigService(TokenFile(tokens), folder / "checks.jsonl", key=KEY.encode()) as svc:
        rig = ClassRig(svc.url, lab, token=TOKEN)
        try:
            for v in (6.0, 3.0):
                name = f"step_p{v:g}V"
                rig.step(v, 0.2, path=folder / name)
                out[name] = folder / f"{name}.csv"
        finally:
            rig.close()
    return out


def edited(csv_path: Path, out: Path, sample: int = 30, by: int = 7) -> Path:
    """A copy of a recording with one sample's encoder count changed by ``by`` and its angle
    with it (consistent, so that :meth:`jerklab.rig.Recording.load` reads it), its metadata
    and signature kept."""
    from jerklab.rig import Recording

    rec = Recording.load(csv_path)
    new = Recording(rec.metadata)
    with open(csv_path, newline="", encoding="ascii") as f:
        rows = list(csv.DictReader(f))
    for i, r in enumerate(rows):
        counts = int(r["counts"]) + (by if i == sample else 0)
        new.append(int(r["index"]), float(r["reference"]), counts, int(r["pwm"]), int(r["flags"]))
    new.finish(rec.metadata.get("status", "complete"))
    return new.save(out)


def forged(signature: dict, out: Path) -> Path:
    """A step recorded on the student's own virtual rig (a practice motor), labelled graded
    and given the signature of a served recording."""
    from jerklab.lab.motors import practice_key, student_device, student_motor
    from jerklab.rig import connect

    motor = student_motor(STUDENT, practice_key())
    rig = connect(
        None,
        device=student_device(motor),
        progress=False,
        metadata={"student": STUDENT, "lab": 1, "mode": "graded"},
    )
    try:
        rec = rig.step(6.0, 0.2)
    finally:
        rig.close()
    rec.metadata["signature"] = dict(signature)
    return rec.save(out)


def _notebook() -> bytes:
    import nbformat

    nb = nbformat.v4.new_notebook()
    nb.metadata["jerklab"] = {"lab": 1}
    nb.cells = [nbformat.v4.new_code_cell(f'STUDENT = "{STUDENT}"\nK = 20.0')]
    return nbformat.writes(nb).encode()


def hand_in(folder: Path, name: str, recordings: dict) -> Path:
    """A lab 1 hand-in ``name`` of :data:`STUDENT` holding ``recordings`` ({name: csv path}),
    its manifest made by the package's own ``pack()`` (as a student who edits a file can)."""
    from jerklab.lab.handin import pack

    files = {"notebook/lab1_identify.ipynb": _notebook()}
    for rec_name, p in recordings.items():
        p = Path(p)
        files[f"recordings/{rec_name}.csv"] = p.read_bytes()
        files[f"recordings/{rec_name}.json"] = p.with_suffix(".json").read_bytes()
    return pack(files, STUDENT, 1, Path(folder) / name, mode="graded")


def grade_rows(subs: Path, out: Path) -> dict:
    """``grades.csv`` rows by file, graded with the instructor key (no worksheet runs: the
    hand-ins are lab 1, the run asks for lab 2)."""
    from jerklab.lab.grade import grade_folder

    with instructor_env():
        grade_folder(subs, out / "grades.csv", labs=[2], unsafe_no_sandbox=True)
    with open(out / "grades.csv", newline="", encoding="utf-8") as f:
        return {r["file"]: r for r in csv.DictReader(f)}


def recordings_class(tmp: Path) -> dict:
    """Three hand-ins (honest, edited, forged) graded once; the rows by file."""
    tmp = Path(tmp)
    served = served_recordings(tmp / "served")
    sig = json.loads(served["step_p6V"].with_suffix(".json").read_text())["signature"]
    subs = tmp / "subs"
    subs.mkdir()
    hand_in(subs, "lab1_honest.zip", served)
    hand_in(
        subs,
        "lab1_edited.zip",
        {
            "step_p6V": edited(served["step_p6V"], tmp / "edit" / "step_p6V"),
            "step_p3V": served["step_p3V"],
        },
    )
    hand_in(subs, "lab1_forged.zip", {"step_p6V": forged(sig, tmp / "forge" / "step_p6V")})
    return grade_rows(subs, tmp / "out")


_ROWS: dict = {}


def _need_service():
    """Skip on a jerklab without the class rig service: nothing there served or signed a
    recording, so every recording was taken as it came."""
    import importlib.util

    if importlib.util.find_spec("jerklab.lab.classrig") is None:
        raise Skip("no class rig service in this jerklab: recordings were unsigned, taken as is")


def _rows():
    _need_service()
    if not _ROWS:
        tmp = tempfile.mkdtemp(prefix="bench-security-recordings-")
        _ROWS.update(recordings_class(Path(tmp)))
    return _ROWS


@attack("recordings", "honest hand-in of served recordings (must verify)")
def honest():
    row = _rows()["lab1_honest.zip"]
    return row["recordings"] == "signed: 2 verified", f"recordings = {row['recordings']!r}"


@attack("recordings", "one count edited in a served recording, signature kept")
def edit_one_value():
    row = _rows()["lab1_edited.zip"]
    ok = row["recordings"] == "rejected: step_p6V" and "step_p6V" in row["flags"]
    return ok, f"recordings = {row['recordings']!r}"


@attack("recordings", "own virtual-rig step labelled graded, a served signature copied")
def forge_one():
    row = _rows()["lab1_forged.zip"]
    ok = row["recordings"] == "rejected: step_p6V" and "step_p6V" in row["flags"]
    return ok, f"recordings = {row['recordings']!r}"


def export_doc(served: dict, forged_csv: Path) -> dict:
    """A worksheet's export (as :mod:`jerklab.lab.sheetrun` writes it) holding the served
    ``step_p3V`` and, as ``step_p6V``, the forged recording with the claim it comes from the
    service."""
    from jerklab.lab.plain import Run
    from jerklab.rig import Recording

    runs, claims, sigs = {}, {}, {}
    for name, p in (("step_p3V", served["step_p3V"]), ("step_p6V", forged_csv)):
        rec = Recording.load(p)
        runs[name] = Run.from_recording(rec).to_dict()
        claims[name] = True
        sigs[name] = rec.metadata["signature"]
    return {"answers": {}, "evidence": {"runs": runs, "claims": claims, "signatures": sigs}}


@attack("recordings", "a forged graded recording in the worksheet's export")
def forged_in_export():
    _need_service()
    from jerklab.lab.grade import _evidence_of

    with tempfile.TemporaryDirectory(prefix="bench-security-export-") as tmp:
        served = served_recordings(Path(tmp) / "served")
        sig = json.loads(served["step_p6V"].with_suffix(".json").read_text())["signature"]
        doc = export_doc(served, forged(sig, Path(tmp) / "forge" / "step_p6V"))
    rejected = []
    ev, _ = _evidence_of(doc, {}, (KEY.encode(), STUDENT, 1), rejected)
    ok = sorted(ev.runs) == ["step_p3V"] and rejected == ["step_p6V"]
    return ok, f"the checks see {sorted(ev.runs)}, left out {rejected}"
