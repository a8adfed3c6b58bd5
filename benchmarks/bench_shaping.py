"""Benchmark of jerklab.shaping against peers in the same process.

1. Shaper design (µs): closed forms (ZV … ZVDD, MZV) and the EI family (Singhose's conditions
   solved numerically for ζ > 0, cached: "cold" clears the cache), against a generic
   numerical design of the same shaper (scipy.optimize.fsolve on the zero-vibration equations).
2. A 1000-point sensitivity curve (µs) against scipy.signal.freqz of the digitized FIR taps on
   the same 1000 frequencies (the same quantity at ζ = 0, up to the digitization).
3. The robust time-optimal LP move of the flexible motor (ms): the default (NNLS screen of the
   horizons, one HiGHS LP) against an LP at every horizon and against scipy.optimize.lsq_linear
   (BVLS, Xu & Meckl eq. 6 literally) — the same horizons.
4. identify_mode on an 8 s chirp record (ms), for the record.
"""

from __future__ import annotations

import math
import time

import numpy as np
from scipy.optimize import fsolve
from scipy.signal import freqz

from benchmarks._record import table as record_table
from jerklab import shaping
from jerklab.plant import FlexibleDCMotor


def _best_time(fn, repeat=7, number=1):
    ts = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        for _ in range(number):
            fn()
        ts.append((time.perf_counter() - t0) / number)
    return float(min(ts))


def _generic_design(n_impulses, f, zeta):
    """A generic ZV/ZVD design: unknown amplitudes and times, V and its derivatives zero at f."""
    w = 2 * math.pi * f
    wd = w * math.sqrt(1 - zeta**2)
    n = n_impulses

    def eqs(x):
        A, t = x[:n], np.r_[0.0, x[n:]]
        out = [A.sum() - 1]
        for j in range(n - 1):
            c = (A * t**j * np.exp(zeta * w * t) * np.exp(1j * wd * t)).sum()
            out += [c.real, c.imag]
        return out[: 2 * n - 1]

    x0 = np.r_[np.full(n, 1 / n), 0.5 / f * np.arange(1, n)]
    return fsolve(eqs, x0, xtol=1e-12)


def main():
    f, zeta = 8.0, 0.03
    rows = []
    for kind, n in (
        ("zv", 2),
        ("zvd", 3),
        ("zvdd", 4),
        ("mzv", None),
        ("ei", None),
        ("2hump_ei", None),
        ("3hump_ei", None),
    ):
        warm = _best_time(lambda: shaping.input_shaper(kind, f, zeta), number=200)
        if kind in ("ei", "2hump_ei", "3hump_ei"):

            def cold():
                shaping._ei_design.cache_clear()
                shaping.input_shaper(kind, f, zeta)

            cold_t = _best_time(cold, repeat=3)
            peer, peer_name = cold_t, "uncached (ours)"
        else:
            peer = _best_time(lambda: _generic_design(n, f, zeta), number=20) if n else math.nan
            peer_name = "fsolve generic" if n else "—"
        rows.append((kind, 1e6 * warm, peer_name, 1e6 * peer, peer / warm))
    record_table(
        "Shaper design (µs), warm, against a generic numerical design (fsolve) or our uncached EI solve",
        ["shaper", "ours µs", "peer", "peer µs", "peer/ours"],
        rows,
    )

    ratios = np.linspace(0.5, 1.5, 1000)
    Ts = 1e-4
    rows = []
    for kind in shaping.KINDS:
        s = shaping.input_shaper(kind, f, 0.0)
        h = s.fir(Ts)
        wT = 2 * math.pi * f * ratios * Ts
        ours = _best_time(lambda: s.sensitivity_curve(ratios), number=20)
        peer = _best_time(lambda: freqz(h, worN=wT), number=20)
        diff = np.abs(100 * np.abs(freqz(h, worN=wT)[1]) - s.sensitivity_curve(ratios)).max()
        rows.append((kind, 1e6 * ours, 1e6 * peer, peer / ours, diff))
    record_table(
        "1000-point sensitivity curve (µs) against scipy.signal.freqz of the FIR taps (Ts = 0.1 ms, ζ = 0)",
        ["shaper", "ours µs", "freqz µs", "peer/ours", "max diff %"],
        rows,
        note="max diff: the digitization of the impulse times to 0.1 ms",
    )

    model = FlexibleDCMotor().ideal()
    rows = []
    for order in (0, 1, 2):
        n = {
            s_: shaping.robust_move(1.0, model, 0.005, order=order, solver=s_).u.size
            for s_ in ("lp", "highs", "lsq")
        }
        ts = {
            s_: _best_time(
                lambda s_=s_: shaping.robust_move(1.0, model, 0.005, order=order, solver=s_),
                repeat=3,
            )
            for s_ in ("lp", "highs", "lsq")
        }
        rows.append(
            (
                f"order {order}",
                "N " + "/".join(str(v) for v in n.values()),
                1e3 * ts["lp"],
                1e3 * ts["highs"],
                1e3 * ts["lsq"],
                ts["highs"] / ts["lp"],
                ts["lsq"] / ts["lp"],
            )
        )
    record_table(
        "Robust time-optimal LP move of FlexibleDCMotor (ms, 1 rad, Ts = 5 ms): default (NNLS screen + one "
        "HiGHS LP) against an LP at every horizon and scipy.optimize.lsq_linear (BVLS)",
        [
            "case",
            "horizons lp/highs/lsq",
            "default ms",
            "HiGHS ms",
            "BVLS ms",
            "HiGHS/default",
            "BVLS/default",
        ],
        rows,
    )

    m = FlexibleDCMotor(
        load_ratio=0.15,
        mode_frequency=2 * math.pi * 8.0,
        mode_damping=0.02,
        noise_std=0.002,
        seed=1,
    )
    u = shaping.chirp_input(8.0, 0.005, 3.0, 1.0, 30.0)
    _, y = m.open_loop(u, 0.005)
    t_id = _best_time(lambda: shaping.identify_mode(u, y, 0.005), repeat=3)
    fit = shaping.identify_mode(u, y, 0.005)
    record_table(
        "identify_mode on an 8 s chirp (1600 samples, 448 counts/rev, 2 mrad noise)",
        ["case", "ms", "f Hz", "se Hz", "zeta", "se", "shaper"],
        [
            (
                "two-mass OE fit",
                1e3 * t_id,
                fit.frequency_hz,
                fit.frequency_se,
                fit.damping,
                fit.damping_se,
                fit.shaper.kind,
            )
        ],
    )


if __name__ == "__main__":
    main()
