"""Identification records: :class:`IdentData` (CSV + JSON sidecar) and :class:`MergedData`.

The Python counterparts of MATLAB's ``iddata`` and ``merge`` used in Stojčić §4A (ASCII:
Stojcic).
"""

from __future__ import annotations

import json

import numpy as np

from jerklab._validate import as_path, as_positive
from jerklab._vocab import aliases
from jerklab.ident._common import _pair, _signal
from jerklab.ident.fit import fit_dc_motor
from jerklab.ident.motorfit import MotorFit


@aliases(t="time", u="voltage", y="position")
class IdentData:
    """An identification record: input voltage u(k), measured angle y(k) every ``Ts`` seconds.

    The Python counterpart of MATLAB's ``iddata(y, u, Ts)`` used in Stojčić §4A. The series
    carry the names of ``jerklab._vocab``: ``time``, ``voltage`` (the input u), ``position``
    (the output y); the older names ``t``, ``u`` and ``y`` read and write the same arrays.

    Parameters
    ----------
    voltage : array_like
        Input samples u (the motor voltage, V), held constant over each sample period (ZOH).
    position : array_like
        Output samples y (the measured angle, rad, or ``output_unit``), same length.
    Ts : float
        Sample period (s), > 0.
    input_unit, output_unit : str
        Units, kept in the JSON sidecar ("V" and "rad" by default: SI inside).
    metadata : dict, optional
        Anything JSON-able describing how the record was made (plant parameters, seed, command).

    Examples
    --------
    >>> d = IdentData(step_input(1.0, 0.005, 6.0), theta, 0.005)        # doctest: +SKIP
    >>> d.save("data/ident/step")                                       # doctest: +SKIP
    >>> fit = IdentData.load("data/ident/step").fit("pem")              # doctest: +SKIP
    """

    FORMAT = "jerklab.ident.IdentData/1"
    __slots__ = ("voltage", "position", "Ts", "input_unit", "output_unit", "metadata")

    def __init__(
        self, voltage, position, Ts, input_unit: str = "V", output_unit: str = "rad", metadata=None
    ):
        self.voltage, self.position = _pair(voltage, position, "voltage", "position", min_len=2)
        self.Ts = as_positive("Ts", Ts)
        if not isinstance(input_unit, str) or not input_unit:
            raise ValueError(f"input_unit must be a non-empty string, got {input_unit!r}")
        if not isinstance(output_unit, str) or not output_unit:
            raise ValueError(f"output_unit must be a non-empty string, got {output_unit!r}")
        self.input_unit = input_unit
        self.output_unit = output_unit
        if metadata is None:
            metadata = {}
        if not isinstance(metadata, dict):
            raise ValueError(f"metadata must be a dict, got {type(metadata).__name__}")
        try:
            json.dumps(metadata)
        except (TypeError, ValueError) as exc:
            raise ValueError(f"metadata must be JSON-serialisable: {exc}") from None
        self.metadata = dict(metadata)

    # -- shape ---------------------------------------------------------------------------------
    @property
    def n(self) -> int:
        """Number of samples."""
        return int(self.voltage.size)

    def __len__(self) -> int:
        return self.n

    @property
    def time(self) -> np.ndarray:
        """Sample times k*Ts (s)."""
        return np.arange(self.n) * self.Ts

    @property
    def duration(self) -> float:
        """Record length n*Ts (s)."""
        return self.n * self.Ts

    def __getitem__(self, index) -> "IdentData":
        """A contiguous slice of samples (e.g. ``d[:200]`` for estimation, ``d[200:]`` to validate)."""
        if not isinstance(index, slice) or index.step not in (None, 1):
            raise ValueError("index must be a contiguous slice of samples, e.g. data[100:400]")
        md = dict(self.metadata)
        start = index.indices(self.n)[0]
        md["slice_start_sample"] = md.get("slice_start_sample", 0) + start
        return IdentData(
            self.voltage[index],
            self.position[index],
            self.Ts,
            self.input_unit,
            self.output_unit,
            md,
        )

    def __repr__(self) -> str:
        return (
            f"IdentData(n={self.n}, Ts={self.Ts:g} s, duration={self.duration:g} s, "
            f"voltage in [{self.voltage.min():g}, {self.voltage.max():g}] {self.input_unit}, "
            f"position in [{self.position.min():g}, {self.position.max():g}] {self.output_unit})"
        )

    # -- conversions ---------------------------------------------------------------------------
    @classmethod
    def from_recording(cls, rec, Ts=None) -> "IdentData":
        """Build from a rig ``Recording`` (fields ``time``, ``position``, ``voltage`` or its older name
        ``control``, and ``metadata``).

        Parameters
        ----------
        rec : jerklab.rig.Recording
            An open-loop record (``rig.step(...)``) or a closed-loop move; its voltage (V) becomes
            the input and ``position`` (rad) the output.
        Ts : float, optional
            Sample period; by default ``rec.metadata["Ts"]`` if present, else the median spacing
            of ``rec.time``. The time stamps must be uniform to 1 % of Ts.
        """
        volt = "voltage" if hasattr(rec, "voltage") else "control"
        for attr in ("time", "position", volt):
            if not hasattr(rec, attr):
                raise ValueError(
                    f"rec must be a Recording with a '{attr}' field (got {type(rec).__name__})"
                )
        t = _signal("rec.time", rec.time, min_len=2)
        u = _signal(f"rec.{volt}", getattr(rec, volt), min_len=2)
        y = _signal("rec.position", rec.position, min_len=2)
        if not (t.size == u.size == y.size):
            raise ValueError(
                f"rec.time, rec.{volt} and rec.position must have the same length, "
                f"got {t.size}, {u.size}, {y.size}"
            )
        md = getattr(rec, "metadata", None) or {}
        if not isinstance(md, dict):
            md = {}
        dt = np.diff(t)
        if Ts is None:
            Ts = md.get("Ts", md.get("ts", None))
            Ts = float(np.median(dt)) if Ts is None else Ts
        Ts = as_positive("Ts", Ts)
        if np.max(np.abs(dt - Ts)) > 0.01 * Ts:
            raise ValueError(
                f"rec.time is not uniformly sampled at Ts = {Ts:g} s "
                f"(spacing from {dt.min():g} to {dt.max():g} s)"
            )
        meta = {}
        for k, v in md.items():
            try:
                json.dumps(v)
                meta[str(k)] = v
            except (TypeError, ValueError):
                meta[str(k)] = repr(v)
        meta["source"] = "jerklab.rig.Recording"
        meta["t0"] = float(t[0])
        return cls(u, y, Ts, "V", "rad", meta)

    def fit(self, method: str = "pem", **kwargs) -> "MotorFit":
        """``fit_dc_motor(self.voltage, self.position, self.Ts, method, **kwargs)``."""
        return fit_dc_motor(self.voltage, self.position, self.Ts, method=method, **kwargs)

    # -- files ---------------------------------------------------------------------------------
    @staticmethod
    def _paths(path):
        p = as_path("path", path)
        if p.suffix in (".csv", ".json"):
            p = p.with_suffix("")
        return p.with_name(p.name + ".csv"), p.with_name(p.name + ".json")

    def save(self, path):
        """Write ``<path>.csv`` (columns time_s, u_<input_unit>, y_<output_unit>: the time, the
        voltage and the position) and its JSON sidecar ``<path>.json``.

        Returns the two paths. Values are written with 17 significant digits, so a round trip is
        exact.
        """
        csv_path, json_path = self._paths(path)
        csv_path.parent.mkdir(parents=True, exist_ok=True)
        cols = ["time_s", f"u_{self.input_unit}", f"y_{self.output_unit}"]
        table = np.column_stack([self.time, self.voltage, self.position])
        header = ",".join(cols)  # plain ASCII, or UTF-8 with a BOM so a spreadsheet reads "µm"
        np.savetxt(
            csv_path,
            table,
            delimiter=",",
            header=header,
            comments="",
            fmt="%.17g",
            encoding="ascii" if header.isascii() else "utf-8-sig",
        )
        side = {
            "format": self.FORMAT,
            "csv": csv_path.name,
            "columns": cols,
            "Ts": self.Ts,
            "n_samples": self.n,
            "input_unit": self.input_unit,
            "output_unit": self.output_unit,
            "metadata": self.metadata,
        }
        json_path.write_text(json.dumps(side, indent=2, sort_keys=False) + "\n")
        return csv_path, json_path

    @classmethod
    def load(cls, path) -> "IdentData":
        """Read a record written by :meth:`save` (``path`` with or without ``.csv``/``.json``)."""
        csv_path, json_path = cls._paths(path)
        if not json_path.exists():
            raise ValueError(f"path: no JSON sidecar {json_path}")
        if not csv_path.exists():
            raise ValueError(f"path: no CSV file {csv_path}")
        try:
            side = json.loads(json_path.read_text())
        except json.JSONDecodeError as exc:
            raise ValueError(f"path: corrupt JSON sidecar {json_path}: {exc}") from None
        if not isinstance(side, dict):
            raise ValueError(
                f"path: {json_path} is not an IdentData sidecar (a JSON {type(side).__name__}, "
                f"not an object)"
            )
        if side.get("format") != cls.FORMAT:
            raise ValueError(
                f"path: {json_path} is not an IdentData sidecar (format {side.get('format')!r})"
            )
        try:
            table = np.loadtxt(csv_path, delimiter=",", skiprows=1, ndmin=2)
        except ValueError as exc:
            raise ValueError(f"path: corrupt CSV {csv_path}: {exc}") from None
        if table.shape[1] != 3:
            raise ValueError(f"path: {csv_path} must have 3 columns, has {table.shape[1]}")
        n = side.get("n_samples")
        if n is not None and n != table.shape[0]:
            raise ValueError(f"path: {csv_path} has {table.shape[0]} rows, sidecar says {n}")
        if "Ts" not in side:
            raise ValueError(f"path: {json_path} has no field 'Ts' (the sample time, s)")
        Ts = as_positive(f"path: {json_path} field 'Ts'", side["Ts"])
        t = table[:, 0]
        if t.size > 1 and np.max(np.abs(np.diff(t) - Ts)) > 0.01 * Ts:
            raise ValueError(f"path: time column of {csv_path} is not sampled at Ts = {Ts:g} s")
        return cls(
            table[:, 1],
            table[:, 2],
            Ts,
            side.get("input_unit", "V"),
            side.get("output_unit", "rad"),
            side.get("metadata", {}),
        )

    def plot(self, axes=None):
        """Input (V) and output (rad) against time (s): :func:`jerklab.plots.plot_ident_data`."""
        from jerklab.plots import plot_ident_data  # drawing is imported when a figure is asked for

        return plot_ident_data(self, axes)


@aliases(u="voltage", y="position")
class MergedData:
    """Several experiments of the same motor, for one estimate (MATLAB's ``merge``).

    Each record keeps its own time axis and initial state; :meth:`fit` passes the lists of
    inputs and outputs to :func:`fit_dc_motor`. Keep validation records out of it. ``voltage``
    and ``position`` (older names ``u``, ``y``) are the lists of the records' series.
    """

    def __init__(self, experiments):
        exps = list(experiments)
        if not exps:
            raise ValueError("experiments must hold at least one IdentData")
        for i, d in enumerate(exps):
            if not isinstance(d, IdentData):
                raise ValueError(f"experiments[{i}] must be an IdentData, got {type(d).__name__}")
        Ts = exps[0].Ts
        for i, d in enumerate(exps):
            if abs(d.Ts - Ts) > 1e-9 * Ts:
                raise ValueError(
                    f"experiments[{i}] has Ts = {d.Ts:g} s, experiments[0] has {Ts:g} s: "
                    f"resample one of them first"
                )
        self.experiments = exps
        self.Ts = Ts

    def __len__(self):
        return len(self.experiments)

    def __getitem__(self, i) -> IdentData:
        return self.experiments[i]

    @property
    def voltage(self) -> list:
        """The input voltage (V) of each experiment."""
        return [d.voltage for d in self.experiments]

    @property
    def position(self) -> list:
        """The measured angle (rad) of each experiment."""
        return [d.position for d in self.experiments]

    def fit(self, method: str = "pem", **kwargs) -> "MotorFit":
        """One fit over every experiment: ``fit_dc_motor([u...], [y...], Ts, method, **kwargs)``."""
        return fit_dc_motor(self.voltage, self.position, self.Ts, method=method, **kwargs)

    def __repr__(self):
        return f"MergedData({len(self)} experiments, Ts={self.Ts:g} s, n={[d.n for d in self.experiments]})"


def merge(*data) -> MergedData:
    """Merge several :class:`IdentData` records into one estimation set (MATLAB's ``merge``)."""
    if len(data) == 1 and isinstance(data[0], (list, tuple)):
        data = tuple(data[0])
    return MergedData(data)
