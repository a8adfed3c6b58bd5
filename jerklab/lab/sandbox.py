"""One bubblewrap sandbox per submission: what a student's worksheet can see and do while graded.

:func:`sandbox_command` builds the ``prlimit ... bwrap ...`` command line that
:func:`jerklab.lab.grade.grade_folder` runs a worksheet under:

* ``--unshare-all``: no network (a loopback only), its own PID, IPC, UTS, user and cgroup
  namespaces; ``--die-with-parent`` and the PID namespace end every process of the submission
  (also a detached ``setsid`` child) when the grader ends the sandbox or exits;
* a read-only system: ``/usr`` (with ``/bin``, ``/lib``, ``/lib64`` as its links), the few files
  of ``/etc`` a Python process reads, the Python interpreter, its site-packages and the
  ``jerklab`` package, all bound read-only; jerklab's lab masters (the solutions) hidden;
* its own ``/tmp`` and ``$HOME`` (tmpfs) and one writable folder, the submission's working copy;
* an empty environment but for :data:`SAFE_ENV` and what the grader adds (never the instructor
  key; no key file is reachable: the home folders are not bound);
* limits (:class:`Limits`): CPU seconds, address space and processes (``prlimit``).

The grader's own files (the submissions, ``grades.csv``, ``feedback/``, the autograder cache)
are not in the sandbox at all.
"""

from __future__ import annotations

import os
import shutil
import sys
from dataclasses import dataclass
from pathlib import Path

import jerklab

__all__ = ["Limits", "SAFE_ENV", "SandboxUnavailable", "bwrap_path", "sandbox_command"]

#: The environment of a sandboxed worksheet (besides what the grader sets for the run).
SAFE_ENV = {
    "PATH": "/usr/local/bin:/usr/bin:/bin",
    "HOME": "/tmp/home",
    "LANG": "C.UTF-8",
    "MPLBACKEND": "Agg",
    "MPLCONFIGDIR": "/tmp/home/.mpl",
    "OMP_NUM_THREADS": "1",
    "OPENBLAS_NUM_THREADS": "1",
    "MKL_NUM_THREADS": "1",
    "PYTHONDONTWRITEBYTECODE": "1",
    "PYTHONHASHSEED": "0",
}

#: Files of /etc a Python process with numpy and matplotlib may read (bound when present).
_ETC = (
    "/etc/ld.so.cache",
    "/etc/localtime",
    "/etc/nsswitch.conf",
    "/etc/fonts",
    "/etc/ssl/certs/ca-certificates.crt",
    "/etc/mime.types",
)


class SandboxUnavailable(RuntimeError):
    """bubblewrap (``bwrap``) or ``prlimit`` is missing or cannot create a sandbox here."""


@dataclass(frozen=True)
class Limits:
    """Resource limits of one sandboxed worksheet (``prlimit``).

    Attributes
    ----------
    cpu_seconds : int
        CPU time of each process (RLIMIT_CPU); the grader's wall-clock timeout comes on top.
    memory_bytes : int
        Address space of each process (RLIMIT_AS).
    processes : int
        More processes (RLIMIT_NPROC, counted per Unix user) than the grading user already
        runs: :func:`sandbox_command` adds this to the user's current count.
    file_bytes : int
        Largest file a process may write (RLIMIT_FSIZE).
    """

    cpu_seconds: int = 240
    memory_bytes: int = 3 * 2**30
    processes: int = 64
    file_bytes: int = 256 * 2**20


def bwrap_path() -> str | None:
    """The ``bwrap`` executable on ``PATH``, or None."""
    return shutil.which("bwrap")


def _processes_of_this_user() -> int:
    uid, n = os.getuid(), 0
    try:
        entries = os.listdir("/proc")
    except OSError:
        return 1024
    for e in entries:
        if e.isdigit():
            try:
                if os.stat(f"/proc/{e}").st_uid == uid:
                    n += 1
            except OSError:
                pass
    return n


def _python_paths() -> list[str]:
    """The read-only folders the worksheet's Python needs: the interpreter's prefix, the
    environment's and every existing ``sys.path`` folder (site-packages, an editable clone's
    ``jerklab`` package only)."""
    pkg = Path(jerklab.__file__).resolve().parent
    paths = {str(Path(sys.base_prefix).resolve()), str(Path(sys.prefix).resolve()), str(pkg)}
    for p in sys.path:
        if not p or not os.path.isdir(p):
            continue
        rp = Path(p).resolve()
        if (rp / "jerklab").resolve() == pkg and (rp / "pyproject.toml").is_file():
            continue  # an editable clone: its jerklab package only, not the rest of the repo
        paths.add(str(rp))
    # nested folders are covered by their parents
    out = []
    for p in sorted(paths, key=len):
        if not any(p == q or p.startswith(q.rstrip("/") + "/") for q in out):
            out.append(p)
    return out


def sandbox_command(
    argv,
    workdir,
    *,
    env=None,
    limits: Limits = Limits(),
    devices=(),
    bwrap: str | None = None,
) -> list[str]:
    """The command that runs ``argv`` in a new sandbox with ``workdir`` as its only writable
    folder (bound at the same path, also the working directory).

    Parameters
    ----------
    argv : list of str
        The program and its arguments (``sys.executable`` is bound read-only).
    workdir : path
        The submission's working copy (a fresh folder of the grader's).
    env : dict, optional
        Variables added to :data:`SAFE_ENV`.
    limits : Limits
        CPU, memory and process limits.
    devices : iterable of (host path, sandbox path)
        Character devices bound in (the grader's virtual rig on a pseudo-terminal).
    bwrap : str, optional
        The ``bwrap`` executable (default: :func:`bwrap_path`).

    Raises
    ------
    SandboxUnavailable
        ``bwrap`` or ``prlimit`` is not installed.
    """
    bwrap = bwrap or bwrap_path()
    prlimit = shutil.which("prlimit")
    if not bwrap or not prlimit:
        raise SandboxUnavailable(
            "bubblewrap (bwrap) and prlimit (util-linux) are needed to grade in a sandbox "
            "(Debian/Ubuntu: apt-get install bubblewrap util-linux)"
        )
    workdir = str(Path(workdir).resolve())
    masters = Path(jerklab.__file__).resolve().parent / "lab" / "masters"
    nproc = _processes_of_this_user() + int(limits.processes)
    cmd = [
        prlimit,
        f"--cpu={int(limits.cpu_seconds)}",
        f"--as={int(limits.memory_bytes)}",
        f"--nproc={nproc}",
        f"--fsize={int(limits.file_bytes)}",
        "--core=0",
        "--",
        bwrap,
        "--unshare-all",
        "--die-with-parent",
        "--new-session",
        "--cap-drop",
        "ALL",
        "--ro-bind",
        "/usr",
        "/usr",
    ]
    for link in ("bin", "sbin", "lib", "lib32", "lib64", "libx32"):
        target = f"/{link}"
        if os.path.islink(target):
            cmd += ["--symlink", os.readlink(target), target]
        elif os.path.isdir(target):
            cmd += ["--ro-bind", target, target]
    for f in _ETC:
        if os.path.exists(f):
            cmd += ["--ro-bind", f, f]
    cmd += ["--proc", "/proc", "--dev", "/dev", "--tmpfs", "/tmp", "--dir", SAFE_ENV["HOME"]]
    for p in _python_paths():
        cmd += ["--ro-bind", p, p]
    if masters.is_dir():
        cmd += ["--tmpfs", str(masters)]
    for host, inside in devices:
        cmd += ["--dev-bind", str(host), str(inside)]
    cmd += ["--bind", workdir, workdir, "--chdir", workdir, "--clearenv"]
    for k, v in {**SAFE_ENV, **(env or {})}.items():
        cmd += ["--setenv", str(k), str(v)]
    return cmd + ["--", *map(str, argv)]
