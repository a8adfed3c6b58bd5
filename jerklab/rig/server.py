"""Serve the virtual rig on a pseudo-terminal or a TCP port, as a board would.

:class:`DeviceServer` runs a :class:`~jerklab.rig.virtual.VirtualDevice` in a thread,
paced at ``speed`` times real time, behind

* a pseudo-terminal (:meth:`DeviceServer.start_pty` returns ``/dev/pts/N``): any serial
  client opens it like ``/dev/ttyACM0`` — ``jerklab.rig.connect("/dev/pts/N")``;
* a TCP port (:meth:`DeviceServer.start_tcp`): ``connect("socket://localhost:PORT")``,
  the paper's Ethernet set-up (Stojčić §4, ASCII Stojcic: the rig as a network server).

``python -m jerklab.rig serve`` is the command-line front end.  :meth:`pull_cable`
and :meth:`freeze` inject the failures a lab sees (a USB cable pulled out, a hung
board) for tests.

One client at a time: on TCP a second client is answered ERROR(BUSY) and closed (the
client reports "rig busy: already in use by another client"); a client that disconnects
stops its own run, and nothing of it reaches the next client.  A host that does not read
loses whole TELEMETRY frames once more than ``_OUT_LIMIT`` bytes wait (never a reply or
END_OF_RUN, never part of a frame): :attr:`DeviceServer.dropped_frames` counts them and
the client sees the gap in the telemetry ``index`` (``lost_samples`` in the recording).
"""

from __future__ import annotations

import collections
import errno
import os
import select
import socket
import threading
import time

from jerklab import protocol as P
from jerklab.rig.virtual import VirtualDevice

__all__ = ["DeviceServer"]

_OUT_LIMIT = 1 << 16  # bytes kept for a host that does not read (then oldest telemetry dropped)
_BUSY_LINGER = 3.0  # s a refused second TCP client is kept at most (a HELLO's retry time)
_AHEAD = 4096  # at speed=None, run ticks while less than this is waiting to be sent


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
        self._fd = None  # the fd the device talks through (pty master or socket)
        self._slave = None
        self._listener = None
        self._conn = None
        self._thread = None
        self._stop = threading.Event()
        self._pull = threading.Event()  # pull_cable() asks the serving thread to drop the link
        self._lock = threading.Lock()
        self._frozen = False
        self.dropped_bytes = 0
        self.dropped_frames = 0  # TELEMETRY frames dropped for a host that did not read
        self.sent_bytes = 0
        self.refused_clients = 0  # second TCP clients answered BUSY
        self._busy = []  # (socket, close time) of refused clients
        self.error = None

    # ------------------------------------------------------------------ start / stop
    def start_pty(self) -> str:
        """Open a pseudo-terminal, start serving, return the path a client opens."""
        if not hasattr(os, "openpty"):
            raise OSError(
                "a pseudo-terminal needs Linux or macOS; on Windows use start_tcp() "
                "(`serve --tcp PORT`) or the in-process virtual rig, jerklab.rig.connect()"
            )
        import tty  # POSIX only (termios): imported here, not at module load

        master, slave = os.openpty()
        tty.setraw(slave)  # no echo, no line editing: a binary link
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
        self._thread = threading.Thread(
            target=self._run, name=f"jerklab-rig {self.port}", daemon=True
        )
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

    def _refuse(self):
        """A second TCP client while one is served: answer ERROR(BUSY) now and to each of its
        frames (a client may discard what arrived before its HELLO), then close it."""
        try:
            conn, _ = self._listener.accept()
        except (BlockingIOError, OSError):
            return
        self.refused_clients += 1
        conn.setblocking(False)
        self._busy.append([conn, P.Decoder(), time.monotonic() + _BUSY_LINGER])
        self._answer_busy(conn)

    @staticmethod
    def _answer_busy(conn):
        try:
            conn.send(P.encode(P.DeviceError(int(P.ErrorCode.BUSY), 0), 0))
        except OSError:
            pass

    def _reap_busy(self):
        """Serve the refused clients: read what they send (closing with unread data would reset
        the connection before they read the answer), answer BUSY to each frame, close them
        shortly after an answered frame, at their EOF, or after _BUSY_LINGER."""
        keep = []
        now = time.monotonic()
        for entry in self._busy:
            conn, dec, until = entry
            done = now >= until
            try:
                while not done:
                    data = conn.recv(4096)
                    if not data:
                        done = True
                    elif dec.feed(data):
                        self._answer_busy(conn)
                        entry[2] = until = min(until, now + 0.2)
            except BlockingIOError:
                pass
            except OSError:
                done = True
            if done:
                conn.close()
            else:
                keep.append(entry)
        self._busy = keep

    def _run(self):
        try:
            self._loop()
        except Exception as exc:  # keep the reason for the test or the CLI
            self.error = exc
        finally:
            for entry in self._busy:
                entry[0].close()
            self._busy = []

    def _host_gone(self, out):
        """The TCP client left: its run stops, its output is dropped; wait for the next."""
        self._close_link()
        self.device.host_gone()
        out.clear()

    def _loop(self):
        dev = self.device
        out = _FrameQueue()
        next_tick = time.monotonic()
        while not self._stop.is_set():
            if self._pull.is_set():
                self._close_link()
                out.clear()
                self._pull.clear()
            if self._busy:
                self._reap_busy()
            fd = self._fd
            if fd is None:
                if self._listener is None:
                    return  # pty closed (pull_cable)
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
            rlist = [fd] if self._listener is None else [fd, self._listener]
            try:
                r, w, _ = select.select(rlist, [fd] if out else [], [], wait)
            except (OSError, ValueError):
                continue  # the fd was closed under us: next round sees None
            if self._listener is not None and self._listener in r:
                self._refuse()
            if fd in r:
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
                    self._host_gone(out)  # TCP client went away: wait for the next one
                    continue
                if data:
                    dev.receive(data)
            if not self._frozen:
                dev.poll()  # a partial frame expires after 20 ms, as on the board
            now = time.monotonic()
            if running:
                if self.speed is None:
                    if len(out) < _AHEAD:
                        dev.tick()
                elif now >= next_tick:
                    dev.tick()
                    next_tick += dev.period / self.speed
                    if next_tick < now - 0.25:  # fell far behind: do not burst
                        next_tick = now
            produced = dev.read_output()
            if not self._frozen:
                out.extend(produced)
            if out:
                try:
                    n = os.write(fd, out.head(4096))
                    self.sent_bytes += n
                    out.consume(n)
                except BlockingIOError:
                    pass
                except OSError:
                    if self._conn is not None:
                        self._host_gone(out)
                        continue
                    return
            if len(out) > _OUT_LIMIT:
                frames, nbytes = out.drop_telemetry(len(out) - _OUT_LIMIT)
                self.dropped_frames += frames
                self.dropped_bytes += nbytes


class _FrameQueue:
    """Bytes waiting to be sent, kept as whole frames so that a host that does not read
    loses whole TELEMETRY frames (the oldest first), never a reply or part of a frame."""

    def __init__(self):
        self._frames = collections.deque()
        self._offset = 0  # bytes of the first frame already written
        self._len = 0

    def __len__(self):
        return self._len

    def clear(self):
        self._frames.clear()
        self._offset = self._len = 0

    def extend(self, data: bytes):
        """Append device output (whole frames, as the device writes them)."""
        i = 0
        while i < len(data):
            n = data[i + 2] + 5 if i + 2 < len(data) else len(data) - i
            self._frames.append(bytes(data[i : i + n]))
            i += n
        self._len += len(data)

    def head(self, n):
        out = bytearray()
        off = self._offset
        for f in self._frames:
            out += f[off:]
            off = 0
            if len(out) >= n:
                break
        return bytes(out[:n])

    def consume(self, n):
        self._len -= n
        n += self._offset
        while self._frames and n >= len(self._frames[0]):
            n -= len(self._frames.popleft())
        self._offset = n

    def drop_telemetry(self, excess):
        """Drop the oldest whole TELEMETRY frames (not the one being written) until
        ``excess`` bytes are gone; returns (frames, bytes) dropped."""
        kept = collections.deque()
        frames = nbytes = 0
        first = True
        while self._frames:
            f = self._frames.popleft()
            partial = first and self._offset > 0
            first = False
            if nbytes < excess and not partial and len(f) > 3 and f[3] == P.MsgType.TELEMETRY:
                frames += 1
                nbytes += len(f)
                continue
            kept.append(f)
        kept.extend(self._frames)
        self._frames = kept
        self._len -= nbytes
        return frames, nbytes
