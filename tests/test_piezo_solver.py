"""The default shaping solver (NNLS screen + one LP per search) against an LP at every horizon.

The screen must give the LP's verdict on every horizon it is asked about, and the default
must return the LP's horizon and command exactly (so Xu & Meckl Table II does not change).
"""

from __future__ import annotations

import numpy as np
import pytest

from jerklab import piezo as pz


@pytest.mark.parametrize("orders", [0, 1, 2])
def test_screen_agrees_with_the_lp_on_every_horizon(orders):
    model, spec = pz.PZTModel(), pz.ScanSpec()
    o = pz._normalize_orders(orders)
    w, G1, beta = pz._ramp_constants(model, spec)
    poles = model.mode_poles(spec.Ts)
    verdicts = []
    for N in range(1, 40):
        lp = pz._rampup_lp(N, model, spec, o, poles, w, G1, beta, None, "lp")
        screen = pz._rampup_lp(N, model, spec, o, poles, w, G1, beta, None, "nnls")
        assert (lp is None) == (screen is None), N
        verdicts.append(lp is not None)
        if screen is not None:  # the screen's point is feasible
            lo = -spec.F_max
            assert np.all(screen[:-1] >= lo - 1e-9) and np.all(screen[:-1] <= spec.F_max + 1e-9)
    assert not all(verdicts) and any(verdicts)  # both kinds were tried


@pytest.mark.parametrize("t_orders, r_orders", [(0, None), (1, 2)])
def test_default_returns_the_lp_command(t_orders, r_orders):
    a = pz.shape_cycle(t_orders, r_orders)
    b = pz.shape_cycle(t_orders, r_orders, solver="highs")
    assert (a.N, a.N_r) == (b.N, b.N_r)
    np.testing.assert_array_equal(a.command(), b.command())


def test_bad_solver_is_named():
    with pytest.raises(ValueError, match="solver"):
        pz.shape_rampup(solver="simplex")
