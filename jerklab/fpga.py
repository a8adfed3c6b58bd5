"""Bit-exact integer model of the FPGA S-curve generator of Yang, Ye, Pan & Ma (2013).

The paper's system (its Fig. 1): a *speed generator* that, every refresh period
``tc``, advances a counter ``n`` and computes the speed from integer formulas
(Yang eqs. 5–8), converts it to a pulse frequency ``f = v / k`` and a divider
count ``cycle = f_clk / f``; a *pulse divider* (the Verilog printed in the paper)
counts the 50 MHz clock and emits one pulse of 50 % duty every ``cycle`` clocks.
A stepper/servo drive in position mode moves ``k`` (µm) per pulse.

Units: this module works in integer µm/s, Hz, clock counts (the hardware's units,
as the paper states them); :meth:`YangSCurve.exact_profile` converts to the
unit-agnostic planner (``jerklab.planner.plan_scurve``) in µm and s.

The reconstruction of the paper's formulas (docs/THEORY.md, Yang), for acceleration time
``T``, peak speed ``V``, ``N = T / (2 tc)`` counts per half:

* Yang eq. 5 (``n <= N``): ``v = 2 V tc^2 n^2 / T^2 = V n^2 / (2 N^2)``;
* Yang eq. 6 (``N < n <= 2N``): ``v = V (4 T n tc - 2 tc^2 n^2 - T^2) / T^2 = V - V (2N - n)^2 / (2 N^2)``;
* Yang eqs. 7, 8 (paper set-up, V = 20000 µm/s, N = 2500): ``v = 16 n^2 / 10000`` and
  ``v = 20000 - (10000 - 2n)^2 / 2500``, Verilog integer division (floor for these
  non-negative operands).

The general integer form used here reduces ``V / (2 N^2)`` to lowest terms ``a / b``
and computes ``floor(a n^2 / b)``; for the paper set-up this is bit-identical to
Yang eqs. 7, 8 (same rational number), which :func:`paper_speed` keeps verbatim.

Things the paper leaves open or gets wrong, and what is done here:

* Deceleration runs the counter back down from ``2N`` (the paper: "1 is
  subtracted"); below the start count ``PWM_INITAL_COUNT`` the speed is 0, so the
  move ends there, symmetric with its start (no published branch covers it).
* The printed divider compares with ``==`` against a ``compare_reg`` that the
  speed generator changes every 200 µs, while a pulse period lasts 1 to 143 ms.
  When the new (shorter) cycle is below the running count, ``count == compare_reg``
  never holds again and the counter runs through 2^32 clocks (86 s at 50 MHz)
  before the next pulse: :func:`published_divider_lockup` finds where that
  happens.  The commented-out ``compare_reg_refresh_flag`` in the paper's listing
  points at the fix used here (and in ``firmware/fpga/pulse_divider.v``): the
  cycle is latched only at the end of a period (``count >= cycle``).
"""

from __future__ import annotations

from dataclasses import dataclass
from fractions import Fraction

import numpy as np

from jerklab import paper as _paper
from jerklab._validate import (
    as_finite_array,
    as_instance,
    as_int,
    as_nonnegative,
    as_path,
    as_positive,
    at_most,
)
from jerklab.multiaxis import MultiAxisPlan
from jerklab.planner import plan_scurve

__all__ = [
    "YangSCurve",
    "PulseTrain",
    "SpeedTable",
    "paper_speed",
    "published_divider_lockup",
    "simulate_verilog",
    "simulate_divider_verilog",
    "read_vcd",
    "VerilogRun",
    "divider_edges",
    "published_divider",
    "HardwareLimitError",
    "PAPER",
    "pulse_speed",
    "vcd_timescale",
    "vcd_to_posedge",
    "YangAxes",
    "yang_axes",
    "simulate_verilog_xy",
    "min_start_count",
]


class HardwareLimitError(ValueError):
    """A value the FPGA cannot hold or produce (counter width, minimum/maximum frequency)."""


def paper_speed(n):
    """Yang eqs. 7, 8 verbatim (µm/s): the paper's set-up, Verilog integer division.

    ``v = 16 n^2 / 10000`` for ``n <= 2500`` (Yang eq. 7, ``div_3_result``),
    ``v = 20000 - (10000 - 2n)^2 / 2500`` for ``2500 < n <= 5000`` (Yang eq. 8, ``div_1_quo``).
    """
    n_arr = np.asarray(n)
    if n_arr.dtype.kind not in "iu":
        raise ValueError(f"n must be integer counts, got dtype {n_arr.dtype}")
    if np.any(n_arr < 0) or np.any(n_arr > 5000):
        raise ValueError("n must be in [0, 5000] (the paper's TOTAL_SPEEDUP_TIMES)")
    n64 = n_arr.astype(np.int64)
    v = np.where(n64 <= 2500, (16 * n64 * n64) // 10000, 20000 - ((10000 - 2 * n64) ** 2) // 2500)
    return int(v) if v.ndim == 0 else v


@dataclass(frozen=True)
class SpeedTable:
    """One row per refresh tick ``m``: counter ``n``, speed (µm/s), frequency (Hz), cycle (clocks)."""

    m: np.ndarray
    n: np.ndarray
    speed: np.ndarray
    frequency: np.ndarray
    cycle: np.ndarray


@dataclass(frozen=True)
class PulseTrain:
    """Divider output: clock indices (posedge numbers, 1 = first after reset) of the edges."""

    rise: np.ndarray
    fall: np.ndarray
    clock_hz: int
    step_um: int

    @property
    def rise_times(self) -> np.ndarray:
        """Rising-edge times (s): posedge ``p`` at ``p / f_clk``."""
        return self.rise / self.clock_hz

    def position(self, t):
        """Commanded position (µm) at time(s) ``t``: ``k`` µm per rising edge so far."""
        t = as_finite_array("t", t)
        return self.step_um * np.searchsorted(self.rise, t * self.clock_hz, side="right")

    def speed(self):
        """Speed the pulses command, ``k / Δt`` between rising edges: ``(t, v)`` in s, µm/s.

        See :func:`pulse_speed`.
        """
        return pulse_speed(self.rise, self.clock_hz, self.step_um)


def pulse_speed(rise, clock_hz, step_um=20):
    """Speed commanded by a pulse train: ``k`` µm per period between consecutive rising edges.

    A drive in position mode moves ``step_um`` per pulse, so over the period that ends at
    rising edge ``i`` the mean speed is ``step_um · f_clk / (rise[i] − rise[i−1])`` (the
    inverse of Yang's ``cycle = f_clk / f`` with ``v = k f``).

    Parameters
    ----------
    rise : array_like of int
        Rising-edge clock indices (posedges), increasing (at least two for one value).
    clock_hz : float
        Divider clock, Hz (> 0).
    step_um : float
        ``k``, µm per pulse (> 0).

    Returns
    -------
    t, v : ndarray
        Time of the later edge of each period (s) and the speed over that period (µm/s);
        one value fewer than ``rise``.
    """
    r = as_finite_array("rise", rise, ndim=1)
    clock_hz = as_positive("clock_hz", clock_hz)
    step_um = as_positive("step_um", step_um)
    dr = np.diff(r)
    if np.any(dr <= 0):
        raise ValueError("rise must be strictly increasing clock indices")
    return r[1:] / clock_hz, step_um * clock_hz / dr


def vcd_timescale(path) -> float:
    """The time unit of a VCD file in seconds (its ``$timescale``, e.g. ``1ps`` -> 1e-12)."""
    import re

    with open(path) as fh:
        head = fh.read().partition("$enddefinitions")[0]
    m = re.search(r"\$timescale\s+(\d+)\s*(s|ms|us|ns|ps|fs)\s+\$end", head)
    if m is None:
        raise ValueError(f"{path}: no $timescale declaration in the VCD header")
    unit = {"s": 1.0, "ms": 1e-3, "us": 1e-6, "ns": 1e-9, "ps": 1e-12, "fs": 1e-15}[m.group(2)]
    return int(m.group(1)) * unit


def vcd_to_posedge(times, clock_period, timescale=1e-12):
    """Convert VCD times to clock-edge numbers of the testbenches in ``firmware/fpga``.

    The testbench clock starts low at time 0 and toggles every half period, so posedge ``p``
    (1 = the first) falls at ``(p − ½) · clock_period``; a register that changes on posedge
    ``p`` shows in the VCD at that time and converts to exactly ``p``.  Negedges give
    half-integers.

    Parameters
    ----------
    times : array_like
        VCD times in units of ``timescale`` (as :func:`read_vcd` returns them).
    clock_period : float
        Testbench clock period, s (20 ns for the 50 MHz of ``tb_pulse_divider.v``).
    timescale : float
        VCD time unit, s (:func:`vcd_timescale`; ``1ps`` for ```timescale 1ns/1ps``).

    Returns
    -------
    ndarray of float
    """
    t = as_finite_array("times", times)
    clock_period = as_positive("clock_period", clock_period)
    timescale = as_positive("timescale", timescale)
    per = clock_period / timescale  # VCD units per clock period
    if abs(per - round(per)) <= 1e-9 * per:
        per = float(round(per))  # exact for whole units (20 ns in ps: 20000)
    return t / per + 0.5


#: most edges :func:`divider_edges` / :func:`published_divider` simulate in one call (a Python
#: loop over edges, ~1 s per 200 000): a larger ``p_end`` raises ValueError
MAX_EDGES = 1_000_000
#: widest register modelled (bits)
MAX_BITS = 64
#: widest register :class:`YangSCurve` models: its tables are numpy int64, so every product
#: and count must stay below 2**62 (the bound :func:`divider_edges` takes its inputs with)
MODEL_BITS = 62
#: most refresh ticks (``4 N + C``) one :class:`YangSCurve` move may have: its speed table holds
#: one row per tick (the paper's move has 15 000; 10**7 is 80 MB per column)
MAX_TICKS = 10_000_000


def _int_array(name, value):
    """``value`` as a 1-D int64 array of whole numbers (ValueError naming ``name``)."""
    a = as_finite_array(name, value, ndim=1)
    if np.any(a != np.round(a)) or np.any(np.abs(a) >= 2.0**62):
        raise ValueError(f"{name} must hold whole numbers below 2**62")
    return a.astype(np.int64)


def _divider_args(starts, values, p_end, bits):
    starts = _int_array("starts", starts)
    values = _int_array("values", values)
    if starts.shape != values.shape or starts.size == 0 or starts[0] != 1:
        raise ValueError("starts must be a 1-D increasing sequence from 1, same length as values")
    if np.any(np.diff(starts) <= 0):
        raise ValueError("starts must be strictly increasing")
    bits = as_int("bits", bits, minimum=1)
    if bits > MAX_BITS:
        raise ValueError(f"bits must be <= {MAX_BITS}, got {bits}")
    p_end = as_int("p_end", p_end, minimum=1)
    nz = values[values > 0]
    cmin = int(nz.min()) if nz.size else 0
    if cmin and 2 * p_end // cmin > 2 * MAX_EDGES:
        raise ValueError(
            f"p_end = {p_end} asks for about {2 * p_end // cmin} edges (cycle {cmin}), more "
            f"than 2 * MAX_EDGES = {2 * MAX_EDGES}: simulate a shorter span"
        )
    return starts, values, p_end, bits


def divider_edges(starts, values, p_end, bits=32):
    """Latched 50 %-duty divider (``firmware/fpga/pulse_divider.v``), clock-exact.

    The ``cycle`` input is a step function of the posedge index: ``values[i]`` from
    posedge ``starts[i]`` on (``starts[0] == 1``).  Register semantics per posedge:

    * idle (``creg == 0``): ``creg <= cycle``, ``count <= 0``, ``clkout <= 0``;
    * ``count == creg >> 1``: ``clkout <= 1``, ``count <= count + 1`` (rising edge);
    * ``count >= creg``: ``clkout <= 0``, ``count <= 1``, ``creg <= cycle`` (falling edge);
    * else ``count <= count + 1``.

    So a period latched at posedge ``q`` rises at ``q + creg//2`` and falls at
    ``q + creg`` (after an idle latch at ``q0``: ``q0 + 1 + creg//2``, ``q0 + 1 + creg``).

    Parameters
    ----------
    starts, values : sequence of int
        The cycle input as a step function (``starts`` increasing, from 1).
    p_end : int
        Last posedge simulated; edges after it are not reported.
    bits : int
        Register width; cycles ``>= 2**bits`` raise :class:`HardwareLimitError`.

    Returns
    -------
    rise, fall : ndarray of int
    """
    starts, values, p_end, bits = _divider_args(starts, values, p_end, bits)
    if np.any(values < 0) or np.any(values >= 2**bits):
        raise HardwareLimitError(f"values (cycles) must fit an unsigned bits = {bits}-bit register")
    if np.any(values == 1):
        raise HardwareLimitError("values: cycle = 1 cannot give a 50 % duty pulse (f > f_clk/2)")

    def w(p):
        return int(values[np.searchsorted(starts, p, side="right") - 1])

    rise, fall = [], []
    p = 1
    creg = 0
    q = 0  # the posedge that latched the current period (set once a period has run)
    while p <= p_end:
        if creg == 0:
            # idle: latch at each posedge until a non-zero value appears
            i = np.searchsorted(starts, p, side="right") - 1
            nz = np.nonzero(values[i:])[0]
            if nz.size == 0:
                break
            j = i + int(nz[0])
            q0 = max(p, int(starts[j]))
            creg = int(values[j])
            r, f = q0 + 1 + creg // 2, q0 + 1 + creg
        else:
            r, f = q + creg // 2, q + creg
        if r > p_end:
            break
        rise.append(r)
        if f > p_end:
            break
        fall.append(f)
        q = f
        creg = w(f)
        p = f + 1
    return np.array(rise, dtype=np.int64), np.array(fall, dtype=np.int64)


class YangSCurve:
    """Yang et al.'s S-curve speed generator + divider as integers (bit-exact).

    Parameters
    ----------
    max_velocity : int
        ``V`` in µm/s (paper: 20000).
    accel_time : float
        ``T`` in s, duration of the acceleration (and of the deceleration) (paper: 1).
    cruise_time : float
        Constant-speed time in s (paper: 1).
    refresh_period : float
        ``tc`` in s (paper: 200e-6).  ``T / (2 tc)`` must be a whole number of counts.
    clock_hz : int
        Divider clock (paper: 50 MHz).  ``tc * clock_hz`` must be whole.
    step_um : int
        ``k``: µm per pulse, ``v = k f`` (paper: 20, the reading of docs/THEORY.md).
    start_count : int
        ``PWM_INITAL_COUNT``: below this count the speed is 0 (paper: 300).
    bits : int
        Width of the hardware registers and multipliers (32); at most ``MODEL_BITS`` = 62 (the
        model computes in int64).

    Raises
    ------
    HardwareLimitError
        If a product or count exceeds ``bits``, if the start speed gives 0 Hz
        (below the minimum frequency ``k`` µm/s -> 1 Hz), or if a cycle would be < 2.
    ValueError
        A bad argument, or a move of more than ``MAX_TICKS`` = 10**7 refresh ticks
        ``(2 T + cruise_time) / tc`` (the paper's has 15 000), refused before any table is built.
    """

    def __init__(
        self,
        max_velocity=_paper.YANG_SETUP["max_velocity"],
        accel_time=_paper.YANG_SETUP["accel_time"],
        cruise_time=_paper.YANG_SETUP["cruise_time"],
        refresh_period=_paper.YANG_SETUP["refresh_period"],
        clock_hz=_paper.YANG_SETUP["clock_hz"],
        step_um=_paper.YANG_SETUP["step_um"],
        start_count=_paper.YANG_SETUP["start_count"],
        bits=32,
    ):
        self.max_velocity = as_int("max_velocity", max_velocity, minimum=1)
        self.accel_time = as_positive("accel_time", accel_time)
        self.cruise_time = as_nonnegative("cruise_time", cruise_time)
        self.refresh_period = as_positive("refresh_period", refresh_period)
        self.clock_hz = as_int("clock_hz", clock_hz, minimum=2)
        self.step_um = as_int("step_um", step_um, minimum=1)
        self.start_count = as_int("start_count", start_count, minimum=0)
        self.bits = at_most(
            "bits",
            as_int("bits", bits, minimum=8),
            MODEL_BITS,
            "fpga.MODEL_BITS: the model computes in int64",
        )
        top = 2**self.bits
        # the tick count before any table is built: accel_time = 1e6 s would be 1e10 ticks
        at_most(
            "accel_time, cruise_time: ticks (2 accel_time + cruise_time) / refresh_period",
            (2.0 * self.accel_time + self.cruise_time) / self.refresh_period,
            MAX_TICKS,
            "fpga.MAX_TICKS refresh ticks per move",
        )

        def whole(name, x):
            r = round(x)
            if r < 1 or abs(x - r) > 1e-9 * max(1.0, abs(x)):
                raise ValueError(f"{name} must be a whole number >= 1, got {x!r}")
            return int(r)

        self.half_counts = whole(
            "accel_time / (2 refresh_period)", self.accel_time / (2 * self.refresh_period)
        )
        self.cruise_counts = (
            whole("cruise_time / refresh_period", self.cruise_time / self.refresh_period)
            if self.cruise_time > 0
            else 0
        )
        self.refresh_clocks = whole(
            "refresh_period * clock_hz", self.refresh_period * self.clock_hz
        )
        N = self.half_counts
        frac = Fraction(self.max_velocity, 2 * N * N)
        self.coef_num, self.coef_den = frac.numerator, frac.denominator
        self.end_tick = 4 * N + self.cruise_counts  # n = 0 from here on
        for name, val in (
            ("multiplier product A_NUM * N^2 (max_velocity, accel_time)", self.coef_num * N * N),
            ("coefficient denominator (max_velocity, accel_time)", self.coef_den),
            ("clock_hz", self.clock_hz),
            ("refresh clocks (refresh_period * clock_hz)", self.refresh_clocks),
            ("tick count (accel_time, cruise_time, refresh_period)", self.end_tick),
            (
                "total clocks (accel_time, cruise_time, clock_hz)",
                (self.end_tick + 1) * self.refresh_clocks,
            ),
        ):
            if val >= top:
                raise HardwareLimitError(f"{name} = {val} does not fit {self.bits} bits")
        if self.start_count > 2 * N:
            raise ValueError(f"start_count must be <= 2 T/(2 tc) = {2 * N}, got {self.start_count}")
        v0 = self.speed(max(self.start_count, 1))
        if self.step_um > self.max_velocity:
            raise HardwareLimitError(
                f"step_um = {self.step_um} µm exceeds max_velocity = "
                f"{self.max_velocity} µm/s: the top speed is below 1 pulse/s"
            )
        if v0 // self.step_um == 0:
            nmin = min_start_count(self.max_velocity, N, self.step_um)
            raise HardwareLimitError(
                f"start_count = {self.start_count} gives {v0} µm/s, below the minimum frequency "
                f"(1 Hz = {self.step_um} µm/s): use start_count >= {nmin}"
            )
        if self.clock_hz // (self.max_velocity // self.step_um or 1) < 2:
            raise HardwareLimitError("max_velocity / step_um exceeds f_clk / 2: cycle < 2")

    # ------------------------------------------------------------------ speed generator
    def speed(self, n):
        """Speed (µm/s) at counter ``n``: Yang eqs. 5, 6 in integer form (floor division).

        ``v = floor(a n^2 / b)`` for ``n <= N``, ``v = V - floor(a (2N - n)^2 / b)`` for
        ``N < n <= 2N``, ``a/b = V/(2N^2)`` in lowest terms; 0 below ``start_count``.
        """
        n_arr = np.asarray(n)
        if n_arr.dtype.kind not in "iu":
            raise ValueError(f"n must be integer counts, got dtype {n_arr.dtype}")
        N = self.half_counts
        if np.any(n_arr < 0) or np.any(n_arr > 2 * N):
            raise ValueError(f"n must be in [0, {2 * N}]")
        n64 = n_arr.astype(np.int64)
        a, b, V = self.coef_num, self.coef_den, self.max_velocity
        d = np.where(n64 <= N, n64, 2 * N - n64)
        q = (a * d * d) // b
        v = np.where(n64 <= N, q, V - q)
        v = np.where(n64 < self.start_count, 0, v)
        return int(v) if v.ndim == 0 else v

    def counter(self, m):
        """Counter ``n`` at refresh tick ``m``: up to 2N, held for the cruise, back down to 0."""
        m = np.asarray(m, dtype=np.int64)
        N, C = self.half_counts, self.cruise_counts
        n = np.where(m <= 2 * N, m, np.where(m <= 2 * N + C, 2 * N, np.maximum(4 * N + C - m, 0)))
        return n

    def speed_table(self) -> SpeedTable:
        """Speed, frequency ``f = v // k`` and divider count ``f_clk // f`` for every tick."""
        m = np.arange(self.end_tick + 1, dtype=np.int64)
        n = self.counter(m)
        v = self.speed(n)
        f = v // self.step_um
        cyc = np.where(f > 0, self.clock_hz // np.maximum(f, 1), 0)
        if np.any(cyc >= 2**self.bits):
            raise HardwareLimitError("a divider count does not fit the register")
        return SpeedTable(m, n, v, f, cyc)

    # ------------------------------------------------------------------ divider
    def cycle_input(self):
        """The divider's cycle input as a step function of the posedge index.

        The tick register ``m`` advances at posedges ``j R`` (``R`` clocks per
        refresh); the combinational speed/cycle path then shows the new value to the
        divider from posedge ``j R + 1`` on.
        """
        tab = self.speed_table()
        starts = tab.m * self.refresh_clocks + 1
        return starts, tab.cycle

    def pulses(self, p_end=None) -> PulseTrain:
        """Pulse train of the whole move (clock-exact, latched divider)."""
        starts, values = self.cycle_input()
        if p_end is None:
            p_end = int(starts[-1] + 2 * int(values.max()) + 2)
        rise, fall = divider_edges(starts, values, p_end, bits=self.bits)
        return PulseTrain(rise, fall, self.clock_hz, self.step_um)

    # ------------------------------------------------------------------ comparison
    @property
    def distance_um(self) -> float:
        """Distance of the ideal (continuous) profile: ``V (T + cruise_time)`` µm."""
        return self.max_velocity * (self.accel_time + self.cruise_time)

    def exact_profile(self):
        """The same move from ``jerklab.planner.plan_scurve`` (µm, s).

        Yang's profile is the 7-segment linear-jerk S-curve with no constant-
        acceleration segment: ``J = 4V/T^2``, ``A = 2V/T``, distance ``V (T + t_cruise)``.
        """
        V, T = float(self.max_velocity), self.accel_time
        return plan_scurve(self.distance_um, 4 * V / T**2, 2 * V / T, V)

    def tick_times(self) -> np.ndarray:
        """Time (s) at which each tick's speed takes effect (``m tc``)."""
        return np.arange(self.end_tick + 1) * self.refresh_period

    def verilog_defines(self) -> dict:
        """Parameters for ``firmware/fpga/scurve_gen.v`` / its testbench (``-P`` / ``-D``)."""
        return {
            "V": self.max_velocity,
            "N": self.half_counts,
            "CRUISE": self.cruise_counts,
            "A_NUM": self.coef_num,
            "B_DEN": self.coef_den,
            "K": self.step_um,
            "F_CLK": self.clock_hz,
            "R": self.refresh_clocks,
            "N_MIN": self.start_count,
        }


PAPER = dict(_paper.YANG_SETUP)
"""Yang et al.'s test set-up (§3), a copy of :data:`jerklab.paper.YANG_SETUP`."""


def published_divider(starts, values, p_end, bits=32):
    """The divider *as printed in the paper* (``==`` compares, live ``compare_reg``), clock-exact.

    Semantics of the listing, per posedge, with ``compare_reg`` the cycle input:
    ``compare_reg == 0`` -> ``clkout <= 0, count <= 0``; else ``count == compare_reg/2``
    -> ``clkout <= 1, count <= count + 1``; else ``count == compare_reg`` ->
    ``clkout <= 0, count <= 1``; else ``count <= count + 1``.

    Returns
    -------
    rise, fall : ndarray of int
        Edge posedges up to ``p_end`` (as :func:`divider_edges`).
    lockup : dict or None
        The first posedge at which ``compare_reg`` changed to a value below the running
        count: from there ``count == compare_reg`` never holds again, and the counter
        runs through ``2**bits`` clocks before the next edge (86 s at 50 MHz);
        ``lockup_clocks`` is the number of clocks until that edge.
    """
    starts, values, p_end, bits = _divider_args(starts, values, p_end, bits)
    if np.any(values < 0) or np.any(values >= 2**bits):
        raise HardwareLimitError(f"values (cycles) must fit an unsigned bits = {bits}-bit register")
    rise, fall = [], []
    count, out, lockup = 0, 0, None
    for i in range(len(starts)):
        c = int(values[i])
        p = int(starts[i])
        if p > p_end:
            break
        p1 = min(int(starts[i + 1]) if i + 1 < len(starts) else p_end + 1, p_end + 1)
        if c == 0:
            if out:
                fall.append(p)
            count, out = 0, 0
            continue
        if count > c and lockup is None:
            lockup = {
                "p": p,
                "m": i,
                "count": count,
                "compare_reg": c,
                "lockup_clocks": 2**bits - count + (c >> 1),
            }
        while p < p1:  # `count` is the value before posedge p
            duty = c >> 1
            if count == duty:
                if not out:
                    rise.append(p)
                out, count, p = 1, count + 1, p + 1
            elif count == c:
                if out:
                    fall.append(p)
                out, count, p = 0, 1, p + 1
            else:
                target = duty if count < duty else c if count < c else 2**bits + duty
                adv = min(p1 - p, target - count)
                count += adv
                p += adv
                if count >= 2**bits:  # wrap-around of the 32-bit counter
                    count -= 2**bits
    return np.array(rise, dtype=np.int64), np.array(fall, dtype=np.int64), lockup


def published_divider_lockup(model: YangSCurve):
    """Where the paper's printed divider locks up on ``model``'s move (``None`` if never).

    Returns a dict: posedge ``p``, time ``t`` (s), tick ``m``, the running ``count``,
    the new ``compare_reg`` below it, and ``lockup_s`` = ``2**bits / f_clk``, the time
    the counter needs to wrap round to the compare value again.
    """
    model = as_instance("model", model, YangSCurve, "a jerklab.fpga.YangSCurve")
    starts, values = model.cycle_input()
    p_end = int(starts[-1] + 2 * int(values.max()) + 2)
    _, _, hit = published_divider(starts, values, p_end, bits=model.bits)
    if hit is None:
        return None
    hit = dict(hit)
    hit["t"] = hit["p"] / model.clock_hz
    hit["lockup_s"] = 2**model.bits / model.clock_hz
    return hit


# ---------------------------------------------------------------------- Verilog (Icarus)
def firmware_dir():
    """``firmware/fpga`` of the source tree (the Verilog sources and testbenches)."""
    from pathlib import Path

    return Path(__file__).resolve().parents[1] / "firmware" / "fpga"


def _run(cmd, cwd):
    import subprocess

    res = subprocess.run(cmd, cwd=cwd, capture_output=True, text=True)
    if res.returncode != 0:
        raise RuntimeError(f"{' '.join(map(str, cmd))} failed:\n{res.stdout}\n{res.stderr}")
    return res.stdout


def _need_iverilog():
    import shutil

    for tool in ("iverilog", "vvp"):
        if shutil.which(tool) is None:
            raise RuntimeError(f"{tool} not found: install the Debian package 'iverilog'")


@dataclass(frozen=True)
class VerilogRun:
    """Output of a testbench: per-tick speed log (``tb_scurve`` only) and edges."""

    table: SpeedTable | None
    rise: np.ndarray
    fall: np.ndarray
    log: str


def _parse(log):
    S, E = [], []
    for line in log.splitlines():
        parts = line.split()
        if parts and parts[0] == "S":
            S.append([int(x) for x in parts[1:6]])
        elif parts and parts[0] == "E":
            E.append((int(parts[1]), int(parts[2])))
    E = np.array(E, dtype=np.int64).reshape(-1, 2)
    rise = E[E[:, 1] == 1, 0]
    fall = E[E[:, 1] == 0, 0]
    table = None
    if S:
        a = np.array(S, dtype=np.int64)
        table = SpeedTable(a[:, 0], a[:, 1], a[:, 2], a[:, 3], a[:, 4])
    return table, rise, fall


def simulate_verilog(
    model: YangSCurve, p_end=None, workdir=None, vcd=None, published=False
) -> VerilogRun:
    """Compile and run ``tb_scurve.v`` (speed generator + divider) with Icarus Verilog.

    ``published=True`` uses the paper's divider as printed (``pulse_divider_published.v``,
    modelled by :func:`published_divider`) instead of the latched one.

    ``p_end`` defaults to the end of the move plus two of the longest periods.  Icarus
    runs ~0.4 M clocks/s here: the paper's 3 s at 50 MHz (1.5e8 clocks) takes minutes,
    so notebooks and tests use a scaled clock (e.g. 500 kHz: same speeds and
    frequencies, cycle counts 100x smaller).
    """
    import tempfile

    model = as_instance("model", model, YangSCurve, "a jerklab.fpga.YangSCurve")
    _need_iverilog()
    starts, values = model.cycle_input()
    if p_end is None:
        p_end = int(starts[-1] + 2 * int(values.max()) + 2)
    p_end = as_int("p_end", p_end, minimum=1)
    d = firmware_dir()
    with tempfile.TemporaryDirectory() as tmp:
        wd = workdir or tmp
        exe = f"{wd}/tb_scurve.vvp"
        params = [f"-Ptb_scurve.{k}={v}" for k, v in model.verilog_defines().items()]
        params.append(f"-Ptb_scurve.P_END={p_end}")
        div = (
            ["-DPUBLISHED", str(d / "pulse_divider_published.v")]
            if published
            else [str(d / "pulse_divider.v")]
        )
        _run(
            [
                "iverilog",
                "-g2012",
                "-o",
                exe,
                *params,
                str(d / "tb_scurve.v"),
                str(d / "scurve_gen.v"),
                *div,
            ],
            wd,
        )
        args = ["vvp", "-n", exe] + ([f"+vcd={vcd}"] if vcd else [])
        log = _run(args, wd)
    table, rise, fall = _parse(log)
    return VerilogRun(table, rise, fall, log)


def simulate_divider_verilog(starts, values, p_end, workdir=None, vcd=None) -> VerilogRun:
    """Run ``tb_pulse_divider.v`` with the cycle input ``values`` from posedges ``starts``."""
    import os
    import tempfile

    _need_iverilog()
    starts = np.asarray(starts, dtype=np.int64)
    values = np.asarray(values, dtype=np.int64)
    p_end = as_int("p_end", p_end, minimum=1)
    d = firmware_dir()
    with tempfile.TemporaryDirectory() as tmp:
        wd = workdir or tmp
        exe = os.path.join(wd, "tb_pulse_divider.vvp")
        stim = os.path.join(wd, "stim.txt")
        with open(stim, "w") as fh:
            for p, v in zip(starts, values):
                fh.write(f"{int(p)} {int(v)}\n")
        _run(
            [
                "iverilog",
                "-g2012",
                "-o",
                exe,
                str(d / "tb_pulse_divider.v"),
                str(d / "pulse_divider.v"),
            ],
            wd,
        )
        args = ["vvp", "-n", exe, f"+stim={stim}", f"+p_end={p_end}"]
        if vcd:
            args.append(f"+vcd={vcd}")
        log = _run(args, wd)
    _, rise, fall = _parse(log)
    return VerilogRun(None, rise, fall, log)


def read_vcd(path, signals):
    """Minimal VCD reader: ``{name: (times, values)}`` for the named signals.

    The first declaration of each name is used; values are ints (``x``/``z`` -> -1);
    times are in the file's timescale units.
    """
    path = as_path("path", path)
    if isinstance(signals, str) or not (
        hasattr(signals, "__iter__") and all(isinstance(n, str) for n in signals)
    ):
        raise ValueError(f"signals must be a list of signal names (str), got {signals!r}")
    ids = {}
    try:
        with open(path) as fh:
            text = fh.read()
    except FileNotFoundError:
        raise FileNotFoundError(f"path: no VCD file at {path}") from None
    except (UnicodeDecodeError, IsADirectoryError) as exc:
        raise ValueError(f"path: {path} is not a VCD text file ({exc})") from None
    if "$enddefinitions" not in text:
        raise ValueError(f"path: {path} is not a VCD file (no $enddefinitions)")
    head, _, body = text.partition("$enddefinitions")
    for line in head.split("$end"):
        p = line.split()
        if len(p) >= 5 and p[0] == "$var" and p[4] in signals and p[4] not in ids.values():
            ids[p[3]] = p[4]
    data = {name: ([], []) for name in signals}
    t = 0
    vector = None
    for tok in body.split():
        if tok[0] == "#":
            t = int(tok[1:])
        elif tok[0] in "bB":
            vector = tok[1:]
        elif vector is not None:
            if tok in ids:
                ts, vs = data[ids[tok]]
                ts.append(t)
                vs.append(int(vector, 2) if set(vector) <= {"0", "1"} else -1)
            vector = None
        elif tok[0] in "01xzXZ" and tok[1:] in ids:
            ts, vs = data[ids[tok[1:]]]
            ts.append(t)
            vs.append(int(tok[0]) if tok[0] in "01" else -1)
    return {
        name: (np.array(ts, dtype=np.int64), np.array(vs, dtype=np.int64))
        for name, (ts, vs) in data.items()
    }


# ---------------------------------------------------------------------- several axes (x–y stand)
#: speed (µm/s) at Yang's ``PWM_INITAL_COUNT`` in the paper's set-up: 144 µm/s (Yang eq. 7 at n = 300),
#: the slowest speed the paper's design emits (7 pulses/s at 20 µm per pulse)
PAPER_START_SPEED = paper_speed(PAPER["start_count"])


def _whole_ticks(x, tc):
    """``ceil(x / tc)``, a value within a relative 1e-9 of a whole number taken as that number."""
    r = x / tc
    n = round(r)
    return int(n) if abs(r - n) <= 1e-9 * max(1.0, r) else int(np.ceil(r))


def min_start_count(max_velocity, half_counts, min_speed):
    """Smallest counter ``n`` whose integer speed (Yang eqs. 5, 6) is ``>= min_speed`` µm/s.

    ``a / b = V / (2 N^2)`` in lowest terms; on the first half ``floor(a n^2 / b) >= s`` holds
    from ``n = ceil(sqrt(s b / a))`` on; above ``V / 2`` the second half
    ``V - floor(a (2N - n)^2 / b)`` is searched.  ``ValueError`` if ``min_speed > max_velocity``.
    """
    import math

    V = as_int("max_velocity", max_velocity, minimum=1)
    N = as_int("half_counts", half_counts, minimum=1)
    s = as_int("min_speed", min_speed, minimum=0)
    if s > V:
        raise ValueError(
            f"min_speed = {s} µm/s is above max_velocity = {V} µm/s: no count reaches it"
        )
    frac = Fraction(V, 2 * N * N)
    a, b = frac.numerator, frac.denominator
    n = math.isqrt((s * b + a - 1) // a)
    while n <= N and (a * n * n) // b < s:
        n += 1
    if n <= N:
        return n
    n = N + 1
    while V - (a * (2 * N - n) ** 2) // b < s:  # ends at n = 2N at the latest (speed V)
        n += 1
    return n


#: how far :func:`yang_axes` may move the common end tick ``M`` and each axis's ``N`` to find integer
#: speeds that fit the registers and the limits (ticks, counts)
YANG_TICK_SEARCH = 64
YANG_COUNT_SEARCH = 16


def _fitting_speed(dist, n, M, tc, step_um, bits, limits):
    """The integer peak speed nearest ``dist / ((M - 2n) tc)`` that fits and keeps the limits, or None.

    ``A_NUM n^2`` and ``B_DEN`` (``V / (2 n^2)`` in lowest terms) must fit ``bits``; the speeds
    tried lie within half a pulse of distance (``step_um / 2``) of the ideal one, nearest first,
    and must keep the axis's limits: ``V``, ``A = 2V/T = V/(n tc)``, ``J = 4V/T^2 = V/(n tc)^2``
    (relative 1e-12).
    """
    if 4 * n > M:
        return None
    top = 2**bits
    J, A, Vmax = limits
    slack = 1.0 + 1e-12
    span = (M - 2 * n) * tc  # T + cruise (s)
    vt = dist / span
    w = max(0.5, 0.5 * step_um / span)
    lo, hi = max(1, int(np.ceil(vt - w))), int(np.floor(vt + w))
    th = n * tc  # T / 2
    for v in sorted(range(lo, hi + 1), key=lambda x: (abs(x - vt), x)):
        f = Fraction(v, 2 * n * n)
        if (
            f.numerator * n * n < top
            and f.denominator < top
            and v <= Vmax * slack
            and v / th <= A * slack
            and v / (th * th) <= J * slack
        ):
            return v
    return None


def _choose_ticks(dists, counts, limits, M0, common, tc, step_um, bits):
    """``(M, [(N_i, V_i)])``: the first end tick ``M >= M0`` (and counts ``N_i >= counts[i]``, the
    same for every axis when ``common``) where every axis has a fitting integer speed."""
    for M in range(M0, M0 + YANG_TICK_SEARCH):
        if common:
            for dn in range(YANG_COUNT_SEARCH):
                n = counts[0] + dn
                vs = [
                    _fitting_speed(d, n, M, tc, step_um, bits, lim) for d, lim in zip(dists, limits)
                ]
                if all(v is not None for v in vs):
                    return M, [(n, v) for v in vs]
            continue
        out = []
        for d, n0, lim in zip(dists, counts, limits):
            for n in range(n0, n0 + YANG_COUNT_SEARCH):
                v = _fitting_speed(d, n, M, tc, step_um, bits, lim)
                if v is not None:
                    out.append((n, v))
                    break
            else:
                break
        if len(out) == len(dists):
            return M, out
    raise HardwareLimitError(
        f"no integer peak speeds near {[round(d / ((M0 - 2 * n) * tc), 1) for d, n in zip(dists, counts)]} "
        f"µm/s fit the {bits}-bit multiplier (A_NUM * N^2) and the axes' limits within {YANG_TICK_SEARCH} "
        f"ticks and {YANG_COUNT_SEARCH} counts: use another refresh_period"
    )


@dataclass(frozen=True)
class YangAxes:
    """Yang S-curve generators that run one synchronized multi-axis plan (:func:`yang_axes`).

    Attributes
    ----------
    generators : tuple of YangSCurve or None
        One per axis (``None``: the axis does not move, no pulses).
    directions : tuple of int
        ``+1``/``-1`` (the drive's direction input), ``0`` for a standstill.
    distances_um : tuple of float
        The plan's signed distances (µm).
    end_tick : int
        Refresh tick at which every generator's speed is back to 0 (``4 N_i + C_i``, the same for
        every axis).
    """

    generators: tuple
    directions: tuple
    distances_um: tuple
    end_tick: int

    def __len__(self):
        return len(self.generators)

    @property
    def end_posedge(self) -> int:
        """First posedge at which every generator's cycle input is 0 (``end_tick R + 1``)."""
        g = next(g for g in self.generators if g is not None)
        return self.end_tick * g.refresh_clocks + 1

    def default_p_end(self) -> int:
        """Last posedge to simulate: the end of the move plus two of the longest periods."""
        ends = []
        for g in self.generators:
            if g is not None:
                starts, values = g.cycle_input()
                ends.append(int(starts[-1] + 2 * int(values.max()) + 2))
        return max(ends)

    def pulses(self, p_end=None) -> tuple:
        """Each axis's :class:`PulseTrain` (the model, clock-exact; ``None`` for a standstill)."""
        p_end = self.default_p_end() if p_end is None else p_end
        return tuple(None if g is None else g.pulses(p_end) for g in self.generators)

    def positions(self, t, trains=None):
        """Signed commanded positions (µm), shape ``(n_axes,) + shape(t)``: ``direction * k * pulses``.

        ``trains``: pulse trains to count (default: :meth:`pulses`), e.g. rising edges from Verilog.
        """
        t = as_finite_array("t", t)
        trains = self.pulses() if trains is None else trains
        out = np.zeros((len(self.generators),) + t.shape)
        for i, (tr, s) in enumerate(zip(trains, self.directions)):
            if tr is not None:
                out[i] = s * tr.position(t)
        return out


def yang_axes(
    plan,
    refresh_period=PAPER["refresh_period"],
    clock_hz=PAPER["clock_hz"],
    step_um=PAPER["step_um"],
    start_count=None,
    bits=32,
) -> YangAxes:
    """Map a synchronized multi-axis S-curve plan (µm, s) to one Yang generator per axis.

    Yang's speed generator (Yang eqs. 5, 6) runs the linear-jerk S-curve *without* an
    acceleration plateau, fixed by three integers per axis: the peak speed ``V`` (µm/s), the
    counts per half acceleration ``N = T / (2 tc)`` and the cruise ticks ``C``; its move lasts
    ``4 N + C`` refresh ticks and covers ``V (2 N + C) tc`` µm.  The mapping:

    1. ``plan.planner`` must be ``"scurve"`` and no axis may have a plateau (``ta = 0``): phase
       synchronization gives every axis the phase times of the normalized path, time
       synchronization of a move whose accelerations stay below ``A`` stretches each axis without
       one (:func:`jerklab.multiaxis.stretch_to_duration`).
    2. Ticks, rounded up (a move never gets faster): ``N_i = ceil(tj_i / tc)``; the common end
       tick ``M = max(ceil(T / tc), 4 N_i)`` (``T`` the plan's duration); ``C_i = M - 4 N_i``.
       Every generator's speed is therefore 0 again from the same tick ``M`` on.  Under phase
       synchronization every axis has the same ``N`` and ``C``: the per-axis profile is the
       normalized one scaled by ``|d_i|`` -- the *scaled limits* ``J_n |d_i|``, ``A_n |d_i|``,
       ``V_n |d_i|``.
    3. ``V_i``: the integer nearest ``|d_i| / ((2 N_i + C_i) tc)`` (the ideal move then covers
       ``|d_i|`` within ``(2 N_i + C_i) tc / 2`` µm) among those whose integer form fits the
       registers (``A_NUM N_i^2 < 2^bits`` with ``A_NUM / B_DEN = V / (2 N^2)`` in lowest terms:
       the paper's ``V = 20000``, ``N = 2500`` give 1/625) and that keep the axis's limits
       (``V_i``, ``2 V_i / T_i``, ``4 V_i / T_i^2``, relative 1e-12), searched within half a pulse
       of distance.  If an axis has none, ``N_i`` grows (the same ``N`` for all axes under phase
       sync; up to ``YANG_COUNT_SEARCH`` = 16 counts), then ``M`` (up to ``YANG_TICK_SEARCH`` = 64
       ticks, 12.8 ms at 200 µs): a slightly slower move whose integers exist.  Else
       ``HardwareLimitError``.
    4. The direction (``sign d_i``) goes to the drive's direction input; the generator counts
       ``|d_i|``.
    5. ``start_count`` (Yang's ``PWM_INITAL_COUNT``): ``None`` takes, per axis, the first count
       whose speed reaches the paper's start speed ``PAPER_START_SPEED`` (144 µm/s, Yang eq. 7 at
       n = 300; at least ``step_um``, 1 pulse/s): 300 for the paper's axis.  A slower axis then
       starts later in its ramp instead of with a longer first pulse period, during which the
       latched divider emits nothing (``1 / f`` at the start speed).  Symmetrically, every
       generator falls silent when its deceleration passes the start count, ``n0_i`` ticks before
       ``M``: an axis whose peak speed is near the start speed (say below 300 µm/s) stops its
       pulses that much earlier than the others (``tests/test_multiaxis.py``).

    Parameters
    ----------
    plan : jerklab.multiaxis.MultiAxisPlan
        Distances in µm, times in s.
    refresh_period, clock_hz, step_um, bits
        As :class:`YangSCurve` (the same for every axis: one clock, one refresh prescaler).
    start_count : int or None
        Start count for every axis, or ``None`` (see 5.).

    Returns
    -------
    YangAxes

    Raises
    ------
    ValueError
        A plan of another planner or with an acceleration plateau; ``HardwareLimitError``
        when an axis does not fit the registers (see :class:`YangSCurve`).
    """
    if not isinstance(plan, MultiAxisPlan):
        raise ValueError(
            f"plan must be a jerklab.multiaxis.MultiAxisPlan, got {type(plan).__name__}"
        )
    if plan.planner != "scurve":
        raise ValueError(
            f"plan.planner must be 'scurve' (Yang eq. 5 is a linear-jerk S-curve), "
            f"got {plan.planner!r}"
        )
    tc = as_positive("refresh_period", refresh_period)
    if start_count is not None:
        start_count = as_int("start_count", start_count, minimum=0)
    rows = []
    for i, (p, d) in enumerate(zip(plan.axes, plan.distances)):
        if d == 0.0:
            rows.append(None)
            continue
        tj, ta, _, tv = p.phase_times[:4]
        if ta > 1e-9 * tj:
            raise ValueError(
                f"plan axis {i} has an acceleration plateau (ta = {ta!r} s): Yang's generator "
                f"(Yang eqs. 5, 6) has none; raise that axis's max_accel to "
                f"sqrt(max_jerk * max_velocity) or more"
            )
        rows.append(max(_whole_ticks(tj, tc), 1))
    if all(r is None for r in rows):
        raise ValueError("plan moves no axis: nothing for the generators to do")
    moving = [i for i, r in enumerate(rows) if r is not None]
    counts = [rows[i] for i in moving]
    M0 = max([_whole_ticks(plan.duration, tc)] + [4 * n for n in counts])
    for i in moving:
        if abs(float(plan.distances[i])) / ((M0 - 2 * rows[i]) * tc) < 0.5:
            raise HardwareLimitError(
                f"axis {i}: distance {float(plan.distances[i])!r} µm over "
                f"{M0 * tc!r} s needs a peak speed below 1 µm/s, the resolution of "
                f"max_velocity"
            )
    M, chosen = _choose_ticks(
        [abs(float(plan.distances[i])) for i in moving],
        counts,
        [plan.limits[i] for i in moving],
        M0,
        plan.sync == "phase",
        tc,
        step_um,
        bits,
    )
    gens, dirs = [None] * len(rows), [0] * len(rows)
    for i, (N, V) in zip(moving, chosen):
        C = M - 4 * N
        if start_count is None:
            n0 = min_start_count(V, N, min(max(PAPER_START_SPEED, step_um), V))
        else:
            n0 = min(start_count, 2 * N)
        gens[i] = YangSCurve(
            V,
            accel_time=2 * N * tc,
            cruise_time=C * tc,
            refresh_period=tc,
            clock_hz=clock_hz,
            step_um=step_um,
            start_count=n0,
            bits=bits,
        )
        dirs[i] = 1 if plan.distances[i] > 0 else -1
    return YangAxes(tuple(gens), tuple(dirs), tuple(float(x) for x in plan.distances), M)


def simulate_verilog_xy(axes: YangAxes, p_end=None, workdir=None, vcd=None):
    """Run ``firmware/fpga/tb_xy.v``: the two generators + dividers of an x–y :class:`YangAxes`.

    Returns
    -------
    (VerilogRun, VerilogRun)
        x and y: per-tick speed tables and edges, as :func:`simulate_verilog` (same posedge
        numbering), to compare with ``axes.generators[i]`` bit for bit.
    """
    import tempfile

    if not isinstance(axes, YangAxes) or len(axes) != 2 or any(g is None for g in axes.generators):
        raise ValueError("axes must be a YangAxes of two moving axes (x and y)")
    _need_iverilog()
    p_end = axes.default_p_end() if p_end is None else as_int("p_end", p_end, minimum=1)
    d = firmware_dir()
    with tempfile.TemporaryDirectory() as tmp:
        wd = workdir or tmp
        exe = f"{wd}/tb_xy.vvp"
        params = [
            f"-Ptb_xy.{ax}_{k}={v}"
            for ax, g in zip("XY", axes.generators)
            for k, v in g.verilog_defines().items()
        ]
        params.append(f"-Ptb_xy.P_END={p_end}")
        _run(
            [
                "iverilog",
                "-g2012",
                "-o",
                exe,
                *params,
                str(d / "tb_xy.v"),
                str(d / "scurve_gen.v"),
                str(d / "pulse_divider.v"),
            ],
            wd,
        )
        log = _run(["vvp", "-n", exe] + ([f"+vcd={vcd}"] if vcd else []), wd)
    runs = []
    for ax in "XY":
        lines = [ln[0] + ln[2:] for ln in log.splitlines() if ln[:2] in (f"S{ax}", f"E{ax}")]
        table, rise, fall = _parse("\n".join(lines))
        runs.append(VerilogRun(table, rise, fall, log))
    return tuple(runs)
