"""Recordings of rig runs: time series + metadata, written to disk as samples arrive.

A :class:`Recording` is a CSV file (one row per telemetry sample, flushed as the
samples come in) plus a JSON sidecar (gains, limits, plant, firmware version,
profile, status).  The sidecar is written when the run starts (``"status":
"recording"``) and rewritten when it ends (``"complete"``, ``"timeout"``,
``"disconnected"``, ``"stopped"``, ...), so a pulled cable or a crash leaves
every sample received so far on disk, described.

SI units in the arrays: s, rad, V (the series names of :mod:`jerklab._vocab`: ``time``,
``reference``, ``position``, ``voltage``).  ``counts`` and ``pwm`` keep the raw integers.  The
CSV keeps its column names (``control`` for the voltage), so files written before stay readable.
"""

from __future__ import annotations

import datetime as _dt
import errno as _errno
import json
import math
import os
import warnings
from pathlib import Path

import numpy as np

from jerklab._validate import (
    BadInput,
    as_having,
    as_instance,
    as_int,
    as_path,
    as_positive,
    as_real,
)
from jerklab._vocab import aliases

__all__ = ["Recording", "RecordingIOError", "recordings_dir", "compare", "plot_comparison"]

#: sidecar keys a recording cannot be read without (each must be a finite number > 0)
REQUIRED_METADATA = ("Ts", "counts_per_rad", "volts_per_pwm")
#: status of a recording whose writer has not finished it (yet, or ever: a killed client)
RECORDING = "recording"
#: what :meth:`Recording.load` reports for a sidecar left at "recording"
INCOMPLETE = "incomplete"


class RecordingIOError(OSError):
    """Writing a recording failed (disk full, I/O error, no permission).

    ``errno`` is the operating system's code; ``filename`` the file; ``samples_saved`` how
    many samples are on disk (flushed before the failure); the message says all three.
    """

    def __init__(self, code, message, filename=None, samples_saved=0):
        super().__init__(code, message)
        self.filename = None if filename is None else str(filename)
        self.samples_saved = int(samples_saved)

    def __str__(self):
        return self.strerror


def _io_error(exc: OSError, path, saved: int, doing: str) -> RecordingIOError:
    code = exc.errno if exc.errno is not None else _errno.EIO
    reason = exc.strerror or os.strerror(code)
    hint = _IO_HINTS.get(code, "")
    return RecordingIOError(
        code,
        f"{path}: {reason} [errno {code}, {_errno.errorcode.get(code, '?')}] while "
        f"{doing}; {saved} samples saved in the file" + (f". {hint}" if hint else ""),
        path,
        saved,
    )


#: what to do about the common write errors (appended to :class:`RecordingIOError`'s message)
_IO_HINTS = {
    _errno.EACCES: "Choose a folder you may write to: connect(recordings=...), the path= of "
    "the run, or $JERKLAB_RECORDINGS",
    _errno.EPERM: "Choose a folder you may write to: connect(recordings=...), the path= of "
    "the run, or $JERKLAB_RECORDINGS",
    _errno.EROFS: "The file system is read-only: choose another folder with "
    "connect(recordings=...), the path= of the run, or $JERKLAB_RECORDINGS",
    _errno.ENOSPC: "The disk is full: free some space or record to another disk",
    _errno.ENOENT: "A folder of the path does not exist and could not be made",
    _errno.ENOTDIR: "A part of the path is a file, not a folder",
    _errno.EEXIST: "A folder of the path is a file, not a folder",
}


def _check_metadata(meta, where: str) -> tuple[float, float, float]:
    """Ts, counts_per_rad, volts_per_pwm from ``meta`` (ValueError naming the field and ``where``)."""
    if not isinstance(meta, dict):
        raise TypeError(f"metadata must be a dict, got {type(meta).__name__}")
    out = []
    for key in REQUIRED_METADATA:
        if key not in meta:
            raise ValueError(f"{where}: metadata must contain {key!r}")
        out.append(as_positive(f"{where}: metadata {key!r}", meta[key]))
    return tuple(out)


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
    p = as_path("path", path)
    if p.suffix.lower() in (".csv", ".json"):
        p = p.with_suffix("")
    return p.with_name(p.name + ".csv"), p.with_name(p.name + ".json")


_INT_COLUMNS = frozenset(("index", "counts", "pwm", "flags"))


def _parse_row(cells, csv_path, ln, scale) -> tuple:
    """One CSV row as ``(index, reference, counts, pwm, flags)``; every cell must be a number of
    its column's kind and the derived columns (time, position, control) must agree with the
    raw ones, else ``ValueError`` naming the file, the line and the column."""
    vals = []
    for col, cell in zip(COLUMNS, cells):
        try:
            if col in _INT_COLUMNS:
                v = int(cell)
                if v < 0 and col in ("index", "flags"):
                    raise ValueError("negative")
            else:
                v = float(cell)
                if not math.isfinite(v):
                    raise ValueError("not finite")
        except ValueError:
            kind = (
                "an integer >= 0"
                if col in ("index", "flags")
                else ("an integer" if col in _INT_COLUMNS else "a finite number")
            )
            raise ValueError(
                f"{csv_path}: line {ln}, column {col!r}: {cell!r} is not {kind}; the file is "
                f"corrupt (fix or delete that line to load the rest)"
            ) from None
        vals.append(v)
    index, time, reference, position, counts, control, pwm, flags = vals
    Ts, cpr, vpp = scale
    for col, got, want in (
        ("time", time, index * Ts),
        ("position", position, counts / cpr),
        ("control", control, pwm * vpp),
    ):
        if abs(got - want) > 1e-9 * max(1.0, abs(want)):
            raise ValueError(
                f"{csv_path}: line {ln}, column {col!r}: {got!r} disagrees with the raw columns "
                f"(expected {want!r} from the sidecar's scale); the file is corrupt"
            )
    return (index, reference, counts, pwm, flags)


@aliases(control="voltage")
class Recording:
    """A run's time series and metadata, optionally streamed to ``path`` (.csv + .json).

    The series are numpy arrays with one entry per received sample.

    Attributes
    ----------
    time : s, ``index * Ts``
    reference : rad, the position reference the device used (0 for an open-loop step)
    position : rad, ``counts / counts_per_rad``
    voltage : V, ``pwm / pwm_max * supply_voltage``: the PWM-quantized voltage applied, held
        from each sample to the next (older name: ``control``)
    counts, pwm, index, flags : the raw telemetry integers
    metadata : dict (JSON sidecar): kind, Ts, gains, limits, plant, device, profile, status,
        and under ``"caller"`` the fields the rig's owner gave (``connect(metadata=...)``)

    Examples
    --------
    >>> rec = Recording({"kind": "demo", "Ts": 0.005, "counts_per_rad": 448 / (2 * math.pi),
    ...                  "volts_per_pwm": 12 / 1023})
    >>> rec.append(0, 0.0, 0, 0); rec.append(1, 0.01, 1, 1023)
    >>> rec.time.tolist(), rec.voltage.tolist()
    ([0.0, 0.005], [0.0, 12.0])
    """

    def __init__(self, metadata: dict, path=None):
        self._Ts, self._cpr, self._vpp = _check_metadata(metadata, "metadata")
        self.metadata = dict(metadata)
        self._rows: list[tuple] = []
        self._file = None
        self._saved = 0  # rows known to be on disk (flushed)
        self._written = 0  # rows handed to the file object
        self.write_error: RecordingIOError | None = None
        self.csv_path = self.json_path = None
        self.metadata.setdefault("status", RECORDING)
        self.metadata.setdefault(
            "created", _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds")
        )
        if path is not None:
            self._open(path)

    # -------------------------------------------------------------- streaming
    def _open(self, path):
        self.csv_path, self.json_path = _paths(path)
        self.metadata["csv"] = self.csv_path.name
        try:
            self.csv_path.parent.mkdir(parents=True, exist_ok=True)
            self._file = open(self.csv_path, "w", newline="", encoding="ascii")
            self._file.write(",".join(COLUMNS) + "\r\n")
            self._file.flush()
        except OSError as exc:
            self._drop_file()
            raise _io_error(exc, self.csv_path, 0, "creating the recording") from exc
        self._write_json()

    def _write_json(self):
        if self.json_path is None:
            return
        tmp = self.json_path.with_name(self.json_path.name + ".tmp")
        try:
            with open(tmp, "w", encoding="utf-8") as f:
                json.dump(_clean(self.metadata), f, indent=2, default=_json_default)
                f.write("\n")
            os.replace(tmp, self.json_path)
        except OSError as exc:
            try:
                os.unlink(tmp)
            except OSError:
                pass
            raise _io_error(exc, self.json_path, self._saved, "writing the sidecar") from exc

    def _drop_file(self):
        f, self._file = self._file, None
        if f is not None:
            try:
                f.close()
            except OSError:
                pass  # the buffered rows that could not be written are lost to the file

    def _fail(self, exc: OSError, doing: str):
        """Stop writing after an I/O error: the samples stay in memory, the error is kept."""
        self._drop_file()
        self.write_error = _io_error(exc, self.csv_path, self._saved, doing)
        raise self.write_error from exc

    def append(self, index: int, reference: float, counts: int, pwm: int, flags: int = 0) -> None:
        """Add one telemetry sample (written to the CSV at once; call :meth:`flush` to push it).

        Raises
        ------
        RecordingIOError
            The file could not be written (disk full, I/O error): the message names the file
            and the number of samples saved in it; this and later samples are kept in memory
            only.
        """
        if type(index) is not int or index < 0:
            index = as_int("index", index, minimum=0)
        if type(reference) is not float or not math.isfinite(reference):
            reference = as_real("reference", reference)
        row = (
            index,
            reference,
            as_int("counts", counts),
            as_int("pwm", pwm),
            as_int("flags", flags, minimum=0),
        )
        self._rows.append(row)
        if self._file is not None:
            i, r, c, p, fl = row
            try:
                self._file.write(
                    f"{i},{i * self._Ts!r},{r!r},{c / self._cpr!r},{c},{p * self._vpp!r},{p},{fl}\r\n"
                )
            except OSError as exc:
                self._fail(exc, f"writing sample {len(self._rows) - 1}")
            self._written = len(self._rows)

    def flush(self) -> None:
        """Push written rows to the operating system (done after every received chunk).

        Raises :class:`RecordingIOError` (naming the file and the samples saved) if that fails.
        """
        if self._file is not None:
            try:
                self._file.flush()
            except OSError as exc:
                self._fail(exc, "flushing samples to disk")
            self._saved = self._written

    def finish(self, status: str = "complete", **info) -> None:
        """Close the CSV and rewrite the sidecar with the final ``status`` and ``info``.

        ``status`` is ``"complete"`` or why the recording ended (``"interrupted"``,
        ``"timeout"``, ``"disconnected"``, ``"error: ..."``). After a write error the sidecar
        also gets ``"samples_saved"`` (rows in the CSV; ``n_samples`` counts those in memory).
        Raises :class:`RecordingIOError` if the CSV or the sidecar cannot be written.
        """
        if not isinstance(status, str) or not status:
            raise ValueError(f"status must be a non-empty string, got {status!r}")
        self.metadata["status"] = status
        self.metadata["n_samples"] = len(self._rows)
        self.metadata.update(info)
        first = None
        if self._file is not None:
            try:
                self._file.flush()
                self._saved = self._written
                self._file.close()
            except OSError as exc:
                first = _io_error(exc, self.csv_path, self._saved, "closing the recording")
                self.write_error = self.write_error or first
            self._file = None
        if self.write_error is not None:
            self.metadata["samples_saved"] = self._saved
            if not status.startswith("error"):
                self.metadata["status"] = f"error: {self.write_error}"
        try:
            self._write_json()
        except RecordingIOError:
            if first is None:
                raise
        if first is not None:
            raise first

    # -------------------------------------------------------------- arrays
    def __len__(self) -> int:
        return len(self._rows)

    def rows(self, start: int = 0, stop: int | None = None) -> list[tuple]:
        """The raw samples ``start:stop`` as ``(index, reference, counts, pwm, flags)`` tuples,
        the arguments of :meth:`append` (a copy: another thread may read them while the run
        appends, e.g. to forward them as they arrive).

        Examples
        --------
        >>> rec = Recording({"Ts": 0.005, "counts_per_rad": 71.3, "volts_per_pwm": 0.0117})
        >>> rec.append(0, 0.0, 0, 0); rec.append(1, 0.01, 1, 1023)
        >>> rec.rows(1)
        [(1, 0.01, 1, 1023, 0)]
        """
        start = as_int("start", start, minimum=0)
        if stop is not None:
            stop = as_int("stop", stop, minimum=0)
        return self._rows[start:stop]

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
    def voltage(self):
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
        """Read a recording written by a run or by :meth:`save` (either file of the pair).

        The sidecar's ``Ts``, ``counts_per_rad`` and ``volts_per_pwm`` must be finite numbers
        > 0 (ValueError naming the field and the file). A sidecar still at ``"recording"``
        (its writer was killed) loads with status ``"incomplete"`` and a warning; a torn last
        row (a crash mid-write) is dropped with a warning; a blank row or one with the wrong
        number of fields inside the file is skipped with a warning naming its line, so no data
        after it is lost. A row with the right fields but a cell that is not a number of its
        column's kind, or a derived column (time, position, control) that disagrees with the
        raw ones, raises ``ValueError`` naming the file, the line and the column: the file
        was changed after it was written, and which of its samples are right is not known.
        """
        csv_path, json_path = _paths(path)
        if not csv_path.exists():
            raise FileNotFoundError(f"no recording at {csv_path}")
        if not json_path.exists():
            raise ValueError(
                f"{json_path} missing: cannot recover Ts, counts_per_rad, volts_per_pwm "
                f"for the samples in {csv_path}"
            )
        try:
            with open(json_path, encoding="utf-8") as f:
                meta = json.load(f)
        except (UnicodeDecodeError, json.JSONDecodeError) as exc:
            raise ValueError(
                f"{json_path} is not a valid JSON sidecar ({exc}); the samples are "
                f"still in {csv_path}"
            ) from None
        if not isinstance(meta, dict):
            raise ValueError(f"{json_path} is not a jerklab sidecar (a JSON {type(meta).__name__})")
        Ts, cpr, vpp = _check_metadata(meta, str(json_path))
        meta_scale = (Ts, cpr, vpp)
        with open(csv_path, "rb") as f:
            data = f.read()
        try:
            text = data.decode("ascii")
        except UnicodeDecodeError as exc:
            raise ValueError(
                f"{csv_path} is not a jerklab recording (not ASCII at byte {exc.start})"
            ) from None
        lines = text.split("\n")
        terminated = lines[-1] == ""  # the writer ends every row with a newline
        if terminated:
            lines.pop()
        header = lines[0].rstrip("\r") if lines else None
        if header is None or tuple(header.split(",")) != COLUMNS:
            raise ValueError(f"{csv_path} is not a jerklab recording (header {header!r})")
        rows = []
        for ln, line in enumerate(lines[1:], start=2):
            line = line.rstrip("\r")
            last = ln == len(lines)
            if last and not terminated:
                warnings.warn(
                    f"{csv_path}: line {ln} (the last row) is torn (no end of line, the "
                    f"writer stopped mid-row): dropped, {len(rows)} samples kept",
                    stacklevel=2,
                )
                break
            if line == "":
                warnings.warn(f"{csv_path}: line {ln} is blank (skipped)", stacklevel=2)
                continue
            cells = line.split(",")
            if len(cells) != len(COLUMNS):
                warnings.warn(
                    f"{csv_path}: line {ln} is not a whole row ({len(cells)} fields instead of "
                    f"{len(COLUMNS)}): skipped",
                    stacklevel=2,
                )
                continue
            rows.append(_parse_row(cells, csv_path, ln, meta_scale))
            # the derived columns must agree with the raw ones (a garbage cell is named)
        status = meta.get("status")
        if status == RECORDING:
            meta["status"] = INCOMPLETE
            meta["status_on_disk"] = RECORDING
            warnings.warn(
                f"{json_path} still says 'recording': its writer stopped without finishing "
                f"(process killed, power lost, or still running); loaded as 'incomplete' "
                f"with the {len(rows)} whole samples in {csv_path}",
                stacklevel=2,
            )
        elif isinstance(meta.get("n_samples"), int) and meta["n_samples"] != len(rows):
            warnings.warn(
                f"{csv_path}: {len(rows)} samples, the sidecar says {meta['n_samples']} "
                f"(status {status!r})",
                stacklevel=2,
            )
        rec = cls(meta)
        rec._rows = rows
        rec.csv_path, rec.json_path = csv_path, json_path
        return rec

    def plot(self, ax=None):
        """Reference and measured position (rad) and voltage (V): :func:`jerklab.plots.plot_recording`."""
        from jerklab.plots import plot_recording

        if ax is not None:
            as_having("ax", ax, ("figure", "plot"), "a matplotlib Axes or None")
        return plot_recording(self, ax)

    def plot_comparison(self, sim, title="Measured vs simulated sine-jerk move"):
        """This recording against a simulation (position, tracking error, voltage):
        :func:`jerklab.plots.plot_comparison`."""
        from jerklab.plots import plot_comparison

        as_having(
            "sim", sim, ("time", "measured", "reference", "voltage"), "a jerklab.sim.SimResult"
        )
        if not isinstance(title, str):
            raise BadInput(f"title must be a str, got {title!r}")
        return plot_comparison(self, sim, title)

    def __repr__(self):
        where = f", path={str(self.csv_path)!r}" if self.csv_path else ""
        return (
            f"Recording(kind={self.metadata.get('kind')!r}, samples={len(self)}, "
            f"status={self.metadata.get('status')!r}{where})"
        )


def compare(rec: Recording, sim) -> dict:
    """Measured vs simulated run on the recording's samples (rad, V).

    ``sim`` is a :class:`jerklab.sim.SimResult` sampled at the same ``Ts`` from t = 0.
    Returns the number of common samples, the largest and RMS difference of the measured
    angles, the largest tracking error of each, and the largest control difference (NaN
    when there is no sample in common).
    """
    rec = as_instance("rec", rec, Recording, "a jerklab.rig.Recording")
    as_having("sim", sim, ("time", "measured", "reference", "voltage"), "a jerklab.sim.SimResult")
    n = min(len(rec), len(sim.time))
    idx = rec.index[rec.index < len(sim.time)][:n]
    if len(idx) == 0:  # no sample in common: every difference is undefined
        nan = float("nan")
        return {
            "samples": 0,
            "max_abs_position_diff": nan,
            "rms_position_diff": nan,
            "max_abs_error_measured": nan,
            "max_abs_error_simulated": nan,
            "max_abs_control_diff": nan,
        }
    meas = rec.position[: len(idx)]
    sim_meas = np.asarray(sim.measured)[idx]
    d = meas - sim_meas
    return {
        "samples": int(len(idx)),
        "max_abs_position_diff": float(np.max(np.abs(d))) if len(d) else float("nan"),
        "rms_position_diff": float(np.sqrt(np.mean(d**2))) if len(d) else float("nan"),
        "max_abs_error_measured": float(np.max(np.abs(rec.reference[: len(idx)] - meas))),
        "max_abs_error_simulated": float(np.max(np.abs(np.asarray(sim.reference)[idx] - sim_meas))),
        "max_abs_control_diff": float(
            np.max(np.abs(rec.voltage[: len(idx)] - np.asarray(sim.voltage)[idx]))
        ),
    }


def plot_comparison(rec: Recording, sim, title="Measured vs simulated sine-jerk move"):
    """``rec.plot_comparison(sim, title)``: a recording against a simulation
    (:func:`jerklab.plots.plot_comparison`)."""
    return rec.plot_comparison(sim, title)
