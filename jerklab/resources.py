"""Where the notebooks, lab worksheets, data and class page live: a clone or an installed wheel.

In a clone (``make lab``, ``pip install -e .``, ``PYTHONPATH=.``) they are the repository's
folders ``notebooks/``, ``data/`` and ``app/`` beside the package. ``pip install jerklab`` (a
wheel) carries copies of the same folders as package data under ``jerklab/_share/`` (mapped
by ``pyproject.toml``, nothing moved in the repository). :func:`share_path` returns whichever
exists, the clone first. Students never write there: ``jerklab lab`` copies the notebooks and
data into a working folder (:func:`copy_missing`), and recordings go under the working folder.
"""

from __future__ import annotations

import os
import shutil
from pathlib import Path

__all__ = ["SHARED", "share_path", "default_work_dir", "copy_missing"]

#: folders a student opens, as named in the repository (and under jerklab/_share/ in a wheel)
SHARED = ("notebooks", "data", "app")

_PACKAGE = Path(__file__).resolve().parent
_SKIP = {".ipynb_checkpoints", "__pycache__", ".DS_Store"}


def share_path(name: str) -> Path:
    """The folder ``name`` (one of :data:`SHARED`): the clone's, else the installed package's.

    >>> share_path("notebooks").is_dir()
    True
    """
    if name not in SHARED:
        raise ValueError(f"name must be one of {SHARED}, got {name!r}")
    clone = _PACKAGE.parent / name
    if (_PACKAGE.parent / "pyproject.toml").is_file() and clone.is_dir():
        return clone
    return _PACKAGE / "_share" / name


def default_work_dir() -> Path:
    """The student's working folder: ``$JERKLAB_HOME`` or ``jerklab`` in the home folder
    (``C:\\Users\\NAME\\jerklab``, ``/Users/NAME/jerklab``, ``/home/NAME/jerklab``)."""
    env = os.environ.get("JERKLAB_HOME")
    return Path(env).expanduser() if env else Path.home() / "jerklab"


def _files(root: Path):
    for dirpath, dirnames, filenames in os.walk(root):
        dirnames[:] = sorted(d for d in dirnames if d not in _SKIP)
        for f in sorted(filenames):
            if f not in _SKIP and not f.endswith(".pyc"):
                yield Path(dirpath, f).relative_to(root)


def copy_missing(work_dir, names=("notebooks", "data")) -> tuple[list[Path], list[Path]]:
    """Copy the shipped folders ``names`` into ``work_dir`` (same layout), never overwriting.

    A file that already exists in ``work_dir`` is kept as it is (a student's edits survive
    every ``jerklab lab``); only missing files are copied.

    Returns
    -------
    copied, kept : list of pathlib.Path
        Paths relative to ``work_dir``.
    """
    work = Path(work_dir)
    copied, kept = [], []
    for name in names:
        src = share_path(name)
        if not src.is_dir():
            raise FileNotFoundError(
                f"jerklab's {name}/ folder is missing from {src.parent} "
                "(a broken install? pip install --force-reinstall jerklab)"
            )
        for rel in _files(src):
            dst = work / name / rel
            if dst.exists():
                kept.append(Path(name) / rel)
                continue
            dst.parent.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(src / rel, dst)
            copied.append(Path(name) / rel)
    return copied, kept
