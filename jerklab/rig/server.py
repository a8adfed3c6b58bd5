"""Serve the virtual rig on a pseudo-terminal or a TCP port, as a board would.

:class:`DeviceServer` runs a :class:`~jerklab.rig.virtual.VirtualDevice` in a thread,
paced at ``speed`` times real time, behind

* a pseudo-terminal (:meth:`DeviceServer.start_pty` returns ``/dev/pts/N``): any serial
  client opens it like ``/dev/ttyACM0`` — ``jerklab.rig.connect("/dev/pts/N")``;
* a TCP port (:meth:`DeviceServer.start_tcp`): ``connect("socket://localhost:PORT")``,
  the paper's Ethernet set-up (Stojčić §4: the rig as a network server).

``python -m jerklab.rig serve`` is the command-line front end.  :meth:`pull_cable`
and :meth:`freeze` inject the failures a lab sees (a USB cable pulled out, a hung
board) for tests.
"""
from __future__ import annotations

import errno
import os
import select
import socket
import threading
import time

from jerklab.rig.virtual import VirtualDevice

__all__ = ["DeviceServer"]

_OUT_LIMIT = 1 << 16      # bytes kept for a host that does not read (then oldest dropped)
_AHEAD = 4096             # at speed=None, run ticks while less than this is waiting to be sent


class DeviceServer:
    """A virtual rig behind a pty or a TCP socket, served from a background thread.

    Parameters
    ----------
    device : VirtualDevice, optional
        The firmware model (default: one with the paper's motor).
    speed : float or None
        Times real time (1.0 = a real board's pace); ``None`` as fast as the host reads.
    """

    def __init__(self, device: VirtualDevice | None = None, speed: float | None = 1.0):
        self.device = VirtualDevice() if device is None else device
        if speed is not None and not speed > 0:
            raise ValueError(f"speed must be > 0 or None, got {speed!r}")
        self.speed = speed
        self.port = None
        self._fd = None            # the fd the device talks through (pty master or socket)
        self._slave = None
        self._listener = None
        self._conn = None
        self._thread = None
        self._stop = threading.Event()
        self._pull = threading.Event()     # pull_cable() asks the serving thread to drop the link
        self._lock = threading.Lock()
        self._frozen = False
        self.dropped_bytes = 0
        self.sent_bytes = 0
        self.error = None

    # ------------------------------------------------------------------ start / stop
    def start_pty(self) -> str:
        """Open a pseudo-terminal, start serving, return the path a client opens."""
        if not hasattr(os, "openpty"):
            raise OSError("a pseudo-terminal needs Linux or macOS; on Windows use start_tcp() "
                          "(`serve --tcp PORT`) or the in-process virtual rig, jerklab.rig.connect()")
        import tty                          # POSIX only (termios): imported here, not at module load

        master, slave = os.openpty()
        tty.setraw(slave)                   # no echo, no line editing: a binary link
        os.set_blocking(master, False)
        self._fd, self._slave = master, slave
        self.port = os.ttyname(slave)
        self._start()
        return self.port

    def start_tcp(self, host="127.0.0.1", port=0) -> str:
        """Listen on ``host:port`` (0: a free port); return the ``socket://`` URL."""
        ls = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        ls.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        ls.bind((host, port))
        ls.listen(1)
        ls.setblocking(False)
        self._listener = ls
        h, p = ls.getsockname()
        self.port = f"socket://{h}:{p}"
        self._start()
        return self.port

    def _start(self):
        self._thread = threading.Thread(target=self._run, name=f"jerklab-rig {self.port}", daemon=True)
        self._thread.start()

    def close(self):
        """Stop the thread and close everything."""
        self._stop.set()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout=2.0)
        self._close_link()
        if self._listener is not None:
            self._listener.close()
            self._listener = None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def _close_link(self):
        with self._lock:
            for attr in ("_fd", "_slave"):
                fd = getattr(self, attr)
                if fd is not None:
                    try:
                        if self._conn is not None and attr == "_fd":
                            self._conn.close()
                        else:
                            os.close(fd)
                    except OSError:
                        pass
                    setattr(self, attr, None)
            self._conn = None

    # ------------------------------------------------------------------ fault injection
    def pull_cable(self):
        """Close the link abruptly, like a USB cable pulled out mid-run (the client sees an I/O error).

        The serving thread owns the file descriptor and closes it itself: closing it from here
        could let the number be reused (by the client's recording file, say) while that thread
        still writes frames to it.
        """
        thread = self._thread
        if thread is None or not thread.is_alive() or thread is threading.current_thread():
            self._close_link()
            return
        self._pull.set()
        deadline = time.monotonic() + 1.0
        while self._pull.is_set() and thread.is_alive() and time.monotonic() < deadline:
            time.sleep(0.001)

    def freeze(self):
        """The board hangs: it stops ticking and sending (the client times out)."""
        self._frozen = True

    # ------------------------------------------------------------------ the loop
    def _accept(self):
        r, _, _ = select.select([self._listener], [], [], 0.05)
        if r:
            conn, _ = self._listener.accept()
            conn.setblocking(False)
            conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            with self._lock:
                self._conn, self._fd = conn, conn.fileno()

    def _run(self):
        try:
            self._loop()
        except Exception as exc:            # keep the reason for the test or the CLI
            self.error = exc

    def _loop(self):
        dev = self.device
        out = bytearray()
        next_tick = time.monotonic()
        while not self._stop.is_set():
            if self._pull.is_set():
                self._close_link()
                out.clear()
                self._pull.clear()
            fd = self._fd
            if fd is None:
                if self._listener is None:
                    return                  # pty closed (pull_cable)
                out.clear()
                self._accept()
                continue
            now = time.monotonic()
            running = dev.active and not self._frozen
            if not running:
                wait, next_tick = 0.02, now
            elif self.speed is None:
                wait = 0.0 if len(out) < _AHEAD else 0.005
            else:
                wait = max(0.0, next_tick - now)
            try:
                r, w, _ = select.select([fd], [fd] if out else [], [], wait)
            except (OSError, ValueError):
                continue                    # the fd was closed under us: next round sees None
            if r:
                try:
                    data = os.read(fd, 4096)
                except BlockingIOError:
                    data = None
                except OSError as exc:
                    if exc.errno in (errno.EIO, errno.EBADF, errno.ECONNRESET):
                        data = b""
                    else:
                        raise
                if data == b"" and self._conn is not None:
                    self._close_link()      # TCP client went away: wait for the next one
                    continue
                if data:
                    dev.receive(data)
            now = time.monotonic()
            if running:
                if self.speed is None:
                    if len(out) < _AHEAD:
                        dev.tick()
                elif now >= next_tick:
                    dev.tick()
                    next_tick += dev.period / self.speed
                    if next_tick < now - 0.25:          # fell far behind: do not burst
                        next_tick = now
            produced = dev.read_output()
            if not self._frozen:
                out += produced
            if out:
                try:
                    n = os.write(fd, out)
                    self.sent_bytes += n
                    del out[:n]
                except BlockingIOError:
                    pass
                except OSError:
                    if self._conn is not None:
                        self._close_link()
                        continue
                    return
            if len(out) > _OUT_LIMIT:
                extra = len(out) - _OUT_LIMIT
                self.dropped_bytes += extra
                del out[:extra]
