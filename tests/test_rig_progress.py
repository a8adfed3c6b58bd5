"""The rig's progress bar: ipywidgets inside a Jupyter kernel, text in a terminal, nothing
when ``progress=False``; at most ~10 redraws a second; headless kernels keep working."""
from __future__ import annotations

import io
import sys
import types

import pytest

from jerklab.rig import client, connect


@pytest.fixture
def rig(tmp_path):
    with connect(recordings=tmp_path) as r:
        yield r


@pytest.fixture
def shown(monkeypatch):
    """Widgets the rig would display in a notebook (captured instead of displayed)."""
    out = []
    monkeypatch.setattr(client, "_display", out.append)
    return out


def _kernel(monkeypatch, detected):
    monkeypatch.setattr(client, "_in_jupyter_kernel", lambda: detected)


def test_widget_bar_in_a_kernel(rig, shown, monkeypatch, capsys):
    import ipywidgets as W

    _kernel(monkeypatch, True)
    rec = rig.step(2.0, 0.5, rest=0.05)              # 10 + 100 samples
    assert len(rec) == 110 and capsys.readouterr().out == ""
    assert len(shown) == 1
    box = shown[0]
    bar, label = box.children
    assert isinstance(box, W.HBox) and isinstance(bar, W.IntProgress) and isinstance(label, W.Label)
    assert bar.max == 110 and bar.value == 110 and bar.bar_style == "success"
    assert bar.description == "virtual step"
    assert label.value.startswith("110/110 samples, ") and label.value.endswith(" s (complete)")


def test_widget_bar_for_a_move(rig, shown, monkeypatch):
    import math

    from jerklab.controller import pole_placement_pid
    from jerklab.planner import plan_sine_jerk

    _kernel(monkeypatch, True)
    prof = plan_sine_jerk(math.pi, 2000.0, 300.0, 60.0)
    rec = rig.run_move(prof, pole_placement_pid(32.4, 0.025, wn=20.0), settle=0.1)
    bar = shown[0].children[0]
    assert bar.max == len(rec) == rec.metadata["plan"]["n_samples"] + 20
    assert bar.value == bar.max and bar.description == "virtual move"


def test_text_bar_in_a_terminal(rig, shown, monkeypatch, capsys):
    _kernel(monkeypatch, False)
    rig.step(2.0, 0.5, rest=0.05)
    out = capsys.readouterr().out
    assert shown == []
    last = out.split("\r")[-1]
    assert last.startswith("virtual step [" + "#" * 25 + "] 110/110 samples")
    assert last.rstrip().endswith("s complete")


def test_text_bar_when_ipywidgets_is_missing(rig, shown, monkeypatch, capsys):
    _kernel(monkeypatch, True)
    monkeypatch.setitem(sys.modules, "ipywidgets", None)   # import ipywidgets -> ImportError
    rig.step(1.0, 0.1, rest=0.0)
    assert shown == [] and "20/20 samples" in capsys.readouterr().out


@pytest.mark.parametrize("detected", [True, False])
def test_no_output_when_progress_is_false(tmp_path, shown, monkeypatch, capsys, detected):
    _kernel(monkeypatch, detected)
    with connect(recordings=tmp_path, progress=False) as r:
        r.step(1.0, 0.1)
    with connect(recordings=tmp_path) as r:
        r.step(1.0, 0.1, progress=False)
    assert shown == [] and capsys.readouterr().out == ""


def test_chooser():
    assert isinstance(client._progress(10, "x", False), client._NoProgress)


def test_kernel_detection(monkeypatch):
    assert client._in_jupyter_kernel() is False          # pytest is no kernel
    fake = types.ModuleType("IPython")
    monkeypatch.setitem(sys.modules, "IPython", fake)
    fake.get_ipython = lambda: None                      # IPython imported, no shell
    assert client._in_jupyter_kernel() is False
    fake.get_ipython = lambda: types.SimpleNamespace()   # terminal IPython: a shell without kernel
    assert client._in_jupyter_kernel() is False
    fake.get_ipython = lambda: types.SimpleNamespace(kernel=object())   # ipykernel's shell
    assert client._in_jupyter_kernel() is True
    monkeypatch.delitem(sys.modules, "IPython")          # never imported: no kernel, no import
    assert client._in_jupyter_kernel() is False and "IPython" not in sys.modules


@pytest.mark.parametrize("kind", ["text", "widget"])
def test_at_most_ten_redraws_a_second(monkeypatch, kind):
    """A real-time run (1000 samples at 5 ms, 5 s) on a fake clock: <= 10 redraws/s + the last."""
    now = [0.0]
    monkeypatch.setattr(client, "time", types.SimpleNamespace(monotonic=lambda: now[0]))
    if kind == "text":
        bar = client._TextProgress(1000, "run", stream=io.StringIO())
    else:
        bar = client._WidgetProgress(1000, "run", display=lambda w: None)
    for n in range(1, 1001):
        now[0] += 0.005
        for _ in range(3):                               # the client updates after every read
            bar.update(n)
    bar.close("complete")
    assert 45 <= bar.draws <= 5.0 / bar.min_interval + 2
    assert bar._drawn == 1000
    if kind == "text":
        assert bar.stream.getvalue().split("\r")[-1].startswith("run [" + "#" * 25 + "] 1000/1000")
    else:
        assert bar.bar.value == 1000 and bar.text.value == "1000/1000 samples, 5.0 s (complete)"


def test_partial_run_shows_its_last_count(monkeypatch):
    now = [0.0]
    monkeypatch.setattr(client, "time", types.SimpleNamespace(monotonic=lambda: now[0]))
    bar = client._WidgetProgress(100, "run", display=lambda w: None)
    bar.update(1)
    bar.update(37)                                       # within 0.1 s: not drawn yet
    assert bar.bar.value == 1
    bar.close("timeout")
    assert bar.bar.value == 37 and bar.bar.bar_style == "danger"
    assert bar.text.value.endswith("(timeout)")


def test_widget_bar_in_a_headless_kernel(tmp_path):
    """A real kernel (nbclient, as tests/test_notebooks.py): detected, the widget is shown
    (a widget view in the output, no text bar), and execution completes."""
    import nbformat
    from nbclient import NotebookClient

    nb = nbformat.v4.new_notebook()
    nb.cells = [nbformat.v4.new_code_cell(
        "from jerklab.rig import connect, client\n"
        f"rig = connect(recordings={str(tmp_path)!r})\n"
        "print('kernel', client._in_jupyter_kernel())\n"
        "rec = rig.step(2.0, 0.2)\n"
        "print(len(rec), rec.metadata['status'])\n"
        "rig.close()")]
    NotebookClient(nb, timeout=60, kernel_name="python3").execute()
    outs = nb.cells[0].outputs
    text = "".join(o.get("text", "") for o in outs if o.output_type == "stream")
    views = [o for o in outs if o.output_type == "display_data"
             and "application/vnd.jupyter.widget-view+json" in o.data]
    assert "kernel True" in text and "50 complete" in text and "samples" not in text
    assert len(views) == 1
