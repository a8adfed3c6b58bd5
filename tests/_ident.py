"""Records the identification tests share: the plant of Stojčić §4A (ASCII: Stojcic) seen through
``jerklab.plant.DCMotor`` (448-pulse encoder, 10-bit PWM, noise), open and closed loop, and
python-control's ZOH response as the independent reference."""

from __future__ import annotations

import functools
import warnings

import control as ct
import numpy as np

from jerklab import ident
from jerklab.plant import DCMotor

#: the motor of Stojčić §4A and the sample period of its record
K0, TAU0, TS = 32.4, 0.025, 0.005


def ct_response(K, tau, Ts, u, theta0=0.0, omega0=0.0):
    """Independent reference: python-control's ZOH discretization of the state space of eq. 1."""
    sys = ct.ss([[0.0, 1.0], [0.0, -1.0 / tau]], [[0.0], [K / tau]], [[1.0, 0.0]], [[0.0]])
    sysd = ct.c2d(sys, Ts, "zoh")
    r = ct.forced_response(sysd, T=np.arange(len(u)) * Ts, U=u, X0=[theta0, omega0])
    return np.asarray(r.outputs).ravel()


def plant_record(u, seed, **kw):
    """(u, theta_measured) as the identification would see them from jerklab.plant.DCMotor."""
    kw.setdefault("noise_std", 0.002)
    m = DCMotor(K=K0, tau=TAU0, seed=seed, **kw)
    _, meas = m.open_loop(u, TS)
    return meas[:-1]


def record(u, delay=0, seed=0, Ts=TS, noise_std=0.001, **kw):
    """What a logger sees: the commanded u (the motor gets it ``delay`` samples late), the
    quantized, noisy angle of jerklab.plant.DCMotor (448-pulse encoder, 10-bit PWM)."""
    m = DCMotor(K=K0, tau=TAU0, seed=seed, noise_std=noise_std, **kw)
    ud = np.concatenate([np.full(delay, u[0]), u[: len(u) - delay]]) if delay else u
    return m.open_loop(ud, Ts)[1][:-1]


def levels(duration=3.0, hold=8, lo=-6.0, hi=6.0, seed=1):
    """Random voltage levels held ``hold`` samples: both directions, many amplitudes, some inside the
    dead zone (what separates K, friction, offset and dead zone)."""
    rng = np.random.default_rng(seed)
    n = int(round(duration / TS))
    return np.repeat(rng.uniform(lo, hi, -(-n // hold)), hold)[:n]


def closed_loop(T=2.0, Ts=0.001, fc=0.4, off=0.25, delay=1, noise=0.0005, seed=0):
    """A PD position loop around DCMotor, 1 kHz, 448-pulse x4 encoder, dither on the command;
    the logged u is the controller output, the motor gets it ``delay`` samples late."""
    m = DCMotor(
        K=K0, tau=TAU0, coulomb_friction=fc, offset=off, noise_std=noise, seed=seed, decoding=4
    )
    n = int(round(T / Ts))
    rng = np.random.default_rng(seed)
    t = np.arange(n) * Ts
    ref = 2.0 * np.sign(np.sin(2 * np.pi * 1.3 * t)) + 0.5 * np.sin(2 * np.pi * 3.1 * t)
    x = np.zeros(2)
    u = np.zeros(n)
    y = np.zeros(n)
    pending = [0.0] * delay
    yprev = 0.0
    for k in range(n):
        y[k] = m.measure(x[0])
        uk = 4.0 * (ref[k] - y[k]) - 0.15 * (y[k] - yprev) / Ts + 0.3 * rng.standard_normal()
        yprev = y[k]
        u[k] = float(np.clip(uk, -12.0, 12.0))
        pending.append(u[k])
        x = m.step_state(x, float(m.quantize_voltage(pending.pop(0))), Ts)
    return u, y


def fit_quiet(*args, **kw):
    with warnings.catch_warnings():
        warnings.simplefilter("error", ident.IdentificationWarning)
        return ident.fit_dc_motor(*args, **kw)


def rel(a, b):
    return abs(a / b - 1.0)


def lab_sweep(seed, motor=None, jitter=None):
    """Lab 1's six steps from rest (``lab_spec(1)``: +-3, +-6, +-9 V, 0.05 s rest, then the step)
    on a motor drawn from the class's hidden ranges (``hidden_ranges("paper")``; or ``motor``, a
    dict of K, tau, fc, offset, noise_counts, ppr), read as the virtual rig reads it: 12 V supply,
    10-bit PWM, the encoder's floor of the count with a Gaussian count jitter before it, the
    shaft at a random angle to the code wheel at the start; ``jitter`` (lo, hi) replaces the
    class's range of the count jitter. Returns (motor, [(u, theta), ...])."""
    from jerklab.lab.specs import hidden_ranges, lab_spec

    rng = np.random.default_rng(seed)
    if motor is None:
        R = hidden_ranges("paper")
        motor = dict(
            K=float(np.exp(rng.uniform(*np.log(R["K"])))),
            tau=float(np.exp(rng.uniform(*np.log(R["tau"])))),
            fc=float(rng.uniform(*R["coulomb_friction"])),
            offset=float(rng.uniform(*R["offset"])),
            noise_counts=float(rng.uniform(*(jitter or R["noise_counts"]))),
            ppr=int(rng.choice(R["encoder_ppr"])),
        )
    spec = lab_spec(1)
    m = DCMotor(
        K=motor["K"],
        tau=motor["tau"],
        supply_voltage=12.0,
        pwm_bits=10,
        encoder_ppr=motor["ppr"],
        decoding=1,
        coulomb_friction=motor["fc"],
        offset=motor["offset"],
    )
    cpr = m.counts_per_rad
    n_rest, n_step = int(round(0.05 / TS)), int(round(spec["step_seconds"] / TS))
    records = []
    for V in spec["sweep_volts"]:
        u = m.quantize_voltage(np.r_[np.zeros(n_rest), np.full(n_step, V)])
        theta, _ = m.open_loop(u, TS, x0=[rng.uniform() / cpr, 0.0])
        jitter = rng.normal(0.0, motor["noise_counts"], theta.size)
        counts = np.floor(theta * cpr + 1e-9 + jitter)[:-1]
        records.append((u, (counts - counts[0]) / cpr))
    return motor, records


@functools.lru_cache(maxsize=1)
def dc_generator_fits():
    """The measured DC motor / generator record (decimated 2, 10 000 samples) split in halves
    and the four prediction-error fits on the first half that the identification notebook
    quotes: ``(estimation half, validation half, {"linear", "viscous", "both", "coulomb"})``.

    Computed once per worker: tests/test_ident_generator.py and tests/test_figures_ident.py
    share it (one xdist group, ``SHARED_WORKER`` in conftest)."""
    data = ident.load_dc_generator(decimate=2)
    n = data.n // 2
    est, val = data[:n], data[n:]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ident.IdentificationWarning)
        fits = {
            "linear": est.fit("pem", delay=True),
            "viscous": est.fit("pem", coast=True, delay=True),
            "both": est.fit("pem", coast=True, friction=True, delay=True),
            "coulomb": est.fit("pem", coast="coulomb", friction=True, delay=True),
        }
    return est, val, fits
