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
_NO_HOST_LOOP = (
    "the class rig service has no host-in-the-loop mode: run lab 5's own law on the virtual rig "
    "(RIG = None with no JERKLAB_CLASS_RIG set), on \"simavr\" or on your own board's serial port"
)


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
        try:
            self._sock.sendall((json.dumps(req) + "\n").encode("utf-8"))
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
        hold ``settle``, ``force`` and ``feedforward``)."""
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

    def host_loop(self, control, Ts, duration, reference=None, **options):
        """Not on the class rig: the service runs the moves on its side and has no
        host-in-the-loop mode (your law would have to answer every tick over the class's
        network). Raises :class:`ClassRigError` saying where lab 5's own law runs."""
        raise ClassRigError(_NO_HOST_LOOP)

    def realtime(self, Ts, duration, reference=None, **options):
        """Not on the class rig (see :meth:`host_loop`): raises :class:`ClassRigError`."""
        raise ClassRigError(_NO_HOST_LOOP)

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
