"""The hand-in: one zip per student and lab, with a manifest of SHA-256 checksums.

Layout of ``lab<N>_<student>.zip``::

    manifest.json        {"format": 1, "student", "lab", "mode", "files": {path: sha256}}
    student.json         student ID, lab, mode ("graded", "practice", "instructor"), time,
                         jerklab version, rig port
    answers.json         every answer checked in the worksheet, with the check's verdict
    gains.json           the gains of the last rig move (or null)
    notebook/<name>.ipynb  the worksheet as saved
    recordings/...       the recordings made in this session, and those the student names
                         (CSV + JSON sidecar)

No file holds a true motor parameter (the answers are the student's own estimates).

:func:`read_handin` trusts nothing in a zip: it refuses one larger than
:data:`MAX_ZIP_BYTES`, one whose members declare more than :data:`MAX_UNCOMPRESSED_BYTES`
uncompressed (a zip bomb) or more than :data:`MAX_MEMBERS` members, and a student ID that
:func:`jerklab.lab.motors.normalize_student` refuses (a path, a NUL, more than 64 characters).

:func:`write_handin` refuses (:class:`HandinRefused`, saying what to do) rather than write a
hand-in that would score nothing: while ``STUDENT`` is still the worksheet's placeholder, when
the notebook is not given or not saved since the last cell ran, or when there are no answers.
"""

from __future__ import annotations

import datetime as _dt
import hashlib
import io
import json
import re
import zipfile
from pathlib import Path

from jerklab import __version__
from jerklab._validate import as_path
from jerklab.lab.motors import normalize_student
from jerklab.lab.plain import jsonable

__all__ = [
    "write_handin",
    "read_handin",
    "pack",
    "HandinError",
    "HandinRefused",
    "MANIFEST",
    "PLACEHOLDER_STUDENT",
    "MAX_ZIP_BYTES",
    "MAX_UNCOMPRESSED_BYTES",
    "MAX_MEMBERS",
]

MANIFEST = "manifest.json"
#: The student ID the worksheets ship with (``STUDENT = "s0000000"``): not a student's.
PLACEHOLDER_STUDENT = "s0000000"
#: The largest hand-in zip read (bytes on disk).
MAX_ZIP_BYTES = 32 * 2**20
#: The largest total uncompressed size the members of a hand-in may declare (bytes).
MAX_UNCOMPRESSED_BYTES = 64 * 2**20
#: The most members a hand-in may hold.
MAX_MEMBERS = 2000


class HandinError(ValueError):
    """A hand-in zip that cannot be trusted: not a zip, no manifest, a checksum that differs."""


class HandinRefused(ValueError):
    """A hand-in that is not written because it would be empty or not the student's: the
    message says what to do."""


_UNFILLED = re.compile(r"^\s*(?:[\w, ()\[\]]+=\s*)?\.\.\.\s*(?:#.*)?$", re.M)
_STUDENT_LINE = re.compile(r"""^\s*STUDENT\s*=\s*["']([^"']*)["']""", re.M)


def _clock(t) -> str:
    return _dt.datetime.fromtimestamp(t).strftime("%H:%M:%S")


def _refusal(session, nb: Path | None):
    """Why ``session``'s hand-in with notebook ``nb`` would be empty or not its own (None: fine)."""
    if session.student == PLACEHOLDER_STUDENT:
        return (
            f"STUDENT is still the placeholder {PLACEHOLDER_STUDENT!r}: put your student ID in "
            "the set-up cell, run the worksheet again from the top (your motor is drawn from "
            "your ID), save it and run this cell."
        )
    if nb is None:
        return (
            "no notebook given: save the worksheet (Ctrl-S / ⌘-S) and give its file name, "
            'e.g. S.submit("lab1_identify.ipynb").'
        )
    if not nb.is_file():
        return (
            f"{str(nb)!r} is not a file here: save the worksheet (Ctrl-S / ⌘-S) and give the "
            "name it is saved under (the tab's title, with .ipynb)."
        )
    last = getattr(session, "last_activity", None)
    saved = nb.stat().st_mtime
    if last is not None and saved + 0.01 < last:
        return (
            f"{nb.name} on disk was saved at {_clock(saved)}, before the cells you ran last "
            f"({_clock(last)}): the zip would hold the older file. Save the notebook "
            "(Ctrl-S / ⌘-S), then run this cell again."
        )
    if not session.results:
        return (
            "no answer has been checked in this session: run the worksheet's cells (each "
            "answer and its check) before handing in."
        )
    try:
        cells = json.loads(nb.read_text(encoding="utf-8")).get("cells", [])
    except (ValueError, UnicodeDecodeError) as exc:
        return f"{nb.name} is not a readable notebook ({exc}): save the worksheet again."

    def source(c):
        src = c.get("source", "")
        return "".join(src) if isinstance(src, list) else str(src)

    code = [source(c) for c in cells if c.get("cell_type") == "code"]
    named = [m.group(1).strip().lower() for c in code for m in [_STUDENT_LINE.search(c)] if m]
    if named and named[0] != session.student:
        return (
            f"the saved {nb.name} names student {named[0]!r}, this session {session.student!r}: "
            "save the worksheet you ran (Ctrl-S / ⌘-S), then run this cell again."
        )
    answer_cells = [
        source(c)
        for c in cells
        if c.get("cell_type") == "code"
        and "otter_answer_cell" in c.get("metadata", {}).get("tags", [])
    ]
    if answer_cells and all(_UNFILLED.search(src) for src in answer_cells):
        return (
            f"the saved {nb.name} has no answers (every answer cell still holds `...`): "
            "save the worksheet you worked in (Ctrl-S / ⌘-S), then run this cell again."
        )
    return None


def _recording_files(session, include):
    """{name in the zip: bytes} of this session's recordings and of those named in ``include``
    (recording names in the lab's folder, or paths of .csv/.json files)."""
    paths = []
    for rec in session.recordings.values():
        paths += [p for p in (rec.csv_path, rec.json_path) if p is not None]
    for item in include:
        p = Path(item)
        if p.suffix in (".csv", ".json") and p.is_file():
            paths.append(p)
            continue
        pair = [session.folder / f"{item}.csv", session.folder / f"{item}.json"]
        if not all(q.is_file() for q in pair):
            raise ValueError(
                f"include: no recording {str(item)!r} (neither a .csv/.json file nor a "
                f"recording name in {session.folder})"
            )
        paths += pair
    files = {}
    for p in paths:
        p = Path(p)
        if p.is_file():
            files[f"recordings/{p.name}"] = p.read_bytes()
    return files


def _sha(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def write_handin(session, notebook=None, out=None, include=()) -> Path:
    """Write ``lab<N>_<student>.zip`` for a :class:`~jerklab.lab.session.LabSession`; return its path.

    Parameters
    ----------
    notebook : path
        The worksheet file (save it first: the zip holds what is on disk).
    out : path, optional
        Folder for the zip (default ``handin/`` beside the worksheet, or ``./handin``).
    include : iterable of str or path, optional
        Recordings of earlier sessions to hand in as well: names in the lab's folder
        (``"step_p6V"``) or paths of their .csv/.json files. Without it only the recordings of
        this session go in.

    Raises
    ------
    HandinRefused
        While ``STUDENT`` is the placeholder, when ``notebook`` is missing or older on disk
        than the last cell run (``session.last_activity``), when no answer was checked, or
        when the saved notebook names another student or has no answers. The message says
        what to do.
    """
    nb = None if notebook is None else Path(notebook)
    why = _refusal(session, nb)
    if why:
        raise HandinRefused(why)
    files = {f"notebook/{nb.name}": nb.read_bytes()}
    files.update(_recording_files(session, include))
    answers = {
        k: {"answer": session.answers.get(k), "ok": r.ok} for k, r in session.results.items()
    }
    files["answers.json"] = json.dumps(answers, indent=1).encode()
    files["gains.json"] = json.dumps(jsonable(session.gains), indent=1).encode()
    mode = getattr(session, "mode", "practice")
    meta = {
        "student": session.student,
        "lab": session.lab,
        "created": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
        "jerklab_version": __version__,
        "rig": session.rig.port,
        "mode": mode,
    }
    files["student.json"] = json.dumps(meta, indent=1).encode()
    folder = (
        Path(out)
        if out is not None
        else (Path(notebook).parent if notebook else Path(".")) / "handin"
    )
    path = pack(
        files,
        session.student,
        session.lab,
        folder / f"lab{session.lab}_{session.student}.zip",
        mode=mode,
    )
    print(f"hand-in written: {path} ({len(files)} files, manifest with SHA-256 checksums)")
    return path


def pack(files: dict, student: str, lab: int, path, mode=None) -> Path:
    """Write ``files`` ({name in the zip: bytes}) and their manifest into the zip ``path``
    (``mode``: the session's, "practice" for work done without the class rig service)."""
    manifest = {
        "format": 1,
        "student": student,
        "lab": int(lab),
        **({} if mode is None else {"mode": str(mode)}),
        "files": {name: _sha(data) for name, data in files.items()},
    }
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as z:
        for name, data in files.items():
            z.writestr(name, data)
        z.writestr(MANIFEST, json.dumps(manifest, indent=1))
    return path


def read_handin(path, data: bytes | None = None) -> dict:
    """Open a hand-in zip and verify it; return ``{"student", "lab", "mode", "notebook" (bytes
    or None), "notebook_name", "files"}``. Raises :class:`HandinError` naming what is wrong.

    Parameters
    ----------
    path : path
        The zip (its name is used in messages; its bytes are read unless ``data`` is given).
    data : bytes, optional
        The zip's bytes, already read (the grader reads every submission before grading any).
    """
    path = as_path("path", path)
    if data is None:
        try:
            if path.stat().st_size > MAX_ZIP_BYTES:
                raise HandinError(f"{path.name}: larger than {MAX_ZIP_BYTES // 2**20} MiB")
            data = path.read_bytes()
        except FileNotFoundError:
            raise FileNotFoundError(f"path: no hand-in at {path}") from None
        except IsADirectoryError:
            raise HandinError(f"path: {path} is a folder, not a hand-in zip") from None
    if not data:
        raise HandinError(f"{path.name}: empty file")
    if len(data) > MAX_ZIP_BYTES:
        raise HandinError(f"{path.name}: larger than {MAX_ZIP_BYTES // 2**20} MiB")
    try:
        z = zipfile.ZipFile(io.BytesIO(data))
        infos = z.infolist()
        names = {i.filename for i in infos}
    except (zipfile.BadZipFile, zipfile.LargeZipFile, ValueError, OSError) as exc:
        raise HandinError(f"{path.name}: not a zip file ({exc})") from None
    if len(infos) > MAX_MEMBERS:
        raise HandinError(f"{path.name}: {len(infos)} members, more than {MAX_MEMBERS}")
    declared = sum(max(i.file_size, 0) for i in infos)
    if declared > MAX_UNCOMPRESSED_BYTES:
        raise HandinError(
            f"{path.name}: its members declare {declared / 2**20:.0f} MiB uncompressed, more "
            f"than the limit of {MAX_UNCOMPRESSED_BYTES // 2**20} MiB (refused unread)"
        )
    if MANIFEST not in names:
        raise HandinError(f"{path.name}: no {MANIFEST} in the zip")
    try:
        manifest = json.loads(z.read(MANIFEST))
        listed = manifest["files"]
        if not isinstance(listed, dict):
            raise TypeError("files is not a mapping")
        student, lab = manifest["student"], int(manifest["lab"])
    except (ValueError, KeyError, TypeError, zipfile.BadZipFile, OSError) as exc:
        raise HandinError(f"{path.name}: unreadable manifest ({type(exc).__name__})") from None
    try:
        student = normalize_student(student)
    except (TypeError, ValueError):
        shown = repr(student)
        shown = shown if len(shown) <= 40 else shown[:37] + "..."
        raise HandinError(
            f"{path.name}: the manifest's student ID {shown} is not 1-64 letters, digits "
            "and ._@+- (refused before any use)"
        ) from None
    extra = names - set(listed) - {MANIFEST}
    if extra:
        raise HandinError(f"{path.name}: files not in the manifest: {sorted(extra)}")
    contents = {}
    for name, digest in listed.items():
        if name not in names:
            raise HandinError(f"{path.name}: {name} is listed in the manifest but missing")
        try:
            blob = z.read(name)
        except (zipfile.BadZipFile, OSError, ValueError, EOFError) as exc:  # CRC, truncated
            raise HandinError(f"{path.name}: {name} cannot be read ({exc})") from None
        if _sha(blob) != digest:
            raise HandinError(
                f"{path.name}: checksum of {name} differs from the manifest (changed after submit)"
            )
        contents[name] = blob
    nbs = [n for n in contents if n.startswith("notebook/") and n.endswith(".ipynb")]
    return {
        "student": student,
        "lab": lab,
        "mode": manifest.get("mode"),
        "notebook": contents[nbs[0]] if nbs else None,
        "notebook_name": nbs[0].split("/", 1)[1] if nbs else None,
        "files": contents,
    }
