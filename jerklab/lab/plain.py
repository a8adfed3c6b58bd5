"""Plain data of a student's work: what a check is given and what a hand-in holds.

* :func:`jsonable` turns an answer (numpy numbers and arrays, tuples, gains) into JSON data.
* :class:`Run` is a recording reduced to its arrays (the series names of
  :mod:`jerklab._vocab`), :class:`Evidence` everything a check may look at besides the answer:
  the runs by name, the answers given so far and the rig's counts per revolution. Both convert
  to and from JSON data (:meth:`Evidence.to_dict`), so they can cross a process boundary.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from jerklab._validate import as_finite_array, as_positive

__all__ = ["jsonable", "Run", "Evidence"]


def jsonable(x):
    """``x`` as JSON data: numpy scalars and arrays as numbers and lists, a non-finite float as
    its repr, gains as ``{"kpd", "kid", "kdd", "Ts", "gamma"}``, anything else as its repr."""
    if isinstance(x, (np.floating, np.integer)):
        return x.item()
    if isinstance(x, np.ndarray):
        return x.tolist()
    if isinstance(x, dict):
        return {str(k): jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [jsonable(v) for v in x]
    if isinstance(x, float) and not math.isfinite(x):
        return repr(x)
    if isinstance(x, (str, int, float, bool)) or x is None:
        return x
    if hasattr(x, "kpd"):
        return {"kpd": x.kpd, "kid": x.kid, "kdd": x.kdd, "Ts": x.Ts, "gamma": x.gamma}
    return repr(x)


_SERIES = ("time", "reference", "position", "voltage", "flags")


@dataclass(frozen=True)
class Run:
    """One recording as arrays: ``time`` (s), ``reference`` (rad; V for a PRBS), ``position``
    (rad), ``voltage`` (V, applied), ``flags`` (TELEMETRY's: bit 0 saturated, bit 1 settling),
    its sample period ``Ts`` (s) and ``kind`` (``"step"``, ``"move"``, ``"prbs"``)."""

    time: np.ndarray
    reference: np.ndarray
    position: np.ndarray
    voltage: np.ndarray
    flags: np.ndarray
    Ts: float
    kind: str = ""

    def __post_init__(self):
        n = None
        for name in _SERIES:
            a = as_finite_array(name, getattr(self, name), ndim=1)
            if name == "flags":
                a = a.astype(np.int64)
            a.setflags(write=False)
            object.__setattr__(self, name, a)
            if n is not None and a.size != n:
                raise ValueError(f"{name} has {a.size} samples, time has {n}")
            n = a.size
        object.__setattr__(self, "Ts", as_positive("Ts", self.Ts))

    @property
    def saturated(self) -> np.ndarray:
        """Samples at the output clamp (flag bit 0)."""
        return (self.flags & 1).astype(bool)

    def __len__(self):
        return self.time.size

    @classmethod
    def from_recording(cls, rec) -> Run:
        """The arrays of a :class:`jerklab.rig.Recording`."""
        return cls(
            rec.time,
            rec.reference,
            rec.position,
            rec.voltage,
            rec.flags,
            rec.Ts,
            str(rec.metadata.get("kind", "")),
        )

    def to_dict(self) -> dict:
        out = {name: getattr(self, name).tolist() for name in _SERIES}
        out.update(Ts=self.Ts, kind=self.kind)
        return out

    @classmethod
    def from_dict(cls, d) -> Run:
        return cls(**{k: d[k] for k in (*_SERIES, "Ts")}, kind=str(d.get("kind", "")))


@dataclass(frozen=True)
class Evidence:
    """Everything a check may look at besides the answer.

    Attributes
    ----------
    runs : dict
        Recording name (``"step_p6V"``, ``"prbs"``, ``"move_sine_jerk"``, ...) -> :class:`Run`.
    answers : dict
        Check name -> the answer given to it so far (:func:`jsonable` data), for the checks
        that build on an earlier one (lab 2's ``design`` on ``model``).
    counts_per_rev : int or None
        The rig's encoder counts per revolution.
    profile : str or None
        The rig's motor profile (a built-in name or a profile file, ``jerklab.rig.profiles``)
        the lab's moves and specs are made for (``jerklab.lab.specs.lab_spec``); None: the
        paper's class motors.
    """

    runs: dict = field(default_factory=dict)
    answers: dict = field(default_factory=dict)
    counts_per_rev: int | None = None
    profile: str | None = None

    def to_dict(self) -> dict:
        return {
            "runs": {k: r.to_dict() for k, r in self.runs.items()},
            "answers": jsonable(self.answers),
            "counts_per_rev": self.counts_per_rev,
            "profile": self.profile,
        }

    @classmethod
    def from_dict(cls, d) -> Evidence:
        return cls(
            runs={k: Run.from_dict(r) for k, r in d.get("runs", {}).items()},
            answers=dict(d.get("answers", {})),
            counts_per_rev=d.get("counts_per_rev"),
            profile=d.get("profile"),
        )
