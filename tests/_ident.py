"""Shared set-up of the identification tests (tests/test_ident_*.py): the motor of Stojčić eq. 1
(ASCII: Stojcic) as the paper identified it, and two independent ways to make its records."""

from __future__ import annotations

import control as ct
import numpy as np

from jerklab.plant import DCMotor

#: the paper's motor (Stojčić §4A) and sample period
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
