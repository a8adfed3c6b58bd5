"""One rig for a whole class page: a broker that owns the rig and runs the students' moves in turn.

``python -m jerklab.app --rig PORT --pool 4`` starts one Voilà kernel per visitor. Were each
kernel to open the serial port itself, a second student would kill the first one's run (and
on a real Uno, opening the port resets the board). Instead, the app starts this broker: the
only process that opens the rig. Each kernel's panel sends its run to the broker, which
queues the runs first come, first served and runs them one at a time; while a run waits,
the broker tells its panel how many runs are ahead ("queued: 2 ahead of you").

    python -m jerklab.broker --rig /dev/ttyACM0        # prints broker://127.0.0.1:PORT
    python -m jerklab.broker --rig virtual             # a virtual rig at real-time pace

The link between a kernel and the broker is one TCP connection per run, carrying one JSON
object per line (localhost only by default):

* client -> broker: ``{"op": "run_move", "profile": {"kind", "distance", "max_jerk",
  "max_accel", "max_velocity"}, "gains": {"kpd", "kid", "kdd", "Ts", "gamma", "loop"},
  "Ts": s, "feedforward": {"K", "tau"} | true | false, "settle": s, "force": false,
  "client": "label", "token": "...", "stream": false}``, or ``{"op": "info"}``;
* broker -> client: ``{"queued": n_ahead}`` (on arrival, when the queue moves and every
  ``HEARTBEAT`` s), ``{"running": true}``, then ``{"done": true, "csv": ..., "json": ...}``
  (the :class:`jerklab.rig.Recording` files) or ``{"error": "...", "type": "..."}``;
* with ``"stream": true``, between ``running`` and ``done``: ``{"samples": {"start": i,
  "rows": [[index, reference, counts, pwm, flags], ...], "meta": {...}}}``, the recording's
  rows ``i, i+1, ...`` (:meth:`jerklab.rig.Recording.rows`) as the rig records them, at most
  every :data:`STREAM_INTERVAL` s; each batch starts where the one before ended, and the
  first carries ``"meta"`` (``Ts``, ``counts_per_rad``, ``volts_per_pwm`` of the recording,
  ``total`` samples expected).

The stream goes only to the connection that sent the run, and it never holds up the rig: the
run's thread only records, and the connection's own thread sends the new rows without
blocking. A client that reads slowly gets fewer, larger batches (rows not yet sent go into
the next one, at most :data:`STREAM_MAX_ROWS` a batch); one that does not read at all holds
at most one unsent batch in the broker. ``done`` is sent whole in any case, after the batch
in flight, and holds every sample.

A client that disconnects while queued leaves the queue. A run whose client went away
still finishes on the rig (a move cannot be abandoned half-way), and its result is dropped.
The broker refuses a design whose sampled loop has ``|z|`` ≥ 1 unless ``force`` is set
(:func:`jerklab.tuning.check_runnable`), so no kernel can run away a motor.

A fair queue for a class. Who sent a run is its *identity*: with ``--hub-auth`` (the broker
run as a JupyterHub service, deploy/jupyterhub) the hub's user name for the request's
``token`` (:mod:`jerklab.hubauth`; a request without a valid token is refused), else the
``client`` label, marked ``"identity": "unverified"`` in the recording. Each identity has at
most one run queued or running (:data:`MAX_RUNS_PER_STUDENT`), and every run is bounded by
:class:`Limits` (distance, planned duration, settle); a refusal names the limit. The run's
recording carries ``"student"`` (the identity) and ``"identity"`` (``"hub"`` or
``"unverified"``); with ``recordings=`` the broker also keeps its own copy under
``<recordings>/<identity>/``, each run in a file of its own.
"""

from __future__ import annotations

import argparse
import dataclasses
import datetime as _dt
import itertools
import json
import math
import os
import re
import select
import socket
import sys
import tempfile
import threading
import time
import uuid
from pathlib import Path

from jerklab import planner, tuning
from jerklab._validate import as_positive
from jerklab.controller import DiscreteGains, Feedforward
from jerklab.hubauth import HubIdentity, token_from_env
from jerklab.rig import Device, connect
from jerklab.rig import live as _live
from jerklab.rig.recording import Recording, recordings_dir

__all__ = [
    "RigBroker",
    "BrokerRig",
    "BrokerError",
    "Limits",
    "SCHEME",
    "HEARTBEAT",
    "MAX_RUNS_PER_STUDENT",
    "STREAM_INTERVAL",
    "STREAM_MAX_ROWS",
    "unique_run_name",
    "main",
]

#: Address prefix of a broker: ``broker://host:port``.
SCHEME = "broker://"

#: Seconds between "queued" messages to a waiting client (a client that hears nothing for
#: ``4 × HEARTBEAT`` gives up).
HEARTBEAT = 1.0

_MAX_REQUEST = 1 << 16  # bytes of one request line
_MAX_TIMEOUT = 86400.0  # s: socket timeouts beyond a day overflow the platform's time_t

#: Runs one identity may have queued or running at once.
MAX_RUNS_PER_STUDENT = 1

#: Seconds between two batches of a streamed run (at most 10 a second).
STREAM_INTERVAL = 0.1

#: Samples in one batch of a streamed run at most (a client that fell behind catches up in
#: several batches).
STREAM_MAX_ROWS = 2000


@dataclasses.dataclass(frozen=True)
class Limits:
    """What the broker runs at most for one request (a refusal names the limit it passes).

    Parameters
    ----------
    max_distance : float
        Largest absolute distance of a move (rad).
    max_duration : float
        Planned duration of a move (s), the settle not counted.
    max_settle : float
        Settle time recorded after the move (s).
    """

    max_distance: float = 120.0
    max_duration: float = 5.0
    max_settle: float = 2.0

    def check(self, distance, duration, settle):
        """Raise :class:`LimitError` naming the first limit a run passes."""
        for name, value, limit, unit in (
            ("distance", abs(distance), self.max_distance, "rad"),
            ("duration", duration, self.max_duration, "s"),
            ("settle", settle, self.max_settle, "s"),
        ):
            if not math.isfinite(value) or value > limit:
                raise LimitError(
                    f"{name} {value:g} {unit} is beyond this rig's limit "
                    f"max_{name} = {limit:g} {unit}"
                )


class LimitError(ValueError):
    """A run passes one of the broker's :class:`Limits`."""


class QueueFullError(RuntimeError):
    """The identity already has :data:`MAX_RUNS_PER_STUDENT` runs queued or running."""


_SAFE_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._-]{0,63}$")
_RUN_COUNTER = itertools.count(1)


def _folder_name(identity):
    """A folder name for an identity: itself when it is a plain name, else a digest of it."""
    if _SAFE_NAME.match(identity) and ".." not in identity:
        return identity
    import hashlib

    return "id-" + hashlib.sha256(identity.encode("utf-8")).hexdigest()[:12]


def unique_run_name(suffix="move"):
    """``<UTC date-time to the microsecond>_<process counter>_<random>_<suffix>``: a file stem no
    other run of this or any other process takes (two runs in one second get two names)."""
    stamp = _dt.datetime.now(_dt.timezone.utc).strftime("%Y%m%d-%H%M%S-%f")
    return f"{stamp}_{next(_RUN_COUNTER):04d}_{uuid.uuid4().hex[:8]}_{suffix}"


class BrokerError(RuntimeError):
    """The broker is unreachable, refused the run, or the run failed on the rig."""


def parse_address(address):
    """``"broker://host:port"`` -> ``(host, port)``; ValueError naming ``address`` otherwise."""
    if not isinstance(address, str) or not address.startswith(SCHEME):
        raise ValueError(f"address must look like 'broker://host:port', got {address!r}")
    host, sep, port = address[len(SCHEME) :].rpartition(":")
    if not sep or not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise ValueError(f"address must look like 'broker://host:port', got {address!r}")
    return host, int(port)


def _send(conn, lock, obj):
    data = (json.dumps(obj) + "\n").encode("utf-8")
    with lock:
        conn.sendall(data)


class _Ticket:
    def __init__(self, conn, request, identity, verified, job):
        self.conn = conn
        self.request = request
        self.identity = identity  # who sent it (the hub's name, or the unverified label)
        self.verified = verified
        self.job = job  # the checked run: a callable returning the Recording
        self.lock = threading.Lock()  # one writer at a time on conn
        self.done = threading.Event()
        self.gone = False  # the client disconnected
        self.reply = None
        self.stream = bool(request.get("stream", False)) if isinstance(request, dict) else False
        self.rec = None  # the Recording of this run, once its first sample is in (streaming)

    def tell(self, obj):
        if self.gone:
            return
        try:
            _send(self.conn, self.lock, obj)
        except OSError:
            self.gone = True


class _Stream:
    """The rows of a running run on their way to its client, sent without ever blocking.

    :meth:`tick` (called by the connection's thread, never the rig's) puts the rows recorded
    since the last batch into one message, at most every ``interval`` s and at most
    ``max_rows`` rows, and writes what the socket takes at once (``send`` on a non-blocking
    socket). While a message is not written out, no new one is made: the rows wait in the
    recording and go into the next batch, so at most one message is held per client.
    :meth:`drain` writes the rest of that message (blocking) before the final reply, so the
    lines stay whole.
    """

    def __init__(self, conn, lock, interval=None, max_rows=None, clock=time.monotonic):
        self.conn = conn
        self.lock = lock
        self.interval = STREAM_INTERVAL if interval is None else float(interval)
        self.max_rows = STREAM_MAX_ROWS if max_rows is None else int(max_rows)
        self.clock = clock
        self.pending = b""  # the part of the last message the socket has not taken yet
        self.rows_sent = 0  # rows put into messages
        self.batches = 0  # messages made
        self.held = 0  # ticks at which the socket was full (the rows waited)
        self._next = -math.inf

    def tick(self, rec):
        """Send what the socket takes; OSError (not BlockingIOError) when the client is gone."""
        if self.pending:
            self._push()
            if self.pending:
                self.held += 1
                return
        now = self.clock()
        n = len(rec)
        if now < self._next or n <= self.rows_sent:
            return
        rows = rec.rows(self.rows_sent, min(n, self.rows_sent + self.max_rows))
        batch = {"start": self.rows_sent, "rows": [list(r) for r in rows]}
        if self.batches == 0:
            m = rec.metadata
            plan = m.get("plan") or {}
            batch["meta"] = {
                "kind": m.get("kind"),
                "Ts": m["Ts"],
                "counts_per_rad": m["counts_per_rad"],
                "volts_per_pwm": m["volts_per_pwm"],
                "total": int(plan.get("n_samples", 0)) + int(m.get("settle_samples", 0)),
            }
        self.pending = (json.dumps({"samples": batch}) + "\n").encode("utf-8")
        self.rows_sent += len(rows)
        self.batches += 1
        self._next = now + self.interval
        self._push()

    def _push(self):
        with self.lock:
            try:
                sent = self.conn.send(self.pending)
            except (BlockingIOError, InterruptedError):
                return
        self.pending = self.pending[sent:]

    def drain(self):
        """Write the rest of the message in flight (blocking: the run is over)."""
        if self.pending:
            with self.lock:
                self.conn.sendall(self.pending)
            self.pending = b""


def _refusal(exc):
    return {"error": f"{type(exc).__name__}: {exc}", "type": type(exc).__name__}


class RigBroker:
    """Owns one rig and runs the moves sent by many clients, one at a time, in arrival order.

    Parameters
    ----------
    rig_port : str or None
        What :func:`jerklab.rig.connect` opens (``None``/``"virtual"``: a virtual rig,
        ``"simavr"``, a device path or pyserial URL).
    host, port : str, int
        Where to listen (port 0: any free port).
    speed : float or None
        Virtual rig only: times real time (default 1.0, the pace of a board).
    connect_kwargs : dict, optional
        More arguments for :func:`jerklab.rig.connect`.
    authenticate : callable, optional
        ``token -> identity`` raising :class:`PermissionError` for a token it does not accept
        (:class:`jerklab.hubauth.HubIdentity` on a hub). When given, a run without a valid
        ``token`` is refused and its identity is the one returned; without it the identity is
        the request's ``client`` label, recorded as unverified.
    limits : Limits, optional
        Bounds of one run (default :class:`Limits`).
    recordings : path, optional
        Folder where the broker keeps its own copy of every run, under
        ``<recordings>/<identity>/<unique name>.csv`` (default: none kept).
    """

    def __init__(
        self,
        rig_port=None,
        host="127.0.0.1",
        port=0,
        speed=1.0,
        connect_kwargs=None,
        *,
        authenticate=None,
        limits=None,
        recordings=None,
    ):
        if authenticate is not None and not callable(authenticate):
            raise TypeError(f"authenticate must be callable, got {type(authenticate).__name__}")
        if limits is not None and not isinstance(limits, Limits):
            raise TypeError(f"limits must be a jerklab.broker.Limits, got {type(limits).__name__}")
        kwargs = dict(connect_kwargs or {})
        if rig_port in (None, "virtual"):
            kwargs.setdefault("device", Device(speed=speed))
        self.authenticate = authenticate
        self.limits = limits or Limits()
        self.recordings = None if recordings is None else Path(recordings)
        self.rig = connect(rig_port, progress=False, **kwargs)
        self._queue = []  # tickets waiting, in arrival order
        self._running = None
        self._cond = threading.Condition()
        self._stop = threading.Event()
        self._listener = socket.create_server((host, port))
        self._listener.settimeout(0.2)
        h, p = self._listener.getsockname()[:2]
        self.address = f"{SCHEME}{h}:{p}"
        self.runs_done = 0
        self.order = []  # identities in the order their runs started
        self.refused = []  # (identity or None, reason) of every refused run
        self.saved = []  # CSV paths of the broker's own copies
        #: one dict per streamed run: identity, batches, rows sent, ticks the client held up
        self.streams = []
        self._threads = [
            threading.Thread(target=self._accept_loop, daemon=True, name="jerklab-broker-accept"),
            threading.Thread(target=self._worker, daemon=True, name="jerklab-broker-worker"),
        ]
        for t in self._threads:
            t.start()

    # ------------------------------------------------------------------ lifecycle
    def close(self):
        """Stop serving and close the rig."""
        self._stop.set()
        with self._cond:
            self._cond.notify_all()
        for t in self._threads:
            t.join(timeout=30.0)
        self._listener.close()
        self.rig.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def queue_length(self):
        """Runs waiting (not counting the one running)."""
        with self._cond:
            return len(self._queue)

    # ------------------------------------------------------------------ clients
    def _accept_loop(self):
        while not self._stop.is_set():
            try:
                conn, _ = self._listener.accept()
            except socket.timeout:
                continue
            except OSError:
                return
            threading.Thread(
                target=self._serve, args=(conn,), daemon=True, name="jerklab-broker-client"
            ).start()

    def _read_request(self, conn):
        conn.settimeout(10.0)
        buf = b""
        while b"\n" not in buf:
            chunk = conn.recv(4096)
            if not chunk:
                raise ConnectionError("client closed before sending a request")
            buf += chunk
            if len(buf) > _MAX_REQUEST:
                raise ValueError(f"request longer than {_MAX_REQUEST} bytes")
        return json.loads(buf.split(b"\n", 1)[0].decode("utf-8"))

    def _identify(self, req):
        """``(identity, verified)`` of a request; PermissionError when a token is required."""
        if self.authenticate is not None:
            token = req.get("token")
            if not isinstance(token, str) or not token or len(token) > 4096:
                raise PermissionError("token: a hub token is required (log in through the hub)")
            return str(self.authenticate(token)), True
        label = req.get("client", "?")
        return (str(label)[:64] if label is not None else "?"), False

    def _serve(self, conn):
        lock = threading.Lock()
        try:
            try:
                req = self._read_request(conn)
                if not isinstance(req, dict):
                    raise ValueError("request must be a JSON object")
            except (ValueError, ConnectionError, OSError) as exc:
                _send(conn, lock, {"error": f"bad request: {exc}", "type": "ValueError"})
                return
            op = req.get("op")
            if op not in ("info", "run_move"):
                _send(
                    conn,
                    lock,
                    {"error": f"op must be 'info' or 'run_move', got {op!r}", "type": "ValueError"},
                )
                return
            try:
                identity, verified = self._identify(req)
            except PermissionError as exc:
                self.refused.append((None, str(exc)))
                _send(conn, lock, _refusal(exc))
                return
            if op == "info":
                r = self.rig
                _send(
                    conn,
                    lock,
                    {
                        "ok": True,
                        "info": r.device_info(),
                        "supply_voltage": r.supply_voltage,
                        "counts_per_rev": r.counts_per_rev,
                        "queued": self.queue_length(),
                        "identity": identity,
                        "verified": verified,
                        "limits": dataclasses.asdict(self.limits),
                    },
                )
                return
            try:
                job = self._prepare(req)
            except Exception as exc:  # a bad or unsafe run is refused before it queues
                self.refused.append((identity, str(exc)))
                _send(conn, lock, _refusal(exc))
                return
            self._queue_and_wait(conn, _Ticket(conn, req, identity, verified, job))
        except OSError:
            pass
        finally:
            conn.close()

    def _ahead(self, ticket):
        """Runs ahead of ``ticket`` (the running one included); call with the lock held."""
        return self._queue.index(ticket) + (1 if self._running is not None else 0)

    def _queue_and_wait(self, conn, ticket):
        with self._cond:
            mine = [t for t in self._queue if t.identity == ticket.identity]
            if self._running is not None and self._running.identity == ticket.identity:
                mine.append(self._running)
            if len(mine) >= MAX_RUNS_PER_STUDENT:
                exc = QueueFullError(
                    f"{ticket.identity!r} already has {len(mine)} run(s) queued or running; "
                    f"one student may have at most MAX_RUNS_PER_STUDENT = "
                    f"{MAX_RUNS_PER_STUDENT} at a time (wait for it to finish)"
                )
                self.refused.append((ticket.identity, str(exc)))
                ticket.tell(_refusal(exc))
                return
            self._queue.append(ticket)
            ahead = self._ahead(ticket)
            self._cond.notify_all()
        ticket.tell({"queued": ahead})
        conn.setblocking(False)
        last = time.monotonic()
        stream = _Stream(conn, ticket.lock) if ticket.stream else None
        while not ticket.done.wait(0.1 if ticket.rec is None else STREAM_INTERVAL / 2):
            if stream is not None and ticket.rec is not None and not ticket.gone:
                try:
                    stream.tick(ticket.rec)
                except OSError:
                    ticket.gone = True
            # a client that hangs up while waiting leaves the queue
            try:
                r, _, _ = select.select([conn], [], [], 0)
                if r and conn.recv(1) == b"":
                    ticket.gone = True
            except (BlockingIOError, InterruptedError):
                pass
            except OSError:
                ticket.gone = True
            if ticket.gone:
                with self._cond:
                    if ticket in self._queue:
                        self._queue.remove(ticket)
                        self._cond.notify_all()
                self._tell_positions()
                return
            if time.monotonic() - last > HEARTBEAT:
                last = time.monotonic()
                with self._cond:
                    ahead = self._ahead(ticket) if ticket in self._queue else None
                if ahead is not None:
                    ticket.tell({"queued": ahead})
        conn.setblocking(True)
        if stream is not None and stream.batches:
            self.streams.append(
                {
                    "identity": ticket.identity,
                    "batches": stream.batches,
                    "rows": stream.rows_sent,
                    "held": stream.held,
                }
            )
            try:
                stream.drain()
            except OSError:
                ticket.gone = True
        ticket.tell(ticket.reply)

    def _tell_positions(self):
        with self._cond:
            waiting = [(t, self._ahead(t)) for t in self._queue]
        for t, ahead in waiting:
            t.tell({"queued": ahead})

    # ------------------------------------------------------------------ the rig
    def _worker(self):
        while True:
            with self._cond:
                while not self._queue and not self._stop.is_set():
                    self._cond.wait(0.5)
                if self._stop.is_set():
                    for t in self._queue:
                        t.reply = {"error": "the broker stopped", "type": "BrokerError"}
                        t.done.set()
                    self._queue.clear()
                    return
                ticket = self._queue.pop(0)
                self._running = ticket
            self._tell_positions()
            ticket.tell({"running": True})
            self.order.append(ticket.identity)
            try:
                ticket.reply = self._finish(ticket, ticket.job(self._watcher(ticket)))
            except Exception as exc:  # every failure goes back to its client
                ticket.reply = _refusal(exc)
            finally:
                self.runs_done += 1
                with self._cond:
                    self._running = None
                ticket.done.set()
                self._tell_positions()

    def _watcher(self, ticket):
        """The run's ``on_telemetry`` when its client asked for the stream, else None: at the
        first sample it hands this run's recording (``rig.recording``, set when the run made
        it) to the connection's thread, which sends the rows; the rig's thread does no more."""
        if not ticket.stream:
            return None

        def on_telemetry(k, reference, position):
            if ticket.rec is None:
                ticket.rec = self.rig.recording

        return on_telemetry

    def _prepare(self, req):
        """Check a run request (kind, gains, stability, :class:`Limits`) and return its job."""
        p = req.get("profile")
        if not isinstance(p, dict):
            raise ValueError("profile must be a JSON object")
        kind = p.get("kind")
        plan = {
            "sine_jerk": planner.plan_sine_jerk,
            "sine_jerk_optimal": planner.plan_sine_jerk_optimal,
            "scurve": planner.plan_scurve,
        }.get(kind)
        distance = _number("profile.distance", p.get("distance"))
        settle = _number("settle", req.get("settle", 0.25))
        if settle < 0:
            raise ValueError(f"settle must be >= 0, got {settle:g}")
        # the distance first: planning a 1e12 rad move is itself work
        self.limits.check(distance, 0.0, settle)
        if kind == "trapezoid":
            profile = planner.plan_trapezoid(distance, p["max_accel"], p["max_velocity"])
        elif plan is None:
            raise ValueError(f"profile.kind must be a jerklab planner kind, got {kind!r}")
        else:
            profile = plan(distance, p["max_jerk"], p["max_accel"], p["max_velocity"])
        self.limits.check(distance, float(profile.duration), settle)
        g = req.get("gains")
        if not isinstance(g, dict):
            raise ValueError("gains must be a JSON object")
        gains = DiscreteGains(
            g["kpd"],
            g["kid"],
            g["kdd"],
            g["Ts"],
            gamma=g.get("gamma", 0.0),
            loop=g.get("loop", "position"),
        )
        ff = req.get("feedforward", True)
        if isinstance(ff, dict):
            ff = Feedforward(ff["K"], ff["tau"])
            K, tau = ff.K, ff.tau
        else:
            ff = bool(ff)
            K, tau = self.rig.model
        tuning.check_runnable(K, tau, gains, force=bool(req.get("force", False)))
        Ts = req.get("Ts", gains.Ts)

        def job(on_telemetry=None):
            return self.rig.run_move(
                profile,
                gains,
                Ts=Ts,
                feedforward=ff,
                settle=settle,
                path=False,
                progress=False,
                on_telemetry=on_telemetry,
            )

        return job

    def _finish(self, ticket, rec):
        """Stamp the identity into the recording, keep the broker's copy, build the reply."""
        rec.metadata["student"] = ticket.identity
        rec.metadata["identity"] = "hub" if ticket.verified else "unverified"
        if self.recordings is not None:
            folder = self.recordings / _folder_name(ticket.identity)
            folder.mkdir(parents=True, exist_ok=True)
            base = folder / unique_run_name()
            while base.with_name(base.name + ".csv").exists():  # never another run's file
                base = folder / unique_run_name()
            self.saved.append(Path(rec.save(base)))
        with tempfile.TemporaryDirectory(prefix="jerklab-broker-") as tmp:
            csv_path = Path(rec.save(Path(tmp) / "run"))
            return {
                "done": True,
                "csv": csv_path.read_text(encoding="ascii"),
                "json": csv_path.with_suffix(".json").read_text(encoding="utf-8"),
            }


def _number(name, value):
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ValueError(f"{name} must be a number, got {value!r}")
    return float(value)


class BrokerRig:
    """A kernel's handle on the class page's shared rig (see :class:`RigBroker`).

    It answers ``run_move`` like :class:`jerklab.rig.Rig`, but the run waits its turn in the
    broker's queue; ``on_status`` hears ``"queued: 2 ahead of you"`` and then ``"running on
    the rig"``. ``queues_runs`` is True so the tuning panel shows those messages.

    While the run is on the rig the broker streams its samples back (the ``samples``
    messages of :class:`RigBroker`), and they draw the same live plot as a kernel's own rig
    (:mod:`jerklab.rig.live`: in a Jupyter kernel, into ``live_display`` if set, else the
    cell's output); ``on_batch`` hears each batch too.

    Parameters
    ----------
    address : str
        ``broker://host:port`` printed by ``python -m jerklab.broker``.
    timeout : float
        Seconds to wait for the broker's answer to ``info`` and for each message while
        queued (the broker sends one every ``HEARTBEAT`` s) or running.
    client : str
        A label for the broker's log (e.g. the student ID); a broker on a hub ignores it and
        names the run by the hub's user for ``token``.
    token : str, optional
        The JupyterHub token sent with every request (default ``$JUPYTERHUB_API_TOKEN``: a
        kernel on the hub has its user's own).
    """

    queues_runs = True

    def __init__(self, address, timeout=10.0, client="kernel", token=None):
        self.address = address
        self.host, self.port = parse_address(address)
        self.timeout = as_positive("timeout", timeout)
        if self.timeout > _MAX_TIMEOUT:
            raise ValueError(f"timeout must be <= {_MAX_TIMEOUT:g} s (a day), got {timeout!r}")
        self.client = str(client)
        self._token = token if token is not None else token_from_env()
        self.info = self._request({"op": "info"})
        #: the name the broker knows this client by (the hub's user when ``verified``)
        self.identity = self.info.get("identity")
        self.verified = bool(self.info.get("verified"))
        self.port_name = address
        self.supply_voltage = self.info["supply_voltage"]
        self.counts_per_rev = self.info["counts_per_rev"]
        #: live plot of every run: None (in a Jupyter kernel unless ``$JERKLAB_LIVE_PLOT=0``),
        #: True or False, as :class:`jerklab.rig.Rig`'s ``live``; a run's ``live=`` overrides it
        self.live = None
        #: where a live plot goes: None (the cell's output), or ``display(widget)`` putting
        #: the plot's widget in a page of one's own (the tuning panel's live box)
        self.live_display = None
        self.closed = False

    def __repr__(self):
        return f"BrokerRig({self.address!r}, device={self.info['info'].get('name')!r})"

    def close(self):
        self.closed = True

    def _connect(self):
        try:
            return socket.create_connection((self.host, self.port), timeout=self.timeout)
        except OSError as exc:
            raise BrokerError(
                f"cannot reach the rig broker at {self.address}: {exc} "
                "(is `python -m jerklab.app --rig ...` still running?)"
            ) from exc

    def _lines(self, sock):
        buf = b""
        while True:
            while b"\n" not in buf:
                try:
                    chunk = sock.recv(1 << 16)
                except socket.timeout:
                    raise BrokerError(
                        f"the rig broker at {self.address} fell silent for {self.timeout:g} s"
                    ) from None
                if not chunk:
                    raise BrokerError(f"the rig broker at {self.address} closed the connection")
                buf += chunk
            line, buf = buf.split(b"\n", 1)
            yield json.loads(line.decode("utf-8"))

    def _request(self, req):
        if self._token:
            req = dict(req, token=self._token)
        with self._connect() as s:
            s.sendall((json.dumps(req) + "\n").encode("utf-8"))
            msg = next(self._lines(s))
        if "error" in msg:
            raise BrokerError(f"rig broker: {msg['error']}")
        return msg

    def run_move(
        self,
        profile,
        gains,
        Ts=None,
        *,
        feedforward=True,
        settle=0.25,
        path=None,
        progress=None,
        on_status=None,
        force=False,
        live=None,
        on_batch=None,
    ):
        """Queue the move on the shared rig, wait for its turn, return the Recording.

        ``path``: None writes to the recordings folder, False keeps it in memory, else that
        path (``.csv`` + ``.json``). ``progress`` is accepted for compatibility (ignored).

        ``live``: a live plot of the run (None: the rig's :attr:`live`; True/None draw one in
        a Jupyter kernel only, False none), drawn from the samples the broker streams while
        the run is on the rig and finished with every sample of the returned recording.
        ``on_batch``: called as ``on_batch(rec)`` in this thread after each streamed batch,
        ``rec`` a :class:`jerklab.rig.Recording` (in memory) holding the samples so far, the
        first ``len(rec)`` of the final recording. The run asks for the stream only when one
        of them wants it; a callback or plot that is slow makes the broker send fewer, larger
        batches, and never slows the rig.
        """
        if not isinstance(gains, DiscreteGains):
            raise TypeError(f"gains must be DiscreteGains, got {type(gains).__name__}")
        kind = getattr(profile, "kind", None)
        if kind is None:
            raise ValueError(
                f"profile must be a jerklab.planner Profile, got {type(profile).__name__}"
            )
        ff = (
            {"K": feedforward.K, "tau": feedforward.tau}
            if isinstance(feedforward, Feedforward)
            else bool(feedforward)
        )
        req = {
            "op": "run_move",
            "client": self.client,
            "profile": {
                "kind": kind,
                "distance": profile.distance,
                "max_jerk": profile.max_jerk,
                "max_accel": profile.max_accel,
                "max_velocity": profile.max_velocity,
            },
            "gains": {
                "kpd": gains.kpd,
                "kid": gains.kid,
                "kdd": gains.kdd,
                "Ts": gains.Ts,
                "gamma": gains.gamma,
                "loop": gains.loop,
            },
            "Ts": gains.Ts if Ts is None else float(Ts),
            "feedforward": ff,
            "settle": float(settle),
            "force": bool(force),
        }
        if self._token:
            req["token"] = self._token
        if on_batch is not None and not callable(on_batch):
            raise TypeError(f"on_batch must be callable, got {on_batch!r}")
        enabled = self.live if live is None else live
        if enabled not in (None, True, False):
            raise ValueError(f"live must be None, True or False, got {live!r}")
        plotting = enabled is not False and _live.in_jupyter_kernel()
        if on_batch is not None or plotting:
            req["stream"] = True
        say = on_status or (lambda msg: None)
        view = _LiveView(
            enabled if plotting else False,
            on_batch,
            "shared rig: move",  # (the page shows no server address)
            self.live_display,
            profile.distance,
        )
        status = "error"
        try:
            with self._connect() as s:
                s.sendall((json.dumps(req) + "\n").encode("utf-8"))
                s.settimeout(max(self.timeout, 4 * HEARTBEAT))
                for msg in self._lines(s):
                    if "samples" in msg:
                        view.batch(msg["samples"])
                    elif "queued" in msg:
                        n = int(msg["queued"])
                        say(f"queued: {n} ahead of you" if n else "queued: next")
                    elif msg.get("running"):
                        s.settimeout(None if self.timeout is None else max(self.timeout, 60.0))
                        say("running on the rig…")
                    elif "error" in msg:
                        raise BrokerError(f"rig broker: {msg['error']}")
                    elif msg.get("done"):
                        break
            rec = self._save(msg, path)
            status = rec.metadata.get("status", "done")
            view.finish(rec)
        finally:
            view.close(status)
        return rec

    def _save(self, msg, path):
        """The Recording of a ``done`` reply, written to ``path`` (see :meth:`run_move`)."""
        keep = path is not False
        if path is None:
            path = recordings_dir() / unique_run_name()
        with tempfile.TemporaryDirectory(prefix="jerklab-run-") as tmp:
            base = Path(path) if keep else Path(tmp) / "run"
            if base.suffix.lower() in (".csv", ".json"):
                base = base.with_suffix("")
            base.parent.mkdir(parents=True, exist_ok=True)
            csv_path = base.with_name(base.name + ".csv")
            json_path = base.with_name(base.name + ".json")
            with open(csv_path, "x" if keep else "w", encoding="ascii") as f:  # never overwrite
                f.write(msg["csv"])
            meta = json.loads(msg["json"])
            meta["csv"] = csv_path.name
            meta["broker"] = self.address
            json_path.write_text(json.dumps(meta, indent=2) + "\n", encoding="utf-8")
            rec = Recording.load(csv_path)
            if not keep:
                rec.csv_path = rec.json_path = None
        return rec


class _LiveView:
    """The client's end of a streamed run: the batches go into an in-memory Recording that
    feeds the run's live plot (made at the first batch, which carries the recording's
    ``meta``) and ``on_batch``; :meth:`finish` completes it from the final recording."""

    def __init__(self, enabled, on_batch, label, display, distance):
        self.enabled = enabled
        self.on_batch = on_batch
        self.label = label
        self.display = display
        self.distance = distance
        self.rec = None
        self.plot = None
        self.batches = 0

    def batch(self, samples):
        """One ``samples`` message; a batch that does not continue the rows is ignored."""
        if self.rec is None:
            meta = samples.get("meta")
            if not isinstance(meta, dict):
                return
            self.rec = Recording(
                {k: meta[k] for k in ("Ts", "counts_per_rad", "volts_per_pwm")}
                | {"kind": meta.get("kind") or "move"}
            )
            if self.enabled is not False:
                self.plot = _live.live_plot(
                    self.rec,
                    meta.get("total") or 1,
                    self.label,
                    self.enabled,
                    display=self.display,
                    position_range=self.distance,
                )
        if samples.get("start") != len(self.rec):
            return
        for row in samples.get("rows", ()):
            self.rec.append(*row)
        self.batches += 1
        if self.plot is not None:
            self.plot.update(len(self.rec))
        if self.on_batch is not None:
            self.on_batch(self.rec)

    def finish(self, final):
        """Add the samples of the final recording that no batch brought."""
        if self.rec is not None:
            for row in final.rows(len(self.rec)):
                self.rec.append(*row)
            if self.plot is not None:
                self.plot.update(len(self.rec))

    def close(self, status):
        if self.plot is not None:
            self.plot.close(status)
            self.plot = None


def main(argv=None):
    """``python -m jerklab.broker``: own a rig, print ``broker://host:port``, serve until stopped."""
    import signal

    ap = argparse.ArgumentParser(
        prog="python -m jerklab.broker", description=__doc__.split("\n")[0]
    )
    ap.add_argument(
        "--rig", default="virtual", help="what jerklab.rig.connect opens (default: virtual)"
    )
    ap.add_argument("--host", default="127.0.0.1", help="address to listen on (default 127.0.0.1)")
    ap.add_argument("--port", type=int, default=0, help="TCP port (default 0: any free port)")
    ap.add_argument(
        "--speed", type=float, default=1.0, help="virtual rig only: times real time (default 1.0)"
    )
    ap.add_argument(
        "--hub-auth",
        action="store_true",
        help="accept only runs whose token the JupyterHub of this service identifies "
        "($JUPYTERHUB_API_URL, $JUPYTERHUB_API_TOKEN, $JUPYTERHUB_SERVICE_NAME)",
    )
    ap.add_argument(
        "--recordings",
        default=None,
        help="keep a copy of every run under RECORDINGS/<identity>/ (default: none)",
    )
    d = Limits()
    ap.add_argument("--max-distance", type=float, default=d.max_distance, help="rad per move")
    ap.add_argument("--max-duration", type=float, default=d.max_duration, help="s per move")
    ap.add_argument("--max-settle", type=float, default=d.max_settle, help="s of settle")
    ap.add_argument(
        "--profile",
        default=os.environ.get("JERKLAB_RIG_PROFILE") or None,
        help="the rig's motor profile: a name or a profile file (default $JERKLAB_RIG_PROFILE)",
    )
    args = ap.parse_args(argv)
    if args.speed <= 0:
        ap.error(f"--speed must be > 0, got {args.speed}")
    for name in ("max_distance", "max_duration", "max_settle"):
        if not getattr(args, name) > 0:
            ap.error(f"--{name.replace('_', '-')} must be > 0, got {getattr(args, name)}")
    authenticate = None
    if args.hub_auth:
        authenticate = HubIdentity()
    rig_port = None if args.rig in ("", "virtual") else args.rig
    extra = {"profile": args.profile} if args.profile else None
    broker = RigBroker(
        rig_port,
        args.host,
        args.port,
        speed=args.speed,
        authenticate=authenticate,
        limits=Limits(args.max_distance, args.max_duration, args.max_settle),
        recordings=args.recordings,
        connect_kwargs=extra,
    )
    print(broker.address, flush=True)
    print(
        f"jerklab rig broker: {broker.rig!r} on {broker.address}; Ctrl-C to stop",
        file=sys.stderr,
        flush=True,
    )
    done = threading.Event()
    signal.signal(signal.SIGTERM, lambda *a: done.set())
    try:
        while not done.wait(0.5):
            if os.getppid() == 1:  # the app that started us is gone
                break
    except KeyboardInterrupt:
        pass
    finally:
        broker.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
