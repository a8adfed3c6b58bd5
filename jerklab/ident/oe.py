"""Output error (the prediction-error method with an output-error noise model, Ljung §4.2).

Single shooting of Stojčić eq. 1 (ASCII: Stojcic) from rest, and multiple shooting of the full model
(:func:`jerklab.ident.simulate_motor`): each segment of the record starts from its own estimated
state, so neither a closed-loop record nor an integrating plant can drift.
"""

from __future__ import annotations

import math

import numpy as np
from scipy import optimize

from jerklab.ident.idim import _filtered_states
from jerklab.ident.model import _shift, _simulate_segments, _unit_response


def _pem_model(u, theta, Ts, fit_theta0, friction):
    """Simulated angle as a function of p = [K, ln tau, (theta0), (f_c)]."""
    su = np.sign(u)

    lo, hi = math.log(Ts * 1e-4), math.log(Ts * u.size * 1e4)

    def sim(p):
        K, tau = p[0], math.exp(min(max(p[1], lo), hi))  # keep tau finite on hopeless data
        i = 2
        th0 = theta[0]
        if fit_theta0:
            th0 = p[i]
            i += 1
        ue = u - p[i] * su if friction else u
        return K * _unit_response(tau, Ts, ue) + th0

    return sim


def _initial_guess(u, theta, Ts, fit_theta0, friction):
    """Variable projection over tau on a log grid: for fixed tau the angle is linear in
    K, theta0 and K f_c, so each grid point is one small least-squares problem."""
    N = u.size
    taus = np.geomspace(Ts / 20.0, max(N * Ts, 2 * Ts), 40)
    best = None
    target = theta if fit_theta0 else theta - theta[0]
    for tau in taus:
        cols = [_unit_response(tau, Ts, u)]
        if fit_theta0:
            cols.append(np.ones(N))
        if friction:
            cols.append(-_unit_response(tau, Ts, np.sign(u)))
        M = np.column_stack(cols)
        coef, *_ = np.linalg.lstsq(M, target, rcond=None)
        r = target - M @ coef
        sse = float(r @ r)
        if best is None or sse < best[0]:
            K = coef[0]
            th0 = coef[1] if fit_theta0 else theta[0]
            fc = coef[-1] / K if (friction and K != 0) else 0.0
            best = (sse, K, tau, th0, fc)
    return best[1:]


def _fit_pem(u, theta, Ts, fit_theta0, friction=False):
    sim = _pem_model(u, theta, Ts, fit_theta0, friction)
    K0, tau0, th00, fc0 = _initial_guess(u, theta, Ts, fit_theta0, friction)
    p0 = [K0, math.log(tau0)]
    if fit_theta0:
        p0.append(th00)
    if friction:
        p0.append(fc0)
    p0 = np.array(p0)

    def resid(p):
        return sim(p) - theta

    sol = optimize.least_squares(
        resid, p0, method="lm", x_scale="jac", xtol=1e-12, ftol=1e-12, gtol=1e-12, max_nfev=2000
    )
    p = sol.x
    # Jacobian at the optimum by central differences (more accurate than the solver's own)
    J = np.empty((theta.size, p.size))
    for i in range(p.size):
        h = 1e-6 * max(abs(p[i]), 1e-3)
        dp = np.zeros_like(p)
        dp[i] = h
        J[:, i] = (sim(p + dp) - sim(p - dp)) / (2 * h)
    r = sim(p) - theta
    dof = max(theta.size - p.size, 1)
    s2 = float(r @ r) / dof
    try:
        cov_p = s2 * np.linalg.inv(J.T @ J)
    except np.linalg.LinAlgError:
        cov_p = np.full((p.size, p.size), np.nan)
    if not math.log(Ts * 1e-4) < p[1] < math.log(Ts * u.size * 1e4):
        raise ValueError(
            f"theta: the output-error fit ran tau to {math.exp(p[1]):.3g} s, outside any motor this "
            f"record can describe (is the angle sampled with u, does the motor have an integrator?)"
        )
    K, tau = p[0], math.exp(p[1])
    # (K, log tau) -> (K, tau)
    T = np.diag([1.0, tau])
    cov = T @ cov_p[:2, :2] @ T
    th0 = p[2] if fit_theta0 else theta[0]
    fc = fc_std = None
    if friction:
        fc, fc_std = float(p[-1]), float(math.sqrt(max(cov_p[-1, -1], 0.0)))
    return K, tau, cov, th0, sol.nfev, math.sqrt(s2), fc, fc_std, sim(p)


def _segment_starts(n, segment_n):
    if segment_n is None or segment_n >= n:
        return np.array([0])
    starts = np.arange(0, n, segment_n)
    if n - starts[-1] < max(segment_n // 2, 10) and starts.size > 1:
        starts = starts[:-1]  # fold a short tail into the previous segment
    return starts


def _fit_oe_ms(exps, Ts, delay, opts, init, segment_n, cutoff, max_nfev=200):
    """Output error with multiple shooting: global (K, ln tau, [f_c], [offset], [dead_zone]) and an
    initial state (theta0, omega0) per segment, minimising sum (theta - theta_sim)^2 over all
    segments of all experiments (Ljung §4.2 output error; Bock's multiple shooting without
    continuity constraints, i.e. each segment a short output-error problem with its own initial
    state, so an integrating plant cannot drift over a long record)."""
    names = ["K", "tau"] + [nm for nm in ("friction", "offset", "dead_zone") if opts[nm]]
    coast = opts.get("coast", False)
    if coast is True:
        names.append("tau_coast")
    ng = len(names)
    vs_u, ths, starts_all, offsets = [], [], [], []
    pos = 0
    for u, th in exps:
        st = _segment_starts(u.size, segment_n)
        starts_all.append(st + pos)
        vs_u.append(_shift(u, delay))
        ths.append(th)
        offsets.append(pos)
        pos += u.size
    starts = np.concatenate(starts_all)
    ucat = np.concatenate(vs_u)
    theta = np.concatenate(ths)
    cmask = ucat == 0.0 if coast else None
    nseg = starts.size
    # the dead zone stays below the largest input it acts on (a larger one would stop the motor for
    # good, and lets K run to infinity against it); reaching this bound is reported
    dz_max = float(np.max(np.abs(ucat))) + 2.0 * abs(init.get("offset", 0.0))
    # initial segment states from the filtered record
    th0, om0 = [], []
    for (u, th), st in zip(exps, starts_all):
        _, w, _ = _filtered_states(th, Ts, cutoff)
        base = st[0]
        for s_ in st - base:
            th0.append(th[s_])
            om0.append(w[min(max(s_ - 1, 0), w.size - 1)])
    tau_lo, tau_hi = math.log(Ts * 1e-3), math.log(Ts * theta.size * 1e3)
    if coast is True and "coast_rate" not in init:
        # start the coasting rate 1/tau_coast from the best of 0 and a few fractions of 1/tau (one
        # simulation each, segment states from the filtered record)
        best = None
        for m in (0.0, 1.0 / 64, 1.0 / 16, 1.0 / 4, 1.0):
            v = ucat + init["offset"]
            if init["dead_zone"] > 0:
                v = np.sign(v) * np.maximum(np.abs(v) - init["dead_zone"], 0.0)
            ys = _simulate_segments(
                v,
                max(init["friction"], 0.0),
                init["K"],
                init["tau"],
                Ts,
                starts,
                th0,
                om0,
                cmask,
                m / init["tau"],
            )
            c = float(np.sum((ys - theta) ** 2))
            if best is None or c < best[0]:
                best = (c, m / init["tau"])
        init = dict(init, coast_rate=max(best[1], 1e-3 / init["tau"]))
    # the coasting enters as its rate 1/tau_coast >= 0 (|p|, like friction): 0 is a motor with no
    # viscous drag, whose open-drive run-down is Coulomb friction alone
    gl = [init["K"], math.log(init["tau"])] + [
        init["coast_rate"] if nm == "tau_coast" else init[nm] for nm in names[2:]
    ]
    x0 = np.concatenate([gl, np.ravel(np.column_stack([th0, om0]))])
    # friction and dead zone enter as |p| (>= 0 without bounds, so MINPACK's Levenberg-Marquardt
    # can be used: it is much faster than a bounded trust region on hundreds of segment states);
    # ln tau is clamped to a range no motor leaves, so a hopeless record cannot overflow
    x0[1] = min(max(x0[1], tau_lo + 1e-6), tau_hi - 1e-6)
    for i, nm in enumerate(names[2:], start=2):
        if nm in ("friction", "dead_zone"):
            x0[i] = max(abs(x0[i]), 1e-6)
        if nm == "dead_zone":
            x0[i] = min(x0[i], 0.5 * dz_max)
        if nm == "tau_coast":
            x0[i] = abs(x0[i])

    def unpack(x):
        g = dict(zip(names, x[:ng]))
        g["tau"] = math.exp(min(max(g["tau"], tau_lo), tau_hi))
        if coast is True:
            g["coast_rate"] = abs(g.pop("tau_coast"))
        else:
            g["coast_rate"] = 0.0
        for nm in ("friction", "dead_zone"):
            g[nm] = abs(g.get(nm, 0.0))
        g["dead_zone"] = min(g["dead_zone"], dz_max)
        g.setdefault("offset", 0.0)
        return g, x[ng::2], x[ng + 1 :: 2]

    def model(x):
        g, t0, w0 = unpack(x)
        v = ucat + g["offset"]
        if g["dead_zone"]:
            v = np.sign(v) * np.maximum(np.abs(v) - g["dead_zone"], 0.0)
        return _simulate_segments(
            v, g["friction"], g["K"], g["tau"], Ts, starts, t0, w0, cmask, g["coast_rate"]
        )

    def resid(x):
        return model(x) - theta

    seg_of = np.repeat(np.arange(nseg), np.diff(np.append(starts, theta.size)))

    def jac(x):
        # globals by central differences; the segment angles exactly (the model is invariant to a
        # shift of the angle); the segment velocities by one grouped difference (segments are
        # independent, so one perturbed simulation gives every segment's column)
        J = np.zeros((theta.size, x.size))
        for i in range(ng):
            h = 1e-6 * max(abs(x[i]), 1e-2)
            xp, xm = x.copy(), x.copy()
            xp[i] += h
            xm[i] -= h
            J[:, i] = (model(xp) - model(xm)) / (2 * h)
        J[np.arange(theta.size), ng + 2 * seg_of] = 1.0
        w0 = x[ng + 1 :: 2]
        h = 1e-6 * max(float(np.max(np.abs(w0))), 1e-2)
        xp, xm = x.copy(), x.copy()
        xp[ng + 1 :: 2] += h
        xm[ng + 1 :: 2] -= h
        J[np.arange(theta.size), ng + 2 * seg_of + 1] = (model(xp) - model(xm)) / (2 * h)
        return J

    sol = optimize.least_squares(
        resid,
        x0,
        jac=jac,
        method="lm",
        x_scale="jac",
        xtol=1e-8,
        ftol=1e-9,
        gtol=1e-9,
        max_nfev=max_nfev,
    )
    x = sol.x
    J = jac(x)
    r = resid(x)
    dof = max(theta.size - x.size, 1)
    s2 = float(r @ r) / dof
    cov_x = s2 * np.linalg.pinv(J.T @ J)
    g, t0, w0 = unpack(x)
    # (K, ln tau, ...) -> (K, tau, ...)
    T = np.eye(ng)
    T[1, 1] = g["tau"]
    rate_sd = 0.0
    if coast is True:
        # tau_coast = 1/rate: d tau_coast / d rate = -1/rate^2 (infinite at rate 0)
        rate_sd = math.sqrt(max(cov_x[ng - 1, ng - 1], 0.0))
        T[ng - 1, ng - 1] = -1.0 / g["coast_rate"] ** 2 if g["coast_rate"] > 0 else 0.0
    cov = T @ cov_x[:ng, :ng] @ T
    if coast is True and not g["coast_rate"] > 0:
        cov[ng - 1, ng - 1] = math.inf
    if coast:
        g["tau_coast"] = 1.0 / g["coast_rate"] if g["coast_rate"] > 0 else math.inf
    Jg = None
    sd = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    at_bound = [
        nm
        for i, nm in enumerate(names)
        if nm in ("friction", "dead_zone")
        and (g[nm] <= 1e-4 * float(np.max(np.abs(ucat))) or g[nm] < 2.0 * sd[i])
    ]
    if not (tau_lo + 1e-3 < x[1] < tau_hi - 1e-3):
        at_bound.append("tau")
    if coast is True and g["coast_rate"] <= 2.0 * rate_sd:
        at_bound.append("tau_coast")
    if "dead_zone" in names and g["dead_zone"] >= 0.98 * dz_max:
        at_bound.append("dead_zone_max")
    y_sim = theta + r  # r = model - theta
    return dict(
        par=g,
        names=names,
        cov=cov,
        y_sim=y_sim,
        theta=theta,
        nfev=sol.nfev,
        s=math.sqrt(s2),
        nseg=nseg,
        starts=starts,
        seg_theta0=t0,
        seg_omega0=w0,
        at_bound=at_bound,
        cost=float(r @ r),
        Jg=Jg,
        exp_offsets=offsets,
    )
