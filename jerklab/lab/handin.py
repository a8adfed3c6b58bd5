"""The hand-in: one zip per student and lab, with a manifest of SHA-256 checksums.

Layout of ``lab<N>_<student>.zip``::

    manifest.json        {"format": 1, "student", "lab", "mode", "files": {path: sha256}}
    student.json         student ID, lab, mode ("graded", "practice", "instructor"), time,
                         jerklab version, rig port
    answers.json         every answer checked in the worksheet, with the check's verdict
    gains.json           the gains of the last rig move (or null)
    notebook/<name>.ipynb  the worksheet as saved
    recordings/...       every recording of the lab (CSV + JSON sidecar)

No file holds a true motor parameter (the answers are the student's own estimates).
"""

from __future__ import annotations

import datetime as _dt
import hashlib
import io
import json
import zipfile
from pathlib import Path

from jerklab import __version__
from jerklab.lab.plain import jsonable

__all__ = ["write_handin", "read_handin", "pack", "HandinError", "MANIFEST"]

MANIFEST = "manifest.json"


class HandinError(ValueError):
    """A hand-in zip that cannot be trusted: not a zip, no manifest, a checksum that differs."""


def _sha(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def write_handin(session, notebook=None, out=None) -> Path:
    """Write ``lab<N>_<student>.zip`` for a :class:`~jerklab.lab.session.LabSession`; return its path.

    Parameters
    ----------
    notebook : path, optional
        The worksheet file (save it first: the zip holds what is on disk).
    out : path, optional
        Folder for the zip (default ``handin/`` beside the worksheet, or ``./handin``).
    """
    files = {}
    if notebook is not None:
        nb = Path(notebook)
        if not nb.is_file():
            raise ValueError(
                f"notebook {str(nb)!r} is not a file (save the worksheet and give its name)"
            )
        files[f"notebook/{nb.name}"] = nb.read_bytes()
    for p in sorted(session.folder.iterdir()) if session.folder.is_dir() else []:
        if p.is_file() and p.suffix in (".csv", ".json"):
            files[f"recordings/{p.name}"] = p.read_bytes()
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


def read_handin(path) -> dict:
    """Open a hand-in zip and verify it; return ``{"student", "lab", "mode", "notebook" (bytes or None),
    "notebook_name", "files"}``. Raises :class:`HandinError` naming what is wrong."""
    path = Path(path)
    data = path.read_bytes()
    if not data:
        raise HandinError(f"{path.name}: empty file")
    try:
        z = zipfile.ZipFile(io.BytesIO(data))
        names = set(z.namelist())
    except zipfile.BadZipFile as exc:
        raise HandinError(f"{path.name}: not a zip file ({exc})") from None
    if MANIFEST not in names:
        raise HandinError(f"{path.name}: no {MANIFEST} in the zip")
    try:
        manifest = json.loads(z.read(MANIFEST))
        listed = manifest["files"]
        student, lab = str(manifest["student"]), int(manifest["lab"])
    except (ValueError, KeyError, TypeError) as exc:
        raise HandinError(f"{path.name}: unreadable manifest ({exc})") from None
    extra = names - set(listed) - {MANIFEST}
    if extra:
        raise HandinError(f"{path.name}: files not in the manifest: {sorted(extra)}")
    contents = {}
    for name, digest in listed.items():
        if name not in names:
            raise HandinError(f"{path.name}: {name} is listed in the manifest but missing")
        try:
            blob = z.read(name)
        except (zipfile.BadZipFile, OSError, ValueError) as exc:  # CRC error, truncated member
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
