"""Closed-loop simulation of the digital positioning system (Stojčić §3, §4B).

The controller runs at ``Ts`` on quantized measurements; between samples the plant is
integrated exactly (closed-form ZOH, with Coulomb-friction events, see
:mod:`jerklab.plant`), so the only approximations are the ones the rig makes: supply
saturation, PWM and encoder quantization, noise.

At sample ``k`` (``t = k Ts``):

1. the encoder gives ``y(k)`` = floor(θ(kTs)·counts/rad)/(counts/rad) (+ noise);
2. the profile is sampled in closed form at ``kTs`` (position, velocity, acceleration);
3. the :class:`~jerklab.controller.DigitalController` law (eqs. 16–18, output clamp,
   anti-windup) gives ``u(k)``; position loop ``e = r − y``, or the paper's velocity loop
   ``e = ω_r − (y(k) − y(k−1))/Ts`` (pulses per sample, §4B);
4. the amplifier applies ``quantize_voltage(u(k))`` during ``[kTs, (k+1)Ts)``.

The loop is one compiled kernel (numba, if installed; else the same code in Python),
cross-checked in the tests against stepping ``DigitalController`` and
``DCMotor.step_state`` in Python and against python-control on the linear loop.
:func:`simulate_batch` runs many perturbed plants (K, τ, friction) at once.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from jerklab._validate import as_finite_array, as_nonnegative, as_positive, as_real
from jerklab.controller import DigitalController, DiscreteGains, Feedforward, Gains
from jerklab.plant import DCMotor, FlexibleDCMotor, advance, advance_em

__all__ = ["simulate", "simulate_batch", "SimResult", "BatchResult", "perturbed_plants",
           "SampledProfile", "StepProfile", "HAVE_NUMBA"]

try:
    from numba import njit as _njit

    HAVE_NUMBA = True

    def _jit(f):
        return _njit(cache=True, nogil=True)(f)
except ImportError:  # pragma: no cover
    HAVE_NUMBA = False

    def _jit(f):
        return f


# ---------------------------------------------------------------------------
# the compiled kernel
# ---------------------------------------------------------------------------
@_jit
def _encoder(th, cpr):
    """Counter reading floor(θ·cpr) as an angle (cpr = 0: ideal sensor)."""
    if cpr > 0.0:
        return np.floor(th * cpr + 1e-9) / cpr
    return th


@_jit
def _pid(e, e_prev, i_prev, d_prev, ff, kpd, kid, kdd, gamma, limit, aw):
    """Eq. 16-18 with the output clamp and conditional integration → (u, p, i, d, sat)."""
    p = kpd * e
    i_new = i_prev + kid * e
    d = gamma * d_prev + kdd * (e - e_prev)
    u = ff + p + i_new + d
    sat = False
    if u > limit:
        sat = True
        if aw and e > 0.0:
            u -= i_new - i_prev
            i_new = i_prev
        if u > limit:
            u = limit
    elif u < -limit:
        sat = True
        if aw and e < 0.0:
            u -= i_new - i_prev
            i_new = i_prev
        if u < -limit:
            u = -limit
    return u, p, i_new, d, sat


@_jit
def _amplifier(u, supply, levels):
    """Supply clamp and PWM rounding (lround) → (voltage, clamped)."""
    if supply <= 0.0:
        return u, False
    clamped = False
    v = u
    if v > supply:
        v = supply
        clamped = True
    elif v < -supply:
        v = -supply
        clamped = True
    if levels > 0.0:
        q = v / supply * levels
        if q >= 0.0:
            q = np.floor(q + 0.5)
        else:
            q = -np.floor(-q + 0.5)
        v = q / levels * supply
    return v, clamped


@_jit
def _rigid_step(th, om, v, k, Ts, fc, K, tau, em_full, dist_on, dist_amp, dist_time):
    """Exact rigid-plant step over [k Ts, (k+1) Ts) with the disturbance split."""
    t0 = k * Ts
    if dist_on and t0 < dist_time and dist_time < t0 + Ts:
        a = dist_time - t0
        th, om = advance_em(th, om, v, fc, K, tau, a, -math.expm1(-a / tau))
        b = t0 + Ts - dist_time
        return advance_em(th, om, v + dist_amp, fc, K, tau, b, -math.expm1(-b / tau))
    w = dist_amp if (dist_on and t0 >= dist_time) else 0.0
    return advance_em(th, om, v + w, fc, K, tau, Ts, em_full)


@_jit
def _kernel(rpos, rvel, racc, noise, x0,
            rigid, K, tau, fc, Phi, Gam, Phi_a, Gam_a, Phi_b, Gam_b,
            dist_on, dist_amp, dist_time,
            supply, levels, cpr,
            kpd, kid, kdd, gamma, ff_on, ffK, fftau, limit, aw, velocity, scale, bumpless, Ts,
            X, meas, ucmd, uapp, P, I, D, FF, E, sat):
    """One run, every signal stored (see :func:`simulate` for the order of events)."""
    n = rpos.shape[0]
    ns = x0.shape[0]
    x = x0.copy()
    xn = np.empty(ns)
    em_full = -math.expm1(-Ts / tau)
    i_prev = 0.0
    e_prev = 0.0
    d_prev = 0.0
    y_prev = 0.0
    for k in range(n):
        for j in range(ns):
            X[k, j] = x[j]
        y = _encoder(x[0], cpr) + noise[k]
        meas[k] = y
        if velocity:
            if k == 0:
                y_prev = y
            e = scale * (rvel[k] - (y - y_prev) / Ts)
        else:
            e = scale * (rpos[k] - y)
        y_prev = y
        ff = (fftau * racc[k] + rvel[k]) / ffK if ff_on else 0.0
        if k == 0 and bumpless:
            e_prev = e
        u, p, i_prev, d_prev, s = _pid(e, e_prev, i_prev, d_prev, ff, kpd, kid, kdd, gamma, limit, aw)
        e_prev = e
        v, s2 = _amplifier(u, supply, levels)
        ucmd[k] = u
        P[k] = p
        I[k] = i_prev
        D[k] = d_prev
        FF[k] = ff
        E[k] = e
        uapp[k] = v
        sat[k] = s or s2
        if rigid:
            th1, om1 = _rigid_step(x[0], x[1], v, k, Ts, fc, K, tau, em_full, dist_on, dist_amp, dist_time)
            x[0] = th1
            x[1] = om1
        else:
            t0 = k * Ts
            if dist_on and t0 < dist_time and dist_time < t0 + Ts:
                for r in range(ns):
                    acc = Gam_a[r] * v
                    for c in range(ns):
                        acc += Phi_a[r, c] * x[c]
                    xn[r] = acc
                for r in range(ns):
                    acc = Gam_b[r] * (v + dist_amp)
                    for c in range(ns):
                        acc += Phi_b[r, c] * xn[c]
                    x[r] = acc
            else:
                w = dist_amp if (dist_on and t0 >= dist_time) else 0.0
                for r in range(ns):
                    acc = Gam[r] * (v + w)
                    for c in range(ns):
                        acc += Phi[r, c] * x[c]
                    xn[r] = acc
                for r in range(ns):
                    x[r] = xn[r]
    return x


@_jit
def _batch_chunk(j0, j1, rpos, rvel, racc, Ks, taus, fcs, noise, noise_on,
                 dist_on, dist_amp, dist_time, supply, levels, cpr,
                 kpd, kid, kdd, gamma, ff_on, ffK, fftau, limit, aw, velocity, scale, bumpless, Ts,
                 duration, distance, band, keep, POS, U, MET):
    """Plants ``j0 … j1-1``, same law as :func:`_kernel`; metrics accumulated on the fly.

    Time is the outer loop and the plants the inner one, so the independent plants
    overlap in the CPU pipeline (one plant alone is a chain of dependent operations).
    MET[j] = max|e|, sum e^2 during the move, final e, last index outside the band,
    max|u applied|, number of samples in the move.
    """
    m = j1 - j0
    n = rpos.shape[0]
    th = np.zeros(m)
    om = np.zeros(m)
    ip = np.zeros(m)
    ep = np.zeros(m)
    dp = np.zeros(m)
    yp = np.zeros(m)
    em = np.empty(m)
    for q in range(m):
        j = j0 + q
        em[q] = -math.expm1(-Ts / taus[j])
    nmove = 0.0
    emax = np.zeros(m)
    esq = np.zeros(m)
    last = np.full(m, -1.0)
    umax = np.zeros(m)
    fin = np.zeros(m)
    for k in range(n):
        in_move = k * Ts <= duration + 1e-12
        if in_move:
            nmove += 1.0
        rp = rpos[k]
        rv = rvel[k]
        ff = (fftau * racc[k] + rv) / ffK if ff_on else 0.0
        t0 = k * Ts
        split = dist_on and t0 < dist_time and dist_time < t0 + Ts
        w = dist_amp if (dist_on and t0 >= dist_time) else 0.0
        for q in range(m):
            j = j0 + q
            x = th[q]
            err = rp - x
            a = abs(err)
            if a > emax[q]:
                emax[q] = a
            if in_move:
                esq[q] += err * err
            if abs(distance - x) > band:
                last[q] = k
            fin[q] = err
            y = _encoder(x, cpr)
            if noise_on:
                y += noise[j, k]
            if velocity:
                if k == 0:
                    yp[q] = y
                e = scale * (rv - (y - yp[q]) / Ts)
            else:
                e = scale * (rp - y)
            yp[q] = y
            if k == 0 and bumpless:
                ep[q] = e
            u, p, i_new, d, s = _pid(e, ep[q], ip[q], dp[q], ff, kpd, kid, kdd, gamma, limit, aw)
            ip[q] = i_new
            dp[q] = d
            ep[q] = e
            v, s2 = _amplifier(u, supply, levels)
            if abs(v) > umax[q]:
                umax[q] = abs(v)
            if keep:
                POS[j, k] = x
                U[j, k] = v
            if split:
                th[q], om[q] = _rigid_step(x, om[q], v, k, Ts, fcs[j], Ks[j], taus[j], em[q],
                                           dist_on, dist_amp, dist_time)
            else:
                th[q], om[q] = advance_em(x, om[q], v + w, fcs[j], Ks[j], taus[j], Ts, em[q])
    for q in range(m):
        j = j0 + q
        MET[j, 0] = emax[q]
        MET[j, 1] = esq[q]
        MET[j, 2] = fin[q]
        MET[j, 3] = last[q]
        MET[j, 4] = umax[q]
        MET[j, 5] = nmove


def _batch_kernel(rpos, rvel, racc, Ks, taus, fcs, noise, noise_on, *args):
    """All plants in one compiled call (see :func:`_batch_chunk`)."""
    _batch_chunk(0, Ks.shape[0], rpos, rvel, racc, Ks, taus, fcs, noise, noise_on, *args)


# ---------------------------------------------------------------------------
# results
# ---------------------------------------------------------------------------
@dataclass
class SimResult:
    """Time series and metrics of one closed-loop run (all SI).

    Attributes
    ----------
    t : sample times k·Ts (s)
    reference, ref_velocity, ref_accel : the profile sampled at t
    measured : encoder reading (rad)
    position, velocity : true motor angle (rad) and speed (rad/s) at t
    load_position : load angle for a :class:`FlexibleDCMotor` (else None)
    error : tracking error ``reference − position`` (true, rad)
    loop_error : the error the PID saw (after ``error_scale``)
    u : controller output after its clamp (V); ``u_applied`` what the motor got (PWM)
    parts : dict of arrays ``p``, ``i``, ``d``, ``ff``
    saturated : bool array, controller clamp or supply limit active
    metrics : dict (see :func:`simulate`)
    """

    t: np.ndarray
    reference: np.ndarray
    ref_velocity: np.ndarray
    ref_accel: np.ndarray
    measured: np.ndarray
    position: np.ndarray
    velocity: np.ndarray
    error: np.ndarray
    loop_error: np.ndarray
    u: np.ndarray
    u_applied: np.ndarray
    parts: dict
    saturated: np.ndarray
    metrics: dict
    loop: str = "position"
    load_position: np.ndarray | None = None
    info: dict = field(default_factory=dict)

    def plot(self, fig=None, title=None):
        """Reference and output, tracking error, and the control parts (3 stacked axes)."""
        import matplotlib.pyplot as plt
        if fig is None:
            fig = plt.figure(figsize=(9, 7))
        ax = fig.subplots(3, 1, sharex=True)
        ax[0].plot(self.t, self.reference, "k--", lw=1, label="reference")
        ax[0].plot(self.t, self.position, label="motor (true)")
        ax[0].plot(self.t, self.measured, ".", ms=2, label="encoder")
        if self.load_position is not None:
            ax[0].plot(self.t, self.load_position, label="load")
        ax[0].set_ylabel("angle (rad)")
        ax[0].legend(loc="best", fontsize=8)
        ax[1].plot(self.t, self.error * 1e3)
        ax[1].set_ylabel("tracking error (mrad)")
        for name in ("ff", "p", "i", "d"):
            ax[2].plot(self.t, self.parts[name], lw=1, label=name)
        ax[2].plot(self.t, self.u_applied, "k", lw=1.2, label="u applied")
        if np.any(self.saturated):
            ax[2].fill_between(self.t, 0, 1, where=self.saturated, color="r", alpha=0.1,
                               transform=ax[2].get_xaxis_transform(), label="saturated")
        ax[2].set_ylabel("voltage (V)")
        ax[2].set_xlabel("time (s)")
        ax[2].legend(loc="best", fontsize=8, ncol=3)
        m = self.metrics
        ax[0].set_title(title or (f"{self.loop} loop: max |e| = {m['max_abs_error'] * 1e3:.3g} mrad, "
                                  f"RMS {m['rms_error'] * 1e3:.3g} mrad, final {m['final_error'] * 1e3:.3g} mrad"))
        fig.tight_layout()
        return fig


@dataclass
class BatchResult:
    """Runs over many plants: ``position`` and ``u`` are (n_plants, n_samples)."""

    t: np.ndarray
    reference: np.ndarray
    K: np.ndarray
    tau: np.ndarray
    coulomb_friction: np.ndarray
    position: np.ndarray
    u: np.ndarray
    metrics: dict


def _metrics(t, err, position, u_app, sat, duration, distance, band, load=None):
    """Metrics of one run (t is the regular grid k·Ts, so the move is a leading slice)."""
    n = len(t)
    Ts = t[1] - t[0] if n > 1 else 1.0
    n_move = min(n, int(math.floor(duration / Ts + 1e-9)) + 1)
    e_move = err[:n_move]
    m = {
        "max_abs_error": float(np.abs(err).max()),
        "rms_error": math.sqrt(float(np.dot(e_move, e_move)) / n_move),
        "final_error": float(err[-1]),
        "max_abs_voltage": float(np.abs(u_app).max()),
        "saturated_fraction": np.count_nonzero(sat) / n,
    }
    out = np.flatnonzero(np.abs(distance - position) > band)
    if len(out) == 0:
        m["settling_time"] = 0.0
    elif out[-1] == n - 1:
        m["settling_time"] = math.inf
    else:
        m["settling_time"] = max(0.0, float(t[out[-1] + 1] - duration))
    m["settling_band"] = band
    if load is not None:
        after = t >= duration
        m["residual_vibration"] = float(np.max(np.abs(load[after] - distance))) if np.any(after) else math.nan
    return m


def _settling(last_out, n, t, duration):
    last_out = np.asarray(last_out)
    idx = np.clip(last_out + 1, 0, n - 1).astype(int)
    st = np.where(last_out < 0, 0.0, np.where(last_out >= n - 1, np.inf, t[idx] - duration))
    return np.maximum(st, 0.0)


def _batch_metrics(t, reference, POS, Uapp, duration, distance, band):
    """The per-plant metrics of :func:`simulate_batch` from full traces."""
    err = reference[None, :] - POS
    move = t <= duration + 1e-12
    outside = np.abs(distance - POS) > band
    n = len(t)
    last = np.where(outside.any(axis=1), n - 1 - np.argmax(outside[:, ::-1], axis=1), -1)
    with np.errstate(invalid="ignore", over="ignore"):
        emax = np.max(np.abs(err), axis=1)
        return _metric_dict(emax, np.sqrt(np.mean(err[:, move] ** 2, axis=1)), err[:, -1],
                            _settling(last, n, t, duration), np.max(np.abs(Uapp), axis=1), distance)


def _metric_dict(emax, rms, final, settle, umax, distance):
    return {"max_abs_error": emax, "rms_error": rms, "final_error": final, "settling_time": settle,
            "max_abs_voltage": umax,
            "diverged": ~np.isfinite(emax) | (emax > 1e3 * max(abs(distance), 1.0))}


# ---------------------------------------------------------------------------
# simple references (anything with duration and sample(t) works)
# ---------------------------------------------------------------------------
class _Sample:
    __slots__ = ("t", "jerk", "accel", "velocity", "position")

    def __init__(self, t, jerk, accel, velocity, position):
        self.t, self.jerk, self.accel, self.velocity, self.position = t, jerk, accel, velocity, position


class StepProfile:
    """A position step of ``distance`` at t = 0 (no velocity or acceleration reference).

    The classic test signal of Stojčić's loop analysis; with feedforward it has none.
    """

    def __init__(self, distance=1.0):
        self.distance = as_real("distance", distance)
        self.duration = 0.0

    def sample(self, t):
        t = np.asarray(t, dtype=float)
        z = np.zeros_like(t)
        return _Sample(t, z, z, z, np.where(t >= 0.0, self.distance, 0.0))


class SampledProfile:
    """A reference given as samples at ``k Ts`` (a recording, or a pre-sampled profile).

    ``sample(t)`` returns the sample at the nearest grid point (held after the end).
    """

    def __init__(self, Ts, position, velocity=None, accel=None, duration=None):
        self.Ts = as_positive("Ts", Ts)
        self.position = as_finite_array("position", position, ndim=1)
        n = len(self.position)
        self.velocity = np.zeros(n) if velocity is None else as_finite_array("velocity", velocity, ndim=1)
        self.accel = np.zeros(n) if accel is None else as_finite_array("accel", accel, ndim=1)
        if not len(self.velocity) == len(self.accel) == n:
            raise ValueError("position, velocity and accel must have the same length")
        self.duration = (n - 1) * self.Ts if duration is None else as_nonnegative("duration", duration)

    @classmethod
    def from_profile(cls, profile, Ts, t_end=None):
        """Sample ``profile`` once on the grid (to re-run many simulations cheaply)."""
        t = _time_grid(profile, Ts, t_end)
        s = profile.sample(t)
        return cls(Ts, s.position, s.velocity, s.accel, duration=float(profile.duration))

    def sample(self, t):
        t = np.asarray(t, dtype=float)
        k = np.clip(np.rint(t / self.Ts).astype(int), 0, len(self.position) - 1)
        return _Sample(t, np.zeros_like(t), self.accel[k], self.velocity[k], self.position[k])


# ---------------------------------------------------------------------------
# public API
# ---------------------------------------------------------------------------
def _check_inputs(profile, motor):
    if not (hasattr(profile, "duration") and callable(getattr(profile, "sample", None))):
        raise ValueError("profile must have .duration and .sample(t) (a jerklab.planner Profile), "
                         f"got {type(profile).__name__}")
    if not isinstance(motor, (DCMotor, FlexibleDCMotor)):
        raise ValueError(f"motor must be a DCMotor or FlexibleDCMotor, got {type(motor).__name__}")


def _controller_for(controller, motor, loop):
    if isinstance(controller, Gains):
        raise ValueError("controller must be a DigitalController or DiscreteGains; "
                         "discretize continuous Gains first (Gains.discretize(Ts), eq. 13)")
    if isinstance(controller, DiscreteGains):
        limit = motor.supply_voltage
        controller = DigitalController(controller, feedforward=Feedforward(motor.K, motor.tau),
                                       output_limit=limit, loop=loop)
    if not isinstance(controller, DigitalController):
        raise ValueError(f"controller must be a DigitalController or DiscreteGains, got "
                         f"{type(controller).__name__}")
    if loop is not None and loop != controller.loop:
        if loop not in ("position", "velocity"):
            raise ValueError(f"loop must be 'position' or 'velocity', got {loop!r}")
        controller = DigitalController(controller.gains, controller.feedforward, controller.output_limit,
                                       controller.anti_windup, loop, controller.error_scale,
                                       controller.bumpless)
    return controller


def _plant_args(motor, Ts, n):
    if isinstance(motor, DCMotor):
        z2, z1 = np.zeros((2, 2)), np.zeros(2)
        rigid = dict(rigid=True, K=motor.K, tau=motor.tau, fc=motor.coulomb_friction,
                     Phi=z2, Gam=z1, Phi_a=z2, Gam_a=z1, Phi_b=z2, Gam_b=z1)
        ns = 2
    elif isinstance(motor, FlexibleDCMotor):
        Phi, Gam = motor.zoh(Ts)
        Phi_a, Gam_a, Phi_b, Gam_b = Phi, Gam, Phi, Gam
        d = motor.load_disturbance
        if d is not None:
            frac = d.time / Ts - math.floor(d.time / Ts)
            if 0.0 < frac < 1.0:
                Phi_a, Gam_a = motor.zoh(frac * Ts)
                Phi_b, Gam_b = motor.zoh((1.0 - frac) * Ts)
        rigid = dict(rigid=False, K=motor.K, tau=motor.tau, fc=0.0, Phi=np.ascontiguousarray(Phi), Gam=Gam[:, 0].copy(),
                     Phi_a=np.ascontiguousarray(Phi_a), Gam_a=Gam_a[:, 0].copy(),
                     Phi_b=np.ascontiguousarray(Phi_b), Gam_b=Gam_b[:, 0].copy())
        ns = 4
    else:
        raise ValueError(f"motor must be a DCMotor or FlexibleDCMotor, got {type(motor).__name__}")
    d = motor.load_disturbance
    common = dict(dist_on=d is not None, dist_amp=0.0 if d is None else d.amplitude,
                  dist_time=0.0 if d is None else d.time,
                  supply=0.0 if motor.supply_voltage is None else motor.supply_voltage,
                  levels=0.0 if motor.pwm_bits is None else float(2 ** motor.pwm_bits - 1),
                  cpr=0.0 if motor.counts_per_rad is None else motor.counts_per_rad)
    return rigid, common, ns


def _sample_profile(profile, t):
    try:
        duration = float(profile.duration)
        s = profile.sample(t)
    except AttributeError:
        raise ValueError("profile must have .duration and .sample(t) (a jerklab.planner Profile)") from None
    return (duration, np.ascontiguousarray(s.position, dtype=float),
            np.ascontiguousarray(s.velocity, dtype=float), np.ascontiguousarray(s.accel, dtype=float))


def _time_grid(profile, Ts, t_end):
    if t_end is None:
        t_end = float(profile.duration) + 0.5
    t_end = as_nonnegative("t_end", t_end)
    n = int(math.floor(t_end / Ts + 1e-9)) + 1
    return np.arange(n) * Ts


def _ctrl_args(c, Ts):
    p = c.params()
    if not math.isclose(p["Ts"], Ts, rel_tol=1e-12):
        raise ValueError(f"Ts={Ts} differs from the controller's gains.Ts={p['Ts']}")
    return dict(kpd=p["kpd"], kid=p["kid"], kdd=p["kdd"], gamma=p["gamma"], ff_on=p["ff_on"],
                ffK=p["ff_K"], fftau=p["ff_tau"], limit=p["limit"], aw=p["anti_windup"],
                velocity=p["velocity"], scale=p["error_scale"], bumpless=p["bumpless"], Ts=Ts)


def simulate(profile, motor, controller, Ts=None, t_end=None, loop=None, x0=None, settle_band=None):
    """Simulate the sampled closed loop on a move.

    Parameters
    ----------
    profile : Profile
        Anything with ``duration`` and ``sample(t)`` → ``.position .velocity .accel``
        (:mod:`jerklab.planner`); sampled in closed form at ``k Ts``.
    motor : DCMotor or FlexibleDCMotor
        The plant with its imperfections (saturation, PWM, encoder, friction,
        disturbance, noise).
    controller : DigitalController or DiscreteGains
        DiscreteGains are wrapped with eq. 16 feedforward from the motor's K, τ and an
        output limit at the supply voltage. The controller object itself is not stepped
        (its state is untouched); the compiled kernel runs the same law.
    Ts : float, optional
        Sampling time; defaults to the gains' Ts (must agree with it).
    t_end : float, optional
        Simulated time, default ``profile.duration + 0.5`` s.
    loop : {"position", "velocity"}, optional
        Override the controller's loop (§4B velocity loop: reference in pulses per Ts
        when the controller's ``error_scale`` is :func:`~jerklab.controller.paper_error_scale`).
    x0 : array, optional
        Initial plant state (default rest at 0).
    settle_band : float, optional
        Band for the settling time (rad); default 2 encoder counts (1 mrad without an
        encoder).

    Returns
    -------
    SimResult
        Metrics: ``max_abs_error``, ``rms_error`` (during the move), ``final_error``,
        ``settling_time`` (after the end of the profile, inf if never), ``max_abs_voltage``,
        ``saturated_fraction`` and, for a flexible load, ``residual_vibration`` (max
        |load − distance| after the move).
    """
    _check_inputs(profile, motor)
    c = _controller_for(controller, motor, loop)
    Ts = c.Ts if Ts is None else as_positive("Ts", Ts)
    t = _time_grid(profile, Ts, t_end)
    n = len(t)
    duration, rpos, rvel, racc = _sample_profile(profile, t)
    plant, common, ns = _plant_args(motor, Ts, n)
    x = np.zeros(ns) if x0 is None else motor._x0(x0)
    noise = motor.rng.normal(0.0, motor.noise_std, n) if motor.noise_std > 0 else np.zeros(n)
    X = np.empty((n, ns))
    out = {k: np.empty(n) for k in ("meas", "ucmd", "uapp", "P", "I", "D", "FF", "E")}
    sat = np.empty(n, dtype=np.bool_)
    _kernel(rpos, rvel, racc, noise, x, plant["rigid"], plant["K"], plant["tau"], plant["fc"],
            plant["Phi"], plant["Gam"], plant["Phi_a"], plant["Gam_a"], plant["Phi_b"], plant["Gam_b"],
            common["dist_on"], common["dist_amp"], common["dist_time"], common["supply"],
            common["levels"], common["cpr"], **_ctrl_args(c, Ts),
            X=X, meas=out["meas"], ucmd=out["ucmd"], uapp=out["uapp"], P=out["P"], I=out["I"],
            D=out["D"], FF=out["FF"], E=out["E"], sat=sat)
    load = X[:, 2].copy() if ns == 4 else None
    cpr = motor.counts_per_rad
    band = settle_band if settle_band is not None else (2.0 / cpr if cpr else 1e-3)
    distance = float(rpos[-1]) if t[-1] >= duration else float(profile.sample(duration).position)
    position = X[:, 0].copy()
    err = rpos - position
    metrics = _metrics(t, err, position, out["uapp"], sat, duration, distance, band, load)
    return SimResult(t=t, reference=rpos, ref_velocity=rvel, ref_accel=racc, measured=out["meas"],
                     position=position, velocity=X[:, 1].copy(), error=err,
                     loop_error=out["E"], u=out["ucmd"], u_applied=out["uapp"],
                     parts={"p": out["P"], "i": out["I"], "d": out["D"], "ff": out["FF"]},
                     saturated=sat, metrics=metrics, loop=c.loop, load_position=load,
                     info=dict(Ts=Ts, duration=duration, distance=distance, compiled=HAVE_NUMBA))


def perturbed_plants(n, K=32.4, tau=0.025, K_spread=0.2, tau_spread=0.2, friction=(0.0, 0.0), seed=None):
    """Random plants for robustness studies: K and τ uniform within ±spread (relative),
    Coulomb friction uniform in ``friction = (low, high)`` V. Returns a dict of arrays."""
    rng = np.random.default_rng(seed)
    n = int(n)
    K = as_positive("K", K)
    tau = as_positive("tau", tau)
    ks = as_nonnegative("K_spread", K_spread)
    ts = as_nonnegative("tau_spread", tau_spread)
    if ks >= 1 or ts >= 1:
        raise ValueError("K_spread and tau_spread must be < 1 (relative spreads)")
    lo, hi = (as_nonnegative("friction low", friction[0]), as_nonnegative("friction high", friction[1]))
    return dict(K=K * (1 + rng.uniform(-ks, ks, n)), tau=tau * (1 + rng.uniform(-ts, ts, n)),
                coulomb_friction=rng.uniform(lo, hi, n))


def simulate_batch(profile, motor, controller, K=None, tau=None, coulomb_friction=None, Ts=None,
                   t_end=None, loop=None, engine="auto", settle_band=None, seed=None, keep_traces=True):
    """The closed loop of :func:`simulate` over many rigid plants at once.

    ``K``, ``tau``, ``coulomb_friction`` are arrays (or scalars, broadcast) overriding
    the template ``motor``'s values; every other imperfection (saturation, PWM,
    encoder, disturbance, noise level) comes from ``motor``. The controller (gains and
    feedforward) is the same for all plants — the robustness question.

    ``engine="numpy"`` vectorizes over the plants (a loop over time, numpy arrays over
    plants, :func:`jerklab.plant.advance`); ``"compiled"`` runs the numba kernel with
    the metrics accumulated on the fly; ``"auto"`` picks compiled when numba is
    present. Both give the same numbers (tested).

    Returns
    -------
    BatchResult
        ``position`` and applied voltage ``u`` (n_plants × n_samples, None unless
        ``keep_traces``) and per-plant ``metrics`` arrays (``max_abs_error``,
        ``rms_error``, ``final_error``, ``settling_time``, ``max_abs_voltage``,
        ``diverged``), defined as in :func:`simulate`.
    """
    _check_inputs(profile, motor)
    if not isinstance(motor, DCMotor):
        raise ValueError("simulate_batch needs a rigid DCMotor template")
    c = _controller_for(controller, motor, loop)
    Ts = c.Ts if Ts is None else as_positive("Ts", Ts)
    Kv = np.atleast_1d(as_finite_array("K", motor.K if K is None else K))
    tv = np.atleast_1d(as_finite_array("tau", motor.tau if tau is None else tau))
    fv = np.atleast_1d(as_finite_array("coulomb_friction", motor.coulomb_friction
                                       if coulomb_friction is None else coulomb_friction))
    Kv, tv, fv = (np.ascontiguousarray(a, dtype=float) for a in np.broadcast_arrays(Kv, tv, fv))
    if np.any(Kv <= 0) or np.any(tv <= 0) or np.any(fv < 0):
        raise ValueError("K and tau must be > 0 and coulomb_friction >= 0 for every plant")
    m = len(Kv)
    t = _time_grid(profile, Ts, t_end)
    n = len(t)
    duration, rpos, rvel, racc = _sample_profile(profile, t)
    _, common, _ = _plant_args(motor, Ts, n)
    ca = _ctrl_args(c, Ts)
    rng = np.random.default_rng(seed)
    noise_on = motor.noise_std > 0
    noise = rng.normal(0.0, motor.noise_std, (m, n)) if noise_on else np.zeros((1, 1))
    cpr = motor.counts_per_rad
    band = settle_band if settle_band is not None else (2.0 / cpr if cpr else 1e-3)
    distance = float(profile.sample(duration).position)
    if engine == "auto":
        engine = "compiled" if HAVE_NUMBA else "numpy"
    if engine == "compiled":
        shape = (m, n) if keep_traces else (1, 1)
        POS = np.empty(shape)
        U = np.empty(shape)
        MET = np.empty((m, 6))
        _batch_kernel(rpos, rvel, racc, Kv, tv, fv, noise, noise_on, common["dist_on"],
                      common["dist_amp"], common["dist_time"], common["supply"], common["levels"],
                      common["cpr"], ca["kpd"], ca["kid"], ca["kdd"], ca["gamma"], ca["ff_on"],
                      ca["ffK"], ca["fftau"], ca["limit"], ca["aw"], ca["velocity"], ca["scale"],
                      ca["bumpless"], Ts, duration, distance, band, keep_traces, POS, U, MET)
        with np.errstate(invalid="ignore", over="ignore"):
            metrics = _metric_dict(MET[:, 0], np.sqrt(MET[:, 1] / np.maximum(MET[:, 5], 1.0)), MET[:, 2],
                                   _settling(MET[:, 3].astype(int), n, t, duration), MET[:, 4], distance)
        if not keep_traces:
            POS = U = None
    elif engine == "numpy":
        if not noise_on:
            noise = np.zeros((m, n))
        POS, U = _batch_numpy(rpos, rvel, racc, Kv, tv, fv, noise, common, ca)
        metrics = _batch_metrics(t, rpos, POS, U, duration, distance, band)
        if not keep_traces:
            POS = U = None
    else:
        raise ValueError(f"engine must be 'auto', 'numpy' or 'compiled', got {engine!r}")
    return BatchResult(t=t, reference=rpos, K=Kv, tau=tv, coulomb_friction=fv, position=POS, u=U,
                       metrics=metrics)


def _batch_numpy(rpos, rvel, racc, Kv, tv, fv, noise, common, ca):
    """Time loop, numpy over plants: the same law as :func:`_kernel`. Returns (θ, u applied)."""
    m, n = noise.shape
    Ts = ca["Ts"]
    th = np.zeros(m)
    om = np.zeros(m)
    i_prev = np.zeros(m)
    e_prev = np.zeros(m)
    d_prev = np.zeros(m)
    y_prev = np.zeros(m)
    POS = np.empty((m, n))
    U = np.empty((m, n))
    cpr, supply, levels = common["cpr"], common["supply"], common["levels"]
    lim = ca["limit"]
    for k in range(n):
        POS[:, k] = th
        y = np.floor(th * cpr + 1e-9) / cpr if cpr > 0 else th.copy()
        y += noise[:, k]
        if ca["velocity"]:
            if k == 0:
                y_prev = y
            e = ca["scale"] * (rvel[k] - (y - y_prev) / Ts)
        else:
            e = ca["scale"] * (rpos[k] - y)
        y_prev = y
        ff = (ca["fftau"] * racc[k] + rvel[k]) / ca["ffK"] if ca["ff_on"] else 0.0
        if k == 0 and ca["bumpless"]:
            e_prev = e
        i_new = i_prev + ca["kid"] * e
        d = ca["gamma"] * d_prev + ca["kdd"] * (e - e_prev)
        u = ff + ca["kpd"] * e + i_new + d
        hi = u > lim
        lo = u < -lim
        if ca["aw"]:
            freeze = (hi & (e > 0)) | (lo & (e < 0))
            u = np.where(freeze, u - (i_new - i_prev), u)
            i_new = np.where(freeze, i_prev, i_new)
        u = np.clip(u, -lim, lim)
        i_prev, e_prev, d_prev = i_new, e, d
        v = u
        if supply > 0:
            v = np.clip(v, -supply, supply)
            if levels > 0:
                q = v / supply * levels
                v = np.sign(q) * np.floor(np.abs(q) + 0.5) / levels * supply
        U[:, k] = v
        t0 = k * Ts
        if common["dist_on"] and t0 < common["dist_time"] < t0 + Ts:
            first = common["dist_time"] - t0
            th, om = advance(th, om, v, fv, Kv, tv, first)
            th, om = advance(th, om, v + common["dist_amp"], fv, Kv, tv, Ts - first)
        else:
            w = common["dist_amp"] if (common["dist_on"] and t0 >= common["dist_time"]) else 0.0
            th, om = advance(th, om, v + w, fv, Kv, tv, Ts)
    return POS, U


def pd_rest_band(kpd, load, coulomb_friction, counts_per_rad=None, supply_voltage=None, pwm_bits=None):
    """Where a PD loop (no integrator) can come to rest under a constant load and Coulomb friction.

    At rest the derivative and the feedforward are zero, so the motor sees ``u = k_pd e_m`` (PWM
    rounded) plus the load ``w`` (input referred, W = P as in Stojčić eq. 9) and sticks while
    ``|u + w| <= f_c``. Without friction and quantization this is the rest error of Stojčić eq. 9, ``e = -w / k_pd``.
    The controller sees the *measured* error ``e_m = r - floor(θ c)/c`` (encoder count ``c`` per
    rad), which exceeds the true error ``e = r - θ`` by less than one count ``q = 1/c``; the PWM
    rounds ``u`` to half a duty step ``Δ/2``. The true error at rest therefore lies in

        ``((-w - f_c - Δ/2)/k_pd - q,  (-w + f_c + Δ/2)/k_pd]``   (for ``k_pd > 0``).

    Parameters
    ----------
    kpd : float
        Proportional gain k_pd (V/rad, > 0).
    load : float
        Constant input-referred load w (V).
    coulomb_friction : float
        Friction f_c (V, >= 0).
    counts_per_rad : float, optional
        Encoder counts per rad (None: ideal sensor, q = 0).
    supply_voltage, pwm_bits : optional
        PWM full scale (V) and resolution; both None: no PWM rounding.

    Returns
    -------
    tuple of float
        ``(lo, hi)`` bounds of the true error ``r - θ`` at rest, rad.
    """
    kpd = as_positive("kpd", kpd)
    w = as_real("load", load)
    fc = as_nonnegative("coulomb_friction", coulomb_friction)
    q = 0.0 if counts_per_rad is None else 1.0 / as_positive("counts_per_rad", counts_per_rad)
    half_step = 0.0
    if supply_voltage is not None and pwm_bits is not None:
        half_step = 0.5 * as_positive("supply_voltage", supply_voltage) / (2 ** int(pwm_bits) - 1)
    return ((-w - fc - half_step) / kpd - q, (-w + fc + half_step) / kpd)


__all__ += ["pd_rest_band"]
