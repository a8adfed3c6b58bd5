"""The flexible mode from the encoder (jerklab.ident.mode): the two-mass model's simulation against
the plant's, the mode found on simulated encoder records against the plant's true poles, bad input.

Independent references: ``jerklab.plant.FlexibleDCMotor`` (its own ZOH model and ``open_loop``
simulation, quantized and noisy) and the eigenvalues of its state matrix.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from jerklab import ident
from jerklab.ident.mode import _flex_simulate
from jerklab.plant import FlexibleDCMotor
from jerklab.shaping import chirp_input


def _true_mode(m):
    A, _ = m._matrices()
    ev = np.linalg.eigvals(A)
    s = ev[np.argmax(ev.imag)]
    return abs(s) / (2 * math.pi), -s.real / abs(s)


def test_fit_model_simulation_matches_the_plant():
    """The identification's fast simulation (eigen-decomposed ZOH, lfilter) against the plant's."""
    m = FlexibleDCMotor(load_ratio=0.3, mode_frequency=50.0, mode_damping=0.02).ideal()
    u = np.random.default_rng(0).normal(size=800)
    th, _ = m.open_loop(u, 0.005)
    p = np.log([m.K, m.tau, m.load_ratio, m.mode_frequency, m.mode_damping])
    np.testing.assert_allclose(_flex_simulate(p, u, 0.005), th, atol=1e-9 * np.abs(th).max())
    params = (m.K, m.tau, m.load_ratio, m.mode_frequency, m.mode_damping)
    assert ident.two_mass_mode(*params) == pytest.approx(_true_mode(m))


def _record(load_ratio, excitation, Ts=0.005):
    m = FlexibleDCMotor(
        load_ratio=load_ratio,
        mode_frequency=2 * math.pi * 8.0,
        mode_damping=0.02,
        noise_std=0.002,
        seed=7,
    )
    u = (
        chirp_input(8.0, Ts, 3.0, 1.0, 30.0)
        if excitation == "chirp"
        else ident.prbs(8.0, Ts, 3.0, clock_period=0.01)
    )
    _, y = m.open_loop(u, Ts)  # quantized to 448 counts/rev, plus noise
    return m, u, y


@pytest.mark.parametrize("load_ratio,excitation", [(0.05, "chirp"), (0.3, "prbs"), (0.15, "chirp")])
def test_identify_mode_from_encoder(load_ratio, excitation):
    Ts = 0.005
    m, u, y = _record(load_ratio, excitation, Ts)
    fit = ident.identify_mode(u, y, Ts)
    assert isinstance(fit, ident.ModeFit)
    f0, z0 = _true_mode(m)
    assert abs(fit.frequency_hz - f0) < max(4 * fit.frequency_se, 0.005 * f0)
    assert abs(fit.damping - z0) < max(4 * fit.damping_se, 0.1 * z0)
    assert 0 < fit.frequency_se < 0.02 * f0
    assert fit.jerk_time == pytest.approx(1 / (fit.frequency_hz * math.sqrt(1 - fit.damping**2)))
    # the fitted plant rings at the reported mode
    model = fit.model()
    assert _true_mode(model) == pytest.approx((fit.frequency_hz, fit.damping), rel=1e-9)
    # the same record as an IdentData (equal lengths: the last input is not used)
    fit2 = ident.identify_mode(ident.IdentData(u, y[:-1], Ts))
    assert fit2.frequency_hz == pytest.approx(fit.frequency_hz, rel=2e-3)


@pytest.mark.parametrize(
    "call,name",
    [
        (lambda: ident.identify_mode(np.ones(100), np.ones(50), 0.01), "y"),
        (lambda: ident.identify_mode(np.ones(100)), "Ts"),
        (lambda: ident.identify_mode(np.ones(100), np.arange(101.0), 0.01), "u"),
        (lambda: ident.identify_mode(np.sin(np.arange(100.0)), np.arange(101.0), -0.01), "Ts"),
        (lambda: ident.identify_mode(np.sin(np.arange(10.0)), np.arange(11.0), 0.01), "u"),
        (
            lambda: ident.identify_mode(
                np.sin(np.arange(100.0)), np.arange(101.0), 0.01, f_range=(5.0, 1.0)
            ),
            "f_range",
        ),
    ],
)
def test_bad_input_names_the_parameter(call, name):
    with pytest.raises((ValueError, TypeError), match=name):
        call()
