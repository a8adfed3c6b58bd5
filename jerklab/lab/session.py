"""A lab session: the student's rig, the recordings of the lab, the answers and their checks."""

from __future__ import annotations

import math
import os
import re
from pathlib import Path

import numpy as np

from jerklab import paper
from jerklab.lab.motors import _truth, normalize_student

__all__ = ["LabSession", "start", "panel_gains", "CheckResult", "LABS", "SPEC", "MOVE"]

#: lab number -> short name (also the worksheet file stem: notebooks/labs/labN_<name>.ipynb)
LABS = {1: "identify", 2: "poles", 3: "move", 4: "ringing"}
#: labs whose rig carries the flexible load (``connect(plant="flexible")``): the student's motor
#: with a hidden load mode
FLEXIBLE_LABS = (4,)

#: The move of labs 2 and 3 (rad, rad/s^3, rad/s^2, rad/s): three revolutions and a bit.
MOVE = {"distance": 20.0, "max_jerk": 2.0e4, "max_accel": 600.0, "max_velocity": 80.0}

#: The spec of lab 2, feasible for every motor of jerklab.lab.motors.RANGES (tests/test_labs.py).
SPEC = {
    "max_error": 0.40,  # rad, |r - y| during the move
    "overshoot_pct": 1.0,  # % of the distance, after the move
    "settle_band": 0.05,  # rad
    "settling_time": 0.25,  # s after the end of the move, into the band for good
    "max_voltage": 12.0,
}  # V, and no saturated sample


class CheckResult:
    """Outcome of one check: ``ok``, the ``message`` shown (hint or explanation), ``name``."""

    def __init__(self, name, ok, message):
        self.name, self.ok, self.message = name, bool(ok), str(message)

    def __bool__(self):
        return self.ok

    def __repr__(self):
        return f"{'✔' if self.ok else '✘'} {self.name}: {self.message}"

    def _repr_markdown_(self):
        colour = "green" if self.ok else "#b00"
        mark = "✔ right" if self.ok else "✘ not yet"
        return f"<span style='color:{colour}'>**{mark} — {self.name}**</span>: {self.message}"


def panel_gains(panel):
    """The gains chosen in a tuning panel: ``panel.gains`` where the panel has it, else
    ``panel.result.gains`` (``jerklab.widgets.pole_placement_panel``)."""
    g = getattr(panel, "gains", None)
    if g is None:
        g = panel.result.gains
    return g


def _port_from_env(port):
    """While grading, every notebook runs on the virtual rig of its student."""
    if os.environ.get("JERKLAB_LAB_GRADING"):
        return None
    return port


class LabSession:
    """What a worksheet works with: ``rig``, ``student``, ``folder``, ``recordings``, ``answers``.

    Make one with :func:`start`. Runs go through :meth:`step` and :meth:`run_move` so that
    every recording lands in the lab's folder (handed in by :meth:`submit`).
    """

    def __init__(self, lab, student, port=None, folder=None, speed=None, key=None, progress=False):
        if lab not in LABS:
            raise ValueError(f"lab must be one of {sorted(LABS)}, got {lab!r}")
        self.lab = lab
        self.student = normalize_student(student)
        self.port = _port_from_env(port)
        base = (
            Path(folder)
            if folder is not None
            else Path(os.environ.get("JERKLAB_LAB_WORK", "lab-work"))
        )
        self.folder = base / self.student / f"lab{lab}"
        self.folder.mkdir(parents=True, exist_ok=True)
        from jerklab.rig import connect

        opts = {"progress": progress, "recordings": self.folder}
        if speed is not None:
            opts["speed"] = speed
        self.plant = "flexible" if lab in FLEXIBLE_LABS else "rigid"
        if self.plant == "flexible" and self.port not in (None, "virtual", "", "simavr"):
            print(
                f"⚠ lab {lab} needs the flexible load: on a real Uno, mount the load on its shaft coupling"
            )
        elif self.plant == "flexible":
            opts["plant"] = "flexible"
        if key is not None:
            from jerklab.lab.motors import connect_student

            self.rig = connect_student(self.student, self.port, key=key, **opts)
        else:
            self.rig = connect(self.port, student=self.student, **opts)
        self._key = key
        self.recordings = {}
        self.answers = {}
        self.results = {}
        self.gains = None

    # ---------------------------------------------------------------- the rig
    @property
    def simulated(self) -> bool:
        """True when the plant is the student's hidden motor (virtual rig or simavr)."""
        return getattr(self.rig, "_hidden_motor", None) is not None

    def _truth(self):
        m = getattr(self.rig, "_hidden_motor", None)
        return None if m is None else _truth(m)

    def _path(self, name):
        if not re.match(r"^[A-Za-z0-9_.+-]{1,60}$", name):
            raise ValueError(f"name must be 1-60 letters, digits or _.+-, got {name!r}")
        return self.folder / name

    def step(self, voltage, seconds, name=None, Ts=paper.TS, **kwargs):
        """``rig.step(voltage, seconds, Ts)`` saved as ``name`` (default ``step_<V>V``)."""
        name = name or f"step_{voltage:+g}V".replace("+", "p").replace("-", "m").replace(".", "_")
        rec = self.rig.step(voltage, seconds, Ts=Ts, path=self._path(name), **kwargs)
        self.recordings[name] = rec
        return rec

    def record_prbs(self, amplitude, name="prbs", Ts=paper.TS, **kwargs):
        """``rig.record_prbs(amplitude, Ts=Ts, **kwargs)`` (the on-board PRBS) saved as ``name``."""
        rec = self.rig.record_prbs(amplitude, Ts=Ts, path=self._path(name), **kwargs)
        self.recordings[name] = rec
        return rec

    def set_shaper(self, shaper, Ts=paper.TS):
        """``rig.set_shaper(shaper, Ts)``: the input shaper of the following moves (None: off)."""
        return self.rig.set_shaper(shaper, Ts)

    def run_move(self, profile, gains, Ts=None, name=None, **kwargs):
        """``rig.run_move(profile, gains, Ts)`` saved as ``name`` (default ``move_<kind>``).

        A planner the device does not have (the firmware runs only the published sine-jerk)
        returns None with a message instead of stopping the worksheet.
        """
        from jerklab.rig import RigError

        Ts = getattr(gains, "Ts", 0.005) if Ts is None else Ts
        name = name or f"move_{profile.kind}"
        try:
            rec = self.rig.run_move(profile, gains, Ts, path=self._path(name), **kwargs)
        except RigError as exc:
            if "planner" not in str(exc):
                raise
            print(
                f"⚠ {self.rig.port}: this device has no {profile.kind!r} planner (the firmware runs "
                f"only the published sine-jerk today); the {profile.kind} move is skipped here and "
                f"its cells use the simulation only."
            )
            return None
        self.recordings[name] = rec
        self.gains = gains
        return rec

    def set_model(self, K, tau):
        """The feedforward model of the rig (your identified K and τ)."""
        self.rig.set_model(K, tau)

    # ---------------------------------------------------------------- checks
    def verify(self, name, answer, **context):
        """Run check ``name`` on ``answer`` silently; return a :class:`CheckResult`."""
        from jerklab.lab.checks import run_check

        self.answers[name] = _jsonable(answer)
        try:
            res = run_check(self, name, answer, **context)
        except _Missing as exc:
            res = CheckResult(name, False, str(exc))
        except (TypeError, ValueError, KeyError, AttributeError, IndexError) as exc:
            res = CheckResult(
                name,
                False,
                f"could not read your answer ({type(exc).__name__}: {exc}). "
                "Replace the `...` with a value of the type the task asks for.",
            )
        self.results[name] = res
        return res

    def check(self, name, answer, **context):
        """Run check ``name`` and show right/wrong with a hint or the reason (the result is in
        ``self.results[name]``; :meth:`verify` returns it silently)."""
        res = self.verify(name, answer, **context)
        try:
            from IPython import get_ipython
            from IPython.display import display

            if get_ipython() is not None:
                display(res)
                return
        except ImportError:
            pass
        print(repr(res))

    def summary(self):
        """One line per check run so far."""
        for r in self.results.values():
            print(repr(r))

    # ---------------------------------------------------------------- hand-in
    def submit(self, notebook=None, out=None):
        """Write the hand-in zip (notebook, recordings, gains, answers, student ID, manifest)."""
        from jerklab.lab.handin import write_handin

        return write_handin(self, notebook=notebook, out=out)

    def close(self):
        self.rig.close()

    def __repr__(self):
        return (
            f"LabSession(lab={self.lab}, student={self.student!r}, rig={self.rig.port!r}, "
            f"recordings={len(self.recordings)})"
        )


class _Missing(Exception):
    """A check needs a recording or an earlier answer that is not there yet."""


def _jsonable(x):
    if isinstance(x, (np.floating, np.integer)):
        return x.item()
    if isinstance(x, np.ndarray):
        return x.tolist()
    if isinstance(x, dict):
        return {str(k): _jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_jsonable(v) for v in x]
    if isinstance(x, float) and not math.isfinite(x):
        return repr(x)
    if isinstance(x, (str, int, float, bool)) or x is None:
        return x
    if hasattr(x, "kpd"):
        return {"kpd": x.kpd, "kid": x.kid, "kdd": x.kdd, "Ts": x.Ts, "gamma": x.gamma}
    return repr(x)


def start(lab, student, port=None, **options):
    """Start lab ``lab`` (1 to 4; lab 4's rig has the flexible load) for ``student`` on ``port`` (None: the virtual rig with
    the student's hidden motor; ``"simavr"``; a serial port of a real Uno)."""
    s = LabSession(lab, student, port, **options)
    if s.port in (None, "virtual", ""):
        where = "virtual rig (your hidden motor)"
    elif s.port == "simavr":
        where = f"firmware on a simulated Uno (your hidden motor; {s.rig.port})"
    else:
        where = f"rig at {s.rig.port}"
    print(
        f"Lab {lab} ({LABS[lab]}) for student {s.student} on the {where}; "
        f"encoder {s.rig.counts_per_rev} counts/rev, supply {s.rig.supply_voltage:g} V; "
        f"recordings in {s.folder}"
    )
    return s
