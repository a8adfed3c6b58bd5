"""piezo.table_ii_sensitivity / table_ii_distance / limit_excursions and the u_r / u_c names of Fig. 1."""

from __future__ import annotations

import math

import numpy as np
import pytest

from jerklab import piezo as pz


def test_distance_of_the_paper_to_itself_is_zero():
    d = pz.table_ii_distance(pz.TABLE_II_PAPER)
    assert d == {"cycle_rms_ms": 0.0, "cycle_max_ms": 0.0, "error_factor": 1.0}
    shifted = {k: (v[0] + 1e-3, v[1] * 2, v[2] / 2) for k, v in pz.TABLE_II_PAPER.items()}
    d = pz.table_ii_distance(shifted)
    assert math.isclose(d["cycle_rms_ms"], 1.0) and math.isclose(d["error_factor"], 2.0)
    with pytest.raises(ValueError, match="rows"):
        pz.table_ii_distance({})


@pytest.mark.slow
def test_sensitivity_matches_table_ii_and_the_both_modes_reading():
    sens = pz.table_ii_sensitivity((38.0, 100.0), readings={"mode 1": (1,), "both modes": (1, 2)})
    # the mode-1 reading at 38 V is table_ii() itself
    ref = pz.table_ii(38.0)
    m1 = next(r for r in sens if r["reading"] == "mode 1" and r["F_max"] == 38.0)
    for name, row in ref.items():
        assert np.allclose(
            m1["rows"][name], (row["cycle_time"], row["e_m"], row["e_r"]), rtol=1e-12
        )
    # both modes robustified at 100 V: the cycle times 8.0 / 11.2 / 15.0 / 13.4 ms
    both = next(r for r in sens if r["reading"] == "both modes" and r["F_max"] == 100.0)
    assert [round(v[0] * 1e3, 1) for v in both["rows"].values()] == [8.0, 11.2, 15.0, 13.4]
    # both fit the paper to about half a millisecond RMS; the reading at 38 V, mode 1, is the closer
    assert max(m1["distance"]["cycle_rms_ms"], both["distance"]["cycle_rms_ms"]) < 0.5
    assert pz.best_table_ii_reading(sens) is m1


def test_sensitivity_infeasible_limit_gives_nan():
    # the scan alone needs a 32 V input ramp from y(T) >= 0: 20 V cannot shape any cycle
    sens = pz.table_ii_sensitivity((20.0,), readings={"mode 1": (1,)})
    assert all(math.isnan(x) for v in sens[0]["rows"].values() for x in v)
    with pytest.raises(ValueError):
        pz.best_table_ii_reading(sens)
    with pytest.raises(ValueError, match="readings"):
        pz.table_ii_sensitivity((38.0,), readings={"bad": (3,)})
    with pytest.raises(ValueError, match="F_max_values"):
        pz.table_ii_sensitivity((-1.0,))


def test_limit_excursions_on_a_known_signal():
    t = np.arange(100) * 1e-3
    u = np.zeros(100)
    u[10:15] = 40.0
    u[50] = -45.0
    ex = pz.limit_excursions(t, u, 38.0)
    assert ex.peak == -45.0 and math.isclose(ex.t_peak, 0.05)
    assert math.isclose(ex.time_above, 6e-3)
    assert np.allclose(ex.intervals, [(0.010, 0.015), (0.050, 0.051)])
    assert pz.limit_excursions(t, np.ones(100), 38.0).intervals == ()
    with pytest.raises(ValueError, match="F_max"):
        pz.limit_excursions(t, u, 0.0)


@pytest.mark.slow
def test_closed_loop_names_follow_fig_1():
    """u_r is the reference H must reproduce, u_c the actuator voltage: H(u_c) ≈ u_r within ε."""
    hyst = pytest.importorskip("jerklab.hysteresis")
    P = hyst.Preisach.piezo_like(-45.0, 45.0, n=30)
    c = pz.shape_cycle(1, 2)
    r = pz.closed_loop(c, hysteresis=P, cancellation_error=0.0, perturbed=c.model)
    assert np.abs(r.f - r.u_r).max() <= P.default_eps + 1e-9  # the hysteresis output follows u_r
    assert (
        np.abs(r.u_c - r.u_r).max() > 10 * P.default_eps
    )  # u_c is the inverted (different) signal
