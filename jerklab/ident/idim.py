"""Inverse-dynamics identification of motion control (IDIM-LS and IDIM-IV, Gautier & Janot).

The start of the output-error fit, and an estimator of its own (``method="idim"``,
``"idim-iv"``): u = (tau/K) omega' + omega/K + f_c sign(omega) - offset + dead_zone sign(u) on the
low-passed angle's derivatives, every column and u filtered by the same zero-phase Butterworth
filter (parallel filtering).
"""

from __future__ import annotations

import functools
import math

import numpy as np
from scipy import signal

from jerklab.ident.model import _drive, _simulate_segments


@functools.lru_cache(maxsize=64)
def _lowpass(Ts, cutoff):
    """4th-order Butterworth (b, a) at ``cutoff`` Hz (at most 0.95 Nyquist); read-only arrays,
    designed once per (Ts, cutoff): a fit filters several times with the same filter."""
    nyq = 0.5 / Ts
    wn = min(cutoff / nyq, 0.95)
    b, a = signal.butter(4, wn)
    b.flags.writeable = a.flags.writeable = False
    return b, a


def _filtered_states(theta, Ts, cutoff):
    """Zero-phase low-passed angle, velocity and acceleration at the midpoints (k + 1/2) Ts.

    The derivatives of the filtered angle (central differences about the midpoint); the input held
    on [k Ts, (k+1) Ts) belongs to the same instant. Returns (theta_mid, omega, alpha) for
    k = 1 .. N - 3 (N - 3 values).
    """
    b, a = _lowpass(Ts, cutoff)
    thf = signal.filtfilt(
        b, a, theta, padtype="odd", padlen=min(3 * max(len(a), len(b)), theta.size - 1)
    )
    w = (thf[2:-1] - thf[1:-2]) / Ts
    al = (thf[3:] - thf[2:-1] - thf[1:-2] + thf[:-3]) / (2.0 * Ts * Ts)
    return 0.5 * (thf[2:-1] + thf[1:-2]), w, al


def _idim_rows(u, theta, Ts, cutoff, delay, opts, theta_inst=None, offset_guess=0.0):
    """Rows of the inverse-dynamics regression u = (tau/K) alpha + (1/K) omega + f_c sgn(omega)
    - offset + dead_zone sgn(u + offset), all sides low-passed by the same filter (parallel
    filtering, Gautier & Janot). ``theta_inst`` (a simulated angle) builds the instruments."""
    b, a = _lowpass(Ts, cutoff)
    pad = min(3 * max(len(a), len(b)), u.size - 1)
    ud = _drive(u, 0.0, 0.0, delay)
    uf = signal.filtfilt(b, a, ud, padtype="odd", padlen=pad)[1:-2]

    def columns(th):
        _, w, al = _filtered_states(th, Ts, cutoff)
        cols = [al, w]
        if opts["friction"]:
            cols.append(
                signal.filtfilt(
                    b,
                    a,
                    np.sign(np.concatenate([[w[0]], w, [w[-1]] * 2])),
                    padtype="odd",
                    padlen=pad,
                )[1:-2]
            )
        if opts["offset"]:
            cols.append(-np.ones(w.size))
        if opts["dead_zone"]:
            cols.append(
                signal.filtfilt(b, a, np.sign(ud + offset_guess), padtype="odd", padlen=pad)[1:-2]
            )
        return np.column_stack(cols), w

    X, w = columns(theta)
    keep = np.ones(w.size, bool)
    if opts["friction"]:
        # friction is set-valued at rest: drop the samples where the motor (nearly) stands still
        wmax = float(np.max(np.abs(w)))
        keep = np.abs(w) > 0.05 * wmax
    Z = None
    if theta_inst is not None:
        Z, _ = columns(theta_inst)
        Z = Z[keep]
    return X[keep], uf[keep], Z


def _params_from_idim(p, opts):
    """(tau/K, 1/K, [f_c], [offset], [dead_zone]) -> dict of physical parameters."""
    out = {
        "K": 1.0 / p[1] if p[1] != 0 else math.inf,
        "tau": p[0] / p[1] if p[1] != 0 else math.nan,
    }
    i = 2
    for name in ("friction", "offset", "dead_zone"):
        if opts[name]:
            out[name] = float(p[i])
            i += 1
        else:
            out[name] = 0.0
    return out


def _idim(exps, Ts, delay, opts, cutoff, iv_iterations=0, segment_n=None):
    """Inverse-dynamics identification (IDIM-LS, optionally IDIM-IV) over merged experiments."""
    Xs, ys = [], []
    for u, th in exps:
        X, y, _ = _idim_rows(u, th, Ts, cutoff, delay, opts)
        Xs.append(X)
        ys.append(y)
    X = np.vstack(Xs)
    y = np.concatenate(ys)
    if X.shape[0] < X.shape[1] + 2:
        raise ValueError("theta: too few moving samples for the inverse-dynamics regression")
    p, *_ = np.linalg.lstsq(X, y, rcond=None)
    Z = None
    for _ in range(iv_iterations):
        par = _params_from_idim(p, opts)
        if not (par["K"] > 0 and par["tau"] > 0):
            break
        Xs, Zs, ys = [], [], []
        for u, th in exps:
            th_sim = _shooting_sim(u, th, Ts, par, delay, cutoff, segment_n)
            X_, y_, Z_ = _idim_rows(u, th, Ts, cutoff, delay, opts, th_sim, -par["offset"])
            Xs.append(X_)
            Zs.append(Z_)
            ys.append(y_)
        X, Z, y = np.vstack(Xs), np.vstack(Zs), np.concatenate(ys)
        try:
            p = np.linalg.solve(Z.T @ X, Z.T @ y)
        except np.linalg.LinAlgError:
            break
    r = y - X @ p
    dof = max(y.size - p.size, 1)
    s2 = float(r @ r) / dof
    if Z is None:
        cov = s2 * np.linalg.pinv(X.T @ X)
    else:
        A = np.linalg.pinv(Z.T @ X)
        cov = s2 * A @ (Z.T @ Z) @ A.T
    return p, cov, float(r @ r), X


def _shooting_sim(u, th, Ts, par, delay, cutoff, segment_n):
    """Simulate the model re-started every ``segment_n`` samples from the filtered measured state
    (the auxiliary model whose output builds the instruments of IDIM-IV)."""
    n = u.size
    L = n if segment_n is None else max(int(segment_n), 20)
    starts = np.arange(0, n, L)
    thm, w, _ = _filtered_states(th, Ts, cutoff)
    idx = np.clip(starts, 0, w.size - 1)
    v = _drive(u, par["offset"], max(par["dead_zone"], 0.0), delay)
    return _simulate_segments(
        v, max(par["friction"], 0.0), par["K"], par["tau"], Ts, starts, th[starts], w[idx]
    )
