"""Input shapers, jerk profiles as implicit shapers, and robust command shaping on a flexible load.

One question across the three papers: a move must end without ringing. An *input shaper*
convolves the reference with a few impulses whose vibrations cancel at a mode (Singer &
Seering 1990; Singhose, Seering & Singer 1994/1997); Xu & Meckl place zeros of the whole
command on the mode, robustly (Xu & Meckl eqs. 8, 13); a smooth jerk profile
(Stojčić eq. 2, Yang's S-curve) is itself a convolution of boxes and pulses, so it has
spectral zeros too (ASCII spelling for grep: Stojcic).

Residual vibration (the measure used everywhere in this module)
---------------------------------------------------------------
A command is read as a *density* ``g(t)`` of total weight 1 on ``[0, T]``: the impulses of a
shaper (amplitudes summing to 1), the velocity of a profile divided by the distance, or a
voltage sequence divided by its sum (a voltage impulse moves the motor by a step). A
lightly damped mode ``s = −ζω ± jω_d`` (``ω_d = ω√(1−ζ²)``) is left ringing after ``T`` with the
amplitude, relative to the ringing a step of the same size would leave at ``T``::

    V(ω, ζ) = | ∫ g(t) exp((ζω + jω_d)(t − T)) dt |        (× 100 for percent)

which for impulses ``A_i`` at ``t_i`` is Singer & Seering's percentage residual vibration
``e^{−ζω t_n} |Σ A_i e^{ζω t_i} e^{jω_d t_i}|``. The shaper's design damping and the plant's
damping may differ: ``residual_vibration(f, ζ)`` evaluates the plant at ``(f, ζ)``.

Which shaper definitions (stated exactly)
-----------------------------------------
``T_d = 1/(f √(1−ζ²))`` is the damped period, ``K = exp(−ζπ/√(1−ζ²))``.

* ZV: ``A = [1, K]/(1+K)`` at ``[0, T_d/2]`` (Singer & Seering).
* ZVD: ``A = [1, 2K, K²]/(1+K)²`` at ``[0, T_d/2, T_d]``; ZVDD: ``[1, 3K, 3K², K³]/(1+K)³``
  at ``[0, T_d/2, T_d, 3T_d/2]`` (Singer & Seering: the derivatives of V vanish too).
* MZV: three equally spaced impulses at ``[0, 3T_d/8, 3T_d/4]`` whose z-polynomial has its
  zero on the mode: ``A ∝ [1, √2 K', K'²]``, ``K' = exp(−3ζπ/(4√(1−ζ²)))`` (the same impulse
  times and zero placement as Klipper's ``mzv``; derived here, not copied).
* EI, 2-hump EI, 3-hump EI (Singhose, Seering & Singer 1997, "extra-insensitive"): ``m + 2``
  impulses whose vibration curve has ``m`` humps of height exactly ``vtol`` (default 5 %,
  Klipper's choice) with zero slope, and ``m + 1`` zeros between and beside them; the middle
  feature (the hump for odd m, the zero for even m) sits at the design frequency. For
  ``ζ = 0`` these are Singhose's closed forms (checked in the tests); for ``ζ > 0`` the same
  conditions are solved numerically (Newton from the undamped solution, continued in ζ) with
  the plant damping equal to the design damping. Klipper instead uses Singhose's curve fits
  in ζ and reports widths covering ζ ≈ 0.05–0.2 around its default 0.1, so its numbers are
  approximate; :func:`insensitivity_table` reproduces its table within a few points.

Digitization on a sample grid (``InputShaper.fir``)
---------------------------------------------------
An impulse at ``t = (k + α) Ts`` (``0 <= α < 1``) is split linearly between the samples ``k`` and
``k + 1``: weights ``(1 − α) A`` and ``α A``. This is exactly delaying the reference by ``t`` with
linear interpolation between its samples; the taps sum to 1 and the first moment (the mean
delay) is preserved exactly; the residual this leaves is reported by
``InputShaper.digitized(Ts).residual_vibration(...)`` (it is small while ``f Ts`` is small:
the split acts as a short triangular low-pass). The firmware runs the same taps.

References
----------
N. C. Singer, W. P. Seering, "Preshaping command inputs to reduce system vibration",
J. Dyn. Sys. Meas. Control 112 (1990). W. Singhose, W. Seering, N. Singer, "Residual vibration
reduction using vector diagrams to generate shaped inputs", J. Mech. Design 116 (1994).
W. Singhose, S. Derezinski, N. Singer, "Extra-insensitive input shapers for controlling
flexible spacecraft", J. Guidance Control Dyn. 19 (1996). Klipper, docs/Resonance_Compensation.md
(the table of insensitivity widths) and klippy/extras/shaper_defs.py (its definitions).
Xu & Meckl, robust time-optimal command shaping (Xu & Meckl eqs. 3, 5, 13, 19).
"""

from __future__ import annotations

import functools
import math
import re
from dataclasses import dataclass, field, fields

import numpy as np
from scipy.optimize import brentq, fsolve

from jerklab import paper, piezo, planner
from jerklab._validate import as_finite_array, as_int, as_nonnegative, as_positive, as_real
from jerklab.ident.mode import ModeEstimate, coupled_mode
from jerklab.ident.mode import identify_mode as _identify_mode
from jerklab.planner import Profile
from jerklab.plant import FlexibleDCMotor

__all__ = [
    "KINDS",
    "InputShaper",
    "input_shaper",
    "residual_vibration_of",
    "insensitivity_table",
    "chirp_input",
    "ModeFit",
    "identify_mode",
    "profile_residual_vibration",
    "tuned_profile",
    "move_time_comparison",
    "RobustMove",
    "robust_move_rows",
    "robust_move",
    "energy_optimal_move",
    "Tradeoff",
    "tradeoff",
    "residual_amplitude",
    "flexible_mode",
]

#: the shaper kinds, in order of duration (aliases are accepted: "2-hump EI", "EI3", ...)
KINDS = ("zv", "mzv", "zvd", "zvdd", "ei", "2hump_ei", "3hump_ei")

_ALIASES = {
    "zv": "zv",
    "mzv": "mzv",
    "zvd": "zvd",
    "zvdd": "zvdd",
    "ei": "ei",
    "2hump_ei": "2hump_ei",
    "2humpei": "2hump_ei",
    "ei2": "2hump_ei",
    "2ei": "2hump_ei",
    "twohumpei": "2hump_ei",
    "3hump_ei": "3hump_ei",
    "3humpei": "3hump_ei",
    "ei3": "3hump_ei",
    "3ei": "3hump_ei",
    "threehumpei": "3hump_ei",
}

#: the largest design damping of the EI family (Klipper's limits in shaper_defs.py: above them the
#: humps of the vibration curve merge)
EI_MAX_DAMPING = {"ei": 0.4, "2hump_ei": 0.3, "3hump_ei": 0.2}

#: Klipper's and Singhose's vibration tolerance of the EI family (5 %: "vibration reduction 20x")
DEFAULT_VTOL = 0.05


def _kind(kind) -> str:
    if not isinstance(kind, str):
        raise TypeError(
            f"kind must be a str such as 'zvd' or '2-hump EI', got {type(kind).__name__}"
        )
    key = re.sub(r"[\s\-]+", "", kind.strip().lower())
    key2 = key.replace("_", "")
    for k in (key, key2):
        if k in _ALIASES:
            return _ALIASES[k]
    raise ValueError(
        f"kind must be one of {', '.join(KINDS)} (case-insensitive; '2-hump EI' style "
        f"aliases accepted), got {kind!r}"
    )


def _damping(name, zeta) -> float:
    zeta = as_nonnegative(name, zeta)
    if zeta >= 1.0:
        raise ValueError(f"{name} must be < 1 (an underdamped mode), got {zeta!r}")
    return zeta


# ----------------------------------------------------------------------------------------------
# residual vibration of impulses
# ----------------------------------------------------------------------------------------------
def _v_impulses(A, t, w, zeta):
    """V(ω) for impulses (A, t) on modes of natural frequency ``w`` (rad/s, array), damping ζ."""
    w = np.asarray(w, dtype=float)
    sig = zeta * w[..., None] + 1j * w[..., None] * math.sqrt(1.0 - zeta * zeta)
    return np.abs(np.exp(sig * (t - t[-1])) @ A)


def residual_vibration_of(amplitudes, times, frequency_hz, damping=0.0):
    """Percentage residual vibration of the impulses ``amplitudes`` at ``times`` (s).

    Singer & Seering's ``100 e^{−ζω t_n} |Σ A_i e^{ζω t_i} e^{jω_d t_i}|`` on a mode of
    ``frequency_hz`` (natural, Hz; scalar or array) and ``damping`` ζ. Amplitudes need not be
    normalized (a command of any sign); the value is relative to their sum.
    """
    A = as_finite_array("amplitudes", amplitudes, ndim=1)
    t = as_finite_array("times", times, ndim=1)
    if A.shape != t.shape or A.size == 0:
        raise ValueError(
            f"amplitudes and times must have the same non-zero length, got {A.size}, {t.size}"
        )
    s = A.sum()
    if s == 0:
        raise ValueError("amplitudes must not sum to 0 (the command would move nothing)")
    f = as_finite_array("frequency_hz", frequency_hz)
    if np.any(f <= 0):
        raise ValueError(f"frequency_hz must be positive and finite, got {frequency_hz!r}")
    zeta = _damping("damping", damping)
    order = np.argsort(t, kind="stable")
    v = 100.0 * _v_impulses(A[order] / s, t[order], 2 * math.pi * f, zeta)
    return float(v) if np.ndim(frequency_hz) == 0 else v


#: the largest frequency ratio searched for the edge of an insensitivity band
_R_MAX = 3.0


def _band(curve, tolerance, r_max=_R_MAX):
    """``(low, high)`` ratios around the zero of ``curve(r)`` (percent) nearest r = 1 where the
    curve stays <= ``tolerance`` (humps of exactly ``tolerance`` inside); ``(nan, nan)`` if that
    band does not hold r = 1."""
    tol = as_positive("tolerance", tolerance)
    if tol >= 100:
        raise ValueError(f"tolerance is in percent and must be < 100, got {tolerance!r}")
    lim = tol * (1 + 1e-7)
    r = np.linspace(0.05, r_max, int(round((r_max - 0.05) * 2000)) + 1)
    vv = curve(r)
    mins = np.flatnonzero((vv[1:-1] <= vv[:-2]) & (vv[1:-1] <= vv[2:])) + 1
    i0 = int(mins[np.argmin(np.abs(r[mins] - 1.0))]) if mins.size else int(np.argmin(np.abs(r - 1)))
    if vv[i0] > lim:
        return (math.nan, math.nan)
    edges = []
    for step in (-1, 1):
        i = i0
        while 0 < i < r.size - 1 and vv[i + step] <= lim:
            i += step
        if i in (0, r.size - 1):
            edges.append(float(r[i]))
        else:
            edges.append(
                brentq(
                    lambda x: float(curve(np.array([x]))[0]) - tol, r[i], r[i + step], xtol=1e-10
                )
            )
    lo, hi = sorted(edges)
    if not lo <= 1.0 <= hi:  # the band must hold the nominal mode
        return (math.nan, math.nan)
    return (lo, hi)


# ----------------------------------------------------------------------------------------------
# EI family: numerical design from Singhose's conditions
# ----------------------------------------------------------------------------------------------
def _ei_undamped(m, V):
    """Singhose's closed-form undamped EI (m = 1), 2-hump (m = 2), 3-hump (m = 3), times in periods."""
    if m == 1:
        A = [(1 + V) / 4, (1 - V) / 2, (1 + V) / 4]
    elif m == 2:
        X = (V * V * (math.sqrt(1 - V * V) + 1)) ** (1 / 3)
        a1 = (3 * X * X + 2 * X + 3 * V * V) / (16 * X)
        A = [a1, 0.5 - a1, 0.5 - a1, a1]
    else:
        a1 = (1 + 3 * V + 2 * math.sqrt(2 * V * (V + 1))) / 16
        a2 = (1 - V) / 4
        A = [a1, a2, 1 - 2 * (a1 + a2), a2, a1]
    return np.array(A), 0.5 * np.arange(m + 2)


def _features(A, t, zeta, m):
    """Frequencies (ratio to 1 Hz) of the m + 1 zeros and m humps of V nearest the design."""
    r = np.linspace(0.2, 1.8, 8001)
    v = _v_impulses(A, t, 2 * math.pi * r, zeta)
    mins = [i for i in range(1, r.size - 1) if v[i] <= v[i - 1] and v[i] < v[i + 1]]
    maxs = [i for i in range(1, r.size - 1) if v[i] >= v[i - 1] and v[i] > v[i + 1]]
    mins = sorted(sorted(mins, key=lambda i: abs(r[i] - 1))[: m + 1])
    maxs = [i for i in maxs if r[mins[0]] < r[i] < r[mins[-1]]]
    return r[mins], r[maxs]


@functools.lru_cache(maxsize=256)
def _ei_design(m: int, zeta: float, V: float):
    """Amplitudes and times (in periods of the design frequency, 1 Hz) of the m-hump EI shaper."""
    A0, t0 = _ei_undamped(m, V)
    zr, hr = _features(A0, t0, 0.0, m)
    if zeta == 0.0:
        return A0, t0
    n = m + 2
    x = np.concatenate([A0, t0[1:], zr, hr])
    h = 1e-6

    def eqs(x, z):
        A, tt = x[:n], np.concatenate([[0.0], x[n : 2 * n - 1]])
        zr, hr = x[2 * n - 1 : 2 * n + m], x[2 * n + m :]
        wd = math.sqrt(1 - z * z)
        out = [A.sum() - 1.0]
        for r in zr:
            c = np.exp(2 * math.pi * r * (z + 1j * wd) * (tt - tt[-1])) @ A
            out += [c.real, c.imag]

        def vv(rr):
            return abs(np.exp(2 * math.pi * rr * (z + 1j * wd) * (tt - tt[-1])) @ A)

        for r in hr:
            out += [vv(r) - V, (vv(r + h) - vv(r - h)) / (2 * h)]
        mid = hr[(m - 1) // 2] if m % 2 == 1 else zr[m // 2]
        out.append(mid - 1.0)
        return out

    # continuation in ζ from the undamped solution, the step halved where Newton fails
    z_now, dz, msg = 0.0, 0.02, ""
    while z_now < zeta:
        z_try = min(zeta, z_now + dz)
        sol, info, ier, msg = fsolve(eqs, x, args=(z_try,), full_output=True, xtol=1e-12)
        if np.max(np.abs(eqs(sol, z_try))) <= 1e-9 and np.all(sol[:n] > 0):
            x, z_now, dz = sol, z_try, min(1.5 * dz, 0.05)
        else:
            dz /= 2
            if dz < 1e-4:
                raise ValueError(
                    f"damping = {zeta!r}: the {m}-hump EI conditions have no solution near "
                    f"the undamped one ({msg.strip()})"
                )
    A, tt = x[:n], np.concatenate([[0.0], x[n : 2 * n - 1]])
    if np.any(A <= 0) or np.any(np.diff(tt) <= 0):
        raise ValueError(f"damping = {zeta!r}: the {m}-hump EI design loses positive amplitudes")
    return A, tt


# ----------------------------------------------------------------------------------------------
# the shaper object
# ----------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class InputShaper:
    """Impulses ``amplitudes`` (sum 1) at ``times`` (s, first 0) designed for a mode.

    Attributes
    ----------
    kind : str
        One of :data:`KINDS` (``"fir"`` for a digitized shaper, ``"custom"`` otherwise).
    frequency_hz, damping : float
        The design mode (natural frequency, Hz, and damping ratio).
    amplitudes, times : ndarray
        The impulses; ``times[0] == 0``, increasing.
    """

    kind: str
    frequency_hz: float
    damping: float
    amplitudes: np.ndarray = field(repr=False)
    times: np.ndarray = field(repr=False)

    def __post_init__(self):
        A = as_finite_array("amplitudes", self.amplitudes, ndim=1)
        t = as_finite_array("times", self.times, ndim=1)
        if A.size == 0 or A.shape != t.shape:
            raise ValueError("amplitudes and times must have the same non-zero length")
        if abs(A.sum() - 1.0) > 1e-9:
            raise ValueError(f"amplitudes must sum to 1, got {A.sum()!r}")
        if t[0] != 0.0 or np.any(np.diff(t) <= 0):
            raise ValueError("times must start at 0 and increase")
        A.setflags(write=False)
        t.setflags(write=False)
        object.__setattr__(self, "amplitudes", A)
        object.__setattr__(self, "times", t)

    @classmethod
    def _trusted(cls, kind, frequency_hz, damping, amplitudes, times):
        """A shaper from this module's own designs (already checked): no re-validation."""
        obj = object.__new__(cls)
        amplitudes.setflags(write=False)
        times.setflags(write=False)
        for name, value in (
            ("kind", kind),
            ("frequency_hz", frequency_hz),
            ("damping", damping),
            ("amplitudes", amplitudes),
            ("times", times),
        ):
            object.__setattr__(obj, name, value)
        return obj

    @property
    def duration(self) -> float:
        """Time from the first to the last impulse (s): the delay the shaper adds to a move."""
        return float(self.times[-1])

    def residual_vibration(self, frequency_hz, damping=None):
        """Percentage residual vibration on a mode ``(frequency_hz, damping)`` (Singer & Seering).

        ``damping`` defaults to the design damping; ``frequency_hz`` may be an array.
        """
        zeta = self.damping if damping is None else damping
        return residual_vibration_of(self.amplitudes, self.times, frequency_hz, zeta)

    def sensitivity_curve(self, ratios, damping=None):
        """Residual vibration (%) at ``ratios`` × the design frequency (the classic robustness plot).

        ``damping`` is the plant's (default: the design damping); a sequence of dampings gives
        the worst case over them at each ratio (a plant whose damping is only known to lie in a
        range, the reading of Klipper's table).
        """
        r = as_finite_array("ratios", ratios, ndim=1)
        if np.any(r <= 0):
            raise ValueError("ratios must be positive")
        w = 2 * math.pi * self.frequency_hz * r
        if damping is not None and np.ndim(damping) == 1:
            zs = [_damping("damping", z) for z in damping]
            if not zs:
                raise ValueError("damping must not be an empty sequence")
            return 100.0 * np.max(
                [_v_impulses(self.amplitudes, self.times, w, z) for z in zs], axis=0
            )
        zeta = self.damping if damping is None else _damping("damping", damping)
        return 100.0 * _v_impulses(self.amplitudes, self.times, w, zeta)

    def insensitivity(self, tolerance=5.0, damping=None, hz=False):
        """The frequency band around the design in which the vibration stays <= ``tolerance`` %.

        Starting from the zero of the vibration curve nearest the design frequency, the band
        grows both ways until the curve exceeds ``tolerance`` (humps of exactly ``tolerance``,
        as the EI shapers have by design, stay inside). Returns ``(low, high)`` as ratios to the
        design frequency (``hz=False``, e.g. ``(0.85, 1.15)`` is "±15 %") or in Hz.

        Parameters
        ----------
        tolerance : float
            Vibration tolerance in percent (0 < tolerance < 100); 5 means 5 %.
        damping : float or sequence of float, optional
            Plant damping (default: the design damping); a sequence: the worst case over those
            dampings (e.g. ``np.linspace(0.05, 0.2, 7)`` for a shaper designed at 0.1, which is
            how Klipper's table reads: its ZVD row ±15 %/±22 % comes out exactly so).
        """
        zeta = self.damping if damping is None else damping
        lo, hi = _band(lambda r: self.sensitivity_curve(r, zeta), tolerance)
        f0 = self.frequency_hz
        return (lo * f0, hi * f0) if hz else (lo, hi)

    # --- sampled references -------------------------------------------------------------------
    def fir(self, Ts):
        """FIR taps on the grid ``Ts`` that :meth:`apply` uses (the firmware runs the same taps).

        Each impulse at ``t = (k + α) Ts`` is split linearly: ``(1 − α) A`` on tap ``k`` and
        ``α A`` on tap ``k + 1`` (delay by linear interpolation). The taps sum to 1; their mean
        delay ``Σ k h_k Ts`` equals ``Σ A_i t_i`` exactly.
        """
        Ts = as_positive("Ts", Ts)
        pos = self.times / Ts
        k = np.floor(pos + 1e-9).astype(int)
        a = np.clip(pos - k, 0.0, 1.0)
        a[a < 1e-9] = 0.0
        n = int(k[-1]) + (2 if a[-1] > 0 else 1)
        if n > 1_000_000:
            raise ValueError(
                f"Ts = {Ts!r} s gives {n} taps for a {self.duration:g} s shaper (too many)"
            )
        h = np.zeros(n)
        np.add.at(h, k, self.amplitudes * (1 - a))
        np.add.at(h, np.minimum(k + 1, n - 1), self.amplitudes * a)
        return h

    def fir_fixed(self, Ts, frac_bits=15):
        """:meth:`fir` in fixed point for a microcontroller: integer taps summing to exactly
        ``2**frac_bits`` (largest-remainder rounding: each tap within one unit of ``2**frac_bits·h``),
        so a shaped move still ends exactly on its target. Returns an ``int64`` array."""
        b = as_int("frac_bits", frac_bits, minimum=1)
        if b > 30:
            raise ValueError(f"frac_bits must be <= 30, got {b}")
        h = self.fir(Ts) * (1 << b)
        q = np.floor(h).astype(np.int64)
        short = (1 << b) - int(q.sum())
        if short > 0:
            order = np.argsort(-(h - q), kind="stable")
            q[order[:short]] += 1
        return q

    def apply_fixed(self, reference, Ts, frac_bits=15, extend=True):
        """Integer shaping, the reference arithmetic for the firmware: for integer references
        (encoder counts) ``y[n] = floor((Σ_j q_j r[n−j] + 2**(frac_bits−1)) / 2**frac_bits)`` with the
        taps ``q`` of :meth:`fir_fixed` (round half up; the same history and extension rules as
        :meth:`apply`). Exact in int64 while ``|r| < 2**(62 − frac_bits)``."""
        r = np.asarray(reference)
        if r.ndim != 1 or r.size == 0 or r.dtype.kind not in "iu":
            raise ValueError("reference must be a non-empty 1-D array of integers (counts)")
        r = r.astype(np.int64)
        q = self.fir_fixed(Ts, frac_bits)
        b = int(frac_bits)
        if np.abs(r).max() >= 1 << (62 - b):
            raise ValueError(f"reference is too large for int64 arithmetic with frac_bits = {b}")
        n = q.size - 1
        x = np.concatenate([np.full(n, r[0]), r, np.full(n if extend else 0, r[-1])])
        m = r.size + (n if extend else 0)
        acc = np.zeros(m, dtype=np.int64)
        for j in np.flatnonzero(q):
            acc += q[j] * x[n - j : n - j + m]
        return (acc + (1 << (b - 1))) >> b

    def digitized(self, Ts) -> "InputShaper":
        """The shaper that :meth:`apply` really applies on the grid ``Ts``: the FIR taps as impulses
        at ``k Ts`` (to check its residual vibration honestly)."""
        h = self.fir(Ts)
        nz = np.flatnonzero(h)
        t = nz * as_positive("Ts", Ts)
        return InputShaper("fir", self.frequency_hz, self.damping, h[nz] / h[nz].sum(), t - t[0])

    def apply(self, reference, Ts, extend=True):
        """Shape a sampled reference: convolve it with :meth:`fir` taps.

        Before its first sample the reference is taken to rest at ``reference[0]``; with
        ``extend=True`` (default) it is held at ``reference[-1]`` after its last sample and the
        result is longer by ``len(fir(Ts)) − 1`` samples (the shaper's delay), so a move ends
        exactly where the reference ends; ``extend=False`` returns ``len(reference)`` samples.
        """
        r = as_finite_array("reference", reference, ndim=1)
        if r.size == 0:
            raise ValueError("reference must not be empty")
        h = self.fir(Ts)
        n = h.size - 1
        x = np.concatenate([np.full(n, r[0]), r, np.full(n if extend else 0, r[-1])])
        m = r.size + (n if extend else 0)
        y = np.zeros(m)
        for j in np.flatnonzero(h):  # at most two taps per impulse: a sparse FIR
            y += h[j] * x[n - j : n - j + m]
        return y


def _closed_form(kind, f, zeta):
    df = math.sqrt(1.0 - zeta * zeta)
    Td = 1.0 / (f * df)
    K = math.exp(-zeta * math.pi / df)
    if kind in ("zv", "zvd", "zvdd"):
        n = {"zv": 1, "zvd": 2, "zvdd": 3}[kind]
        A = np.array([math.comb(n, i) * K**i for i in range(n + 1)])
        return A / A.sum(), 0.5 * Td * np.arange(n + 1)
    if kind == "mzv":
        K3 = math.exp(-0.75 * zeta * math.pi / df)
        A = np.array([1.0, math.sqrt(2.0) * K3, K3 * K3])
        return A / A.sum(), 0.375 * Td * np.arange(3)
    raise AssertionError(kind)


def input_shaper(kind, frequency_hz, damping=0.0, vtol=DEFAULT_VTOL) -> InputShaper:
    """Design an input shaper for the mode ``(frequency_hz, damping)``.

    Parameters
    ----------
    kind : str
        ``"zv"``, ``"mzv"``, ``"zvd"``, ``"zvdd"``, ``"ei"``, ``"2hump_ei"``, ``"3hump_ei"``
        (case-insensitive; ``"2-hump EI"``, ``"EI2"`` and the like are accepted).
    frequency_hz : float
        Natural frequency of the mode, Hz (> 0).
    damping : float
        Damping ratio of the mode, 0 <= ζ < 1 (the EI family: up to ``EI_MAX_DAMPING``, 0.4, 0.3
        and 0.2 for EI, 2-hump and 3-hump EI).
    vtol : float
        Hump height of the EI family as a fraction (default 0.05, Klipper's and Singhose's).

    Returns
    -------
    InputShaper
        See the module docstring for the definitions.

    Examples
    --------
    >>> s = input_shaper("zvd", 8.0, 0.02)
    >>> round(float(s.amplitudes.sum()), 12), s.times[0]
    (1.0, 0.0)
    """
    kind = _kind(kind)
    f = as_positive("frequency_hz", frequency_hz)
    zeta = _damping("damping", damping)
    vtol = as_real("vtol", vtol)
    if not 0.0 < vtol < 0.5:
        raise ValueError(f"vtol must lie in (0, 0.5) (a fraction: 0.05 is 5 %), got {vtol!r}")
    if kind in ("ei", "2hump_ei", "3hump_ei"):
        m = {"ei": 1, "2hump_ei": 2, "3hump_ei": 3}[kind]
        if zeta > EI_MAX_DAMPING[kind]:
            raise ValueError(
                f"damping must be <= {EI_MAX_DAMPING[kind]} for the {kind} shaper (above it the "
                f"humps merge and the design conditions have no solution), got {zeta!r}"
            )
        A, tn = _ei_design(m, round(zeta, 12), round(vtol, 12))
        return InputShaper._trusted(kind, f, zeta, A / A.sum(), tn / f)
    A, t = _closed_form(kind, f, zeta)
    return InputShaper._trusted(kind, f, zeta, A, t)


def insensitivity_table(tolerances=(5.0, 10.0), damping=0.0, kinds=KINDS):
    """``{kind: {tolerance: (low, high)}}``: the insensitivity band (ratios) of each shaper
    designed and evaluated at ``damping`` (compare Klipper's table, docs/Resonance_Compensation.md)."""
    out = {}
    for k in kinds:
        s = input_shaper(k, 1.0, damping)
        out[_kind(k)] = {tol: s.insensitivity(tol) for tol in tolerances}
    return out


# ----------------------------------------------------------------------------------------------
# finding the mode from the encoder alone
# ----------------------------------------------------------------------------------------------
#: most samples :func:`chirp_input` makes (80 MB of float64)
MAX_CHIRP_SAMPLES = 10_000_000


def chirp_input(duration, Ts, amplitude, f0, f1, offset=0.0):
    """Linear chirp ``offset + amplitude sin(2π (f0 t + (f1 − f0) t²/(2 duration)))`` (V per sample).

    A swept sine through the rig's drive voltage, ``f0`` to ``f1`` Hz (both below the Nyquist
    frequency ``1/(2 Ts)``), for :func:`identify_mode`; ``jerklab.ident.prbs`` is the other choice.
    """
    duration = as_positive("duration", duration)
    Ts = as_positive("Ts", Ts)
    amplitude = as_positive("amplitude", amplitude)
    f0 = as_positive("f0", f0)
    f1 = as_positive("f1", f1)
    offset = as_real("offset", offset)
    if max(f0, f1) >= 0.5 / Ts:
        raise ValueError(
            f"f1 and f0 must lie below the Nyquist frequency 0.5 / Ts = {0.5 / Ts:g} Hz "
            f"(Ts = {Ts:g} s), got {f0:g}, {f1:g}"
        )
    if not duration / Ts <= MAX_CHIRP_SAMPLES:
        raise ValueError(
            f"duration / Ts = {duration:g} / {Ts:g} is more than shaping.MAX_CHIRP_SAMPLES = "
            f"{MAX_CHIRP_SAMPLES} samples: shorten duration or raise Ts"
        )
    n = int(round(duration / Ts))
    if n < 2:
        raise ValueError(
            f"duration must span at least 2 samples of Ts = {Ts:g} s, got {duration:g}"
        )
    t = np.arange(n) * Ts
    return offset + amplitude * np.sin(2 * math.pi * (f0 * t + 0.5 * (f1 - f0) * t * t / duration))


def flexible_mode(model=None):
    """``(f, ζ)``: natural frequency (Hz) and damping of the lightly damped pole pair of a
    :class:`jerklab.plant.FlexibleDCMotor` (the coupled mode of motor and load, open loop)."""
    m = _flex_model(model)
    return coupled_mode(m.K, m.tau, m.load_ratio, m.mode_frequency, m.mode_damping)


@dataclass
class ModeFit(ModeEstimate):
    """The mode found by :func:`identify_mode`, with the input shaper recommended for it.

    The fields of :class:`jerklab.ident.ModeEstimate` (``frequency_hz``, ``damping``, their
    standard errors, ``params``, ``fit_percent``, ``jerk_time``, ``residual_std``, ``model()``),
    and ``shaper``: the recommended :class:`InputShaper` (see :meth:`recommend`).
    """

    shaper: InputShaper

    @staticmethod
    def recommend(frequency_hz, damping, frequency_se, coverage=2.0, tolerance=5.0, margin=0.0):
        """The shortest shaper whose ``tolerance`` % band covers ``f (1 ± margin) ± coverage·se``.

        Shapers are tried by duration (ZV, MZV, ZVD, EI, 2-hump EI, 3-hump EI); if none covers
        the uncertainty, the 3-hump EI is returned (its band is the widest).
        """
        lo = 1 - margin - coverage * frequency_se / frequency_hz
        hi = 1 + margin + coverage * frequency_se / frequency_hz
        zeta = min(max(damping, 0.0), 0.2)
        for kind in ("zv", "mzv", "zvd", "ei", "2hump_ei", "3hump_ei"):
            s = input_shaper(kind, frequency_hz, zeta)
            blo, bhi = s.insensitivity(tolerance)
            if blo <= lo and bhi >= hi:
                return s
        return s


def identify_mode(u, y=None, Ts=None, f_range=None, max_nfev=400, margin=0.0) -> ModeFit:
    """Find the flexible mode from a drive-voltage record and the encoder angle, and recommend
    the input shaper for it.

    The identification is :func:`jerklab.ident.identify_mode` (a two-mass model fitted by
    output error; ``u``, ``y``, ``Ts``, ``f_range`` and ``max_nfev`` as there, ``u`` may be an
    ``IdentData`` record); the shaper is :meth:`ModeFit.recommend` for the mode found.

    Parameters
    ----------
    margin : float
        Relative drift of the mode the recommended shaper must also cover (0.05: ±5 %, e.g.
        belts or loads that change). The standard errors are statistical only: they say how
        well this record pins the mode down, not how much the machine will move it.

    Returns
    -------
    ModeFit
    """
    margin = as_nonnegative("margin", margin)
    est = _identify_mode(u, y, Ts, f_range, max_nfev)
    shaper = ModeFit.recommend(est.frequency_hz, est.damping, est.frequency_se, margin=margin)
    return ModeFit(**{f.name: getattr(est, f.name) for f in fields(ModeEstimate)}, shaper=shaper)


# ----------------------------------------------------------------------------------------------
# jerk profiles as implicit shapers
# ----------------------------------------------------------------------------------------------
def _sigma(frequency_hz, damping):
    w = 2 * math.pi * np.asarray(frequency_hz, dtype=float)
    return damping * w + 1j * w * math.sqrt(1.0 - damping * damping)


def _box(sig, L):
    """End-referenced transform of the unit box of length L: (1 − e^{−σL})/(σL)."""
    if L == 0.0:
        return np.ones_like(sig)
    x = sig * L
    small = np.abs(x) < 1e-8
    return np.where(small, 1.0 - x / 2, (1 - np.exp(-x)) / np.where(small, 1.0, x))


def _half_sine(sig, L):
    """End-referenced transform of the unit-area half-sine pulse of length L (the jerk pulse of
    the sine-jerk profiles): (a²/2)(1 + e^{−σL})/(σ² + a²), a = π/L (``|.|`` = π/4 at σ = ja)."""
    if L == 0.0:
        return np.ones_like(sig)
    a = math.pi / L
    d = sig * sig + a * a
    sing = np.abs(d) < 1e-9 * a * a
    return np.where(
        sing,
        math.pi / 4 * np.exp(-0.5j * math.pi),
        0.5 * a * a * (1 + np.exp(-sig * L)) / np.where(sing, 1.0, d),
    )


def _raised_cosine(sig, L):
    """End-referenced transform of the unit-area pulse (1 − cos(2πt/L))/L (Stojčić eq. 2's
    acceleration): (1 − e^{−σL}) b² / (L σ (σ² + b²)), b = 2π/L (−1/2 at σ = jb)."""
    if L == 0.0:
        return np.ones_like(sig)
    b = 2 * math.pi / L
    d = sig * sig + b * b
    sing = (np.abs(d) < 1e-9 * b * b) | (np.abs(sig) < 1e-12)
    safe = np.where(sing, 1.0, sig * d)
    val = (1 - np.exp(-sig * L)) * b * b / (L * safe)
    return np.where(np.abs(sig) < 1e-12, 1.0, np.where(np.abs(d) < 1e-9 * b * b, -0.5 + 0j, val))


def _profile_factors(profile):
    """The velocity/distance of a planner profile as a convolution of unit pulses:
    ``[(shape, length), ...]`` (shape in "box", "half_sine", "raised_cosine")."""
    if not isinstance(profile, Profile):
        raise TypeError(f"profile must be a jerklab.planner Profile, got {type(profile).__name__}")
    if profile.distance == 0.0:
        raise ValueError("profile must move (distance 0 leaves nothing to ring)")
    pt = profile.phase_times
    if profile.kind == "trapezoid":
        ta, tv, _ = pt
        return [("box", ta), ("box", ta + tv)]
    if profile.kind == "sine_jerk":
        T, tv, _ = pt
        return [("raised_cosine", T), ("box", T + tv)]
    tj, ta, _, tv = pt[:4]
    pulse = "box" if profile.kind == "scurve" else "half_sine"
    return [(pulse, tj), ("box", tj + ta), ("box", 2 * tj + ta + tv)]


_PULSES = {"box": _box, "half_sine": _half_sine, "raised_cosine": _raised_cosine}


def profile_residual_vibration(profile, frequency_hz, damping=0.0):
    """Percentage residual vibration a planner profile leaves on a mode (closed form).

    A symmetric rest-to-rest profile's velocity, divided by the distance, is a convolution of
    unit-area pulses: the trapezoid ``box(t_a) ⊛ box(t_a + t_v)``; the S-curve and the
    time-optimal sine-jerk profile ``p(t_j) ⊛ box(t_j + t_a) ⊛ box(2t_j + t_a + t_v)`` with ``p``
    the jerk pulse (a box, or a half sine); Stojčić's profile (Stojčić eq. 2) the raised-cosine
    acceleration pulse of length T ⊛ ``box(T + t_v)``. The residual vibration (module docstring)
    is the product of the pulses' transforms at ``σ = ζω + jω_d``: each box of length L is a
    "continuous ZV" with zeros at ``f = k/L`` (ζ = 0), the half sine at ``f = (k + ½)/L``
    (k >= 1), the raised cosine at ``f = k/L`` (k >= 2). Checked against a numerically
    integrated mass–spring response in the tests.

    Parameters
    ----------
    profile : jerklab.planner.Profile
        A planned move (any of the four kinds).
    frequency_hz : float or array_like
        Natural frequency of the mode, Hz.
    damping : float
        Damping ratio of the mode.
    """
    factors = _profile_factors(profile)
    f = as_finite_array("frequency_hz", frequency_hz)
    if np.any(f <= 0):
        raise ValueError(f"frequency_hz must be positive and finite, got {frequency_hz!r}")
    sig = _sigma(f, _damping("damping", damping))
    F = np.ones_like(sig)
    for shape, L in factors:
        F = F * _PULSES[shape](sig, L)
    v = 100.0 * np.abs(F)
    return float(v) if np.ndim(frequency_hz) == 0 else v


def tuned_profile(
    kind, distance, frequency_hz, max_accel, max_velocity, max_jerk=None, damping=0.0
):
    """The profile of ``kind`` with its jerk (or acceleration) time set on a spectral zero of the mode.

    * ``"scurve"``: the jerk time ``t_j = T_d = 1/f_d`` (the box of the jerk pulse has its first zero
      there); ``max_jerk`` is replaced by ``A'/T_d``.
    * ``"sine_jerk_optimal"``: the half-sine jerk pulse of length ``1.5 T_d`` (its first zero).
    * ``"sine_jerk"``: Stojčić's acceleration time ``T = 2 T_d`` (the raised cosine's first zero,
      Stojčić eq. 4 with the jerk lowered until ``T = 2 T_d``).
    * ``"trapezoid"``: its velocity is ``box(t_a) ⊛ box(t_a + t_v)``; either the acceleration time
      or the time between the start of acceleration and of deceleration is rounded up to a whole
      number of ``T_d`` (lowering the acceleration, or the cruise speed), whichever is shorter.

    The acceleration (and velocity) limits are kept as upper bounds: where the move is too short
    to reach ``max_accel`` within the tuned time, the acceleration is lowered. ``max_jerk`` is
    not used (the jerk follows from the tuned time); it is accepted for a uniform call.
    ``T_d = 1/(f √(1 − ζ²))``; a box has no exact zero once ζ > 0, the residual is then small but
    not zero.

    Returns
    -------
    jerklab.planner.Profile
    """
    if kind not in ("trapezoid", "scurve", "sine_jerk", "sine_jerk_optimal"):
        raise ValueError(
            f"kind must be 'trapezoid', 'scurve', 'sine_jerk' or 'sine_jerk_optimal', got {kind!r}"
        )
    d = as_real("distance", distance)
    f = as_positive("frequency_hz", frequency_hz)
    A = as_positive("max_accel", max_accel)
    V = as_positive("max_velocity", max_velocity)
    zeta = _damping("damping", damping)
    if max_jerk is not None:
        as_positive("max_jerk", max_jerk)
    Td = 1.0 / (f * math.sqrt(1 - zeta * zeta))
    ad = abs(d)
    if ad == 0.0:
        raise ValueError("distance must not be 0")
    try:
        return _tuned(kind, d, ad, Td, A, V)
    except (ValueError, ZeroDivisionError, OverflowError) as exc:
        raise ValueError(
            f"frequency_hz = {f!r} Hz (T_d = {Td!r} s) gives no finite {kind} plan of "
            f"distance {d!r} within max_accel = {A!r}, max_velocity = {V!r} ({exc}); scale the units"
        ) from None


def _tuned(kind, d, ad, Td, A, V):
    """:func:`tuned_profile` after its checks."""
    if kind == "trapezoid":
        # two boxes, box(t_a) and box(t_a + t_v): round the cheaper one up to whole periods
        base = planner.plan_trapezoid(ad, A, V)
        ta0, tv0, _ = base.phase_times
        ta = max(1, math.ceil(ta0 / Td - 1e-9)) * Td  # option 1: the acceleration time
        p1 = planner.plan_trapezoid(d, min(V / ta, ad / ta**2), V)
        L2 = max(1, math.ceil((ta0 + tv0) / Td - 1e-9)) * Td  # option 2: the time between ramps
        v = ad / L2
        p2 = planner.plan_trapezoid(d, v / ta0, v * (1 + 1e-12))
        return p1 if p1.duration <= p2.duration else p2
    if kind == "scurve":
        tj = Td
        A2 = min(A, ad / (2 * tj * tj), V / tj)
        return planner.plan_scurve(d, A2 / tj, A2, V)
    if kind == "sine_jerk_optimal":
        tj = 1.5 * Td
        A2 = min(A, ad / (2 * tj * tj), V / tj)
        return planner.plan_sine_jerk_optimal(d, math.pi * A2 / (2 * tj), A2, V)
    T = 2 * Td  # "sine_jerk"
    J = min(A * math.pi / T, 2 * math.pi * ad / T**3, 2 * math.pi * V / T**2)
    return planner.plan_sine_jerk(d, J, A, V)


def move_time_comparison(
    distance, frequency_hz, max_accel, max_velocity, damping=0.0, shapers=("zv", "zvd", "ei")
):
    """Move time of a zero-ringing move: a tuned profile against a shaped time-optimal trapezoid.

    The baseline is the time-optimal trapezoid under ``max_accel``, ``max_velocity`` (it rings).
    A shaper adds its duration to it (positive impulses keep the acceleration limit); a tuned
    profile (:func:`tuned_profile`) costs the difference of durations. Returns
    ``{name: {"duration": s, "penalty": s, "residual": % at the mode}}``. The tuned profile wins
    when the move's own acceleration time is long against the mode period (rounding it up to a
    period costs less than half a period, ZV's price), and loses for short, fast moves, where
    the jerk time ``1/f`` is added almost entirely.
    """
    base = planner.plan_trapezoid(distance, max_accel, max_velocity)
    out = {
        "trapezoid": {
            "duration": base.duration,
            "penalty": 0.0,
            "residual": profile_residual_vibration(base, frequency_hz, damping),
        }
    }
    for kind in ("trapezoid", "scurve", "sine_jerk_optimal", "sine_jerk"):
        p = tuned_profile(kind, distance, frequency_hz, max_accel, max_velocity, damping=damping)
        out[f"tuned {kind}"] = {
            "duration": p.duration,
            "penalty": p.duration - base.duration,
            "residual": profile_residual_vibration(p, frequency_hz, damping),
        }
    for k in shapers:
        s = input_shaper(k, frequency_hz, damping)
        r = (
            s.residual_vibration(frequency_hz, damping)
            * profile_residual_vibration(base, frequency_hz, damping)
            / 100
        )
        out[f"trapezoid + {_kind(k).upper()}"] = {
            "duration": base.duration + s.duration,
            "penalty": s.duration,
            "residual": r,
        }
    return out


# ----------------------------------------------------------------------------------------------
# Xu & Meckl's robust time-optimal shaping, generalized to a rest-to-rest move of the flexible motor
# ----------------------------------------------------------------------------------------------
def _zoh_poles(model, Ts):
    """Discrete poles (z = e^{λTs}) of the flexible motor: the real (motor) pole and the mode pole
    in the upper half plane; the integrator (λ = 0) is left out."""
    A, _ = model._matrices()
    lam = np.linalg.eigvals(A)
    lam = lam[np.abs(lam) > 1e-9 * max(1.0, np.abs(lam).max())]
    real = lam[np.abs(lam.imag) <= 1e-9 * np.abs(lam)].real
    cplx = lam[lam.imag > 1e-9 * np.abs(lam)]
    return [math.exp(r * Ts) for r in real], [complex(np.exp(c * Ts)) for c in cplx]


def _poly_rows(N, z, j):
    """Row of d^j/dz^j of P(z) = Σ_k u_k z^{N−1−k} (the command's z-transform times z^{N−1}: the
    same zeros away from 0, and ``|z^m|`` <= 1 inside the unit circle, so the rows stay well scaled)."""
    m = (N - 1 - np.arange(N)).astype(float)
    coef = np.ones(N)
    for i in range(j):
        coef = coef * (m - i)
    with np.errstate(divide="ignore", invalid="ignore"):
        pw = np.where(m - j >= 0, np.power(complex(z), np.maximum(m - j, 0)), 0.0)
    return coef * pw


def robust_move_rows(N, model, Ts, distance, order=0):
    """Equality rows ``E u = f`` on the N voltage samples of a rest-to-rest move of ``model``.

    The move ends at rest at ``distance`` (motor and load, rad) once the input is 0 after N
    samples. In modal form (Xu & Meckl eq. 3 with the terminal state of Xu & Meckl eq. 6) that is:
    the integrator sums the input (``K Ts Σ u_k = distance``: the rigid motor's momentum
    balance), and the command's z-transform vanishes at every other pole (the motor pole and the
    mode pole). Order ``m`` robustness (Xu & Meckl eqs. 8, 13) makes the mode
    pole a zero of multiplicity ``m + 1`` (the derivatives up to m vanish too), as in
    :mod:`jerklab.piezo` — here on ``z^{N−1} U(z)``, a polynomial, so the rows are bounded.
    Rows are scaled to unit norm.
    """
    real, cplx = _zoh_poles(model, Ts)
    rows, rhs = [np.ones(N)], [distance / (model.K * Ts)]
    for z in real:
        rows.append(np.real(_poly_rows(N, z, 0)))
        rhs.append(0.0)
    for z in cplx:
        for j in range(order + 1):
            r = _poly_rows(N, z, j)
            rows += [r.real, r.imag]
            rhs += [0.0, 0.0]
    E, f = np.array(rows), np.array(rhs)
    s = np.linalg.norm(E, axis=1)
    s[s == 0] = 1.0
    return E / s[:, None], f / s


@dataclass
class RobustMove:
    """A shaped voltage command for a rest-to-rest move of the flexible motor.

    ``u``: volts per sample (held, ZOH), 0 after the last; ``order``: robustness order of the
    mode (``None``: only rest of the rigid motor, the mode ignored); ``lp_count``: LPs/screens run.
    """

    u: np.ndarray
    Ts: float
    distance: float
    order: int | None
    u_max: float
    mode_hz: float
    mode_damping: float
    lp_count: int = 0
    objective: str = "time"

    @property
    def duration(self) -> float:
        """Length of the command, s."""
        return self.u.size * self.Ts

    def sensitivity_curve(self, ratios, damping=None):
        """Residual vibration (%) with the mode at ``ratios`` × its nominal frequency.

        The command read as a density (module docstring): ZOH pulses ``u_k/Σu`` of length Ts, so
        a voltage impulse of the same area (a position step) would leave 100 %.
        """
        r = as_finite_array("ratios", ratios, ndim=1)
        if np.any(r <= 0):
            raise ValueError("ratios must be positive")
        zeta = self.mode_damping if damping is None else _damping("damping", damping)
        sig = _sigma(self.mode_hz * r, zeta)[:, None]
        k = np.arange(self.u.size)
        T = self.u.size * self.Ts
        F = (
            np.exp(sig * (k * self.Ts - T))
            @ self.u
            * _box(sig[:, 0], self.Ts)
            * np.exp(sig[:, 0] * self.Ts)
        )
        return 100.0 * np.abs(F) / abs(self.u.sum())

    def residual_vibration(self, frequency_hz, damping=None):
        """Residual vibration (%) on a mode at ``frequency_hz`` (scalar)."""
        f = as_positive("frequency_hz", frequency_hz)
        return float(self.sensitivity_curve(np.array([f / self.mode_hz]), damping)[0])


def _flex_model(model):
    if model is None:
        return FlexibleDCMotor()
    if not isinstance(model, FlexibleDCMotor):
        raise TypeError(
            f"model must be a jerklab.plant.FlexibleDCMotor, got {type(model).__name__}"
        )
    return model


def robust_move(distance, model=None, Ts=0.005, order=0, u_max=None, max_samples=2000, solver="lp"):
    """Time-optimal (robust) voltage command moving the flexible motor by ``distance`` rad, rest to rest.

    Xu & Meckl's formulation (Xu & Meckl eqs. 3, 5, 6, 13) generalized from the piezo scan to a
    positioning move: the smallest horizon N for which voltage samples with ``|u_k| <= u_max``
    (Xu & Meckl eq. 5, the supply) meet :func:`robust_move_rows` — rest at ``distance``, the mode robust
    to ``order`` (0, 1, 2: zero placement of multiplicity 1, 2, 3). Bisection on N over LP
    feasibility problems, with the NNLS screen and the HiGHS LP of :mod:`jerklab.piezo` (``solver``
    as there: ``"lp"``, ``"highs"`` or ``"lsq"`` for Xu & Meckl eq. 6 literally). ``order=None``
    ignores the mode (rest of the rigid motor only): the baseline of the move-time penalty.

    Parameters
    ----------
    distance : float
        Move, rad (non-zero).
    model : jerklab.plant.FlexibleDCMotor, optional
        The plant (default ``FlexibleDCMotor()``: 8 Hz shaft, load ratio 0.05).
    Ts : float
        Sample period, s.
    order : int or None
        Robustness order of the mode.
    u_max : float, optional
        Voltage limit, V (default the model's supply voltage, else 12 V).
    """
    model = _flex_model(model)
    d = as_real("distance", distance)
    if d == 0.0:
        raise ValueError("distance must not be 0")
    Ts = as_positive("Ts", Ts)
    if order is not None:
        order = as_int("order", order, minimum=0)
        if order > 4:
            raise ValueError(f"order must be <= 4, got {order}")
    U = as_positive("u_max", u_max if u_max is not None else (model.supply_voltage or 12.0))
    if solver not in ("lp", "highs", "lsq"):
        raise ValueError(f"solver must be 'lp', 'highs' or 'lsq', got {solver!r}")
    max_samples = as_int("max_samples", max_samples, minimum=2)
    count = [0]
    real, cplx = _zoh_poles(model, Ts)

    n_rows = 1 + len(real) + (0 if order is None else 2 * len(cplx) * (order + 1))

    def make(N, how):
        count[0] += 1
        if N < n_rows:  # fewer samples than conditions: a zero row at best
            return None
        if order is None:
            E = np.vstack([np.ones(N)] + [np.real(_poly_rows(N, z, 0)) for z in real])
            f = np.r_[d / (model.K * Ts), np.zeros(len(real))]
            s = np.linalg.norm(E, axis=1)
            E, f = E / s[:, None], f / s
        else:
            E, f = robust_move_rows(N, model, Ts, d, order)
        return piezo._solve_lp(E, f, None, None, [(-U, U)] * N, N, how)

    n_lo = max(1, math.ceil(abs(d) / (model.K * Ts * U)) - 1)  # Σ|u| Ts K >= |d|
    N, x = piezo._bisect_solver(make, n_lo, max_samples, solver)
    fm, zm = coupled_mode(
        model.K, model.tau, model.load_ratio, model.mode_frequency, model.mode_damping
    )
    return RobustMove(
        u=np.asarray(x, dtype=float),
        Ts=Ts,
        distance=d,
        order=order,
        u_max=U,
        mode_hz=fm,
        mode_damping=zm,
        lp_count=count[0],
    )


def energy_optimal_move(distance, N, model=None, Ts=0.005, order=1, u_max=None, objective="input"):
    """Time-energy-optimal variant: a move of a fixed ``N`` samples of least energy (Xu & Meckl eq. 19).

    Minimises ``½ Σ u_k²`` (``objective="input"``, Xu & Meckl eq. 19 as published) or
    ``½ Σ (u_k − u_{k−1})²`` with ``u_{−1} = u_N = 0`` (``"increment"``: the smoother command)
    subject to the same rest/robustness rows and ``|u| <= u_max``; ``N`` longer than the
    time-optimal horizon of :func:`robust_move` trades time for a gentler command. Raises
    ``RuntimeError`` when ``N`` is shorter than the time-optimal horizon.
    """
    model = _flex_model(model)
    d = as_real("distance", distance)
    if d == 0.0:
        raise ValueError("distance must not be 0")
    Ts = as_positive("Ts", Ts)
    N = as_int("N", N, minimum=2)
    if N > 20_000:
        raise ValueError(f"N must be <= 20000 samples, got {N}")
    order = as_int("order", order, minimum=0)
    if objective not in ("input", "increment"):
        raise ValueError(f"objective must be 'input' or 'increment', got {objective!r}")
    U = as_positive("u_max", u_max if u_max is not None else (model.supply_voltage or 12.0))
    E, f = robust_move_rows(N, model, Ts, d, order)
    x0 = piezo._solve_lp(E, f, None, None, [(-U, U)] * N, N)
    if x0 is None:
        raise RuntimeError(f"N = {N} is shorter than the time-optimal move")
    M = m = None
    if objective == "increment":
        M = np.eye(N + 1, N) - np.eye(N + 1, N, -1)
        m = np.zeros(N + 1)
    u = piezo._least_squares_qp(E, f, np.full(N, -U), np.full(N, U), M, m, x0=x0)
    if u is None:
        raise RuntimeError("the QP of Xu & Meckl eq. 19 did not converge")
    fm, zm = coupled_mode(
        model.K, model.tau, model.load_ratio, model.mode_frequency, model.mode_damping
    )
    return RobustMove(
        u=u,
        Ts=Ts,
        distance=d,
        order=order,
        u_max=U,
        mode_hz=fm,
        mode_damping=zm,
        objective=objective,
    )


# ----------------------------------------------------------------------------------------------
# the trade-off: one figure and one table
# ----------------------------------------------------------------------------------------------
@dataclass
class Tradeoff:
    """Residual vibration against the frequency ratio and the move-time cost of each method.

    ``ratios``: mode frequency / nominal (design) frequency; ``curves``: ``{name: V %}``;
    ``rows``: one dict per method with ``name``, ``family`` ("profile", "shaper", "robust LP"),
    (a band reaching ratio 3, the search limit, is open above: a profile is a low-pass filter)
    ``duration`` (s, the whole move), ``penalty`` (s, against its family's baseline: the
    time-optimal trapezoid for profiles and shapers, the time-optimal voltage command that
    ignores the mode for the LP), ``band`` (the 5 % insensitivity band as ratios, nan if the
    method leaves more than 5 % at the nominal mode) and ``width`` (high − low).
    """

    frequency_hz: float
    damping: float
    distance: float
    ratios: np.ndarray
    curves: dict
    rows: list

    def table(self) -> str:
        """The table as text: method, move time, penalty, 5 % band and its width."""
        lines = [
            f"{'method':<24} {'family':<10} {'move s':>7} {'penalty s':>9} {'5 % band':>16} {'width':>7}"
        ]
        for r in self.rows:
            lo, hi = r["band"]
            band = "—" if math.isnan(lo) else f"{100 * (lo - 1):+5.1f}…{100 * (hi - 1):+5.1f} %"
            if not math.isnan(lo) and hi >= _R_MAX - 1e-9:
                band = f"{100 * (lo - 1):+5.1f}…   ∞ %"
            width = "—" if math.isnan(lo) else f"{100 * (hi - lo):5.1f} %"
            if not math.isnan(lo) and hi >= _R_MAX - 1e-9:
                width = "∞"
            lines.append(
                f"{r['name']:<24} {r['family']:<10} {r['duration']:7.3f} {r['penalty']:9.3f} "
                f"{band:>16} {width:>7}"
            )
        return "\n".join(lines)

    def plot(self, ax=None):
        """Draw the curves (``jerklab.plots.plot_tradeoff``)."""
        from jerklab.plots import plot_tradeoff

        return plot_tradeoff(self, ax=ax)


def tradeoff(
    model=None,
    distance=1.0,
    Ts=0.005,
    max_accel=None,
    max_velocity=None,
    ratios=None,
    orders=(0, 1, 2),
    shapers=("zv", "mzv", "zvd", "ei", "2hump_ei", "3hump_ei"),
):
    """Compute the trade-off figure and table for the flexible motor's mode.

    The mode is the coupled pole pair of ``model`` (default ``FlexibleDCMotor()``: 8.1 Hz,
    ζ = 0.033). The default move (1 rad under Stojčić's limits) accelerates in 58 ms, under half the
    mode period, so the plain trapezoid rings; a move whose acceleration time exceeds the period
    is already a good filter on its own (try ``distance=2 * math.pi``). Curves: the time-optimal
    trapezoid and the S-curve and sine-jerk profiles tuned to the mode (:func:`tuned_profile`)
    over ``distance`` under ``max_accel``/``max_velocity`` (default Stojčić's limits,
    ``jerklab.paper``); the shapers designed for the mode; the robust time-optimal voltage
    commands (:func:`robust_move`) of each order. Every curve uses the same measure (module
    docstring): the residual with the mode at ``ratio ×`` its nominal frequency, damping held,
    as a percentage of what a step of the same size leaves.
    """
    model = _flex_model(model)
    A = paper.MAX_ACCEL if max_accel is None else as_positive("max_accel", max_accel)
    V = paper.MAX_VELOCITY if max_velocity is None else as_positive("max_velocity", max_velocity)
    r = np.linspace(0.5, 1.5, 201) if ratios is None else as_finite_array("ratios", ratios, ndim=1)
    if np.any(r <= 0):
        raise ValueError("ratios must be positive")
    f, z = coupled_mode(
        model.K, model.tau, model.load_ratio, model.mode_frequency, model.mode_damping
    )
    base = planner.plan_trapezoid(distance, A, V)
    curves, rows = {}, []

    def add(name, family, dur, pen, curve_fn):
        curves[name] = curve_fn(r)
        band = _band(curve_fn, 5.0)
        rows.append(
            dict(
                name=name,
                family=family,
                duration=float(dur),
                penalty=float(pen),
                band=band,
                width=band[1] - band[0],
            )
        )

    add(
        "trapezoid",
        "profile",
        base.duration,
        0.0,
        lambda x: profile_residual_vibration(base, f * x, z),
    )
    for kind, label in (
        ("trapezoid", "tuned trapezoid"),
        ("scurve", "tuned S-curve"),
        ("sine_jerk", "tuned sine-jerk"),
    ):
        p = tuned_profile(kind, distance, f, A, V, damping=z)
        add(
            label,
            "profile",
            p.duration,
            p.duration - base.duration,
            lambda x, p=p: profile_residual_vibration(p, f * x, z),
        )
    for k in shapers:
        s = input_shaper(k, f, z)
        add(
            f"{_kind(k).upper().replace('HUMP_', '-hump ')}",
            "shaper",
            base.duration + s.duration,
            s.duration,
            lambda x, s=s: s.sensitivity_curve(x),
        )
    rigid = robust_move(distance, model, Ts, order=None)
    for o in orders:
        m = robust_move(distance, model, Ts, order=o)
        add(
            f"robust LP order {o}",
            "robust LP",
            m.duration,
            m.duration - rigid.duration,
            lambda x, m=m: m.sensitivity_curve(x),
        )
    return Tradeoff(
        frequency_hz=f, damping=z, distance=float(distance), ratios=r, curves=curves, rows=rows
    )


# ----------------------------------------------------------------------------------------------
# measuring the ringing in a record
# ----------------------------------------------------------------------------------------------
def residual_amplitude(y, Ts, start, frequency_hz=None, damping=0.0, final=None):
    """Amplitude of the ringing left in a sampled record after the move ends (same unit as ``y``).

    Parameters
    ----------
    y : array_like
        The record (an encoder or load angle, rad), sampled every ``Ts``.
    Ts : float
        Sample period, s.
    start : int
        First sample after the move (the command has ended).
    frequency_hz, damping : float, optional
        The mode. Given, ``y[start:] − final`` is fitted by least squares with
        ``e^{−ζωt}(a cos ω_d t + b sin ω_d t)`` (t from ``start``) and ``√(a² + b²)`` is returned:
        the amplitude at ``start``, robust to encoder quantization and noise. Without it, the largest
        ``|y − final|`` after ``start``.
    final : float, optional
        The rest position (default: the mean of the last quarter of the record after ``start``).
    """
    y = as_finite_array("y", y, ndim=1)
    Ts = as_positive("Ts", Ts)
    start = as_int("start", start, minimum=0)
    if start > y.size - 4:
        raise ValueError(f"start must leave at least 4 samples of y (len {y.size}), got {start}")
    tail = y[start:]
    final = (
        float(tail[-max(1, tail.size // 4) :].mean()) if final is None else as_real("final", final)
    )
    e = tail - final
    if frequency_hz is None:
        return float(np.abs(e).max())
    f = as_positive("frequency_hz", frequency_hz)
    zeta = _damping("damping", damping)
    w = 2 * math.pi * f
    t = np.arange(e.size) * Ts
    env = np.exp(-zeta * w * t)
    wd = w * math.sqrt(1 - zeta * zeta)
    X = np.column_stack([env * np.cos(wd * t), env * np.sin(wd * t)])
    (a, b), *_ = np.linalg.lstsq(X, e, rcond=None)
    return float(math.hypot(a, b))
