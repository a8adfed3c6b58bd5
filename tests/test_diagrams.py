"""jerklab.diagrams: every diagram builds; the flowchart of Stojčić Fig. 2 is the planner."""

from __future__ import annotations

import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from jerklab import diagrams as D
from jerklab.planner import plan_sine_jerk

pytest.importorskip("schemdraw")

pos = st.floats(1e-3, 1e4, allow_nan=False, allow_infinity=False)


@given(pos, pos, pos, pos)
def test_flowchart_walk_is_the_planner(theta, J, E, W):
    """Walking the drawn steps gives plan_sine_jerk's T, t_v and t_u."""
    run = D.run_flowchart(theta, J, E, W)
    p = plan_sine_jerk(theta, J, E, W)
    assert math.isclose(run.accel_time, p.accel_time, rel_tol=1e-12)
    assert math.isclose(run.duration, p.duration, rel_tol=1e-9, abs_tol=1e-12)
    assert math.isclose(run.peak_velocity, p.peak_velocity, rel_tol=1e-9)
    # the branches decide which limit binds: T is the smallest of the three candidate times
    T_theta = (2 * math.pi * theta / J) ** (1 / 3)
    T_E, T_W = E * math.pi / J, math.sqrt(2 * math.pi * W / J)
    assert math.isclose(run.accel_time, min(T_theta, T_E, T_W), rel_tol=1e-12)


def test_branch_cases_cover_every_path():
    """The four moves notebook 01 plots take the four paths of the flowchart, one each."""
    paths = {D.run_flowchart(*args).branches for args in D.PLANNER_BRANCH_CASES.values()}
    assert paths == set(D.flowchart_branches())
    for name, args in D.PLANNER_BRANCH_CASES.items():
        run, p = D.run_flowchart(*args), plan_sine_jerk(*args)
        assert math.isclose(run.cruise_time, p.cruise_time, rel_tol=1e-9, abs_tol=1e-15), name


def test_flowchart_drawing_shows_every_step():
    d = D.stojcic_fig2()
    text = "\n".join(D.drawing_labels(d))
    for step in D.PLANNER_FLOWCHART:
        assert step.label in text and step.equation in text or step.kind == "decision"
        if step.kind == "decision":
            assert step.label in text and step.yes_label in text
    assert "Stojčić Fig. 2" in text


def test_flowchart_rejects_bad_input():
    with pytest.raises(ValueError, match="max_jerk"):
        D.run_flowchart(1.0, -1.0, 1.0, 1.0)
    with pytest.raises(ValueError, match="distance"):
        D.run_flowchart(float("nan"), 1.0, 1.0, 1.0)


@pytest.mark.parametrize("name", list(D.ALL_DIAGRAMS))
def test_diagram_builds_svg(name, tmp_path):
    d = D.ALL_DIAGRAMS[name]()
    out = tmp_path / "d.svg"
    d.save(str(out))
    svg = out.read_text()
    assert svg.startswith("<?xml") or "<svg" in svg[:500]
    number = name.split("Fig. ")[1]
    assert any(f"Fig. {number}" in lab for lab in D.drawing_labels(d))


def test_xu_fig3_from_a_shaped_cycle():
    import matplotlib

    matplotlib.use("Agg")
    from jerklab.piezo import ScanSpec, shape_cycle

    c = shape_cycle(0, 0, spec=ScanSpec(F_max=100.0))
    ax = D.xu_fig3(c)
    assert "Fig. 3" in ax.get_title()
    # the dashed ramp starts at u_T(T) and rises at w_ss per sample, as the scan command does
    line = ax.get_lines()[1]
    x, y = line.get_data()
    u = c.command()
    assert math.isclose(y[0], u[c.N], rel_tol=1e-12)
    slope = (y[-1] - y[0]) / (x[-1] - x[0]) * c.spec.Ts * 1e3
    assert math.isclose(slope, c.w, rel_tol=1e-9)
    assert D.xu_fig3().get_title() == ax.get_title()
