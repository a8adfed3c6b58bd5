"""The numbers notebooks 01-04 show for Stojčić's paper (ASCII: Stojcic), computed by the library
and checked against an independent reference: the derived formulas, a numerical integration of
the jerk, the flowchart's own formulas, Ruckig, python-control, the rest band of the PD loop.

Each test names the notebook section whose text quotes the number; the notebooks show the numbers
and say what they mean, these tests keep them true.
"""

from __future__ import annotations

import importlib.util
import itertools
import math

import numpy as np
import pytest
from scipy.integrate import cumulative_trapezoid

from jerklab.controller import (
    DigitalController,
    DiscreteGains,
    Feedforward,
    PositionLoop,
    discrete_pole_placement_pid,
    pole_placement_pid,
)
from jerklab.diagrams import PLANNER_BRANCH_CASES
from jerklab.planner import (
    plan_batch,
    plan_scurve,
    plan_sine_jerk,
    plan_sine_jerk_optimal,
    plan_trapezoid,
)
from jerklab.plant import DCMotor
from jerklab.sim import pd_rest_band, simulate

HAVE_RUCKIG = importlib.util.find_spec("ruckig") is not None


# ------------------------------------------------------------------ notebook 01, section 1
def test_closed_form_is_the_derivation_of_eq_2_to_4():
    """Stojčić eqs. 2–4 integrated by hand (notebook 01 §1) against the library's closed form."""
    theta, J, E, W = 100.0, 1000.0, 100.0, 60.0
    p = plan_sine_jerk(theta, J, E, W)
    T = p.accel_time
    w = 2 * np.pi / T
    t = np.linspace(0, T, 2001)
    s = p.sample(t)
    derived = {
        "accel": (J / w) * (1 - np.cos(w * t)),
        "velocity": (J / w) * (t - np.sin(w * t) / w),
        "position": (J / w) * (t**2 / 2 + (np.cos(w * t) - 1) / w**2),
    }
    for name, f in derived.items():
        assert np.max(np.abs(getattr(s, name) - f)) / np.max(np.abs(f)) < 1e-12, name
    # eq. 3: E = J T / pi is the peak acceleration (the acceleration limit binds here),
    # Omega(T) = J T^2 / (2 pi)
    assert math.isclose(s.accel.max(), E, rel_tol=1e-9)
    assert math.isclose(s.velocity[-1], J * T**2 / (2 * np.pi), rel_tol=1e-12)


def test_closed_form_is_the_jerk_integrated_three_times():
    """The whole move's jerk integrated numerically (trapezoidal rule) reaches the distance."""
    p = plan_sine_jerk(100.0, 1000.0, 100.0, 60.0)
    tt = np.linspace(0, p.duration, 400_001)
    jerk = p.sample(tt).jerk
    acc = cumulative_trapezoid(jerk, tt, initial=0)
    vel = cumulative_trapezoid(acc, tt, initial=0)
    pos = cumulative_trapezoid(vel, tt, initial=0)
    ref = p.sample(tt)
    assert abs(pos[-1] - 100.0) < 1e-4
    assert np.abs(pos - ref.position).max() < 1e-4
    assert np.abs(vel - ref.velocity).max() < 1e-4


# ------------------------------------------------------------------ notebook 01, section 3
# (that the four cases walk every path of the flowchart is tests/test_diagrams.py's
# test_branch_cases_cover_every_path)
@pytest.mark.parametrize("name", list(PLANNER_BRANCH_CASES))
def test_each_branch_takes_the_shortest_of_the_three_times(name):
    th, J, E, W = PLANNER_BRANCH_CASES[name]
    p = plan_sine_jerk(th, J, E, W)
    T_theta = (2 * np.pi * th / J) ** (1 / 3)  # eq. 4
    T_E, T_W = E * np.pi / J, np.sqrt(2 * np.pi * W / J)  # eq. 3 solved for T
    assert math.isclose(p.accel_time, min(T_theta, T_E, T_W), rel_tol=1e-12)
    assert p.peak_jerk == J  # the published planner never lowers the jerk


def test_when_the_acceleration_binds_the_cruise_collapses():
    """Notebook 01 §3 quotes the second row: 15.7 rad/s (= E T / 2) against Omega = 1000."""
    th, J, E, W = PLANNER_BRANCH_CASES["acceleration binds (T = Eπ/J)"]
    q = plan_sine_jerk(th, J, E, W)
    assert round(q.peak_velocity, 1) == 15.7 and W == 1000.0
    assert math.isclose(q.peak_velocity, E * q.accel_time / 2, rel_tol=1e-12)


# ------------------------------------------------------------------ notebook 01, section 4
def test_eq_15_misses_the_target_by_0_8_percent_at_5_ms():
    """The eq. 15 recursion against the exact distance (also quoted in docs/THEORY.md)."""
    p = plan_sine_jerk(100.0, 1000.0, 100.0, 60.0)
    rec = p.discretize(0.005)
    assert round(100 * (rec.position[-1] - 100.0) / 100.0, 2) == -0.80


def _drift(n_samples):
    """(acceleration left after the pulse / E, end error %, end velocity) of eq. 15 for a pulse
    of ``n_samples`` samples (acceleration binding), Theta = 100 rad, J = 1e4, Ts = 5 ms."""
    Ts = 0.005
    E = 1e4 * n_samples * Ts / np.pi
    q = plan_sine_jerk(100.0, 1e4, E, 1e9)
    d = q.discretize(Ts)
    k = int(np.ceil(q.accel_time / Ts)) + 1  # the first sample after the acceleration pulse
    return d.accel[k] / q.peak_accel, 100 * (d.position[-1] - 100.0) / 100.0, d.velocity[-1]


def test_eq_15_drift_grows_with_a_fraction_of_a_sample():
    """Notebook 01 §4: -4 % at 9 samples (ending backwards); 1 % of E left and -141 % at 15.5;
    thousands of percent at 9.5. The closed form ends exactly at 100 rad in every case."""
    left, err, v_end = _drift(9)
    assert round(err, 1) == -4.1 and v_end < 0
    left, err, _ = _drift(15.5)
    assert round(left, 2) == -0.01 and round(err) == -141
    assert _drift(9.5)[1] < -1000


def test_synchronized_plan_ends_exactly_on_a_sample():
    Ts = 0.005
    q = plan_sine_jerk(100.0, 1000.0, 100.0, 60.0).synchronized(Ts)
    s = q.sample(np.arange(round(q.duration / Ts) + 1) * Ts)
    assert abs(s.position[-1] - 100.0) < 1e-12 and abs(s.velocity[-1]) < 1e-12
    assert all(abs(x / Ts - round(x / Ts)) < 1e-9 for x in q.phase_times)


# ------------------------------------------------------------------ notebook 01, section 5
THEORY_EXAMPLE = (10 * np.pi, 2e4, 300.0, 100.0)


def test_published_planner_cruises_at_7_rad_s_for_4_49_s():
    """The example of docs/THEORY.md (Stojčić eq. 4): T = 47 ms, a cruise at 7.07 rad/s, 4.49 s."""
    pub = plan_sine_jerk(*THEORY_EXAMPLE)
    assert round(pub.accel_time, 3) == 0.047
    assert round(pub.peak_velocity, 2) == 7.07
    assert round(pub.duration, 2) == 4.49


def test_published_planner_is_six_times_slower_than_the_optimum():
    d, J, E, W = THEORY_EXAMPLE
    best = plan_scurve(d, J, E, W).duration
    if HAVE_RUCKIG:
        from jerklab.peers import ruckig_duration

        assert abs(ruckig_duration(d, J, E, W) - best) < 1e-9 * best
    assert plan_sine_jerk(d, J, E, W).duration / best > 6
    assert plan_sine_jerk_optimal(d, J, E, W).duration / best < 1.02
    # the optimal sine profile lasts exactly as long as the S-curve at jerk 2J/pi
    assert math.isclose(
        plan_sine_jerk_optimal(d, J, E, W).duration,
        plan_scurve(d, 2 * J / np.pi, E, W).duration,
        rel_tol=1e-12,
    )
    assert plan_trapezoid(d, E, W).duration < best


def test_optimal_sine_is_at_most_the_cube_root_of_pi_half_slower():
    """Notebook 01 §5 over 48 limit sets: the optimal sine profile is at most (pi/2)^(1/3) = 1.162
    slower than the time-optimal jerk-limited move, and reaches the bound; the published one is
    never faster than it."""
    grid = list(
        itertools.product(
            [0.01, 0.1, 1.0, 10 * np.pi, 100.0, 1000.0], [1e3, 2e4], [10.0, 300.0], [10.0, 100.0]
        )
    )
    d, J, E, W = (np.array(c) for c in zip(*grid))
    ref = plan_batch("scurve", d, J, E, W).duration
    pub = plan_batch("sine_jerk", d, J, E, W).duration / ref
    opt = plan_batch("sine_jerk_optimal", d, J, E, W).duration / ref
    bound = (np.pi / 2) ** (1 / 3)
    assert opt.max() <= bound * (1 + 1e-12) and round(opt.max(), 3) == round(bound, 3) == 1.162
    assert np.all(pub >= opt * (1 - 1e-12))


# ------------------------------------------------------------------ notebook 03, section 2
@pytest.mark.parametrize("wn,radius", [(10, 0.952), (30, 0.876), (40, 0.992), (50, 1.162)])
def test_eq_13_design_radius_at_5_ms(wn, radius):
    """The largest |z| of eq. 11 + eq. 13 at Ts = 5 ms that notebook 03 quotes (unstable at 50),
    against the roots of the characteristic polynomial computed by python-control."""
    import control as ct

    K, tau, Ts = 32.4, 0.025, 0.005
    g = pole_placement_pid(K, tau, wn)
    L = PositionLoop(K, tau, g, Ts=Ts)
    assert round(L.max_pole_radius(), 3) == radius
    d = g.discretize(Ts)
    P = ct.c2d(ct.tf([K], [tau, 1, 0]), Ts, "zoh")
    B = ct.tf([d.kpd + d.kid + d.kdd, -(d.kpd + 2 * d.kdd), d.kdd], [1, -1, 0], Ts)
    assert math.isclose(
        np.abs(ct.feedback(B * P, 1).poles()).max(), L.max_pole_radius(), rel_tol=1e-9
    )


# ------------------------------------------------------------------ notebook 04, section 4
def test_pd_loop_rests_inside_its_band_under_a_load():
    """Notebook 04 §4: the PD loop (k_id = 0) under a -1 V load rests where the rest band of
    friction, an encoder count and a PWM step says, below (|w| - f_c) / k_pd."""
    K, tau, Ts = 32.4, 0.025, 0.005
    rig = DCMotor(
        K, tau, supply_voltage=12.0, pwm_bits=10, encoder_ppr=448, decoding=1, coulomb_friction=0.2
    )
    gains = discrete_pole_placement_pid(K, tau, wn=30.0, Ts=Ts)
    p = plan_sine_jerk_optimal(4 * np.pi, 2000.0, 150.0, 40.0)
    pd_only = DiscreteGains(gains.kpd, 0.0, gains.kdd, Ts)
    r = simulate(
        p,
        rig.replace(load_disturbance=(1.2, -1.0)),
        DigitalController(pd_only, Feedforward(K, tau)),
        t_end=2.5,
    )
    lo, hi = pd_rest_band(gains.kpd, -1.0, 0.2, rig.counts_per_rad, 12.0, 10)
    final = r.metrics["final_error"]
    assert lo <= final <= hi
    assert final < (1.0 - 0.2) / gains.kpd
