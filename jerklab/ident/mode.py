"""The flexible mode of motor and load found from the encoder alone (``identify_mode``).

A two-mass model (:class:`jerklab.plant.FlexibleDCMotor`: K, tau, load ratio, shaft frequency
and damping) is fitted by output error to a drive-voltage record and the motor-side encoder
angle; the mode is the lightly damped pole pair of the fitted model (:func:`coupled_mode`).
``jerklab.shaping`` designs the input shaper for it (``jerklab.shaping.identify_mode`` adds the
recommendation): identification knows nothing of shapers.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares
from scipy.signal import csd, lfilter, welch

from jerklab._validate import as_finite_array, as_positive
from jerklab.ident._common import _signal
from jerklab.ident.data import IdentData
from jerklab.plant import FlexibleDCMotor


def _flex_matrices(K, tau, ratio, wr, zr):
    Jm = tau / (1.0 + ratio)
    Jl = tau * ratio / (1.0 + ratio)
    k = wr * wr * Jl
    c = 2.0 * zr * wr * Jl
    A = np.array(
        [
            [0.0, 1.0, 0.0, 0.0],
            [-k / Jm, -(1.0 + c) / Jm, k / Jm, c / Jm],
            [0.0, 0.0, 0.0, 1.0],
            [k / Jl, c / Jl, -k / Jl, -c / Jl],
        ]
    )
    B = np.array([0.0, K / Jm, 0.0, 0.0])
    return A, B


def coupled_mode(K, tau, load_ratio, mode_frequency, mode_damping):
    """(natural frequency Hz, damping) of the complex pole pair of the two-mass model.

    The coupled mode of motor and load of :class:`jerklab.plant.FlexibleDCMotor` with these
    parameters (K rad/(V s), tau s, load ratio, shaft frequency rad/s and damping), open loop:
    what rings when the motor moves. ``(nan, nan)`` when the pair is real (overdamped).
    """
    K, tau, ratio, wr, zr = K, tau, load_ratio, mode_frequency, mode_damping
    A, _ = _flex_matrices(K, tau, ratio, wr, zr)
    ev = np.linalg.eigvals(A)
    c = ev[np.abs(ev.imag) > 1e-9]
    if c.size == 0:
        return math.nan, math.nan
    s = c[np.argmax(c.imag)]
    wn = abs(s)
    return wn / (2 * math.pi), -s.real / wn


def _flex_simulate(p, u, Ts):
    """Motor angle θ_m(k), k = 0 .. len(u), from rest for the log-parameters ``p`` (exact ZOH).

    ``Φ = V e^{ΛTs} V⁻¹`` and ``Γ = V diag((e^{λTs} − 1)/λ) V⁻¹ B`` from the eigenvectors of the
    continuous model (``(e^{λTs} − 1)/λ → Ts`` at the integrator), which is the exact ZOH model
    (``scipy.linalg.expm`` of the augmented matrix gives the same, two orders slower).
    """
    K, tau, ratio, wr, zr = np.exp(p[:5])
    A, B = _flex_matrices(K, tau, ratio, wr, zr)
    lam, V = np.linalg.eig(A)
    e = np.exp(lam * Ts)
    small = np.abs(lam) < 1e-9
    phi = np.where(small, Ts, (e - 1) / np.where(small, 1.0, lam))
    Vi = np.linalg.inv(V)
    Phi = np.real((V * e) @ Vi)
    Gam = np.real((V * phi) @ (Vi @ B))
    den = np.real(np.poly(e))
    num = np.real(np.poly(Phi - np.outer(Gam, [1.0, 0, 0, 0]))) - den  # C (zI − Φ)^-1 Γ, C = e1
    return lfilter(num, den, np.concatenate([u, [0.0]]))


@dataclass
class ModeEstimate:
    """The flexible mode found by :func:`identify_mode`.

    ``frequency_hz``, ``damping``: the lightly damped pole pair of the fitted two-mass model
    (natural frequency, Hz; damping ratio), with standard errors ``frequency_se``,
    ``damping_se`` (linearized: residual variance × (JᵀJ)⁻¹, carried to (f, ζ) by the delta
    method). ``params`` holds K (rad/(V s)), tau (s), load_ratio, mode_frequency (rad/s) and
    mode_damping of ``jerklab.plant.FlexibleDCMotor``; ``fit_percent`` is the NRMSE fit of the
    simulated encoder angle (100 % = perfect); ``jerk_time`` the S-curve jerk time ``1/f_d``
    that puts a spectral zero on the mode (s); ``residual_std`` the residual standard deviation
    of the angle increments (rad). ``jerklab.shaping.identify_mode`` returns the same with the
    input shaper it recommends for the mode (``jerklab.shaping.ModeFit``).
    """

    frequency_hz: float
    damping: float
    frequency_se: float
    damping_se: float
    params: dict
    fit_percent: float
    jerk_time: float
    residual_std: float

    def model(self):
        """The fitted plant as an ideal :class:`jerklab.plant.FlexibleDCMotor`."""
        return FlexibleDCMotor(**self.params).ideal()


def identify_mode(u, y=None, Ts=None, f_range=None, max_nfev=400) -> ModeEstimate:
    """Find the flexible mode from a drive-voltage record ``u`` and the encoder angle ``y``.

    A two-mass model (:class:`jerklab.plant.FlexibleDCMotor`: K, τ, load ratio, shaft
    frequency and damping) is fitted by output error (the prediction-error method with an
    output-error noise model: the simulated encoder angle against the measured one,
    ``scipy.optimize.least_squares`` on log-parameters, on the angle *increments* per sample so
    that the encoder's constant floor-quantization offset and the integrator's drift drop
    out). Start values: a rigid fit of K, τ (the fit's first stage), then the resonance (peak)
    and antiresonance (dip) of the ratio between the empirical frequency response (Welch
    cross-spectra) and the rigid model, which give the coupled and the shaft frequency and
    hence the load ratio. The reported mode is the complex pole pair of the fitted model (see
    :func:`coupled_mode`): what rings when the motor moves.

    Parameters
    ----------
    u : array_like or jerklab.ident.IdentData
        Drive voltage per sample (V), held over each sample (a chirp: ``jerklab.shaping.chirp_input``, or
        ``jerklab.ident.prbs``); or a whole record (``IdentData``: its ``u``, ``y``, ``Ts``; then
        leave ``y`` and ``Ts`` out).
    y : array_like
        Encoder angle (rad): ``len(u) + 1`` samples (``plant.open_loop``'s convention: ``y[k]``
        read at ``k Ts`` before ``u[k]``) or ``len(u)`` (then the last input is not used).
    Ts : float
        Sample period, s.
    f_range : (float, float), optional
        Band (Hz) searched for the mode in the start values; default 0.5 Hz to 0.45/Ts.
    max_nfev : int
        Function evaluations of the final fit.

    Returns
    -------
    ModeEstimate
        The standard errors are statistical only: they say how well this record pins the mode
        down, not how much the machine will move it.
    """
    if isinstance(u, IdentData):
        if y is not None or Ts is not None:
            raise TypeError("y and Ts must be left out when u is an IdentData record")
        u, y, Ts = u.voltage, u.position, u.Ts
    if y is None or Ts is None:
        raise TypeError("y and Ts are required (or pass an IdentData record as u)")
    u = _signal("u", as_finite_array("u", u, ndim=1), min_len=1)
    y = _signal("y", as_finite_array("y", y, ndim=1), min_len=1)
    Ts = as_positive("Ts", Ts)
    if y.size == u.size:
        u = u[:-1]
    if y.size != u.size + 1:
        raise ValueError(
            f"y must have len(u) + 1 (or len(u)) samples, got {y.size} for {u.size + 1}"
        )
    if u.size < 64:
        raise ValueError(f"u must have at least 64 samples, got {u.size}")
    if np.ptp(u) == 0:
        raise ValueError("u must vary (a constant input excites no mode)")
    if np.ptp(y) == 0:
        raise ValueError("y must vary (the encoder did not move)")
    fmax = 0.45 / Ts
    if f_range is None:
        f_range = (0.5, fmax)
    f_lo, f_hi = (as_positive("f_range", v) for v in f_range)
    if not f_lo < f_hi:
        raise ValueError(f"f_range must be (low, high) with low < high, got {f_range!r}")
    dy_meas = np.diff(y)
    scale = np.std(dy_meas) or 1.0

    def resid(q, nmode=True):
        # output error on the angle increments: an integrating plant's angle error grows with
        # any gain error, its increments do not (the same minimum, a better-shaped cost)
        p = (
            q[:5]
            if nmode
            else np.r_[q[:2], math.log(1e-6), math.log(2 * math.pi * fmax), math.log(0.5)]
        )
        with np.errstate(all="ignore"):
            try:
                r = (np.diff(_flex_simulate(p, u, Ts)) - dy_meas) / scale
            except (np.linalg.LinAlgError, ValueError):
                r = np.full(dy_meas.size, 1e6)
        return np.where(np.isfinite(r), r, 1e6)

    # stage 1: rigid K, τ (a negligible load far above the band)
    q0 = np.array(
        [math.log(max(np.ptp(y) / max(np.abs(u).sum() * Ts, 1e-12), 1e-6)), math.log(20 * Ts)]
    )
    best = None
    for ltau in (math.log(5 * Ts), math.log(20 * Ts), math.log(100 * Ts)):
        q0[1] = ltau
        try:
            with np.errstate(all="ignore"):
                r = least_squares(lambda q: resid(q, False), q0, method="lm", max_nfev=200)
        except (ValueError, np.linalg.LinAlgError):
            continue
        if best is None or r.cost < best.cost:
            best = r
    K0, tau0 = np.exp(best.x[:2])
    # stage 2: resonance and antiresonance of the measured response against the rigid model
    dy = np.diff(y)
    nper = min(u.size, 1 << max(6, int(math.log2(u.size / 4))))
    f, Puy = csd(u, dy, fs=1 / Ts, nperseg=nper)
    _, Puu = welch(u, fs=1 / Ts, nperseg=nper)
    H = Puy / np.where(Puu > 0, Puu, np.inf)  # Δθ per sample / V
    band = (f >= f_lo) & (f <= f_hi) & (f > 0)
    s = 2j * math.pi * np.where(band, f, 1.0)
    rigid = K0 / (s * (tau0 * s + 1)) * (1 - np.exp(-s * Ts))  # Δθ per sample per V (ZOH ignored)
    ratio = np.abs(H[band] / np.where(np.abs(rigid[band]) > 0, rigid[band], np.nan))
    fb = f[band]
    starts = []
    if fb.size >= 3 and np.all(np.isfinite(ratio)):
        ip = int(np.argmax(ratio))
        idip = int(np.argmin(ratio[:ip])) if ip > 0 else None
        fc = fb[ip]
        fr = fb[idip] if idip is not None and ratio[idip] < 0.9 else fc / math.sqrt(1.1)
        starts.append((fc, fr))
    starts += [(fc_, fc_ / math.sqrt(1.1)) for fc_ in np.geomspace(f_lo * 2, f_hi / 1.5, 5)]
    fits = []
    for fc, fr in starts:
        lr = min(max((fc / fr) ** 2 - 1.0, 0.01), 3.0)
        for zr in (0.02, 0.1):
            q = np.array(
                [
                    math.log(K0),
                    math.log(tau0),
                    math.log(lr),
                    math.log(2 * math.pi * fr),
                    math.log(zr),
                ]
            )
            try:
                with np.errstate(all="ignore"):
                    r = least_squares(resid, q, method="trf", max_nfev=60, x_scale="jac")
            except (ValueError, np.linalg.LinAlgError, OverflowError):
                continue
            if np.all(np.isfinite(r.fun)):
                fits.append(r)
    if not fits:
        raise RuntimeError("identify_mode: no start value gave a finite fit")
    best = min(fits, key=lambda r: r.cost)
    with np.errstate(all="ignore"):
        r = least_squares(
            resid,
            best.x,
            method="trf",
            max_nfev=int(as_positive("max_nfev", max_nfev)),
            x_scale="jac",
        )
    if not np.isfinite(coupled_mode(*np.exp(r.x[:5]))[0]):
        # the best two-mass model has no lightly damped pole pair: no mode to report (the
        # worse fits' modes are not the record's)
        raise ValueError(
            "identify_mode: the best fit of this record is overdamped (no lightly damped pole "
            "pair, so no mode to report): is a flexible load mounted? Excite the mode (a PRBS "
            "whose bits last less than a quarter of its period, or a chirp across it), record "
            f"longer, or set f_range about the mode (searched: {f_lo:g} to {f_hi:g} Hz)"
        )
    q = r.x
    e = r.fun * scale
    dof = max(e.size - q.size, 1)
    s2 = float(e @ e) / dof
    J = r.jac * scale
    cov = s2 * np.linalg.pinv(J.T @ J)
    fm, zm = coupled_mode(*np.exp(q[:5]))
    G = np.zeros((2, q.size))
    for i in range(5):
        h = 1e-6
        qp, qm = q.copy(), q.copy()
        qp[i] += h
        qm[i] -= h
        G[:, i] = (
            np.array(coupled_mode(*np.exp(qp[:5]))) - np.array(coupled_mode(*np.exp(qm[:5])))
        ) / (2 * h)
    cf = G @ cov @ G.T
    f_se, z_se = (math.sqrt(max(v, 0.0)) for v in np.diag(cf))
    fit = 100.0 * (1 - np.linalg.norm(e) / np.linalg.norm(dy_meas - dy_meas.mean()))
    K, tau, lr, wr, zr = (float(v) for v in np.exp(q[:5]))
    jt = 1.0 / (fm * math.sqrt(max(1 - zm * zm, 1e-12)))
    return ModeEstimate(
        frequency_hz=fm,
        damping=zm,
        frequency_se=f_se,
        damping_se=z_se,
        params=dict(K=K, tau=tau, load_ratio=lr, mode_frequency=wr, mode_damping=zr),
        fit_percent=float(fit),
        jerk_time=jt,
        residual_std=math.sqrt(s2),
    )
