"""sim.pd_rest_band: the band notebook 04 draws around eq. 9's PD rest error holds the simulated rest."""

from __future__ import annotations

import math

import numpy as np
import pytest

from jerklab.controller import (
    DigitalController,
    DiscreteGains,
    Feedforward,
    discrete_pole_placement_pid,
)
from jerklab.planner import plan_sine_jerk_optimal
from jerklab.plant import DCMotor, measure_angle, quantize_voltage
from jerklab.sim import pd_rest_band, simulate

K, TAU, TS = 32.4, 0.025, 0.005


def _brute_force_hull(kpd, w, fc, cpr, r, supply, bits):
    """Every encoder count n at which the PD output (PWM rounded) plus the load is held by friction."""
    q = 1.0 / cpr
    errs = []
    for n in range(int((r - 2.0) * cpr), int((r + 2.0) * cpr)):
        em = r - n * q
        u = float(quantize_voltage(kpd * em, supply, bits))
        if abs(u + w) <= fc:
            # true error r - θ for θ within this count: θ in [n q, (n+1) q)
            errs += [r - (n + 1) * q + 1e-12, em]
    return min(errs), max(errs)


@pytest.mark.parametrize(
    "w,fc,r", [(-1.0, 0.2, 4 * math.pi), (-1.0, 0.2, 1.0), (0.5, 0.1, 2.3), (-2.0, 0.5, 0.7)]
)
def test_band_is_the_hull_of_the_rest_states(w, fc, r):
    kpd, cpr = 3.0, 448 / (2 * math.pi)
    lo, hi = pd_rest_band(kpd, w, fc, cpr, 12.0, 10)
    blo, bhi = _brute_force_hull(kpd, w, fc, cpr, r, 12.0, 10)
    # slack: the admissible measured errors lie on a grid of one count, and the PWM grid (one duty
    # step, 12/1023 V) decides where inside [E_lo, E_lo + Δ/k_pd] the first admissible one falls
    slack = 1.0 / cpr + 12.0 / 1023 / kpd
    assert lo - 1e-9 <= blo and bhi <= hi + 1e-9  # every rest state is inside the band
    assert blo - lo <= slack + 1e-9 and hi - bhi <= slack + 1e-9


def test_notebook_04_pd_rest_is_in_the_band():
    """Notebook 04, section 4: PD (k_id = 0) with a −1 V load step and 0.2 V Coulomb friction."""
    rig = DCMotor(
        K,
        TAU,
        supply_voltage=12.0,
        pwm_bits=10,
        encoder_ppr=448,
        decoding=1,
        coulomb_friction=0.2,
        load_disturbance=(1.2, -1.0),
    )
    g = discrete_pole_placement_pid(K, TAU, wn=30.0, Ts=TS)
    p = plan_sine_jerk_optimal(4 * np.pi, 2000.0, 150.0, 40.0)
    r = simulate(
        p,
        rig,
        DigitalController(DiscreteGains(g.kpd, 0.0, g.kdd, TS), Feedforward(K, TAU)),
        t_end=2.5,
    )
    lo, hi = pd_rest_band(g.kpd, -1.0, 0.2, rig.counts_per_rad, 12.0, 10)
    final = r.metrics["final_error"]
    assert lo <= final <= hi
    # the band without the encoder count (what the notebook drew before) misses this rest state
    naive_lo = (1.0 - 0.2) / g.kpd
    assert final < naive_lo
    # the measured error the PD saw is inside the friction band proper
    em = p.distance - float(measure_angle(r.position[-1], rig.counts_per_rad))
    assert abs(float(quantize_voltage(g.kpd * em, 12.0, 10)) - 1.0) <= 0.2 + 1e-9


def test_band_rejects_bad_input():
    with pytest.raises(ValueError, match="kpd"):
        pd_rest_band(-1.0, 1.0, 0.1)
    with pytest.raises(ValueError, match="coulomb_friction"):
        pd_rest_band(1.0, 1.0, -0.1)
    assert pd_rest_band(2.0, -1.0, 0.0) == (0.5, 0.5)
