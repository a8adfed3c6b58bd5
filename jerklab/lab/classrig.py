"""A student's handle on the class rig service (:mod:`jerklab.lab.service`): a rig over a socket.

:class:`ClassRig` answers ``step``, ``record_prbs``, ``run_move``, ``set_model`` and
``set_shaper`` like :class:`jerklab.rig.Rig` (each returns the :class:`jerklab.rig.Recording`
the service made, written where the session asks) and ``check(name, answer)``, which the
service scores against the truth it alone holds. Nothing that comes back carries a true
motor parameter: recordings and verdicts only.

The address is ``classrig://HOST:PORT`` or ``classrig+unix:///PATH`` (``$JERKLAB_CLASS_RIG``);
the token is the hub's ``$JUPYTERHUB_API_TOKEN`` inside a hub's server, else
``$JERKLAB_CLASS_TOKEN``. The student is whoever the token names.
"""

from __future__ import annotations

import json
import math
import os
import socket
import tempfile
from pathlib import Path

import numpy as np

from jerklab._validate import as_nonnegative, as_positive, as_real, at_most
from jerklab.lab.checkbase import UnknownCheckError
from jerklab.lab.plain import jsonable
from jerklab.rig import RigError
from jerklab.rig.hostloop import (
    MAX_TS,
    MIN_TS,
    ControlLawError,
    EndsOnExit,
    HostStep,
    _reference_table,
    run_law,
)
from jerklab.rig.profiles import profile_from_dict
from jerklab.rig.recording import Recording

__all__ = [
    "ClassRig",
    "ClassRigError",
    "SCHEMES",
    "service_address",
    "service_token",
    "encode_answer",
]

SCHEMES = ("classrig://", "classrig+unix://")


class ClassRigError(RigError):
    """The class rig service is unreachable, refused the connection or the request."""


def service_address(address=None):
    """The service's address: ``address`` or ``$JERKLAB_CLASS_RIG`` (None when neither)."""
    a = address if address is not None else os.environ.get("JERKLAB_CLASS_RIG") or None
    if a is not None and not (isinstance(a, str) and a.startswith(SCHEMES)):
        raise ValueError(
            f"address must look like 'classrig://HOST:PORT' or 'classrig+unix:///PATH', got {a!r}"
        )
    if a is not None and a.startswith("classrig://"):
        host, _, port = a[len("classrig://") :].rpartition(":")
        if not host or not port.isdigit() or not 0 < int(port) < 65536:
            raise ValueError(
                f"address must be 'classrig://HOST:PORT' with a port 1-65535, got {a!r}"
            )
    return a


def service_token(token=None):
    """The token that names the student: ``token``, else ``$JUPYTERHUB_API_TOKEN`` (a hub's
    server), else ``$JERKLAB_CLASS_TOKEN``; ValueError naming ``token`` when there is none."""
    t = token or os.environ.get("JUPYTERHUB_API_TOKEN") or os.environ.get("JERKLAB_CLASS_TOKEN")
    if not t:
        raise ValueError(
            "token: the class rig service needs your login's token (JUPYTERHUB_API_TOKEN on the "
            "hub, or JERKLAB_CLASS_TOKEN from your instructor)"
        )
    return str(t)


def encode_answer(x):
    """An answer as JSON data for the service: gains with their design, ``...`` as None (no
    answer yet), numpy values as numbers, anything else as :func:`jerklab.lab.plain.jsonable`."""
    if x is Ellipsis:
        return None
    if hasattr(x, "kpd") and hasattr(x, "kdd"):
        out = jsonable(x)
        design = getattr(x, "design", None)
        if isinstance(design, dict):
            out["design"] = {
                str(k): v
                for k, v in jsonable(design).items()
                if isinstance(v, (int, float, str, bool)) or v is None
            }
        loop = getattr(x, "loop", None)
        if isinstance(loop, str):
            out["loop"] = loop
        return out
    if isinstance(x, dict):
        return {str(k): encode_answer(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [encode_answer(v) for v in x]
    if isinstance(x, (np.bool_,)):
        return bool(x)
    return jsonable(x)


#: why :meth:`ClassRig.host_loop` refuses
class ClassRig:
    """A connection to the class rig service for one lab (see the module's text).

    Parameters
    ----------
    address : str
        ``classrig://HOST:PORT`` or ``classrig+unix:///PATH``.
    lab : int
        The lab (the service gives lab 4 the flexible load).
    token : str, optional
        See :func:`service_token`.
    student : str, optional
        The ID the student typed, if any: the service refuses it unless the token names the
        same student.
    timeout : float
        Seconds to wait for each answer.
    """

    is_virtual = False
    queues_runs = False

    def __init__(self, address, lab, token=None, student=None, timeout=120.0):
        self.port = service_address(address)
        if self.port is None:
            raise ValueError("address: no class rig service given (JERKLAB_CLASS_RIG)")
        self.timeout = at_most("timeout", as_positive("timeout", timeout), 3600.0, "s")
        self._sock = self._connect()
        self._buf = b""
        hello = {"op": "hello", "token": service_token(token), "lab": lab}
        if student is not None:
            hello["student"] = student
        info = self._ask(hello)
        self.student = info["student"]
        self.lab = info["lab"]
        self.counts_per_rev = int(info["counts_per_rev"])
        self.supply_voltage = float(info["supply_voltage"])
        self.name = str(info.get("name", "classrig"))
        self.firmware_version = str(info.get("firmware_version", ""))
        self.model = None
        #: the service's motor profile (a jerklab.rig.MotorProfile, None: the paper's motors)
        #: and the lab's numbers on it
        prof = info.get("profile")
        self.profile = None if prof is None else profile_from_dict(prof)
        self.spec = info.get("spec")

    def _connect(self):
        try:
            if self.port.startswith("classrig+unix://"):
                s = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
                s.settimeout(self.timeout)
                s.connect(self.port[len("classrig+unix://") :])
            else:
                host, _, port = self.port[len("classrig://") :].rpartition(":")
                s = socket.create_connection((host, int(port)), timeout=self.timeout)
        except (OSError, ValueError) as exc:
            raise ClassRigError(
                f"the class rig service at {self.port} cannot be reached ({exc}); "
                "ask your instructor whether it runs"
            ) from None
        return s

    def _ask(self, req):
        self._send(req)
        return self._read()

    def _send(self, req):
        try:
            self._sock.sendall((json.dumps(req) + "\n").encode("utf-8"))
        except OSError as exc:
            raise ClassRigError(f"the class rig service at {self.port}: {exc}") from None

    def _read(self):
        try:
            while b"\n" not in self._buf:
                data = self._sock.recv(1 << 16)
                if not data:
                    raise ClassRigError(f"the class rig service at {self.port} closed the link")
                self._buf += data
        except OSError as exc:
            raise ClassRigError(f"the class rig service at {self.port}: {exc}") from None
        line, self._buf = self._buf.split(b"\n", 1)
        msg = json.loads(line.decode("utf-8"))
        if "error" in msg:
            kind = msg.get("type")
            if kind in ("ValueError", "TypeError"):
                raise ValueError(msg["error"])
            if kind in ("KeyError", "UnknownCheckError"):
                raise UnknownCheckError(msg["error"])
            if kind in ("AuthError", "PermissionError"):
                raise PermissionError(msg["error"])
            raise ClassRigError(msg["error"])
        return msg

    def _recording(self, msg, path):
        with tempfile.TemporaryDirectory(prefix="jerklab-classrig-") as tmp:
            csv_path = Path(tmp) / "run.csv"
            csv_path.write_text(msg["csv"], encoding="ascii")
            csv_path.with_suffix(".json").write_text(msg["json"], encoding="utf-8")
            rec = Recording.load(csv_path)
            if path is None or path is False:
                rec.csv_path = rec.json_path = None
                return rec
            return Recording.load(rec.save(path))

    def step(self, voltage, seconds, Ts=0.005, *, rest=0.05, path=None, progress=None, name=None):
        """An open-loop step on your motor (see :meth:`jerklab.rig.Rig.step`)."""
        req = {
            "op": "step",
            "name": name or _name_of(path, "step"),
            "voltage": _volts("voltage", voltage),
            "seconds": as_positive("seconds", seconds),
            "Ts": as_positive("Ts", Ts),
            "rest": as_nonnegative("rest", rest),
        }
        return self._recording(self._ask(req), path)

    def record_prbs(
        self,
        amplitude,
        seconds=None,
        Ts=0.005,
        *,
        order=8,
        seed=1,
        hold=1,
        offset=0.0,
        rest=0.05,
        path=None,
        progress=None,
        name=None,
    ):
        """A PRBS record on your motor (see :meth:`jerklab.rig.Rig.record_prbs`)."""
        req = {
            "op": "record_prbs",
            "name": name or _name_of(path, "prbs"),
            "amplitude": float(amplitude),
            "seconds": None if seconds is None else float(seconds),
            "Ts": float(Ts),
            "order": int(order),
            "seed": int(seed),
            "hold": int(hold),
            "offset": float(offset),
            "rest": float(rest),
        }
        return self._recording(self._ask(req), path)

    def run_move(self, profile, gains, Ts=None, *, path=None, progress=None, name=None, **run):
        """A planned move on your motor (see :meth:`jerklab.rig.Rig.run_move`; ``run`` may
        hold ``settle``, ``force`` and ``feedforward``; in lab 5 also ``max_voltage``, ``max_error``
        (at most the lab's), ``runaway_time`` and ``saturation_time``)."""
        if not hasattr(gains, "kdd"):
            raise ValueError("gains must be DiscreteGains (discretize continuous gains first)")
        prof = {
            "kind": profile.kind,
            "distance": float(profile.distance),
            "max_jerk": None if profile.max_jerk is None else float(profile.max_jerk),
            "max_accel": float(profile.max_accel),
            "max_velocity": float(profile.max_velocity),
        }
        req = {
            "op": "run_move",
            "name": name or _name_of(path, f"move_{profile.kind}"),
            "profile": prof,
            "gains": encode_answer(gains),
            "Ts": None if Ts is None else float(Ts),
            "run": run,
        }
        return self._recording(self._ask(req), path)

    def set_model(self, K, tau):
        """The feedforward model of the following moves (your identified K and τ)."""
        self._ask({"op": "set_model", "K": float(K), "tau": float(tau)})
        self.model = (float(K), float(tau))

    def set_shaper(self, shaper, Ts=0.005):
        """An input shaper for the following moves (None: off); see
        :meth:`jerklab.rig.Rig.set_shaper`."""
        taps = None
        if shaper is not None:
            taps = shaper.fir(Ts) if hasattr(shaper, "fir") else shaper
            taps = [float(t) for t in np.asarray(taps, dtype=float).ravel()]
            if not all(math.isfinite(t) for t in taps):
                raise ValueError("shaper: its taps must be finite numbers")
        self._ask({"op": "set_shaper", "taps": taps, "Ts": float(Ts)})

    def realtime(self, Ts, duration, reference=None, *, path=None, name=None, **options):
        """Host-in-the-loop on your motor (lab 5): iterate the ticks, ``step.apply(v)`` each;
        as :meth:`jerklab.rig.Rig.realtime`. The service runs the motor and sends each
        tick's sample; your kernel answers with the voltage for the next tick. ``options``:
        ``max_misses``, ``max_voltage`` and ``max_error`` (at most the lab's); the loop's
        ``recording`` is the service's signed one, its status final on every exit path."""
        return _ClassRealtime(self, Ts, duration, reference, path, name, options)

    def host_loop(self, control, Ts, duration, reference=None, **options):
        """:meth:`jerklab.rig.Rig.host_loop` on your motor: the callable law
        ``control(t, position, reference) -> volts`` over :meth:`realtime`; returns the
        recording, and raises ``jerklab.rig.hostloop.ControlLawError`` (the motor stopped, the
        tick named) when the law raises or returns a non-finite voltage."""
        return run_law(self.realtime(Ts, duration, reference, **options), control)

    def check(self, name, answer):
        """``(passed, message)`` of check ``name`` on ``answer``, scored by the service."""
        msg = self._ask({"op": "check", "name": name, "answer": encode_answer(answer)})
        return bool(msg["passed"]), str(msg["message"])

    def close(self):
        try:
            self._sock.close()
        except OSError:
            pass

    def __repr__(self):
        return f"ClassRig({self.port!r}, student={self.student!r}, lab={self.lab})"


def _volts(name, value):
    """A voltage for the service: a real number, one below float32's range sent as 0 V."""
    v = as_real(name, value)
    return 0.0 if abs(v) < float(np.finfo(np.float32).tiny) else v


def _name_of(path, default):
    if path is None or path is False:
        return default
    return Path(path).name.removesuffix(".csv").removesuffix(".json")


class _ClassRealtime(EndsOnExit):
    """The iterable of :meth:`ClassRig.realtime`: the service's ticks as
    :class:`jerklab.rig.hostloop.HostStep` objects; :attr:`recording` once it has ended."""

    def __init__(self, rig, Ts, duration, reference, path, name, options):
        Ts = as_positive("Ts", Ts)
        if not MIN_TS - 1e-12 <= Ts <= MAX_TS + 1e-12:
            raise ValueError(
                f"Ts must be between {MIN_TS * 1e3:g} ms and {MAX_TS * 1e3:g} ms in the "
                f"host-in-the-loop mode, got {Ts!r} s"
            )
        duration = as_positive("duration", duration)
        unknown = set(options) - {"max_misses", "max_voltage", "max_error", "live", "progress"}
        if unknown:
            raise ValueError(
                f"options: {sorted(unknown)} not known on the class rig "
                "(max_misses, max_voltage, max_error)"
            )
        mv = options.get("max_voltage")
        self.max_voltage = rig.supply_voltage if mv is None else as_positive("max_voltage", mv)
        if self.max_voltage > rig.supply_voltage:
            raise ValueError(f"max_voltage must be <= the supply {rig.supply_voltage} V, got {mv}")
        n = int(math.ceil(duration / Ts - 1e-9)) + 1
        table = _reference_table(reference, n, Ts)
        opts = {k: options.get(k) for k in ("max_misses", "max_voltage", "max_error")}
        self._req = {
            "op": "host_loop",
            "name": name or _name_of(path, "host"),
            "Ts": float(Ts),
            "duration": float(duration),
            "reference": table,
            "options": {k: float(v) for k, v in opts.items() if v is not None},
        }
        self._rig, self._path = rig, path
        self._used = False
        self._aborted = None
        self._error = None  # (status, tick) of a law that raised (run_law)
        self.recording = None
        self.misses = 0

    def _refuse(self, step, what):
        """A non-finite voltage (:meth:`HostStep.apply`): stop the run, raise naming the tick."""
        status = (
            f"error: {what} at tick {step.index} (t={step.t:.3f} s); refused, the motor is stopped"
        )
        self.abort(status)
        raise ControlLawError(status[len("error: ") :], tick=step.index, recording=self.recording)

    def abort(self, status="stopped"):
        """Stop the run now with ``status``; the service's final recording follows."""
        if self.recording is not None or self._aborted is not None or not self._used:
            return
        self._aborted = status
        self._rig._send({"abort": status})
        self._final(self._rig._read())

    def _final(self, msg):
        self.recording = self._rig._recording(msg, self._path)
        self.misses = int(self.recording.metadata.get("hostloop", {}).get("misses", 0))

    def _run(self):
        rig = self._rig
        rig._send(self._req)
        while True:
            msg = rig._read()
            if "tick" not in msg:
                self._final(msg)
                return
            ref = msg.get("reference")
            step = HostStep(
                self,
                int(msg["tick"]),
                float(msg["t"]),
                float(msg["position"]),
                math.nan if ref is None else float(ref),
                float(msg["voltage"]),
                bool(msg.get("missed")),
            )
            try:
                yield step
            except GeneratorExit:
                self.abort("stopped: the loop ended before the run")
                raise
            if self._aborted is not None:
                return
            rig._send({"voltage": step._volts})
