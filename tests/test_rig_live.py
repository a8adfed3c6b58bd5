"""jerklab.rig.live: the live plot of the rig's runs.

The throttle (at least 5 and at most 8 redraws a second of run, on a fake clock that follows
the samples' own time, and in real time with the background thread), nothing lost (the final
drawing holds every sample of the recording, the curves equal the recording's arrays), one
drawing only when not live, the headless bundle (widget view and the final PNG), the ranges
of the axes, and the rig client driving the plot in step, PRBS, move and host-loop runs.
The tests that run seconds of telemetry are marked ``slow``, the headless notebook ``notebook``.
"""

from __future__ import annotations

import base64
import io
import math
import threading
import time

import numpy as np
import pytest
from PIL import Image

from jerklab import planner
from jerklab import rig as R
from jerklab.controller import pole_placement_pid
from jerklab.rig import live as L
from jerklab.rig.options import Device
from jerklab.rig.recording import Recording

TS = 0.005


def _recording(kind="demo"):
    return Recording(
        {"kind": kind, "Ts": TS, "counts_per_rad": 448 / (2 * math.pi), "volts_per_pwm": 12 / 1023}
    )


@pytest.fixture
def plots(monkeypatch):
    """The rig client's live plots, made synchronous on a clock that is the run's own time
    (samples × Ts: a rig running in real time), without a widget, at a low resolution (quick)."""
    made = []

    def factory(rec, total, label, enabled=None, **kw):
        kw.pop("display", None)
        p = L.LivePlot(
            rec,
            total,
            label,
            widget=False,
            background=False,
            clock=lambda: len(rec) * rec.Ts,
            dpi=36,
            **kw,
        )
        made.append(p)
        return p

    import jerklab.rig.client as C

    monkeypatch.setattr(C, "_live_plot", factory)
    return made


def _check_complete(p, rec):
    """The final drawing holds every sample and its curves are the recording's arrays."""
    assert p.drawn_samples[-1] == len(rec) > 0
    np.testing.assert_array_equal(p.line_pos.get_xdata(), rec.time)
    np.testing.assert_array_equal(p.line_pos.get_ydata(), rec.position)
    np.testing.assert_array_equal(p.line_v.get_ydata(), rec.voltage)
    if p.line_ref is not None:
        np.testing.assert_array_equal(p.line_ref.get_ydata(), rec.reference)
    img = Image.open(io.BytesIO(p.png))
    assert img.format == "PNG" and img.size == (7 * p.fig.dpi, round(4.2 * p.fig.dpi))


def _rate_during_run(p, rec):
    """Redraws per second of run between the first and the last sample (the initial empty
    figure and the final drawing on close left out)."""
    during = p.draws - 2
    return during / (len(rec) * rec.Ts)


def test_nice_limit_is_the_next_1_2_5_value():
    for x, want in [(0.3, 0.5), (1.0, 1.0), (1.01, 2.0), (7, 10.0), (-0.0012, 0.002), (200, 200)]:
        assert L.nice_limit(x) == pytest.approx(want), x
    assert L.nice_limit(0) == 1.0 and L.nice_limit(math.nan) == 1.0


def test_axes_widen_and_never_narrow():
    rec = _recording()
    p = L.LivePlot(rec, 100, "demo", widget=False, background=False, clock=lambda: 0.0)
    assert p.ax_pos.get_ylim() == (-1.0, 1.0)
    for k in range(100):  # position 0 -> ~3.4 rad (counts), voltage 0 -> -12 V
        rec.append(k, 0.0, 5 * k, -10 * k)
    p.close("complete")
    lo, hi = p.ax_pos.get_ylim()
    assert lo == -1.0 and hi >= rec.position.max() and hi == L.nice_limit(1.25 * rec.position.max())
    vlo, vhi = p.ax_v.get_ylim()
    assert vhi == 1.0 and vlo <= rec.voltage.min()
    assert p.full_draws == 2  # the empty figure, then once more as both axes widened


@pytest.mark.slow  # seconds of runs, in real time or drawn 8 times a second
def test_step_redraws_5_to_8_times_a_second_and_loses_nothing(plots):
    board = R.connect(progress=False)
    rec = board.step(3.0, 2.0, path=False)
    (p,) = plots
    rate = _rate_during_run(p, rec)
    assert 5.0 <= rate <= 8.0 + 1 / (len(rec) * TS), rate
    assert p.drawn_samples == sorted(p.drawn_samples)
    assert p.draws > 10 and p.full_draws == 1  # the step's axes were right from the start
    assert p.line_ref is None and p.status == "complete"
    _check_complete(p, rec)


@pytest.mark.slow  # seconds of runs, in real time or drawn 8 times a second
def test_prbs_and_move_plots_hold_every_sample(plots):
    board = R.connect(progress=False)
    rec = board.record_prbs(2.0, seconds=0.6, path=False)
    p = plots[-1]
    assert p.reference == "V" and p.line_ref.axes is p.ax_v
    assert _rate_during_run(p, rec) >= 5.0
    _check_complete(p, rec)
    profile = planner.plan_sine_jerk(10 * math.pi, 2e4, 300.0, 100.0)
    gains = pole_placement_pid(*board.model, wn=20.0).discretize(TS)
    rec = board.run_move(profile, gains, TS, path=False, settle=0.5)
    p = plots[-1]
    assert p.reference == "rad" and p.line_ref.axes is p.ax_pos
    assert p.ax_pos.get_ylim()[1] >= 10 * math.pi  # the move's distance, from the start
    assert _rate_during_run(p, rec) >= 5.0
    _check_complete(p, rec)


def test_live_false_draws_nothing_and_a_bad_value_is_named(plots):
    board = R.connect(progress=False)
    board.step(1.0, 0.2, path=False, live=False)
    assert plots == []
    with pytest.raises(TypeError, match="live"):
        board.step(1.0, 0.2, path=False, live="yes")
    with pytest.raises(TypeError, match="live"):
        R.connect(progress=False, live=1)
    quiet = R.connect(progress=False, live=False)
    assert quiet.live is False
    quiet.step(1.0, 0.2, path=False)  # the rig's setting, no run's live=
    assert plots == []


def test_not_live_draws_the_final_figure_once():
    rec = _recording()
    p = L.LivePlot(rec, 50, "headless", live=False, widget=False)
    for k in range(50):
        rec.append(k, 0.0, k, 100)
        p.update(len(rec))
    assert p.draws == 0
    p.close("complete")
    p.close("complete")  # a second close does nothing
    assert p.draws == 1 and p.drawn_samples == [50]
    _check_complete(p, rec)


@pytest.mark.slow  # seconds of runs, in real time or drawn 8 times a second
def test_background_thread_redraws_in_real_time_and_close_draws_all():
    """A producer appends 200 samples a second for 1 s (a rig in real time); the plot's thread
    redraws at 5 to 8 per second meanwhile, and close() draws all of them."""
    rec = _recording()
    # the positions stay within the expected range: no full redraw during the run
    p = L.LivePlot(
        rec, 200, "real time", widget=False, position_range=200 / rec._cpr, voltage_range=2.0
    )
    assert p.draws == 1  # the empty figure, before the run
    t0 = time.monotonic()
    for k in range(200):
        while time.monotonic() < t0 + k * TS:
            time.sleep(0.001)
        rec.append(k, 0.0, k, 100)
        p.update(len(rec))
    elapsed = time.monotonic() - t0
    during = p.draws - 1
    p.close("complete")
    assert threading.active_count() == 1 or not p._thread.is_alive()
    assert 5.0 * elapsed - 1 <= during <= 8.0 * elapsed + 1, (during, elapsed)
    assert p.full_draws == 1
    _check_complete(p, rec)


def test_widget_shows_the_count_and_the_end_bundle_carries_the_png():
    pytest.importorskip("ipywidgets")
    shown, updates = [], []

    class Handle:
        def update(self, bundle, raw=False):
            updates.append((bundle, raw))

    def display(widget):
        shown.append(widget)
        return Handle()

    rec = _recording()
    p = L.LivePlot(rec, 20, "widget", background=False, display=display, clock=lambda: len(rec))
    assert shown == [p.widget] and L.BOX_CLASS in p.widget._dom_classes
    assert p.count.value == "0/20 samples" and L.COUNT_CLASS in p.count._dom_classes
    for k in range(20):
        rec.append(k, 0.0, k, 100)
        p.update(len(rec))
    assert p.count.value.endswith("/20 samples") and p.image.value == p.png
    p.close("complete")
    assert p.count.value == "20 samples (complete)"
    ((bundle, raw),) = updates
    assert raw is True
    assert bundle["application/vnd.jupyter.widget-view+json"]["model_id"] == p.widget.model_id
    assert base64.b64decode(bundle["image/png"]) == p.png


def test_host_loop_plots_every_tick(plots):
    board = R.connect(progress=False)
    profile = planner.plan_sine_jerk(2 * math.pi, 500.0, 40.0, 10.0)  # one turn in 1.5 s
    rec = board.host_loop(
        lambda t, x, r: 1.5 * (r - x),  # V/rad, as tests/test_hostloop.py
        max_misses=255,
        Ts=0.01,
        duration=profile.duration + 0.2,
        reference=profile,
        path=False,
    )
    p = plots[-1]
    assert rec.metadata["status"] == "complete" and p.status == "complete"
    assert p.label.endswith("hostloop")
    _check_complete(p, rec)


def test_outside_a_kernel_there_is_no_plot():
    assert isinstance(L.live_plot(_recording(), 10, "script", True), L.NoProgress)


def test_the_environment_turns_the_default_off(monkeypatch):
    monkeypatch.setattr(L, "in_jupyter_kernel", lambda: True)
    for value in ("0", "off", "False", " no "):
        monkeypatch.setenv(L.ENV, value)
        assert not L.default_on()
        assert isinstance(L.live_plot(_recording(), 10, "env"), L.NoProgress)
    monkeypatch.setenv(L.ENV, "1")
    assert L.default_on()


@pytest.mark.notebook
def test_headless_notebook_keeps_the_final_plot(tmp_path):
    """A notebook executed headless (nbclient: a kernel, no widget front end): the live plot's
    output ends as a bundle of the widget view and the final figure's PNG, which a viewer
    without widgets shows; the kernel's own sample count is printed beside it."""
    nbformat = pytest.importorskip("nbformat")
    nbclient = pytest.importorskip("nbclient")
    nb = nbformat.v4.new_notebook()
    nb.cells = [
        nbformat.v4.new_code_cell(
            "from jerklab import rig\n"
            "board = rig.connect(progress=False, live=True)\n"
            "rec = board.step(3.0, 0.5, path=False)\n"
            "print(len(rec))"
        )
    ]
    nbclient.NotebookClient(nb, timeout=120, kernel_name="python3").execute()
    outputs = nb.cells[0].outputs
    (shown,) = [o for o in outputs if o.output_type == "display_data"]
    assert "application/vnd.jupyter.widget-view+json" in shown.data
    img = Image.open(io.BytesIO(base64.b64decode(shown.data["image/png"])))
    assert img.format == "PNG" and img.size == (504, 302)
    (printed,) = [o for o in outputs if o.output_type == "stream"]
    assert int(printed.text) == 0.5 / TS + 10  # the step's samples and 0.05 s at rest


@pytest.mark.slow  # seconds of runs, in real time or drawn 8 times a second
def test_a_real_time_rig_run_feeds_the_thread(monkeypatch):
    """The client's own factory (background thread) on a virtual rig in real time."""
    pytest.importorskip("ipywidgets")
    made = []
    real = L.LivePlot

    def plot(*a, **kw):
        kw["display"] = lambda w: None
        made.append(real(*a, **kw))
        return made[-1]

    monkeypatch.setattr(L, "in_jupyter_kernel", lambda: True)
    monkeypatch.setattr(L, "LivePlot", plot)
    monkeypatch.delenv(L.ENV, raising=False)  # the default: on
    board = R.connect(device=Device(speed=1.0), progress=False)
    rec = board.step(2.0, 0.6, path=False, rest=0.0)
    (p,) = made
    assert p.draws >= 3 and not p._thread.is_alive()  # empty, during the run (>= 1), final
    assert p.count.value == f"{len(rec)} samples (complete)"
    _check_complete(p, rec)


def test_the_tuning_panel_draws_its_rig_run_live_in_its_own_box(monkeypatch, tmp_path):
    """The class page's panel on a rig of its kernel (``jerklab app`` without a shared rig): a
    button callback has no cell output, so the run's live plot goes into the panel's own box
    (``rig.live_display``), is redrawn during the run, ends with the recording's sample count,
    and is dropped when a slider changes the design."""
    from jerklab.app import panel_for_page

    monkeypatch.setenv("JERKLAB_RECORDINGS", str(tmp_path))
    made = []

    def factory(rec, total, label, enabled=None, **kw):
        p = L.LivePlot(
            rec, total, label, background=False, clock=lambda: len(rec) * rec.Ts, dpi=36, **kw
        )
        made.append(p)
        return p

    import jerklab.rig.client as C

    monkeypatch.setattr(C, "_live_plot", factory)
    p = panel_for_page(rig_port="virtual")
    try:
        p.student.value = "s-live"
        p.rig_button.click()
        assert p._rig_error is not None, p.rig_status.value
        (plot,) = made
        (box,) = p.live_box.children
        assert box is plot.widget and L.BOX_CLASS in box._dom_classes
        n = len(p.last_recording)
        assert plot.count.value == f"{n} samples (complete)"
        assert _rate_during_run(plot, p.last_recording) >= 5.0
        _check_complete(plot, p.last_recording)
        p.controls["wn"].value = 25.0
        assert p.live_box.children == ()
    finally:
        p.rig.close()


@pytest.mark.slow  # seconds of runs in real time
def test_the_tuning_panel_draws_a_shared_rig_run_live_in_its_own_box(monkeypatch, tmp_path):
    """The class page's panel on the shared rig (``jerklab app --rig``: a broker): the samples
    the broker streams during the run feed the same live plot, in the panel's own box, redrawn
    during the run, finished with every sample of the returned recording."""
    from jerklab.app import panel_for_page
    from jerklab.broker import RigBroker

    monkeypatch.setenv("JERKLAB_RECORDINGS", str(tmp_path))
    monkeypatch.setattr(L, "in_jupyter_kernel", lambda: True)
    made = []
    real = L.LivePlot

    def plot(rec, total, label, **kw):
        # in step with the batches (no thread), at a low resolution
        made.append(real(rec, total, label, background=False, clock=time.monotonic, dpi=36, **kw))
        return made[-1]

    monkeypatch.setattr(L, "LivePlot", plot)
    with RigBroker(None, speed=1.0) as broker:
        p = panel_for_page(rig_port=broker.address)
        p.student.value = "s-shared"
        p.move = dict(p.move, distance=50.0)  # a 2 s move: seconds of redraws on a loaded machine
        p.rig_button.click()
        assert p._rig_error is not None, p.rig_status.value
    (live,) = made
    (box,) = p.live_box.children
    assert box is live.widget and L.BOX_CLASS in box._dom_classes
    rec = p.last_recording
    assert live.count.value == f"{len(rec)} samples (complete)"
    during = [n for n in live.drawn_samples[1:-1] if 0 < n < len(rec)]
    assert len(during) >= 3, live.drawn_samples
    _check_complete(live, rec)
    assert broker.streams and broker.streams[0]["identity"] == "s-shared"
