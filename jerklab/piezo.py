"""PZT actuator model and robust time-optimal command shaping (Xu & Meckl).

Implements the linear part of the piezo model (Xu & Meckl eq. 1, Table I), its ZOH model at
Ts = 0.2 ms, time-optimal command shaping (Xu & Meckl eqs. 3–6) as a linear program per
horizon with the minimum horizon found by bisection, robust shaping for velocity tracking
(Xu & Meckl eqs. 7, 8, 13, 16, 17) with the outer search over the scan start y(T)
(Xu & Meckl eq. 18, Fig. 4), the time-energy-optimal return (Xu & Meckl eq. 19, Fig. 7),
the evaluation under a natural-frequency perturbation (Table II) and a closed loop with
hysteresis compensation (Figs. 8, 9).

Units follow the paper: input in V, output in µm, time in s.

How the discrete formulation relates to the paper
-------------------------------------------------
The paper sets terminal states of a Jordan-augmented *continuous* model (Xu & Meckl eqs. 14.1, 15.1,
16, 17). Used on a ZOH model those leave mode-1 ringing and a velocity error (a staircase input acts
like the ramp delayed by Ts/2), and the augmented system is badly conditioned. The equivalent
discrete condition is used instead: a command is *m-th order robust* for a mode with discrete pole
``z_i`` when the z-transform of the whole command (including its unbounded ramp tail, Xu & Meckl
eqs. 11, 12 in z) and its first ``m`` derivatives vanish at ``z_i`` (Bhat & Miu's condition,
Xu & Meckl eqs. 8, 13, mapped by ``z = e^{sTs}``). Order 0 is the nominal zero-vibration condition.
Because the model has no rigid-body mode, these conditions fix the terminal state completely: after
the ramp-up the output is exactly the steady ramp, after the return the state is exactly zero.
"""

from __future__ import annotations

import functools
import math
import time
from dataclasses import dataclass, replace

import numpy as np
from scipy.linalg import matrix_balance
from scipy.optimize import linprog, lsq_linear, minimize, nnls
from scipy.signal import lfilter

from jerklab import paper as _paper
from jerklab._lazy import lazy_module
from jerklab._validate import (
    BadInput,
    as_finite_array,
    as_having,
    as_instance,
    as_int,
    as_nonnegative,
    as_positive,
    as_real,
    at_most,
)

control = lazy_module("control")  # python-control imports matplotlib: import it on first use

__all__ = [
    "TABLE_I",
    "TABLE_II_PAPER",
    "TABLE_II_INPUTS",
    "TS",
    "DEFAULT_F_MAX",
    "PZTModel",
    "ScanSpec",
    "RampUp",
    "Return",
    "ScanCycle",
    "CycleEvaluation",
    "FeedbackGains",
    "ClosedLoopResult",
    "simulate",
    "robustness_rows_rampup",
    "robustness_rows_return",
    "shape_rampup",
    "shape_return",
    "shape_cycle",
    "rampup_time_vs_scan_start",
    "evaluate_cycle",
    "table_ii",
    "format_table_ii",
    "energy_optimal_return",
    "with_return",
    "pole_placement_gains",
    "closed_loop",
]

#: longest horizon (samples) a shaping problem is built for: a dense k x k problem beyond it
MAX_HORIZON = 20_000

#: Xu & Meckl Table I: the linear PZT dynamics of Xu & Meckl eq. 1 (frequencies in Hz); from jerklab.paper.
TABLE_I = dict(_paper.PIEZO_TABLE_I)

#: Xu & Meckl: sampling time of the simulation study (0.2 ms); jerklab.paper.PIEZO_TS.
TS = _paper.PIEZO_TS

#: Xu & Meckl Table II: cycle time (s), e_m (µm), e_r (µm) for each input.
TABLE_II_PAPER = {
    "non-robust": (8.4e-3, 0.18, 1.37),
    "1st-order robust": (10.4e-3, 0.025, 0.25),
    "2nd-order robust": (14.8e-3, 0.006, 0.04),
    "combined-robust": (13.4e-3, 0.025, 0.04),
}

#: The actuator limit F_max used for Table II. The paper never states it. With mode 1 (the one
#: whose frequency is perturbed) robustified and mode 2 held at zero vibration, 38 V puts every
#: cycle time of Table II within 1 ms (see ``table_ii``); the scan alone needs a 32 V input ramp
#: (v_d Ts / G(0) = 1.066 V per sample over 30 samples), so F_max must exceed 16 V for a
#: symmetric range and 38 V leaves a moderate margin for the transitions.
DEFAULT_F_MAX = 38.0


# ----------------------------------------------------------------------------------------------
# Model
# ----------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class PZTModel:
    """The linear PZT dynamics G(s) of Xu & Meckl eq. 1 (Table I), volts -> µm.

    ``G(s) = K (s² − 2ζz ωz s + ωz²) / ((s² + 2ζ1ω1 s + ω1²)(s² + 2ζ2ω2 s + ω2²))`` with a
    non-minimum-phase zero. Frequencies are in Hz (ω = 2πf).
    """

    K: float = TABLE_I["K"]
    zeta_z: float = TABLE_I["zeta_z"]
    f_z: float = TABLE_I["f_z"]
    zeta_1: float = TABLE_I["zeta_1"]
    f_1: float = TABLE_I["f_1"]
    zeta_2: float = TABLE_I["zeta_2"]
    f_2: float = TABLE_I["f_2"]

    def __post_init__(self):
        for name in ("K", "f_z", "f_1", "f_2"):
            as_positive(name, getattr(self, name))
        for name in ("zeta_z", "zeta_1", "zeta_2"):
            as_nonnegative(name, getattr(self, name))

    def tf(self) -> control.TransferFunction:
        """Return G(s) (Xu & Meckl eq. 1) as a python-control transfer function (V -> µm)."""
        wz, w1, w2 = (2 * math.pi * f for f in (self.f_z, self.f_1, self.f_2))
        num = self.K * np.array([1.0, -2 * self.zeta_z * wz, wz**2])
        den = np.polymul([1.0, 2 * self.zeta_1 * w1, w1**2], [1.0, 2 * self.zeta_2 * w2, w2**2])
        return control.tf(num, den)

    def ss(self) -> control.StateSpace:
        """Return G(s) as a continuous state-space system (python-control), balanced.

        The controllable canonical form of Xu & Meckl eq. 1 spans 13 orders of magnitude (its output row
        holds K ωz² ~ 1e13), which makes pole placement and observer design inaccurate; a
        diagonal similarity (``scipy.linalg.matrix_balance`` of ``[[A, B], [C, 0]]``) brings the
        condition number of A from ~1e14 to ~10 without changing the transfer function.
        """
        sys = control.tf2ss(self.tf())
        A, B, C, D = (np.asarray(x, dtype=float) for x in (sys.A, sys.B, sys.C, sys.D))
        n = A.shape[0]
        M = np.zeros((n + 1, n + 1))
        M[:n, :n], M[:n, n:], M[n:, :n] = A, B, C
        _, (scale, _) = matrix_balance(M, permute=False, separate=True)
        d = scale[:n]
        return control.ss(A * (d[None, :] / d[:, None]), B / d[:, None], C * d[None, :], D)

    def zoh(self, Ts: float = TS) -> control.StateSpace:
        """Return the exact zero-order-hold model at ``Ts`` (Xu & Meckl eq. 3)."""
        Ts = as_positive("Ts", Ts)
        try:
            sysd = control.c2d(self.ss(), Ts, method="zoh")
        except (np.linalg.LinAlgError, ValueError, OverflowError) as exc:
            raise ValueError(f"Ts = {Ts!r} s cannot be discretized: {exc}") from None
        if not np.all(np.isfinite(np.asarray(sysd.A))) or not np.all(
            np.isfinite(np.asarray(sysd.B))
        ):
            raise ValueError(f"Ts = {Ts!r} s is too long for this model: the ZOH matrices overflow")
        return sysd

    def dc_gain(self) -> float:
        """Return G(0) = K ωz² / (ω1² ω2²) in µm/V (0.18759 for Table I)."""
        wz, w1, w2 = (2 * math.pi * f for f in (self.f_z, self.f_1, self.f_2))
        return self.K * wz**2 / (w1**2 * w2**2)

    def mode_poles(self, Ts: float = TS) -> dict:
        """Return ``{1: z1, 2: z2}``, the discrete pole (upper half plane) of each mode at ``Ts``."""
        Ts = as_positive("Ts", Ts)
        out = {}
        for i, (zeta, f) in enumerate(((self.zeta_1, self.f_1), (self.zeta_2, self.f_2)), 1):
            w = 2 * math.pi * f
            s = -zeta * w + 1j * w * math.sqrt(max(1.0 - zeta**2, 0.0))
            out[i] = complex(np.exp(s * Ts))
        return out

    def perturbed(
        self, freq_scale: float = 1.1, modes=(1,), hold_dc_gain: bool = True
    ) -> "PZTModel":
        """Return the model with the natural frequency of ``modes`` scaled by ``freq_scale``.

        Xu & Meckl test robustness with a "+10 % frequency perturbation" without saying which
        frequencies or what happens to the gain. Defaults: only mode 1 (the lightly damped
        242 Hz mode that shaping must cancel) is moved, and K is rescaled so that the DC gain is
        unchanged — otherwise a 21 % static gain error would swamp the vibration errors that
        e_m, e_r are meant to measure.
        """
        freq_scale = as_positive("freq_scale", freq_scale)
        modes = tuple(modes)
        for m in modes:
            if m not in (1, 2):
                raise ValueError(f"modes must contain only 1 or 2, got {m!r}")
        try:
            new = replace(
                self,
                f_1=self.f_1 * (freq_scale if 1 in modes else 1.0),
                f_2=self.f_2 * (freq_scale if 2 in modes else 1.0),
            )
            if hold_dc_gain:
                new = replace(new, K=new.K * self.dc_gain() / new.dc_gain())
        except (ZeroDivisionError, OverflowError, ValueError) as exc:
            raise ValueError(f"freq_scale = {freq_scale!r} gives no usable model ({exc})") from None
        return new


@functools.lru_cache(maxsize=64)
def _discrete_cached(model: PZTModel, Ts: float):
    sysd = model.zoh(Ts)
    out = (
        np.asarray(sysd.A, dtype=float),
        np.asarray(sysd.B, dtype=float).ravel(),
        np.asarray(sysd.C, dtype=float).ravel(),
        float(np.asarray(sysd.D).ravel()[0]),
    )
    for a in out[:3]:
        a.setflags(write=False)
    return out


def _discrete(model: PZTModel, Ts: float):
    """(A, B, C, D) of the ZOH model as read-only arrays (cached: c2d costs ~10 ms)."""
    return _discrete_cached(model, float(Ts))


def simulate(model: PZTModel, u, Ts: float = TS) -> np.ndarray:
    """Simulate the ZOH model from rest: ``y[k]`` for the input samples ``u[k]`` (Xu & Meckl eq. 3).

    The exact ZOH pulse transfer function of ``model.zoh(Ts)`` run by ``scipy.signal.lfilter``
    (tests compare it with ``control.forced_response``).
    """
    if not isinstance(model, PZTModel):
        raise TypeError(f"model must be a PZTModel, got {type(model).__name__}")
    u = as_finite_array("u", u, ndim=1)
    A, B, C, D = _discrete(model, as_positive("Ts", Ts))
    den = np.real(np.poly(A))
    num = np.real(np.poly(A - np.outer(B, C))) - den + D * den  # C (zI − A)^-1 B + D
    return lfilter(num, den, u)


# ----------------------------------------------------------------------------------------------
# z-transform robustness conditions
# ----------------------------------------------------------------------------------------------
def _dz_power(k: np.ndarray, z: complex, j: int) -> np.ndarray:
    """d^j/dz^j z^(-k) = (-1)^j k (k+1) ... (k+j-1) z^(-k-j)."""
    k = np.asarray(k, dtype=float)
    coef = np.ones_like(k)
    for i in range(j):
        coef = coef * (k + i)
    return (-1) ** j * coef * z ** (-k - j)


def _dz_step_tail(M: int, z: complex, j: int) -> complex:
    """d^j/dz^j of sum_{k>=M} z^-k = z^-M · z/(z-1) (analytic continuation to ``|z|`` < 1)."""
    tot = 0j
    for i in range(j + 1):
        n = j - i
        g = z / (z - 1) if n == 0 else (-1) ** n * math.factorial(n) * (z - 1) ** (-n - 1)
        tot += math.comb(j, i) * complex(_dz_power(np.array([M]), z, i)[0]) * g
    return tot


def _dz_ramp_tail(M: int, z: complex, j: int) -> complex:
    """d^j/dz^j of sum_{k>=M} (k-M) z^-k = z^-M · z/(z-1)²."""
    tot = 0j
    for i in range(j + 1):
        n = j - i
        g = (-1) ** n * math.factorial(n) * (z - 1) ** (-n - 1) + (-1) ** n * math.factorial(
            n + 1
        ) * (z - 1) ** (-n - 2)
        tot += math.comb(j, i) * complex(_dz_power(np.array([M]), z, i)[0]) * g
    return tot


#: the highest robustness order per mode: each order adds a row per mode to every LP and raises
#: the horizon; the paper uses 0-2, order 50 ran for seconds before this limit
MAX_ROBUST_ORDER = 8


def _normalize_orders(orders, name="orders") -> dict:
    """``{1: m1, 2: m2}`` from an int (mode 1) or a dict; ``ValueError`` naming ``name``."""
    if isinstance(orders, (int, np.integer)) and not isinstance(orders, bool):
        orders = {1: orders, 2: 0}
    elif not isinstance(orders, dict):
        raise BadInput(
            f"{name} must be an int or a dict {{mode: order}} (modes 1 and 2), got {orders!r}"
        )
    out = {1: 0, 2: 0}
    for mode, m in orders.items():
        if mode not in (1, 2) or isinstance(mode, bool):
            raise ValueError(f"{name}: modes are 1 and 2, got {mode!r}")
        out[mode] = at_most(
            f"{name}[{mode}]",
            as_int(f"{name}[{mode}]", m, minimum=0),
            MAX_ROBUST_ORDER,
            "robustness order per mode, piezo.MAX_ROBUST_ORDER",
        )
    return out


def robustness_rows_rampup(N: int, poles: dict, orders: dict, w: float, min_order: int = 0):
    """Linear conditions on ``[u_0 .. u_{N-1}, a]`` making the ramp-up command robust.

    The command is ``u_k`` for ``k < N`` and the ramp ``a + w (k − N)`` for ``k ≥ N`` (Xu & Meckl
    eq. 11, Fig. 3). Its z-transform ``U(z) = Σ u_k z^-k + z^-N (a z/(z−1) + w z/(z−1)²)``
    (Xu & Meckl eq. 12 in z) and its first ``orders[i]`` derivatives must vanish at each mode pole ``z_i``
    (Xu & Meckl eq. 13 with Xu & Meckl eqs. 15.1, 16, 17 in
    discrete form). Returns ``(E, f)`` with real rows ``E x = f``,
    each row scaled to unit norm. ``min_order = 1`` leaves out the order-0 (zero-vibration)
    rows, for a scan tracked within a tolerance instead (``ScanSpec.e_allow > 0``).
    """
    rows, rhs = [], []
    k = np.arange(N)
    for mode, m in orders.items():
        z = poles[mode]
        for j in range(min_order, m + 1):
            r = np.concatenate([_dz_power(k, z, j), [_dz_step_tail(N, z, j)]])
            c = -w * _dz_ramp_tail(N, z, j)
            for part in (np.real, np.imag):
                rows.append(part(r))
                rhs.append(part(c))
    if not rows:
        return np.zeros((0, N + 1)), np.zeros(0)
    E, f = np.array(rows), np.array(rhs)
    s = np.linalg.norm(E, axis=1)
    return E / s[:, None], f / s


def _cycle_rows(N: int, S: int, N_r: int, poles: dict, orders: dict, w: float):
    """Conditions on ``[u_up (N), a, u_ret (N_r)]``: the finite whole-cycle command (ramp-up, scan
    ramp ``a + w k`` for S samples, return, then 0) has a z-transform whose first ``orders[i]``
    derivatives vanish at each mode pole — the residual vibration after the cycle is zero and
    robust, whatever state the ramp-up left (used when the scan is only tracked within
    ``e_allow``)."""
    rows, rhs = [], []
    for mode, m in orders.items():
        z = poles[mode]
        for j in range(m + 1):
            ps = _dz_power(N + np.arange(S), z, j)
            r = np.concatenate(
                [_dz_power(np.arange(N), z, j), [ps.sum()], _dz_power(N + S + np.arange(N_r), z, j)]
            )
            c = w * (np.arange(S) * ps).sum()
            for part in (np.real, np.imag):
                rows.append(part(r))
                rhs.append(-part(c))
    E, f = np.array(rows), np.array(rhs)
    s = np.linalg.norm(E, axis=1)
    return E / s[:, None], f / s


def _scan_tracking_rows(
    N: int, model: "PZTModel", spec: "ScanSpec", w: float, G1: float, beta: float
):
    """Xu & Meckl eq. 4 on the scan: ``|y(k) − y_line(k)| <= e_allow`` and ``|Δy(k)/Ts − v_d| <= tol`` for
    the scan samples, as ``A_ub x <= b_ub`` on ``x = [u_0 .. u_{N-1}, a]`` (command continued by
    the scan ramp), with ``y_line(k) = y(T) + v_d Ts (k − N)`` and ``y(T) = G(1) a + β``."""
    A, B, C, D = _discrete(model, spec.Ts)
    S = spec.scan_samples
    K = N + S + 1
    h = np.empty(K)
    h[0] = D
    x = B.copy()
    for k in range(1, K):
        h[k] = C @ x
        x = A @ x
    Y = np.zeros((S + 1, N + 1))
    c = np.zeros(S + 1)
    for i, k in enumerate(range(N, N + S + 1)):
        j = np.arange(N)
        Y[i, :N] = h[k - j]
        jj = np.arange(N, k + 1)
        Y[i, N] = h[k - jj].sum() - G1
        c[i] = w * (h[k - jj] * (jj - N)).sum() - beta - spec.scan_velocity * spec.Ts * (k - N)
    # rows in nm and µm/s, so that the solver's absolute feasibility tolerance (~1e-7) is small
    # against the bounds (a velocity bound of 0.1 µm/s is only 2e-5 µm per sample)
    Y, c = Y * 1e3, c * 1e3
    V = (Y[1:] - Y[:-1]) / (1e3 * spec.Ts)
    cv = (c[1:] - c[:-1]) / (1e3 * spec.Ts)
    e, tv = spec.e_allow * 1e3, spec.velocity_tolerance
    A_ub = np.vstack([Y, -Y, V, -V])
    b_ub = np.concatenate([e - c, e + c, tv - cv, tv + cv])
    return A_ub, b_ub


def robustness_rows_return(N_r: int, poles: dict, orders: dict, w: float):
    """Linear conditions on ``[u_0 .. u_{N_r-1}, b]`` making the return robust and ending at rest.

    The scan ramp would continue as ``b + w k``; the return replaces it by ``u_k`` for
    ``k < N_r`` and 0 afterwards. The difference ``d = u − ramp`` has
    ``D(z) = Σ (u_k − b − w k) z^-k − z^-N_r ((b + w N_r) z/(z−1) + w z/(z−1)²)``; ``D`` and its
    first ``orders[i]`` derivatives vanish at each mode pole. Order 0 for both modes puts the
    state exactly at rest (no rigid-body mode), higher orders make it robust (Xu & Meckl eq. 8).
    """
    rows, rhs = [], []
    k = np.arange(N_r)
    for mode, m in orders.items():
        z = poles[mode]
        for j in range(m + 1):
            pk = _dz_power(k, z, j)
            coef_b = -pk.sum() - _dz_step_tail(N_r, z, j)
            const = (
                -w * (k * pk).sum()
                - w * N_r * _dz_step_tail(N_r, z, j)
                - w * _dz_ramp_tail(N_r, z, j)
            )
            r = np.concatenate([pk, [coef_b]])
            for part in (np.real, np.imag):
                rows.append(part(r))
                rhs.append(-part(const))
    E, f = np.array(rows), np.array(rhs)
    s = np.linalg.norm(E, axis=1)
    return E / s[:, None], f / s


# ----------------------------------------------------------------------------------------------
# Problem set-up
# ----------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class ScanSpec:
    """The STM scan cycle of Xu & Meckl and every choice the paper leaves open.

    Parameters
    ----------
    scan_length : float
        Scan distance, µm (paper: 6 µm).
    scan_velocity : float
        Desired scan speed v_d, µm/s (paper: 10³ µm/s).
    Ts : float
        Sampling time, s (paper: 0.2 ms).
    F_max : float
        Actuator limit ``|u|`` <= F_max of Xu & Meckl eq. 5, V. Not given by the paper; 38 V
        (``DEFAULT_F_MAX``) reproduces Table II's cycle times with mode 1 robustified.
    velocity_tolerance : float
        Velocity tracking tolerance in the scan, µm/s (paper: 0.1 µm/s). With ``e_allow = 0`` the
        shaping imposes the zero-vibration conditions exactly and this is the acceptance bound
        checked on the result; with ``e_allow > 0`` it is a constraint of the LP.
    e_allow : float
        Position tracking tolerance of Xu & Meckl eq. 4 on the scan line, µm. The paper does not give it.
        Default 0: the scan lies exactly on the line (order-0 conditions as equalities, the
        return conditions relative to the exact scan ramp). ``e_allow > 0`` replaces the order-0
        conditions of the ramp-up by the inequalities ``|y − y_line| <= e_allow`` and
        ``|v − v_d| <= velocity_tolerance`` on every scan sample, and the return conditions by
        conditions on the whole-cycle command (rest after the cycle whatever the ramp-up left).
        With the paper's 0.1 µm/s the velocity bound allows only ~7e-5 µm of 242 Hz ringing, so
        a positive ``e_allow`` does not shorten the cycles of Table II: exact is the default.
    min_scan_start : float or None
        Lower bound on y(T), µm. The paper defines a cycle as rest -> accelerate -> scan ->
        return to the start; without this bound the optimiser starts the scan below 0, hiding
        part of the fly-back inside the ramp-up. Default 0. ``None`` drops the bound.
    residual_window : float
        Length of the window after the return over which e_r is measured, s. Default 50 ms:
        12 periods of the 242 Hz mode; its envelope e^{-ζω t} decays only by 45 % in that time,
        so the maximum is reached early and the value hardly depends on the window.
    """

    scan_length: float = 6.0
    scan_velocity: float = 1e3
    Ts: float = TS
    F_max: float = DEFAULT_F_MAX
    velocity_tolerance: float = 0.1
    min_scan_start: float | None = 0.0
    residual_window: float = 50e-3
    e_allow: float = 0.0

    def __post_init__(self):
        as_positive("scan_length", self.scan_length)
        as_positive("scan_velocity", self.scan_velocity)
        as_positive("Ts", self.Ts)
        as_positive("F_max", self.F_max)
        as_positive("velocity_tolerance", self.velocity_tolerance)
        as_positive("residual_window", self.residual_window)
        as_nonnegative("e_allow", self.e_allow)
        if self.min_scan_start is not None:
            as_real("min_scan_start", self.min_scan_start)

    @property
    def scan_samples(self) -> int:
        """Number of sample intervals in the scan (30 for the paper's case)."""
        n = self.scan_length / (self.scan_velocity * self.Ts)
        if abs(n - round(n)) > 1e-9:
            raise ValueError("scan_length / (scan_velocity * Ts) must be a whole number of samples")
        return int(round(n))


def _ramp_constants(model: PZTModel, spec: ScanSpec):
    """Return (w, G1, beta): input slope per sample and y(T) = G1·a + beta (steady ramp)."""
    A, B, C, _ = _discrete(model, spec.Ts)
    eye = np.eye(A.shape[0])
    G1 = float(C @ np.linalg.solve(eye - A, B))
    w = spec.scan_velocity * spec.Ts / G1
    Q = np.linalg.solve(eye - A, B * w)
    beta = float(-C @ np.linalg.solve(eye - A, Q))
    return w, G1, beta


@dataclass
class RampUp:
    """A shaped ramp-up: ``u`` (N samples) then the ramp ``a + w (k − N)``; ``y(T) = scan_start``."""

    u: np.ndarray
    a: float
    w: float
    scan_start: float
    orders: dict
    lp_count: int = 0

    @property
    def N(self) -> int:
        return int(self.u.size)


@dataclass
class Return:
    """A shaped return from the scan ramp level ``b`` to rest: ``u`` (N_r samples), then 0."""

    u: np.ndarray
    b: float
    orders: dict
    lp_count: int = 0

    @property
    def N(self) -> int:
        return int(self.u.size)


#: Feasibility tolerance of the least-squares solver (residual of the unit-norm condition rows).
LSQ_TOL = 1e-9


def _solve_lp(A_eq, b_eq, A_ub, b_ub, bounds, n, solver="lp"):
    """Find x with ``A_eq x = b_eq`` (``A_ub x <= b_ub``) within ``bounds``, or ``None``.

    ``solver="lp"``: a feasibility LP (zero objective) with HiGHS (``scipy.optimize.linprog``).
    ``solver="lsq"``: the paper's Xu & Meckl eq. 6 literally, ``min |A_eq x − b_eq|`` within the bounds
    (bounded-variable least squares, ``scipy.optimize.lsq_linear``), feasible when the residual
    of the unit-norm rows is below ``LSQ_TOL``; only equality rows.
    """
    if solver == "lp":
        if A_eq is not None and A_eq.shape[0] == 0:
            A_eq = b_eq = None
        res = linprog(
            np.zeros(n), A_ub=A_ub, b_ub=b_ub, A_eq=A_eq, b_eq=b_eq, bounds=bounds, method="highs"
        )
        return res.x if res.status == 0 else None
    if solver == "nnls":
        if A_ub is not None or A_eq is None:
            return _solve_lp(A_eq, b_eq, A_ub, b_ub, bounds, n, "lp")
        return _screen_nnls(A_eq, b_eq, bounds)
    if A_ub is not None:
        raise ValueError(
            "solver='lsq' handles equality rows and bounds only (use solver='lp' with e_allow > 0)"
        )
    lo = np.array([b[0] for b in bounds], dtype=float)
    hi = np.array([b[1] for b in bounds], dtype=float)
    fixed = lo == hi
    x = lo.copy()
    if (~fixed).any():
        rhs = b_eq - A_eq[:, fixed] @ lo[fixed]
        res = lsq_linear(A_eq[:, ~fixed], rhs, bounds=(lo[~fixed], hi[~fixed]), method="bvls")
        x[~fixed] = res.x
    return x if np.abs(A_eq @ x - b_eq).max() <= LSQ_TOL else None


#: an NNLS residual (unit-norm rows) above this is clearly infeasible, also for the LP's tolerance
SCREEN_CLEAR = 1e-6


def _screen_nnls(A_eq, b_eq, bounds):
    """Feasibility of ``A_eq x = b_eq``, ``lo <= x <= hi`` by one non-negative least squares.

    With ``x = lo + y`` and a slack ``s`` for the upper bounds the problem is
    ``[A 0; I I] [y; s] = [b − A lo; hi − lo]``, ``y, s >= 0``: feasible iff the NNLS residual
    is zero (Lawson–Hanson active set, ``scipy.optimize.nnls``, compiled). A residual below
    ``LSQ_TOL`` is feasible, above ``SCREEN_CLEAR`` infeasible; in between the LP decides, so
    the verdicts are the LP's. Used to screen the horizons of a bisection; the command itself
    is the LP's (see :func:`_bisect_solver`).
    """
    lo = np.array([b[0] for b in bounds], dtype=float)
    hi = np.array([b[1] for b in bounds], dtype=float)
    free = lo != hi
    A = A_eq[:, free]
    m, n = A.shape
    rhs = b_eq - A_eq @ lo
    if n == 0:
        return lo if np.abs(rhs).max(initial=0.0) <= LSQ_TOL else None
    C = np.zeros((m + n, 2 * n))
    C[:m, :n] = A
    C[m:, :n] = np.eye(n)
    C[m:, n:] = np.eye(n)
    try:
        y, _ = nnls(C, np.r_[rhs, hi[free] - lo[free]], maxiter=50 * (2 * n + 1))
    except RuntimeError:  # no convergence: let the LP decide
        return _solve_lp(A_eq, b_eq, None, None, bounds, len(lo), "lp")
    x = lo.copy()
    x[free] += y[:n]
    x = np.minimum(x, hi)
    res = np.abs(A_eq @ x - b_eq).max(initial=0.0)
    if res <= LSQ_TOL:
        return x
    if res < SCREEN_CLEAR:  # marginal: the LP's tolerance decides
        return _solve_lp(A_eq, b_eq, None, None, bounds, len(lo), "lp")
    return None


def _bisect_solver(make, n_lo, n_max, solver):
    """Smallest horizon with ``make(n, solver)`` feasible, and its solution (see :func:`_bisect`).

    ``solver="lp"`` (the default): the horizons are screened by :func:`_screen_nnls` (about ten
    times faster than an LP through ``linprog``, with the LP's verdict where the screen is
    marginal) and the LP runs once, at the minimum horizon ``N`` (walking up should it find
    ``N`` infeasible). The horizon and the command are the LP's, as if every horizon had been
    an LP (the same Table II, command for command), at about one LP per search.
    """
    if solver == "lsq":
        return _bisect(lambda n: make(n, "lsq"), n_lo, n_max)
    if solver == "highs":  # an LP at every horizon (the former default)
        return _bisect(lambda n: make(n, "lp"), n_lo, n_max)
    hi, _ = _bisect(lambda n: make(n, "nnls"), n_lo, n_max)
    sol = make(hi, "lp")
    while sol is None and hi < n_max:
        hi += 1
        sol = make(hi, "lp")
    if sol is None:
        raise RuntimeError(f"no feasible horizon up to {n_max} samples (raise F_max?)")
    return hi, sol


def _check_solver(solver):
    if solver not in ("lp", "lsq", "highs"):
        raise ValueError(f"solver must be 'lp', 'lsq' or 'highs', got {solver!r}")
    return solver


def _rampup_lp(N, model, spec, orders, poles, w, G1, beta, scan_start=None, solver="lp"):
    relaxed = spec.e_allow > 0
    E, f = robustness_rows_rampup(N, poles, orders, w, min_order=1 if relaxed else 0)
    F = spec.F_max
    # the scan samples u(N) .. u(N+S-1) = a + w k must respect |u| <= F_max too
    a_lo, a_hi = -F, F - (spec.scan_samples - 1) * w
    A_ub = b_ub = None
    if relaxed:
        A_ub, b_ub = _scan_tracking_rows(N, model, spec, w, G1, beta)
        if E.shape[0] == 0:
            E = f = None
    if scan_start is not None:
        a = (scan_start - beta) / G1
        if not (a_lo - 1e-12 <= a <= a_hi + 1e-12):
            return None
        a_lo = a_hi = a
    elif spec.min_scan_start is not None:
        a_lo = max(a_lo, (spec.min_scan_start - beta) / G1)
    if a_lo > a_hi:
        return None
    bounds = [(-F, F)] * N + [(a_lo, a_hi)]
    return _solve_lp(E, f, A_ub, b_ub, bounds, N + 1, solver)


def _bisect(feasible, n_lo, n_max):
    """Smallest n in (n_lo, n_max] with feasible(n) (monotone), and its solution."""
    n = max(n_lo + 1, 1)
    sol = None
    # grow geometrically until feasible
    while n <= n_max:
        sol = feasible(n)
        if sol is not None:
            break
        n_lo, n = n, 2 * n
    if sol is None:
        if n_max > n_lo:
            sol = feasible(n_max)
            if sol is not None:
                n = n_max
        if sol is None:
            raise RuntimeError(f"no feasible horizon up to {n_max} samples (raise F_max?)")
    hi, best = n, sol
    while hi - n_lo > 1:
        mid = (hi + n_lo) // 2
        s = feasible(mid)
        if s is None:
            n_lo = mid
        else:
            hi, best = mid, s
    return hi, best


def shape_rampup(
    model: PZTModel | None = None,
    spec: ScanSpec | None = None,
    orders=None,
    scan_start: float | None = None,
    max_samples: int = 400,
    solver: str = "lp",
) -> RampUp:
    """Time-optimal (robust) ramp-up from rest to the scan velocity (Xu & Meckl eqs. 3–6, 13, 16, 17).

    Minimises the horizon N by bisection over LP feasibility problems (HiGHS): find input samples
    with ``|u| <= F_max`` (Xu & Meckl eq. 5) whose command, continued by the scan ramp, meets the m-th order
    robustness conditions (``robustness_rows_rampup``). With ``scan_start=None`` the ramp level
    ``a = u_T(T)`` is a free LP variable, which solves the paper's outer search over y(T)
    exactly (the feasible set over (U, a) is convex); with a value, y(T) is fixed as in one point
    of Fig. 4.

    Parameters
    ----------
    orders : dict or int
        Robustness order per mode, e.g. ``{1: 1, 2: 0}`` (default: non-robust, 0 for both).
    scan_start : float, optional
        Fixed y(T) in µm.
    max_samples : int
        Largest horizon tried.
    solver : {"lp", "highs", "lsq"}
        ``"lp"`` (default): the horizons screened by one NNLS each, then the feasibility LP
        (HiGHS) at the minimum horizon: the LP's horizon and command, at about one LP per search.
        ``"highs"``: a feasibility LP at every horizon (the former default, same result, slower).
        ``"lsq"``: Xu & Meckl eq. 6 literally, bounded least squares of the conditions (BVLS), feasible at
        zero residual; same horizons, another feasible command (``python -m benchmarks piezo``).
    """
    model = model or PZTModel()
    spec = spec or ScanSpec()
    orders = _normalize_orders(orders or 0)
    max_samples = as_int("max_samples", max_samples, minimum=1)
    if max_samples > MAX_HORIZON:
        raise ValueError(f"max_samples must be <= MAX_HORIZON = {MAX_HORIZON}, got {max_samples}")
    _check_solver(solver)
    if scan_start is not None:
        scan_start = as_real("scan_start", scan_start)
    poles = model.mode_poles(spec.Ts)
    w, G1, beta = _ramp_constants(model, spec)
    if scan_start is not None:
        # y(T) = G1 a + beta with the ramp level a within -F_max … F_max - (S-1) w
        # (Xu & Meckl eq. 5 on the scan)
        ends = sorted(
            (G1 * -spec.F_max + beta, G1 * (spec.F_max - (spec.scan_samples - 1) * w) + beta)
        )
        if not ends[0] - 1e-9 <= scan_start <= ends[1] + 1e-9:
            raise _Unreachable(
                f"scan_start must lie within {ends[0]:.6g} … {ends[1]:.6g} µm (the scan ramp within "
                f"|u| <= F_max = {spec.F_max:g} V), got {scan_start:g}"
            )
    count = [0]

    def feasible(N, how):
        count[0] += 1
        return _rampup_lp(N, model, spec, orders, poles, w, G1, beta, scan_start, how)

    N, x = _bisect_solver(feasible, 0, max_samples, solver)
    a = float(x[-1])
    return RampUp(
        u=x[:-1].copy(), a=a, w=w, scan_start=G1 * a + beta, orders=orders, lp_count=count[0]
    )


class _Unreachable(ValueError):
    """A ``scan_start`` outside the range the scan ramp reaches under ``|u| <= F_max``."""


def _check_return_level(b, w, F_max):
    """Refuse a ramp level ``b`` no scan under ``|u| <= F_max`` can end at (its last sample + one slope)."""
    if abs(b) > F_max + abs(w) + 1e-9:
        raise ValueError(
            f"b must lie within ±(F_max + w) = ±{F_max + abs(w):.6g} V (the scan ramp's level one "
            f"sample after its last sample, |u| <= F_max = {F_max:g} V), got {b:g}"
        )


def shape_return(
    b: float,
    model: PZTModel | None = None,
    spec: ScanSpec | None = None,
    orders=None,
    max_samples: int = 400,
    solver: str = "lp",
) -> Return:
    """Time-optimal (robust) return from the scan ramp at input level ``b`` to rest at 0.

    Bisection on the return horizon over LP feasibility problems: ``|u| <= F_max`` and the
    robustness conditions of ``robustness_rows_return`` (Xu & Meckl eq. 8 for the difference between the
    command and the continued scan ramp). Zero-order conditions for both modes put the actuator
    exactly at rest at 0.
    """
    model = model or PZTModel()
    spec = spec or ScanSpec()
    b = as_real("b", b)
    orders = _normalize_orders(orders or 0)
    max_samples = as_int("max_samples", max_samples, minimum=1)
    if max_samples > MAX_HORIZON:
        raise ValueError(f"max_samples must be <= MAX_HORIZON = {MAX_HORIZON}, got {max_samples}")
    _check_solver(solver)
    poles = model.mode_poles(spec.Ts)
    w, _, _ = _ramp_constants(model, spec)
    F = spec.F_max
    _check_return_level(b, w, F)
    count = [0]

    def feasible(N_r, how):
        count[0] += 1
        E, f = robustness_rows_return(N_r, poles, orders, w)
        bounds = [(-F, F)] * N_r + [(b, b)]
        return _solve_lp(E, f, None, None, bounds, N_r + 1, how)

    N_r, x = _bisect_solver(feasible, 0, max_samples, solver)
    return Return(u=x[:-1].copy(), b=b, orders=orders, lp_count=count[0])


def _joint_lp(N, N_r, model, spec, t_orders, r_orders, poles, w, G1, beta, solver="lp"):
    """One LP over [u_up (N), a, u_ret (N_r)]: ramp-up and return sharing the ramp level a."""
    S = spec.scan_samples
    n = N + 1 + N_r
    A_ub = b_ub = None
    if spec.e_allow > 0:
        E1, f1 = robustness_rows_rampup(N, poles, t_orders, w, min_order=1)
        E2, f2 = _cycle_rows(N, S, N_r, poles, r_orders, w)
        T_ub, t_ub = _scan_tracking_rows(N, model, spec, w, G1, beta)
        A_ub = np.hstack([T_ub, np.zeros((T_ub.shape[0], N_r))])
        b_ub = t_ub
        A = np.vstack([np.hstack([E1, np.zeros((E1.shape[0], N_r))]), E2])
        f = np.concatenate([f1, f2])
    else:
        E1, f1 = robustness_rows_rampup(N, poles, t_orders, w)
        E2, f2 = robustness_rows_return(N_r, poles, r_orders, w)
        A = np.zeros((E1.shape[0] + E2.shape[0], n))
        A[: E1.shape[0], : N + 1] = E1
        A[E1.shape[0] :, N + 1 :] = E2[:, :-1]
        A[E1.shape[0] :, N] = E2[:, -1]  # b = a + S w
        f = np.concatenate([f1, f2 - E2[:, -1] * S * w])
    F = spec.F_max
    a_lo, a_hi = -F, F - (S - 1) * w
    if spec.min_scan_start is not None:
        a_lo = max(a_lo, (spec.min_scan_start - beta) / G1)
    if a_lo > a_hi:
        return None
    bounds = [(-F, F)] * N + [(a_lo, a_hi)] + [(-F, F)] * N_r
    return _solve_lp(A, f, A_ub, b_ub, bounds, n, solver)


@dataclass
class ScanCycle:
    """A full scan cycle: ramp-up, scan, return, rest (the command and its nominal response)."""

    u: np.ndarray  # the command over the cycle (N + S + N_r samples), 0 afterwards
    N: int  # ramp-up samples
    S: int  # scan intervals
    N_r: int  # return samples
    a: float  # input level at the scan start, u_T(T)
    w: float  # input slope per sample during the scan
    scan_start: float  # y(T), µm
    tracking_orders: dict
    return_orders: dict
    spec: ScanSpec
    model: PZTModel
    lp_count: int = 0
    solve_time: float = 0.0

    @property
    def cycle_time(self) -> float:
        """Ramp-up + scan + return, s."""
        return (self.N + self.S + self.N_r) * self.spec.Ts

    @property
    def rampup_time(self) -> float:
        return self.N * self.spec.Ts

    @property
    def return_time(self) -> float:
        return self.N_r * self.spec.Ts

    def command(self, extra_time: float | None = None) -> np.ndarray:
        """The command padded with zeros for ``extra_time`` (default: the residual window)."""
        extra = (
            self.spec.residual_window
            if extra_time is None
            else as_nonnegative("extra_time", extra_time)
        )
        pad = int(round(extra / self.spec.Ts))
        return np.concatenate([self.u, np.zeros(pad)])

    def time(self, n: int) -> np.ndarray:
        return np.arange(n) * self.spec.Ts

    @property
    def scan_slice(self) -> slice:
        """Output samples of the scan: y(N) .. y(N+S)."""
        return slice(self.N, self.N + self.S + 1)


def shape_cycle(
    tracking_orders=0,
    return_orders=None,
    model: PZTModel | None = None,
    spec: ScanSpec | None = None,
    max_samples: int = 400,
    joint_extra: int = 2,
    solver: str = "lp",
) -> ScanCycle:
    """Shape a whole scan cycle: robust time-optimal ramp-up, scan, robust time-optimal return.

    A cycle (the paper does not define it; this reading reproduces Table II) is: rest at 0 ->
    accelerate to v_d -> scan ``scan_length`` at v_d -> return to rest at the start. Cycle time =
    ramp-up + scan + return.

    1. The ramp-up horizon N is minimised (bisection on LP feasibility, with the scan start
       y(T) = G(1) a + β as a free variable: the optimum of the outer search of Fig. 4).
    2. For N, N+1, ..., N+``joint_extra`` the return horizon is minimised by bisection on a joint
       LP in which ramp-up and return share the ramp level ``a`` (the return depends on where the
       scan ends); the shortest total wins (ties: the shorter ramp-up).

    Parameters
    ----------
    tracking_orders, return_orders : dict or int
        Robustness order per mode for the ramp-up ("tracking") and for the return. An int ``m``
        means ``{1: m, 2: 0}``: mode 1 robustified, mode 2 only cancelled nominally.
        ``return_orders`` defaults to ``tracking_orders``.
    solver : {"lp", "highs", "lsq"}
        Feasibility solver per horizon (see ``shape_rampup``).
    """
    t0 = time.perf_counter()
    model = model or PZTModel()
    spec = spec or ScanSpec()
    t_orders = _normalize_orders(tracking_orders, "tracking_orders")
    r_orders = (
        dict(t_orders)
        if return_orders is None
        else _normalize_orders(return_orders, "return_orders")
    )
    joint_extra = as_int("joint_extra", joint_extra, minimum=0)
    _check_solver(solver)
    up = shape_rampup(model, spec, t_orders, max_samples=max_samples, solver=solver)
    poles = model.mode_poles(spec.Ts)
    w, G1, beta = _ramp_constants(model, spec)
    count = [up.lp_count]
    best = None
    for N in range(up.N, up.N + joint_extra + 1):

        def feasible(N_r, how, N=N):
            count[0] += 1
            return _joint_lp(N, N_r, model, spec, t_orders, r_orders, poles, w, G1, beta, how)

        try:
            if solver == "lp":  # screen only; the LP runs once, for the winner below
                N_r, x = _bisect(lambda n, f=feasible: f(n, "nnls"), 0, max_samples)
            else:
                N_r, x = _bisect_solver(feasible, 0, max_samples, solver)
        except RuntimeError:
            continue
        if best is None or N + N_r < best[0] + best[1]:
            best = (N, N_r, x, feasible)
    if best is None:
        raise RuntimeError("no feasible return (raise F_max or max_samples)")
    N, N_r, x, feasible = best
    if solver == "lp":
        x = feasible(N_r, "lp")
        if x is None:  # the screen and the LP disagree here: an LP everywhere
            return shape_cycle(
                tracking_orders,
                return_orders,
                model,
                spec,
                max_samples=max_samples,
                joint_extra=joint_extra,
                solver="highs",
            )
    S = spec.scan_samples
    a = float(x[N])
    u = np.concatenate([x[:N], a + w * np.arange(S), x[N + 1 :]])
    return ScanCycle(
        u=u,
        N=N,
        S=S,
        N_r=N_r,
        a=a,
        w=w,
        scan_start=G1 * a + beta,
        tracking_orders=t_orders,
        return_orders=r_orders,
        spec=spec,
        model=model,
        lp_count=count[0],
        solve_time=time.perf_counter() - t0,
    )


# ----------------------------------------------------------------------------------------------
# Fig. 4: the outer search over y(T)
# ----------------------------------------------------------------------------------------------
def rampup_time_vs_scan_start(
    scan_starts,
    orders=1,
    model: PZTModel | None = None,
    spec: ScanSpec | None = None,
    max_samples: int = 200,
) -> np.ndarray:
    """Minimum ramp-up time for each fixed scan start y(T) (Xu & Meckl Fig. 4).

    For each y(T) the ramp level ``a = u_T(T)`` follows from Xu & Meckl eq. 18 in its discrete form
    (``y(T) = G(1) a + β``), so the terminal conditions are fixed and the minimum horizon is found
    by bisection on LP feasibility, as in the paper's iterative search. Returns the times in s
    (``nan`` where no horizon up to ``max_samples`` is feasible, e.g. y(T) beyond what F_max
    allows). The minimum over y(T) equals ``shape_rampup(...)`` with y(T) free; the feasible
    window at that minimum is only a few hundredths of a µm wide, so a coarse grid overestimates
    the optimum.
    """
    scan_starts = as_finite_array("scan_starts", scan_starts, ndim=1)
    model = model or PZTModel()
    spec = spec or ScanSpec()
    out = np.full(scan_starts.size, np.nan)
    for i, y0 in enumerate(scan_starts):
        try:
            r = shape_rampup(model, spec, orders, scan_start=float(y0), max_samples=max_samples)
        except (RuntimeError, _Unreachable):
            continue
        out[i] = r.N * spec.Ts
    return out


# ----------------------------------------------------------------------------------------------
# Evaluation (Table II)
# ----------------------------------------------------------------------------------------------
@dataclass
class CycleEvaluation:
    """Performance of a scan cycle under a plant perturbation (Xu & Meckl Table II).

    ``e_m``: max ``|y_perturbed − y_nominal|`` over the scan (perturbed tracking error);
    ``e_r``: max ``|y_perturbed − y_nominal|`` over ``residual_window`` after the return (perturbed
    residual vibration); ``velocity_error``: max ``|v − v_d|`` of the nominal output in the scan, with
    v the sample-to-sample velocity (µm/s); ``t``, ``y_nominal``, ``y_perturbed`` are the traces.
    """

    cycle_time: float
    e_m: float
    e_r: float
    velocity_error: float
    perturbed_velocity_error: float
    t: np.ndarray
    u: np.ndarray
    y_nominal: np.ndarray
    y_perturbed: np.ndarray


def evaluate_cycle(
    cycle: ScanCycle, perturbed: PZTModel | None = None, freq_scale: float = 1.1, modes=(1,)
) -> CycleEvaluation:
    """Cycle time, e_m, e_r and the scan velocity error of ``cycle`` (Xu & Meckl Table II).

    The perturbed plant defaults to ``cycle.model.perturbed(freq_scale, modes)`` (+10 % on ω1,
    DC gain held). Simulation of the ZOH models from rest, the command padded with zeros for the
    residual window.
    """
    cycle = as_instance("cycle", cycle, ScanCycle, "a jerklab.piezo.ScanCycle")
    spec = cycle.spec
    if perturbed is None:
        perturbed = cycle.model.perturbed(freq_scale, modes)
    else:
        as_instance("perturbed", perturbed, PZTModel, "a jerklab.piezo.PZTModel or None")
    u = cycle.command()
    y = simulate(cycle.model, u, spec.Ts)
    yp = simulate(perturbed, u, spec.Ts)
    sl = cycle.scan_slice
    n_end = cycle.N + cycle.S + cycle.N_r
    d = np.abs(yp - y)
    v = np.diff(y[sl]) / spec.Ts
    vp = np.diff(yp[sl]) / spec.Ts
    return CycleEvaluation(
        cycle_time=cycle.cycle_time,
        e_m=float(d[sl].max()),
        e_r=float(d[n_end:].max()),
        velocity_error=float(np.abs(v - spec.scan_velocity).max()),
        perturbed_velocity_error=float(np.abs(vp - spec.scan_velocity).max()),
        t=cycle.time(u.size),
        u=u,
        y_nominal=y,
        y_perturbed=yp,
    )


#: The four inputs of Table II: (tracking orders, return orders); an int m means mode 1 at
#: order m and mode 2 at order 0.
TABLE_II_INPUTS = {
    "non-robust": (0, 0),
    "1st-order robust": (1, 1),
    "2nd-order robust": (2, 2),
    "combined-robust": (1, 2),
}


def table_ii(
    F_max: float = DEFAULT_F_MAX,
    model: PZTModel | None = None,
    spec: ScanSpec | None = None,
    freq_scale: float = 1.1,
    perturbed_modes=(1,),
    inputs=None,
    solver: str = "lp",
) -> dict:
    """Reproduce Xu & Meckl Table II with one call.

    Shapes the non-robust, 1st-order, 2nd-order and combined-robust (1st-order tracking, 2nd-order
    return) scan cycles with one actuator limit ``F_max`` and evaluates each under the +10 %
    natural-frequency perturbation. Returns ``{name: row}`` where ``row`` is a dict with keys
    ``cycle``, ``evaluation``, ``cycle_time``, ``e_m``, ``e_r``, ``velocity_error``, ``paper``
    (the published (cycle time, e_m, e_r)). ``solver`` as in ``shape_cycle``.

    Examples
    --------
    >>> from jerklab.piezo import table_ii, format_table_ii
    >>> print(format_table_ii(table_ii()))          # doctest: +SKIP
    """
    F_max = as_positive("F_max", F_max)
    model = model or PZTModel()
    spec = replace(spec or ScanSpec(), F_max=F_max)
    inputs = TABLE_II_INPUTS if inputs is None else inputs
    out = {}
    for name, (t_o, r_o) in inputs.items():
        c = shape_cycle(t_o, r_o, model, spec, solver=solver)
        ev = evaluate_cycle(c, freq_scale=freq_scale, modes=perturbed_modes)
        out[name] = {
            "cycle": c,
            "evaluation": ev,
            "cycle_time": ev.cycle_time,
            "e_m": ev.e_m,
            "e_r": ev.e_r,
            "velocity_error": ev.velocity_error,
            "paper": TABLE_II_PAPER.get(name),
        }
    return out


def format_table_ii(rows: dict) -> str:
    """Format ``table_ii()`` next to the paper's values as a text table."""
    lines = [
        f"{'input':<18} {'cycle ms':>9} {'paper':>6} {'e_m µm':>8} {'paper':>6} "
        f"{'e_r µm':>8} {'paper':>6} {'|v-v_d| µm/s':>13}"
    ]
    for name, r in rows.items():
        p = r["paper"] or (float("nan"),) * 3
        lines.append(
            f"{name:<18} {r['cycle_time'] * 1e3:9.1f} {p[0] * 1e3:6.1f} {r['e_m']:8.4f} "
            f"{p[1]:6.3f} {r['e_r']:8.4f} {p[2]:6.2f} {r['velocity_error']:13.2e}"
        )
    return "\n".join(lines)


# ----------------------------------------------------------------------------------------------
# Time-energy-optimal return (Xu & Meckl eq. 19, Fig. 7)
# ----------------------------------------------------------------------------------------------
def _least_squares_qp(E, f, lo, hi, M=None, m=None, x0=None):
    """min ½|M u − m|² s.t. E u = f, lo <= u <= hi (small strictly convex QP) with SLSQP.

    ``M = I``, ``m = 0`` (the default) is the minimum-norm problem of Xu & Meckl eq. 19.
    """
    n = E.shape[1]
    M = np.eye(n) if M is None else M
    m = np.zeros(M.shape[0]) if m is None else m
    if x0 is None:
        x0 = np.clip(E.T @ np.linalg.lstsq(E @ E.T, f, rcond=None)[0], lo, hi)
    H, g = M.T @ M, M.T @ m
    res = minimize(
        lambda u: 0.5 * u @ H @ u - g @ u,
        x0,
        jac=lambda u: H @ u - g,
        method="SLSQP",
        bounds=list(zip(lo, hi)),
        constraints=[{"type": "eq", "fun": lambda u: E @ u - f, "jac": lambda u: E}],
        options={"maxiter": 1000, "ftol": 1e-14},
    )
    # status 8 ("positive directional derivative in line search") is SLSQP stalling at round-off
    # when the feasible set is a thin sliver (k_r at the time-optimal minimum); accept the point
    # if it satisfies the constraints.
    x = np.clip(res.x, lo, hi)
    if res.status not in (0, 8) or np.abs(E @ x - f).max() > 1e-7 * max(1.0, np.abs(f).max()):
        return None
    return x


def energy_optimal_return(
    b: float,
    k_r: int,
    model: PZTModel | None = None,
    spec: ScanSpec | None = None,
    orders=1,
    objective: str = "input",
) -> Return:
    """Time-energy-optimal return of ``k_r`` steps (Xu & Meckl eq. 19, Fig. 7).

    Minimises a quadratic cost over the return samples subject to (a) the terminal/robustness
    conditions (rest at 0, m-th order robust: ``robustness_rows_return``, the discrete form of
    ``Φ U = x_d − A^k x_0``) and (b) ``|u| <= F_max``. Larger ``k_r`` (than the time-optimal
    return) trades time for a smoother transition.

    Parameters
    ----------
    objective : {"input", "increment"}
        ``"input"``: ``½ UᵀU`` exactly as Xu & Meckl eq. 19. The return starts from the top of the scan ramp
        (~38 V), so this cost pulls the input to 0 at once: a step that swings the output far
        below the start (several µm) before the robustness conditions cancel it — the opposite of
        the smooth transitions of Fig. 7 (the paper is silent on this). ``"increment"``:
        ``½ Σ (u_k − u_{k−1})²`` with ``u_{−1} = b`` (continuous with the scan) and
        ``u_{k_r} = 0``: the energy of the input *changes*, which gives the smooth, monotone-ish
        returns that Fig. 7 shows.

    Raises ``RuntimeError`` if ``k_r`` is shorter than the time-optimal return.
    """
    model = model or PZTModel()
    spec = spec or ScanSpec()
    b = as_real("b", b)
    k_r = as_int("k_r", k_r, minimum=1)
    if k_r > MAX_HORIZON:
        raise ValueError(f"k_r must be <= MAX_HORIZON = {MAX_HORIZON} samples, got {k_r}")
    orders = _normalize_orders(orders)
    if objective not in ("input", "increment"):
        raise ValueError(f"objective must be 'input' or 'increment', got {objective!r}")
    w, _, _ = _ramp_constants(model, spec)
    _check_return_level(b, w, spec.F_max)
    E, f = robustness_rows_return(k_r, model.mode_poles(spec.Ts), orders, w)
    E_u, f_u = E[:, :-1], f - E[:, -1] * b
    F = spec.F_max
    x0 = _solve_lp(E_u, f_u, None, None, [(-F, F)] * k_r, k_r)
    if x0 is None:
        raise RuntimeError(f"k_r = {k_r} is shorter than the time-optimal return")
    M = m = None
    if objective == "increment":
        M = np.eye(k_r + 1, k_r) - np.eye(k_r + 1, k_r, -1)
        m = np.zeros(k_r + 1)
        m[0] = b
    u = _least_squares_qp(E_u, f_u, np.full(k_r, -F), np.full(k_r, F), M, m, x0=x0)
    if u is None:
        raise RuntimeError("the QP of Xu & Meckl eq. 19 did not converge")
    return Return(u=u, b=b, orders=orders)


def with_return(cycle: ScanCycle, ret: Return) -> ScanCycle:
    """Return a copy of ``cycle`` with its return section replaced by ``ret``."""
    b = cycle.a + cycle.S * cycle.w
    if abs(ret.b - b) > 1e-9 * max(1.0, abs(b)):
        raise ValueError(f"ret starts at input level {ret.b}, the cycle's scan ends at {b}")
    u = np.concatenate([cycle.u[: cycle.N + cycle.S], ret.u])
    return replace(cycle, u=u, N_r=ret.N, return_orders=ret.orders)


# ----------------------------------------------------------------------------------------------
# Closed loop (Figs. 8, 9)
# ----------------------------------------------------------------------------------------------
def _s_poles(zeta, f):
    w = 2 * math.pi * f
    return [
        complex(-zeta * w, w * math.sqrt(1 - zeta**2)),
        complex(-zeta * w, -w * math.sqrt(1 - zeta**2)),
    ]


@dataclass
class FeedbackGains:
    """Discrete pole-placement state feedback with integral action and an observer.

    ``u_fb = −K (x̂ − x_d) − k_i ξ``, ``ξ(k+1) = ξ(k) + (y(k) − y_d(k))``,
    ``x̂(k+1) = A x̂ + B u + L (y − C x̂)``; ``poles`` and ``observer_poles`` are the z-plane
    poles placed.
    """

    K: np.ndarray
    k_i: float
    L: np.ndarray
    poles: np.ndarray
    observer_poles: np.ndarray
    Ts: float


def pole_placement_gains(
    model: PZTModel | None = None,
    Ts: float = TS,
    mode1_damping: float = 0.1,
    integral_frequency: float = 60.0,
    observer_speedup: float = 2.0,
    observer_damping: float = 0.7,
) -> FeedbackGains:
    """Pole-placement feedback for the ZOH PZT model (Xu & Meckl, closed loop, Fig. 8).

    The paper only says "pole placement". Choices (continuous poles mapped by z = e^{sTs}):
    mode 1 keeps its frequency, its damping raised from 0.008 to ``mode1_damping``; mode 2 and
    its damping (0.39) are kept; an integrator (creep, static cancellation errors) gets a real
    pole at ``integral_frequency`` Hz; the observer poles are the plant's modes at
    ``observer_speedup`` times their frequency with damping ``observer_damping`` plus a fast real
    pole. Modest gains keep the loop robust to the +10 % frequency error and leave the shaped
    command to do the fast part of the work.
    """
    model = model or PZTModel()
    Ts = as_positive("Ts", Ts)
    mode1_damping = as_positive("mode1_damping", mode1_damping)
    integral_frequency = as_positive("integral_frequency", integral_frequency)
    observer_speedup = as_positive("observer_speedup", observer_speedup)
    observer_damping = as_positive("observer_damping", observer_damping)
    if mode1_damping >= 1 or observer_damping >= 1:
        raise ValueError("mode1_damping and observer_damping must be < 1")
    A, B, C, _ = _discrete(model, Ts)
    n = A.shape[0]
    Aa = np.block([[A, np.zeros((n, 1))], [C[None, :], np.ones((1, 1))]])
    Ba = np.concatenate([B, [0.0]])[:, None]
    s = (
        _s_poles(mode1_damping, model.f_1)
        + _s_poles(model.zeta_2, model.f_2)
        + [-2 * math.pi * integral_frequency]
    )
    zp = np.exp(np.array(s) * Ts)
    so = _s_poles(observer_damping, observer_speedup * model.f_1) + _s_poles(
        observer_damping, observer_speedup * model.f_2
    )
    zo = np.exp(np.array(so) * Ts)
    try:
        Ka = np.asarray(control.place(Aa, Ba, zp)).ravel()
        L = np.asarray(control.place(A.T, C[:, None], zo)).ravel()
    except (np.linalg.LinAlgError, ValueError) as exc:
        raise ValueError(
            f"no pole placement for Ts = {Ts!r} s, integral_frequency = {integral_frequency!r} Hz, "
            f"observer_speedup = {observer_speedup!r}: the requested discrete poles "
            f"coincide or underflow ({exc})"
        ) from None
    return FeedbackGains(K=Ka[:n], k_i=float(Ka[n]), L=L, poles=zp, observer_poles=zo, Ts=Ts)


@dataclass
class ClosedLoopResult:
    """Closed-loop simulation (Xu & Meckl Fig. 9): traces and the scan tracking error."""

    t: np.ndarray
    y_desired: np.ndarray  # nominal output of the shaped command, µm
    y: np.ndarray  # closed-loop output of the perturbed plant, µm
    u_ff: np.ndarray  # shaped command (desired hysteresis output), V
    u_r: np.ndarray  # reference of the hysteresis: feedforward + feedback (Xu & Meckl Fig. 1), V
    u_c: np.ndarray  # compensated command on the actuator, H⁻¹(u_r) by the CNIA (Fig. 1), V
    f: np.ndarray  # hysteresis output reaching G (with cancellation error), V
    scan_slice: slice
    scan_error: float  # max |y − y_desired| over the scan, µm
    open_loop_scan_error: float  # the same without feedback, µm


def closed_loop(
    cycle: ScanCycle,
    perturbed: PZTModel | None = None,
    gains: FeedbackGains | None = None,
    hysteresis=None,
    actuator=None,
    cancellation_error: float = 0.15,
    cancellation_model: str = "branch",
    extra_time: float = 10e-3,
    feedback: bool = True,
) -> ClosedLoopResult:
    """Closed-loop simulation of a shaped scan cycle (Xu & Meckl Figs. 8, 9).

    Per sample: the shaped command ``u_ff`` plus pole-placement feedback on the error to the
    nominal trajectory gives ``u_r``, the reference (desired output) of the hysteresis; the CNIA of
    the identified model ``hysteresis`` (``Preisach.invert``) gives the actuator voltage ``u_c``
    (names as in Xu & Meckl Fig. 1 and notebook 08; before 2026-11 ``u_c`` and ``u_r`` were
    swapped here); the
    actuator's own hysteresis ``actuator`` (``Preisach.apply``) turns it into ``f``, plus a
    cancellation error; ``f`` drives the perturbed linear plant.

    Parameters
    ----------
    perturbed : PZTModel
        The true linear plant (default: +10 % on ω1, DC gain held).
    hysteresis, actuator : Preisach-like, optional
        The identified operator (inverted) and the actuator's operator (applied); each needs
        ``invert(f_d)`` / ``apply(u)`` on scalars with memory, and ``copy()``. ``actuator``
        defaults to a copy of ``hysteresis``. ``None`` for both: ideal cancellation.
        Both are first driven (from their current memory) to output 0, the rest state.
    cancellation_error : float
        Amplitude of the hysteresis cancellation error, V (paper: 0.15 V).
    cancellation_model : {"branch", "constant"}
        The paper gives only the amplitude. "branch" (default): ``+e`` while ``u_r`` rises,
        ``−e`` while it falls (held when it does not move), the sign pattern of a mismatch
        between identified and true hysteresis loops; "constant": ``+e`` throughout.
    extra_time : float
        Simulated time after the cycle, s.
    feedback : bool
        ``False`` runs the same chain open loop.
    """
    cycle = as_instance("cycle", cycle, ScanCycle, "a jerklab.piezo.ScanCycle")
    if perturbed is not None:
        as_instance("perturbed", perturbed, PZTModel, "a jerklab.piezo.PZTModel or None")
    for name, op, needs in (
        ("hysteresis", hysteresis, ("invert", "apply", "copy", "input")),
        ("actuator", actuator, ("apply", "copy")),
    ):
        if op is not None:
            as_having(name, op, needs, "a jerklab.hysteresis.Preisach (or one like it) or None")
    cancellation_error = as_nonnegative("cancellation_error", cancellation_error)
    if cancellation_model not in ("branch", "constant"):
        raise ValueError(
            f"cancellation_model must be 'branch' or 'constant', got {cancellation_model!r}"
        )
    extra_time = as_nonnegative("extra_time", extra_time)
    spec, model = cycle.spec, cycle.model
    perturbed = perturbed or model.perturbed()
    gains = gains or pole_placement_gains(model, spec.Ts)
    u_ff = cycle.command(extra_time)
    n_s = u_ff.size
    A, B, C, D = _discrete(model, spec.Ts)
    Ap, Bp, Cp, Dp = _discrete(perturbed, spec.Ts)
    # nominal state trajectory of the shaped command
    xd = np.zeros((n_s + 1, A.shape[0]))
    for k in range(n_s):
        xd[k + 1] = A @ xd[k] + B * u_ff[k]
    yd = xd[:-1] @ C + D * u_ff

    def run(use_fb):
        H = hysteresis.copy() if hysteresis is not None else None
        Ha = (actuator.copy() if actuator is not None else H.copy()) if H is not None else None
        if H is not None:
            H.invert(0.0)
            Ha.apply(H.input)
        x = np.zeros(Ap.shape[0])
        xh = np.zeros(A.shape[0])
        xi = 0.0
        y = np.empty(n_s)
        uc = np.empty(n_s)
        ur = np.empty(n_s)
        f = np.empty(n_s)
        sign = 1.0 if cancellation_model == "constant" else 0.0
        prev = 0.0
        for k in range(n_s):
            y[k] = Cp @ x  # strictly proper plant (D = 0)
            u = u_ff[k]
            if use_fb:
                u = u - gains.K @ (xh - xd[k]) - gains.k_i * xi
            uc[k] = u
            if cancellation_model == "branch" and u != prev:
                sign = 1.0 if u > prev else -1.0
            prev = u
            if H is not None:
                ur[k] = H.invert(u)
                f[k] = Ha.apply(ur[k])
            else:
                ur[k] = u
                f[k] = u
            f[k] += sign * cancellation_error
            x = Ap @ x + Bp * f[k]
            if use_fb:
                xi += y[k] - yd[k]
                xh = A @ xh + B * u + gains.L * (y[k] - C @ xh)
        return y, uc, ur, f

    y, uc, ur, f = run(feedback)
    sl = cycle.scan_slice
    y_ol = run(False)[0] if feedback else y
    return ClosedLoopResult(
        t=cycle.time(n_s),
        y_desired=yd,
        y=y,
        u_ff=u_ff,
        u_r=uc,
        u_c=ur,
        f=f,
        scan_slice=sl,
        scan_error=float(np.abs(y - yd)[sl].max()),
        open_loop_scan_error=float(np.abs(y_ol - yd)[sl].max()),
    )


# ----------------------------------------------------------------------------------------------
# Table II's open choices (F_max, which modes are robustified) and the actuator limit in Fig. 9
# ----------------------------------------------------------------------------------------------
#: The readings of "robustified" compared by :func:`table_ii_sensitivity`: the order of each input
#: of Table II applies to mode 1 only (mode 2 cancelled nominally) or to both modes.
TABLE_II_MODE_READINGS = {"mode 1": (1,), "both modes": (1, 2)}


def _orders_for(m: int, modes) -> dict:
    return {1: m if 1 in modes else 0, 2: m if 2 in modes else 0}


def table_ii_sensitivity(
    F_max_values=(20.0, 30.0, 38.0, 50.0, 70.0, 100.0),
    readings=None,
    model: PZTModel | None = None,
    spec: ScanSpec | None = None,
    freq_scale: float = 1.1,
    solver: str = "lp",
) -> list:
    """Xu & Meckl Table II under each reading of the choices the paper leaves open.

    The paper gives neither the actuator limit ``F_max`` (Xu & Meckl eq. 5) nor whether "m-th order robust"
    applies to mode 1 only or to both modes. For each ``F_max`` and each reading this shapes the
    four inputs (as :func:`table_ii`) and evaluates them under the +10 % perturbation of ω1.
    A cycle too short for the limit (no feasible horizon) gives NaN.

    Parameters
    ----------
    F_max_values : sequence of float
        Actuator limits to try, V (> 0).
    readings : dict, optional
        ``{name: modes}`` (default :data:`TABLE_II_MODE_READINGS`).

    Returns
    -------
    list of dict
        One row per (reading, F_max): ``reading``, ``F_max``, ``rows`` (``{input: (cycle s, e_m
        µm, e_r µm)}``) and ``distance`` (:func:`table_ii_distance`).
    """
    readings = TABLE_II_MODE_READINGS if readings is None else dict(readings)
    F_list = [as_positive("F_max_values", F) for F in F_max_values]
    if not F_list:
        raise ValueError("F_max_values must not be empty")
    model = model or PZTModel()
    out, memo = [], {}
    for name, modes in readings.items():
        if not modes or any(m not in (1, 2) for m in modes):
            raise ValueError(f"readings[{name!r}]: modes are 1 and/or 2, got {modes!r}")
        inputs = {
            k: (_orders_for(t, modes), _orders_for(r, modes))
            for k, (t, r) in TABLE_II_INPUTS.items()
        }
        for F in F_list:
            rows = {}
            for k, (t_o, r_o) in inputs.items():
                key = (F, tuple(t_o.items()), tuple(r_o.items()))  # the non-robust row is shared
                if key not in memo:
                    try:
                        c = shape_cycle(
                            t_o, r_o, model, replace(spec or ScanSpec(), F_max=F), solver=solver
                        )
                    except RuntimeError:
                        memo[key] = (math.nan, math.nan, math.nan)
                    else:
                        ev = evaluate_cycle(c, freq_scale=freq_scale, modes=(1,))
                        memo[key] = (ev.cycle_time, ev.e_m, ev.e_r)
                rows[k] = memo[key]
            out.append(
                {"reading": name, "F_max": F, "rows": rows, "distance": table_ii_distance(rows)}
            )
    return out


def table_ii_distance(rows: dict) -> dict:
    """Distance of a reproduction of Table II from the published table.

    ``cycle_rms_ms``: root mean square of (ours − paper) cycle time over the four inputs, ms;
    ``cycle_max_ms``: the largest absolute difference, ms; ``error_factor``: the largest ratio
    max(ours/paper, paper/ours) over all e_m and e_r. NaN if any input is infeasible.

    Parameters
    ----------
    rows : dict
        ``{input name: (cycle time s, e_m µm, e_r µm)}`` for the inputs of ``TABLE_II_PAPER``.
    """
    d_t, fac = [], []
    for name, (tp, emp, erp) in TABLE_II_PAPER.items():
        if name not in rows:
            raise ValueError(f"rows: missing input {name!r}")
        t, em, er = rows[name]
        d_t.append((t - tp) * 1e3)
        fac += [max(em / emp, emp / em), max(er / erp, erp / er)]
    d_t = np.asarray(d_t)
    return {
        "cycle_rms_ms": float(np.sqrt(np.mean(d_t**2))),
        "cycle_max_ms": float(np.abs(d_t).max()),
        "error_factor": float(max(fac)),
    }


def best_table_ii_reading(sensitivity: list) -> dict:
    """The row of :func:`table_ii_sensitivity` closest to the paper (smallest ``cycle_rms_ms``,
    ties broken by ``error_factor``); infeasible rows are skipped."""
    ok = [r for r in sensitivity if np.isfinite(r["distance"]["cycle_rms_ms"])]
    if not ok:
        raise ValueError("sensitivity: no feasible reading")
    return min(
        ok, key=lambda r: (round(r["distance"]["cycle_rms_ms"], 9), r["distance"]["error_factor"])
    )


@dataclass(frozen=True)
class LimitExcursion:
    """Where a signal exceeds ``|u| <= F_max``: peak value (V) and its time (s), time above (s),
    and the intervals ``[(t_start, t_end), ...]`` (s) in which it is above."""

    F_max: float
    peak: float
    t_peak: float
    time_above: float
    intervals: tuple


def limit_excursions(t, u, F_max: float = DEFAULT_F_MAX) -> LimitExcursion:
    """Find where ``u`` leaves the actuator range ``|u| <= F_max`` (Xu & Meckl eq. 5).

    Parameters
    ----------
    t, u : array_like
        Sample times (s, equally spaced) and values (V) of one signal, same length.
    F_max : float
        The limit, V (> 0).
    """
    t = as_finite_array("t", t)
    u = as_finite_array("u", u)
    if t.shape != u.shape or t.ndim != 1 or t.size < 2:
        raise ValueError("t and u must be 1-D arrays of the same length (>= 2)")
    F_max = as_positive("F_max", F_max)
    dt = float(t[1] - t[0])
    above = np.abs(u) > F_max
    k = int(np.argmax(np.abs(u)))
    edges = np.flatnonzero(np.diff(np.r_[0, above.astype(int), 0]))
    intervals = tuple((float(t[a]), float(t[b - 1] + dt)) for a, b in zip(edges[::2], edges[1::2]))
    return LimitExcursion(F_max, float(u[k]), float(t[k]), float(above.sum() * dt), intervals)


__all__ += [
    "TABLE_II_MODE_READINGS",
    "table_ii_sensitivity",
    "table_ii_distance",
    "best_table_ii_reading",
    "LimitExcursion",
    "limit_excursions",
]
