"""Build helpers for the rig firmware: ``make -C firmware`` from Python, serialised by a lock.

``make -C firmware`` builds the Uno firmware (``build/jerklab_rig.elf``/``.hex``), the host
build of its portable core (``build/jl_host``) and the simavr harness (``build/jl_simavr``).
"""

from __future__ import annotations

import os
import shutil
import subprocess
from contextlib import contextmanager
from pathlib import Path

try:  # POSIX; on Windows the build lock falls back to msvcrt
    import fcntl
except ImportError:  # pragma: no cover - Windows
    fcntl = None

__all__ = ["firmware_dir", "default_build_dir", "build_firmware", "FirmwareBuildError"]


class FirmwareBuildError(RuntimeError):
    """``make -C firmware`` failed (the message carries its output)."""


def firmware_dir() -> Path:
    """The ``firmware/`` folder of the source tree (``JERKLAB_FIRMWARE_DIR`` overrides it)."""
    env = os.environ.get("JERKLAB_FIRMWARE_DIR")
    path = Path(env) if env else Path(__file__).resolve().parents[3] / "firmware"
    if not (path / "Makefile").is_file():
        raise FileNotFoundError(
            f"firmware sources not found at {path} (set JERKLAB_FIRMWARE_DIR to the firmware/ folder "
            "of a jerklab checkout)"
        )
    return path


def _is_define(d: str) -> bool:
    return (
        d.startswith("-D")
        and d[2:3].isalpha()
        and d[2:].replace("_", "").replace("=", "").isalnum()
    )


def _env_defs() -> list[str]:
    """``JERKLAB_FIRMWARE_DEFS``: extra ``-D`` options for every firmware build (e.g.
    ``-DJL_ASM=1``, to run the simavr tests on the assembly build of the control law)."""
    defs = os.environ.get("JERKLAB_FIRMWARE_DEFS", "").split()
    for d in defs:
        if not _is_define(d):
            raise ValueError(
                f"JERKLAB_FIRMWARE_DEFS must hold -DNAME or -DNAME=VALUE options, got {d!r}"
            )
    return defs


def _defs_folder(build: Path) -> Path:
    """``build``, or its subfolder for the options of ``JERKLAB_FIRMWARE_DEFS`` (a build folder
    per set of options: builds with other options do not overwrite each other's)."""
    defs = _env_defs()
    if not defs:
        return build
    return build / ("defs-" + "-".join(d[2:].replace("=", "") for d in defs))


def default_build_dir() -> Path:
    """The folder ``build_firmware()`` builds in by default: ``firmware/build`` (its subfolder
    for the options of ``JERKLAB_FIRMWARE_DEFS`` when that is set)."""
    return _defs_folder(firmware_dir() / "build")


@contextmanager
def _build_lock(build: Path):
    """Exclusive lock on ``build/.lock``: parallel test workers share one build folder."""
    build.mkdir(parents=True, exist_ok=True)
    with open(build / ".lock", "a+") as fh:
        if fcntl is not None:
            fcntl.flock(fh, fcntl.LOCK_EX)
        else:  # pragma: no cover - Windows
            import msvcrt

            msvcrt.locking(fh.fileno(), msvcrt.LK_LOCK, 1)
        try:
            yield
        finally:
            if fcntl is not None:
                fcntl.flock(fh, fcntl.LOCK_UN)
            else:  # pragma: no cover - Windows
                import msvcrt

                fh.seek(0)
                msvcrt.locking(fh.fileno(), msvcrt.LK_UNLCK, 1)


def build_firmware(*targets: str, build_dir=None, baud=None, probe_part=None, defines=()) -> dict:
    """Run ``make -C firmware <targets>`` (serialised by a file lock) and return the paths.

    Parameters
    ----------
    targets : str
        Make targets (``"avr"``, ``"size"``, ``"host"``, ``"simavr"``, ``"optiboot"``); none =
        the default (everything the installed tools allow).
    build_dir : path-like, optional
        Output folder (default ``firmware/build``). With ``JERKLAB_FIRMWARE_DEFS`` set (extra
        ``-D`` options for every build, e.g. ``-DJL_ASM=1``), a subfolder of it named after
        those options.
    baud : int, optional
        UART speed of the sketch (``-DJL_BAUD``): 115200 (default), 500000 or 1000000 (both
        exact on a 16 MHz Uno with U2X). Use a separate ``build_dir`` for another speed.
    probe_part : int, optional
        A cycle-profiling build (``-DJL_PROBE_PART``): the PB5 probe is high around that part of
        a tick instead of the whole control step (firmware/README.md "Cycle budget").
    defines : sequence of str
        More ``-DNAME`` or ``-DNAME=VALUE`` options (e.g. ``("-DJL_ASM=1",)``, the assembly
        build of the control law). Use a separate ``build_dir`` for each set of options.

    Returns
    -------
    dict
        ``elf``, ``hex``, ``host``, ``harness``, ``optiboot`` paths and ``output`` (make's stdout, which
        holds the flash/RAM line printed by the ``size`` target).
    """
    if shutil.which("make") is None:
        raise FirmwareBuildError("make is not installed")
    fw = firmware_dir()
    build = _defs_folder(Path(build_dir) if build_dir is not None else fw / "build")
    for t in targets:
        if not isinstance(t, str) or not t.replace("_", "").isalnum():
            raise ValueError(f"targets must be make target names, got {t!r}")
    defs = _env_defs()
    for d in defines:
        if not isinstance(d, str) or not _is_define(d):
            raise ValueError(f"defines must be -DNAME or -DNAME=VALUE options, got {d!r}")
        defs.append(d)
    if baud is not None:
        if baud not in (115200, 500000, 1000000):
            raise ValueError(f"baud must be 115200, 500000 or 1000000, got {baud!r}")
        defs.append(f"-DJL_BAUD={int(baud)}UL")
    if probe_part is not None:
        if (
            isinstance(probe_part, bool)
            or not isinstance(probe_part, int)
            or not 1 <= probe_part <= 10
        ):
            raise ValueError(f"probe_part must be an integer in 1..10, got {probe_part!r}")
        defs.append(f"-DJL_PROBE_PART={probe_part}")
    extra = [f"EXTRA_DEFS={' '.join(defs)}"] if defs else []
    with _build_lock(build):
        proc = subprocess.run(
            ["make", "-s", "-C", str(fw), f"BUILD={build}", *extra, *targets],
            capture_output=True,
            text=True,
        )
    if proc.returncode != 0:
        raise FirmwareBuildError(
            f"make -C {fw} {' '.join(targets)} failed:\n{proc.stdout}\n{proc.stderr}"
        )
    return {
        "elf": build / "jerklab_rig.elf",
        "hex": build / "jerklab_rig.hex",
        "host": build / "jl_host",
        "harness": build / "jl_simavr",
        "optiboot": build / "optiboot_atmega328.hex",
        "output": proc.stdout,
    }
