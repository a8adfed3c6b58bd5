"""Input design (jerklab.ident.design): the PRBS is maximum-length and held per clock, the step and
the sample-time rule of Stojčić §4A.
"""

from __future__ import annotations

import numpy as np
import pytest
from _ident import TS

from jerklab import ident


def test_prbs_properties():
    u = ident.prbs(127 * 0.02, TS, 2.0, offset=5.0, clock_period=0.02, nbits=7, seed=3)
    assert u.size == 127 * 4
    assert set(np.unique(u)) == {3.0, 7.0}
    bits = u[::4]
    assert np.all(u.reshape(-1, 4) == bits[:, None])  # each bit held 4 samples
    assert np.count_nonzero(bits == 7.0) == 64  # maximum-length: 2^(n-1) ones per period
    assert not np.array_equal(
        bits, ident.prbs(127 * 0.02, TS, 2.0, offset=5.0, clock_period=0.02, nbits=7, seed=4)[::4]
    )
    with pytest.raises(ValueError, match="clock_period"):
        ident.prbs(1.0, TS, 1.0, clock_period=0.0123)
    with pytest.raises(ValueError, match="amplitude"):
        ident.prbs(1.0, TS, -1.0)


def test_step_input_and_sample_time_rule():
    u = ident.step_input(0.1, TS, 6.0, t_step=0.02)
    assert u.size == 20 and np.all(u[:4] == 0) and np.all(u[4:] == 6.0)
    with pytest.raises(ValueError, match="t_step"):
        ident.step_input(0.1, TS, 6.0, t_step=0.2)
    lo, hi = ident.sample_time_range(0.025)
    assert lo == pytest.approx(0.005) and hi == pytest.approx(0.0125)
