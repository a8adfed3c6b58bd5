"""Serial ports for a rig: which ones look like an Uno, and who holds one.

``python -m jerklab.rig ports`` prints :func:`list_ports`. :func:`connect` opens a device path
exclusively (pyserial ``exclusive=True`` on POSIX) and leaves a lock file that names the holder
(pid, host, program), so a second kernel or script that tries the same board gets an error that
says who has it, instead of silently sharing the port (a second client would kill the first
one's run; on a real Uno opening the port also resets the board).
"""

from __future__ import annotations

import errno
import json
import os
import re
import socket
import sys
import tempfile
import time
from pathlib import Path

try:  # POSIX only; Windows opens a COM port exclusively anyway
    import fcntl
except ImportError:  # pragma: no cover - Windows
    fcntl = None

from jerklab.rig.client import PortBusyError

__all__ = ["list_ports", "PortLock", "lock_dir", "port_holders", "ARDUINO_USB_IDS"]

# USB vendor:product ids of boards and USB-serial chips an Uno (or a clone) shows up as.
ARDUINO_USB_IDS = {
    (0x2341, 0x0043): "Arduino Uno (ATmega16U2)",
    (0x2341, 0x0001): "Arduino Uno (ATmega8U2)",
    (0x2341, 0x0243): "Arduino Uno R3 (ATmega16U2)",
    (0x2341, 0x0069): "Arduino Uno R4 Minima",
    (0x2A03, 0x0043): "Arduino Uno (arduino.org)",
}
_ARDUINO_VIDS = {0x2341: "Arduino", 0x2A03: "Arduino (arduino.org)"}
_CLONE_CHIPS = {
    (0x1A86, 0x7523): "CH340 USB-serial (Uno clone?)",
    (0x0403, 0x6001): "FTDI FT232R USB-serial",
    (0x10C4, 0xEA60): "CP210x USB-serial",
}


def list_ports(include_all=False) -> list:
    """Serial ports that may have a rig behind them, likely Arduinos first.

    Parameters
    ----------
    include_all : bool
        Also list ports without a USB id (legacy ``/dev/ttyS*`` and the like).

    Returns
    -------
    list of dict
        ``device``, ``description``, ``vid_pid`` (``"2341:0043"`` or None), ``manufacturer``,
        ``serial_number``, ``likely`` (``"arduino"``, ``"usb-serial"`` or ``""``), ``note``
        (what the USB id says) and ``holder`` (who has it open, if anyone we can see).
    """
    try:
        from serial.tools import list_ports as lp
    except ImportError as exc:  # pragma: no cover - pyserial is a dependency
        raise ImportError("listing ports needs pyserial (pip install pyserial)") from exc
    rows = []
    for p in lp.comports():
        vid, pid = p.vid, p.pid
        if vid is None and not include_all:
            continue
        note, likely = "", ""
        if vid is not None:
            if (vid, pid) in ARDUINO_USB_IDS:
                note, likely = ARDUINO_USB_IDS[(vid, pid)], "arduino"
            elif vid in _ARDUINO_VIDS:
                note, likely = _ARDUINO_VIDS[vid], "arduino"
            elif (vid, pid) in _CLONE_CHIPS:
                note, likely = _CLONE_CHIPS[(vid, pid)], "usb-serial"
        holder = PortLock.holder_of(p.device)
        rows.append(
            {
                "device": p.device,
                "description": p.description or "",
                "vid_pid": None if vid is None else f"{vid:04x}:{pid or 0:04x}",
                "manufacturer": p.manufacturer,
                "serial_number": p.serial_number,
                "likely": likely,
                "note": note,
                "holder": _describe(holder) if holder else "",
            }
        )
    order = {"arduino": 0, "usb-serial": 1, "": 2}
    rows.sort(key=lambda r: (order[r["likely"]], r["device"]))
    return rows


def lock_dir() -> Path:
    """Folder of the port lock files (``$JERKLAB_LOCK_DIR``, else ``<tmp>/jerklab-locks``)."""
    d = os.environ.get("JERKLAB_LOCK_DIR")
    return Path(d) if d else Path(tempfile.gettempdir()) / "jerklab-locks"


def _lock_path(device: str) -> Path:
    real = os.path.realpath(device) if os.path.exists(device) else device
    name = re.sub(r"[^A-Za-z0-9_.-]", "_", real.strip("/\\")) or "port"
    return lock_dir() / f"{name}.lock"


def _describe(info: dict) -> str:
    prog = info.get("program") or "?"
    since = info.get("since")
    when = (
        time.strftime(" since %H:%M:%S", time.localtime(since))
        if isinstance(since, (int, float))
        else ""
    )
    return f"pid {info.get('pid', '?')} on {info.get('host', '?')} ({prog}){when}"


def _pid_alive(pid) -> bool:
    if not isinstance(pid, int) or pid <= 0:
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    except OSError:  # pragma: no cover - Windows without the pid
        return False
    return True


def port_holders(device: str) -> list:
    """Processes that have ``device`` open (Linux ``/proc``; only those we may look at).

    Returns a list of ``(pid, program)``; empty where ``/proc`` is not there.
    """
    if not os.path.isdir("/proc") or not os.path.exists(device):
        return []
    target = os.path.realpath(device)
    out = []
    for pid in os.listdir("/proc"):
        if not pid.isdigit() or int(pid) == os.getpid():
            continue
        fd_dir = f"/proc/{pid}/fd"
        try:
            fds = os.listdir(fd_dir)
        except OSError:
            continue
        for fd in fds:
            try:
                if os.readlink(f"{fd_dir}/{fd}") == target:
                    try:
                        with open(f"/proc/{pid}/cmdline", "rb") as fh:
                            cmd = fh.read().replace(b"\0", b" ").decode(errors="replace").strip()
                    except OSError:
                        cmd = "?"
                    out.append((int(pid), cmd[:120]))
                    break
            except OSError:
                continue
    return out


class PortLock:
    """An advisory lock on a serial port, held while a :class:`~jerklab.rig.Rig` uses it.

    The lock file (one per device, in :func:`lock_dir`) is locked with ``flock`` (released by
    the kernel if the process dies) and carries the holder's pid, host, program and start
    time, so the error a second user gets can name the holder.

    Parameters
    ----------
    device : str
        The port (``/dev/ttyACM0``, a ``/dev/pts/N``, ``COM3``).
    """

    def __init__(self, device: str):
        self.device = device
        self.path = _lock_path(device)
        self._fh = None

    @staticmethod
    def holder_of(device: str):
        """The holder's info dict if ``device`` is locked by a live process, else None."""
        path = _lock_path(device)
        try:
            with open(path) as fh:
                if fcntl is not None:
                    try:
                        fcntl.flock(fh, fcntl.LOCK_SH | fcntl.LOCK_NB)
                    except OSError:
                        pass  # held: read what the holder wrote
                    else:
                        fcntl.flock(fh, fcntl.LOCK_UN)
                        return None  # nobody holds it (stale file)
                info = json.loads(fh.read() or "{}")
        except (OSError, ValueError):
            return None
        if info.get("host") == socket.gethostname() and not _pid_alive(info.get("pid")):
            return None
        return info or None

    def acquire(self):
        """Take the lock or raise :class:`~jerklab.rig.PortBusyError` naming the holder."""
        self.path.parent.mkdir(parents=True, exist_ok=True)
        fh = open(self.path, "a+")
        try:
            if fcntl is not None:
                try:
                    fcntl.flock(fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
                except OSError as exc:
                    if exc.errno not in (errno.EAGAIN, errno.EACCES, errno.EWOULDBLOCK):
                        raise
                    fh.seek(0)
                    try:
                        info = json.loads(fh.read() or "{}")
                    except ValueError:
                        info = {}
                    raise PortBusyError(
                        f"port {self.device!r} is in use by {_describe(info) if info else 'another process'} "
                        f"(lock file {self.path}); close that rig (rig.close(), or stop its kernel) or use "
                        "another port",
                        port=self.device,
                        holder=info,
                    ) from None
            else:  # pragma: no cover - Windows
                import msvcrt

                try:
                    msvcrt.locking(fh.fileno(), msvcrt.LK_NBLCK, 1)
                except OSError:
                    raise PortBusyError(
                        f"port {self.device!r} is in use by another jerklab process "
                        f"(lock file {self.path})",
                        port=self.device,
                    ) from None
            fh.seek(0)
            fh.truncate()
            fh.write(
                json.dumps(
                    {
                        "pid": os.getpid(),
                        "host": socket.gethostname(),
                        "program": " ".join(sys.argv)[:200] or sys.executable,
                        "port": self.device,
                        "since": time.time(),
                    }
                )
            )
            fh.flush()
        except BaseException:
            fh.close()
            raise
        self._fh = fh
        return self

    def release(self):
        """Give the lock back (idempotent)."""
        fh, self._fh = self._fh, None
        if fh is None:
            return
        try:
            fh.seek(0)
            fh.truncate()
            fh.flush()
        except OSError:
            pass
        finally:
            fh.close()  # closing drops the flock

    @property
    def held(self) -> bool:
        return self._fh is not None

    def __enter__(self):
        return self.acquire()

    def __exit__(self, *exc):
        self.release()
