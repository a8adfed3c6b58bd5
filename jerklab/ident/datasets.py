"""Measured records shipped in data/real, as SI :class:`~jerklab.ident.IdentData`.

The micromouse gearmotor records (CERN-OHL-P v2) and the DC motor/generator record of
SysIdentPy (MIT); each folder's README holds the source, the licence and the conversions.
"""

from __future__ import annotations

import math
import pathlib

import numpy as np

from jerklab._validate import as_int, as_positive
from jerklab.ident._common import MIN_SAMPLES
from jerklab.ident.data import IdentData
from jerklab.resources import share_path

#: PWM amplitude (of 255) of the micromouse records whose command the log lets us rebuild
#: (README_original_data.md: "max speed"); the trapezoid records (2, 4, 6) ramp the PWM at a rate
#: the log does not hold, so they cannot be used as input/output records.
MICROMOUSE_RECORDS = {
    "encoders1": (100, "rectangle, 1 s"),
    "encoders3": (100, "step"),
    "encoders5": (255, "step"),
}


def _default_real_root():
    # the clone's data/, or the installed wheel's copy
    return share_path("data") / "real"


def _read_table(path):
    try:
        with open(path) as fh:
            header = [h.strip() for h in fh.readline().split(",")]
        table = np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2)
    except (OSError, ValueError) as exc:
        raise ValueError(f"path: cannot read {path}: {exc}") from None
    return header, table


def micromouse_battery_voltage(root=None) -> float:
    """Median battery voltage (V) logged with the PWM sweep ``wheelSpeedCalibration3.csv``
    (LiPo 2S, the battery of the speed records; see data/real/micromouse/README.md)."""
    root = pathlib.Path(root) if root is not None else _default_real_root() / "micromouse"
    header, table = _read_table(root / "wheelSpeedCalibration3.csv")
    return float(np.median(table[:, header.index("batteryVoltage")])) / 1000.0


def load_micromouse(
    name: str,
    root=None,
    battery_voltage=None,
    counts_per_motor_rev: int = 12,
    gear_ratio: float = 29.861,
    sign: int = -1,
    pre_samples: int = 20,
) -> IdentData:
    """A measured record of the Pololu 30:1 micro gearmotor of the micromouse "Algernon" as SI data.

    The files (``data/real/micromouse``, CERN-OHL-P v2, from github.com/opatiny/micromouse) log the
    cumulative encoder count of the left motor and its mode every 5 ms; the PWM command is a known
    constant while the mode is non-zero (see ``MICROMOUSE_RECORDS``). Conversions:

    * angle (rad, gearbox output) = ``sign`` * count * 2 pi / (counts_per_motor_rev * gear_ratio):
      the magnetic encoder gives 12 counts per motor revolution when both edges of both channels
      are counted (X4), so 12 * 29.861 counts per output revolution. The left encoder counts down
      for a positive command as wired, hence ``sign=-1``; ``sign=+1`` gives the raw direction (and
      a negative K, which the fit diagnoses as a reversed encoder).
    * voltage (V) = PWM / 255 * ``battery_voltage``, the nominal mean voltage of the DRV8833's
      PWM. Default: :func:`micromouse_battery_voltage`. It is nominal: at light load the bridge's
      coasting PWM makes the speed a nonlinear function of the duty (the PWM sweep shows a dead
      band below about 50/255), so K is a gain per *nominal* volt.

    Parameters
    ----------
    name : {"encoders1", "encoders3", "encoders5"}
        Record: a 1 s rectangle at PWM 100, a step at PWM 100, a step at PWM 255.
    root : path, optional
        Folder holding the CSV files (default: the repository's data/real/micromouse).
    battery_voltage : float, optional
        Supply voltage (V).
    counts_per_motor_rev : int
        Encoder counts per motor revolution (12: Pololu magnetic encoder, X4).
    gear_ratio : float
        Gearbox ratio (29.861 for the "30:1" gearbox).
    sign : {+1, -1}
        Direction of the encoder count relative to a positive command.
    pre_samples : int
        Samples kept before the command starts (the motor at rest); the rest of the idle lead-in
        is dropped.

    Returns
    -------
    IdentData
        u in V, y in rad (output shaft), Ts = 0.005 s; metadata names the source and conversions.
    """
    if name not in MICROMOUSE_RECORDS:
        raise ValueError(
            f"name must be one of {sorted(MICROMOUSE_RECORDS)} (the trapezoid records "
            f"encoders2/4/6 do not log their PWM ramp), got {name!r}"
        )
    root = pathlib.Path(root) if root is not None else _default_real_root() / "micromouse"
    if battery_voltage is None:
        battery_voltage = micromouse_battery_voltage(root)
    battery_voltage = as_positive("battery_voltage", battery_voltage)
    counts_per_motor_rev = as_int("counts_per_motor_rev", counts_per_motor_rev, minimum=1)
    gear_ratio = as_positive("gear_ratio", gear_ratio)
    sign = as_int("sign", sign)
    if sign not in (-1, 1):
        raise ValueError(f"sign must be +1 or -1, got {sign}")
    pre_samples = as_int("pre_samples", pre_samples, minimum=0)
    header, table = _read_table(root / f"{name}.csv")
    for col in ("time", "leftEncoder", "leftMode"):
        if col not in header:
            raise ValueError(f"path: {name}.csv has no '{col}' column (columns {header})")
    t_ms = table[:, header.index("time")]
    counts = table[:, header.index("leftEncoder")]
    mode = table[:, header.index("leftMode")]
    dt = np.diff(t_ms)
    if dt.size == 0 or np.any(dt != dt[0]):
        raise ValueError(f"path: {name}.csv is not uniformly sampled")
    Ts = float(dt[0]) / 1000.0
    on = np.flatnonzero(mode != 0)
    if on.size == 0:
        raise ValueError(f"path: {name}.csv never switches the motor on")
    start = max(int(on[0]) - pre_samples, 0)
    pwm = MICROMOUSE_RECORDS[name][0]
    u = np.where(mode != 0, pwm / 255.0 * battery_voltage, 0.0)[start:]
    rad_per_count = 2.0 * math.pi / (counts_per_motor_rev * gear_ratio)
    y = sign * (counts[start:] - counts[start]) * rad_per_count
    meta = {
        "source": "github.com/opatiny/micromouse matlab/data (CERN-OHL-P v2)",
        "record": name,
        "profile": MICROMOUSE_RECORDS[name][1],
        "pwm": pwm,
        "battery_voltage_V": battery_voltage,
        "counts_per_motor_rev": counts_per_motor_rev,
        "gear_ratio": gear_ratio,
        "sign": sign,
        "rad_per_count": rad_per_count,
        "t0_ms": float(t_ms[start]),
    }
    return IdentData(u, y, Ts, "V", "rad", meta)


#: the DC motor/generator record (data/real/dc-generator): the file, the raw samples per stored row,
#: and the raw samples per PRBS clock period (the hold of the input)
DC_GENERATOR_FILE = "dc_generator_every25.csv"
DC_GENERATOR_ROW_STEP = 25
DC_GENERATOR_RAW_PER_CLOCK = 500


def load_dc_generator(root=None, decimate: int = 1, clock_period: float = 1.0) -> IdentData:
    """The measured DC motor driving a DC generator of SysIdentPy as identification data.

    Lacerda Junior, W. R., et al., "Identificação de um motor/gerador CC por meio de modelos
    polinomiais autorregressivos e redes neurais artificiais", SBAI 2017; the files ``x_cc.csv``
    (motor voltage, 0 or 5 V, a PRBS held for 500 raw samples) and ``y_cc.csv`` (a speed-like
    output, units not stated) of github.com/wilsonrljr/sysidentpy-data (MIT). The repository
    ships every 25th raw sample (``data/real/dc-generator``, README there).

    * u (V): ``x_cc``, as recorded.
    * speed: ``y_cc`` minus its median at rest (the samples before the first switch-on,
      -143.64), in the record's own unit (not stated by the authors).
    * y: the speed integrated by the trapezoidal rule from 0, so the angle-based estimators of
      this module apply: ``fit_dc_motor`` fits K (speed unit per V) and tau on it, and
      ``compare(data, fit, output="speed")`` compares the speed, ``diff(y)/Ts`` (the mean of
      two neighbouring speed samples) against the model's mean speed over each sample period.
    * time: the sample period of the record is not stated anywhere. The input is held for 500
      raw samples (its PRBS clock), so time is counted in clock periods: ``Ts`` =
      25 ``decimate`` / 500 ``clock_period``. With the default ``clock_period=1.0`` every time
      (Ts, tau) is in clock periods, *written as seconds*; pass the true clock period (s) if
      you know it.

    Parameters
    ----------
    root : path, optional
        Folder holding the CSV (default: the repository's data/real/dc-generator).
    decimate : int
        Keep every ``decimate``-th stored row (1: 20 samples per clock period, 20000 samples).
        The output is smooth, so plain decimation (no filter) loses nothing above the clock rate.
    clock_period : float
        The PRBS clock period (s); 1.0 by convention (time in clock periods).

    Returns
    -------
    IdentData
        u in V, y the integrated speed (``output_unit`` "y_cc*s"), Ts = 0.05 ``decimate``
        ``clock_period``; metadata names the source, the rest level and the conventions.
    """
    decimate = as_int("decimate", decimate, minimum=1)
    clock_period = as_positive("clock_period", clock_period)
    root = pathlib.Path(root) if root is not None else _default_real_root() / "dc-generator"
    header, table = _read_table(root / DC_GENERATOR_FILE)
    for col in ("sample", "x_cc", "y_cc"):
        if col not in header:
            raise ValueError(f"path: {DC_GENERATOR_FILE} has no '{col}' column (columns {header})")
    raw = table[:, header.index("sample")]
    if np.any(np.diff(raw) != DC_GENERATOR_ROW_STEP):
        raise ValueError(
            f"path: {DC_GENERATOR_FILE} is not every {DC_GENERATOR_ROW_STEP}th raw sample"
        )
    rows = slice(None, None, decimate)
    u = table[rows, header.index("x_cc")]
    y_cc = table[rows, header.index("y_cc")]
    if u.size < MIN_SAMPLES:
        raise ValueError(f"decimate: {decimate} leaves {u.size} samples, fewer than {MIN_SAMPLES}")
    on = np.flatnonzero(u != 0)
    if on.size == 0 or on[0] < 1:
        raise ValueError(
            f"path: {DC_GENERATOR_FILE} has no idle lead-in before the first switch-on"
        )
    rest = float(np.median(y_cc[: on[0]]))
    speed = y_cc - rest
    Ts = DC_GENERATOR_ROW_STEP * decimate / DC_GENERATOR_RAW_PER_CLOCK * clock_period
    y = np.concatenate([[0.0], np.cumsum(0.5 * Ts * (speed[1:] + speed[:-1]))])
    meta = {
        "source": "github.com/wilsonrljr/sysidentpy-data datasets/generator (MIT), commit "
        "72715362eadcf860fdbd77d88b5d7e92b6143a83",
        "paper": "Lacerda Junior et al., SBAI 2017, motor/gerador CC",
        "raw_samples_per_row": DC_GENERATOR_ROW_STEP * decimate,
        "raw_samples_per_clock": DC_GENERATOR_RAW_PER_CLOCK,
        "clock_period_s": clock_period,
        "time_unit": "PRBS clock period" if clock_period == 1.0 else "s",
        "speed_rest_level": rest,
        "output": "trapezoidal integral of (y_cc - rest)",
        "speed_unit": "y_cc (not stated by the authors)",
    }
    return IdentData(u, y, Ts, "V", "y_cc*s", meta)
