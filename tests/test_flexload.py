"""The flexible load's prediction (jerklab.rig.flexload) against independent computations: a
finite-element Euler–Bernoulli beam and the textbook clamped-free cantilever."""

from __future__ import annotations

import math

import numpy as np
import pytest
import scipy.linalg

from jerklab import shaping
from jerklab.lab.motors import coupled_mode
from jerklab.plant import FlexibleDCMotor
from jerklab.rig import Device, connect, load_profile
from jerklab.rig.flexload import (
    DESIGN_RANGE,
    RulerLoad,
    design_loads,
    exact_frequency,
    mode_ranges,
    motor_inertia,
    predict,
)


def fe_frequency(load: RulerLoad, n=40) -> float:
    """First mode (rad/s) of a clamped-free beam with a tip point mass: n Hermite cubic
    elements, consistent mass matrices (Przemieniecki), the tip mass on the last deflection."""
    le = load.length / n
    EI = load.EI
    rhoA = load.rho * load.width * load.thickness
    k = (
        EI
        / le**3
        * np.array(
            [
                [12, 6 * le, -12, 6 * le],
                [6 * le, 4 * le**2, -6 * le, 2 * le**2],
                [-12, -6 * le, 12, -6 * le],
                [6 * le, 2 * le**2, -6 * le, 4 * le**2],
            ]
        )
    )
    m = (
        rhoA
        * le
        / 420
        * np.array(
            [
                [156, 22 * le, 54, -13 * le],
                [22 * le, 4 * le**2, 13 * le, -3 * le**2],
                [54, 13 * le, 156, -22 * le],
                [-13 * le, -3 * le**2, -22 * le, 4 * le**2],
            ]
        )
    )
    N = 2 * (n + 1)
    K, M = np.zeros((N, N)), np.zeros((N, N))
    for e in range(n):
        i = slice(2 * e, 2 * e + 4)
        K[i, i] += k
        M[i, i] += m
    M[-2, -2] += load.tip_mass
    free = slice(2, N)  # clamped: deflection and slope 0 at the root
    w2 = scipy.linalg.eigh(K[free, free], M[free, free], eigvals_only=True)
    return math.sqrt(w2[0])


def test_the_bare_cantilever_is_the_textbook_one():
    # clamped-free, no tip mass: omega = 1.8751^2 sqrt(EI / (rho A L^4)) (Blevins ch. 8)
    ld = RulerLoad(tip_mass=0.0)
    ref = 1.875104069**2 * math.sqrt(ld.EI / (ld.rho * ld.width * ld.thickness * ld.length**4))
    assert fe_frequency(ld) == pytest.approx(ref, rel=1e-5)
    assert exact_frequency(ld) == pytest.approx(ref, rel=1e-8)
    # Rayleigh's 33/140 of the beam's mass at the tip: 1.5 % high without a tip mass
    assert predict(ld)["mode_frequency"] == pytest.approx(ref, rel=0.016)
    assert predict(ld)["mode_frequency"] > ref


@pytest.mark.parametrize(
    "load", design_loads(3) + [RulerLoad(length=0.25, tip_mass=0.005, thickness=0.0008)]
)
def test_the_prediction_agrees_with_a_finite_element_beam(load):
    fe = fe_frequency(load)
    assert exact_frequency(load) == pytest.approx(fe, rel=1e-5)
    assert predict(load)["mode_frequency"] == pytest.approx(fe, rel=0.01)


def test_the_design_range_gives_the_labs_mode_band():
    f = [predict(ld)["mode_hz"] for ld in design_loads(2)]
    assert 5.0 < min(f) < 7.0 and 14.0 < max(f) < 17.0


def test_the_two_mass_model_keeps_the_rigid_inertia():
    p = load_profile("pololu-37d-30")
    ld = RulerLoad(length=0.2, tip_mass=0.04)
    r = predict(ld, p)
    # J_m + J_l is the motor plus every part turning rigidly about the axis (direct sum here)
    R = ld.hub_radius + ld.length
    x = np.linspace(ld.hub_radius, R, 20001)
    J_rule = np.trapezoid(ld.rho * ld.width * ld.thickness * x**2, x)
    J_all = motor_inertia(p) + ld.hub_inertia + J_rule + ld.tip_mass * R**2
    assert r["motor_side_inertia"] + r["load_inertia"] == pytest.approx(J_all, rel=1e-6)
    assert r["tau"] == pytest.approx(p.tau * J_all / motor_inertia(p), rel=1e-6)
    # the motor's inertia from K, tau and R_a = V / I_stall: tau = J R_a k_t^-1 k_e^-1
    R_a = 12.0 / 5.5
    assert motor_inertia(p) * R_a / (1 / p.K) ** 2 == pytest.approx(p.tau)
    # the plant built from it has the predicted coupled mode
    m = FlexibleDCMotor(
        K=p.K,
        tau=r["tau"],
        load_ratio=r["load_ratio"],
        mode_frequency=r["mode_frequency"],
        mode_damping=r["damping"],
    )
    assert coupled_mode(m)[0] == pytest.approx(r["coupled_hz"], rel=1e-9)


def test_mode_ranges_span_the_design():
    p = load_profile("pololu-37d-30")
    rng = mode_ranges(p)
    lo, hi = rng["mode_hz"]
    assert lo < predict(RulerLoad(length=0.2, tip_mass=0.04))["mode_hz"] < hi
    assert 0 < rng["load_ratio"][0] < rng["load_ratio"][1]
    with pytest.raises(ValueError, match="stall current"):
        mode_ranges(load_profile("jgb37-520-30"))


def test_bad_dimensions_name_the_parameter():
    with pytest.raises(ValueError, match="length"):
        RulerLoad(length=-0.1)
    with pytest.raises(ValueError, match="tip_mass"):
        RulerLoad(tip_mass=float("nan"))
    with pytest.raises(TypeError, match="load"):
        predict({"length": 0.2})
    assert DESIGN_RANGE["length"][0] < DESIGN_RANGE["length"][1]


@pytest.mark.parametrize("length, tip_mass", [(0.17, 0.03), (0.22, 0.05)])
def test_the_mode_identified_from_the_encoder_is_the_predicted_one(length, tip_mass):
    """The rule's two-mass model on the Pololu 37D's virtual rig: a PRBS through it, the mode
    fitted from the motor's encoder alone (jerklab.shaping.identify_mode, lab 4's method), and
    the prediction from the dimensions agree."""
    p = load_profile("pololu-37d-30")
    r = predict(RulerLoad(length=length, tip_mass=tip_mass, damping=0.02), p)
    motor = FlexibleDCMotor(
        K=p.K,
        tau=r["tau"],
        load_ratio=r["load_ratio"],
        mode_frequency=r["mode_frequency"],
        mode_damping=r["damping"],
        encoder_ppr=p.counts_per_rev,
        decoding=1,
    )
    rig = connect(device=Device(motor), progress=False)
    try:
        rp = rig.record_prbs(3.0, offset=6.0, order=9, hold=1, path=False, progress=False)
    finally:
        rig.close()
    fit = shaping.identify_mode(rp.voltage, rp.position, rp.metadata["Ts"])
    assert fit.frequency_hz == pytest.approx(r["coupled_hz"], rel=0.02)
    # the encoder sees the coupled mode, above the rule's own (hub held still)
    assert fit.frequency_hz > r["mode_hz"]
