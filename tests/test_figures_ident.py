"""The numbers notebook 02 (identification, Stojčić §4A; ASCII: Stojcic) shows, computed by
jerklab.ident on the records the notebook fits and checked against the truth the data were made
with (the simulated records) or against bounds from the data themselves (the measured ones).

Each test names the notebook section whose text quotes the number.
"""

from __future__ import annotations

import pathlib
import warnings

import numpy as np
import pytest
from _ident import dc_generator_fits

from jerklab import ident
from jerklab.controller import DigitalController, discrete_pole_placement_pid
from jerklab.plant import DCMotor
from jerklab.sim import SampledProfile, simulate

DATA = pathlib.Path(__file__).resolve().parents[1] / "data" / "ident"
K_TRUE, TAU_TRUE = 32.4, 0.025


def quiet(f, *args, **kw):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ident.IdentificationWarning)
        return f(*args, **kw)


# ------------------------------------------------------------------ section 2
def test_two_levels_separate_the_gain_from_the_friction():
    """The PRBS between 3 V and 9 V of data/ident/prbs_6V_3V (made with f_c = 0.2 V): the fit with
    friction finds it within 0.02 V and K within 1 %."""
    prbs = ident.IdentData.load(DATA / "prbs_6V_3V")
    assert prbs.metadata["plant"]["coulomb_friction"] == 0.2
    f = prbs.fit("pem", friction=True)
    assert abs(f.friction - 0.2) < 0.02 and abs(f.K / K_TRUE - 1) < 0.01


def test_the_papers_p2_structure_runs_its_pole_to_the_integrator():
    """MATLAB's 'P2' on the step record: T1 goes to its bound and K/T1 is eq. 1's K (to 1 %)."""
    step = ident.IdentData.load(DATA / "step_6V")
    p2 = ident.fit_p2(step.u, step.y, step.Ts)
    pem = step.fit("pem")
    assert p2.at_bound
    assert abs(p2.integrator_gain / pem.K - 1) < 0.01


# ------------------------------------------------------------------ section 7
def closed_loop_record(seed=0, T=2.0, Ts=0.001):
    """Notebook 02 §7's record: the z-domain PID of notebook 03 (wn = 30 rad/s) at 1 kHz on a
    square-and-sine reference, simulated by jerklab.sim with friction, an input offset, an x4 encoder
    and noise; the logged voltage is the controller's output."""
    m = DCMotor(
        K=K_TRUE,
        tau=TAU_TRUE,
        coulomb_friction=0.4,
        offset=0.25,
        noise_std=0.0005,
        seed=seed,
        decoding=4,
    )
    t = np.arange(int(round(T / Ts))) * Ts
    ref = 2.0 * np.sign(np.sin(2 * np.pi * 1.3 * t)) + 0.5 * np.sin(2 * np.pi * 3.1 * t)
    gains = discrete_pole_placement_pid(K_TRUE, TAU_TRUE, wn=30.0, Ts=Ts)
    run = simulate(
        SampledProfile(Ts, ref),
        m,
        DigitalController(gains, feedforward=None, output_limit=12.0),
        t_end=t[-1],
    )
    return ident.IdentData(run.u, run.measured, Ts)


@pytest.fixture(scope="module")
def closed_loop_fit():
    return quiet(closed_loop_record().fit, "pem", friction=True, offset=True, delay=True)


def test_closed_loop_record_gives_every_parameter_to_one_percent(closed_loop_fit):
    f = closed_loop_fit
    truth = dict(K=K_TRUE, tau=TAU_TRUE, friction=0.4, offset=0.25)
    assert all(abs(getattr(f, k) / v - 1) < 0.01 for k, v in truth.items()), f.summary()
    assert f.delay == 0  # the simulation applies each voltage at its sampling instant


def test_eq_1_alone_on_the_closed_loop_record_misses_by_about_half():
    """Eq. 1 without friction and offset, one segment on the first second: K and tau about half."""
    old = quiet(closed_loop_record()[:1000].fit, "pem")
    assert -0.7 < old.K / K_TRUE - 1 < -0.4 and -0.6 < old.tau / TAU_TRUE - 1 < -0.35


def test_the_fit_predicts_a_fresh_closed_loop_record(closed_loop_fit):
    fresh = closed_loop_record(seed=7)
    assert ident.compare(fresh, closed_loop_fit).fit_percent > 99.0
    assert ident.compare(fresh, closed_loop_fit, horizon=20).fit_percent > 98.0


# ------------------------------------------------------------------ section 8: the micromouse
@pytest.fixture(scope="module")
def micromouse():
    est, val = (ident.load_micromouse(n) for n in ("encoders1", "encoders3"))
    fits = {
        "linear": quiet(est.fit, "pem", delay=True),
        "friction": quiet(est.fit, "pem", delay=True, friction=True),
    }
    return est, val, fits


def test_micromouse_numbers_the_notebook_quotes(micromouse):
    """K about 26 rad/(V s), f_c about 1.7 V, validation fit about 91 % with friction against about
    83 % without, both above the floor that the two records' different steady speeds set."""
    est, val, fits = micromouse
    fm = fits["friction"]
    last = int(np.flatnonzero(est.u > 0)[-1])
    w1 = (est.y[last] - est.y[last - 80]) / (80 * est.Ts)
    w3 = (val.y[-1] - val.y[-81]) / (80 * val.Ts)
    floor = ident.fit_percent(val.y, val.y * w1 / w3)
    v_fr = ident.compare(val, fm).fit_percent
    v_lin = ident.compare(val, fits["linear"]).fit_percent
    assert floor < v_fr and v_fr > v_lin + 3 and 0.10 < fm.tau < 0.25
    assert 24 < fm.K < 28 and 1.5 < fm.friction < 1.9
    assert 88 < v_fr < 94 and 80 < v_lin < 86
    assert round(w1, 1) == 36.5 and round(w3, 1) == 41.3


# ------------------------------------------------------------------ section 8b: the DC generator
@pytest.fixture(scope="module")
def generator():
    _, val, f = dc_generator_fits()
    names = {
        "eq. 1 + delay": "linear",
        "open drive, viscous": "viscous",
        "open drive, viscous + Coulomb": "both",
        "open drive, Coulomb": "coulomb",
    }
    return val, {label: f[key] for label, key in names.items()}


def test_dc_generator_numbers_the_notebook_quotes(generator):
    """The open drive is the model: validation speed fit above 70 % with the Coulomb run-down,
    at least 5 points above the viscous one, below 0 % for eq. 1 alone; given both run-downs the
    viscous rate runs to its bound (tau_coast beyond 1e3 clock periods)."""
    val, fits = generator
    v = {k: ident.compare(val, f, output="speed").fit_percent for k, f in fits.items()}
    assert v["open drive, Coulomb"] > 70 and v["eq. 1 + delay"] < 0
    assert v["open drive, Coulomb"] > v["open drive, viscous"] + 5
    assert fits["open drive, viscous + Coulomb"].tau_coast > 1e3
