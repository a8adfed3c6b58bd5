"""Recordings of rig runs: time series + metadata, written to disk as samples arrive.

A :class:`Recording` is a CSV file (one row per telemetry sample, flushed as the
samples come in) plus a JSON sidecar (gains, limits, plant, firmware version,
profile, status).  The sidecar is written when the run starts (``"status":
"recording"``) and rewritten when it ends (``"complete"``, ``"timeout"``,
``"disconnected"``, ``"stopped"``, ...), so a pulled cable or a crash leaves
every sample received so far on disk, described.

SI units in the arrays: s, rad, V.  ``counts`` and ``pwm`` keep the raw integers.
"""
from __future__ import annotations

import csv
import datetime as _dt
import json
import math
import os
from pathlib import Path

import numpy as np

__all__ = ["Recording", "recordings_dir", "compare", "plot_comparison"]

COLUMNS = ("index", "time", "reference", "position", "counts", "control", "pwm", "flags")


def recordings_dir() -> Path:
    """Where recordings go: ``$JERKLAB_RECORDINGS`` or ``./recordings``."""
    return Path(os.environ.get("JERKLAB_RECORDINGS") or "recordings")


def _json_default(o):
    if isinstance(o, (np.integer,)):
        return int(o)
    if isinstance(o, (np.floating,)):
        return float(o)
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, Path):
        return str(o)
    return repr(o)


def _clean(o):
    """JSON has no inf/nan: write them as strings."""
    if isinstance(o, float) and not math.isfinite(o):
        return str(o)
    if isinstance(o, dict):
        return {str(k): _clean(v) for k, v in o.items()}
    if isinstance(o, (list, tuple)):
        return [_clean(v) for v in o]
    return o


def _paths(path) -> tuple[Path, Path]:
    p = Path(path)
    if p.suffix.lower() in (".csv", ".json"):
        p = p.with_suffix("")
    return p.with_name(p.name + ".csv"), p.with_name(p.name + ".json")


class Recording:
    """A run's time series and metadata, optionally streamed to ``path`` (.csv + .json).

    Attributes (numpy arrays, one entry per received sample)
    ----------
    time : s, ``index * Ts``
    reference : rad, the position reference the device used (0 for an open-loop step)
    position : rad, ``counts / counts_per_rad``
    control : V, ``pwm / pwm_max * supply_voltage``
    counts, pwm, index, flags : the raw telemetry integers
    metadata : dict (JSON sidecar): kind, Ts, gains, limits, plant, device, profile, status, ...

    Examples
    --------
    >>> rec = Recording({"kind": "demo", "Ts": 0.005, "counts_per_rad": 448 / (2 * math.pi),
    ...                  "volts_per_pwm": 12 / 1023})
    >>> rec.append(0, 0.0, 0, 0); rec.append(1, 0.01, 1, 1023)
    >>> rec.time.tolist(), rec.control.tolist()
    ([0.0, 0.005], [0.0, 12.0])
    """

    def __init__(self, metadata: dict, path=None):
        self.metadata = dict(metadata)
        for key in ("Ts", "counts_per_rad", "volts_per_pwm"):
            if key not in self.metadata:
                raise ValueError(f"metadata must contain {key!r}")
        self._Ts = float(self.metadata["Ts"])
        self._cpr = float(self.metadata["counts_per_rad"])
        self._vpp = float(self.metadata["volts_per_pwm"])
        self._rows: list[tuple] = []
        self._file = None
        self._writer = None
        self.csv_path = self.json_path = None
        self.metadata.setdefault("status", "recording")
        self.metadata.setdefault("created", _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"))
        if path is not None:
            self._open(path)

    # -------------------------------------------------------------- streaming
    def _open(self, path):
        self.csv_path, self.json_path = _paths(path)
        self.csv_path.parent.mkdir(parents=True, exist_ok=True)
        self.metadata["csv"] = self.csv_path.name
        self._file = open(self.csv_path, "w", newline="", encoding="ascii")
        self._writer = csv.writer(self._file)
        self._writer.writerow(COLUMNS)
        self._file.flush()
        self._write_json()

    def _write_json(self):
        if self.json_path is None:
            return
        tmp = self.json_path.with_name(self.json_path.name + ".tmp")
        with open(tmp, "w", encoding="utf-8") as f:
            json.dump(_clean(self.metadata), f, indent=2, default=_json_default)
            f.write("\n")
        os.replace(tmp, self.json_path)

    def append(self, index: int, reference: float, counts: int, pwm: int, flags: int = 0) -> None:
        """Add one telemetry sample (written to the CSV at once; call :meth:`flush` to push it)."""
        row = (int(index), float(reference), int(counts), int(pwm), int(flags))
        self._rows.append(row)
        if self._writer is not None:
            i, r, c, p, fl = row
            self._writer.writerow((i, repr(i * self._Ts), repr(r), repr(c / self._cpr), c,
                                   repr(p * self._vpp), p, fl))

    def flush(self) -> None:
        """Push written rows to the operating system (done after every received chunk)."""
        if self._file is not None:
            self._file.flush()

    def finish(self, status: str = "complete", **info) -> None:
        """Close the CSV and rewrite the sidecar with the final ``status`` and ``info``."""
        self.metadata["status"] = status
        self.metadata["n_samples"] = len(self._rows)
        self.metadata.update(info)
        if self._file is not None:
            self._file.flush()
            self._file.close()
            self._file = None
            self._writer = None
        self._write_json()

    # -------------------------------------------------------------- arrays
    def __len__(self) -> int:
        return len(self._rows)

    def _col(self, j, dtype=float):
        if not self._rows:
            return np.zeros(0, dtype=dtype)
        return np.array([r[j] for r in self._rows], dtype=dtype)

    @property
    def index(self):
        return self._col(0, np.int64)

    @property
    def time(self):
        return self.index * self._Ts

    @property
    def reference(self):
        return self._col(1)

    @property
    def counts(self):
        return self._col(2, np.int64)

    @property
    def position(self):
        return self.counts / self._cpr

    @property
    def pwm(self):
        return self._col(3, np.int64)

    @property
    def control(self):
        return self.pwm * self._vpp

    @property
    def flags(self):
        return self._col(4, np.int64)

    @property
    def saturated(self):
        return (self.flags & 1).astype(bool)

    @property
    def Ts(self) -> float:
        return self._Ts

    @property
    def error(self):
        """reference − position (rad)."""
        return self.reference - self.position

    # -------------------------------------------------------------- files
    def save(self, path) -> Path:
        """Write the whole recording to ``path`` (.csv + .json sidecar); returns the CSV path."""
        csv_path, _ = _paths(path)
        rec = Recording(self.metadata, csv_path)
        for row in self._rows:
            rec.append(*row)
        rec.finish(self.metadata.get("status", "complete"))
        return csv_path

    @classmethod
    def load(cls, path) -> "Recording":
        """Read a recording written by a run or by :meth:`save` (either file of the pair)."""
        csv_path, json_path = _paths(path)
        if not csv_path.exists():
            raise FileNotFoundError(f"no recording at {csv_path}")
        meta = {}
        if json_path.exists():
            try:
                with open(json_path, encoding="utf-8") as f:
                    meta = json.load(f)
            except (UnicodeDecodeError, json.JSONDecodeError) as exc:
                raise ValueError(f"{json_path} is not a valid JSON sidecar ({exc}); the samples are "
                                 f"still in {csv_path}") from None
        rows = []
        with open(csv_path, newline="", encoding="ascii") as f:
            reader = csv.reader(f)
            header = next(reader, None)
            if header is None or tuple(header) != COLUMNS:
                raise ValueError(f"{csv_path} is not a jerklab recording (header {header!r})")
            for line in reader:
                if len(line) != len(COLUMNS):
                    break                        # a row cut by a crash: keep what is whole
                rows.append((int(line[0]), float(line[2]), int(line[4]), int(line[6]), int(line[7])))
        if "Ts" not in meta and len(rows) > 1:
            raise ValueError(f"{json_path} missing: cannot recover Ts")
        rec = cls(meta)
        rec._rows = rows
        rec.csv_path, rec.json_path = csv_path, json_path
        return rec

    def plot(self, ax=None):
        """Reference and measured position (rad) and control (V) against time (s)."""
        import matplotlib.pyplot as plt

        if ax is None:
            fig, ax = plt.subplots(2, 1, sharex=True, figsize=(7, 5))
        else:
            fig = ax[0].figure
        t = self.time
        if self.metadata.get("kind") == "move":
            ax[0].plot(t, self.reference, label="reference")
        ax[0].plot(t, self.position, label="measured")
        ax[0].set_ylabel("position (rad)")
        ax[0].legend()
        ax[1].step(t, self.control, where="post")
        ax[1].set_ylabel("control (V)")
        ax[1].set_xlabel("time (s)")
        ax[0].set_title(f"rig recording: {self.metadata.get('kind', '')} "
                        f"({self.metadata.get('status', '')})")
        return fig

    def __repr__(self):
        where = f", path={str(self.csv_path)!r}" if self.csv_path else ""
        return (f"Recording(kind={self.metadata.get('kind')!r}, samples={len(self)}, "
                f"status={self.metadata.get('status')!r}{where})")


def compare(rec: Recording, sim) -> dict:
    """Measured vs simulated run on the recording's samples (rad, V).

    ``sim`` is a :class:`jerklab.sim.SimResult` sampled at the same ``Ts`` from t = 0.
    Returns the number of common samples, the largest and RMS difference of the measured
    angles, the largest tracking error of each, and the largest control difference.
    """
    n = min(len(rec), len(sim.t))
    idx = rec.index[rec.index < len(sim.t)][:n]
    meas = rec.position[:len(idx)]
    sim_meas = np.asarray(sim.measured)[idx]
    d = meas - sim_meas
    return {
        "samples": int(len(idx)),
        "max_abs_position_diff": float(np.max(np.abs(d))) if len(d) else float("nan"),
        "rms_position_diff": float(np.sqrt(np.mean(d ** 2))) if len(d) else float("nan"),
        "max_abs_error_measured": float(np.max(np.abs(rec.reference[:len(idx)] - meas))),
        "max_abs_error_simulated": float(np.max(np.abs(np.asarray(sim.reference)[idx] - sim_meas))),
        "max_abs_control_diff": float(np.max(np.abs(rec.control[:len(idx)]
                                                    - np.asarray(sim.u_applied)[idx]))),
    }


def plot_comparison(rec: Recording, sim, title="Measured vs simulated sine-jerk move"):
    """Overlay a rig recording and a simulation: position, tracking error, control voltage.

    Both tracking errors are ``reference − encoder reading`` (what the controller sees).
    """
    import matplotlib.pyplot as plt

    n = min(len(rec), len(sim.t))
    idx = rec.index[rec.index < len(sim.t)][:n]
    t = rec.time[:len(idx)]
    fig, ax = plt.subplots(3, 1, sharex=True, figsize=(8, 7.5))
    ax[0].plot(t, rec.reference[:len(idx)], "k--", lw=1, label="reference")
    ax[0].plot(t, rec.position[:len(idx)], label="measured (rig)")
    ax[0].plot(t, np.asarray(sim.measured)[idx], ":", label="simulated")
    ax[0].set_ylabel("position (rad)")
    ax[0].legend(loc="lower right")
    ax[1].plot(t, 1e3 * (rec.reference[:len(idx)] - rec.position[:len(idx)]), label="measured (rig)")
    ax[1].plot(t, 1e3 * (np.asarray(sim.reference)[idx] - np.asarray(sim.measured)[idx]), ":",
               label="simulated")
    ax[1].set_ylabel("tracking error (mrad)")
    ax[1].legend(loc="upper right")
    ax[2].step(t, rec.control[:len(idx)], where="post", label="measured (rig)")
    ax[2].step(t, np.asarray(sim.u_applied)[idx], ":", where="post", label="simulated")
    ax[2].set_ylabel("control (V)")
    ax[2].set_xlabel("time (s)")
    ax[2].legend(loc="upper right")
    ax[0].set_title(title)
    fig.tight_layout()
    return fig
