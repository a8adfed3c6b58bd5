"""The flexible mode found from the encoder alone (jerklab.ident.mode.identify_mode).

Independent references: the plant's own state-space simulation and eigenvalues
(``FlexibleDCMotor.open_loop``, ``FlexibleDCMotor._matrices``) for the identification's fast
simulation and coupled mode; simulated, quantized, noisy encoder records of a known plant for
the fit. The shaper recommended for the mode is tested with ``jerklab.shaping``
(tests/test_shaping.py).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from jerklab import shaping
from jerklab.ident import IdentData, ModeEstimate, coupled_mode, identify_mode, prbs
from jerklab.ident.mode import _flex_simulate
from jerklab.plant import FlexibleDCMotor


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
    mode = coupled_mode(m.K, m.tau, m.load_ratio, m.mode_frequency, m.mode_damping)
    assert mode == pytest.approx(_true_mode(m))
    assert shaping.flexible_mode(m) == mode


@pytest.mark.parametrize("load_ratio,excitation", [(0.05, "chirp"), (0.3, "prbs"), (0.15, "chirp")])
def test_identify_mode_from_encoder(load_ratio, excitation):
    m = FlexibleDCMotor(
        load_ratio=load_ratio,
        mode_frequency=2 * math.pi * 8.0,
        mode_damping=0.02,
        noise_std=0.002,
        seed=7,
    )
    Ts = 0.005
    u = (
        shaping.chirp_input(8.0, Ts, 3.0, 1.0, 30.0)
        if excitation == "chirp"
        else prbs(8.0, Ts, 3.0, clock_period=0.01)
    )
    _, y = m.open_loop(u, Ts)  # quantized to 448 counts/rev, plus noise
    fit = identify_mode(u, y, Ts)
    assert isinstance(fit, ModeEstimate) and not hasattr(fit, "shaper")
    f0, z0 = _true_mode(m)
    assert abs(fit.frequency_hz - f0) < max(4 * fit.frequency_se, 0.005 * f0)
    assert abs(fit.damping - z0) < max(4 * fit.damping_se, 0.1 * z0)
    assert 0 < fit.frequency_se < 0.02 * f0
    assert fit.jerk_time == pytest.approx(1 / (fit.frequency_hz * math.sqrt(1 - fit.damping**2)))
    # the fitted plant has the mode that was reported
    fm = fit.model()
    assert coupled_mode(fm.K, fm.tau, fm.load_ratio, fm.mode_frequency, fm.mode_damping) == (
        pytest.approx((fit.frequency_hz, fit.damping))
    )
    # the same record as an IdentData (equal lengths: the last input is not used)
    fit2 = identify_mode(IdentData(u, y[:-1], Ts))
    assert fit2.frequency_hz == pytest.approx(fit.frequency_hz, rel=2e-3)


@pytest.mark.parametrize(
    "call,name",
    [
        (lambda: identify_mode(np.ones(100), np.ones(50), 0.01), "y"),
        (lambda: identify_mode(np.ones(100)), "Ts"),
        (lambda: identify_mode(np.ones(100), np.arange(101.0), 0.01), "u"),
        (lambda: identify_mode(np.sin(np.arange(100.0)), np.arange(101.0), -0.01), "Ts"),
        (lambda: identify_mode(np.sin(np.arange(100.0)), np.arange(101.0), float("nan")), "Ts"),
        (lambda: identify_mode(np.sin(np.arange(100.0)), [np.nan] * 101, 0.01), "y"),
        (lambda: shaping.identify_mode(np.ones(100), np.ones(50), 0.01), "y"),
        (
            lambda: identify_mode(
                np.sin(np.arange(100.0)), np.arange(101.0), 0.01, f_range=(5.0, 1.0)
            ),
            "f_range",
        ),
        (
            lambda: identify_mode(
                IdentData(np.sin(np.arange(100.0)), np.arange(100.0), 0.01), Ts=1
            ),
            "Ts",
        ),
    ],
)
def test_bad_input_names_the_parameter(call, name):
    with pytest.raises((ValueError, TypeError), match=name):
        call()


@pytest.mark.parametrize("fit", [identify_mode, shaping.identify_mode])
def test_an_overdamped_load_is_reported_not_returned_as_nan(fit):
    """A shaft so damped (ζ 1.5, 3) that the two-mass model has no complex pole pair: the plant's
    own eigenvalues are real, the fit's best model is overdamped too, and identify_mode says so
    by name instead of returning f = ζ = NaN (which shaping's shaper design then refused with
    "frequency_hz must be finite")."""
    for zr, lr in ((1.5, 0.3), (3.0, 1.0)):
        m = FlexibleDCMotor(
            load_ratio=lr,
            mode_frequency=2 * math.pi * 8.0,
            mode_damping=zr,
            noise_std=0.002,
            seed=7,
        )
        A, _ = m._matrices()
        assert np.all(np.abs(np.linalg.eigvals(A).imag) < 1e-9)  # no mode to find
        u = prbs(4.0, 0.005, 3.0, clock_period=0.01)
        _, y = m.open_loop(u, 0.005)
        with pytest.raises(ValueError, match="overdamped"):
            fit(u, y, 0.005)
